"""The stepping plant reproduces the batch engine offline, applies setpoints from the next step,
and keeps real time with catch-up."""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from bench_ctl.engine.simulate import pulse_usetp, simulate
from bench_ctl.plants import FLAG_CEILING, O_EFD, O_EFD_REC, O_USETP, O_VT, Plant
from bench_ctl.plants import realtime as RT
from bench_ctl.units.unit import load_unit

EFFECTS = {
    "none": {},
    "ceiling_limit": {"ceiling_limit": {"VRMAX": 2.8, "VRMIN": -0.5}},
    "dead_time": {"dead_time": {"TD": 0.0155}},          # not a whole number of steps: split steps
    "transducer_lag": {"transducer_lag": {"TR": 0.02}},
    "saturation": {"saturation": {"S10": 0.1, "S12": 0.3}},
    "rate_limit": {"rate_limit": {"RATE": 50.0}},
    "setpoint_ramp": {"setpoint_ramp": {"RAMP": 0.5}},
    "recorder_gain": {"recorder_gain": {"GAIN": 1.1}},
    "time_skew": {"time_skew": {"SKEW": 0.0123}},
}


@pytest.mark.parametrize("name", list(EFFECTS))
def test_offline_stepping_reproduces_simulate(name):
    unit = load_unit(None).with_effects(EFFECTS[name])
    _, u = pulse_usetp(amplitude=0.05, width=1.0, start=1.0, duration=6.0)
    efd, vt, fail = simulate(unit.values(), u, 1e-3, usetp_pre=1.0)
    assert fail == -1
    plant = Plant(unit, rt_priority=None)
    # uneven chunks: the carried state must make chunking invisible
    parts = [plant.advance(c) for c in np.split(u, [1, 700, 1003, 2500, 2501])]
    out = np.vstack(parts)
    assert np.max(np.abs(out[:, O_EFD_REC] - efd)) < 1e-6
    assert np.max(np.abs(out[:, O_VT] - vt)) < 1e-6
    assert np.array_equal(out[:, O_USETP], u)
    if name == "ceiling_limit":
        assert out[:, O_EFD].max() == pytest.approx(2.8)
        assert np.any(out[:, 6].astype(int) & FLAG_CEILING)
    if name == "none":   # the reference response of docs/model.md
        assert 3.0 < efd.max() < 3.2 and -1.1 < efd.min() < -0.9


def test_setpoint_acts_from_the_next_step_offline():
    plant = Plant(rt_priority=None)
    plant.run_offline(5)
    assert plant.write_setpoint(1.05) == 5
    out = plant.run_offline(3)
    assert list(out[:, O_USETP]) == [1.05, 1.05, 1.05]
    # state at step 5 was computed with the old setpoint: the response starts one step later
    assert out[0, O_EFD] == pytest.approx(1.0, abs=1e-12)
    assert out[1, O_EFD] > 1.0 + 1e-6


def test_realtime_write_acts_from_the_next_step_after_its_wall_time():
    plant = Plant()
    got = {}

    def listen(k0, out):
        for i in range(out.shape[0]):
            if 495 <= k0 + i <= 505:
                got[k0 + i] = out[i, O_USETP]

    plant.add_listener(listen)
    t0 = plant.start()
    try:
        at = t0 + 0.2004            # wall time between steps 200 and 201 (still in the future)
        assert time.monotonic() < at
        assert plant.write_setpoint(1.02, at=at) == 201
        plant.write_setpoint(1.0, at=t0 + 0.3)        # exactly on a step boundary: from step 300
        plant.write_setpoint(1.03, at=t0 + 0.5001)    # -> from step 501
        while plant.step < 510:
            time.sleep(0.01)
    finally:
        plant.stop()
    assert [got[k] for k in range(495, 506)] == [1.0] * 6 + [1.03] * 5


def test_realtime_keeps_wall_time():
    plant = Plant()
    seen = []
    plant.add_listener(lambda k0, out: seen.append((k0, out.shape[0])))
    t0 = plant.start()
    try:
        time.sleep(0.5)
        end = time.monotonic()
        behind_at_end = (end - t0) - plant.step * plant.dt
    finally:
        plant.stop()
    timing = plant.timing()
    # the listeners got every step exactly once, in order
    assert seen[0][0] == 0
    assert all(a + n == b for (a, n), (b, _) in zip(seen, seen[1:]))
    assert sum(n for _, n in seen) == plant.step
    # plant time trails wall time by about one step (+ scheduling slack: tens of ms on a loaded
    # machine without real-time priority), never leads it
    assert -1e-4 <= behind_at_end < 0.001 + 0.03
    assert timing.steps == plant.step and timing.late_setpoints == 0


def test_loop_catches_up_a_stall_in_one_burst():
    """Started 50 ms 'late', the compiled loop computes the missing steps at once, then keeps
    time (what happens after the thread was not scheduled for 50 ms)."""
    plant = Plant(rt_priority=None)
    plant.warm()
    start_ns = time.monotonic_ns() - 50_000_000
    plant._t0_ns = start_ns
    clock = (plant._ctrl, plant._sp_step, plant._sp_val, plant._fst, plant._ring, plant._lag, plant._behind)
    th = threading.Thread(target=plant._loop(), args=plant._rt_args(plant._work, clock))
    th.start()
    time.sleep(0.1)
    plant._ctrl[RT.C_STOP] = 1
    th.join()
    stop_ns = time.monotonic_ns()
    assert plant._ctrl[RT.C_MAXBURST] >= 50
    assert plant._behind[0] >= 0.050                       # reported how late it was
    assert 0 <= (stop_ns - start_ns) * 1e-9 - plant.step * plant.dt < 0.03


def test_timer_probe_never_wakes_before_its_deadline():
    """The machine baseline of benchmarks/sim_latency.py: absolute deadlines, lateness >= 0."""
    got = RT.timer_jitter(0.05, rt_priority=None)
    assert got["wakeups"] == 50 and got["rt_priority"] is False
    assert 0.0 <= got["late_median_ms"] <= got["late_p99_ms"] <= got["late_max_ms"]
    assert got["late_over_5ms"] <= got["late_over_1ms"] <= 50
