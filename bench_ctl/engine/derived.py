"""Per-candidate factors of the engine (the derived matrix, columns `layout.D_*`) from a parameter
matrix: which candidates are valid, each block's factors, the effects, the steady state a run
starts from and what the candidate needs of the engine (D_BITS). One compiled loop over the
candidates, scalar arithmetic without fast-math (IEEE, the numbers numpy gave); the machine on the
grid adds its own columns (`machines.grid.derive_grid`).

An invalid candidate (a parameter outside what the engine can run) gets harmless factors and
D_VALID = 0: the engine marks it failed at step 0.
"""
from __future__ import annotations

import math

import numpy as np

from bench_ctl.model.params import KERNEL_PARAMS, RECORD_PARAMS

from .jit import njit
from .layout import (
    B_DELAY,
    B_FLUX,
    B_FULL,
    B_LIMITED,
    B_RAMP,
    B_SKEW,
    B_ST4,
    B_ST4_ONLY,
    D_ACON,
    D_BITS,
    D_DCON,
    D_E0,
    D_EDGE0,
    D_EFD0,
    D_GAIN,
    D_IT2,
    D_IT4,
    D_ITD0P,
    D_ITD0PP,
    D_ITE,
    D_ITEX,
    D_ITF,
    D_ITR,
    D_KAVR,
    D_KC,
    D_KCAC,
    D_KCIN,
    D_KD,
    D_KDA,
    D_KDT,
    D_KE,
    D_KFT,
    D_KG,
    D_KI1,
    D_KIM,
    D_KPM,
    D_KPP,
    D_KPV,
    D_LIMOUT,
    D_OUT0,
    D_OUTK,
    D_P1,
    D_PID,
    D_R1,
    D_R2,
    D_RAMP,
    D_RATE,
    D_SATA,
    D_SATB,
    D_SATVT,
    D_SEA,
    D_SEB,
    D_SKEW,
    D_ST4,
    D_TD,
    D_TDON,
    D_TRON,
    D_UREF0,
    D_VALID,
    D_VBMAX,
    D_VMMAX,
    D_VMMIN,
    D_VR0,
    D_VRIN,
    D_VRMAX,
    D_VRMIN,
    D_VRVT,
    D_VT0,
    D_X20,
    D_XE0,
    D_XF0,
    D_Y1MAX,
    D_Y1MIN,
    N_DERIVED,
    P_ACEX,
    P_E1,
    P_E2,
    P_EDGE1,
    P_GAIN,
    P_KAVR,
    P_KC,
    P_KD,
    P_KDA,
    P_KDR,
    P_KE,
    P_KF,
    P_KG,
    P_KII,
    P_KIM,
    P_KPI,
    P_KPM,
    P_KPP,
    P_KPV,
    P_LIMOUT,
    P_RAMP,
    P_RATE,
    P_S10,
    P_S12,
    P_SATEQ,
    P_SE1,
    P_SE2,
    P_SKEW,
    P_TA1,
    P_TA2,
    P_TA3,
    P_TA4,
    P_TD,
    P_TDR,
    P_TE,
    P_TEX,
    P_TF,
    P_TR,
    P_VBMAX,
    P_VMMAX,
    P_VMMIN,
    P_VPMAX,
    P_VPMIN,
    P_VRIN,
    P_VRMAX,
    P_VRMIN,
    P_VRVT,
    P_Td0p,
    P_Td0pp,
    P_Vt0,
)

INF = math.inf

#: parameters the engine needs finite and positive, finite and not negative, finite (`_valid`)
_POSITIVE = tuple(KERNEL_PARAMS.index(n) for n in ("KAVR", "TA2", "TA4", "TE", "Td0p", "Td0pp"))
_NOT_NEGATIVE = tuple(KERNEL_PARAMS.index(n) for n in (
    "TA1", "TA3", "TR", "TD", "SKEW", "Vt0", "S10", "S12", "KC", "KF", "KDR", "TEX", "KD", "KDA", "KPV",
    "KPI", "KII", "KPM", "KIM", "KG"))
_FINITE = tuple(KERNEL_PARAMS.index(n) for n in ("GAIN", "KE", "ACEX", *RECORD_PARAMS))
_N_EDGES = len(RECORD_PARAMS)


def derive(P: np.ndarray, field0: np.ndarray | None = None) -> np.ndarray:
    """Per-candidate factors (n, N_DERIVED) of the parameter matrix P (n, len(KERNEL_PARAMS)).
    `field0`: the field voltage (field current, XadIfd) of the steady state where the generator
    is not at no load (the machine on the grid); else the no-load one. The machine's and the
    stabiliser's columns are left 0 (`machines.grid.derive_grid` fills them)."""
    P = np.ascontiguousarray(np.atleast_2d(np.asarray(P, dtype=np.float64)))
    if P.shape[1] != len(KERNEL_PARAMS):
        raise ValueError(f"parameter matrix has {P.shape[1]} columns, expected {len(KERNEL_PARAMS)}")
    n = P.shape[0]
    given = field0 is not None
    fld = np.array(np.broadcast_to(np.asarray(field0, np.float64), (n,))) if given else np.zeros(n)
    D = np.zeros((n, N_DERIVED))
    _derive(P, fld, given, D)
    return D


@njit(fastmath=False, nogil=True)
def _derive(P, field0, given, D):
    """`derive`'s loop: every candidate's row of D."""
    for i in range(P.shape[0]):
        derive_row(P[i], field0[i], given, D[i])


@njit(fastmath=False)
def _valid(p):
    """Whether the engine can run the parameter row p: time constants, gains and limits in their
    domain."""
    for q in _POSITIVE:
        if not (math.isfinite(p[q]) and p[q] > 0.0):
            return False
    for q in _NOT_NEGATIVE:
        if not (math.isfinite(p[q]) and p[q] >= 0.0):
            return False
    for q in _FINITE:
        if not math.isfinite(p[q]):
            return False
    return (p[P_RATE] > 0.0 and p[P_RAMP] > 0.0 and p[P_VRMAX] > p[P_VRMIN] and 0.0 <= p[P_VRVT] <= 1.0
            and (p[P_KF] == 0.0 or p[P_TF] > 0.0) and (p[P_KDR] == 0.0 or p[P_TDR] > 0.0)
            and 0.0 <= p[P_KPP] <= 1.0 and p[P_VBMAX] > 0.0 and p[P_VPMAX] > p[P_VPMIN]
            and p[P_VMMAX] > p[P_VMMIN])


@njit(fastmath=False)
def saturation_ab(s10, s12):
    """Quadratic saturation Sat(x) = B (x - A)^2 for x > A through S(1.0) = S10, S(1.2) = S12;
    (0, 0) unless 0 < S10 < S12."""
    if not (s10 > 0.0 and s12 > s10):
        return 0.0, 0.0
    r = math.sqrt(s12 / s10)
    a = (r - 1.2) / (r - 1.0)
    return a, s10 / ((1.0 - a) * (1.0 - a))


@njit(fastmath=False)
def exciter_saturation_ab(e1, se1, e2, se2):
    """DC exciter saturation SE(Efd) Efd = B (Efd - A)^2 for Efd > A, through SE(E1) = SE1 and
    SE(E2) = SE2 (the quadratic form of IEEE 421.5 as PSS/E and ANDES' ExcQuadSat use it).
    (0, 0) unless 0 < E1 < E2, SE1 > 0 and E2 SE2 > E1 SE1."""
    if not (e1 > 0 and e2 > e1 and se1 > 0 and se2 * e2 > se1 * e1):
        return 0.0, 0.0
    r = math.sqrt((e2 * se2) / (e1 * se1))
    a = (r * e1 - e2) / (r - 1.0)
    return a, e1 * se1 / ((e1 - a) * (e1 - a))


@njit(fastmath=False)
def bridge_voltage(ve, kc_ifd, vbmax):
    """VB = VE FEX(KC Ifd / VE), at most VBMAX: IEEE 421.5's rectifier regulation (VE >= 1e-6)."""
    ve = max(ve, 1.0e-6)
    x = kc_ifd / ve
    if x <= 0.0:
        f = 1.0
    elif x <= 0.433:
        f = 1.0 - 0.577 * x
    elif x <= 0.75:
        f = math.sqrt(max(0.75 - x * x, 0.0))
    elif x <= 1.0:
        f = 1.732 * (1.0 - x)
    else:
        f = 0.0
    return min(ve * f, vbmax)


@njit(fastmath=False)
def ac_exciter_ve(fld0, kc_ifd):
    """The AC exciter's VE at which VE FEX(KC Ifd / VE) gives the field voltage fld0. On each piece
    of FEX the equation has a closed form in VE, with c = KC Ifd: VE - 0.577 c (IN = c / VE <=
    0.433), sqrt(0.75 VE^2 - c^2) (up to 0.75), 1.732 (VE - c) (up to 1); VE FEX is increasing in
    VE, so the answer is the piece's root whose IN lies in that piece. Where rounding at a piece's
    end leaves none (or fld0 is not above 1e-6), `bisect_ve`."""
    c = max(kc_ifd, 0.0)
    if fld0 > 1.0e-6:
        root = fld0 + 0.577 * c
        x = c / root
        if x <= 0.433:
            return root
        root = math.sqrt((fld0 * fld0 + c * c) / 0.75)
        x = c / root
        if 0.433 < x <= 0.75:
            return root
        root = fld0 / 1.732 + c
        x = c / root
        if 0.75 < x <= 1.0:
            return root
    return bisect_ve(fld0, kc_ifd)


@njit(fastmath=False)
def bisect_ve(fld0, kc_ifd):
    """`ac_exciter_ve` by bisection between fld0 and fld0 + 2 KC Ifd + 1."""
    lo = max(fld0, 1.0e-6)
    hi = lo + 2.0 * abs(kc_ifd) + 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if bridge_voltage(mid, kc_ifd, INF) < fld0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@njit(fastmath=False)
def derive_row(p, field0, given, d):
    """Row d of the derived matrix from the parameter row p (see `derive`)."""
    valid = _valid(p)
    d[D_VALID] = 1.0 if valid else 0.0
    # ---- the generator at no load: time constants, saturation, GENROU-like flux shares
    sat_a, sat_b = saturation_ab(p[P_S10], p[P_S12])
    vt0 = p[P_Vt0] if valid else 1.0
    d[D_ITD0P] = 1.0 / p[P_Td0p] if valid else 1.0
    d[D_ITD0PP] = 1.0 / p[P_Td0pp] if valid else 1.0
    d[D_SATA] = sat_a
    d[D_SATB] = sat_b
    d[D_VT0] = vt0
    d[D_KPP] = p[P_KPP] if valid else 0.0
    sateq = p[P_SATEQ] if valid else 0.0
    d[D_SATVT] = 1.0 if (d[D_KPP] > 0.0 and not sateq > 0.5) else 0.0
    d[D_KDA] = p[P_KDA] if valid else 0.0
    fld0 = field0 if given else vt0 + (sat_b * ((vt0 - sat_a) * (vt0 - sat_a)) if vt0 > sat_a else 0.0)
    # ---- the rotating exciter (TEX > 0): DC, or AC (ACEX)
    dc = valid and p[P_TEX] > 0.0
    ac = dc and p[P_ACEX] > 0.5
    sea, seb = exciter_saturation_ab(p[P_E1], p[P_SE1], p[P_E2], p[P_SE2])
    d[D_ITEX] = 1.0 / p[P_TEX] if dc else 0.0
    d[D_DCON] = 1.0 if dc else 0.0
    d[D_KE] = p[P_KE] if dc else 0.0
    d[D_SEA] = sea if dc else 0.0
    d[D_SEB] = seb if dc else 0.0
    d[D_ACON] = 1.0 if ac else 0.0
    d[D_KD] = p[P_KD] if ac else 0.0
    d[D_KCAC] = p[P_KC] if ac else 0.0
    # ---- the potential-source stage (ESST4B: KP > 0, no rotating exciter)
    st4 = valid and not dc and p[P_KPV] > 0.0
    d[D_ST4] = 1.0 if st4 else 0.0
    d[D_KPV] = p[P_KPV] if st4 else 1.0
    d[D_VBMAX] = p[P_VBMAX] if st4 else INF
    d[D_KPM] = p[P_KPM] if st4 else 0.0
    d[D_KIM] = p[P_KIM] if st4 else 0.0
    d[D_VMMAX] = p[P_VMMAX] if st4 else INF
    d[D_VMMIN] = p[P_VMMIN] if st4 else -INF
    d[D_KG] = p[P_KG] if st4 else 0.0
    # ---- the regulator: lead-lags, or a PI in place of the first (ESST4B's; AC8B's PID with
    # its derivative on the second lead-lag's state)
    pid = valid and not st4 and p[P_KDR] > 0.0
    pi = st4 or (valid and (p[P_KPI] > 0.0 or p[P_KII] > 0.0)) or pid
    d[D_KAVR] = p[P_KAVR] if valid else 1.0
    d[D_R1] = 0.0 if pi else (p[P_TA1] / p[P_TA2] if valid else 1.0)
    d[D_IT2] = 0.0 if pi else (1.0 / p[P_TA2] if valid else 1.0)
    d[D_R2] = 1.0 if pid else (p[P_TA3] / p[P_TA4] if valid else 1.0)
    d[D_IT4] = 1.0 / p[P_TDR] if pid else (1.0 / p[P_TA4] if valid else 1.0)
    d[D_ITE] = 1.0 / p[P_TE] if valid else 1.0
    d[D_P1] = p[P_KPI] if pi else 0.0
    d[D_KI1] = p[P_KII] if pi else 0.0
    d[D_Y1MAX] = p[P_VPMAX] if pi else INF
    d[D_Y1MIN] = p[P_VPMIN] if pi else -INF
    d[D_PID] = 1.0 if pid else 0.0
    d[D_KDT] = p[P_KDR] / p[P_TDR] if pid else 0.0
    # ---- rate feedback KF s / (1 + s TF)
    fb = valid and p[P_KF] > 0.0
    d[D_KFT] = p[P_KF] / p[P_TF] if fb else 0.0
    d[D_ITF] = 1.0 / p[P_TF] if fb else 0.0
    # ---- the ceilings and their variants; the ST5B regulator (VRIN) moves the commutation drop
    # to the lag's input and limits the first lead-lag's output to [VRMIN, VRMAX] / KAVR
    vrin = valid and not dc and not st4 and p[P_VRIN] > 0.5
    d[D_VRMAX] = p[P_VRMAX]
    d[D_VRMIN] = p[P_VRMIN]
    d[D_VRVT] = p[P_VRVT] if valid else 0.0
    d[D_KC] = p[P_KC] if (valid and not vrin and not ac) else 0.0
    d[D_LIMOUT] = 1.0 if (valid and not dc and p[P_LIMOUT] > 0.5) else 0.0
    d[D_VRIN] = 1.0 if vrin else 0.0
    d[D_KCIN] = p[P_KC] if vrin else 0.0
    if vrin:
        d[D_Y1MAX] = p[P_VRMAX] / p[P_KAVR]
        d[D_Y1MIN] = p[P_VRMIN] / p[P_KAVR]
    # ---- the effects outside the blocks, the edges' offsets
    d[D_ITR] = 1.0 / p[P_TR] if (valid and p[P_TR] > 0.0) else 0.0
    d[D_TRON] = 1.0 if d[D_ITR] > 0.0 else 0.0
    d[D_TD] = p[P_TD] if valid else 0.0
    d[D_TDON] = 1.0 if d[D_TD] > 0.0 else 0.0
    d[D_RATE] = p[P_RATE]
    d[D_RAMP] = p[P_RAMP]
    d[D_GAIN] = p[P_GAIN] if valid else 1.0
    d[D_SKEW] = p[P_SKEW] if valid else 0.0
    for slot in range(_N_EDGES):
        d[D_EDGE0 + slot] = p[P_EDGE1 + slot] if valid else 0.0
    _steady_state(p, d, valid, dc, ac, st4, pi, vrin, vt0, fld0)
    _bits(d, valid, st4)


@njit(fastmath=False)
def _steady_state(p, d, valid, dc, ac, st4, pi, vrin, vt0, fld0):
    """The steady state at Vt0 the run starts from: the regulator lag's output, the lead-lags'
    states, the reference, the output, the rate feedback's state. A DC exciter needs VR = (KE +
    SE(Efd)) Efd from the regulator, an AC one VR = VFE = KE VE + SE(VE) + KD Ifd with VE FEX(KC
    Ifd / VE) = Efd, a static one Efd itself; the potential-source stage Efd = VB VM, its
    regulator's error 0 and its PI and lag at KG Efd, the inner integrator at Efd / VB (as ANDES
    initialises it). A PI regulator has its error at 0 and its integrator at the output; the
    PID's derivative filter at 0. The ST5B regulator's output is Efd + KC Ifd (within [VRMIN,
    VRMAX])."""
    xe0 = ac_exciter_ve(fld0, d[D_KCAC] * fld0) if ac else fld0
    if dc:
        s = max(xe0 - d[D_SEA], 0.0)
        efd0 = d[D_KE] * xe0 + d[D_SEB] * (s * s) + d[D_KD] * fld0
    else:
        efd0 = fld0
    vb0 = bridge_voltage((p[P_KPV] if st4 else 1.0) * vt0, (p[P_KC] if valid else 0.0) * fld0, p[P_VBMAX])
    if st4:
        efd0 = p[P_KG] * fld0
    # Ifd = E'q + Sat(E'q) = efd0 at no load, the limits at Vt0
    scale0 = 1.0 + d[D_VRVT] * (vt0 - 1.0)
    hi0 = p[P_VRMAX] * scale0 - d[D_KC] * efd0
    lo0 = p[P_VRMIN] * scale0
    lag0 = min(max(efd0, lo0), max(hi0, lo0))
    d[D_EFD0] = lag0
    vr0 = min(max(lag0 + d[D_KCIN] * fld0, p[P_VRMIN]), p[P_VRMAX]) if vrin else lag0
    d[D_VR0] = vr0
    d[D_E0] = vr0 / d[D_KAVR]
    d[D_X20] = 0.0 if d[D_PID] > 0.0 else d[D_E0]
    d[D_UREF0] = vt0 + (0.0 if pi else d[D_E0])
    # the output: the rotating exciter's, VB VM of the potential source, else the regulator output
    d[D_OUT0] = fld0 if (st4 or dc) else lag0
    d[D_XE0] = xe0 if dc else d[D_OUT0]
    d[D_OUTK] = fld0 / xe0 if ac else 1.0
    # the rate feedback's source: the regulator output, the DC exciter's Efd, the AC exciter's VFE
    # (= the regulator output at the steady state)
    src0 = lag0 if ac else lag0 + d[D_DCON] * (d[D_OUT0] - lag0)
    d[D_XF0] = fld0 / vb0 if st4 else src0


@njit(fastmath=False)
def _bits(d, valid, st4):
    """D_BITS: what a valid candidate needs of the engine (`layout.B_*`)."""
    if not valid:
        d[D_BITS] = 0.0
        return
    bits = 0
    if (d[D_KFT] != 0.0 or d[D_DCON] != 0.0 or d[D_LIMOUT] != 0.0 or d[D_VRIN] != 0.0 or d[D_ACON] != 0.0
            or d[D_P1] != 0.0 or d[D_KI1] != 0.0 or d[D_PID] != 0.0):
        bits |= B_FULL
    if d[D_KPP] != 0.0 or d[D_KDA] != 0.0:
        bits |= B_FLUX
    if st4:
        bits |= B_ST4
        if d[D_LIMOUT] != 0.0 and d[D_DCON] == 0.0:
            bits |= B_ST4_ONLY
    if d[D_RATE] < INF or d[D_VRMAX] < INF or d[D_VRMIN] > -INF:
        bits |= B_LIMITED
    if d[D_TD] > 0.0:
        bits |= B_DELAY
    if d[D_SKEW] > 0.0:
        bits |= B_SKEW
    if d[D_RAMP] < 1.0e300:
        bits |= B_RAMP
    d[D_BITS] = float(bits)
