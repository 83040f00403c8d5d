"""The on-line plant (the unit on the grid as the simulated bench's plant, issue 27 item 4): stepping
it reproduces `engine.run` on the grid sample for sample, the turbine moves P, and real time keeps
a written setpoint on the step after it was written."""
from __future__ import annotations

import time

import numpy as np
import pytest

from bench_ctl.engine import run
from bench_ctl.engine.machines.grid import machine_matrix, unit_machine
from bench_ctl.engine.simulate import param_matrix
from bench_ctl.plants import O_EFD_REC as A_EFD_REC
from bench_ctl.plants import O_IFD as A_IFD
from bench_ctl.plants import O_P as A_P
from bench_ctl.plants import O_Q as A_Q
from bench_ctl.plants import O_VT as A_VT
from bench_ctl.plants import OnlinePlant
from bench_ctl.units.overrides import apply_overrides
from bench_ctl.units.unit import load_unit


def _unit():
    return load_unit(None)


def test_online_plant_reproduces_the_engine_sample_for_sample():
    unit = _unit()
    plant = OnlinePlant(unit, rt_priority=None)
    u = np.full(3000, plant.usetp_pre)
    u[500:2000] += 0.02
    # in two calls: the state carried across the boundary is the run's
    out = np.vstack([plant.advance(u[:1234]), plant.advance(u[1234:])])
    ref = run(param_matrix(unit.values()), u, plant.dt, plant.usetp_pre, machine=machine_matrix(unit_machine(unit)))
    for col, name in ((A_EFD_REC, "efd"), (A_VT, "vt"), (A_P, "p"), (A_Q, "q"), (A_IFD, "ifd")):
        np.testing.assert_allclose(out[:, col], ref[name][0], rtol=0, atol=1e-12, err_msg=name)
    # the step did something: a test that cannot fail proves nothing
    assert np.ptp(out[:, A_Q]) > 0.05 and np.ptp(out[:, A_VT]) > 0.005
    st = plant.state()
    assert st.step == 3000 and abs(st.p - unit.grid["P0"]) < 0.01


def test_online_plant_starts_at_the_operating_point_and_the_turbine_moves_p():
    unit = _unit()
    plant = OnlinePlant(unit, rt_priority=None)
    st = plant.state()
    assert st.vt == pytest.approx(unit.values()["Vt0"], abs=1e-9)
    assert st.p == pytest.approx(unit.grid["P0"], abs=1e-9) and st.q == pytest.approx(unit.grid["Q0"], abs=1e-9)
    plant.advance(plant.usetp_pre, 500)
    assert plant.state().p == pytest.approx(unit.grid["P0"], abs=1e-9)   # steady
    plant.set_mech_power(0.5)
    out = plant.advance(plant.usetp_pre, 20000)
    assert out[-1, A_P] == pytest.approx(0.5, abs=2e-3)
    with pytest.raises(ValueError, match="mechanical power"):
        plant.set_mech_power(3.0)


def test_online_plant_refuses_a_unit_it_cannot_run():
    unit = apply_overrides(_unit(), ["XDPP=0.35"])   # X"d above X'd
    with pytest.raises(ValueError, match="reactances are out of order"):
        OnlinePlant(unit, rt_priority=None)


def test_online_plant_in_real_time_acts_on_a_setpoint_from_the_next_step():
    plant = OnlinePlant(_unit(), rt_priority=None)
    seen = []
    plant.add_listener(lambda k0, rows: seen.append((k0, rows[:, 0].copy())))
    plant.start()
    try:
        deadline = time.monotonic() + 10
        while plant.step < 200 and time.monotonic() < deadline:
            time.sleep(0.01)
        k = plant.write_setpoint(plant.usetp_pre + 0.02)
        while plant.step < k + 300 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        plant.stop()
    steps = np.concatenate([k0 + np.arange(r.size) for k0, r in seen])
    usetp = np.concatenate([r for _, r in seen])
    assert np.array_equal(steps, np.arange(steps.size))          # every step, in order, once
    first = int(np.flatnonzero(usetp > plant.usetp_pre + 0.01)[0])
    assert first == k
    assert plant.state().q > _unit().grid["Q0"] + 0.02            # the step raised Q
    t = plant.timing()
    assert t.steps >= k + 300 and t.late_setpoints == 0
