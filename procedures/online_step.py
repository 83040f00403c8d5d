"""On-line voltage-reference step (MOD-026 style): the unit synchronised, a step on the AVR setpoint
held for `hold_s`, then back; P, Q, Vt and efd recorded for identification on line.

PURPOSE
    Record the unit's response (efd, vt, p, q, ifd) to a step of the AVR voltage reference with the
    generator breaker closed (default +0.02 pu held 10 s, then back to the pre-test setpoint); the
    capture is an on-line record (it has p and q) and feeds identification on the grid.

PARAMETERS (each bounded, checked before anything is opened; see PARAMETERS below)
    amplitude_pu 0.005..0.05 pu in size, hold_s 1..60 s, pre_trigger_s 0.5..30 s, record_s
    2..120 s and longer than pre-trigger + hold, rate_hz 10..1000 Hz, hold_tolerance_s 1..100 ms,
    amplitude_tolerance_pu 0.00001..0.01 pu and <= 20 % of the amplitude, recovery_tolerance_pu
    0.0001..0.05 pu, vt_margin_pu 0..0.05 pu, q_margin 0..0.4 (of the Q band), poll_s 0.02..1 s.

PRECONDITIONS (checked before anything is written; the test is refused, never adjusted)
    - One run on this exciter (the runner's bench lock), remote free.
    - The exciter's heartbeat watchdog, READ FROM THE DEVICE, within limits.watchdog_max_s.
    - The unit ON LINE: |p| at or above limits.no_load_p_max_mw (the breaker closed).
    - The bench config has the unit's Q band (limits.q_min_mvar .. q_max_mvar); the exciter reads q
      and the recorder's profile records p and q.
    - Q inside its band by q_margin of its width; Vt inside limits.vt_min_pu .. vt_max_pu by
      vt_margin_pu, and still by vt_margin_pu were Vt to move by the whole amplitude.
    - No limiter acting: every status bit the profile names `*_limit` or `*_active` clear.
    - |amplitude_pu| <= limits.pulse_amplitude_max_pu, hold_s <= limits.step_hold_max_s, both
      setpoints inside limits.setpoint_min_pu .. setpoint_max_pu.
    - The recorder is idle or holds a finished record.

SEQUENCE
    1. Read p, q, vt, the setpoint, the status bits and the watchdog; check the limits; print the
       plan and ask the operator (real devices, unless --yes).
    2. Configure and arm the recorder (trigger on a usetp step of half the amplitude).
    3. Start the heartbeat, take remote.
    4. Write setpoint + amplitude. While it is held, read Vt and Q every poll_s: one outside its
       band, or a failed read, ends the step at once (the pre-test setpoint written back). Else
       exactly hold_s after the first write, write the pre-test setpoint back.
    5. Wait for the record to finish (Vt and Q still watched) and Vt to recover; give remote
       back, stop the heartbeat.
    6. Download the record, save the raw download, then the capture (p, q, ifd with efd, vt).

HAZARDS
    A reference step moves Vt and the unit's reactive power on a live grid: the amplitude cap, the
    Vt and Q bands with their margins, and the watch during the hold protect it. Whatever ends the
    test (error, lost link, Ctrl-C), the runner restores the pre-test setpoint and gives remote
    back; a host that dies leaves the device to its heartbeat watchdog, which reverts the setpoint
    (for a hold longer than the watchdog, the step then ends early: on the safe side).

PASS CRITERIA
    - Vt and Q stayed inside their bands throughout (an abort fails the test; its record is kept).
    - Recorded step amplitude within amplitude_tolerance_pu, hold within hold_tolerance_s.
    - vt back within recovery_tolerance_pu of its pre-test value at the end.
    - Setpoint read back equal to the pre-test setpoint (raw registers).
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from bench_ctl.runner.context import Criterion, ProcedureResult, RunContext
from bench_ctl.runner.devices import TIMED_WRITE_GUARD_S, DeviceError, RecordSettings, hold_gc
from bench_ctl.runner.protocols import ExcitationSystem, ProcedureBench
from bench_ctl.runner.safety import BenchBusy, LimitViolation, PreconditionFailed, check_pulse
from procedures.recorded import measure_pulse, signed

#: the run is meant to leave a capture: when it ends without one, the outcome says so
CAPTURES = True
#: the simulated bench of a dry run: the unit on the grid (its recorder profile records p and q)
SIMULATED_BENCH = {"online": True}

PARAMETERS: dict[str, tuple[float, float, str]] = {
    "amplitude_pu": (-0.05, 0.05, "pu"),
    "hold_s": (1.0, 60.0, "s"),
    "pre_trigger_s": (0.5, 30.0, "s"),
    "record_s": (2.0, 120.0, "s"),
    "rate_hz": (10, 1000, "Hz"),
    "hold_tolerance_s": (0.001, 0.1, "s"),
    "amplitude_tolerance_pu": (0.00001, 0.01, "pu"),
    "recovery_tolerance_pu": (0.0001, 0.05, "pu"),
    "recovery_timeout_s": (0.0, 600.0, "s"),
    "vt_margin_pu": (0.0, 0.05, "pu"),
    "q_margin": (0.0, 0.4, ""),
    "poll_s": (0.02, 1.0, "s"),
}
MIN_AMPLITUDE_PU = 0.005
#: status bits that mean a limiter is acting (by their profile names)
LIMITER_SUFFIXES = ("_limit", "_active")


def check_parameters(params: dict[str, Any]) -> list[str]:
    """Every problem with the test's parameters (empty when fine)."""
    problems = []
    for name, (lo, hi, unit) in PARAMETERS.items():
        value = params.get(name)
        if value is None:
            continue
        if name == "rate_hz" and (isinstance(value, bool) or value != int(value)):
            problems.append(f"rate_hz = {value!r} must be a whole number of Hz")
        elif not lo <= value <= hi:
            problems.append(f"{name} = {value:g} {unit} outside {lo:g}..{hi:g} {unit}".rstrip())
    if problems:
        return problems
    amp = params["amplitude_pu"]
    if abs(amp) < MIN_AMPLITUDE_PU:
        problems.append(f"|amplitude_pu| = {abs(amp):g} pu below {MIN_AMPLITUDE_PU:g} pu")
    if not params["pre_trigger_s"] + params["hold_s"] < params["record_s"]:
        problems.append(f"record_s = {params['record_s']:g} s must exceed pre_trigger_s + hold_s = "
                        f"{params['pre_trigger_s'] + params['hold_s']:g} s")
    if params["amplitude_tolerance_pu"] > 0.2 * abs(amp):
        problems.append(f"amplitude_tolerance_pu = {params['amplitude_tolerance_pu']:g} pu above 20 % of "
                        f"|amplitude_pu| = {abs(amp):g} pu")
    return problems


class Band:
    """The Vt and Q band of the test (limits.vt_*, q_*): what ends the step when left."""

    def __init__(self, vt: tuple[float, float], q: tuple[float, float]) -> None:
        self.vt, self.q = vt, q
        self.worst: str | None = None    # the first excursion seen

    def outside(self, vt: float, q: float) -> str | None:
        """What is outside (None when both are in), and remember the first."""
        why = None
        if not (math.isfinite(vt) and self.vt[0] <= vt <= self.vt[1]):
            why = f"vt {vt:.4f} pu outside {self.vt[0]:.4f}..{self.vt[1]:.4f} pu"
        elif not (math.isfinite(q) and self.q[0] <= q <= self.q[1]):
            why = f"q {q:.2f} Mvar outside {self.q[0]:.2f}..{self.q[1]:.2f} Mvar"
        if why is not None and self.worst is None:
            self.worst = why
        return why


def online_step(bench: ProcedureBench, run: RunContext, *, amplitude_pu: float = 0.02, hold_s: float = 10.0,
                pre_trigger_s: float = 2.0, record_s: float = 20.0, rate_hz: int = 200,
                hold_tolerance_s: float = 0.02, amplitude_tolerance_pu: float = 0.001,
                recovery_tolerance_pu: float = 0.01, recovery_timeout_s: float = 30.0,
                vt_margin_pu: float = 0.005, q_margin: float = 0.1, poll_s: float = 0.05) -> ProcedureResult:
    """The on-line step; see the module docstring (the test sheet)."""
    ex, rec = bench.exciter, bench.recorder
    lim = run.limits

    with run.step("preconditions"):
        p_mw = ex.read("p")
        q0 = ex.read("q") if ex.has("q") else math.nan
        pre = ex.snapshot()
        vt0 = ex.read("vt")
        state = rec.status()
        holder = ex.remote_holder()
        limiters = _limiters_acting(ex)
        run.note("readings", p_mw=p_mw, q_mvar=q0, setpoint_pu=pre.setpoint_pu, mode=pre.mode, vt_pu=vt0,
                 recorder_status=state, remote_holder=holder, limiters_acting=limiters)
        if holder is not None:
            raise BenchBusy(f"refused before any write: {holder}")
        watchdog_s = run.check_watchdog()
        if lim.q_min_mvar is None or lim.q_max_mvar is None:
            raise LimitViolation("refused before any write: the bench config has no Q band (limits.q_min_mvar, "
                                 "q_max_mvar: the unit's capability at this P): an on-line step needs it")
        if not ex.has("q"):
            raise PreconditionFailed("refused before any write: the exciter's profile reads no q: an on-line step "
                                     "watches the reactive power")
        missing = [c for c in ("p", "q") if c not in rec.channels]
        if missing:
            raise PreconditionFailed(f"refused before any write: the recorder's profile records "
                                     f"{', '.join(rec.channels)}, not {', '.join(missing)}: an on-line record "
                                     "needs p and q")
        if not (math.isfinite(p_mw) and abs(p_mw) >= lim.no_load_p_max_mw):
            raise PreconditionFailed(f"on-line precondition failed: active power p = {p_mw:.6g} MW below "
                                     f"limits.no_load_p_max_mw = {lim.no_load_p_max_mw:g} MW: the unit is not "
                                     "synchronised (the no-load test is no_load_pulse)")
        if limiters:
            raise PreconditionFailed(f"refused before any write: limiter(s) acting: {', '.join(limiters)}")
        plan = check_pulse(lim, setpoint_pu=pre.setpoint_pu, amplitude_pu=amplitude_pu, width_s=hold_s,
                           width_cap="step_hold_max_s")
        band = Band(lim.vt_band_pu, (lim.q_min_mvar, lim.q_max_mvar))
        _check_margins(band, vt0, q0, amplitude_pu, vt_margin_pu, q_margin)
        if state not in ("idle", "done"):
            raise PreconditionFailed(f"recorder status {state!r}: expected idle or done")
        ex.encode("setpoint", plan.pulse_setpoint_pu)  # representable? (RangeError, nothing sent)
        settings = RecordSettings(rate_hz=rate_hz, pre_trigger_s=pre_trigger_s, length_s=record_s,
                                  trigger="usetp_step", threshold_pu=round(abs(amplitude_pu) / 2, 4))
        run.note("plan", setpoint_pu=plan.setpoint_pu, step_setpoint_pu=plan.pulse_setpoint_pu, hold_s=hold_s,
                 watchdog_s=watchdog_s, vt_band_pu=list(band.vt), q_band_mvar=list(band.q),
                 record=settings.__dict__)

    run.confirm("\n".join((
        f"{run.procedure} on the exciter {ex.endpoint_url} (unit {ex.unit_id}), the unit ON LINE:",
        f"  setpoint  {plan.setpoint_pu:.4f} pu -> {plan.pulse_setpoint_pu:.4f} pu held {hold_s:.3f} s, "
        f"then back to {plan.setpoint_pu:.4f} pu",
        f"  unit now  p {p_mw:.2f} MW, q {q0:.2f} Mvar, vt {vt0:.4f} pu",
        f"  band      vt {band.vt[0]:.4f}..{band.vt[1]:.4f} pu, q {band.q[0]:.2f}..{band.q[1]:.2f} Mvar: "
        f"leaving it ends the step at once",
        f"  limits    |amplitude| <= {lim.pulse_amplitude_max_pu:.4f} pu, hold <= {lim.step_hold_max_s:.3f} s",
        f"  watchdog  {run.watchdog_text()}",
        f"  recorder  {rate_hz:g} Hz, pre-trigger {pre_trigger_s:.3f} s, record {record_s:.3f} s, "
        f"channels {', '.join(rec.channels)}")))

    with run.step("arm recorder"):
        rec.configure(settings)
        rec.arm()
        rec.wait_status(("armed",), pre_trigger_s + 5.0, check=bench.check)

    with run.step("take remote"):
        ex.take_remote()

    with run.step("step", amplitude_pu=amplitude_pu, hold_s=hold_s):
        on = ex.write_setpoint(plan.pulse_setpoint_pu, purpose="step on")
        run.hook("step_applied")
        deadline = on.t_tx_mono + hold_s
        why = _watch(run, bench, ex, band, until=deadline - TIMED_WRITE_GUARD_S - ex.request_timeout_s - 0.05,
                     poll_s=poll_s)
        with hold_gc():
            if why is None:
                off = ex.write_setpoint(plan.setpoint_pu, purpose="step off (restore pre-test setpoint)",
                                        at_mono=deadline)
            else:
                run.status(f"ABORT: {why}; restoring the pre-test setpoint")
                off = ex.write_setpoint(plan.setpoint_pu, purpose=f"abort ({why}): restore pre-test setpoint")
        held_s = off.t_tx_mono - on.t_tx_mono
        run.note("step_sent", held_s=held_s, aborted=why)
        run.hook("step_restored")

    with run.step("recovery"):
        rec.wait_status(("done",), record_s + 5.0, check=_watching(run, bench, ex, band, poll_s))
        end = time.monotonic() + recovery_timeout_s
        vt_end = ex.read("vt")
        while abs(vt_end - vt0) > recovery_tolerance_pu and time.monotonic() < end:
            bench.check()
            time.sleep(0.1)
            vt_end = ex.read("vt")
        sp_words = tuple(ex.read_words("setpoint"))
        run.note("recovered", vt_pu=vt_end, setpoint_words=list(sp_words), band_left=band.worst)

    with run.step("release exciter"):
        run.release(ex, "on-line step complete")

    with run.step("download"):
        raw, data = run.download(rec)   # saved as received before any conversion

    with run.step("save capture"):
        step = measure_pulse(data["time"], data["usetp"], amplitude_pu, raw.trigger_sample)
        test: dict[str, Any] = {
            "kind": "pulse", "online": True, "amplitude_pu": amplitude_pu, "width_s": hold_s,
            "start_s": raw.trigger_sample / raw.rate_hz, "pre_trigger_s": pre_trigger_s,
            "setpoint_pu": plan.setpoint_pu, "commanded_width_s": held_s, "recorded": step.__dict__,
            "operating_point": {"p_mw": p_mw, "q_mvar": q0, "vt_pu": vt0},
            "band": {"vt_pu": list(band.vt), "q_mvar": list(band.q), "left": band.worst}}
        run.save_record(raw, data, test)

    hold_err = step.width_s - hold_s
    amp_err = step.amplitude_pu - amplitude_pu
    criteria = (
        Criterion("vt and q inside the band", band.worst is None, band.worst or "inside", "inside", "",
                  shown=band.worst or (f"vt {band.vt[0]:.4f}..{band.vt[1]:.4f} pu, "
                                       f"q {band.q[0]:.2f}..{band.q[1]:.2f} Mvar throughout")),
        Criterion("step amplitude error", abs(amp_err) <= amplitude_tolerance_pu, amp_err,
                  amplitude_tolerance_pu, "pu",
                  shown=f"{signed(amp_err, 4)} pu (limit ±{amplitude_tolerance_pu:.4f} pu)"),
        Criterion("step hold error", abs(hold_err) <= hold_tolerance_s, hold_err, hold_tolerance_s, "s",
                  shown=f"{signed(hold_err * 1e3, 1)} ms (limit ±{hold_tolerance_s * 1e3:.1f} ms)"),
        Criterion("vt recovered", abs(vt_end - vt0) <= recovery_tolerance_pu, vt_end - vt0,
                  recovery_tolerance_pu, "pu",
                  shown=f"{vt_end:.4f} pu, {signed(vt_end - vt0, 4)} pu from pre-test "
                        f"(limit ±{recovery_tolerance_pu:.4f} pu)"),
        Criterion("setpoint restored (raw)", sp_words == pre.setpoint_words, list(sp_words),
                  list(pre.setpoint_words),
                  shown=(f"{ex.decode('setpoint', sp_words):.4f} pu, pre-test {pre.setpoint_pu:.4f} pu "
                         f"(register words {'identical' if sp_words == pre.setpoint_words else 'DIFFER'})")),
    )
    run.note("criteria", criteria=[c.to_dict() for c in criteria])
    summary = (f"recorded step {step.amplitude_pu:.4f} pu held {step.width_s:.3f} s from p {p_mw:.1f} MW, "
               f"q {q0:.1f} Mvar" + (f"; ABORTED: {why}" if why else ""))
    return ProcedureResult(criteria=criteria, summary=summary,
                           data={"hold_err_s": hold_err, "amplitude_err_pu": amp_err, "aborted": why,
                                 "recorded": step.__dict__, "download_s": raw.download_s})


def _limiters_acting(ex: ExcitationSystem) -> list[str]:
    """The status bits named *_limit or *_active that read 1 (the profile's names)."""
    return [name for name, on in ex.bits("status").items() if on and name.endswith(LIMITER_SUFFIXES)]


def _check_margins(band: Band, vt0: float, q0: float, amplitude_pu: float, vt_margin_pu: float,
                   q_margin: float) -> None:
    """Refuse a start near a Vt or Q limit (PreconditionFailed naming the value and the limit)."""
    lo, hi = band.vt
    qlo, qhi = band.q
    q_room = q_margin * (qhi - qlo)
    problems = []
    if not (math.isfinite(vt0) and lo + vt_margin_pu <= vt0 <= hi - vt_margin_pu):
        problems.append(f"vt {vt0:.4f} pu not inside {lo:.4f}..{hi:.4f} pu by vt_margin_pu {vt_margin_pu:g} pu")
    elif not lo + vt_margin_pu <= vt0 + amplitude_pu <= hi - vt_margin_pu:
        problems.append(f"vt {vt0:.4f} pu moved by the whole step {amplitude_pu:+g} pu would leave "
                        f"{lo:.4f}..{hi:.4f} pu less vt_margin_pu {vt_margin_pu:g} pu")
    if not (math.isfinite(q0) and qlo + q_room <= q0 <= qhi - q_room):
        problems.append(f"q {q0:.2f} Mvar not inside {qlo:.2f}..{qhi:.2f} Mvar by q_margin {q_margin:g} of the "
                        f"band ({q_room:.2f} Mvar)")
    if problems:
        raise PreconditionFailed("refused before any write: near a limit: " + "; ".join(problems))


def _read_band(ex: ExcitationSystem) -> tuple[float, float]:
    return ex.read("vt", attempts=1), ex.read("q", attempts=1)


def _watch(run: RunContext, bench: ProcedureBench, ex: ExcitationSystem, band: Band, *, until: float,
           poll_s: float) -> str | None:
    """Read Vt and Q every poll_s until `until`: what left the band (or the failed read) ends it."""
    while (now := time.monotonic()) < until:
        bench.check()
        try:
            vt, q = _read_band(ex)
        except DeviceError as exc:
            band.worst = band.worst or f"vt / q not read ({exc.summary})"
            return band.worst
        why = band.outside(vt, q)
        if why is not None:
            return why
        run.status(f"vt {vt:.4f} pu, q {q:.2f} Mvar, {max(0.0, until - now):.1f} s held")
        time.sleep(max(0.0, min(poll_s, until - time.monotonic())))
    return None


def _watching(run: RunContext, bench: ProcedureBench, ex: ExcitationSystem, band: Band,
              poll_s: float) -> Callable[[], None]:
    """The bench's check while the record completes, with Vt and Q held against the band (the
    setpoint is already back; an excursion is noted and fails the test)."""
    last = [0.0]

    def check() -> None:
        bench.check()
        now = time.monotonic()
        if now - last[0] >= poll_s:
            last[0] = now
            vt, q = _read_band(ex)
            band.outside(vt, q)
            run.status(f"recording, vt {vt:.4f} pu, q {q:.2f} Mvar")
    return check
