"""What a procedure receives besides the bench: steps, confirmation, audit, output files.

`RunContext.step(name)` logs the start, end, duration and outcome of a step to the audit;
`check_watchdog()` refuses a device watchdog (as read from the device) the limits do not allow;
`check_link()` measures the exciter link's response time and refuses one too slow for the
test's cap (docs/decisions/0023);
`confirm(plan)` checks that this run holds the bench lock and the watchdog, shows the plan
(printed on every run shown to an operator, asked about on real devices unless `--yes`,
recorded either way), and `guard` refuses any device write before it; `hook(name)` calls a
test's hook at a named moment (deterministic fault injection); `save_raw` and `save_capture`
write files that are never overwritten, and a file that cannot be written (disk full,
read-only) is recorded in `lost_outputs` and ends the procedure with `OutputLost`.
"""
from __future__ import annotations

import contextlib
import getpass
import hashlib
import logging
import math
import statistics
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from bench_ctl.capture import write_capture
from bench_ctl.runner.audit import AuditLog
from bench_ctl.runner.config import BenchConfig, Limits
from bench_ctl.runner.safety import (
    LINK_SAMPLES,
    LinkTiming,
    NoOperator,
    OperatorDeclined,
    OutputLost,
    Refused,
    check_link,
    check_watchdog,
)
from drivers.device import TIMED_WRITE_GUARD_S, WriteRecord
from drivers.errors import DeviceError
from drivers.exciter import WatchdogReading
from drivers.recorder import RawRecord

log = logging.getLogger(__name__)

CAPTURE_NAME = "capture.csv"
RAW_NAME = "recorder_raw.bin"
ROUTINE_WRITES = ("heartbeat", "download")   # audited, flushed, not fsynced one by one

Hook = Callable[["RunContext"], None]
Confirm = Callable[[str], bool]


class WriteRefused(Refused):
    """A device write before the operator confirmed (a procedure bug; nothing was sent)."""


@dataclass(frozen=True)
class Criterion:
    """One pass criterion: measured value against its limit."""

    name: str
    passed: bool
    value: Any = None
    limit: Any = None
    unit: str = ""
    shown: str = ""     # how the operator reads it (engineering values), when not value/limit

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "passed": self.passed, "value": self.value,
                "limit": self.limit, "unit": self.unit, "shown": self.shown}

    def text(self) -> str:
        """`value (limit L unit)` rounded for a person; `shown` when the procedure gave one."""
        if self.shown:
            return self.shown
        def num(v: Any) -> str:
            return f"{v:.4g}" if isinstance(v, float) else str(v)
        return f"{num(self.value)} {self.unit} (limit {num(self.limit)} {self.unit})".replace("  ", " ")


@dataclass(frozen=True)
class ProcedureResult:
    """What a procedure returns when it ran to its end. `comms_error`: a communication error the
    procedure met after its test and carried to the end so as to keep the record (a read lost for
    good during recovery): the run still ends with exit 3 and says it."""

    criteria: tuple[Criterion, ...] = ()
    summary: str = ""
    data: dict[str, Any] = field(default_factory=dict)
    comms_error: str | None = None

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.criteria)


def part_name(name: str, part: str) -> str:
    """A run file's name for a part of a test of several records: capture.csv -> capture_<part>.csv."""
    if not part:
        return name
    stem, dot, suffix = name.partition(".")
    return f"{stem}_{part}{dot}{suffix}"


class RunContext:
    """The run a procedure is part of (see the module docstring)."""

    def __init__(self, *, procedure: str, config: BenchConfig, out_dir: Path, audit: AuditLog,
                 dry_run: bool, yes: bool, confirm: Confirm | None = None,
                 hooks: Mapping[str, Hook] | None = None, progress: bool = False,
                 warnings: tuple[str, ...] = ()) -> None:
        self.procedure = procedure
        self.warnings = warnings  # said loudly, and in the question before the first write
        self.config = config
        self.out_dir = out_dir
        self.audit = audit
        self.dry_run = dry_run
        self.yes = yes
        self.progress = progress
        self.operator = getpass.getuser()
        self.confirmed = False
        self.writes: list[WriteRecord] = []
        self.identities: dict[str, Any] = {}   # filled by the runner after connecting
        self.capture_path: Path | None = None
        self.sidecar_path: Path | None = None
        self.raw_path: Path | None = None
        self.lost_outputs: list[str] = []       # files that could not be saved, and why
        self.watchdog: WatchdogReading | None = None   # read from the exciter after connecting
        self.watchdog_s: float | None = None    # the watchdog once check_watchdog accepted it
        self.connected_mono: float | None = None  # when the runner connected (the link measured since)
        self.link: LinkTiming | None = None     # the exciter link once check_link accepted it
        self.bench_lock: Any = None             # runner.lock.BenchLock once taken (writing runs)
        self.download_tried = False             # the procedure asked for the record
        self.kept_raw: Path | None = None       # the record of an aborted test, kept by the runner
        #: the part of a test of several records the next one belongs to ("": the only one); its
        #: files are then capture_<part>.csv, recorder_raw_<part>.bin (`part_name`)
        self.part = ""
        self.captures: list[Path] = []          # every capture saved, in order
        self._confirm = confirm
        self._hooks = dict(hooks or {})

    @property
    def limits(self) -> Limits:
        return self.config.limits

    # -- steps -------------------------------------------------------------------------------
    @contextlib.contextmanager
    def step(self, name: str, **info: Any) -> Iterator[None]:
        outer = self.audit.step
        self.audit.step = name
        self.audit.event("step_start", **info)
        log.info("step %s", name)
        self._show(f"{name} ...", end="")
        t0 = time.monotonic()
        try:
            yield
        except BaseException as exc:
            self.audit.event("step_end", result="failed", duration_s=time.monotonic() - t0,
                             error=f"{type(exc).__name__}: {exc}")
            self._show(f"{name}: failed ({time.monotonic() - t0:.1f} s)", end="\n")
            raise
        else:
            self.audit.event("step_end", result="ok", duration_s=time.monotonic() - t0)
            self._show(f"{name}: ok ({time.monotonic() - t0:.1f} s)", end="\n")
        finally:
            self.audit.step = outer

    def status(self, text: str) -> None:
        """A live readout on the operator's terminal (e.g. vt and efd while waiting); nothing
        when the run is not shown on a terminal. Never audited: notes are."""
        step = self.audit.step or ""
        self._show(f"{step}: {text}" if step else text, end="")

    @property
    def shown(self) -> bool:
        """The run is shown on a terminal (steps and live readouts are written)."""
        isatty = getattr(sys.stderr, "isatty", None)    # None: stderr closed (`2>&-`)
        try:
            return bool(self.progress and isatty is not None and isatty())
        except ValueError:                                # a closed file object
            return False

    def _show(self, text: str, *, end: str) -> None:
        """One line on stderr, rewritten in place until it ends (`end` = newline)."""
        if not self.shown:
            return
        sys.stderr.write("\r\x1b[K  " + text + end)
        sys.stderr.flush()

    def note(self, kind: str, **fields: Any) -> None:
        """An audit line of the procedure's own (readings, preconditions, measurements)."""
        self.audit.event(kind, **fields)

    def hook(self, name: str) -> None:
        """Call a test's hook registered for this moment (no-op otherwise)."""
        fn = self._hooks.get(name)
        if fn is not None:
            self.audit.event("hook", name=name)
            fn(self)

    # -- the device's watchdog ---------------------------------------------------------------
    def check_watchdog(self) -> float:
        """The exciter's watchdog as read from the device, or LimitViolation (nothing written)
        naming the value found and the limit (safety.check_watchdog). A watchdog longer than the
        pulse width cap but within the limit is said: it joins the run's warnings."""
        ex = self.config.exciter
        try:
            wd = check_watchdog(self.limits, self.watchdog, heartbeat_period_s=ex.heartbeat_period_s,
                                request_timeout_s=ex.timeout_s)
        except Refused as exc:
            self.audit.event("watchdog_check", accepted=False, reading=self.watchdog,
                             limit_s=self.limits.watchdog_limit_s, refused=str(exc))
            raise
        if self.watchdog_s is None:
            self.audit.event("watchdog_check", accepted=True, reading=self.watchdog,
                             limit_s=self.limits.watchdog_limit_s)
            cap = self.limits.pulse_width_max_s
            if wd > cap:
                warning = (f"the exciter's watchdog ({wd:.3f} s, read from the device) is longer than "
                           f"the pulse width cap ({cap:.3f} s): if this host dies during the pulse, "
                           f"the device ends it up to {wd:.3f} s after the last heartbeat")
                log.info("WARNING: %s", warning)   # in the plan the operator reads
                self.audit.event("warning", message=warning)
                self.warnings = (*self.warnings, warning)
        self.watchdog_s = wd
        return wd

    # -- the exciter's link -----------------------------------------------------------------
    def check_link(self, ex: Any, *, width_s: float, cap_name: str, what: str = "pulse") -> LinkTiming:
        """Measure the exciter link (LINK_SAMPLES reads of the setpoint, with every request answered
        since connecting) and refuse it (LimitViolation, nothing written) when it is too slow for
        a `width_s` pulse or step under the cap `limits.<cap_name>` (safety.check_link)."""
        times = sorted(ex.measure_link(LINK_SAMPLES, since_mono=self.connected_mono))
        # the slowest reply but one counts: one reply held up by this host (a stall of the
        # process, not the link) does not refuse the test; two do (docs/decisions/0023)
        slowest = times[-2] if len(times) >= LINK_SAMPLES else (times[-1] if times else math.inf)
        timing = LinkTiming(samples=len(times), max_s=slowest,
                            median_s=statistics.median(times) if times else math.inf)
        ex_cfg = self.config.exciter
        try:
            check_link(timing, width_s=width_s, cap_s=getattr(self.limits, cap_name), cap_name=cap_name,
                       timeout_s=ex_cfg.timeout_s, watchdog_s=self.watchdog_s,
                       heartbeat_period_s=ex_cfg.heartbeat_period_s, guard_s=TIMED_WRITE_GUARD_S, what=what)
        except Refused as exc:
            self.audit.event("link_check", accepted=False, **asdict(timing), refused=str(exc))
            raise
        self.audit.event("link_check", accepted=True, **asdict(timing))
        self.link = timing
        return timing

    def link_text(self) -> str:
        """`10 requests answered in 1.2 ms (median), 3.4 ms at most` for the plan."""
        return self.link.text() if self.link else "not measured"

    def watchdog_text(self) -> str:
        """`2.000 s (read from the device, register ...); limit 3.000 s` for the plan."""
        reading = self.watchdog.text() if self.watchdog else "not read"
        return f"{reading}; limit {self.limits.watchdog_limit_text()}"

    # -- confirmation and the write guard ----------------------------------------------------
    def confirm(self, summary: str) -> None:
        """Before the first write: this run holds the bench lock, the device's watchdog is
        accepted (else refused, nothing written), then the plan is shown and confirmed. A real
        bench asks the operator unless --yes; dry runs and --yes skip the question (recorded)
        but the plan is still printed on a run shown to an operator. The bench's warnings are
        part of what the operator confirms."""
        if self.bench_lock is None or not self.bench_lock.held:
            raise WriteRefused(f"{self.procedure}: no write without the bench lock (a procedure "
                               "declared WRITES = False writes nothing)")
        self.check_watchdog()
        if self.link is None:
            raise WriteRefused(f"{self.procedure}: no write before the exciter link was measured "
                               "(RunContext.check_link: a link too slow for the cap is refused)")
        if self.warnings:
            summary = summary + "".join(f"\nWARNING: {w}" for w in self.warnings)
        if self.dry_run or self.yes:
            why = "dry run against the simulated bench" if self.dry_run else "--yes given"
            self.audit.event("confirmation", asked=False, why=why, summary=summary)
            if self.progress:
                sys.stdout.write(f"{summary}\n({why}: not asked)\n")
                sys.stdout.flush()
        else:
            ask = self._confirm or _ask_operator
            try:
                answer = bool(ask(summary))
            except NoOperator as exc:
                self.audit.event("confirmation", asked=True, answer=None, refused="no operator",
                                 detail=str(exc), summary=summary, operator=self.operator)
                raise
            self.audit.event("confirmation", asked=True, answer=answer, summary=summary,
                             operator=self.operator)
            if not answer:
                raise OperatorDeclined("the operator did not confirm; nothing was written")
        self.confirmed = True

    def guard(self, device: str, register: str, value: float, purpose: str) -> None:
        """Called by the drivers before every write."""
        if not self.confirmed:
            raise WriteRefused(f"{device}: write of {value!r} to {register} ({purpose}) refused: "
                               "the procedure has not been confirmed (nothing was sent)")

    def on_write(self, record: WriteRecord) -> None:
        """Called by the drivers after every write and its read-back."""
        self.writes.append(record)
        self.audit.event("write", durable=record.purpose not in ROUTINE_WRITES,
                         **record.to_dict())

    # -- output files ------------------------------------------------------------------------
    def save_raw(self, raw: RawRecord) -> Path:
        """The recorder download exactly as received (before any conversion); OutputLost when
        it cannot be written (whatever was written whole is kept and named)."""
        target = self.out_dir / part_name(RAW_NAME, self.part)
        payload = raw.payload()
        try:
            path, head = raw.save(target)
        except OSError as exc:
            kept = target if target.exists() and not isinstance(exc, FileExistsError) else None
            self.raw_path = kept
            self._lost(f"{target.name}{'.json (its header)' if kept else ''}", exc,
                       f"the recorder download, {len(payload)} bytes, is not on disk" if not kept
                       else "the raw download is saved without its header")
        self.raw_path = path
        self.audit.event("raw_saved", path=str(path), header=str(head),
                         sha256=hashlib.sha256(payload).hexdigest(), bytes=len(payload))
        return path

    def save_capture(self, data: Mapping[str, Any], meta: Mapping[str, Any]) -> Path:
        """capture.csv and its sidecar, both or neither; OutputLost when they cannot be written."""
        try:
            csv_path, json_path = write_capture(self.out_dir / part_name(CAPTURE_NAME, self.part), dict(data),
                                                dict(meta))
        except OSError as exc:
            self._lost(f"{part_name(CAPTURE_NAME, self.part)} and its sidecar", exc, "the capture is not on disk")
        self.capture_path, self.sidecar_path = csv_path, json_path
        self.captures.append(csv_path)
        self.audit.event("capture_saved", path=str(csv_path), sidecar=str(json_path))
        return csv_path

    def _lost(self, what: str, exc: OSError, consequence: str) -> None:
        reason = f"[Errno {exc.errno}] {exc.strerror}" if exc.errno else str(exc)
        text = f"{self.out_dir / what}: NOT SAVED ({reason}); {consequence}"
        self.lost_outputs.append(text)
        self.audit.event("output_lost", what=what, error=reason)
        log.error("%s", text)
        raise OutputLost(text) from None

    # -- the end every recording test shares ------------------------------------------------
    def release(self, ex: Any, reason: str) -> None:
        """Give the exciter back (the heartbeat's statistics and the safe state noted); DeviceError
        when the device does not confirm it."""
        self.note("heartbeat", **asdict(ex.heartbeat_stats()))
        report = ex.safe_state(reason)
        self.note("safe_state", **report.to_dict())
        if not report.ok:
            raise DeviceError(f"release failed: {report.detail}", device=ex.name)

    def download(self, rec: Any) -> tuple[RawRecord, dict[str, Any]]:
        """The record downloaded, saved as received (before any conversion), then converted."""
        self.download_tried = True
        raw = rec.download(progress=self.progress_bar())
        self.save_raw(raw)
        return raw, raw.convert()

    def save_record(self, raw: RawRecord, data: Mapping[str, Any], test: Mapping[str, Any]) -> Path:
        """The capture of a recorded test: its data, the test's description, the recorder's header."""
        raw_file = self.raw_path.name if self.raw_path else None
        meta = self.sidecar_meta(test=dict(test), recorder={**raw.header(), "raw_file": raw_file},
                                 channel_scaling=raw.scales)
        return self.save_capture(data, meta)

    def progress_bar(self) -> Callable[[int, int], None] | None:
        """A download progress bar on a terminal (None without `progress`)."""
        if not self.progress:
            return None
        from tqdm import tqdm

        bar = tqdm(unit="block", desc="download", leave=False, disable=None)  # None: off unless a terminal

        def update(done: int, total: int) -> None:
            bar.total = total
            bar.n = done
            bar.refresh()
            if done == total:
                bar.close()

        return update

    def sidecar_meta(self, **extra: Any) -> dict[str, Any]:
        """The capture sidecar's common part: bench config, devices, every write so far."""
        meta = {"procedure": self.procedure, "dry_run": self.dry_run, "operator": self.operator,
                "bench_config": self.config.to_dict(), "devices": dict(self.identities),
                "writes": [w.to_dict() for w in self.writes]}
        meta.update(extra)
        return meta


def _ask_operator(summary: str) -> bool:
    """Ask on the terminal. End of input (stdin closed or redirected from /dev/null) is no
    operator at all, refused as such; Ctrl-C at the question stays an interrupt."""
    import sys

    sys.stdout.write(f"{summary}\nThis writes to REAL devices. Proceed? [y/N]: ")
    sys.stdout.flush()
    line = sys.stdin.readline() if sys.stdin is not None else ""
    if not line:
        sys.stdout.write("\n")
        raise NoOperator("no operator confirmed (standard input is closed); an unattended run "
                         "needs --yes")
    return line.strip().lower() in ("y", "yes")
