"""The identification problem: the paper's objective, MSE, failure penalty, windows, constraints.

Expected values are recomputed here from the kernel's stored traces with numpy (trapezoid rule,
mean of squares), not taken from the code under test.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from bench_ctl.capture import Capture
from bench_ctl.engine.simulate import simulate
from bench_ctl.identification.construction import ProblemError, make_problem
from bench_ctl.identification.synthetic import synthetic_capture
from bench_ctl.units.overrides import apply_overrides


@pytest.fixture(scope="module")
def cap(unit):
    return synthetic_capture(unit, duration=3.0, rate=500.0, seed=11)


def _trapz(e2: np.ndarray, dt: float) -> float:
    return float(dt * (e2.sum() - 0.5 * (e2[0] + e2[-1])))


def test_objective_is_trapezoid_of_squared_efd_error(unit, cap):
    p = make_problem([cap], unit, fit_edges=False)
    x = p.x_start() * np.array([1.1, 0.9, 1.0, 1.2, 0.8, 1.0])
    efd, vt, fail = simulate(p.values(x), cap.usetp, cap.dt)
    assert fail < 0
    e2 = (efd - cap.efd) ** 2
    assert p.objective(x[None])[0] == pytest.approx(_trapz(e2, cap.dt), rel=1e-9)
    assert p.mse(x)[0] == pytest.approx(float(np.mean(e2)), rel=1e-9)
    R, failed = p.residuals(x[None])
    assert not failed[0]
    assert float(R[0] @ R[0]) == pytest.approx(_trapz(e2, cap.dt), rel=1e-9)


def test_vt_weight_and_capture_weights_enter_the_sum(unit, cap):
    u2 = apply_overrides(unit, ["weights.vt=0.5"])
    cap2 = synthetic_capture(unit, duration=2.0, rate=500.0, seed=12)
    p = make_problem([cap, cap2], u2, weights=[1.0, 3.0], fit_edges=False)
    x = p.x_start() * 1.05
    want = 0.0
    for c, a in ((cap, 1.0), (cap2, 3.0)):
        efd, vt, _ = simulate(p.values(x), c.usetp, c.dt)
        want += a * (_trapz((efd - c.efd) ** 2, c.dt) + 0.5 * _trapz((vt - c.vt) ** 2, c.dt))
    assert p.objective(x[None])[0] == pytest.approx(want, rel=1e-9)
    assert sum(p.capture_objectives(x)) == pytest.approx(want, rel=1e-9)
    # the population call gives the same as one-by-one calls
    X = np.vstack([x, p.x_start()])
    assert p.objective(X)[0] == pytest.approx(want, rel=1e-12)


@pytest.mark.parametrize("setting", ["weights.q=-1", "weights.vs=-0.5", "weights.q=nan"])
def test_a_negative_or_nan_signal_weight_is_refused_by_name(unit, cap, setting):
    name = setting.split("=")[0].split(".")[1]
    try:
        u2 = apply_overrides(unit, [setting])
    except ValueError as exc:   # refused where it is read: as good
        assert name in str(exc)
        return
    with pytest.raises(ProblemError, match=rf"signal weight {name} = .*: need a finite value >= 0"):
        make_problem([cap], u2, fit_edges=False)


def test_failed_candidates_rank_below_every_finite_one_and_earlier_is_worse(unit, cap):
    p = make_problem([cap], unit, fit_edges=False)
    good = p.x_start()
    invalid = good.copy()
    invalid[2] = -0.1  # TA2 < 0: refused before the first step
    # high gain, strong leads, slow exciter: the loop diverges (early, later)
    early = np.array([800.0, 5.0, 0.01, 5.0, 1.0, 0.2])
    late = np.array([800.0, 5.0, 0.01, 0.05, 1.0, 0.2])
    f = p.objective(np.vstack([good, invalid, early, late]))
    fs_early = simulate(p.values(early), cap.usetp, cap.dt)[2]
    fs_late = simulate(p.values(late), cap.usetp, cap.dt)[2]
    assert 0 < fs_early < fs_late, "the chosen sets should fail after some steps, in this order"
    assert math.isfinite(f[0]) and f[0] < p.penalty_base
    assert min(f[1:]) > p.penalty_base
    assert f[1] > f[2] > f[3], "failing earlier must rank worse"
    assert p.mse(invalid)[0] == math.inf


def test_fit_window_restricts_objective_and_mse(unit, cap):
    p = make_problem([cap], unit, fit_window=(0.8, 2.2), fit_edges=False)
    x = p.x_start() * 1.1
    efd, _, _ = simulate(p.values(x), cap.usetp, cap.dt)
    t = cap.time - cap.time[0]
    m = (t >= 0.8 - 1e-12) & (t <= 2.2 + 1e-12)
    e2 = (efd[m] - cap.efd[m]) ** 2
    assert p.objective(x[None])[0] == pytest.approx(_trapz(e2, cap.dt), rel=1e-9)
    assert p.mse(x)[0] == pytest.approx(float(np.mean(e2)), rel=1e-9)
    seg = make_problem([cap], unit, segment=slice(400, 1101), fit_edges=False)
    assert seg.objective(x[None])[0] == pytest.approx(p.objective(x[None])[0], rel=1e-9)
    full = p.with_window(None)
    assert full.mse(x)[0] == pytest.approx(float(np.mean((efd - cap.efd) ** 2)), rel=1e-9)
    with pytest.raises(ProblemError, match="fit window"):
        make_problem([cap], unit, fit_window=(2.0, 1.0), fit_edges=False)


def test_effect_parameters_bounds_and_constraints(unit, cap):
    names = list(unit.identified_names) + ["VRMAX", "VRMIN", "S10", "S12"]
    p = make_problem([cap], unit, names=names, fit_edges=False)
    assert p.bounds[names.index("VRMAX")] == (1.5, 10.0)
    exprs = [c.expr for c in p.constraints]
    assert "S12 >= 1.44*S10" in exprs and "TA2 <= TA1" in exprs
    x = p.x_start()
    assert math.isfinite(x[names.index("VRMAX")])  # inf start replaced by the bound
    assert p.values(x)["VRMAX"] == x[names.index("VRMAX")]


def test_constraint_on_a_fixed_parameter_is_folded_into_the_bound(unit, cap):
    p = make_problem([cap], unit, names=["KAVR", "TA2"], fit_edges=False)
    (c,) = [c for c in p.constraints if c.expr == "TA2 <= TA1"]
    assert c.satisfied([200.0, 0.9]) and not c.satisfied([200.0, 1.1])  # TA1 fixed at 1.0
    # "TA4 >= TA2" still involves TA2; with only KAVR fitted both are reported as fixed facts
    p2 = make_problem([cap], unit, names=["KAVR"], fit_edges=False)
    assert p2.constraints == ()
    assert {e for e, ok in p2.fixed_constraints} == {"TA2 <= TA1", "TA4 >= TA2"}
    assert all(c["satisfied"] for c in p2.constraint_report([200.0]))


def test_bad_input_is_refused_with_the_name(unit, cap):
    with pytest.raises(ProblemError, match="FOO"):
        make_problem([cap], unit, names=["KAVR", "FOO"], fit_edges=False)
    with pytest.raises(ProblemError, match="TA9|unknown"):
        make_problem([cap], unit, bounds={"TA9": (0, 1)}, fit_edges=False)
    with pytest.raises(ProblemError, match="Td0p"):
        make_problem([cap], unit, names=["Td0p"], fit_edges=False)  # no default bounds
    from bench_ctl.identification.constraints import ConstraintError
    with pytest.raises(ConstraintError, match="TAX"):
        make_problem([cap], unit, constraints=["TAX <= TA1"], fit_edges=False)
    with pytest.raises(ProblemError, match="weights"):
        make_problem([cap], unit, weights=[1.0, 2.0], fit_edges=False)
    tiny = Capture(time=[0.0, 0.001], usetp=[1.0, 1.0], efd=[1.0, 1.0])
    with pytest.raises(ProblemError, match="too few"):
        make_problem([tiny], unit, fit_edges=False)
