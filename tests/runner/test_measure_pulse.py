"""The pulse test's measurement of the recorded pulse (`procedures.recorded.measure_pulse`)
on the shared edge finder: the same start, width and amplitude the procedure's own threshold
finder gave (kept here as the reference), so the pass criteria keep their meaning."""
from __future__ import annotations

import numpy as np
import pytest

from procedures.recorded import RecordedPulse, measure_pulse


def threshold_pulse(time_s, usetp, expected_pu, pre_samples=1) -> RecordedPulse:
    """The finder the procedure had before (first run of samples more than half the expected
    amplitude from the pre-trigger median)."""
    baseline = float(np.median(usetp[:max(1, pre_samples)]))
    away = np.abs(usetp - baseline) > abs(expected_pu) / 2
    idx = np.flatnonzero(away)
    i0 = int(idx[0])
    back = np.flatnonzero(~away[i0:])
    i1 = i0 + int(back[0]) if back.size else usetp.size
    dt = float(time_s[1] - time_s[0])
    return RecordedPulse(float(time_s[i0]), (i1 - i0) * dt, float(np.mean(usetp[i0:i1]) - baseline), baseline)


def record(rate_hz=1000, n=3000, start=1000, width=1000, amplitude=0.05, base=1.0, lsb=1e-4):
    t = np.arange(n) / rate_hz
    u = np.full(n, base)
    u[start:start + width] += amplitude
    return t, np.round(u / lsb) * lsb        # the recorder's usetp: exact counts of 1e-4 pu


@pytest.mark.parametrize("case", [
    dict(),                                              # the paper's +5 % for 1 s at 1 kHz
    dict(amplitude=-0.05),                               # a negative pulse
    dict(rate_hz=200, n=800, start=200, width=60),       # 0.3 s at 200 Hz
    dict(width=2000),                                    # never back within the record: a step
    dict(amplitude=0.0123, base=0.987),
])
def test_the_edge_finder_measures_what_the_threshold_finder_measured(case):
    t, u = record(**case)
    amp, pre = case.get("amplitude", 0.05), case.get("start", 1000)
    got, ref = measure_pulse(t, u, amp, pre), threshold_pulse(t, u, amp, pre)
    assert got.start_s == ref.start_s and got.width_s == pytest.approx(ref.width_s, abs=1e-12)
    assert got.amplitude_pu == pytest.approx(ref.amplitude_pu, abs=1e-12)
    assert got.baseline_pu == ref.baseline_pu


def test_a_pulse_the_wrong_way_is_measured_as_one_and_fails_on_its_amplitude():
    t, u = record(amplitude=-0.05)
    got = measure_pulse(t, u, 0.05, 1000)
    assert got.width_s == pytest.approx(1.0) and got.amplitude_pu == pytest.approx(-0.05)


def test_a_small_setpoint_move_before_the_pulse_is_not_the_pulse():
    t, u = record()
    u[300:] += 0.002                        # someone nudged the setpoint 0.7 s before the trigger
    got = measure_pulse(t, u, 0.05, 1000)
    assert got.start_s == pytest.approx(1.0) and got.width_s == pytest.approx(1.0)


def test_no_pulse_is_refused():
    t, u = record(amplitude=0.01)
    with pytest.raises(ValueError, match="no pulse in usetp"):
        measure_pulse(t, u, 0.05, 1000)
