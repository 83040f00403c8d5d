"""The procedure runner: one call runs a procedure on a bench and always ends in a safe state.

`run_procedure(name, bench_config, out_dir, dry_run=..., yes=...)` loads
`procedures/<name>.py`, checks its parameters (types and the bounds the procedure declares),
opens the audit file and a DEBUG log next to the capture, takes the bench lock (one writing run
per exciter endpoint; procedures that declare `WRITES = False` do not), connects the bench (a
dry run first starts the simulated bench and points the config at it), reads the exciter's
watchdog, runs the procedure, and on EVERY exit path - normal end, refusal, device error, lost
link, Ctrl-C, SIGTERM / SIGHUP / SIGQUIT, a full disk - puts the devices in their safe state
(exciter: pre-test setpoint back, remote given back, heartbeat stopped; recorder: disarmed)
with those signals deferred meanwhile, then releases the lock.

The safe state never depends on the output folder: an audit line, the DEBUG log, the raw
download or the capture that cannot be written is counted and reported ("NOT SAVED ...") and
the run ends with exit 2 (3 when the safe state was not confirmed). A folder that cannot be
written at all is refused before anything is sent (`OutputUnusable`).

Exit codes: 0 passed, 1 criteria failed, 2 aborted / refused (safe state reached) / outputs
not saved, 3 communication error - and 3 whenever a safe state could NOT be confirmed, whatever
else happened (a failed restore is never a quiet log line).
"""
from __future__ import annotations

import contextlib
import importlib
import inspect
import logging
import math
import sys
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench_ctl.exitcodes import ExitCode
from bench_ctl.runner.audit import AuditLog
from bench_ctl.runner.bench import Bench
from bench_ctl.runner.config import BenchConfig, ConfigError, load_bench_config
from bench_ctl.runner.context import CAPTURE_NAME, RAW_NAME, Confirm, Criterion, Hook, ProcedureResult, RunContext
from bench_ctl.runner.lock import BenchLock
from bench_ctl.runner.safety import BenchBusy, CtrlC, OutputLost, Refused, Terminated
from drivers.device import SafeStateReport
from drivers.errors import CommError, DeviceError, IntegrityError

log = logging.getLogger(__name__)

#: how a run ended, in words (the audit's and the console's status)
STATUS = {ExitCode.OK: "passed", ExitCode.FAILED: "criteria failed", ExitCode.ABORTED: "aborted",
          ExitCode.COMMS: "communication error"}
AUDIT_NAME = "audit.jsonl"
LOG_NAME = "run.log"
OUTPUT_NAMES = (AUDIT_NAME, LOG_NAME, CAPTURE_NAME, Path(CAPTURE_NAME).with_suffix(".json").name,
                RAW_NAME, RAW_NAME + ".json")


class OutputExists(FileExistsError):
    """The output folder already holds a run's files; nothing is overwritten."""


class OutputUnusable(OSError):
    """The output folder cannot be written (read-only, full, not a folder): the run is refused
    before anything is sent to a device (no audit, no run). `str()` is the operator's line."""

    def __str__(self) -> str:
        return str(self.strerror)


@dataclass(frozen=True)
class RunOutcome:
    """What a run left behind and how it ended."""

    procedure: str
    exit_code: ExitCode
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
    not_saved: tuple[str, ...] = ()  # what the run could not save (disk full, read-only), and why
    expects_capture: bool = False   # the procedure is meant to leave a capture (its module's CAPTURES)
    started: bool = False           # the test was confirmed (writes may have been sent): not a refusal

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
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(f"{config.source}: procedures.{name}.{key} = {value!r} must be finite")
    check = getattr(inspect.getmodule(fn), "check_parameters", None)
    if check is not None:
        full = {k: p.default for k, p in allowed.items() if p.default is not inspect.Parameter.empty}
        problems = check({**full, **params})
        if problems:
            raise ConfigError(f"{config.source} / --param: procedures.{name}: " + "; ".join(problems))
    return params


def simulated_options(fn: Any, sim_options: Mapping[str, Any] | None) -> dict[str, Any]:
    """The simulated bench a dry run of the procedure starts: its module's SIMULATED_BENCH (e.g. the
    unit on line for an on-line test), then `sim_options`."""
    return {**dict(getattr(inspect.getmodule(fn), "SIMULATED_BENCH", {})), **dict(sim_options or {})}


def records_capture(fn: Any) -> bool:
    """Whether a procedure is meant to leave a capture (its module's CAPTURES, False unless it says
    True): a run of it that ends without one says so."""
    return bool(getattr(inspect.getmodule(fn), "CAPTURES", False))


def writes_to_devices(fn: Any) -> bool:
    """Whether a procedure may write (its module's WRITES, True unless it says False)."""
    return bool(getattr(inspect.getmodule(fn), "WRITES", True))


def _check_config(config: BenchConfig) -> list[str]:
    """Everything the config names must exist and fit before a file is opened: procedures, and
    (the profiles' kinds and roles were checked when the config was loaded) the drivers built
    once, without I/O. Returns warnings to say loudly (none today: the device's watchdog is
    read from the device after connecting, docs/decisions/0011)."""
    for other in config.procedures:
        load_procedure(other)
    try:
        Bench(config)   # the drivers check their profiles (registers, layout); no I/O
    except (KeyError, ValueError) as exc:
        raise ConfigError(f"{config.source}: {exc.args[0] if exc.args else exc}") from None
    return []


class _RunLogHandler(logging.FileHandler):
    """The run's DEBUG log file. A line it cannot write (disk full, read-only) stops it, quietly:
    no traceback on the console for each record; the loss is reported with the outcome."""

    def __init__(self, path: Path) -> None:
        super().__init__(path, encoding="utf-8")
        self.error: OSError | None = None
        self.lost = 0

    def emit(self, record: logging.LogRecord) -> None:
        if self.error is not None:
            self.lost += 1
            return
        super().emit(record)

    def handleError(self, record: logging.LogRecord) -> None:  # noqa: N802 - logging's name
        exc = sys.exc_info()[1]
        if not isinstance(exc, OSError):
            super().handleError(record)
            return
        self.error, self.lost = exc, self.lost + 1
        stream, self.stream = self.stream, None  # type: ignore[assignment]
        with contextlib.suppress(OSError):
            if stream is not None:
                stream.close()

    def close(self) -> None:
        try:
            super().close()
        except OSError as exc:
            self.error = self.error or exc
            self.stream = None  # type: ignore[assignment]

    def loss_text(self) -> str:
        if self.error is None:
            return ""
        reason = f"[Errno {self.error.errno}] {self.error.strerror}" if self.error.errno \
            else str(self.error)
        return f"{self.baseFilename}: NOT SAVED: {self.lost} log records lost ({reason})"


@contextlib.contextmanager
def _debug_log(path: Path) -> Iterator[_RunLogHandler]:
    """A per-run DEBUG log file; other handlers keep the level they had."""
    root = logging.getLogger()
    handler = _RunLogHandler(path)
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
        yield handler
    finally:
        root.removeHandler(handler)
        handler.close()
        root.setLevel(old_level)
        pymodbus.setLevel(old_pymodbus)
        for h in pinned:
            h.setLevel(logging.NOTSET)


def _classify(exc: BaseException) -> tuple[ExitCode, str, bool]:
    """(exit code, message, reconnect before the safe state) for what ended a run. A device
    error's message is its summary (device, register, value, device state); its raw frames are
    in the audit and the DEBUG log, not on the operator's console."""
    if isinstance(exc, Terminated):
        return ExitCode.ABORTED, f"terminated by {exc.signal_name}", True
    if isinstance(exc, KeyboardInterrupt):
        return ExitCode.ABORTED, "interrupted by the operator (Ctrl-C)", True
    if isinstance(exc, (Refused, OutputLost)):
        return ExitCode.ABORTED, str(exc), False
    if isinstance(exc, (CommError, IntegrityError)):
        return ExitCode.COMMS, f"communication error: {exc.summary}", True
    if isinstance(exc, DeviceError):
        return ExitCode.ABORTED, f"aborted: {exc.summary}", False
    if isinstance(exc, OSError):
        return ExitCode.ABORTED, f"aborted: {exc}", False
    return ExitCode.ABORTED, f"aborted by an unexpected error: {type(exc).__name__}: {exc}", False


def run_procedure(name: str, bench_config: BenchConfig | str | Path, out_dir: str | Path, *,
                  dry_run: bool = False, yes: bool = False,
                  params: Mapping[str, Any] | None = None, confirm: Confirm | None = None,
                  hooks: Mapping[str, Hook] | None = None, progress: bool = False,
                  sim_options: Mapping[str, Any] | None = None,
                  lock_folder: Path | None = None) -> RunOutcome:
    """Run procedure `name` on the bench and return how it ended (never raises for device
    trouble or a full disk; raises ConfigError / OutputExists / OutputUnusable before anything
    is sent).

    `params` override `[procedures.NAME]` of the config; `confirm(summary) -> bool` replaces
    the interactive question for real devices; `hooks` maps moment names a procedure announces
    (e.g. "pulse_applied") to callables (tests inject faults there); `sim_options` go to the
    simulated bench of a dry run; `lock_folder` replaces the per-user folder of bench locks.
    """
    t_start = time.monotonic()
    config = (bench_config if isinstance(bench_config, BenchConfig)
              else load_bench_config(bench_config))
    fn = load_procedure(name)
    kwargs = procedure_params(fn, config, name, params)
    warnings = _check_config(config)
    out = Path(out_dir)
    audit_path, log_path = out / AUDIT_NAME, out / LOG_NAME
    _usable_out(out)
    with contextlib.ExitStack() as stack:
        try:
            runlog = stack.enter_context(_debug_log(log_path))
            audit = AuditLog(audit_path).open()
        except OSError as exc:
            stack.close()
            _remove_new(log_path)
            raise OutputUnusable(exc.errno, f"--out {out}: cannot write the run's files there: "
                                 f"{exc.strerror or exc}; nothing was sent to a device") from None
        stack.callback(audit.close)
        audit.event("run_start", procedure=name, params=kwargs, dry_run=dry_run, yes=yes,
                    out_dir=str(out))
        if not audit.intact:  # no audit, no run
            reason = audit.loss_text()
            stack.close()
            _remove_new(audit_path, log_path)
            raise OutputUnusable(audit.error.errno if audit.error else 0,
                                 f"--out {out}: cannot write the audit ({reason}); nothing was sent "
                                 "to a device")
        if dry_run:
            from bench_ctl.runner.dryrun import simulated_bench

            config, _sim = stack.enter_context(simulated_bench(config, **simulated_options(fn, sim_options)))
        audit.event("config", bench_config=config.to_dict())
        for w in warnings:
            log.warning("WARNING: %s", w)
            audit.event("warning", message=w)
        ctx = RunContext(procedure=name, config=config, out_dir=out, audit=audit,
                         dry_run=dry_run, yes=yes, confirm=confirm, hooks=hooks,
                         progress=progress, warnings=tuple(warnings))
        lock = (BenchLock(config.exciter.url, config.exciter.unit_id, procedure=name,
                          out_dir=str(out), folder=lock_folder)
                if writes_to_devices(fn) else None)
        code, message, result, reports = _run(fn, kwargs, config, ctx, lock)
        if not all(r.ok for r in reports):
            failed = "; ".join(f"{r.device}: {r.action} - {r.detail}" for r in reports if not r.ok)
            log.critical("SAFE STATE NOT CONFIRMED: %s", failed)
            message = f"SAFE STATE NOT CONFIRMED ({failed}); run ended with: {message}"
            code = ExitCode.COMMS
        summary = "; ".join(f"{r.device}: {r.action}" for r in reports)
        message = f"{message} [safe state: {summary}]" if summary else message
        audit.event("run_end", exit_code=code, status=STATUS[code], message=message,
                    criteria=[c.to_dict() for c in result.criteria],
                    safe_state=[r.to_dict() for r in reports],
                    capture=str(ctx.capture_path) if ctx.capture_path else None,
                    not_saved=list(ctx.lost_outputs))
        stack.close()   # the audit and the DEBUG log are closed (their last losses counted)
        not_saved = _not_saved(ctx, audit, runlog)
        if not_saved and code in (ExitCode.OK, ExitCode.FAILED):
            code = ExitCode.ABORTED
        if not_saved and not ctx.lost_outputs:  # a lost capture already leads the message
            message = "; ".join(not_saved) + f"; run ended with: {message}"
        log.info("%s: %s: %s", name, STATUS[code], message)  # the caller reports the outcome
    return RunOutcome(procedure=name, exit_code=code, status=STATUS[code], message=message,
                      out_dir=out, audit_path=audit_path, log_path=log_path,
                      capture_path=ctx.capture_path, sidecar_path=ctx.sidecar_path,
                      raw_path=ctx.raw_path, safe_state=tuple(reports),
                      criteria=result.criteria, data=dict(result.data), dry_run=dry_run,
                      duration_s=time.monotonic() - t_start, not_saved=tuple(not_saved),
                      expects_capture=records_capture(fn), started=ctx.confirmed)


def _usable_out(out: Path) -> None:
    """The output folder exists (made if needed), holds no earlier run, and is writable;
    OutputExists / OutputUnusable otherwise (before any file is opened)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputUnusable(exc.errno, f"--out {out}: cannot make the folder: {exc.strerror or exc}; "
                             "nothing was sent to a device") from None
    existing = [n for n in OUTPUT_NAMES if (out / n).exists()]
    if existing:
        raise OutputExists(f"{out}: already holds {', '.join(existing)}; refusing to overwrite "
                           "a previous run (choose another --out)")


def _remove_new(*paths: Path) -> None:
    """Remove files this run created and that hold nothing of value (refused at the start)."""
    for path in paths:
        with contextlib.suppress(OSError):
            path.unlink()


def _not_saved(ctx: RunContext, audit: AuditLog, runlog: _RunLogHandler) -> list[str]:
    """What the run could not save, one line each: the capture / raw download, the audit, the
    DEBUG log."""
    lines = list(ctx.lost_outputs)
    if audit.loss_text():
        lines.append(audit.loss_text())
    if runlog.loss_text():
        lines.append(runlog.loss_text())
    return lines


def _run(fn: Any, kwargs: dict[str, Any], config: BenchConfig, ctx: RunContext,
         lock: BenchLock | None) -> tuple[ExitCode, str, ProcedureResult, list[SafeStateReport]]:
    """Take the bench lock, connect, read the watchdog, run the procedure, then the safe state
    on every exit path, then release the lock."""
    bench = Bench(config, guard=ctx.guard, listener=ctx.on_write)
    result = ProcedureResult()
    reason = "end of procedure"
    reconnect = False
    failed: BaseException | None = None
    with CtrlC().installed() as ctrl_c:
        try:
            if lock is not None:
                with ctx.step("bench lock"):
                    try:
                        ctx.bench_lock = lock.acquire()
                    except OSError as exc:
                        raise BenchBusy(f"refused before any write: cannot take the bench lock "
                                        f"({exc}); a run must know it is alone on the exciter") from None
                    ctx.note("bench_lock", key=lock.key, path=str(lock.path))
            with ctx.step("connect"):
                bench.connect()
                ctx.connected_mono = time.monotonic()
                ctx.identities = bench.identities()
                ctx.note("identity", devices=ctx.identities)
                ctx.watchdog = bench.exciter.read_watchdog()
                ctx.note("watchdog", **ctx.watchdog.to_dict())
            result = fn(bench, ctx, **kwargs)
            code = ExitCode.OK if result.passed else ExitCode.FAILED
            message = result.summary or STATUS[code]
            if result.comms_error is not None:   # met after the test, carried to keep the record
                code = ExitCode.COMMS
                message = f"communication error: {result.comms_error}; {message}"
                ctx.note("error", error="CommError", message=result.comms_error, carried=True)
        except BaseException as exc:  # noqa: BLE001 - every exit path ends in the safe state
            ctrl_c.armed = False
            failed = exc
            code, message, reconnect = _classify(exc)
            reason = message.splitlines()[0]
            ctx.note("error", error=type(exc).__name__, message=str(exc),
                     **({"device_error": exc.to_dict()} if isinstance(exc, DeviceError) else {}))
            if isinstance(exc, DeviceError):
                log.debug("%s", exc)  # with the last frames on the link (-vv and run.log)
            elif not isinstance(exc, (Refused, KeyboardInterrupt, OutputLost)):
                log.exception("procedure %s failed", ctx.procedure)
        finally:
            ctrl_c.armed = False
            ctx.audit.step = "safe state"
            keep = None
            if failed is not None and not isinstance(failed, OutputLost) and not ctx.download_tried:
                keep = lambda: _keep_record(bench, ctx, ctrl_c.abandon)  # noqa: E731
            reports = bench.safe_state(reason, reconnect=reconnect, cancel=ctrl_c.abandon, between=keep)
            for r in reports:
                ctx.note("safe_state", **r.to_dict())
            bench.close()
            if lock is not None:
                lock.release()   # only once the devices are safe
            ctx.audit.step = None
            if ctrl_c.ignored:
                ctx.note("ctrl_c_ignored", count=ctrl_c.ignored)
    if ctx.kept_raw is not None:
        message = f"{message}; the recorder's record of the aborted test was downloaded and saved raw ({ctx.kept_raw})"
    return code, message, result, reports


#: how long past the record's length the runner waits for the record of an aborted test
KEEP_MARGIN_S = 5.0


def _keep_record(bench: Bench, ctx: RunContext, cancel: Any) -> None:
    """After a test that ended abnormally, once the exciter is safe: a record this run's recorder
    triggered on (still recording, or done) is waited for and downloaded, and saved raw (there is
    no capture: the procedure did not finish), so that what the recorder holds is never thrown
    away by the recorder's safe state (a disarm). A Ctrl-C now (`cancel`) leaves it: the recorder
    is then disarmed. Trouble is noted, never raised."""
    rec = bench.recorder
    if not rec.armed_by_us:
        return
    try:
        state = rec.status()
        if state not in ("triggered", "done"):
            return
        if state == "triggered":
            wait_s = float(rec.read("record_length")) + KEEP_MARGIN_S
            log.warning("waiting up to %.0f s for the recorder to finish the record of the aborted test "
                        "(the setpoint is back; Ctrl-C again leaves the record)", wait_s)
            ctx.status(f"keeping the record: waiting for the recorder (up to {wait_s:.0f} s; Ctrl-C leaves it)")

            def check() -> None:
                if cancel.is_set():
                    raise KeyboardInterrupt
            rec.wait_status(("done",), wait_s, check=check)
        raw = rec.download()
        path = ctx.save_raw(raw)
        ctx.kept_raw = path
        ctx.note("record_kept", path=str(path), state_before=state)
    except KeyboardInterrupt:
        ctx.note("record_kept", left="the operator stopped it (Ctrl-C)")
    except (DeviceError, OutputLost, OSError) as exc:
        ctx.note("record_kept", failed=f"{type(exc).__name__}: {exc}")
        log.error("the record of the aborted test could not be kept: %s", exc)
