"""The unit on the grid (issue 27, item 1): a GENROU synchronised through XE to an infinite bus
under SEXS and ESST1A, the engine's machine on the grid (`bench_ctl.engine.machines.grid`) against solve_ivp
on the equations written apart from it (tests/independent_online.py): the network solved as a
linear system rather than in closed form, the steady state found by a root finder from the
operating point rather than by ANDES' closed-form initialisation the machine uses."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bench_ctl.engine import run
from bench_ctl.engine.machines.grid import machine_matrix
from bench_ctl.engine.simulate import param_matrix
from bench_ctl.model.params import MACHINE_PARAMS
from bench_ctl.units.overrides import apply_overrides, with_model
from bench_ctl.units.unit import reference_unit
from independent_online import ESST1A, GEN, SALIENT, SEXS, Machine, exciter


def _machine(xe: float, p0: float, q0: float, g: dict = GEN) -> dict[str, float]:
    return {"XD": g["xd"], "XQ": g["xq"], "XDP": g["xd1"], "XQP": g["xq1"], "XDPP": g["xd2"], "XLS": g["xl"],
            "Tq0p": g["Tq10"], "Tq0pp": g["Tq20"], "H": g["H"], "DAMP": g["D"], "XE": xe, "P0": p0, "Q0": q0,
            "FN": g["fn"]}


def _unit(model: str, values: dict[str, float], vt0: float, g: dict = GEN):
    kpp = (g["xd2"] - g["xl"]) / (g["xd1"] - g["xl"])
    kda = (g["xd"] - g["xd1"]) * (g["xd1"] - g["xd2"]) / (g["xd1"] - g["xl"]) ** 2
    unit = with_model(reference_unit(), model)
    unit = apply_overrides(unit, [f"Td0p={g['Td10']}", f"Td0pp={g['Td20']}", f"KPP={kpp}", f"KDA={kda}",
                                  f"Vt0={vt0}", f"SATEQ={1 if g.get('salient') else 0}"]
                          + [f"{k}={v}" for k, v in values.items()])
    return unit.with_effects({"saturation": {"S10": g["S10"], "S12": 1.2 * g["S12"]}})


def _reference(model: str, s: dict, xe: float, p0: float, q0: float, vt0: float, steps, t_end: float, dt: float,
               g: dict = GEN, pss: dict | None = None, ramp: float = math.inf, skew: float = 0.0):
    """efd, Vt, P, Q of the exciter `model` on the machine by solve_ivp; `steps`: (instant, change
    of the reference); `pss`: an IEEEST on the speed (KS, T1..T4, TW, LSMAX; lead-lags, gain,
    washout, limit) whose output adds to the reference; `ramp`: the reference moves to each new
    value at that rate (pu/s) instead of stepping; `skew`: efd as recorded that late (s)."""
    from scipy.integrate import solve_ivp

    mach = Machine(xe, g=g)
    e1q, e2d, e1d, e2q, delta, efd0, vinf = mach.steady_state(p0, q0, vt0)
    m0 = [e1q, e2d, e1d, e2q, delta, 1.0]
    x0, exc, ka = exciter(model, s, vt0, efd0)
    vref0 = vt0 + efd0 / ka
    ne = len(x0)
    ks = pss["KS"] if pss else 0.0

    def stabiliser(w, xs):
        """(vs, its state derivatives) of the IEEEST at speed w."""
        if not pss:
            return 0.0, [0.0, 0.0, 0.0]
        a, b, c = xs
        dw = w - 1.0
        y1 = a + pss["T1"] / pss["T2"] * (dw - a)
        y2 = b + pss["T3"] / pss["T4"] * (y1 - b)
        v = ks * y2
        vs = min(max(v - c, -pss["LSMAX"]), pss["LSMAX"])
        return vs, [(dw - a) / pss["T2"], (y1 - b) / pss["T4"], (v - c) / pss["TW"]]

    def vref(t, start):
        """The reference at t in the integration that starts at `start` (a change acts from its
        instant on: every change is a start): each reached at the rate `ramp` (at once when
        infinite)."""
        return vref0 + sum(c if math.isinf(ramp) else math.copysign(min(abs(c), ramp * (t - a)), c)
                           for a, c in steps if a <= start)

    def f(t, z, start):
        m, x, xs = z[:6], z[6:6 + ne], z[6 + ne:]
        vt, ifd, *_ = mach.algebra(*m[:5], vinf)
        vs, dxs = stabiliser(m[5], xs)
        dx, efd = exc(x, vt, ifd, vref(t, start) + vs)
        return mach.derivatives(m, efd, vinf) + dx + dxs

    t = np.arange(int(round(t_end / dt)) + 1) * dt
    z = np.array(m0 + x0 + [0.0, 0.0, 0.0])
    # one integration between the reference's breaks: each change and the end of its ramp
    breaks = {a for a, _ in steps} | ({a + abs(c) / ramp for a, c in steps} if math.isfinite(ramp) else set())
    cuts = [0.0, *sorted(b for b in breaks if 0.0 < b < t[-1]), t[-1] + dt]
    sols = []
    for j in range(len(cuts) - 1):
        sol = solve_ivp(f, (cuts[j], cuts[j + 1]), z, args=(cuts[j],), method="DOP853", rtol=1e-10, atol=1e-12,
                        dense_output=True)
        assert sol.success
        sols.append(sol)
        z = sol.y[:, -1]

    def state(tk):
        j = min(max(int(np.searchsorted(cuts, tk, side="right")) - 1, 0), len(sols) - 1)
        return sols[j].sol(tk)

    out = np.empty((4, t.size))
    for k, tk in enumerate(t):
        m = state(tk)[:6]
        vt, ifd, _cid, _ciq, p, q, _xaq = mach.algebra(*m[:5], vinf)
        # efd as recorded `skew` late: the state then (steady before 0)
        late = state(max(tk - skew, 0.0))
        m_late, x_late = late[:6], late[6:6 + ne]
        vt_late, ifd_late, *_ = mach.algebra(*m_late[:5], vinf)
        out[:, k] = [exc(x_late, vt_late, ifd_late, vref0)[1], vt, p, q]
    return out


def _kernel(model, s, xe, p0, q0, vt0, steps, t_end, dt, g=GEN, pss=None, effects=None):
    unit = _unit(model, s, vt0, g)
    if effects:
        unit = unit.with_effects({**unit.effects, **effects})
    P = param_matrix(unit.values())
    M = machine_matrix({**_machine(xe, p0, q0, g), **{f"PSS_{k}": v for k, v in (pss or {}).items()}})
    n = int(round(t_end / dt)) + 1
    usetp = np.ones(n)
    for at, change in steps:
        usetp[int(round(at / dt)):] += change
    return run(P, usetp, dt, 1.0, machine=M), unit


CASES = [
    # SEXS, +2 % step held, XE 0.4, lagging Q
    ("SEXS", SEXS, 0.4, 0.8, 0.2, 1.0, [(0.5, 0.02)], 4.0, GEN),
    # ESST1A, a 10 % pulse: efd rides the bus-fed ceiling VRMAX Vt - KC Ifd (moving with Vt and Ifd)
    ("ESST1A", ESST1A, 0.2, 0.8, 0.1, 1.02, [(0.5, 0.10), (1.5, -0.10)], 4.0, GEN),
    # a salient-pole unit (the Mostar unit's GENSAL, saturation on E'q), ESST1A, a 5 % step at P 0.2
    ("ESST1A", ESST1A, 0.15, 0.2, -0.02, 0.98, [(0.5, 0.05)], 4.0, SALIENT),
]


@pytest.mark.parametrize("model,s,xe,p0,q0,vt0,steps,t_end,g", CASES)
def test_online_machine_matches_its_equations_solved_by_solve_ivp(model, s, xe, p0, q0, vt0, steps, t_end, g):
    dt = 1e-3
    out, unit = _kernel(model, s, xe, p0, q0, vt0, steps, t_end, dt, g)
    assert out["fail_step"][0] < 0
    ref = _reference(model, s, xe, p0, q0, vt0, steps, t_end, dt, g)
    k = ref.shape[1]
    errs = {name: np.abs(out[name][0, :k] - ref[q]) for q, name in enumerate(("efd", "vt", "p", "q"))}
    worst = {name: f"{e.max():.2e} at {np.argmax(e) * dt:.3f} s" for name, e in errs.items()}
    assert errs["efd"].max() < 1e-3, worst
    assert errs["vt"].max() < 1e-4, worst
    assert errs["q"].max() < 1e-4, worst
    assert errs["p"].max() < 1e-4, worst
    # the operating point is the one asked for, and the step moved the unit
    assert abs(out["p"][0, 0] - p0) < 1e-9 and abs(out["q"][0, 0] - q0) < 1e-9 and abs(out["vt"][0, 0] - vt0) < 1e-9
    assert np.ptp(out["q"][0]) > 0.05 and np.ptp(out["p"][0]) > 0.005   # Q follows, P swings
    if model == "ESST1A" and g is GEN:   # the 10 % pulse reached the ceiling: VRMAX Vt - KC Ifd
        hi = s["VRMAX"] * out["vt"][0] - s["KC"] * out["ifd"][0]
        assert np.any(out["efd"][0] >= hi - 1e-6)


#: an IEEEST on the speed, active: two lead-lags, washout 5 s, output limit +-0.1 pu
PSS = dict(KS=20.0, T1=0.3, T2=0.05, T3=0.2, T4=0.1, TW=5.0, LSMAX=0.1)


def test_online_stabiliser_matches_its_equations_and_damps_the_swing():
    """SEXS on the GENROU through XE 0.4 with an active stabiliser against solve_ivp (the same
    tolerances), and the swing it damps: the electromechanical mode in P, with and without it."""
    from bench_ctl.signals.mode import electromechanical_mode

    dt, steps = 1e-3, [(0.5, 0.02)]
    out, _unit_ = _kernel("SEXS", SEXS, 0.4, 0.8, 0.2, 1.0, steps, 6.0, dt, pss=PSS)
    ref = _reference("SEXS", SEXS, 0.4, 0.8, 0.2, 1.0, steps, 6.0, dt, pss=PSS)
    k = ref.shape[1]
    errs = {name: np.abs(out[name][0, :k] - ref[q]).max() for q, name in enumerate(("efd", "vt", "p", "q"))}
    assert errs["efd"] < 1e-3 and errs["vt"] < 1e-4 and errs["q"] < 1e-4 and errs["p"] < 1e-4, errs
    plain, _unit_ = _kernel("SEXS", SEXS, 0.4, 0.8, 0.2, 1.0, steps, 6.0, dt)
    t = np.arange(k) * dt
    with_pss, without = (electromechanical_mode(t, o["p"][0, :k], 0.5) for o in (out, plain))
    assert with_pss is not None and without is not None
    assert with_pss.damping > without.damping + 0.05, (with_pss, without)
    # a stabiliser with KS = 0 is none: the same run to the last bit
    zero, _unit_ = _kernel("SEXS", SEXS, 0.4, 0.8, 0.2, 1.0, steps, 6.0, dt, pss={**PSS, "KS": 0.0})
    assert np.array_equal(zero["efd"], plain["efd"]) and np.array_equal(zero["p"], plain["p"])


@pytest.mark.parametrize("model,s,effects,ramp,skew", [
    # ESST1A: the ramped 5 % reference drives efd onto its bus-fed ceiling and back
    ("ESST1A", ESST1A, {"setpoint_ramp": {"RAMP": 0.1}}, 0.1, 0.0),
    # SEXS: the recorded efd read between the engine's samples (cubic Hermite; across the kink
    # where ESST1A's ceiling engages that readout was 2.2e-3 pu off for one sample)
    ("SEXS", SEXS, {"time_skew": {"SKEW": 0.0123}}, math.inf, 0.0123)], ids=["setpoint_ramp", "time_skew"])
def test_online_ramp_and_skew_match_their_equations(model, s, effects, ramp, skew):
    """The setpoint ramp (the reference moves at RAMP pu/s) and the recorder skew (efd recorded
    SKEW late) on the unit on the grid, against solve_ivp with the ramp in the reference and the
    recorded efd read from the solution SKEW earlier (the diagnosis tries the skew on line, not yet the ramp)."""
    dt, steps = 1e-3, [(0.5, 0.05), (2.0, -0.05)]
    out, _unit_ = _kernel(model, s, 0.2, 0.8, 0.1, 1.02, steps, 4.0, dt, effects=effects)
    ref = _reference(model, s, 0.2, 0.8, 0.1, 1.02, steps, 4.0, dt, ramp=ramp, skew=skew)
    plain, _unit_ = _kernel(model, s, 0.2, 0.8, 0.1, 1.02, steps, 4.0, dt)
    errs = {name: np.abs(out[name][0] - ref[q]).max() for q, name in enumerate(("efd", "vt", "p", "q"))}
    assert errs["efd"] < 1e-3 and errs["vt"] < 1e-4 and errs["q"] < 1e-4 and errs["p"] < 1e-4, errs
    assert np.abs(out["efd"][0] - plain["efd"][0]).max() > 0.1   # the effect acted


def test_online_steady_state_is_steady():
    """Without a step every signal stays where the operating point put it (ANDES' closed-form
    initialisation of a GENROU, the exciters' steady state at that field voltage)."""
    for model, s, g in (("SEXS", SEXS, GEN), ("ESST1A", ESST1A, GEN), ("ESST1A", ESST1A, SALIENT)):
        unit = _unit(model, s, 1.03, g)
        P = param_matrix(unit.values())
        M = machine_matrix([_machine(0.3, 0.9, -0.1, g), _machine(0.1, 0.2, 0.4, g)])
        out = run(np.vstack([P, P]), np.ones(3001), 1e-3, 1.0, machine=M)
        for name in ("efd", "vt", "p", "q", "ifd"):
            drift = np.abs(out[name] - out[name][:, :1]).max()
            assert drift < 1e-9, f"{model} {name} drifts {drift:.1e}"
        assert np.all(out["fail_step"] < 0)


def test_the_dead_time_delays_the_unit_on_the_grid_as_at_no_load():
    """The one engine runs every effect whatever the machine: a dead time of 20 ms in the control
    path of the unit on the grid moves efd 20 ms after the reference step, as at no load."""
    unit = _unit("SEXS", SEXS, 1.0)
    M = machine_matrix(_machine(0.3, 0.8, 0.2))
    usetp = np.ones(301)
    usetp[100:] += 0.02
    first = []
    for td in (0.0, 0.02):
        P = param_matrix(unit.with_effects({"dead_time": {"TD": td}}).values() if td else unit.values())
        efd = run(P, usetp, 1e-3, 1.0, machine=M)["efd"][0]
        first.append(int(np.argmax(np.abs(efd - efd[0]) > 1e-6)))
    assert first[0] == 101 and first[1] == 121, first


def test_online_refuses_what_it_does_not_simulate():
    unit = _unit("SEXS", SEXS, 1.0)
    P = param_matrix(unit.values())
    M = machine_matrix(_machine(0.3, 0.8, 0.2))
    with pytest.raises(ValueError, match="XE"):
        machine_matrix({**_machine(0.3, 0.8, 0.2), "XE": 5.0})
    with pytest.raises(ValueError, match="H .*missing"):
        machine_matrix({k: v for k, v in _machine(0.3, 0.8, 0.2).items() if k != "H"})
    # reactances out of order: the candidate fails at step 0, its neighbour runs
    M2 = machine_matrix([_machine(0.3, 0.8, 0.2), {**_machine(0.3, 0.8, 0.2), "XDP": 0.2, "XDPP": 0.25}])
    out = run(np.vstack([P, P]), np.ones(10), 1e-3, 1.0, machine=M2)
    assert list(out["fail_step"]) == [-1, 0]
    assert len(MACHINE_PARAMS) == M.shape[1]


def test_the_reference_blocks_variant_runs_what_the_full_blocks_run():
    """A call of reference-structure and SEXS candidates runs the reference blocks' variant; one
    ESST1A candidate in the call puts it on every block's. The same candidates give the same
    traces either way: a 2 % step and a 20 % pulse into SEXS's EMAX and the reference structure's
    ceiling (non-windup), at two XE."""
    from bench_ctl.engine import classify
    from bench_ctl.engine.layout import X_FULL, X_REF
    from bench_ctl.engine.machines.grid import derive_grid
    from bench_ctl.engine.stabilisers import ieeest

    dt, n = 1e-3, 3001
    usetp = np.ones(n)
    usetp[500:] += 0.02
    pulse = np.ones(n)
    pulse[500:1500] += 0.2
    ceiling = apply_overrides(with_model(reference_unit(), "REFERENCE"), ["VRMAX=4.0", "VRMIN=-3.0", "VRVT=1"])
    fast = [param_matrix(_unit("SEXS", {**SEXS, "K": k}, 1.0).values()) for k in (120.0, 200.0, 400.0)]
    fast.append(param_matrix(ceiling.values()))
    P = np.vstack(fast)
    M = machine_matrix([_machine(xe, 0.8, 0.1) for xe in (0.2, 0.4, 0.3, 0.3)])
    full = np.vstack([P, param_matrix(_unit("ESST1A", ESST1A, 1.0).values())])
    Mf = machine_matrix([_machine(xe, 0.8, 0.1) for xe in (0.2, 0.4, 0.3, 0.3, 0.3)])
    assert classify(derive_grid(P, M)) == X_REF and classify(derive_grid(full, Mf)) == X_FULL
    Gp = machine_matrix({**_machine(0.3, 0.8, 0.1), "PSS_KS": 10.0})
    assert ieeest.present(derive_grid(P[:1], Gp)) and not ieeest.present(derive_grid(P, M))   # its own variant
    for u in (usetp, pulse):
        a = run(P, u, dt, 1.0, machine=M)
        b = run(full, u, dt, 1.0, machine=Mf)
        assert np.all(a["fail_step"] < 0) and np.all(b["fail_step"] < 0)
        for name in ("efd", "vt", "p", "q", "ifd"):
            diff = np.abs(a[name] - b[name][:4]).max()
            assert diff < 1e-9, f"{name}: {diff:.1e}"
    hi = 4.0 * a["vt"][3]
    assert np.any(a["efd"][3] >= hi - 1e-9) and np.any(a["efd"][:3] >= 4.5 - 1e-9)   # the limits acted


@pytest.mark.parametrize("model, values", [("SEXS", SEXS), ("ESST1A", ESST1A)])
def test_a_candidates_run_does_not_depend_on_where_its_chunk_mates_put_their_edges(model, values):
    """The chunk looks at the edges only in the steps between an edge's nominal sample and its
    chunk's fitted instants; elsewhere every candidate's reference is the record's. A candidate with
    its edges inside a step runs the same next to a chunk-mate whose edges are 0.3 s late (the
    window then spans 300 steps) as next to itself: a window cut too short would leave its jump
    out."""
    from bench_ctl.engine import edge_plan
    from bench_ctl.model.params import COL
    from bench_ctl.signals.edges import EDGE_PARAMS

    dt, n = 1e-3, 2001
    usetp = np.ones(n)
    usetp[500:1500] += 0.05
    spec = edge_plan.build(np.array([500, 1500]), np.array([0.05, -0.05]), np.array([0.4996, 1.4993]),
                           np.array([0, 1]))
    p = param_matrix(_unit(model, values, 1.0).values())
    late = p.copy()
    p[0, COL[EDGE_PARAMS[0]]], p[0, COL[EDGE_PARAMS[1]]] = 0.0003, -0.0002   # inside steps 499 and 1492
    late[0, COL[EDGE_PARAMS[0]]], late[0, COL[EDGE_PARAMS[1]]] = 0.3, 0.3
    M = machine_matrix([_machine(0.3, 0.8, 0.1)] * 2)
    alone = run(np.vstack([p, p]), usetp, dt, 1.0, machine=M, edges=spec)
    beside = run(np.vstack([p, late]), usetp, dt, 1.0, machine=M, edges=spec)
    assert np.all(alone["fail_step"] < 0) and np.all(beside["fail_step"] < 0)
    for name in ("efd", "vt", "q"):
        assert np.abs(alone[name][0] - beside[name][0]).max() < 1e-12, name
    # a chunk-mate's instant that is not a number does not move the chunk's window
    lost = late.copy()
    lost[0, COL[EDGE_PARAMS[0]]] = np.nan
    beside_nan = run(np.vstack([p, lost]), usetp, dt, 1.0, machine=M, edges=spec)
    assert np.abs(alone["efd"][0] - beside_nan["efd"][0]).max() < 1e-12
    # the edges acted where they were fitted: the late chunk-mate's efd leaves its steady state 0.3 s later
    moved = [int(np.argmax(np.abs(beside["efd"][c] - beside["efd"][c][0]) > 1e-6)) for c in (0, 1)]
    assert moved[0] in (499, 500) and moved[1] - moved[0] in range(299, 302), moved


def test_a_chunk_runs_the_same_on_the_calling_thread_and_on_a_pool_thread():
    """A call's chunks run on the calling thread or side by side on the engine's threads (a fit on
    another thread beside it): the compiled entry points release the GIL, and the numbers do not
    depend on the thread, bit for bit."""
    from bench_ctl import engine
    from bench_ctl.engine import runner

    for dispatcher in (runner.new_work, runner.advance):
        assert dispatcher.targetoptions.get("nogil") is True
    dt, n = 1e-3, 1501
    usetp = np.ones(n)
    usetp[300:1300] += 0.05
    rows = np.repeat(param_matrix(_unit("ESST1A", ESST1A, 1.0).values()), 5, axis=0)
    rows[:, 0] *= np.linspace(0.8, 1.2, rows.shape[0])   # every candidate its own gain
    M = machine_matrix([_machine(0.3, 0.8, 0.1)] * rows.shape[0])
    call = lambda: run(rows, usetp, dt, 1.0, machine=M, measured={"efd": np.ones(n)})  # noqa: E731
    here = call()
    there = engine._pool(2).submit(call).result()
    for name in ("efd", "vt", "p", "q", "ifd", "obj", "fail_step"):
        assert np.array_equal(here[name], there[name]), name
