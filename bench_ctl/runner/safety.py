"""Safety checks done before the first write (docs/safety.md), and Ctrl-C handling.

Checks refuse, never clip: every violated limit is listed in one `LimitViolation` (or
`PreconditionFailed` for the state of the unit), raised before anything is written. The
device's watchdog is one of them: read from the device, refused when longer than the limits
allow or too short for this host's heartbeat (`check_watchdog`, docs/decisions/0011); the link to
the exciter is another: its response time, measured before the first write, must leave the
pulse (or the step) inside its cap as the plant sees it (`check_link`, docs/decisions/0023).
`CtrlC` keeps a Ctrl-C (or SIGTERM, SIGHUP, SIGQUIT) from interrupting the safe-state sequence
itself.
"""
from __future__ import annotations

import contextlib
import logging
import math
import signal
import threading
from collections.abc import Iterator
from dataclasses import dataclass

from bench_ctl.runner.config import Limits
from drivers.exciter import WatchdogReading, heartbeat_problems
from drivers.link import defer_interrupt, in_link_bookkeeping

log = logging.getLogger(__name__)


class Refused(Exception):
    """The run was refused before any write (exit 2)."""


class LimitViolation(Refused):
    """A requested test exceeds a configured limit."""


class PreconditionFailed(Refused):
    """The unit is not in the state the procedure needs (e.g. loaded, setpoint outside band)."""


class NoOperator(Refused):
    """Nobody could be asked: standard input is closed (an unattended run without --yes)."""


class OperatorDeclined(Refused):
    """The operator did not confirm."""


class BenchBusy(Refused):
    """Another run holds this bench (the host lock), or another master holds the exciter."""


class OutputLost(Exception):
    """A file of the run could not be saved (disk full, read-only): the run ends (exit 2) and
    says what it could not save; the devices' safe state never depends on it."""


@dataclass(frozen=True)
class PulsePlan:
    """A checked pulse: setpoints in pu, width in s."""

    setpoint_pu: float
    amplitude_pu: float
    width_s: float

    @property
    def pulse_setpoint_pu(self) -> float:
        return self.setpoint_pu + self.amplitude_pu


def _finite(name: str, value: float) -> str | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return f"{name} = {value!r} is not a finite number"
    return None


def check_pulse(limits: Limits, *, setpoint_pu: float, amplitude_pu: float,
                width_s: float, width_cap: str = "pulse_width_max_s") -> PulsePlan:
    """The pulse `setpoint_pu -> setpoint_pu + amplitude_pu` for `width_s`, or LimitViolation
    listing every violated limit (amplitude cap, width cap, absolute setpoint band). `width_cap`
    names the limit that caps the width (an on-line step's hold: "step_hold_max_s")."""
    problems = [p for p in (_finite("amplitude_pu", amplitude_pu), _finite("width_s", width_s),
                            _finite("setpoint_pu", setpoint_pu)) if p]
    if problems:
        raise LimitViolation("pulse refused: " + "; ".join(problems))
    if amplitude_pu == 0:
        problems.append("amplitude_pu = 0: nothing to test")
    if abs(amplitude_pu) > limits.pulse_amplitude_max_pu:
        problems.append(f"|amplitude_pu| = {abs(amplitude_pu):g} pu above the cap "
                        f"limits.pulse_amplitude_max_pu = {limits.pulse_amplitude_max_pu:g} pu")
    if not width_s > 0:
        problems.append(f"width_s = {width_s:g} s must be > 0")
    elif width_s > getattr(limits, width_cap):
        problems.append(f"width_s = {width_s:g} s above the cap limits.{width_cap} = "
                        f"{getattr(limits, width_cap):g} s")
    band = (limits.setpoint_min_pu, limits.setpoint_max_pu)
    for label, value in (("pre-test setpoint", setpoint_pu),
                         ("pulse setpoint", setpoint_pu + amplitude_pu)):
        if not band[0] <= value <= band[1]:
            problems.append(f"{label} {value:.6g} pu outside the band limits.setpoint_min_pu.."
                            f"setpoint_max_pu = {band[0]:g}..{band[1]:g} pu")
    if problems:
        raise LimitViolation("pulse refused before any write: " + "; ".join(problems))
    return PulsePlan(setpoint_pu=setpoint_pu, amplitude_pu=amplitude_pu, width_s=width_s)


def check_watchdog(limits: Limits, reading: WatchdogReading | None, *, heartbeat_period_s: float,
                   request_timeout_s: float) -> float:
    """The device's watchdog period as read from it, or LimitViolation naming the value found
    and the limit: unknown, zero (off), longer than `limits.watchdog_limit_s` (a host that dies
    during a pulse or a step leaves it on until the watchdog), or too short for this host's heartbeat
    (shorter than its period, under two beats, or a timed write could hold the beats off)."""
    if reading is None or reading.value_s is None:
        why = reading.error if reading is not None else "it was not read"
        raise LimitViolation(f"refused before any write: the exciter's watchdog period is unknown "
                             f"({why}); if this host dies while the setpoint is moved (a pulse, a step), "
                             "nothing is known to end it")
    wd = reading.value_s
    found = f"the exciter's watchdog reads {wd:.3f} s ({reading.register})"
    if not math.isfinite(wd) or wd <= 0:
        raise LimitViolation(f"refused before any write: {found}: the device's watchdog is off; "
                             "if this host dies while the setpoint is moved (a pulse, a step), nothing ends it")
    if wd > limits.watchdog_limit_s:
        raise LimitViolation(f"refused before any write: {found}, longer than the limit "
                             f"{limits.watchdog_limit_text()}: if this host dies while the setpoint is moved, the "
                             f"device holds it up to {wd:.3f} s after the last heartbeat; shorten "
                             "the device's watchdog or raise limits.watchdog_max_s")
    problems = heartbeat_problems(wd, heartbeat_period_s, request_timeout_s)
    if problems:
        raise LimitViolation(f"refused before any write: {found}: " + "; ".join(problems))
    return wd


#: reads of the exciter's setpoint that measure the link before the first write (with every
#: request answered since connecting)
LINK_SAMPLES = 10
#: the restore may reach the device up to one response time after it left; the slowest reply
#: measured counts this many times (a sample of a few tens of requests does not see the worst)
LINK_MARGIN = 2.0
#: the slowest reply measured may take at most this share of the request timeout: nearer, a
#: restore write would time out (WriteUncertain) and the pulse would end only in the safe state
LINK_TIMEOUT_SHARE = 0.5


@dataclass(frozen=True)
class LinkTiming:
    """The exciter link's response times as measured before the first write (s): `max_s` is the
    slowest reply but one (one reply held up by a stall of this host is not the link's)."""

    samples: int
    max_s: float
    median_s: float

    def text(self) -> str:
        return (f"{self.samples} requests answered in {self.median_s * 1e3:.1f} ms (median), "
                f"{self.max_s * 1e3:.1f} ms at most but one")


def check_link(timing: LinkTiming, *, width_s: float, cap_s: float, cap_name: str, timeout_s: float,
               watchdog_s: float | None, heartbeat_period_s: float, guard_s: float,
               what: str = "pulse") -> None:
    """Refuse (LimitViolation, nothing written) a link too slow for the test: the slowest reply
    (`timing.max_s`, taken LINK_MARGIN times) added to the width must stay inside the cap, as the
    plant sees it (the restore acts when it reaches the device, up to one response after it was
    sent); the pulse write's reply and read-back and one request in flight (3 replies) inside the
    width; the slowest reply within LINK_TIMEOUT_SHARE of the request timeout; and the heartbeat,
    which waits for a timed write's hold (the guard, one timeout and its reply) and sends a write and
    its read-back, within the device's watchdog."""
    if timing.samples < 1 or not math.isfinite(timing.max_s):
        raise LimitViolation("refused before any write: the exciter link's response time was not measured")
    r = timing.max_s
    found = f"the exciter answers in up to {r * 1e3:.1f} ms ({timing.text()})"
    problems = []
    if r > LINK_TIMEOUT_SHARE * timeout_s:
        problems.append(f"more than {LINK_TIMEOUT_SHARE:.0%} of the request timeout exciter.timeout_s = "
                        f"{timeout_s:.3f} s: the restore write could time out and the setpoint stay moved "
                        "until the safe state")
    if 3 * r > width_s:
        problems.append(f"the {what} write's reply and read-back and one request in flight (3 x {r * 1e3:.1f} ms) "
                        f"do not fit inside the {width_s:.3f} s {what}: the restore could not have the link at "
                        "its deadline")
    seen_s = width_s + LINK_MARGIN * r
    if seen_s > cap_s:
        problems.append(f"a {width_s:.3f} s {what} could last {seen_s:.3f} s as the plant sees it (the width + "
                        f"{LINK_MARGIN:g} x the slowest reply), above the cap limits.{cap_name} = {cap_s:.3f} s; "
                        "shorten the width or mend the link")
    if watchdog_s is not None:
        gap_s = heartbeat_period_s + guard_s + timeout_s + 3 * r
        if gap_s >= watchdog_s:
            problems.append(f"the heartbeat could be held off {gap_s:.3f} s (period, a timed write's hold, "
                            f"its reply, a beat and its read-back), not under the device's watchdog "
                            f"{watchdog_s:.3f} s")
    if problems:
        raise LimitViolation(f"refused before any write: the link is too slow for this test: {found}: "
                             + "; ".join(problems))


def check_no_load(limits: Limits, p_mw: float) -> None:
    """No-load precondition: |p| below limits.no_load_p_max_mw."""
    if not math.isfinite(p_mw) or abs(p_mw) >= limits.no_load_p_max_mw:
        raise PreconditionFailed(
            f"no-load precondition failed: active power p = {p_mw:.6g} MW, must be below "
            f"limits.no_load_p_max_mw = {limits.no_load_p_max_mw:g} MW (open the breaker first)")


#: signals that end a run through the safe state: Ctrl-C, a kill (SIGTERM), a closed terminal
#: (SIGHUP), Ctrl-\ (SIGQUIT, whose default would dump core and skip the safe state)
HANDLED_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


class Terminated(KeyboardInterrupt):
    """The run was ended by SIGTERM, SIGHUP or SIGQUIT (handled like Ctrl-C: through the safe
    state)."""

    def __init__(self, signal_name: str) -> None:
        super().__init__(signal_name)
        self.signal_name = signal_name


class CtrlC:
    """The Ctrl-C policy of a run (SIGTERM, SIGHUP and SIGQUIT alike): the first one while the
    procedure runs raises KeyboardInterrupt (`Terminated` for the others; the runner then restores the
    safe state). A Ctrl-C after that never
    interrupts a request in flight: it sets `abandon`, which stops the exciter's restore
    *retries* (after the first attempt): the heartbeat stops and the device watchdog reverts
    the setpoint, instead of the host holding the pulse while it retries."""

    def __init__(self) -> None:
        self.armed = True
        self.ignored = 0
        self.abandon = threading.Event()

    def _handler(self, signum: int, frame: object) -> None:
        if self.armed:
            self.armed = False
            exc = Terminated(signal.Signals(signum).name) if signum != signal.SIGINT else KeyboardInterrupt()
            if in_link_bookkeeping():   # a link lock's state half changed: raised once it is whole
                defer_interrupt(exc)
                return
            raise exc
        self.ignored += 1
        self.abandon.set()
        log.warning("Ctrl-C during the safe state: the host stops retrying the restore once the "
                    "current attempt ends; the heartbeat stops and the device watchdog reverts the setpoint")

    @contextlib.contextmanager
    def installed(self) -> Iterator[CtrlC]:
        """Install the policy for the block (main thread only; elsewhere a no-op)."""
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        previous = {sig: signal.signal(sig, self._handler) for sig in HANDLED_SIGNALS}
        try:
            yield self
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
