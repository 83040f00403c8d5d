"""AC8B and ESAC1A (issue 26, item 4): the PID regulator on the kernel - proportional, integral
with tracking anti-windup inside its limits, a filtered derivative - ahead of the regulator lag and
the AC exciter, against solve_ivp on its equations written here apart from the kernel; ESAC1A as
EXAC1 with its VA limits; both records read from a .dyr and written back."""
from __future__ import annotations

import numpy as np
import pytest

from ac_equations import S10, S12, ac_steady_state, kernel_pulse
from ac_equations import fex as _fex
from ac_equations import quad as _quad
from bench_ctl.engine.simulate import simulate
from bench_ctl.units.dyr import DyrRecord, dyr_text, read_dyr
from bench_ctl.units.dyr_unit import unit_from_dyr
from bench_ctl.units.overrides import apply_overrides, with_model
from bench_ctl.units.unit import reference_unit

TRACK = 2.0   # ANDES' PITrackAW tracking gain ks (its AC8B's default)


def _ac8b(s: dict[str, float], amp: float, width: float, n: int, dt: float, s10: float, s12: float):
    """efd and the PID's output of AC8B on the reference generator at no load (Vt = E''q,
    saturation on E'q, Ifd = E'q + Sat) by solve_ivp, in the standard's names: e = Vref - Vc,
    ys = KPR e + xi + KDR/TDR (e - xd), y = ys within [VPIDMIN, VPIDMAX], xi' = KIR (e - ks (ys - y)),
    TDR xd' = e - xd, TA VR' = KA y - VR (held at VRMIN, VRMAX), TE VE' = VR - VFE,
    VFE = KE VE + SE(VE) VE + KD Ifd, Efd = VE FEX(KC Ifd / VE). The pulse of `amp` starts at 0.5 s."""
    from ode_pieces import solve_pieces

    sat = _quad(1.0, s10, 1.2, s12) if s10 > 0 else (lambda x: 0.0)
    se = _quad(s["E1"], s["E1"] * s["SE1"], s["E2"], s["E2"] * s["SE2"])
    kp, ki, kd, tdr = s["KPR"], s["KIR"], s["KDR"], s["TDR"]
    ka, ta, te, ke, kdd, kc = (s[k] for k in ("KA", "TA", "TE", "KE", "KD", "KC"))
    vpmax, vpmin, vrmax, vrmin, tr = s["VPIDMAX"], s["VPIDMIN"], s["VRMAX"], s["VRMIN"], s["TR"]
    td0p, td0pp = s["Td0p"], s["Td0pp"]
    _ifd0, ve0, vfe0 = ac_steady_state(kc, ke, kdd, sat, se)

    def pid(e, xi, xd):
        ys = kp * e + xi + kd / tdr * (e - xd)
        return min(max(ys, vpmin), vpmax), ys

    def f(t, x):
        xm, xi, xd, vr, ve, eqp, eqpp = x
        vt = eqpp
        ifd = eqp + sat(eqp)
        vm = xm if tr > 0 else vt
        e = 1.0 + (amp if 0.5 <= t < 0.5 + width else 0.0) - vm
        y, ys = pid(e, xi, xd)
        dvr = (ka * y - vr) / ta
        if (vr >= vrmax and dvr > 0) or (vr <= vrmin and dvr < 0):
            dvr = 0.0
        vfe = ke * ve + se(ve) + kdd * ifd
        efd = ve * _fex(kc * ifd / ve)
        return [(vt - xm) / tr if tr > 0 else 0.0, ki * (e - TRACK * (ys - y)), (e - xd) / tdr, dvr,
                (vr - vfe) / te, (efd - ifd) / td0p, (eqp - eqpp) / td0pp]

    t = np.arange(n) * dt
    Y = solve_pieces(f, t, [1.0, vfe0 / ka, 0.0, vfe0, ve0, 1.0, 1.0], (0.5, 0.5 + width))
    eqp = Y[5]
    ifd = eqp + np.array([sat(v) for v in eqp])
    efd = np.array([ve * _fex(kc * i / ve) for ve, i in zip(Y[4], ifd)])
    e = 1.0 + np.where((t >= 0.5) & (t < 0.5 + width), amp, 0.0) - (Y[0] if tr > 0 else Y[6])
    y = np.array([pid(a, b, c)[0] for a, b, c in zip(e, Y[1], Y[2])])
    return efd, y, Y[3]


# The derivative (KDR / TDR = 100 at the typical values) makes a setpoint edge a spike of the PID's
# output, so the cases run at 0.5 ms, as EXAC1's: the kernel, like every fixed-step one, sees a
# limit at the step's end
@pytest.mark.parametrize("amp,width,overrides", [
    (0.05, 1.0, []),                                                       # typical values
    (0.1, 0.5, ["VPIDMAX=6", "VPIDMIN=-2", "KC=0.3", "KD=0.4", "TR=0.01"]),  # the PID at its limits
    (0.2, 0.6, ["VRMAX=8", "VRMIN=0.5", "KIR=20", "KDR=2", "TDR=0.05", "TA=0.05", "KA=2"]),   # VR at its limits
])
def test_ac8b_matches_its_equations_solved_by_solve_ivp(amp, width, overrides):
    dt, n = 5e-4, 6000
    s, efd, fail = kernel_pulse("AC8B", overrides, amp, width, dt=dt, n=n)
    assert fail < 0
    ref, y, vr = _ac8b(s, amp, width, n, dt, S10, S12)
    err = np.abs(efd - ref)
    assert err.max() < 1e-3, f"max |efd error| {err.max():.2e} pu at t = {np.argmax(err) * dt:.3f} s"
    assert efd.max() - efd[0] > 0.2           # it moved
    if "VPIDMAX=6" in overrides:
        assert y.max() >= 6.0 - 1e-6 and y.min() <= -2.0 + 1e-6   # the PID met both limits
    if "VRMAX=8" in overrides:
        assert vr.max() >= 8.0 - 1e-6 and vr.min() <= 0.5 + 1e-6  # VR met both limits
    # the check can fail: the same equations without the derivative
    other, _, _ = _ac8b({**s, "KDR": 1e-9}, amp, width, n, dt, S10, S12)
    assert np.abs(efd - other).max() > 0.01


def test_esac1a_runs_as_exac1_with_its_va_limits():
    """On the kernel ESAC1A is EXAC1 with VAMAX/VAMIN where EXAC1 has VRMAX/VRMIN (its VR clamp is
    the record's, as in ANDES): the same values give the same record to the last bit."""
    base = apply_overrides(reference_unit(), ["S10=0.05", "S12=0.24"])
    a = apply_overrides(with_model(base, "ESAC1A"), ["VAMAX=3", "VAMIN=0", "KD=0.5"])
    b = apply_overrides(with_model(base, "EXAC1"), ["VRMAX=3", "VRMIN=0", "KD=0.5", "E1=3.14", "SE1=0.03",
                                                      "E2=4.18", "SE2=0.1", "KC=0.2"])
    usetp = np.ones(4000)
    usetp[500:1500] += 0.2
    ea, _, fa = simulate(a.values(), usetp, 1e-3)
    eb, _, fb = simulate(b.values(), usetp, 1e-3)
    assert fa < 0 and fb < 0
    assert np.array_equal(ea, eb)
    assert ea.max() - ea[0] > 0.3
    c = apply_overrides(with_model(base, "ESAC1A"), ["VAMAX=20", "VAMIN=-20", "KD=0.5"])
    ec, _, _ = simulate(c.values(), usetp, 1e-3)
    assert np.abs(ec - ea).max() > 0.05       # the VA limits act


def test_ac8b_and_esac1a_records_read_into_a_unit_and_write_back(tmp_path):
    dyr = tmp_path / "unit.dyr"
    dyr.write_text("1 'GENROU' 1 6.0 0.05 0.4 0.05 3.0 0.0 1.8 1.7 0.3 0.55 0.25 0.2 0.05 0.2 /\n"
                   "1 'ESAC8B' 1 0.02 15 0.8 10 0.03 0.6 0.04 5 -4 0.4 1 5.7 0.1 7.6 0.4 /\n")
    unit = unit_from_dyr(reference_unit(), dyr)
    assert unit.model == "AC8B"
    v = unit.values()
    assert (v["KPI"], v["KII"], v["KDR"], v["TDR"], v["KAVR"], v["TE"], v["TEX"]) == (15, 0.8, 10, 0.03, 0.6,
                                                                                      0.04, 0.4)
    assert (v["VRMAX"], v["VRMIN"], v["ACEX"], v["KC"], v["KD"]) == (5, -4, 1.0, 0.0, 0.0)
    (rec,) = [r for r in read_dyr(dyr) if r.model == "ESAC8B"]
    again = tmp_path / "again.dyr"
    again.write_text(dyr_text([(DyrRecord(1, "ESAC8B", "1", dict(rec.values)), None)]))
    (back,) = read_dyr(again)
    assert back.values == rec.values
    # ESAC1A in PSS/E's order (TR TB TC KA TA VAMAX VAMIN TE KF TF KC KD KE E1 SE1 E2 SE2 VRMAX VRMIN)
    dyr.write_text("1 'GENROU' 1 6.0 0.05 0.4 0.05 3.0 0.0 1.8 1.7 0.3 0.55 0.25 0.2 0.05 0.2 /\n"
                   "1 'ESAC1A' 1 0 0 0 280.463 0.02 16.5957 -16.5957 1.0339 0.0162 1 0.2 1 1 1.5823 0.0919 "
                   "2.1097 0.827 9 -9 /\n")
    unit = unit_from_dyr(reference_unit(), dyr)
    assert unit.model == "ESAC1A"
    v = unit.values()
    assert (v["KAVR"], v["TE"], v["VRMAX"], v["TEX"], v["KF"], v["KC"], v["KD"]) == (280.463, 0.02, 16.5957,
                                                                                    1.0339, 0.0162, 0.2, 1.0)


def test_a_derivative_without_its_filter_is_not_a_candidate_the_engine_runs():
    """KDR > 0 needs TDR > 0 (as rate feedback KF needs TF): the engine marks such a row invalid
    rather than dividing by 0; without the derivative TDR is not looked at."""
    from bench_ctl.engine import derive
    from bench_ctl.engine.layout import D_VALID
    from bench_ctl.engine.simulate import param_matrix
    from bench_ctl.model.params import COL

    unit = with_model(reference_unit(), "AC8B")
    P = np.repeat(param_matrix(unit.values()), 3, axis=0)
    P[1, COL["TDR"]] = 0.0
    P[2, [COL["TDR"], COL["KDR"]]] = 0.0
    assert derive(P)[:, D_VALID].tolist() == [1.0, 0.0, 1.0]
