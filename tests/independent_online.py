"""The unit on line written apart from the engine: the machine on the grid (GENROU or GENSAL
through XE to an infinite bus), SEXS and ESST1A, the PSS2A / PSS2B, solved by solve_ivp; and a
recorder around them that makes an independent on-line record (issue 49: identification with the
stabiliser on), as tests/independent_plant.py does at no load.

Nothing here imports `bench_ctl`: tests/engine/test_grid.py and tests/engine/test_pss2.py check
the engine against these equations; `online_record` makes the records the PSS2B identification
benchmark (benchmarks/pss2_identify.py) and its test fit. The network is solved as a linear
system, the steady state by a root finder from the operating point (not the engine's closed
form); the PSS2B's ramp-tracking filter is its transfer function in state-space form (not a
chain of lags)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: the GENROU of the ANDES fixtures (tests/fixtures/andes), H = M / 2
GEN = dict(xd=1.8, xq=1.7, xd1=0.3, xq1=0.55, xd2=0.25, xl=0.15, Td10=7.5, Tq10=0.4, Td20=0.05, Tq20=0.05,
           H=3.0, D=0.0, fn=60.0, S10=0.05, S12=0.2)
#: a salient-pole unit: the Mostar unit's GENSAL as its OpenIPSL study fitted it (X'q, T'q0 unused)
SALIENT = dict(xd=1.183, xq=0.62, xd1=0.371, xq1=0.62, xd2=0.215, xl=0.1, Td10=3.77, Tq10=1.0, Td20=0.0552,
               Tq20=0.0823, H=2.137, D=0.0, fn=50.0, S10=0.1, S12=0.4, salient=True)
SEXS = dict(TA=1.0, TB=10.0, K=200.0, TE=0.05, EMIN=-3.0, EMAX=4.5)
ESST1A = dict(TR=0.01, KA=200.0, TA=0.02, TB=10.0, TC=1.0, TB1=0.2, TC1=0.5, VRMAX=4.0, VRMIN=-3.0, KC=0.1)


def _sat(g: dict):
    """B (x - A)^2 through S(1.0) 1.0 = S10 and S(1.2) 1.2 = 1.2 S12 (absolute), 0 below A."""
    y1, y2 = g["S10"], 1.2 * g["S12"]
    r = np.sqrt(y2 / y1)
    a = (r * 1.0 - 1.2) / (r - 1.0)
    b = y1 / (1.0 - a) ** 2
    return lambda x: b * max(x - a, 0.0) ** 2


class Machine:
    """GENROU (X''d = X''q, RA = 0) through RE + j XE to an infinite bus, written out; a GENSAL
    (`salient`): saturation Sat(E'q) on the d-axis alone, one q-axis circuit psi''q =
    psikq with T''q0 dpsikq/dt = -psikq + (Xq - X''d) Iq."""

    def __init__(self, xe: float, re: float = 0.0, g: dict = GEN):
        self.g = g
        self.salient = bool(g.get("salient"))
        self.xe, self.re = xe, re
        self.sat = _sat(g)
        self.gd1 = (g["xd2"] - g["xl"]) / (g["xd1"] - g["xl"])
        self.gq1 = (g["xd2"] - g["xl"]) / (g["xq1"] - g["xl"])
        self.gqd = (g["xq"] - g["xl"]) / (g["xd"] - g["xl"])

    def algebra(self, e1q, e2d, e1d, e2q, delta, vinf):
        g = self.g
        psd = self.gd1 * e1q + (1 - self.gd1) * e2d
        psq = e2q if self.salient else self.gq1 * e1d + (1 - self.gq1) * e2q
        psi = np.hypot(psd, psq)
        se = 0.0 if self.salient else self.sat(psi) / psi
        x2, xe, re = g["xd2"], self.xe, self.re
        # vd = psq + x2 iq = vinf sin(delta) + re id - xe iq; vq = psd - x2 id = vinf cos(delta) + re iq + xe id
        A = np.array([[-re, x2 + xe], [-(x2 + xe), -re]])
        cid, ciq = np.linalg.solve(A, [vinf * np.sin(delta) - psq, vinf * np.cos(delta) - psd])
        vd, vq = psq + x2 * ciq, psd - x2 * cid
        p, q = vd * cid + vq * ciq, vq * cid - vd * ciq
        gd2 = (g["xd1"] - g["xd2"]) / (g["xd1"] - g["xl"]) ** 2
        ifd = e1q + (g["xd"] - g["xd1"]) * (self.gd1 * cid + gd2 * (e1q - e2d)) + se * psd
        if self.salient:
            ifd += self.sat(e1q)
        xaq = (e1d + (g["xq"] - g["xq1"]) * ((g["xq1"] - g["xd2"]) / (g["xq1"] - g["xl"]) ** 2 * (e1d - e2q)
                                             - self.gq1 * ciq) + se * psq * self.gqd)
        return np.hypot(vd, vq), ifd, cid, ciq, p, q, xaq

    def derivatives(self, m, efd, vinf):
        g = self.g
        e1q, e2d, e1d, e2q, delta, omega = m
        vt, ifd, cid, ciq, p, q, xaq = self.algebra(e1q, e2d, e1d, e2q, delta, vinf)
        if self.salient:
            dq = [0.0, (-e2q + (g["xq"] - g["xd2"]) * ciq) / g["Tq20"]]
        else:
            dq = [-xaq / g["Tq10"], (e1d - e2q + (g["xq1"] - g["xl"]) * ciq) / g["Tq20"]]
        return [(efd - ifd) / g["Td10"], (e1q - e2d - (g["xd1"] - g["xl"]) * cid) / g["Td20"], *dq,
                2 * np.pi * g["fn"] * (omega - 1.0), (self.tm - p - g["D"] * (omega - 1.0)) / (2 * g["H"])]

    def steady_state(self, p0: float, q0: float, vt0: float):
        """(E'q, psikd, E'd, psikq, delta), Efd and Vinf with every derivative 0 at P0, Q0, Vt0."""
        from scipy.optimize import fsolve

        self.tm = p0

        def eqs(z):
            e1q, e2d, e1d, e2q, delta, efd, vinf = z
            vt, _ifd, _cid, _ciq, p, q, _xaq = self.algebra(e1q, e2d, e1d, e2q, delta, vinf)
            d = self.derivatives([e1q, e2d, e1d, e2q, delta, 1.0], efd, vinf)
            return [d[0], d[1], e1d if self.salient else d[2], d[3], p - p0, q - q0, vt - vt0]

        z, _info, ok, msg = fsolve(eqs, [1.2, 1.0, 0.3, 0.3, 0.6, 2.0, 1.0], full_output=True, xtol=1e-13)
        assert ok == 1, msg
        return z


def exciter(model: str, s: dict, vt0: float, efd0: float):
    """(initial states, f(x, vt, ifd, vref) -> (derivatives, efd), the steady-state gain) of the
    exciter `model` (SEXS or ESST1A with the values `s`, PSS/E's names) at Vt0, Efd0."""
    if model == "SEXS":
        ka = s["K"]

        def sexs(x, vt, ifd, vref):
            xl, efd = x
            e = vref - vt
            y = xl + s["TA"] / s["TB"] * (e - xl)
            de = (ka * y - efd) / s["TE"]
            if (efd >= s["EMAX"] and de > 0) or (efd <= s["EMIN"] and de < 0):
                de = 0.0
            return [(e - xl) / s["TB"], de], efd
        return [efd0 / ka, efd0], sexs, ka   # lead-lag state, efd
    if model == "ESST1A":
        ka = s["KA"]

        def esst1a(x, vt, ifd, vref):
            xm, x1, x2, va = x
            e = vref - xm
            y1 = x1 + s["TC"] / s["TB"] * (e - x1)
            y2 = x2 + s["TC1"] / s["TB1"] * (y1 - x2)
            efd = min(max(va, s["VRMIN"] * vt), s["VRMAX"] * vt - s["KC"] * ifd)
            return [(vt - xm) / s["TR"], (e - x1) / s["TB"], (y1 - x2) / s["TB1"], (ka * y2 - va) / s["TA"]], efd
        return [vt0, efd0 / ka, efd0 / ka, efd0], esst1a, ka   # transducer, lead-lag 1, lead-lag 2, VA
    raise ValueError(f"exciter {model!r}: SEXS or ESST1A")


class Pss2:
    """PSS2A / PSS2B written out from IEEE 421.5-2016's PSS2B diagram: absolute inputs, limited
    (PSS2B), each washout's state the lagged input; the ramp-tracking filter as the transfer
    function (1 + s T8)^N / (1 + s T9)^(M N) in state-space form; `drop_tw2` leaves the second
    washout of input 1 out (a mutation)."""

    def __init__(self, p: dict, pe0: float, drop_tw2: bool = False):
        from scipy.signal import tf2ss

        self.p, self.b = p, p["MODEL"] == "PSS2B"
        self.drop_tw2 = drop_tw2
        mn = p["M"] * p["N"]
        if mn:
            num = np.poly1d([p["T8"], 1.0]) ** p["N"]
            den = np.poly1d([p["T9"], 1.0]) ** mn
            self.A, self.B, self.C, self.D = tf2ss(num.coeffs, den.coeffs)
        else:
            self.A, self.B, self.C, self.D = np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.ones((1, 1))
        self.nr = self.A.shape[0]
        u1, u2 = self.inputs(1.0, pe0)
        # washouts' states (their lagged inputs), lags, the filter's states, the lead-lags'
        self.x0 = np.concatenate([[u1, 0.0, 0.0, u2, 0.0, 0.0], np.zeros(self.nr), [0.0, 0.0, 0.0]])

    def inputs(self, w, pe):
        p = self.p
        if self.b:
            return float(np.clip(w - 1.0, p["VS1MIN"], p["VS1MAX"])), float(np.clip(pe, p["VS2MIN"], p["VS2MAX"]))
        return w - 1.0, pe

    def __call__(self, x, w, pe):
        """(vs, the derivatives of x)."""
        p = self.p
        u1, u2 = self.inputs(w, pe)
        wo = []   # washout i: s T/(1 + s T), state z: dz = (u - z)/T, y = u - z; T = 0 passes u

        def washout(u, z, t):
            if t == 0.0:
                wo.append(0.0)
                return u
            wo.append((u - z) / t)
            return u - z

        def lag(u, z, k, t):
            return (k * u, 0.0) if t == 0.0 else (z, (k * u - z) / t)

        a = washout(u1, x[0], p["TW1"])
        a = washout(a, x[1], 0.0 if self.drop_tw2 else p["TW2"])
        v1, d2 = lag(a, x[2], 1.0, p["T6"])
        b = washout(u2, x[3], p["TW3"])
        b = washout(b, x[4], p["TW4"])
        v2, d5 = lag(b, x[5], p["KS2"], p["T7"])
        r = x[6:6 + self.nr]
        f_in = v1 + p["KS3"] * v2
        dr = self.A @ r + self.B[:, 0] * f_in
        f_out = float(self.C[0] @ r + self.D[0, 0] * f_in)
        y = p["KS1"] * (f_out - v2)
        lls = [("T1", "T2"), ("T3", "T4")] + ([("T10", "T11")] if self.b else [])
        dll = []
        for j, (lead, lagc) in enumerate(lls):
            z = x[6 + self.nr + j]
            dll.append((y - z) / p[lagc])
            y = z + p[lead] / p[lagc] * (y - z)
        dll += [0.0] * (3 - len(lls))
        vs = min(max(y, p.get("VSTMIN", -0.1)), p.get("VSTMAX", 0.1))
        return vs, np.concatenate([[wo[0], wo[1], d2, wo[2], wo[3], d5], dr, dll])


# ---------------------------------------------------------------------- the on-line record

@dataclass(frozen=True)
class OnlineStep:
    """A reference step of `amplitude_pu` at `step_s` (any instant, between samples as real
    records have it) into `exciter` (SEXS or ESST1A, PSS/E's names) on the machine `g` through XE,
    from the operating point P0, Q0, Vt0, with the stabiliser `pss` (a `Pss2` dict: MODEL PSS2A or
    PSS2B and its values) or none."""
    exciter: str
    values: dict
    pss: dict | None
    g: dict = field(default_factory=lambda: dict(GEN))
    xe: float = 0.4
    p0: float = 0.8
    q0: float = 0.2
    vt0: float = 1.0
    step_s: float = 1.0
    amplitude_pu: float = 0.02


@dataclass(frozen=True)
class OnlineRecorder:
    """The recorder: uniform samples at `rate_hz` over `duration_s`; seeded Gaussian noise on each
    channel (efd 0.01 pu; Vt 0.0005 pu, Q and P 0.002 pu: the on-line captures' of the tests; the
    stabiliser's output 5e-5 pu, the AVR's own signal on an analogue output), then an ADC of `bits`
    over +-`range_efd_pu` (efd), +-`range_pu` (Vt, P, Q, each a transducer on its own range) or
    +-`range_vs_pu` (vs: twice a PSS's usual output limit). The setpoint is recorded exactly (the
    regulator's digital value)."""
    rate_hz: float = 1000.0
    duration_s: float = 10.0
    noise_efd_pu: float = 0.01
    noise_vt_pu: float = 0.0005
    noise_pq_pu: float = 0.002
    bits: int = 12
    range_efd_pu: float = 10.0
    range_pu: float = 2.0
    noise_vs_pu: float = 5e-5
    range_vs_pu: float = 0.2

    def quantise(self, x: np.ndarray, range_pu: float) -> np.ndarray:
        if self.bits <= 0:
            return x
        lsb = 2.0 * range_pu / 2 ** self.bits
        return np.round(x / lsb) * lsb


def solve_online(case: OnlineStep, t: np.ndarray, *, rtol: float = 1e-8) -> dict[str, np.ndarray]:
    """efd, Vt, P, Q, the stabiliser's output vs and the speed deviation at the instants `t`,
    solved by solve_ivp (RK45) in two pieces split exactly at the step; the values at `t` read
    from the solver's dense output."""
    from scipy.integrate import solve_ivp

    mach = Machine(case.xe, g=case.g)
    e1q, e2d, e1d, e2q, delta, efd0, vinf = mach.steady_state(case.p0, case.q0, case.vt0)
    x0, exc, ka = exciter(case.exciter, case.values, case.vt0, efd0)
    ne = len(x0)
    stab = Pss2(case.pss, case.p0) if case.pss else None
    xs0 = stab.x0 if stab else np.zeros(0)
    vref0 = case.vt0 + efd0 / ka

    def parts(z):
        m, x, xs = z[:6], z[6:6 + ne], z[6 + ne:]
        vt, ifd, _cid, _ciq, pe, q, _xaq = mach.algebra(*m[:5], vinf)
        vs, dxs = stab(xs, m[5], pe) if stab else (0.0, np.zeros(0))
        return m, x, vt, ifd, pe, q, vs, dxs

    def f(_t, z, vref):
        m, x, vt, ifd, _pe, _q, vs, dxs = parts(z)
        dx, efd = exc(x, vt, ifd, vref + vs)
        return np.concatenate([mach.derivatives(m, efd, vinf), dx, dxs])

    z = np.concatenate([[e1q, e2d, e1d, e2q, delta, 1.0], x0, xs0])
    cuts = [0.0, case.step_s, float(t[-1]) + 1e-9]
    out = np.empty((6, t.size))
    for j, vref in enumerate((vref0, vref0 + case.amplitude_pu)):
        sol = solve_ivp(f, (cuts[j], cuts[j + 1]), z, args=(vref,), method="RK45", rtol=rtol, atol=rtol * 1e-2,
                        max_step=0.01, dense_output=True)
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed on {case}: {sol.message}")
        here = np.flatnonzero((t >= cuts[j]) & (t < cuts[j + 1])) if j else np.flatnonzero(t < cuts[1])
        Y = sol.sol(t[here]) if here.size else np.zeros((z.size, 0))
        for k, col in zip(here, Y.T):
            m, x, vt, ifd, pe, q, vs, _dxs = parts(col)
            out[:, k] = [exc(x, vt, ifd, vref + vs)[1], vt, pe, q, vs, m[5] - 1.0]
        z = sol.y[:, -1]
    return dict(zip(("efd", "vt", "p", "q", "vs", "dw"), out))


def online_record(case: OnlineStep, recorder: OnlineRecorder = OnlineRecorder(), seed: int = 0) -> dict:
    """The record a recorder makes of `case`: columns time, usetp (Vt0 before the step, Vt0 plus
    the amplitude from the first sample at or after it), efd, vt, p, q and the stabiliser's output
    vs with the recorder's noise (efd's drawn first, then vt, q, p, vs: a record without vs has the
    same noise) and quantisation; `truth` holds the clean signals and the noise actually in efd
    and vs (their mean squares over the record)."""
    n = int(round(recorder.duration_s * recorder.rate_hz)) + 1
    t = np.arange(n) / recorder.rate_hz
    clean = solve_online(case, t)
    rng = np.random.default_rng(seed)
    efd = recorder.quantise(clean["efd"] + rng.normal(0.0, recorder.noise_efd_pu, n), recorder.range_efd_pu)
    noisy = {"efd": efd}
    for name, sd in (("vt", recorder.noise_vt_pu), ("q", recorder.noise_pq_pu), ("p", recorder.noise_pq_pu)):
        noisy[name] = recorder.quantise(clean[name] + rng.normal(0.0, sd, n), recorder.range_pu)
    noisy["vs"] = recorder.quantise(clean["vs"] + rng.normal(0.0, recorder.noise_vs_pu, n), recorder.range_vs_pu)
    usetp = case.vt0 + np.where(t >= case.step_s, case.amplitude_pu, 0.0)
    return {"time": t, "usetp": usetp, **noisy,
            "truth": {"clean": clean, "noise_efd_var": float(np.mean((efd - clean["efd"]) ** 2)),
                      "noise_vs_var": float(np.mean((noisy["vs"] - clean["vs"]) ** 2))}}
