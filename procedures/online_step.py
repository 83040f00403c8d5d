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
    0.0001..0.05 pu, vt_margin_pu 0..0.05 pu, q_margin 0..0.4 (of the Q band), poll_s 0.02..1 s,
    steady_timeout_s 0..600 s (how long to wait for the steady state before refusing).

PRECONDITIONS (checked before anything is written; the test is refused, never adjusted)
    - One run on this exciter (the runner's bench lock), remote free.
    - The exciter's heartbeat watchdog, READ FROM THE DEVICE, within limits.watchdog_max_s.
    - The unit ON LINE: |p| at or above limits.no_load_p_max_mw (the breaker closed), and P inside
      the unit's on-line range limits.p_min_mw .. p_max_mw (reverse power, a unit below its minimum
      load: refused). Without that range in the bench config there is no on-line test.
    - The bench config has the unit's Q band (limits.q_min_mvar .. q_max_mvar); the exciter reads q
      and the recorder's profile records p and q.
    - Q inside its band by q_margin of its width; Vt inside limits.vt_min_pu .. vt_max_pu by
      vt_margin_pu, and still by vt_margin_pu were Vt to move by the whole amplitude.
    - No limiter acting: every status bit the profile names `*_limit` or `*_active` clear.
    - |amplitude_pu| <= limits.pulse_amplitude_max_pu, hold_s <= limits.step_hold_max_s, both
      setpoints inside limits.setpoint_min_pu .. setpoint_max_pu.
    - The exciter link fast enough for the cap, MEASURED before the first write: hold_s plus twice the
      slowest reply (but one) within limits.step_hold_max_s (docs/decisions/0023).
    - The recorder is idle or holds a finished record.
    - The unit STEADY: P, Q and Vt each within its band (limits.steady_p_band_mw, steady_q_band_mvar,
      steady_vt_band_pu, as max - min) over limits.steady_time_s, waited for up to steady_timeout_s;
      checked again right before the step (a unit that started to swing meanwhile: no step).

SEQUENCE
    1. Read p, q, vt, the setpoint, the status bits and the watchdog; wait for the steady state;
       measure the link; check the limits; print the plan and ask the operator (real devices,
       unless --yes).
    2. Configure and arm the recorder (trigger on a usetp step of half the amplitude).
    3. Start the heartbeat, take remote; the steady state once more (no step otherwise).
    4. Write setpoint + amplitude. While it is held, read Vt, Q, P and the status every poll_s (one
       request where the map keeps them together): Vt or Q outside its band, P outside the unit's
       range or moved more than limits.p_swing_max_mw from its start value (a trip, a load
       rejection, reverse power), a limiter acting, or a failed read, ends the step at once (the
       pre-test setpoint written back). Else exactly hold_s after the first write, write the
       pre-test setpoint back. No read of the watch can end after the restore write asks for the
       link: it never delays the restore.
    5. Wait for the record to finish and Vt to recover (the same watch, its excursions noted; its
       reads retried, one lost for good carried to the end: the record is still kept, the run then
       ends with exit 3); give remote back, stop the heartbeat.
    6. Download the record, save the raw download, then the capture (p, q, ifd with efd, vt).

HAZARDS
    A reference step moves Vt and the unit's reactive power on a live grid: the amplitude cap, the
    Vt and Q bands with their margins, the P range and the watch during the hold protect it.
    Whatever ends the test (error, lost link, Ctrl-C), the runner restores the pre-test setpoint
    and gives remote back; a host that dies leaves the device to its heartbeat watchdog, which
    reverts the setpoint (for a hold longer than the watchdog, the step then ends early: on the
    safe side).

PASS CRITERIA
    - The unit inside its bands throughout: Vt, Q, P (range and swing), no limiter acting (an abort
      fails the test, naming what ended it; its record is kept).
    - Recorded step amplitude within amplitude_tolerance_pu, hold within hold_tolerance_s and
      within the cap limits.step_hold_max_s (as recorded: what the plant saw).
    - vt back within recovery_tolerance_pu of its pre-test value at the end.
    - Setpoint read back equal to the pre-test setpoint (raw registers).
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from bench_ctl.runner.context import Criterion, ProcedureResult, RunContext
from bench_ctl.runner.devices import DeviceError, RecordSettings, hold_gc
from bench_ctl.runner.protocols import ExcitationSystem, ProcedureBench
from bench_ctl.runner.safety import BenchBusy, LimitViolation, PreconditionFailed, check_pulse
from procedures.online_band import Band, Steady
from procedures.recorded import (
    RECOVERY_READ_ATTEMPTS,
    Carried,
    link_free_at,
    measure_pulse,
    signed,
    timed_write_cause,
)

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
    "steady_timeout_s": (0.0, 600.0, "s"),
}
MIN_AMPLITUDE_PU = 0.005
#: status bits that mean a limiter is acting (by their profile names)
LIMITER_SUFFIXES = ("_limit", "_active")
#: what the watch reads each poll (one request where the map keeps them together)
WATCHED = ("vt", "q", "p", "status")


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


def online_step(bench: ProcedureBench, run: RunContext, *, amplitude_pu: float = 0.02, hold_s: float = 10.0,
                pre_trigger_s: float = 2.0, record_s: float = 20.0, rate_hz: int = 200,
                hold_tolerance_s: float = 0.02, amplitude_tolerance_pu: float = 0.001,
                recovery_tolerance_pu: float = 0.01, recovery_timeout_s: float = 30.0,
                vt_margin_pu: float = 0.005, q_margin: float = 0.1, poll_s: float = 0.05,
                steady_timeout_s: float = 30.0) -> ProcedureResult:
    """The on-line step; see the module docstring (the test sheet)."""
    given = locals()
    params = {name: given[name] for name in PARAMETERS}
    return step_on_line(bench, run, params)


@dataclass(frozen=True)
class StepPart:
    """One record of a test of several (procedures/pss_step.py): its name (the files' suffix,
    `RunContext.part`), what to do once remote is taken and before the steady state is awaited
    (e.g. switch the PSS; the safe state of the release undoes it), what to add to the capture's
    test, a line for the plan, whether this part asks the operator (the first does), what to
    call with the record's data and test once its capture is saved, and what to undo at once when
    the step is ended early (`on_abort(why)`, e.g. the PSS back as found: the unit is not left
    without its stabiliser for the rest of the record; the release's safe state checks it again)."""

    name: str
    after_remote: Callable[[], None]
    test: dict[str, Any]
    plan: str
    confirm: bool
    saved: Callable[[dict[str, Any], dict[str, Any]], None]
    on_abort: Callable[[str], None] | None = None


def step_on_line(bench: ProcedureBench, run: RunContext, params: dict[str, Any],
                 part: StepPart | None = None) -> ProcedureResult:
    """The on-line step with `params` (PARAMETERS' names, all given), the whole test or one `part`
    of a longer one (its record saved under the part's name before the next part starts)."""
    (amplitude_pu, hold_s, pre_trigger_s, record_s, rate_hz, hold_tolerance_s, amplitude_tolerance_pu,
     recovery_tolerance_pu, recovery_timeout_s, vt_margin_pu, q_margin, poll_s,
     steady_timeout_s) = (params[name] for name in PARAMETERS)
    ex, rec = bench.exciter, bench.recorder
    lim = run.limits
    run.part = part.name if part is not None else ""

    with run.step("preconditions"):
        p_mw = ex.read("p")
        q0 = ex.read("q") if ex.has("q") else math.nan
        pre = ex.snapshot()
        vt0 = ex.read("vt")
        state = rec.status()
        holder = ex.remote_holder()
        limiters = _limiters_acting(ex.bits("status"))
        run.note("readings", p_mw=p_mw, q_mvar=q0, setpoint_pu=pre.setpoint_pu, mode=pre.mode, vt_pu=vt0,
                 recorder_status=state, remote_holder=holder, limiters_acting=limiters)
        if holder is not None:
            raise BenchBusy(f"refused before any write: {holder}")
        watchdog_s = run.check_watchdog()
        if lim.q_min_mvar is None or lim.q_max_mvar is None:
            raise LimitViolation("refused before any write: the bench config has no Q band (limits.q_min_mvar, "
                                 "q_max_mvar: the unit's capability at this P): an on-line step needs it")
        if lim.p_min_mw is None or lim.p_max_mw is None:
            raise LimitViolation("refused before any write: the bench config has no P range (limits.p_min_mw, "
                                 "p_max_mw: the unit's on-line range, its minimum load to its rating): an on-line "
                                 "step needs it to see a trip, a load rejection or reverse power")
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
        if not lim.p_min_mw <= p_mw <= lim.p_max_mw:
            kind = ("reverse power: the unit is motoring" if p_mw < 0 else
                    "below the unit's minimum load" if p_mw < lim.p_min_mw else "above the unit's rating")
            raise PreconditionFailed(f"refused before any write: p = {p_mw:.2f} MW outside the unit's on-line "
                                     f"range limits.p_min_mw..p_max_mw = {lim.p_min_mw:g}..{lim.p_max_mw:g} MW "
                                     f"({kind})")
        if limiters:
            raise PreconditionFailed(f"refused before any write: limiter(s) acting: {', '.join(limiters)}")
        plan = check_pulse(lim, setpoint_pu=pre.setpoint_pu, amplitude_pu=amplitude_pu, width_s=hold_s,
                           width_cap="step_hold_max_s")
        band = Band(lim.vt_band_pu, (lim.q_min_mvar, lim.q_max_mvar), (lim.p_min_mw, lim.p_max_mw),
                    lim.p_swing_mw, p_mw)
        _check_margins(band, vt0, q0, amplitude_pu, vt_margin_pu, q_margin)
        if state not in ("idle", "done"):
            raise PreconditionFailed(f"recorder status {state!r}: expected idle or done")
        ex.encode("setpoint", plan.pulse_setpoint_pu)  # representable? (RangeError, nothing sent)
        bands = lim.steady_bands()
        assert bands is not None   # the P range and the Q band are there
        steady = Steady(bands, lim.steady_time_s, max_gap_s=max(0.5, 4 * poll_s) + ex.request_timeout_s)
        _wait_steady(run, bench, ex, steady, steady_timeout_s, poll_s, before="any write")
        link = run.check_link(ex, width_s=hold_s, cap_name="step_hold_max_s", what="step")
        settings = RecordSettings(rate_hz=rate_hz, pre_trigger_s=pre_trigger_s, length_s=record_s,
                                  trigger="usetp_step", threshold_pu=round(abs(amplitude_pu) / 2, 4))
        run.note("plan", setpoint_pu=plan.setpoint_pu, step_setpoint_pu=plan.pulse_setpoint_pu, hold_s=hold_s,
                 watchdog_s=watchdog_s, link_max_s=link.max_s, vt_band_pu=list(band.vt), q_band_mvar=list(band.q),
                 p_range_mw=list(band.p), p_swing_mw=band.p_swing_mw, steady_bands=bands,
                 steady_time_s=lim.steady_time_s, record=settings.__dict__)

    plan_text = "\n".join((
        f"{run.procedure} on the exciter {ex.endpoint_url} (unit {ex.unit_id}), the unit ON LINE:",
        f"  setpoint  {plan.setpoint_pu:.4f} pu -> {plan.pulse_setpoint_pu:.4f} pu held {hold_s:.3f} s, "
        f"then back to {plan.setpoint_pu:.4f} pu",
        f"  unit now  p {p_mw:.2f} MW, q {q0:.2f} Mvar, vt {vt0:.4f} pu, steady over {lim.steady_time_s:g} s "
        f"(p {bands['p']:g} MW, q {bands['q']:g} Mvar, vt {bands['vt']:g} pu)",
        f"  band      {band.text()}: leaving it ends the step at once",
        f"  limits    |amplitude| <= {lim.pulse_amplitude_max_pu:.4f} pu, hold <= {lim.step_hold_max_s:.3f} s",
        f"  watchdog  {run.watchdog_text()}",
        f"  link      {run.link_text()}",
        f"  recorder  {rate_hz:g} Hz, pre-trigger {pre_trigger_s:.3f} s, record {record_s:.3f} s, "
        f"channels {', '.join(rec.channels)}",
        *((part.plan,) if part is not None else ())))
    if part is None or part.confirm:
        run.confirm(plan_text)
    else:
        run.note("plan_confirmed", part=part.name, summary=plan_text)

    sample = _sampler(run, bench, ex, steady, poll_s)
    with run.step("arm recorder"):
        rec.configure(settings)
        rec.arm()
        rec.wait_status(("armed",), pre_trigger_s + 5.0, check=sample)

    with run.step("take remote"):
        ex.take_remote()
        if part is not None:
            part.after_remote()
        _wait_steady(run, bench, ex, steady, steady_timeout_s, poll_s, before="the step")

    with run.step("step", amplitude_pu=amplitude_pu, hold_s=hold_s):
        on = ex.write_setpoint(plan.pulse_setpoint_pu, purpose="step on")
        run.hook("step_applied")
        deadline = on.t_tx_mono + hold_s
        why = _watch(run, bench, ex, band, t_on=on.t_tx_mono, hold_s=hold_s, poll_s=poll_s)
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

    carried = Carried(run)   # trouble after the step: noted, the record still kept
    if why is not None and part is not None and part.on_abort is not None:
        try:
            part.on_abort(why)
        except DeviceError as exc:   # the release's safe state tries again
            carried.note("undoing the part's change after the abort", exc)
    with run.step("recovery"):
        rec.wait_status(("done",), record_s + 5.0, check=_watching(run, bench, ex, band, poll_s, carried))
        end = time.monotonic() + recovery_timeout_s
        vt_end = _read_vt(ex, carried)
        while not abs(vt_end - vt0) <= recovery_tolerance_pu and time.monotonic() < end:
            carried.check(bench.check)
            time.sleep(0.1)
            vt_end = _read_vt(ex, carried)
        try:
            sp_words = tuple(ex.read_words("setpoint", attempts=RECOVERY_READ_ATTEMPTS))
        except DeviceError as exc:
            carried.note("reading the setpoint back", exc)
            sp_words = ()
        run.note("recovered", vt_pu=vt_end, setpoint_words=list(sp_words), band_left=band.worst)

    with run.step("release exciter"):
        try:
            run.release(ex, "on-line step complete")
        except DeviceError as exc:   # the runner's safe state tries again after the download
            carried.note("giving the exciter back", exc)

    with run.step("download"):
        raw, data = run.download(rec)   # saved as received before any conversion

    with run.step("save capture"):
        step = measure_pulse(data["time"], data["usetp"], amplitude_pu, raw.trigger_sample)
        test: dict[str, Any] = {
            "kind": "pulse", "online": True, "amplitude_pu": amplitude_pu, "width_s": hold_s,
            "start_s": raw.trigger_sample / raw.rate_hz, "pre_trigger_s": pre_trigger_s,
            "setpoint_pu": plan.setpoint_pu, "commanded_width_s": held_s, "recorded": step.__dict__,
            "operating_point": {"p_mw": p_mw, "q_mvar": q0, "vt_pu": vt0},
            "band": {"vt_pu": list(band.vt), "q_mvar": list(band.q), "p_mw": list(band.p),
                     "p_swing_mw": band.p_swing_mw, "left": band.worst},
            **(part.test if part is not None else {})}
        run.save_record(raw, data, test)
        if part is not None:
            part.saved(data, test)

    hold_err = step.width_s - hold_s
    amp_err = step.amplitude_pu - amplitude_pu
    cap_s = lim.step_hold_max_s
    criteria = (
        Criterion("unit inside its bands", band.worst is None, band.worst or "inside", "inside", "",
                  shown=band.worst or f"{band.text()} throughout"),
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
                         f"(register words {'identical' if sp_words == pre.setpoint_words else 'DIFFER'})")
                  if sp_words else "not read back (the read failed after the step)"),
        Criterion("step within the cap (as recorded)", step.width_s <= cap_s, step.width_s, cap_s, "s",
                  shown=f"{step.width_s:.3f} s on the device (cap limits.step_hold_max_s {cap_s:.3f} s)"),
    )
    run.note("criteria", criteria=[c.to_dict() for c in criteria])
    summary = (f"recorded step {step.amplitude_pu:.4f} pu held {step.width_s:.3f} s from p {p_mw:.1f} MW, "
               f"q {q0:.1f} Mvar" + (f"; ABORTED: {why}" if why else "")
               + (f"; after the step: {band.worst}" if band.worst and not why else ""))
    late_s = held_s - hold_s
    if why is None and abs(late_s) > hold_tolerance_s:   # the restore left late: the link's or this host's doing
        summary += (f"; the restore write left {signed(late_s * 1e3, 1)} ms off its deadline (the cause: "
                    f"{timed_write_cause(off)}), so the step was that much off on the wire")
    return ProcedureResult(criteria=criteria, summary=summary, comms_error=carried.first,
                           data={"hold_err_s": hold_err, "amplitude_err_pu": amp_err, "aborted": why,
                                 "recorded": step.__dict__, "download_s": raw.download_s})


def _limiters_acting(bits: dict[str, bool]) -> list[str]:
    """The status bits named *_limit or *_active that read 1 (the profile's names)."""
    return [name for name, on in bits.items() if on and name.endswith(LIMITER_SUFFIXES)]


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


def _read_watched(ex: ExcitationSystem, attempts: int | None,
                  start_by: float | None = None) -> tuple[dict[str, float], list[str]] | None:
    """Vt, Q, P and the status in one request where the map allows, and the limiters acting; None
    when a request could not start before `start_by`."""
    seen = ex.read_many(WATCHED, attempts=attempts, start_by=start_by)
    if len(seen) < len(WATCHED):
        return None
    return seen, _limiters_acting(ex.bits_of("status", seen["status"]))


def _sampler(run: RunContext, bench: ProcedureBench, ex: ExcitationSystem, steady: Steady,
             poll_s: float) -> Callable[[], None]:
    """The bench's check while the recorder arms, sampling the steady state every poll_s."""
    last = [0.0]

    def check() -> None:
        bench.check()
        now = time.monotonic()
        if now - last[0] >= poll_s:
            last[0] = now
            got = _read_watched(ex, attempts=None)
            assert got is not None
            steady.add(now, got[0])
    return check


def _wait_steady(run: RunContext, bench: ProcedureBench, ex: ExcitationSystem, steady: Steady,
                 timeout_s: float, poll_s: float, *, before: str) -> None:
    """Sample until P, Q and Vt have been steady over limits.steady_time_s (and no limiter acts);
    PreconditionFailed when that takes longer than steady_time_s + `timeout_s`."""
    give_up = time.monotonic() + steady.time_s + timeout_s
    while True:
        bench.check()
        now = time.monotonic()
        got = _read_watched(ex, attempts=None)
        assert got is not None
        seen, limiters = got
        steady.add(now, seen)
        verdict = steady.verdict()
        if limiters:
            verdict = f"limiter(s) acting: {', '.join(limiters)}"
        if verdict is None:
            run.note("steady", before=before, moved=steady.moved(), bands=steady.bands, time_s=steady.time_s)
            return
        if now >= give_up:
            run.note("steady", before=before, moved=steady.moved(), bands=steady.bands, time_s=steady.time_s,
                     refused=verdict)
            waited = steady.time_s + timeout_s
            raise PreconditionFailed(f"refused before {before}: the unit is not steady: {verdict} "
                                     f"(limits.steady_time_s {steady.time_s:g} s, waited {waited:g} s in all); "
                                     "wait for it to settle")
        run.status(f"waiting for a steady state: {verdict}")
        time.sleep(max(0.0, poll_s - (time.monotonic() - now)))


def _watch(run: RunContext, bench: ProcedureBench, ex: ExcitationSystem, band: Band, *, t_on: float,
           hold_s: float, poll_s: float) -> str | None:
    """Read Vt, Q, P and the status every poll_s while the step is held: what left the band (or
    a failed read, a failing heartbeat) ends it. A request starts before the timed restore asks for
    the link or not at all (`link_free_at`), so the watch never delays the restore."""
    free_at = link_free_at(t_on + hold_s, ex.request_timeout_s)
    while time.monotonic() < free_at:
        try:
            bench.check()
        except DeviceError as exc:
            band.worst = band.worst or f"heartbeat failing ({exc.summary})"
            return band.worst
        try:
            got = _read_watched(ex, attempts=1, start_by=free_at)
        except DeviceError as exc:
            band.worst = band.worst or f"vt / q / p not read ({exc.summary})"
            return band.worst
        if got is None:
            return None
        seen, limiters = got
        why = band.outside(seen, limiters)
        if why is not None:
            return why
        now = time.monotonic()
        run.status(f"vt {seen['vt']:.4f} pu, q {seen['q']:.2f} Mvar, p {seen['p']:.1f} MW, "
                   f"{now - t_on:.1f} s of {hold_s:.1f} s held")
        time.sleep(max(0.0, min(poll_s, free_at - time.monotonic())))
    return None


def _read_vt(ex: ExcitationSystem, carried: Carried) -> float:
    """vt after the step, read again on a lost reply; NaN (carried) when it fails for good."""
    return carried.read("reading vt after the step", lambda: ex.read("vt", attempts=RECOVERY_READ_ATTEMPTS))


def _watching(run: RunContext, bench: ProcedureBench, ex: ExcitationSystem, band: Band, poll_s: float,
              carried: Carried) -> Callable[[], None]:
    """The bench's check while the record completes, with Vt, Q, P and the limiters held against the
    band (the setpoint is already back; an excursion is noted and fails the test). Its reads are
    retried; one lost for good, or a failing heartbeat, is carried (the record is still kept)."""
    last = [0.0]

    def check() -> None:
        carried.check(bench.check)
        now = time.monotonic()
        if now - last[0] >= poll_s:
            last[0] = now
            try:
                got = _read_watched(ex, attempts=RECOVERY_READ_ATTEMPTS)
            except DeviceError as exc:
                carried.note("reading vt, q, p after the step", exc)
                return
            assert got is not None
            seen, limiters = got
            band.outside(seen, limiters)
            run.status(f"recording, vt {seen['vt']:.4f} pu, q {seen['q']:.2f} Mvar, p {seen['p']:.1f} MW")
    return check
