"""No-load setpoint pulse test (the reference paper's field test).

PURPOSE
    Record the exciter's response (efd, vt) to a rectangular pulse on the AVR voltage setpoint
    (default +0.05 pu for 1 s) at rated speed and no load; the capture feeds identification.

PARAMETERS (each bounded, checked before anything is opened; see PARAMETERS below)
    amplitude_pu 0.005..0.2 pu in size, width_s 0.1..10 s and >= 20 recorder samples,
    pre_trigger_s 0.05..30 s, record_s 0.5..60 s and longer than pre-trigger + width,
    rate_hz 10..1000 Hz, width_tolerance_s 0.5..100 ms and <= 10 % of the width,
    amplitude_tolerance_pu 0.00001..0.01 pu and <= 20 % of the amplitude,
    recovery_tolerance_pu 0.0001..0.05 pu, recovery_timeout_s 0..600 s.

PRECONDITIONS (checked before anything is written; the test is refused, never adjusted)
    - One run on this exciter (the runner's bench lock), and remote free: not held by another
      master (status.remote_other_master where the profile has it, or the mode already remote).
    - The exciter's heartbeat watchdog, READ FROM THE DEVICE, within limits.watchdog_max_s and
      long enough for this host's heartbeat (if this host dies, only it ends the pulse).
    - Unit at rated speed, field breaker closed, generator breaker OPEN: |p| below
      limits.no_load_p_max_mw.
    - Pre-test setpoint, terminal voltage and pulse setpoint inside
      limits.setpoint_min_pu .. setpoint_max_pu.
    - |amplitude_pu| <= limits.pulse_amplitude_max_pu, width_s <= limits.pulse_width_max_s.
    - The exciter link fast enough for the cap, MEASURED before the first write: width_s plus twice
      the slowest reply (but one) within limits.pulse_width_max_s, that reply within half the
      request timeout, the heartbeat's worst gap within the device's watchdog (decision 0023).
    - The recorder is idle or holds a finished record (it will be overwritten only on arm).

SEQUENCE
    1. Read p, setpoint, mode, vt, the watchdog; measure the link; check the limits; print the
       plan (setpoint from -> to, width, limits, watchdog found, link measured) and ask the
       operator (real devices, unless --yes).
    2. Configure the recorder (rate_hz, pre_trigger_s, record_s, trigger on a usetp step of
       half the amplitude) and arm it; wait until its pre-trigger buffer is full.
    3. Start the exciter heartbeat, take remote.
    4. Write setpoint + amplitude; exactly width_s later (monotonic clock, from the moment the
       first request left) write the pre-test setpoint back. Each write is read back. On a
       terminal the operator sees setpoint, vt, efd and the time left meanwhile: each of its
       requests starts before the restore write asks for the link, or not at all, so it never
       delays the restore.
    5. Wait for the record to finish and vt to recover; give remote back, stop the heartbeat.
       Reads here are retried; one that fails for good (or a failing heartbeat, a release not
       confirmed) is carried to the end: the record is still downloaded and saved, then the run
       ends with exit 3 naming it.
    6. Download the record, save the raw download, then convert and save the capture
       (capture.csv + capture.json: bench config, device identities, every write with its time).

HAZARDS
    A setpoint step moves the terminal voltage of a live machine: the amplitude cap and the
    band protect it. Whatever ends the test (error, lost link, Ctrl-C), the runner restores the
    pre-test setpoint and gives remote back; a host that dies leaves the device to its heartbeat
    watchdog, which reverts the setpoint on its own.

PASS CRITERIA
    - Recorded pulse width within width_tolerance_s of the commanded width, and within the cap
      limits.pulse_width_max_s (the recorder records the device's setpoint: what the plant saw).
    - Recorded pulse amplitude within amplitude_tolerance_pu of the commanded amplitude.
    - vt back within recovery_tolerance_pu of its pre-test value at the end of the record.
    - Setpoint read back equal to the pre-test setpoint (raw registers).
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

from bench_ctl.runner.context import Criterion, ProcedureResult, RunContext
from bench_ctl.runner.devices import DeviceError, RecordSettings, hold_gc
from bench_ctl.runner.protocols import ExcitationSystem, ProcedureBench
from bench_ctl.runner.safety import BenchBusy, PreconditionFailed, check_no_load, check_pulse
from procedures.recorded import (
    RECOVERY_READ_ATTEMPTS,
    Carried,
    link_free_at,
    measure_pulse,
    signed,
    timed_write_cause,
)

log = logging.getLogger(__name__)

#: the run is meant to leave a capture: when it ends without one, the outcome says so
CAPTURES = True

#: parameter -> (min, max, unit): every parameter is bounded (the bench limits bound the pulse
#: further); `check_parameters` adds the bounds between parameters
PARAMETERS: dict[str, tuple[float, float, str]] = {
    "amplitude_pu": (-0.2, 0.2, "pu"),
    "width_s": (0.1, 10.0, "s"),
    "pre_trigger_s": (0.05, 30.0, "s"),
    "record_s": (0.5, 60.0, "s"),
    "rate_hz": (10, 1000, "Hz"),
    "width_tolerance_s": (0.0005, 0.1, "s"),
    "amplitude_tolerance_pu": (0.00001, 0.01, "pu"),
    "recovery_tolerance_pu": (0.0001, 0.05, "pu"),
    "recovery_timeout_s": (0.0, 600.0, "s"),
}
MIN_AMPLITUDE_PU = 0.005      # smaller steps drown in the recorder's noise
MIN_PULSE_SAMPLES = 20        # the recorder must see the pulse
MIN_PRE_TRIGGER_SAMPLES = 10  # the baseline before the pulse


def check_parameters(params: dict[str, Any]) -> list[str]:
    """Every problem with the test's parameters (empty when fine); the runner refuses the run
    before anything is opened when there is one."""
    problems = []
    for name, (lo, hi, unit) in PARAMETERS.items():
        value = params.get(name)
        if value is None:
            continue
        if name == "rate_hz" and (isinstance(value, bool) or value != int(value)):
            problems.append(f"rate_hz = {value!r} must be a whole number of Hz")
        elif not lo <= value <= hi:
            problems.append(f"{name} = {value:g} {unit} outside {lo:g}..{hi:g} {unit}")
    if problems:
        return problems
    amp, width, rate = params["amplitude_pu"], params["width_s"], params["rate_hz"]
    if abs(amp) < MIN_AMPLITUDE_PU:
        problems.append(f"|amplitude_pu| = {abs(amp):g} pu below {MIN_AMPLITUDE_PU:g} pu")
    if width * rate < MIN_PULSE_SAMPLES:
        problems.append(f"width_s = {width:g} s is {width * rate:g} samples at rate_hz = {rate:g} Hz; "
                        f"the recorder needs at least {MIN_PULSE_SAMPLES}")
    if params["pre_trigger_s"] * rate < MIN_PRE_TRIGGER_SAMPLES:
        problems.append(f"pre_trigger_s = {params['pre_trigger_s']:g} s is under "
                        f"{MIN_PRE_TRIGGER_SAMPLES} samples at {rate:g} Hz")
    if not params["pre_trigger_s"] + width < params["record_s"]:
        problems.append(f"record_s = {params['record_s']:g} s must exceed pre_trigger_s + width_s = "
                        f"{params['pre_trigger_s'] + width:g} s")
    if params["width_tolerance_s"] > 0.1 * width:
        problems.append(f"width_tolerance_s = {params['width_tolerance_s']:g} s above 10 % of "
                        f"width_s = {width:g} s")
    if params["amplitude_tolerance_pu"] > 0.2 * abs(amp):
        problems.append(f"amplitude_tolerance_pu = {params['amplitude_tolerance_pu']:g} pu above "
                        f"20 % of |amplitude_pu| = {abs(amp):g} pu")
    return problems


def no_load_pulse(bench: ProcedureBench, run: RunContext, *, amplitude_pu: float = 0.05,
                  width_s: float = 1.0, pre_trigger_s: float = 1.0, record_s: float = 10.0,
                  rate_hz: int = 1000, width_tolerance_s: float = 0.005,
                  amplitude_tolerance_pu: float = 0.001, recovery_tolerance_pu: float = 0.01,
                  recovery_timeout_s: float = 30.0) -> ProcedureResult:
    """The pulse test; see the module docstring (the test sheet)."""
    ex, rec = bench.exciter, bench.recorder

    with run.step("preconditions"):
        p_mw = ex.read("p")
        pre = ex.snapshot()
        vt0 = ex.read("vt")
        state = rec.status()
        holder = ex.remote_holder()
        run.note("readings", p_mw=p_mw, setpoint_pu=pre.setpoint_pu, mode=pre.mode, vt_pu=vt0,
                 recorder_status=state, remote_holder=holder)
        if holder is not None:
            raise BenchBusy(f"refused before any write: {holder}")
        watchdog_s = run.check_watchdog()
        check_no_load(run.limits, p_mw)
        plan = check_pulse(run.limits, setpoint_pu=pre.setpoint_pu, amplitude_pu=amplitude_pu,
                           width_s=width_s)
        if not run.limits.setpoint_min_pu <= vt0 <= run.limits.setpoint_max_pu:
            raise PreconditionFailed(f"terminal voltage vt = {vt0:.4f} pu outside the band "
                                     f"{run.limits.setpoint_min_pu:.4f}..{run.limits.setpoint_max_pu:.4f} pu")
        if state not in ("idle", "done"):
            raise PreconditionFailed(f"recorder status {state!r}: expected idle or done")
        ex.encode("setpoint", plan.pulse_setpoint_pu)  # representable? (RangeError, nothing sent)
        link = run.check_link(ex, width_s=width_s, cap_name="pulse_width_max_s")
        settings = RecordSettings(rate_hz=rate_hz, pre_trigger_s=pre_trigger_s,
                                  length_s=record_s, trigger="usetp_step",
                                  threshold_pu=round(abs(amplitude_pu) / 2, 4))
        run.note("plan", setpoint_pu=plan.setpoint_pu, pulse_setpoint_pu=plan.pulse_setpoint_pu,
                 width_s=width_s, watchdog_s=watchdog_s, link_max_s=link.max_s, record=settings.__dict__)

    lim = run.limits
    run.confirm("\n".join((
        f"{run.procedure} on the exciter {ex.endpoint_url} (unit {ex.unit_id}):",
        f"  setpoint  {plan.setpoint_pu:.4f} pu -> {plan.pulse_setpoint_pu:.4f} pu for {width_s:.3f} s, "
        f"then back to {plan.setpoint_pu:.4f} pu",
        f"  unit now  p {p_mw:.2f} MW, vt {vt0:.4f} pu",
        f"  limits    |amplitude| <= {lim.pulse_amplitude_max_pu:.4f} pu, width <= "
        f"{lim.pulse_width_max_s:.3f} s, setpoints {lim.setpoint_min_pu:.4f}..{lim.setpoint_max_pu:.4f} pu, "
        f"|p| < {lim.no_load_p_max_mw:.2f} MW",
        f"  watchdog  {run.watchdog_text()}",
        f"            if this host dies during the pulse, the device ends it {watchdog_s:.3f} s after "
        "the last heartbeat",
        f"  link      {run.link_text()}",
        f"  recorder  {rate_hz:g} Hz, pre-trigger {pre_trigger_s:.3f} s, record {record_s:.3f} s, "
        f"trigger on a {settings.threshold_pu:.4f} pu usetp step")))

    with run.step("arm recorder"):
        rec.configure(settings)
        rec.arm()
        rec.wait_status(("armed",), pre_trigger_s + 5.0, check=bench.check)

    with run.step("take remote"):
        ex.take_remote()

    with run.step("pulse", amplitude_pu=amplitude_pu, width_s=width_s), hold_gc():
        on = ex.write_setpoint(plan.pulse_setpoint_pu, purpose="pulse on")
        run.hook("pulse_applied")
        _pulse_readout(run, ex, deadline=on.t_tx_mono + width_s)
        off = ex.write_setpoint(plan.setpoint_pu, purpose="pulse off (restore pre-test setpoint)",
                                at_mono=on.t_tx_mono + width_s)
        commanded_width_s = off.t_tx_mono - on.t_tx_mono
        run.note("pulse_sent", commanded_width_s=commanded_width_s,
                 late_s=commanded_width_s - width_s)
        run.hook("pulse_restored")

    carried = Carried(run)   # trouble after the pulse: noted, the record still kept
    with run.step("recovery"):
        rec.wait_status(("done",), record_s + 5.0, check=_watching(run, bench, ex, vt0, carried))
        deadline = time.monotonic() + recovery_timeout_s
        vt_end = _read_vt(ex, carried)
        while not abs(vt_end - vt0) <= recovery_tolerance_pu and time.monotonic() < deadline:
            carried.check(bench.check)
            time.sleep(0.1)
            vt_end = _read_vt(ex, carried)
            run.status(f"vt {vt_end:.4f} pu (pre-test {vt0:.4f} pu)")
        try:
            sp_words = tuple(ex.read_words("setpoint", attempts=RECOVERY_READ_ATTEMPTS))
        except DeviceError as exc:
            carried.note("reading the setpoint back", exc)
            sp_words = ()
        run.note("recovered", vt_pu=vt_end, setpoint_words=list(sp_words))

    with run.step("release exciter"):
        try:
            run.release(ex, "pulse test complete")
        except DeviceError as exc:   # the runner's safe state tries again after the download
            carried.note("giving the exciter back", exc)

    with run.step("download"):
        raw, data = run.download(rec)   # saved as received before any conversion

    with run.step("save capture"):
        pulse = measure_pulse(data["time"], data["usetp"], amplitude_pu, raw.trigger_sample)
        test: dict[str, Any] = {
            "kind": "pulse", "amplitude_pu": amplitude_pu, "width_s": width_s,
            "start_s": raw.trigger_sample / raw.rate_hz, "pre_trigger_s": pre_trigger_s,
            "setpoint_pu": plan.setpoint_pu, "commanded_width_s": commanded_width_s,
            "recorded": pulse.__dict__}
        run.save_record(raw, data, test)

    width_err = pulse.width_s - width_s
    amp_err = pulse.amplitude_pu - amplitude_pu
    cap_s = lim.pulse_width_max_s
    criteria = (
        Criterion("pulse width error", abs(width_err) <= width_tolerance_s, width_err,
                  width_tolerance_s, "s",
                  shown=f"{signed(width_err * 1e3, 1)} ms (limit ±{width_tolerance_s * 1e3:.1f} ms)"),
        Criterion("pulse amplitude error", abs(amp_err) <= amplitude_tolerance_pu, amp_err,
                  amplitude_tolerance_pu, "pu",
                  shown=f"{signed(amp_err, 4)} pu (limit ±{amplitude_tolerance_pu:.4f} pu)"),
        Criterion("vt recovered", abs(vt_end - vt0) <= recovery_tolerance_pu, vt_end - vt0,
                  recovery_tolerance_pu, "pu",
                  shown=f"{vt_end:.4f} pu, {signed(vt_end - vt0, 4)} pu from pre-test "
                        f"(limit ±{recovery_tolerance_pu:.4f} pu)"),
        Criterion("setpoint restored (raw)", sp_words == pre.setpoint_words, list(sp_words),
                  list(pre.setpoint_words),
                  shown=(f"{ex.decode('setpoint', sp_words):.4f} pu, pre-test "
                         f"{pre.setpoint_pu:.4f} pu (register words "
                         f"{'identical' if sp_words == pre.setpoint_words else 'DIFFER'})") if sp_words
                  else "not read back (the read failed after the pulse)"),
        Criterion("pulse within the cap (as recorded)", pulse.width_s <= cap_s, pulse.width_s, cap_s, "s",
                  shown=f"{pulse.width_s:.3f} s on the device (cap limits.pulse_width_max_s {cap_s:.3f} s)"),
    )
    run.note("criteria", criteria=[c.to_dict() for c in criteria])
    summary = (f"recorded width {pulse.width_s * 1e3:.1f} ms (commanded {width_s * 1e3:.1f} ms), "
               f"amplitude {pulse.amplitude_pu:.4f} pu (commanded {amplitude_pu:.4f} pu)")
    host_late_s = commanded_width_s - width_s
    if abs(host_late_s) > width_tolerance_s:  # the restore left late: the link's or this host's doing
        summary += (f"; the restore write left {signed(host_late_s * 1e3, 1)} ms off its deadline "
                    f"(the cause: {timed_write_cause(off)}), so the pulse was "
                    "that much off on the wire")
    return ProcedureResult(criteria=criteria, summary=summary, comms_error=carried.first,
                           data={"width_err_s": width_err, "amplitude_err_pu": amp_err,
                                 "recorded": pulse.__dict__, "download_s": raw.download_s,
                                 "commanded_width_s": commanded_width_s,
                                 "block_retries": raw.block_retries,
                                 "record_attempts": raw.record_attempts})


def _pulse_readout(run: RunContext, ex: ExcitationSystem, *, deadline: float, every_s: float = 0.1) -> None:
    """On a terminal, setpoint / vt / efd and the time left while the pulse is on. Every request
    is tried once and starts before the timed restore write asks for the link (`link_free_at`) or
    not at all, so the readout never delays the restore; a failed read ends the readout, not the
    pulse (the restore write reports the link's trouble itself)."""
    if not run.shown:
        return
    free_at = link_free_at(deadline, ex.request_timeout_s)
    names = ("setpoint", "vt", "efd") if ex.has("efd") else ("setpoint", "vt")
    while (now := time.monotonic()) < free_at:
        try:
            seen = ex.read_many(names, attempts=1, start_by=free_at)
        except DeviceError:
            return
        if len(seen) < len(names):
            return
        text = (f"setpoint {seen['setpoint']:.4f} pu, vt {seen['vt']:.4f} pu"
                + (f", efd {seen['efd']:.3f} pu" if "efd" in seen else ""))
        run.status(f"{text}, {max(0.0, deadline - now):.2f} s left")
        time.sleep(max(0.0, min(every_s, free_at - time.monotonic())))


def _read_vt(ex: ExcitationSystem, carried: Carried) -> float:
    """vt after the pulse, read again on a lost reply; NaN (carried) when it fails for good."""
    return carried.read("reading vt after the pulse", lambda: ex.read("vt", attempts=RECOVERY_READ_ATTEMPTS))


def _watching(run: RunContext, bench: ProcedureBench, ex: ExcitationSystem, vt0: float, carried: Carried,
              every_s: float = 0.25) -> Callable[[], None]:
    """The bench's check while the record completes (a failing heartbeat is carried, not raised:
    the setpoint is back and the record must be kept), plus (on a terminal) a live vt / efd
    readout every `every_s`: the operator sees the unit while the recorder finishes. A readout
    that cannot be read is skipped."""
    last = [0.0]
    names = ("vt", "efd") if ex.has("efd") else ("vt",)

    def check() -> None:
        carried.check(bench.check)
        now = time.monotonic()
        if run.shown and now - last[0] >= every_s:
            last[0] = now
            try:
                seen = ex.read_many(names, attempts=1)
            except DeviceError:
                return
            run.status(f"recording, vt {seen['vt']:.4f} pu (pre-test {vt0:.4f} pu)"
                       + (f", efd {seen['efd']:.3f} pu" if "efd" in seen else ""))
    return check
