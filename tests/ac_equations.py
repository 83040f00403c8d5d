"""The AC exciters' algebra written apart from the kernel, for the tests that solve their
equations with solve_ivp (tests/model/test_exac1.py, test_ac8b.py, test_structures.py)."""
from __future__ import annotations

import numpy as np

from bench_ctl.engine.simulate import simulate
from bench_ctl.units.overrides import apply_overrides, with_model
from bench_ctl.units.unit import reference_unit

#: the generator's saturation of these tests, S(1.0), S(1.2)
S10, S12 = 0.05, 0.24


def fex(i_n: float) -> float:
    """IEEE 421.5 rectifier regulation FEX(IN)."""
    if i_n <= 0.0:
        return 1.0
    if i_n <= 0.433:
        return 1.0 - 0.577 * i_n
    if i_n <= 0.75:
        return float(np.sqrt(0.75 - i_n * i_n))
    if i_n <= 1.0:
        return 1.732 * (1.0 - i_n)
    return 0.0


def quad(x1: float, y1: float, x2: float, y2: float):
    """B (x - A)^2 through (x1, y1) and (x2, y2), 0 below A."""
    r = np.sqrt(y2 / y1)
    a = (r * x1 - x2) / (r - 1.0)
    b = y1 / (x1 - a) ** 2
    return lambda x: b * max(x - a, 0.0) ** 2


def kernel_pulse(model: str, overrides: list[str], amp: float, width: float, *, dt: float = 5e-4,
                 n: int = 6000):
    """`model` on the reference generator with saturation (S10, S12) and `overrides`, a pulse of
    `amp` from 0.5 s lasting `width` run by the kernel: (its standard values with T'd0, T''d0,
    efd, the failed step)."""
    unit = with_model(apply_overrides(reference_unit(), [f"S10={S10}", f"S12={S12}"]), model)
    unit = apply_overrides(unit, overrides)
    s = unit.structure.std_values(unit.values(), unit.model_values)
    s.update({"Td0p": unit.values()["Td0p"], "Td0pp": unit.values()["Td0pp"]})
    usetp = np.ones(n)
    k0 = int(round(0.5 / dt))
    usetp[k0:k0 + int(round(width / dt))] += amp
    efd, _, fail = simulate(unit.values(), usetp, dt)
    return s, efd, fail


def ac_steady_state(kc: float, ke: float, kd: float, sat, se) -> tuple[float, float, float]:
    """The AC exciter at no load and Vt = 1: (Ifd, VE, VFE) with VE FEX(KC Ifd / VE) = Ifd =
    1 + Sat(1) (VE by bisection) and VFE = KE VE + SE(VE) VE + KD Ifd; `sat`, `se` the generator's
    and the exciter's saturation curves."""
    ifd0 = 1.0 + sat(1.0)
    lo, hi = ifd0, ifd0 + 2 * kc * ifd0 + 1.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if mid * fex(kc * ifd0 / mid) < ifd0 else (lo, mid)
    ve0 = 0.5 * (lo + hi)
    return ifd0, ve0, ke * ve0 + se(ve0) + kd * ifd0
