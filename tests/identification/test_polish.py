"""The fitting stack's parts that identification and the diagnosis share: the scores a Problem
gives the diagnosis, the search space, and the one polish (docs/decisions/0015-one-fitting-stack.md).

Expected values are recomputed here from the kernel's traces with numpy, not taken from the code
under test.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from bench_ctl.engine.simulate import simulate
from bench_ctl.identification.construction import make_problem
from bench_ctl.identification.polish import polish
from bench_ctl.identification.result import Result
from bench_ctl.identification.space import SearchSpace
from bench_ctl.identification.synthetic import synthetic_capture
from bench_ctl.units.overrides import apply_overrides


@pytest.fixture(scope="module")
def cap(truth_unit):
    return synthetic_capture(truth_unit, duration=3.0, rate=500.0, seed=5)


@pytest.fixture(scope="module")
def problem(unit, cap):
    return make_problem([cap], unit, fit_edges=False)


def _trapz_mean(e2: np.ndarray) -> float:
    return float((e2.sum() - 0.5 * (e2[0] + e2[-1])) / (e2.size - 1))


def test_mean_objective_is_the_trapezoidal_mse_and_scores_whole_parameter_sets_alike(problem, cap):
    x = problem.x_start()
    efd, vt, fail = simulate(problem.values(x), cap.usetp, cap.dt)
    assert fail < 0
    e2 = (efd - cap.efd) ** 2
    assert problem.scored_s == pytest.approx((cap.n - 1) * cap.dt, rel=1e-12)
    assert problem.mean_objective(x[None])[0] == pytest.approx(_trapz_mean(e2), rel=1e-9)
    # a start point that sets a parameter the problem does not fit (a dead time here)
    both = problem.mean_objective_of([problem.values(x), {**problem.values(x), "TD": 0.02}])
    assert both[0] == pytest.approx(_trapz_mean(e2), rel=1e-9)
    efd_td, _, _ = simulate({**problem.values(x), "TD": 0.02}, cap.usetp, cap.dt)
    assert both[1] == pytest.approx(_trapz_mean((efd_td - cap.efd) ** 2), rel=1e-9)
    # the Vt error, whatever its weight (the diagnosis' check when Vt is not fitted)
    assert problem.mse(x, signal="vt")[0] == pytest.approx(float(np.mean((vt - cap.vt) ** 2)), rel=1e-9)


def test_a_failed_candidate_scores_the_problems_penalty_everywhere(problem):
    bad = problem.x_start()
    bad[0] = 1e9   # KAVR far beyond any stable loop
    f = problem.objective(bad[None])[0]
    assert f > problem.penalty_base
    R, f2 = problem.residuals_and_objective(bad[None])
    assert f2[0] == f and np.all(np.isfinite(R))
    assert problem.residuals(bad[None])[1][0]


def test_residual_rows_give_a_windows_mean_objective(unit, cap):
    u2 = apply_overrides(unit, ["weights.vt=0.5"])
    p = make_problem([cap], u2, fit_edges=False)
    x = p.x_start()
    R, failed = p.residuals(x[None])
    capt, t, sec = p.residual_rows()
    assert R.shape[1] == t.size == 2 * cap.n and not failed[0]
    assert float(R[0] @ R[0]) / sec.sum() == pytest.approx(p.mean_objective(x[None])[0], rel=1e-9)
    efd, vt, _ = simulate(p.values(x), cap.usetp, cap.dt)
    inw = (t >= 1.0) & (t <= 1.5)
    tt = np.arange(cap.n) * cap.dt
    w = (tt >= 1.0) & (tt <= 1.5)
    want = float(np.mean((efd[w] - cap.efd[w]) ** 2 + 0.5 * (vt[w] - cap.vt[w]) ** 2))
    assert float(R[0][inw] @ R[0][inw]) / sec[inw].sum() == pytest.approx(want, rel=1e-9)


def test_search_space_is_logarithmic_where_the_lower_bound_is_positive(problem):
    s = SearchSpace(problem)
    assert all(s.log) and s.kind == {n: "log" for n in problem.names}
    x = problem.x_start()
    np.testing.assert_allclose(s.to_x(s.to_z(x)), x, rtol=1e-12)
    bad = x.copy()
    bad[1] = 0.5 * bad[2]      # TA1 below TA2
    assert list(s.feasible(np.vstack([x, bad]))) == [True, False]
    assert s.violation(bad[None])[0] == pytest.approx(problem.violations(bad)["TA2 <= TA1"])


def test_polish_keeps_its_budget_and_the_constraints_and_never_ends_worse(problem):
    x0 = problem.x_start()
    f0 = float(problem.objective(x0[None])[0])
    r = polish(problem, x0, budget=80)
    assert isinstance(r, Result) and r.success and r.names == problem.names
    assert 0 < r.nfev <= 80 and r.violated == ()
    assert r.fun <= f0 and r.fun == pytest.approx(float(problem.objective(r.x[None])[0]), rel=1e-9)
    assert np.all(r.x >= problem.lower) and np.all(r.x <= problem.upper)
    counts = [n for n, _ in r.history]
    assert counts == sorted(counts) and counts[-1] == r.nfev
    assert r.jac is not None and r.jac.shape[1] == problem.d
    # the standard deviations only with a noise variance; they scale with its square root
    a = polish(problem, x0, budget=80, noise_variance=1e-4)
    b = polish(problem, x0, budget=80, noise_variance=4e-4)
    assert r.std is None and set(a.std) == set(problem.names)
    for n in problem.names:
        assert b.std[n] == pytest.approx(2.0 * a.std[n], rel=1e-9) or math.isnan(a.std[n])


def test_polish_from_an_infeasible_point_is_led_back_by_the_violation_row(problem):
    x0 = problem.x_start()
    x0[1] = 0.5 * x0[2]   # TA2 <= TA1 broken
    assert problem.violated(x0) == ["TA2 <= TA1"]
    r = polish(problem, x0, budget=120)
    assert r.success and r.violated == () and r.nfev <= 120
    assert r.fun < float(problem.objective(problem.x_start()[None])[0])
    # with too few simulations to leave the infeasible start, nothing feasible is claimed
    short = polish(problem, x0, budget=problem.d + 2)
    assert not short.success and math.isinf(short.fun) and "no feasible point" in short.message
    with pytest.raises(ValueError, match="budget"):
        polish(problem, x0, budget=0)
