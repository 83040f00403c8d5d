"""MVMO's peers (de, local, open-loop) and MVMO itself through `run_optimizer`.

The same short synthetic capture for all; checks are on what each method promises: the budget,
a monotone history, bounds and constraints where the method respects them, and the listing of
broken constraints where it does not.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from bench_ctl.identification.construction import make_problem
from bench_ctl.identification.peers import OPTIMIZERS, OpenLoopModel, run_optimizer
from bench_ctl.identification.result import Result
from bench_ctl.identification.space import SearchSpace
from bench_ctl.identification.synthetic import synthetic_capture
from truth import TRUTH


@pytest.fixture(scope="module")
def problem(unit, truth_unit):
    cap = synthetic_capture(truth_unit, duration=3.0, rate=500.0, seed=5)
    return make_problem([cap], unit, fit_edges=False)  # the optimizers on the six AVR parameters


@pytest.mark.parametrize("name", OPTIMIZERS)
def test_every_optimizer_keeps_the_budget_and_reports_alike(problem, name):
    seen = []
    r = run_optimizer(name, problem, max_evals=120, seed=4, progress=lambda n, f: seen.append((n, f)))
    assert isinstance(r, Result) and r.method == name and 0 < r.nfev <= 120
    assert r.x.shape == (6,) and np.all(r.x > 0) and r.names == problem.names
    assert math.isfinite(r.fun) and r.success
    assert r.fun == pytest.approx(float(problem.objective(r.x[None])[0]))
    counts = [n for n, _ in r.history]
    assert counts == sorted(counts) and counts[-1] == r.nfev
    best = [f for _, f in r.history]
    assert all(a >= b for a, b in zip(best, best[1:]))
    assert seen and seen[-1][0] == r.nfev
    assert r.wall_s > 0 and isinstance(r.settings, dict)
    assert list(r.violated) == problem.violated(r.x)


@pytest.mark.parametrize("name", ["mvmo", "de"])
def test_global_methods_respect_bounds_and_constraints(problem, name):
    r = run_optimizer(name, problem, max_evals=300, seed=1)
    assert np.all(r.x >= problem.lower) and np.all(r.x <= problem.upper)
    assert r.violated == ()


def test_mvmo_is_deterministic_for_a_seed(problem):
    a = run_optimizer("mvmo", problem, max_evals=200, seed=7)
    b = run_optimizer("mvmo", problem, max_evals=200, seed=7)
    assert np.array_equal(a.x, b.x) and a.history == b.history


def test_mvmo_search_space_is_logarithmic_and_keeps_the_ratio_constraints_linear(problem):
    s = SearchSpace(problem, "log")
    assert all(s.log)
    x = np.array([200.0, 1.0, 0.3, 0.1, 2.0, 0.03])
    np.testing.assert_allclose(s.to_x(s.to_z(x)), x, rtol=1e-12)
    # TA2 <= TA1 becomes ln TA2 - ln TA1 <= 0: same verdict as in x
    for xx in (x, np.array([200.0, 0.2, 0.3, 0.1, 2.0, 0.03])):
        for c_z, c_x in zip(s.constraints, problem.constraints):
            assert c_z.satisfied(s.to_z(xx)) == c_x.satisfied(xx)


def test_local_may_break_constraints_and_says_which(problem):
    # started at the lead-swapped set (TA1 <-> TA3), the positivity-only gradient search stays
    # in that equally good valley, where TA2 <= TA1 does not hold
    x0 = np.array([200.0, 0.1, 0.3, 1.0, 2.0, 0.03])
    r = run_optimizer("local", problem, max_evals=200, seed=0, x0=x0)
    assert r.violated == ("TA2 <= TA1",)
    assert r.x[1] < r.x[2]
    assert problem.mse(r.x)[0] < 1.1e-4  # a good fit, just not an allowed one
    assert r.settings["bounds"].startswith("positivity only")


def test_open_loop_model_matches_the_closed_loop_when_the_pseudo_measurement_is_exact(unit, truth_unit):
    cap = synthetic_capture(truth_unit, duration=3.0, rate=500.0, seed=5, noise_pu=0.0)
    p = make_problem([cap], unit, fit_edges=False)
    x = np.array([TRUTH[n] for n in p.names])
    exact = OpenLoopModel(p, truth_unit.values())  # pseudo-Vt from the true parameters
    sim = p.simulate(x)[0]["efd"]
    out, bad = exact.simulate(x[None])
    assert not bad[0]
    assert np.max(np.abs(out[0][0] - sim)) < 2e-3  # exact discretisation; only RK4's error left


def test_open_loop_fit_is_worse_when_the_typical_parameters_are_wrong(problem, unit, truth_unit):
    # typical = the unit's values (reference AVR), far from the truth: the pseudo-measured Vt is
    # wrong, so the open-loop fit scores worse in closed loop than a closed-loop fit
    r_open = run_optimizer("open-loop", problem, max_evals=300, seed=0)
    r_local = run_optimizer("local", problem, max_evals=300, seed=0)
    mse_open, mse_local = problem.mse(r_open.x)[0], problem.mse(r_local.x)[0]
    assert mse_local < 1.1e-4
    assert mse_open > 2.0 * mse_local
    assert r_open.settings["typical"]["TA4"] == unit.identify["TA4"].value


def test_unknown_optimizer_and_bad_budget_are_refused(problem):
    with pytest.raises(ValueError, match="unknown optimizer"):
        run_optimizer("pso", problem, max_evals=10, seed=0)
    with pytest.raises(ValueError, match="max_evals"):
        run_optimizer("de", problem, max_evals=0, seed=0)
    with pytest.raises(ValueError, match="population"):
        run_optimizer("de", problem, max_evals=10, seed=0)


@pytest.mark.parametrize("name", ["mvmo", "de", "local"])
def test_no_simulation_beyond_the_budget(problem, name, monkeypatch):
    """max_evals counts every candidate simulated, the final score included (one capture here:
    one engine row per candidate; the copies that pad a call to the engine's vector width are not
    candidates, `engine.layout.LANES`)."""
    from bench_ctl import engine

    rows = [0]
    real = engine.run

    def counting(P, *args, **kwargs):
        rows[0] += np.atleast_2d(P).shape[0]
        return real(P, *args, **kwargs)

    monkeypatch.setattr(engine, "run", counting)
    r = run_optimizer(name, problem, max_evals=120, seed=0)
    assert r.nfev <= 120 and rows[0] == r.nfev, (r.nfev, rows[0])
    assert r.fun == pytest.approx(float(problem.objective(r.x[None])[0]), rel=1e-9)


def test_the_reference_polishes_again_from_its_exchanged_lags(problem):
    """A fit stalled with TA2 and TE exchanged (TE pressed on its 0.2 s bound, TA2 at the true TE):
    the restart from the exchanged point reaches the truth's fit; TA4 <-> TE, whose two exchanged
    values lie outside their bounds, is skipped and leaves the evaluations to it."""
    from bench_ctl.identification import peers

    swaps = peers._swaps(problem)
    assert [(problem.names[i], problem.names[j]) for _, i, j in swaps] == [("TA2", "TE"), ("TA4", "TE")]
    stalled = {**TRUTH, "TA2": TRUTH["TE"], "TE": 0.2}
    x = np.array([stalled[n] for n in problem.names])
    f = float(problem.objective(x[None])[0])
    start = Result(x=x, fun=f, nfev=0, success=True, names=problem.names)
    res = peers._swap_restarts(problem, SearchSpace(problem), swaps, 150, start, None)
    ta2, ta4 = res.settings["swap_restarts"]
    assert ta2["kept"] and ta4["skipped"] == "the exchanged values of TA4 and TE lie outside their bounds"
    assert res.nfev <= 150 and res.fun < 0.5 * f
    truth_fit = float(problem.objective(np.array([[TRUTH[n] for n in problem.names]]))[0])
    assert res.fun <= 1.001 * truth_fit


def test_the_start_point_is_polished_again_and_the_better_end_kept(problem):
    """A fit stalled in another basin (the second lead-lag cancelled, TA3 = TA4 = 1 s: MVMO's end
    on a real record at some seeds) and the caller's start point near the truth: the restart from
    the start reaches the truth's fit. From a start worse than the fit, the fit is kept as it is."""
    from bench_ctl.identification import peers

    stalled = {**TRUTH, "TA3": 1.0, "TA4": 1.0}
    x = np.array([stalled[n] for n in problem.names])
    f = float(problem.objective(x[None])[0])
    fit = Result(x=x, fun=f, nfev=0, success=True, names=problem.names)
    near = np.array([1.3 * TRUTH[n] for n in problem.names])
    res = peers._restarts(problem, SearchSpace(problem), near, [], 150, fit, None)
    entry = res.settings["start_restart"]
    assert entry["kept"] and entry["objective_before"] == f and res.nfev <= 150
    truth_fit = float(problem.objective(np.array([[TRUTH[n] for n in problem.names]]))[0])
    assert res.fun <= 1.001 * truth_fit < 0.5 * f
    truth = Result(x=np.array([TRUTH[n] for n in problem.names]), fun=truth_fit, nfev=0, success=True,
                   names=problem.names)
    kept = peers._restarts(problem, SearchSpace(problem), x, [], 150, truth, None)
    assert not kept.settings["start_restart"]["kept"] and np.array_equal(kept.x, truth.x) and kept.fun == truth_fit


def test_mvmo_from_a_start_point_keeps_the_restarts_within_the_budget(problem):
    """With x0 MVMO leaves the restarts their share and the whole run stays within max_evals; the
    diagnosis' searches, which split the budget themselves (polish_evals), get no start restart."""
    x0 = np.array([1.3 * TRUTH[n] for n in problem.names])
    r = run_optimizer("mvmo", problem, max_evals=300, seed=0, x0=x0)
    assert "objective" in r.settings["start_restart"] and r.nfev <= 300
    r2 = run_optimizer("mvmo", problem, max_evals=300, seed=0, x0=x0, options={"polish_evals": 60})
    assert "start_restart" not in r2.settings and r2.nfev <= 300


def test_an_exchange_that_breaks_a_constraint_restarts_with_the_leads_exchanged_too(problem):
    """Stalled with TA2 and TE exchanged and the leads too (TA1 below TE's bound, TA3 above it):
    TA2 <-> TE alone gives TA2 = 0.2 s > TA1 and breaks TA2 <= TA1. The restart exchanges the
    leads TA1 <-> TA3 as well (the same forward path), which meets it, and polishes from there
    instead of skipping the exchange."""
    from bench_ctl.identification import peers

    swaps = peers._swaps(problem)
    stalled = {**TRUTH, "TA1": 0.15, "TA3": 0.5, "TA2": TRUTH["TE"], "TE": 0.2}
    x = np.array([stalled[n] for n in problem.names])
    f = float(problem.objective(x[None])[0])
    start = Result(x=x, fun=f, nfev=0, success=True, names=problem.names)
    res = peers._swap_restarts(problem, SearchSpace(problem), swaps, 150, start, None)
    ta2 = res.settings["swap_restarts"][0]
    assert "skipped" not in ta2 and ta2["with"] == "leads TA1 <-> TA3 swapped"
    begun = ta2["start"]
    assert (begun["TA2"], begun["TE"], begun["TA1"], begun["TA3"]) == (0.2, TRUTH["TE"], 0.5, 0.15)
    assert ta2["kept"] and res.fun < 0.5 * f and res.nfev <= 150
    truth_fit = float(problem.objective(np.array([[TRUTH[n] for n in problem.names]]))[0])
    assert res.fun <= 1.01 * truth_fit


def test_a_call_padded_to_the_vector_width_gives_each_candidate_its_own_result(problem, monkeypatch):
    """Six candidates run padded to LANES with copies of the last; each gets what it gets alone
    (to rounding: the vector loop and the scalar one may round differently) and the copies are
    dropped."""
    from bench_ctl import engine

    rows = []
    real = engine._run

    def seen(D, *args, **kwargs):
        rows.append(D.shape[0])
        return real(D, *args, **kwargs)

    monkeypatch.setattr(engine, "_run", seen)
    x = problem.x_start()
    X = x[None, :] * (1.0 + 0.05 * np.random.default_rng(3).normal(size=(6, problem.d)))
    X = SearchSpace(problem).clip(X)
    together = problem.objective(X)
    alone = np.array([problem.objective(X[i:i + 1])[0] for i in range(6)])
    assert together.shape == (6,) and rows[0] == engine.layout.LANES and rows[1:] == [1] * 6
    assert np.allclose(together, alone, rtol=1e-9, atol=0.0)
    assert np.ptp(alone) > 1e-3 * np.max(alone)     # six different candidates, not one six times


def test_a_trial_point_and_its_differences_share_one_engine_call(problem, monkeypatch):
    """With d + 1 <= SPECULATE the polish simulates each trial point with its difference steps in
    one call: fewer engine calls for the same budget and the same optimum as one call each."""
    import bench_ctl.identification.polish as polish_module
    from bench_ctl import engine

    assert problem.d + 1 <= polish_module.SPECULATE
    calls = [0]
    real = engine.run

    def counting(P, *args, **kwargs):
        calls[0] += 1
        return real(P, *args, **kwargs)

    monkeypatch.setattr(engine, "run", counting)
    x0 = problem.x_start()
    together = polish_module.SPECULATE
    out = {}
    for spec in (together, 0):
        monkeypatch.setattr(polish_module, "SPECULATE", spec)
        calls[0] = 0
        r = polish_module.polish(problem, x0, budget=300)
        out[spec] = (r.fun, r.nfev, calls[0])
    (f_s, n_s, c_s), (f_p, n_p, c_p) = out[together], out[0]
    assert n_s <= 300 and n_p <= 300
    assert c_s < 0.75 * c_p, (c_s, c_p)
    assert f_s == pytest.approx(f_p, rel=1e-6)
