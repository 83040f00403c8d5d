"""ESST5B and GENSAL (issue 26): the ST5B regulator on the kernel, on a GENROU-like and a GENSAL
generator (saturation on E'q), against solve_ivp on their equations written here apart from the
kernel (with KC = 0.3 the commutation drop at the lag's input changes the
linear response, so its place is checked), and its .dyr record read into a unit."""
from __future__ import annotations

import numpy as np
import pytest

from bench_ctl.engine.simulate import simulate
from bench_ctl.model.structures import structure
from bench_ctl.units.dyr import read_dyr
from bench_ctl.units.dyr_unit import unit_from_dyr
from bench_ctl.units.overrides import apply_overrides, with_model
from bench_ctl.units.unit import reference_unit

# the Mostar unit's voltage channel as its OpenIPSL study fitted it (Data/Step5/init.mo in
# ALSETLab/Mostar; numbers only), with its T'd0
MOSTAR = ["TC1=1.071137", "TB1=10.7561", "TC2=3.414283", "TB2=1.701033", "KR=358.6086", "T1=0.004361481",
          "KC=0.3", "VRMAX=10", "VRMIN=-10", "TR=0.02"]


def _reference(v: dict[str, float], amp: float, n: int, dt: float, kpp: float, kda: float,
               s10: float, s12: float, gensal: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """efd of ST5B on a GENROU-like generator at no load by solve_ivp (a GENSAL: saturation on E'q
    rather than on psi'' = Vt): the lead-lags' outputs
    limited (the first to [VRMIN, VRMAX]/KR; their states free), VR = KR y2 limited to [VRMIN,
    VRMAX], the firing lag driven by VR - KC Ifd and held (non-windup) at Vt VRMIN, Vt VRMAX.
    Returns (efd, KR y1 unlimited, KR y2 unlimited) for the hit counts."""
    from ode_pieces import solve_pieces

    r = np.sqrt(s12 / s10)
    a_ = (r - 1.2) / (r - 1.0)
    b_ = s10 / (1.0 - a_) ** 2
    sat = lambda x: b_ * max(x - a_, 0.0) ** 2  # noqa: E731
    clamp = lambda x, lo, hi: min(max(x, lo), hi)  # noqa: E731
    kr, tc1, tb1, tc2, tb2 = v["KAVR"], v["TA1"], v["TA2"], v["TA3"], v["TA4"]
    vrmax, vrmin, kc, t1, tr, td0p, td0pp = v["VRMAX"], v["VRMIN"], v["KC"], v["TE"], v["TR"], v["Td0p"], v["Td0pp"]

    fld0 = 1.0 + sat(1.0)
    e0 = fld0 * (1.0 + kc) / kr

    def parts(t, x):
        xm, x1, x2, ef, eqp, eqpp = x
        vt = eqpp + kpp * (eqp - eqpp)
        ifd = eqp + kda * (eqp - eqpp) + sat(eqp if gensal else vt)
        e = 1.0 + e0 + (amp if 0.5 <= t < 1.5 else 0.0) - xm     # the reference holds the steady state
        y1s = x1 + tc1 / tb1 * (e - x1)
        y1 = clamp(y1s, vrmin / kr, vrmax / kr)
        y2 = x2 + tc2 / tb2 * (y1 - x2)
        vr = clamp(kr * y2, vrmin, vrmax) - kc * ifd
        fld = ifd                                     # T'd0 dE'q/dt = Efd - Ifd
        return vt, ifd, e, y1, y2, vr, fld, y1s

    def f(t, x):
        xm, x1, x2, ef, eqp, eqpp = x
        vt, ifd, e, y1, y2, vr, fld, _ = parts(t, x)
        deqp = (ef - fld) / td0p
        deqpp = (eqp - eqpp) / td0pp
        dvt = deqpp + kpp * (deqp - deqpp)
        de = (vr - ef) / t1
        if ef >= vt * vrmax and de > vrmax * dvt:
            de = vrmax * dvt
        if ef <= vt * vrmin and de < vrmin * dvt:
            de = vrmin * dvt
        return [(vt - xm) / tr, (e - x1) / tb1, (y1 - x2) / tb2, de, deqp, deqpp]

    t = np.arange(n) * dt
    Y = solve_pieces(f, t, [1.0, e0, e0, fld0, 1.0, 1.0], (0.5, 1.5))
    vt = Y[5] + kpp * (Y[4] - Y[5])
    efd = np.clip(Y[3], vt * vrmin, vt * vrmax)
    y = [parts(t[k], Y[:, k]) for k in range(n)]
    return efd, kr * np.array([p[7] for p in y]), kr * np.array([p[4] for p in y])


@pytest.mark.parametrize("amp,overrides,hits,gensal", [
    (0.05, ["VRMAX=20", "VRMIN=-20"], False, False),           # linear, typical values
    (0.2, ["VRMAX=2.5", "VRMIN=-1.5", "KC=0.15"], True, False),  # the limiter ahead of the firing lag
    (0.1, MOSTAR, False, True),                                # the Mostar unit's values (KC 0.3) on a GENSAL
    (0.2, ["VRMAX=2.5", "VRMIN=-3", "KC=0.15"], True, True),  # floor not reached (LSODA stalls there)
])
def test_esst5b_matches_solve_ivp(amp, overrides, hits, gensal):
    u = apply_overrides(with_model(reference_unit(), "ESST5B"),
                        ["KPP=0.6", "KDA=0.5", "Td0p=3.77", "Td0pp=0.05", "TR=0.02", f"SATEQ={int(gensal)}",
                         *overrides])
    v = u.with_effects({"saturation": {"S10": 0.1, "S12": 0.4}}).values()
    assert v["VRIN"] == 1.0 and v["VRVT"] == 1.0 and v["LIMOUT"] == 0.0
    dt, n = 1e-3, 4000
    usetp = np.ones(n)
    usetp[500:1500] = 1.0 + amp
    efd, _, fail = simulate(v, usetp, dt)
    assert fail == -1
    ref, vr1, vr2 = _reference(v, amp, n, dt, 0.6, 0.5, 0.1, 0.4, gensal)
    assert abs(efd[0] - ref[0]) < 1e-9 and abs(efd[499] - ref[0]) < 1e-6     # the steady state holds
    assert np.max(np.abs(efd - ref)) < 1e-3, np.max(np.abs(efd - ref))
    # the limits act where the case says (checked on the reference solution)
    over = (np.sum(vr2 > v["VRMAX"]) + np.sum(vr2 < v["VRMIN"]), np.sum(vr1 > v["VRMAX"]) + np.sum(vr1 < v["VRMIN"]))
    assert (min(over) > 10) == hits, over


def test_esst5b_record_reads_into_a_unit(tmp_path):
    path = tmp_path / "mostar.dyr"
    path.write_text("1 'GENSAL' 1 3.77 0.0552 0.0823 2.137 0 1.183 0.62 0.371 0.215 0.1 0.1 0.4 /\n"
                    "1 'ESST5B' 1 0.5 358.6086 0.004361481 0.3 10 -10 1.071137 10.7561 3.414283 1.701033"
                    " 1 1 1 1 1 1 1 1 /\n")
    rec = read_dyr(path)[1]
    assert rec.values["KR"] == 358.6086 and rec.values["TB2"] == 1.701033 and rec.values["TUB2"] == 1.0
    u = unit_from_dyr(reference_unit(), path)
    assert u.model == "ESST5B"
    v = u.values()
    assert (v["KAVR"], v["TE"], v["TA1"], v["TA2"], v["TA3"], v["TA4"]) == (
        358.6086, 0.004361481, 1.071137, 10.7561, 3.414283, 1.701033)
    assert (v["KC"], v["VRMAX"], v["VRMIN"], v["TR"], v["VRIN"]) == (0.3, 10.0, -10.0, 0.5, 1.0)
    assert v["Td0p"] == 3.77 and v["SATEQ"] == 1.0 and structure("esst5b").name == "ESST5B"
    # a GENROU record saturates on psi'': SATEQ 0
    path.write_text(path.read_text().replace("'GENSAL' 1 3.77 0.0552 0.0823", "'GENROU' 1 3.77 0.0552 0.5 0.0823")
                    .replace("0.62 0.371", "0.62 0.371 0.5"))
    assert unit_from_dyr(reference_unit(), path).values()["SATEQ"] == 0.0
