"""The procedure runner: one call runs a procedure on a bench and always ends in a safe state.

`run_procedure(name, bench_config, out_dir, dry_run=..., yes=...)` loads
`procedures/<name>.py`, checks its parameters, opens the audit file and a DEBUG log next to
the capture, connects the bench (a dry run first starts the simulated bench and points the
config at it), runs the procedure, and on EVERY exit path - normal end, refusal, device error,
lost link, Ctrl-C - puts the devices in their safe state (exciter: pre-test setpoint back,
remote given back, heartbeat stopped; recorder: disarmed) with Ctrl-C deferred meanwhile.

Exit codes: 0 passed, 1 criteria failed, 2 aborted / refused (safe state reached),
3 communication error - and 3 whenever a safe state could NOT be confirmed, whatever else
happened (a failed restore is never a quiet log line).
"""
from __future__ import annotations

import contextlib
import importlib
import inspect
import logging
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench_ctl.runner.audit import AuditLog
from bench_ctl.runner.bench import Bench
from bench_ctl.runner.config import BenchConfig, ConfigError, load_bench_config
from bench_ctl.runner.context import (CAPTURE_NAME, RAW_NAME, Confirm, Criterion, Hook,
                                      ProcedureResult, RunContext)
from bench_ctl.runner.safety import CtrlC, Refused, Terminated
from drivers.device import SafeStateReport
from drivers.errors import CommError, DeviceError, IntegrityError
from drivers.exciter import check_heartbeat_timing, watchdog_s
from drivers.profile import load_profile

log = logging.getLogger(__name__)

EXIT_PASSED, EXIT_FAILED, EXIT_ABORTED, EXIT_COMMS = 0, 1, 2, 3
STATUS = {EXIT_PASSED: "passed", EXIT_FAILED: "criteria failed", EXIT_ABORTED: "aborted",
          EXIT_COMMS: "communication error"}
AUDIT_NAME = "audit.jsonl"
LOG_NAME = "run.log"
OUTPUT_NAMES = (AUDIT_NAME, LOG_NAME, CAPTURE_NAME, Path(CAPTURE_NAME).with_suffix(".json").name,
                RAW_NAME, RAW_NAME + ".json")


class OutputExists(FileExistsError):
    """The output folder already holds a run's files; nothing is overwritten."""


@dataclass(frozen=True)
class RunOutcome:
    """What a run left behind and how it ended."""

    procedure: str
    exit_code: int
    status: str                     # passed | criteria failed | aborted | communication error
    message: str
    out_dir: Path
    audit_path: Path
    log_path: Path
    capture_path: Path | None       # None when the run ended before saving a capture
    sidecar_path: Path | None
    raw_path: Path | None
    safe_state: tuple[SafeStateReport, ...]
    criteria: tuple[Criterion, ...]
    data: dict[str, Any]            # the procedure's measurements (ProcedureResult.data)
    dry_run: bool
    duration_s: float

    @property
    def safe(self) -> bool:
        """Every device confirmed its safe state."""
        return all(r.ok for r in self.safe_state)


def load_procedure(name: str) -> Any:
    """The function `procedures.<name>.<name>`; ConfigError naming what is missing."""
    if not name.isidentifier():
        raise ConfigError(f"procedure {name!r}: not a procedure name")
    try:
        module = importlib.import_module(f"procedures.{name}")
    except ModuleNotFoundError as exc:
        if exc.name == f"procedures.{name}":
            raise ConfigError(f"no procedure {name!r} (expected procedures/{name}.py)") from None
        raise
    fn = getattr(module, name, None)
    if not callable(fn):
        raise ConfigError(f"procedures/{name}.py has no function {name}()")
    return fn


def procedure_params(fn: Any, config: BenchConfig, name: str,
                     overrides: Mapping[str, Any] | None) -> dict[str, Any]:
    """[procedures.NAME] from the bench config, then `overrides`; unknown keys are errors."""
    allowed = {p.name: p for p in inspect.signature(fn).parameters.values()
               if p.kind is inspect.Parameter.KEYWORD_ONLY}
    params = {**config.procedure_params(name), **dict(overrides or {})}
    for key, value in params.items():
        if key not in allowed:
            raise ConfigError(f"{config.source}: unknown parameter procedures.{name}.{key} "
                              f"(allowed: {', '.join(sorted(allowed))})")
        default = allowed[key].default
        if isinstance(default, (int, float)) and not isinstance(default, bool) and (
                isinstance(value, bool) or not isinstance(value, (int, float))):
            raise ConfigError(f"{config.source}: procedures.{name}.{key} = {value!r} must be a "
                              "number")
    return params


def _check_config(config: BenchConfig) -> list[str]:
    """Everything the config names must exist before a file is opened: procedures, profiles;
    the heartbeat must be fast enough for the device watchdog. Returns warnings to say loudly:
    a device watchdog longer than the pulse width cap (a host that dies mid-pulse leaves the
    pulse on until the watchdog, beyond the cap; see docs/decisions/0007)."""
    for other in config.procedures:
        load_procedure(other)
    profiles = {}
    for device in ("exciter", "recorder"):
        try:
            profiles[device] = load_profile(getattr(config, device).profile)
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{config.source}: {device}.profile: {exc}") from None
    ex = config.exciter
    try:
        check_heartbeat_timing(profiles["exciter"], ex.heartbeat_period_s, ex.timeout_s)
    except ValueError as exc:
        raise ConfigError(f"{config.source}: exciter.heartbeat_period_s: {exc}") from None
    warnings = []
    wd = watchdog_s(profiles["exciter"])
    if wd is not None and wd > config.limits.pulse_width_max_s:
        warnings.append(f"the exciter's watchdog ({wd:g} s, profile {profiles['exciter'].name!r}) is longer "
                        f"than the pulse width cap ({config.limits.pulse_width_max_s:g} s): if this host "
                        f"dies during the pulse, the pulse lasts until the watchdog reverts it, up to "
                        f"{wd:g} s")
    return warnings


@contextlib.contextmanager
def _debug_log(path: Path) -> Iterator[None]:
    """A per-run DEBUG log file; other handlers keep the level they had."""
    root = logging.getLogger()
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setLevel(logging.DEBUG)
    handler.setFormatter(logging.Formatter(
        "%(asctime)s.%(msecs)03d %(levelname)s %(threadName)s %(name)s: %(message)s",
        "%Y-%m-%dT%H:%M:%S"))
    old_level = root.level
    pinned = [h for h in root.handlers if h.level == logging.NOTSET]
    for h in pinned:
        h.setLevel(old_level)
    pymodbus = logging.getLogger("pymodbus")
    old_pymodbus = pymodbus.level
    pymodbus.setLevel(max(logging.INFO, old_pymodbus))  # frames are in the errors already
    root.addHandler(handler)
    root.setLevel(logging.DEBUG)
    try:
        yield
    finally:
        root.removeHandler(handler)
        handler.close()
        root.setLevel(old_level)
        pymodbus.setLevel(old_pymodbus)
        for h in pinned:
            h.setLevel(logging.NOTSET)


def _classify(exc: BaseException) -> tuple[int, str, bool]:
    """(exit code, message, reconnect before the safe state) for what ended a run."""
    if isinstance(exc, Terminated):
        return EXIT_ABORTED, f"terminated by {exc.signal_name}", True
    if isinstance(exc, KeyboardInterrupt):
        return EXIT_ABORTED, "interrupted by the operator (Ctrl-C)", True
    if isinstance(exc, Refused):
        return EXIT_ABORTED, str(exc), False
    if isinstance(exc, (CommError, IntegrityError)):
        return EXIT_COMMS, f"communication error: {exc}", True
    if isinstance(exc, DeviceError):
        return EXIT_ABORTED, f"aborted: {exc}", False
    return EXIT_ABORTED, f"aborted by an unexpected error: {type(exc).__name__}: {exc}", False


def run_procedure(name: str, bench_config: BenchConfig | str | Path, out_dir: str | Path, *,
                  dry_run: bool = False, yes: bool = False,
                  params: Mapping[str, Any] | None = None, confirm: Confirm | None = None,
                  hooks: Mapping[str, Hook] | None = None, progress: bool = False,
                  sim_options: Mapping[str, Any] | None = None) -> RunOutcome:
    """Run procedure `name` on the bench and return how it ended (never raises for device
    trouble; raises ConfigError / OutputExists before anything is opened).

    `params` override `[procedures.NAME]` of the config; `confirm(summary) -> bool` replaces
    the interactive question for real devices; `hooks` maps moment names a procedure announces
    (e.g. "pulse_applied") to callables (tests inject faults there); `sim_options` go to the
    simulated bench of a dry run.
    """
    t_start = time.monotonic()
    config = (bench_config if isinstance(bench_config, BenchConfig)
              else load_bench_config(bench_config))
    fn = load_procedure(name)
    kwargs = procedure_params(fn, config, name, params)
    warnings = _check_config(config)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    existing = [n for n in OUTPUT_NAMES if (out / n).exists()]
    if existing:
        raise OutputExists(f"{out}: already holds {', '.join(existing)}; refusing to overwrite "
                           "a previous run (choose another --out)")
    audit_path, log_path = out / AUDIT_NAME, out / LOG_NAME
    with contextlib.ExitStack() as stack:
        stack.enter_context(_debug_log(log_path))
        audit = stack.enter_context(AuditLog(audit_path))
        audit.event("run_start", procedure=name, params=kwargs, dry_run=dry_run, yes=yes,
                    out_dir=str(out))
        if dry_run:
            from bench_ctl.runner.dryrun import simulated_bench

            config, _sim = stack.enter_context(simulated_bench(config, **dict(sim_options or {})))
        audit.event("config", bench_config=config.to_dict())
        for w in warnings:
            log.warning("WARNING: %s", w)
            audit.event("warning", message=w)
        ctx = RunContext(procedure=name, config=config, out_dir=out, audit=audit,
                         dry_run=dry_run, yes=yes, confirm=confirm, hooks=hooks,
                         progress=progress, warnings=tuple(warnings))
        code, message, result, reports = _run(fn, kwargs, config, ctx)
        if not all(r.ok for r in reports):
            failed = "; ".join(f"{r.device}: {r.action} - {r.detail}" for r in reports if not r.ok)
            log.critical("SAFE STATE NOT CONFIRMED: %s", failed)
            message = f"SAFE STATE NOT CONFIRMED ({failed}); run ended with: {message}"
            code = EXIT_COMMS
        summary = "; ".join(f"{r.device}: {r.action}" for r in reports)
        message = f"{message} [safe state: {summary}]" if summary else message
        audit.event("run_end", exit_code=code, status=STATUS[code], message=message,
                    criteria=[c.to_dict() for c in result.criteria],
                    safe_state=[r.to_dict() for r in reports],
                    capture=str(ctx.capture_path) if ctx.capture_path else None)
        log.info("%s: %s: %s", name, STATUS[code], message)  # the caller reports the outcome
    return RunOutcome(procedure=name, exit_code=code, status=STATUS[code], message=message,
                      out_dir=out, audit_path=audit_path, log_path=log_path,
                      capture_path=ctx.capture_path, sidecar_path=ctx.sidecar_path,
                      raw_path=ctx.raw_path, safe_state=tuple(reports),
                      criteria=result.criteria, data=dict(result.data), dry_run=dry_run,
                      duration_s=time.monotonic() - t_start)


def _run(fn: Any, kwargs: dict[str, Any], config: BenchConfig,
         ctx: RunContext) -> tuple[int, str, ProcedureResult, list[SafeStateReport]]:
    """Connect, run the procedure, then the safe state on every exit path."""
    bench = Bench(config, guard=ctx.guard, listener=ctx.on_write)
    result = ProcedureResult()
    reason = "end of procedure"
    reconnect = False
    with CtrlC().installed() as ctrl_c:
        try:
            with ctx.step("connect"):
                bench.connect()
                ctx.identities = bench.identities()
                ctx.note("identity", devices=ctx.identities)
            result = fn(bench, ctx, **kwargs)
            code = EXIT_PASSED if result.passed else EXIT_FAILED
            message = result.summary or STATUS[code]
        except BaseException as exc:  # noqa: BLE001 - every exit path ends in the safe state
            ctrl_c.armed = False
            code, message, reconnect = _classify(exc)
            reason = message.splitlines()[0]
            ctx.note("error", error=type(exc).__name__, message=str(exc),
                     **({"device_error": exc.to_dict()} if isinstance(exc, DeviceError) else {}))
            if not isinstance(exc, (Refused, DeviceError, KeyboardInterrupt)):
                log.exception("procedure %s failed", ctx.procedure)
        finally:
            ctrl_c.armed = False
            ctx.audit.step = "safe state"
            reports = bench.safe_state(reason, reconnect=reconnect, cancel=ctrl_c.abandon)
            for r in reports:
                ctx.note("safe_state", **r.to_dict())
            bench.close()
            ctx.audit.step = None
            if ctrl_c.ignored:
                ctx.note("ctrl_c_ignored", count=ctrl_c.ignored)
    return code, message, result, reports
