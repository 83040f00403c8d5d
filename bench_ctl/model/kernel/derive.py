"""Per-candidate factors of the kernel (the derived matrix, columns `layout.D_*`), once a call:
which candidates are valid, each block's factors (`blocks.derive_*`, beside the block's compiled
algebra), the effects outside the blocks, then the steady state the run starts from. Array code,
compiled by numba without fast-math (the numbers numpy gives, at a tenth of its time for a few
candidates).

An invalid candidate (a parameter outside what the kernel can run) gets harmless factors and
D_VALID = 0: the kernel marks it failed at step 0.
"""
from __future__ import annotations

import math

import numpy as np
from numba import types
from numba.typed import Dict

from ..params import KERNEL_PARAMS, RECORD_PARAMS
from .blocks import (
    Params,
    bridge_voltage_np,
    derive_ceilings,
    derive_dc_exciter,
    derive_generator,
    derive_potential_source,
    derive_rate_feedback,
    derive_regulator,
)
from .jit import njit
from .layout import (
    D_DCON,
    D_E0,
    D_EDGE0,
    D_EFD0,
    D_GAIN,
    D_ITR,
    D_KAVR,
    D_KC,
    D_KCAC,
    D_KCIN,
    D_KD,
    D_KE,
    D_OUT0,
    D_OUTK,
    D_PID,
    D_RAMP,
    D_RATE,
    D_SEA,
    D_SEB,
    D_SKEW,
    D_TD,
    D_TDON,
    D_TRON,
    D_UREF0,
    D_VALID,
    D_VR0,
    D_VRVT,
    D_X20,
    D_XE0,
    D_XF0,
    N_DERIVED,
)


def derive(P: np.ndarray, field0: np.ndarray | None = None) -> np.ndarray:
    """Per-candidate factors for the kernel from the parameter matrix (n, len(KERNEL_PARAMS)).
    `field0`: the field voltage (and field current, XadIfd) of the steady state where the generator
    is not at no load (the on-line machine, `bench_ctl.model.online`); else the no-load one."""
    P = np.atleast_2d(np.asarray(P, dtype=np.float64))
    if P.shape[1] != len(KERNEL_PARAMS):
        raise ValueError(f"parameter matrix has {P.shape[1]} columns, expected {len(KERNEL_PARAMS)}")
    n = P.shape[0]
    given = field0 is not None
    # (a copy: a broadcast view is read-only, and numba would compile another `_derive` for it)
    fld = np.array(np.broadcast_to(np.asarray(field0, np.float64), (n,))) if given else np.zeros(n)
    return _derive(np.ascontiguousarray(P.T), fld, given)


#: the parameter matrix's column names, as the compiled derivation reads them
_NAMES = tuple(KERNEL_PARAMS)


@njit(inline=False, fastmath=False, nogil=True)
def _derive(PT: np.ndarray, field0: np.ndarray, given: bool) -> np.ndarray:
    """`derive` of the transposed parameter matrix PT, compiled: a call of a few candidates is
    some 200 array operations, which numpy ran at about a microsecond each (0.22 ms, a fifth of
    a kernel call of one candidate on a 10 s record); numba's IEEE arithmetic (no fast-math)
    gives the same numbers."""
    g = Dict.empty(key_type=types.unicode_type, value_type=types.float64[::1])
    for q in range(len(_NAMES)):
        g[_NAMES[q]] = PT[q]
    D = np.zeros((PT.shape[1], N_DERIVED))
    valid = _valid(PT, g)
    D[:, D_VALID] = valid.astype(np.float64)
    vt0, fld0 = derive_generator(D, g, valid)
    if given:
        fld0 = field0
    dc, ac = derive_dc_exciter(D, g, valid)
    st4 = derive_potential_source(D, g, valid, dc)
    pi = derive_regulator(D, g, valid, st4)
    derive_rate_feedback(D, g, valid)
    vrin = derive_ceilings(D, g, valid, dc, st4, ac)
    _effects(D, g, valid)
    _steady_state(D, g, valid, dc, ac, st4, pi, vrin, vt0, fld0)
    return D


#: parameters the kernel needs finite and positive, finite and not negative, finite (`_valid`)
_POSITIVE = tuple(KERNEL_PARAMS.index(n) for n in ("KAVR", "TA2", "TA4", "TE", "Td0p", "Td0pp"))
_NOT_NEGATIVE = tuple(KERNEL_PARAMS.index(n) for n in (
    "TA1", "TA3", "TR", "TD", "SKEW", "Vt0", "S10", "S12", "KC", "KF", "KDR", "TEX", "KD", "KDA", "KPV",
    "KPI", "KII", "KPM", "KIM", "KG"))
_FINITE = tuple(KERNEL_PARAMS.index(n) for n in ("GAIN", "KE", "ACEX", *RECORD_PARAMS))


@njit(inline=False, fastmath=False)
def _valid(PT: np.ndarray, g: Params) -> np.ndarray:
    """The candidates the kernel can run: time constants, gains and limits in their domain."""
    valid = np.ones(PT.shape[1], np.bool_)
    for i in range(PT.shape[1]):
        for q in _POSITIVE:
            valid[i] &= math.isfinite(PT[q, i]) and PT[q, i] > 0.0
        for q in _NOT_NEGATIVE:
            valid[i] &= math.isfinite(PT[q, i]) and PT[q, i] >= 0.0
        for q in _FINITE:
            valid[i] &= math.isfinite(PT[q, i])
    valid &= (g["RATE"] > 0.0) & (g["RAMP"] > 0.0)
    valid &= g["VRMAX"] > g["VRMIN"]
    valid &= (g["VRVT"] >= 0.0) & (g["VRVT"] <= 1.0)
    valid &= (g["KF"] == 0.0) | (g["TF"] > 0.0)
    valid &= (g["KDR"] == 0.0) | (g["TDR"] > 0.0)
    valid &= (g["KPP"] >= 0.0) & (g["KPP"] <= 1.0) & (g["VBMAX"] > 0.0)
    valid &= (g["VPMAX"] > g["VPMIN"]) & (g["VMMAX"] > g["VMMIN"])
    return valid


@njit(inline=False, fastmath=False)
def _effects(D: np.ndarray, g: Params, valid: np.ndarray) -> None:
    """The transducer lag, dead time, slew limit, setpoint ramp, recorder gain and skew, the
    setpoint edges' offsets."""
    D[:, D_ITR] = np.where(valid & (g["TR"] > 0.0), 1.0 / np.where(g["TR"] > 0, g["TR"], 1.0), 0.0)
    D[:, D_TRON] = (D[:, D_ITR] > 0.0).astype(np.float64)
    D[:, D_TD] = np.where(valid, g["TD"], 0.0)
    D[:, D_TDON] = (D[:, D_TD] > 0.0).astype(np.float64)
    D[:, D_RATE] = g["RATE"]
    D[:, D_RAMP] = g["RAMP"]
    D[:, D_GAIN] = np.where(valid, g["GAIN"], 1.0)
    D[:, D_SKEW] = np.where(valid, g["SKEW"], 0.0)
    for slot in range(len(RECORD_PARAMS)):
        D[:, D_EDGE0 + slot] = np.where(valid, g[RECORD_PARAMS[slot]], 0.0)


@njit(inline=False, fastmath=False)
def _ac_exciter_ve(fld0: np.ndarray, kc_ifd: np.ndarray) -> np.ndarray:
    """The AC exciter's VE at which VE FEX(KC Ifd / VE) gives the field voltage fld0 (Ifd = fld0
    at no load). On each piece of FEX the equation has a closed form in VE, with c = KC Ifd:
    VE - 0.577 c (IN = c / VE <= 0.433), sqrt(0.75 VE^2 - c^2) (up to 0.75), 1.732 (VE - c) (up to
    1). VE FEX is increasing in VE, so the answer is the piece's root whose IN lies in that piece.
    Where rounding at a piece's end leaves none (or fld0 is not above 1e-6), the bisection (what
    every row took before: 60 numpy steps, 0.48 s of a structure selection)."""
    c = np.maximum(kc_ifd, 0.0)
    roots = (fld0 + 0.577 * c, np.sqrt((fld0 * fld0 + c * c) / 0.75), fld0 / 1.732 + c)
    ends = (-np.inf, 0.433, 0.75, 1.0)
    ve = np.full(fld0.shape[0], np.nan)
    for j in range(3):
        x = c / roots[j]
        ve = np.where(np.isnan(ve) & (fld0 > 1.0e-6) & (x > ends[j]) & (x <= ends[j + 1]), roots[j], ve)
    left = np.isnan(ve)
    if np.any(left):
        ve[left] = _bisect_ve(fld0[left], kc_ifd[left])
    return ve


@njit(inline=False, fastmath=False)
def _bisect_ve(fld0: np.ndarray, kc_ifd: np.ndarray) -> np.ndarray:
    """`_ac_exciter_ve` by bisection between fld0 and fld0 + 2 KC Ifd + 1."""
    lo = np.maximum(fld0, 1.0e-6)
    hi = lo + 2.0 * np.abs(kc_ifd) + 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        low = bridge_voltage_np(mid, kc_ifd, np.inf) < fld0
        lo = np.where(low, mid, lo)
        hi = np.where(low, hi, mid)
    return 0.5 * (lo + hi)


@njit(inline=False, fastmath=False)
def _steady_state(D: np.ndarray, g: Params, valid: np.ndarray, dc: np.ndarray, ac: np.ndarray, st4: np.ndarray,
                  pi: np.ndarray, vrin: np.ndarray, vt0: np.ndarray, fld0: np.ndarray) -> None:
    """The steady state at Vt0 the run starts from (`blocks.steady_state`): the regulator lag's
    output, the lead-lags' states, the reference, the output, the rate feedback's state. A DC
    exciter needs VR = (KE + SE(Efd)) Efd from the regulator, an AC one VR = VFE = KE VE +
    SE(VE) + KD Ifd with VE FEX(KC Ifd / VE) = Efd, a static one Efd itself; the
    potential-source stage Efd = VB VM, its regulator's error 0 and its PI and lag at KG Efd, the
    inner integrator at Efd / VB (as ANDES initialises it). A PI regulator (ESST4B's, AC8B's PID)
    has its error at 0 and its integrator at the output; the PID's derivative filter at 0. The ST5B
    regulator's output is Efd + KC Ifd (within [VRMIN, VRMAX])."""
    # the rotating exciter's state: its Efd (DC) or VE (AC: Efd = VE FEX(KC Ifd / VE), solved for
    # the AC exciter's rows only)
    xe0 = fld0.copy()
    if np.any(ac):
        xe0[ac] = _ac_exciter_ve(fld0[ac], D[:, D_KCAC][ac] * fld0[ac])
    efd0 = np.where(dc, D[:, D_KE] * xe0 + D[:, D_SEB] * np.maximum(xe0 - D[:, D_SEA], 0.0) ** 2
                    + D[:, D_KD] * fld0, fld0)
    vb0 = bridge_voltage_np(np.where(st4, g["KPV"], 1.0) * vt0, np.where(valid, g["KC"], 0.0) * fld0, g["VBMAX"])
    efd0 = np.where(st4, np.where(st4, g["KG"], 0.0) * fld0, efd0)
    # Ifd = E'q + Sat(E'q) = efd0, the limits at Vt0
    scale0 = 1.0 + D[:, D_VRVT] * (vt0 - 1.0)
    hi0 = g["VRMAX"] * scale0 - D[:, D_KC] * efd0
    lo0 = g["VRMIN"] * scale0
    D[:, D_EFD0] = np.clip(efd0, lo0, np.maximum(hi0, lo0))
    vr0 = np.where(vrin, np.clip(D[:, D_EFD0] + D[:, D_KCIN] * fld0, g["VRMIN"], g["VRMAX"]), D[:, D_EFD0])
    D[:, D_VR0] = vr0
    D[:, D_E0] = vr0 / D[:, D_KAVR]
    D[:, D_X20] = np.where(D[:, D_PID] > 0.0, 0.0, D[:, D_E0])
    D[:, D_UREF0] = vt0 + np.where(pi, 0.0, D[:, D_E0])
    # the output: the DC exciter's Efd, VB VM of the potential source, else the regulator output
    D[:, D_OUT0] = np.where(st4, fld0, np.where(dc, fld0, D[:, D_EFD0]))
    D[:, D_XE0] = np.where(dc, xe0, D[:, D_OUT0])
    D[:, D_OUTK] = np.where(ac, fld0 / np.where(ac, xe0, 1.0), 1.0)
    # the rate feedback's source: the regulator output, the DC exciter's Efd, the AC exciter's VFE
    # (= the regulator output at the steady state)
    src0 = np.where(ac, D[:, D_EFD0], D[:, D_EFD0] + D[:, D_DCON] * (D[:, D_OUT0] - D[:, D_EFD0]))
    D[:, D_XF0] = np.where(st4, fld0 / np.where(st4, vb0, 1.0), src0)
