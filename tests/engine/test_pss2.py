"""PSS2A and PSS2B on the unit on the grid (issue 49, item 1): the engine's plug-in
(`bench_ctl/engine/stabilisers/pss2.py`) against the stabiliser written out apart from it
(tests/independent_online.py's `Pss2`) and solved with the machine (`Machine`) and SEXS by
solve_ivp.

The equations here differ in form from the engine's where they can: the inputs are limited and
washed out as absolute signals (the washouts' states start at the operating point's input), the
ramp-tracking filter is the transfer function (1 + s T8)^N / (1 + s T9)^(M N) in state-space form
(scipy.signal.tf2ss), not a chain of lags. Each case compares efd (1e-3 pu: the SEXS gain of 200
makes that 5e-6 pu of the stabiliser's output), Vt, P and Q (1e-4 pu) and the stabiliser's output
vs, the engine's signal (1e-5 pu); a mutation of the equations (M and N swapped, a washout
dropped) must fail the same comparison. The engine scores vs like the other signals, and a run
that does not weigh it is the run without it to the last bit."""
from __future__ import annotations

import numpy as np
import pytest

from bench_ctl.engine import run
from bench_ctl.engine.machines.grid import machine_matrix
from bench_ctl.engine.simulate import param_matrix
from bench_ctl.units.overrides import apply_overrides, with_model
from bench_ctl.units.unit import reference_unit
from independent_online import GEN, SEXS, Machine, Pss2, exciter

XE, P0, Q0, VT0 = 0.4, 0.8, 0.2, 1.0
DT, T_END, STEPS = 1e-3, 4.0, [(0.5, 0.02)]

#: a dual-input PSS2A tuned for this machine (KS2 = T7 / 2H), the ramp-tracking filter M 5, N 1
PSS2A = dict(MODEL="PSS2A", KS1=10.0, TW1=2.0, TW2=2.0, T6=0.02, TW3=2.0, TW4=0.0, T7=2.0, KS2=2.0 / 6.0, KS3=1.0,
             T8=0.3, T9=0.06, M=5, N=1, T1=0.3, T2=0.05, T3=0.2, T4=0.05)
#: a PSS2B: PSS2A with the third lead-lag and input limits (none reached unless a case sets them)
PSS2B = {**PSS2A, "MODEL": "PSS2B", "T10": 0.15, "T11": 0.05, "VS1MAX": 1.0, "VS1MIN": -1.0, "VS2MAX": 2.0,
         "VS2MIN": -2.0}

CASES = {
    # the speed input alone: no power path (KS2 = KS3 = 0)
    "speed": {**PSS2A, "KS2": 0.0, "KS3": 0.0},
    # the power input alone: input 1 held by its PSS2B limits to a 1e-12 pu band, the filter off
    "power": {**PSS2B, "VS1MAX": 1e-12, "VS1MIN": -1e-12, "M": 0, "N": 0, "KS3": 0.0},
    # both inputs through the ramp-tracking filter, M 5, N 1
    "rtf_5_1": PSS2A,
    # PSS2B, the filter M 2, N 4 (eight lags), the third lead-lag
    "rtf_2_4": {**PSS2B, "M": 2, "N": 4, "T8": 0.2, "T9": 0.05},
    # the output limits reached both ways
    "output_limits": {**PSS2A, "KS1": 60.0, "VSTMAX": 0.006, "VSTMIN": -0.004},
    # PSS2B's input limits reached: the speed deviation and the electrical power itself
    # (the step swings the speed deviation over -2e-4..1.2e-5 pu, P over -0.003..+0.005 pu)
    "input_limits": {**PSS2B, "VS1MAX": 5e-6, "VS1MIN": -1e-4, "VS2MAX": P0 + 0.003, "VS2MIN": P0 - 0.0015},
}


def _unit():
    g = GEN
    kpp = (g["xd2"] - g["xl"]) / (g["xd1"] - g["xl"])
    kda = (g["xd"] - g["xd1"]) * (g["xd1"] - g["xd2"]) / (g["xd1"] - g["xl"]) ** 2
    unit = apply_overrides(with_model(reference_unit(), "SEXS"),
                           [f"Td0p={g['Td10']}", f"Td0pp={g['Td20']}", f"KPP={kpp}", f"KDA={kda}", f"Vt0={VT0}",
                            "SATEQ=0"] + [f"{k}={v}" for k, v in SEXS.items()])
    return unit.with_effects({"saturation": {"S10": g["S10"], "S12": 1.2 * g["S12"]}})


def _grid(pss: dict | None) -> dict:
    g = GEN
    out = {"XD": g["xd"], "XQ": g["xq"], "XDP": g["xd1"], "XQP": g["xq1"], "XDPP": g["xd2"], "XLS": g["xl"],
           "Tq0p": g["Tq10"], "Tq0pp": g["Tq20"], "H": g["H"], "DAMP": g["D"], "XE": XE, "P0": P0, "Q0": Q0,
           "FN": g["fn"]}
    if pss:
        out["PSS_MODEL"] = {"PSS2A": 2.0, "PSS2B": 3.0}[pss["MODEL"]]
        out.update({f"PSS2_{k}": float(v) for k, v in pss.items() if k != "MODEL"})
    return out


def engine_run(pss: dict | None):
    P = param_matrix(_unit().values())
    n = int(round(T_END / DT)) + 1
    usetp = np.ones(n)
    for at, change in STEPS:
        usetp[int(round(at / DT)):] += change
    return run(P, usetp, DT, 1.0, machine=machine_matrix(_grid(pss)))


def reference(pss: dict, *, drop_tw2: bool = False, swap_mn: bool = False):
    """efd, Vt, P, Q and the stabiliser's output of SEXS with `pss` on the machine, by solve_ivp."""
    from scipy.integrate import solve_ivp

    mach = Machine(XE, g=GEN)
    e1q, e2d, e1d, e2q, delta, efd0, vinf = mach.steady_state(P0, Q0, VT0)
    p = {**pss, "M": pss["N"], "N": pss["M"]} if swap_mn else pss
    stab = Pss2(p, P0, drop_tw2)
    x0, exc, ka = exciter("SEXS", SEXS, VT0, efd0)   # tests/independent_online.py's SEXS
    vref0 = VT0 + efd0 / ka
    ns = stab.x0.size

    def f(t, z, vref):
        m, x, xs = z[:6], z[6:8], z[8:]
        vt, _ifd, _cid, _ciq, pe, _q, _xaq = mach.algebra(*m[:5], vinf)
        vs, dxs = stab(xs, m[5], pe)
        dx, efd = exc(x, vt, 0.0, vref + vs)
        return np.concatenate([mach.derivatives(m, efd, vinf), dx, dxs])

    t = np.arange(int(round(T_END / DT)) + 1) * DT
    z = np.concatenate([[e1q, e2d, e1d, e2q, delta, 1.0], x0, stab.x0])
    cuts = [0.0] + [a for a, _ in STEPS] + [t[-1] + DT]
    vref, ys = vref0, []
    for j in range(len(cuts) - 1):   # one integration between reference changes
        sol = solve_ivp(f, (cuts[j], cuts[j + 1]), z, args=(vref,), method="DOP853", rtol=1e-10,
                        atol=1e-12, dense_output=True)
        assert sol.success
        seg = t[(t >= cuts[j] - 1e-9) & (t < cuts[j + 1] - 1e-9)]
        ys.append((sol.sol(seg), np.full(seg.size, vref)))
        z = sol.y[:, -1]
        if j < len(STEPS):
            vref += STEPS[j][1]
    out = []
    for Y, vr in ys:
        for k in range(Y.shape[1]):
            m, x, xs = Y[:6, k], Y[6:8, k], Y[8:8 + ns, k]
            vt, _ifd, _cid, _ciq, pe, q, _xaq = mach.algebra(*m[:5], vinf)
            vs = stab(xs, m[5], pe)[0]
            out.append([exc(x, vt, 0.0, vr[k] + vs)[1], vt, pe, q, vs, m[5] - 1.0, pe])
    return np.array(out).T


def errors(out, ref) -> dict[str, float]:
    k = ref.shape[1]
    return {name: float(np.abs(out[name][0, :k] - ref[q]).max())
            for q, name in enumerate(("efd", "vt", "p", "q", "vs"))}


def _within(err: dict[str, float]) -> bool:
    return err["efd"] < 1e-3 and err["vt"] < 1e-4 and err["p"] < 1e-4 and err["q"] < 1e-4 and err["vs"] < 1e-5


@pytest.mark.parametrize("case", sorted(CASES))
def test_pss2_matches_its_equations_solved_by_solve_ivp(case):
    pss = CASES[case]
    out = engine_run(pss)
    assert out["fail_step"][0] < 0
    ref = reference(pss)
    err = errors(out, ref)
    print(f"{case}: max |engine - solve_ivp| " + ", ".join(f"{k} {v:.2e}" for k, v in err.items()))
    assert _within(err), (case, err)
    vs, dw, pe = ref[4], ref[5], ref[6]
    assert np.ptp(vs) > 1e-3, "the stabiliser acted"
    if case == "output_limits":   # both limits reached, for a while
        assert np.sum(vs >= pss["VSTMAX"] - 1e-12) > 20 and np.sum(vs <= pss["VSTMIN"] + 1e-12) > 20
    if case == "input_limits":    # the speed deviation and the power went past their limits
        assert dw.max() > pss["VS1MAX"] and dw.min() < pss["VS1MIN"]
        assert pe.max() > pss["VS2MAX"] and pe.min() < pss["VS2MIN"]
    assert np.ptp(dw) > 1e-4 and np.ptp(pe) > 1e-3, "the inputs moved"


@pytest.mark.parametrize("case,mutation", [("rtf_2_4", "swap_mn"), ("rtf_5_1", "swap_mn"), ("speed", "drop_tw2")])
def test_a_mutated_reference_fails_the_comparison(case, mutation):
    """The comparison can fail: the reference with M and N swapped, or input 1's second washout
    dropped, is more than the tolerance away from the engine."""
    pss = CASES[case]
    out = engine_run(pss)
    err = errors(out, reference(pss, **{mutation: True}))
    print(f"{case} with {mutation}: max |engine - mutated solve_ivp| "
          + ", ".join(f"{k} {v:.2e}" for k, v in err.items()))
    assert not _within(err), (case, mutation, err)
    assert err["efd"] > 1e-2, err


def test_pss2b_damps_the_swing_and_ks1_zero_is_none():
    """The PSS2B damps the electromechanical mode in P after the step (damping ratio up by more
    than 0.05); with KS1 = 0 the run is the one without a stabiliser, to the last bit."""
    from bench_ctl.signals.mode import electromechanical_mode

    with_pss, without = engine_run(PSS2B), engine_run(None)
    t = np.arange(with_pss["p"].shape[1]) * DT
    on, off = (electromechanical_mode(t, o["p"][0], STEPS[0][0]) for o in (with_pss, without))
    print(f"mode in P: without {off}, with PSS2B {on}")
    assert on is not None and off is not None
    assert on.damping > off.damping + 0.05, (on, off)
    zero = engine_run({**PSS2B, "KS1": 0.0})
    assert np.array_equal(zero["efd"], without["efd"]) and np.array_equal(zero["p"], without["p"])


def test_the_stabilisers_output_is_scored_like_the_other_signals():
    """vs measured and weighted adds its weighted trapezoidal squared error to the objective
    (`sse_vs`); measured with weight 0 the objective is the one without it, to the last bit."""
    P = param_matrix(_unit().values())
    M = machine_matrix(_grid(PSS2B))
    sim = engine_run(PSS2B)
    usetp = np.ones(sim["efd"].shape[1])
    usetp[int(round(STEPS[0][0] / DT)):] += STEPS[0][1]
    rng = np.random.default_rng(5)
    efd = sim["efd"][0] + rng.normal(0.0, 0.01, usetp.size)
    vs = sim["vs"][0] + rng.normal(0.0, 1e-4, usetp.size)
    assert np.ptp(sim["vs"][0]) > 1e-3 and np.all(engine_run(None)["vs"] == 0.0)

    def obj(measured, weights):
        return run(P, usetp, DT, 1.0, machine=M, measured=measured, weights=weights, store=False)

    base = obj({"efd": efd}, {"efd": 1.0})
    unweighted = obj({"efd": efd, "vs": vs}, {"efd": 1.0, "vs": 0.0})
    assert unweighted["obj"][0] == base["obj"][0] and "sse_vs" not in unweighted
    scored = obj({"efd": efd, "vs": vs}, {"efd": 1.0, "vs": 100.0})
    e2 = (sim["vs"][0] - vs) ** 2
    trapezoid = DT * (e2.sum() - 0.5 * (e2[0] + e2[-1]))
    assert scored["sse_vs"][0] == pytest.approx(e2.sum(), rel=1e-9)
    assert scored["obj"][0] - base["obj"][0] == pytest.approx(100.0 * trapezoid, rel=1e-9)


def test_pss2_values_that_do_not_go_together_are_refused():
    for change, words in (({"M": 3, "N": 3}, "at most 8"), ({"M": 2.5}, "integers"), ({"T9": 0.0}, "T9 > 0"),
                          ({"T2": 0.0}, "lag > 0"), ({"VS1MIN": 0.1, "VS1MAX": 0.05}, "below")):
        with pytest.raises(ValueError, match=words):
            machine_matrix(_grid({**PSS2B, **change}))
    machine_matrix(_grid({**PSS2B, "T10": 0.0, "T11": 0.0, "M": 0, "N": 3, "T9": 0.0}))   # bypassed: fine
