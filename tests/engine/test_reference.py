"""The compiled engine against an independent high-accuracy integration (scipy solve_ivp).

The reference equations below are written again from docs/model.md, not imported from the
kernel: state vector, saturation, limits, ramp, dead time (method of steps with dense output),
recorder gain and skew. Integration is split at every input discontinuity (pulse edges, ramp
ends) with tight tolerances. Criterion (issue 2): max |efd error| < 1e-3 pu over the reference
5 % / 1 s pulse, with no effect and with each effect on in turn.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bench_ctl.engine import edge_plan
from bench_ctl.engine import run as run_engine
from bench_ctl.engine.simulate import param_matrix, pulse_usetp
from bench_ctl.signals.edges import find_setpoint_edges
from bench_ctl.units.unit import reference_unit

REF = dict(KAVR=200.0, TA1=1.0, TA2=0.2, TA3=0.5, TA4=10.0, TE=0.02, Td0p=7.5, Td0pp=0.05, Vt0=1.0)
NEUTRAL = dict(VRMAX=math.inf, VRMIN=-math.inf, TD=0.0, TR=0.0, S10=0.0, S12=0.0, RATE=math.inf,
               RAMP=math.inf, GAIN=1.0, SKEW=0.0, VRVT=0.0, KC=0.0)
START, WIDTH, AMP, DURATION, RATE_HZ = 1.0, 1.0, 0.05, 4.0, 1000.0


def reference_efd(p: dict, t_eval: np.ndarray, on: float = START, off: float = START + WIDTH) -> np.ndarray:
    """efd as recorded, by solve_ivp (DOP853, rtol 1e-10: 3x faster here than Radau, the same
    figures within 1e-6) on the continuous-time equations, for a setpoint pulse of AMP from `on`
    to `off` (s, any instant, not only sample instants)."""
    if p["S10"] > 0:
        r = math.sqrt(p["S12"] / p["S10"])
        A = (r - 1.2) / (r - 1.0)
        B = p["S10"] / (1.0 - A) ** 2
    else:
        A, B = 0.0, 0.0

    def sat(x):
        return B * (x - A) ** 2 if x > A else 0.0

    def limits(eqp, eqpp):  # bus-fed: x Vt; the upper one less KC * Ifd, Ifd = E'q + Sat(E'q)
        sc = 1.0 + p["VRVT"] * (eqpp - 1.0)
        return p["VRMAX"] * sc - p["KC"] * (eqp + sat(eqp)), p["VRMIN"] * sc

    vt0 = p["Vt0"]
    efd0 = vt0 + sat(vt0)
    e0 = efd0 / p["KAVR"]
    uref0 = vt0 + e0

    def target(t):
        return uref0 + (AMP if on <= t < off else 0.0)

    ramp = p["RAMP"]

    def uref(t):
        if not math.isfinite(ramp):
            return target(t)
        if t < on:
            return uref0
        rise = min(AMP, ramp * (t - on))
        if t < off:
            return uref0 + rise
        top = min(AMP, ramp * (off - on))
        return uref0 + max(0.0, top - ramp * (t - off))

    def avr_out(t, x):
        xm, x1, x2 = x[0], x[1], x[2]
        vm = xm if p["TR"] > 0 else x[5]
        e = uref(t) - vm
        y1 = x1 + p["TA1"] / p["TA2"] * (e - x1)
        y2 = x2 + p["TA3"] / p["TA4"] * (y1 - x2)
        return p["KAVR"] * y2, e, y1

    history = []  # dense solutions, for the dead time
    mode = [0]    # moving limits: 0 free, +1 / -1 efd held at the upper / lower limit

    def limit_rate(eqp, eqpp, deqp, deqpp, h=1e-7):
        hi, lo = limits(eqp, eqpp)
        hi2, lo2 = limits(eqp + h * deqp, eqpp + h * deqpp)
        return (hi2 - hi) / h, (lo2 - lo) / h

    def free_rate(t, x):
        vr = avr_out(t, x)[0]
        drive = vr_at(t - p["TD"]) if p["TD"] > 0 else vr
        return min(max((drive - x[3]) / p["TE"], -p["RATE"]), p["RATE"])

    def moving(t, x):  # the event that changes the mode of the moving limits
        if mode[0] == 0:
            hi, lo = limits(x[4], x[5])
            return min(hi - x[3], x[3] - lo)
        rates = limit_rate(x[4], x[5], (x[3] - x[4] - sat(x[4])) / p["Td0p"], (x[4] - x[5]) / p["Td0pp"])
        return mode[0] * (rates[0 if mode[0] > 0 else 1] - free_rate(t, x))
    moving.terminal = True
    moving.direction = -1

    def vr_at(t):
        if t <= 0:
            return efd0
        for sol in reversed(history):
            if sol.t[0] - 1e-12 <= t <= sol.t[-1] + 1e-12:
                return avr_out(t, sol.sol(t))[0]
        raise AssertionError(f"no history at {t}")

    def f(t, x):
        xm, x1, x2, ef, eqp, eqpp = x
        vr, e, y1 = avr_out(t, x)
        drive = vr_at(t - p["TD"]) if p["TD"] > 0 else vr
        de = (drive - ef) / p["TE"]
        de = min(max(de, -p["RATE"]), p["RATE"])
        deqp = (ef - eqp - sat(eqp)) / p["Td0p"]
        deqpp = (eqp - eqpp) / p["Td0pp"]
        # non-windup limits that move with Vt and Ifd: while clamped (mode[0]) efd follows the limit
        if mode[0]:
            de = limit_rate(eqp, eqpp, deqp, deqpp)[0 if mode[0] > 0 else 1]
        elif p["VRVT"] == 0 and p["KC"] == 0:  # fixed limits: the plain non-windup clamp
            if (ef >= p["VRMAX"] and de > 0) or (ef <= p["VRMIN"] and de < 0):
                de = 0.0
        return [
            (eqpp - xm) / p["TR"] if p["TR"] > 0 else 0.0,
            (e - x1) / p["TA2"],
            (y1 - x2) / p["TA4"],
            de,
            deqp,
            deqpp,
        ]

    # breakpoints: input edges, ramp ends, and their images through the dead time
    edges = {on, off}
    if math.isfinite(ramp):
        edges |= {on + min(off - on, AMP / ramp), off + min(AMP, ramp * (off - on)) / ramp}
    if p["TD"] > 0:
        edges |= {e + j * p["TD"] for e in list(edges) for j in range(1, 4)}
        edges |= set(np.arange(p["TD"], t_eval[-1], p["TD"]))
    bps = sorted(b for b in edges if 0 < b < t_eval[-1]) + [float(t_eval[-1])]
    x = np.array([vt0, e0, e0, efd0, vt0, vt0])
    t0 = 0.0
    events = moving if (p["VRVT"] or p["KC"]) else None
    for t1 in bps:
        while t1 - t0 >= 1e-12:
            moving.direction = -1 if mode[0] == 0 else 1  # reaching a limit / leaving it
            sol = solve_ivp(f, (t0, t1), x, method="DOP853", rtol=1e-10, atol=1e-12, dense_output=True,
                            events=events)
            assert sol.success, sol.message
            history.append(sol)
            x = sol.y[:, -1].copy()
            hi, lo = limits(x[4], x[5])
            x[3] = min(max(x[3], lo), hi)
            if sol.status == 1:  # a limit reached, or left: switch the mode and go on
                mode[0] = (1 if x[3] >= hi - 1e-9 else -1) if mode[0] == 0 else 0
                t0 = float(sol.t[-1]) + 1e-12
            else:
                t0 = t1
        if events is not None and mode[0] == 0:  # an input edge may leave efd at a limit
            hi, lo = limits(x[4], x[5])
            mode[0] = 1 if x[3] >= hi - 1e-12 and free_rate(t0, x) > 0 else (
                -1 if x[3] <= lo + 1e-12 and free_rate(t0, x) < 0 else 0)

    def efd_true(t):
        if t <= 0:
            return efd0
        for sol in history:
            if sol.t[0] - 1e-12 <= t <= sol.t[-1] + 1e-12:
                y = sol.sol(t)
                hi, lo = limits(y[4], y[5])
                return min(max(y[3], lo), hi)
        return history[-1].y[3, -1]

    return np.array([p["GAIN"] * efd_true(t - p["SKEW"]) for t in t_eval])


CASES = {
    "none": {},
    "ceiling_limit": dict(VRMAX=2.8, VRMIN=-0.8),
    "ceiling_limit_bus_fed": dict(VRMAX=2.7, VRMIN=-0.75, VRVT=1.0, KC=0.08),
    "dead_time": dict(TD=0.015),
    "dead_time_fractional": dict(TD=0.0153),
    "transducer_lag": dict(TR=0.02),
    "saturation": dict(S10=0.1, S12=0.4),
    "rate_limit": dict(RATE=40.0),
    "setpoint_ramp": dict(RAMP=0.5),
    "recorder_gain": dict(GAIN=1.05),
    "time_skew": dict(SKEW=0.0123),
}


#: the cases `make test` runs; the others are in the slow tier (`make test-slow`, CI runs both)
QUICK_CASES = ("none", "ceiling_limit", "saturation")


def tiered(cases: list[str]) -> list:
    """`cases` as parameters, those outside QUICK_CASES marked slow."""
    return [c if c in QUICK_CASES else pytest.param(c, marks=pytest.mark.slow) for c in cases]


@pytest.mark.parametrize("case", tiered(list(CASES)))
def test_kernel_matches_solve_ivp(case):
    p = {**REF, **NEUTRAL, **CASES[case]}
    t, u = pulse_usetp(amplitude=AMP, width=WIDTH, start=START, duration=DURATION, rate=RATE_HZ)
    out = run_engine(param_matrix(p), u, 1.0 / RATE_HZ, 1.0)
    assert out["fail_step"][0] == -1
    efd = out["efd"][0]
    ref = reference_efd(p, t)
    err = np.max(np.abs(efd - ref))
    assert err < 1e-3, f"{case}: max |efd error| = {err:.2e} pu"
    # the case must actually move the response (a test that cannot fail would not)
    if case != "none":
        base = reference_efd({**REF, **NEUTRAL}, t)
        assert np.max(np.abs(ref - base)) > 0.01


#: fitted edge offsets (s) of the off-grid cases: the pulse starts 0.37 ms and ends 0.81 ms before
#: the samples that first show it
OFF_GRID = (-0.00037, -0.00081)


@pytest.mark.parametrize("case", tiered(list(CASES)))
def test_kernel_edges_between_samples_match_solve_ivp(case):
    """A setpoint edge inside a sample interval (docs/model.md, "Edge timing"): the kernel, told the
    edge's offset, integrates the change at that instant as exactly as at a sample."""
    p = {**REF, **NEUTRAL, **CASES[case], "EDGE1": OFF_GRID[0], "EDGE2": OFF_GRID[1]}
    t, u = pulse_usetp(amplitude=AMP, width=WIDTH, start=START, duration=DURATION, rate=RATE_HZ)
    k = find_setpoint_edges(u)
    spec = edge_plan.build(k, np.diff(u)[k - 1], t[k], np.arange(k.size))
    out = run_engine(param_matrix(p), u, 1.0 / RATE_HZ, 1.0, edges=spec)
    assert out["fail_step"][0] == -1
    ref = reference_efd(p, t, on=START + OFF_GRID[0], off=START + WIDTH + OFF_GRID[1])
    err = np.max(np.abs(out["efd"][0] - ref))
    assert err < 1e-3, f"{case}: max |efd error| = {err:.2e} pu"
    # the zero-order hold (edges on the samples) misses the same record by far more
    zoh = run_engine(param_matrix({**p, "EDGE1": 0.0, "EDGE2": 0.0}), u, 1.0 / RATE_HZ, 1.0, edges=spec)
    assert np.max(np.abs(zoh["efd"][0] - ref)) > 20 * max(err, 1e-4)


def test_kernel_edge_offsets_batch_like_other_parameters():
    """Candidates with different edge offsets in one call each get their own edge instant."""
    t, u = pulse_usetp(amplitude=AMP, width=WIDTH, start=START, duration=2.5, rate=RATE_HZ)
    k = find_setpoint_edges(u)
    spec = edge_plan.build(k, np.diff(u)[k - 1], t[k], np.arange(k.size))
    offs = np.array([[0.0, 0.0], [-0.0002, -0.0009], [-0.0007, 0.0], [-0.001, -0.001]])
    base = {**REF, **NEUTRAL, "TD": 0.0123}
    P = np.vstack([param_matrix({**base, "EDGE1": a, "EDGE2": b}) for a, b in offs])
    batch = run_engine(P, u, 1e-3, 1.0, edges=spec)["efd"]
    for row, (a, b) in zip(batch, offs):
        alone = run_engine(param_matrix({**base, "EDGE1": a, "EDGE2": b}), u, 1e-3, 1.0, edges=spec)["efd"][0]
        np.testing.assert_allclose(row, alone, rtol=0, atol=1e-12)
    # a whole step early is the zero-order hold of the setpoint shifted by one sample
    early = run_engine(P[:1], np.roll(u, -1), 1e-3, 1.0)["efd"][0]
    np.testing.assert_allclose(batch[3][:-2], early[:-2], rtol=0, atol=1e-9)


def test_reference_pulse_shape():
    """docs/model.md: the pulse drives efd from 1.0 to about 3.1 pu and down to about -1.0 pu."""
    t, u = pulse_usetp(duration=DURATION)
    efd = run_engine(param_matrix(reference_unit().values()), u, 1e-3, 1.0)["efd"][0]
    assert efd[0] == pytest.approx(1.0)
    assert 2.9 < efd.max() < 3.3
    assert -1.2 < efd.min() < -0.8
