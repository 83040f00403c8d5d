"""No-load setpoint pulse test (the reference paper's field test).

PURPOSE
    Record the exciter's response (efd, vt) to a rectangular pulse on the AVR voltage setpoint
    (default +0.05 pu for 1 s) at rated speed and no load; the capture feeds identification.

PRECONDITIONS (checked before anything is written; the test is refused, never adjusted)
    - Unit at rated speed, field breaker closed, generator breaker OPEN: |p| below
      limits.no_load_p_max_mw.
    - Pre-test setpoint, terminal voltage and pulse setpoint inside
      limits.setpoint_min_pu .. setpoint_max_pu.
    - |amplitude_pu| <= limits.pulse_amplitude_max_pu, width_s <= limits.pulse_width_max_s.
    - The recorder is idle or holds a finished record (it will be overwritten only on arm).

SEQUENCE
    1. Read p, setpoint, mode, vt; check the limits; ask the operator (real devices only).
    2. Configure the recorder (rate_hz, pre_trigger_s, record_s, trigger on a usetp step of
       half the amplitude) and arm it; wait until its pre-trigger buffer is full.
    3. Start the exciter heartbeat, take remote.
    4. Write setpoint + amplitude; exactly width_s later (monotonic clock, from the moment the
       first request left) write the pre-test setpoint back. Each write is read back.
    5. Wait for the record to finish and vt to recover; give remote back, stop the heartbeat.
    6. Download the record, save the raw download, then convert and save the capture
       (capture.csv + capture.json: bench config, device identities, every write with its time).

HAZARDS
    A setpoint step moves the terminal voltage of a live machine: the amplitude cap and the
    band protect it. Whatever ends the test (error, lost link, Ctrl-C), the runner restores the
    pre-test setpoint and gives remote back; a host that dies leaves the device to its heartbeat
    watchdog, which reverts the setpoint on its own.

PASS CRITERIA
    - Recorded pulse width within width_tolerance_s of the commanded width.
    - Recorded pulse amplitude within amplitude_tolerance_pu of the commanded amplitude.
    - vt back within recovery_tolerance_pu of its pre-test value at the end of the record.
    - Setpoint read back equal to the pre-test setpoint (raw registers).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from bench_ctl.runner.bench import Bench
from bench_ctl.runner.context import Criterion, ProcedureResult, RunContext
from bench_ctl.runner.safety import PreconditionFailed, check_no_load, check_pulse
from bench_ctl.runner.devices import DeviceError, RecordSettings, hold_gc

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecordedPulse:
    """The pulse as the recorder saw it in usetp."""

    start_s: float
    width_s: float
    amplitude_pu: float
    baseline_pu: float


def measure_pulse(time_s: np.ndarray, usetp: np.ndarray, expected_pu: float,
                  pre_samples: int = 1) -> RecordedPulse:
    """The first run of samples where usetp departs from its baseline (median of the first
    `pre_samples`, the pre-trigger part) by more than half the expected amplitude: its start,
    width (samples x step) and mean level above the baseline."""
    time_s, usetp = np.asarray(time_s, float), np.asarray(usetp, float)
    baseline = float(np.median(usetp[:max(1, pre_samples)]))
    away = np.abs(usetp - baseline) > abs(expected_pu) / 2
    idx = np.flatnonzero(away)
    if idx.size == 0:
        raise ValueError(f"no pulse in usetp (no sample departs {abs(expected_pu) / 2:g} pu "
                         f"from the initial {baseline:g} pu)")
    i0 = int(idx[0])
    back = np.flatnonzero(~away[i0:])
    i1 = i0 + int(back[0]) if back.size else usetp.size
    dt = float(time_s[1] - time_s[0])
    return RecordedPulse(start_s=float(time_s[i0]), width_s=(i1 - i0) * dt,
                         amplitude_pu=float(np.mean(usetp[i0:i1]) - baseline),
                         baseline_pu=baseline)


def no_load_pulse(bench: Bench, run: RunContext, *, amplitude_pu: float = 0.05,
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
        run.note("readings", p_mw=p_mw, setpoint_pu=pre.setpoint_pu, mode=pre.mode, vt_pu=vt0,
                 recorder_status=state)
        check_no_load(run.limits, p_mw)
        plan = check_pulse(run.limits, setpoint_pu=pre.setpoint_pu, amplitude_pu=amplitude_pu,
                           width_s=width_s)
        if not run.limits.setpoint_min_pu <= vt0 <= run.limits.setpoint_max_pu:
            raise PreconditionFailed(f"terminal voltage vt = {vt0:.6g} pu outside the band "
                                     f"{run.limits.setpoint_min_pu:g}..{run.limits.setpoint_max_pu:g} pu")
        if state not in ("idle", "done"):
            raise PreconditionFailed(f"recorder status {state!r}: expected idle or done")
        if not pre_trigger_s + width_s < record_s:
            raise PreconditionFailed(f"record_s {record_s:g} s must exceed pre_trigger_s + "
                                     f"width_s = {pre_trigger_s + width_s:g} s")
        ex.encode("setpoint", plan.pulse_setpoint_pu)  # representable? (RangeError, nothing sent)
        settings = RecordSettings(rate_hz=rate_hz, pre_trigger_s=pre_trigger_s,
                                  length_s=record_s, trigger="usetp_step",
                                  threshold_pu=round(abs(amplitude_pu) / 2, 4))
        run.note("plan", setpoint_pu=plan.setpoint_pu, pulse_setpoint_pu=plan.pulse_setpoint_pu,
                 width_s=width_s, record=settings.__dict__)

    run.confirm(f"{run.procedure}: pulse the setpoint {plan.setpoint_pu:.4f} -> "
                f"{plan.pulse_setpoint_pu:.4f} pu for {width_s:g} s on {ex.link.endpoint.url} "
                f"(p = {p_mw:.3g} MW, vt = {vt0:.4f} pu)")

    with run.step("arm recorder"):
        rec.configure(settings)
        rec.arm()
        rec.wait_status(("armed",), pre_trigger_s + 5.0, check=bench.check)

    with run.step("take remote"):
        ex.take_remote()

    with run.step("pulse", amplitude_pu=amplitude_pu, width_s=width_s), hold_gc():
        on = ex.write_setpoint(plan.pulse_setpoint_pu, purpose="pulse on")
        run.hook("pulse_applied")
        off = ex.write_setpoint(plan.setpoint_pu, purpose="pulse off (restore pre-test setpoint)",
                                at_mono=on.t_tx_mono + width_s)
        commanded_width_s = off.t_tx_mono - on.t_tx_mono
        run.note("pulse_sent", commanded_width_s=commanded_width_s,
                 late_s=commanded_width_s - width_s)
        run.hook("pulse_restored")

    with run.step("recovery"):
        rec.wait_status(("done",), record_s + 5.0, check=_watching(run, bench, ex, vt0))
        deadline = time.monotonic() + recovery_timeout_s
        vt_end = ex.read("vt")
        while abs(vt_end - vt0) > recovery_tolerance_pu and time.monotonic() < deadline:
            bench.check()
            time.sleep(0.1)
            vt_end = ex.read("vt")
            run.status(f"vt {vt_end:.4f} pu (pre-test {vt0:.4f} pu){_efd_text(ex)}")
        sp_words = tuple(ex.read_words("setpoint"))
        run.note("recovered", vt_pu=vt_end, setpoint_words=list(sp_words))

    with run.step("release exciter"):
        hb = ex.heartbeat
        run.note("heartbeat", beats=hb.beats, failures=hb.failures, max_gap_s=hb.max_gap_s)
        report = ex.safe_state("pulse test complete")
        run.note("safe_state", **report.to_dict())
        if not report.ok:
            raise DeviceError(f"release failed: {report.detail}", device=ex.name)

    with run.step("download"):
        raw = rec.download(progress=_progress_bar(run))
        run.save_raw(raw)  # before any conversion
        data = raw.convert()

    with run.step("save capture"):
        pulse = measure_pulse(data["time"], data["usetp"], amplitude_pu, raw.trigger_sample)
        test: dict[str, Any] = {
            "kind": "pulse", "amplitude_pu": amplitude_pu, "width_s": width_s,
            "start_s": raw.trigger_sample / raw.rate_hz, "pre_trigger_s": pre_trigger_s,
            "setpoint_pu": plan.setpoint_pu, "commanded_width_s": commanded_width_s,
            "recorded": pulse.__dict__}
        raw_file = run.raw_path.name if run.raw_path else None
        meta = run.sidecar_meta(test=test, recorder={**raw.header(), "raw_file": raw_file},
                                channel_scaling=raw.scales)
        run.save_capture(data, meta)

    width_err = pulse.width_s - width_s
    amp_err = pulse.amplitude_pu - amplitude_pu
    criteria = (
        Criterion("pulse width error", abs(width_err) <= width_tolerance_s, width_err,
                  width_tolerance_s, "s"),
        Criterion("pulse amplitude error", abs(amp_err) <= amplitude_tolerance_pu, amp_err,
                  amplitude_tolerance_pu, "pu"),
        Criterion("vt recovered", abs(vt_end - vt0) <= recovery_tolerance_pu, vt_end - vt0,
                  recovery_tolerance_pu, "pu"),
        Criterion("setpoint restored (raw)", sp_words == pre.setpoint_words, list(sp_words),
                  list(pre.setpoint_words),
                  shown=(f"{ex.register('setpoint').decode(list(sp_words)):.4f} pu, pre-test "
                         f"{pre.setpoint_pu:.4f} pu (register words "
                         f"{'identical' if sp_words == pre.setpoint_words else 'DIFFER'})")),
    )
    run.note("criteria", criteria=[c.to_dict() for c in criteria])
    summary = (f"recorded width {pulse.width_s * 1e3:.1f} ms (commanded {width_s * 1e3:.1f} ms), "
               f"amplitude {pulse.amplitude_pu:.5f} pu (commanded {amplitude_pu:.5f} pu)")
    host_late_s = commanded_width_s - width_s
    if abs(host_late_s) > width_tolerance_s:  # the width error is the host's, not the device's
        summary += (f"; this host sent the restore write {host_late_s * 1e3:+.1f} ms off its deadline "
                    f"(the process or the machine stalled), so the pulse was that much off on the wire")
    return ProcedureResult(criteria=criteria, summary=summary,
                           data={"width_err_s": width_err, "amplitude_err_pu": amp_err,
                                 "recorded": pulse.__dict__, "download_s": raw.download_s,
                                 "commanded_width_s": commanded_width_s,
                                 "block_retries": raw.block_retries,
                                 "record_attempts": raw.record_attempts})


def _watching(run: RunContext, bench: Bench, ex: Any, vt0: float, every_s: float = 0.25) -> Any:
    """The bench's check while the record completes, plus (on a terminal) a live vt / efd
    readout every `every_s`: the operator sees the unit while the recorder finishes."""
    last = [0.0]

    def check() -> None:
        bench.check()
        now = time.monotonic()
        if run.shown and now - last[0] >= every_s:
            last[0] = now
            run.status(f"recording, vt {ex.read('vt'):.4f} pu (pre-test {vt0:.4f} pu){_efd_text(ex)}")
    return check


def _efd_text(ex: Any) -> str:
    """`, efd X pu` for the operator's live readout, when the exciter's profile maps efd."""
    return f", efd {ex.read('efd'):.3f} pu" if "efd" in ex.profile.registers else ""


def _progress_bar(run: RunContext) -> Any:
    if not run.progress:
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
