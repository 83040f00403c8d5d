"""The engine never crashes and never returns NaN: parameters at their bounds, unstable loops,
invalid values; failures carry a step the optimizer can rank."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bench_ctl.engine import CHUNK, run
from bench_ctl.engine.simulate import param_matrix, pulse_usetp
from bench_ctl.units.unit import reference_unit

NAMES = ["KAVR", "TA1", "TA2", "TA3", "TA4", "TE"]


def _run(X, **extra):
    unit = reference_unit()
    base = {**unit.values(), **extra}
    t, u = pulse_usetp(duration=4.0)
    P = param_matrix(base, NAMES, np.asarray(X, float))
    ref = run(param_matrix(unit.values()), u, 1e-3, 1.0)["efd"][0]
    return run(P, u, 1e-3, 1.0, measured={"efd": ref})


def test_corners_of_the_bounds_are_finite_or_failed():
    unit = reference_unit()
    lo = np.array([unit.identify[n].min for n in NAMES])
    hi = np.array([unit.identify[n].max for n in NAMES])
    corners = np.array([[lo[j] if (k >> j) & 1 else hi[j] for j in range(6)] for k in range(64)])
    out = _run(corners)
    assert np.all(np.isfinite(out["efd"]))
    assert np.all(np.isfinite(out["obj"]))
    assert np.all(np.isfinite(out["vt"]))
    # some corners are violently unstable at a 1 ms step: they must be reported, not hidden
    assert np.any(out["fail_step"] >= 0)
    assert np.any(out["fail_step"] == -1)


def test_unstable_loop_fails_early_with_a_step():
    # a very large gain with a high-frequency lead: the closed loop diverges
    out = _run([[5000.0, 5.0, 0.01, 5.0, 1.0, 0.2]])
    k = out["fail_step"][0]
    assert k >= 0
    assert np.all(np.isfinite(out["efd"]))


def test_ta2_towards_zero_and_invalid_values():
    X = [[200.0, 1.0, 1e-9, 0.5, 10.0, 0.02],   # TA2 -> 0
         [200.0, 1.0, 0.0, 0.5, 10.0, 0.02],    # TA2 = 0: improper lead, invalid
         [200.0, 1.0, math.nan, 0.5, 10.0, 0.02],
         [-5.0, 1.0, 0.2, 0.5, 10.0, 0.02],
         [200.0, 1.0, 0.2, 0.5, 10.0, math.inf]]
    out = _run(X)
    assert np.all(np.isfinite(out["efd"]))
    assert np.all(out["fail_step"][1:] == 0)        # refused at the start
    assert out["fail_step"][0] >= 0                  # stiff beyond the step: fails, finite


def test_population_evaluation_matches_single_runs():
    rng = np.random.default_rng(3)
    X = np.array([200, 1, 0.2, 0.5, 10, 0.02]) * (1 + 0.3 * (rng.random((9, 6)) - 0.5))
    batch = _run(X)
    for j in range(X.shape[0]):
        one = _run(X[j:j + 1])
        assert np.array_equal(one["efd"][0], batch["efd"][j])
        assert one["obj"][0] == batch["obj"][j]


def test_objective_is_the_trapezoidal_integral():
    rng = np.random.default_rng(4)
    X = np.array([[230.0, 0.9, 0.25, 0.6, 12.0, 0.03]])
    unit = reference_unit()
    t, u = pulse_usetp(duration=4.0)
    meas = run(param_matrix(unit.values()), u, 1e-3, 1.0)["efd"][0] + rng.normal(0, 0.01, t.size)
    out = run(param_matrix(unit.values(), NAMES, X), u, 1e-3, 1.0, measured={"efd": meas})
    err2 = (out["efd"][0] - meas) ** 2
    assert math.isclose(out["obj"][0], np.trapezoid(err2, t), rel_tol=1e-9)
    assert math.isclose(out["sse_efd"][0], err2.sum(), rel_tol=1e-9)


def test_numba_runs_the_optimisation_the_engine_needs():
    """bench_ctl sets NUMBA_OPT=max before numba builds its code generator (the engine's RK4 loop
    of the standard structures is vectorised only then); a process where that was overridden is
    told so."""
    import os
    import subprocess
    import sys

    from bench_ctl.engine import optimisation_note

    assert optimisation_note() is None
    code = "import bench_ctl.engine as e; print(e.optimisation_note())"
    env = {**os.environ, "NUMBA_OPT": "3"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert "NUMBA_OPT='3'" in out.stdout and "2.5x slower" in out.stdout


def test_a_call_of_several_chunks_gives_each_candidate_its_own_simulation():
    """More than CHUNK candidates run as several chunks (side by side on threads): each candidate
    gets the simulation it gets in a call of its own chunk's size."""
    rng = np.random.default_rng(5)
    X = np.array([200, 1, 0.2, 0.5, 10, 0.02]) * (1 + 0.3 * (rng.random((CHUNK + 9, 6)) - 0.5))
    unit = reference_unit()
    t, u = pulse_usetp(duration=2.0)
    P = param_matrix(unit.values(), NAMES, X)
    whole = run(P, u, 1e-3, 1.0)
    parts = np.vstack([run(P[:CHUNK], u, 1e-3, 1.0)["efd"], run(P[CHUNK:], u, 1e-3, 1.0)["efd"]])
    assert np.ptp(whole["efd"], axis=1).min() > 0.1
    assert np.max(np.abs(parts - whole["efd"])) < 1e-12


def test_the_reference_steps_run_in_one_loop_as_step_by_step():
    """Outside the edges' windows a reference-only chunk runs its steps in one compiled loop
    (`span.span_limited`); scoring Vt as well keeps it on the step-by-step path, which must give the
    same traces, efd errors and failure steps, for stable candidates, an unstable one and an
    invalid one, with a fitted edge inside a step."""
    from bench_ctl.engine import edge_plan

    rng = np.random.default_rng(11)
    X = np.array([200, 1, 0.2, 0.5, 10, 0.02]) * (1 + 0.3 * (rng.random((12, 6)) - 0.5))
    X[3] = [5000.0, 5.0, 0.01, 5.0, 1.0, 0.2]   # diverges
    X[5, 2] = 0.0                                # invalid: refused at step 0
    unit = reference_unit()
    t, u = pulse_usetp(duration=3.0)
    P = param_matrix({**unit.values(), "EDGE1": 0.00037}, NAMES, X)
    edges = edge_plan.build(np.array([np.argmax(u > u[0])]), np.array([0.05]), np.array([t[np.argmax(u > u[0])]]),
                            np.array([0]))
    ref = run(param_matrix(unit.values()), u, 1e-3, 1.0)["efd"][0]
    meas = ref + 0.01 * rng.standard_normal(ref.size)
    one_loop = run(P, u, 1e-3, 1.0, measured={"efd": meas}, edges=edges)
    by_step = run(P, u, 1e-3, 1.0, measured={"efd": meas, "vt": np.ones_like(meas)}, weights={"vt": 1e-300},
                  edges=edges)
    assert one_loop["fail_step"][3] > 0 and one_loop["fail_step"][5] == 0
    assert np.array_equal(one_loop["fail_step"], by_step["fail_step"])
    ok = one_loop["fail_step"] < 0   # (a failed candidate's outputs are held, not compared)
    assert np.max(np.abs(one_loop["efd"] - by_step["efd"])[ok]) < 1e-12
    assert np.max(np.abs(one_loop["vt"] - by_step["vt"])[ok]) < 1e-12
    assert np.allclose(one_loop["sse_efd"][ok], by_step["sse_efd"][ok], rtol=1e-12, atol=0.0)


def test_a_call_of_one_chunk_split_over_two_threads_gives_the_one_chunk_results():
    """A call of CHUNK/2 < n <= CHUNK candidates long enough to use the threads runs as two halves:
    the same numbers as one chunk on one thread, bit for bit."""
    import numba

    if numba.get_num_threads() < 2:
        pytest.skip("one numba thread: no split to compare")
    rng = np.random.default_rng(12)
    unit = reference_unit()
    t, u = pulse_usetp(duration=20.0)   # (a short call runs on one thread anyway)
    threads = numba.get_num_threads()
    for n in (CHUNK // 2 + 5, CHUNK):
        X = np.array([200, 1, 0.2, 0.5, 10, 0.02]) * (1 + 0.3 * (rng.random((n, 6)) - 0.5))
        P = param_matrix(unit.values(), NAMES, X)
        meas = run(P[:1], u, 1e-3, 1.0)["efd"][0] * 1.01
        split = run(P, u, 1e-3, 1.0, measured={"efd": meas})
        numba.set_num_threads(1)
        try:
            whole = run(P, u, 1e-3, 1.0, measured={"efd": meas})
        finally:
            numba.set_num_threads(threads)
        for key in ("efd", "vt", "obj", "fail_step"):
            assert np.array_equal(split[key], whole[key]), (n, key)


def test_a_chunk_without_limits_runs_without_their_arithmetic_with_the_same_numbers():
    """The paper's unit has no slew limit and no ceilings: a chunk where no candidate has either
    runs the reference loop without their arithmetic (`span.span_unlimited`). Beside one
    candidate with a finite ceiling it never reaches, the same candidates run the limited loop:
    the same traces and objectives."""
    rng = np.random.default_rng(13)
    unit = reference_unit()
    assert unit.values()["VRMAX"] == math.inf and unit.values()["RATE"] == math.inf
    X = np.array([200, 1, 0.2, 0.5, 10, 0.02]) * (1 + 0.3 * (rng.random((8, 6)) - 0.5))
    t, u = pulse_usetp(duration=2.0)
    P = param_matrix(unit.values(), NAMES, X)
    meas = run(P[:1], u, 1e-3, 1.0)["efd"][0] * 1.01
    free = run(P, u, 1e-3, 1.0, measured={"efd": meas})
    ceiling = param_matrix({**unit.values(), "VRMAX": 1e9}, NAMES, X[:1])
    limited = run(np.vstack([P, ceiling]), u, 1e-3, 1.0, measured={"efd": meas})
    assert np.ptp(free["efd"], axis=1).min() > 0.05
    assert np.max(np.abs(free["efd"] - limited["efd"][:8])) < 1e-12
    assert np.allclose(free["obj"], limited["obj"][:8], rtol=1e-12, atol=0.0)
    assert np.array_equal(free["fail_step"], limited["fail_step"][:8])
