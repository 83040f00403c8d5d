"""The excitation system's compiled algebra: its blocks (regulator lead-lags or PI / PID, rate
feedback, regulator lag with its ceilings, DC / AC exciter, potential-source stage) and the two
state sets a variant steps them with.

The exciter meets the machine at one seam: it reads the terminal voltage `vt` and the field
current `ifd` (air-gap-line base) whatever machine gives them, and the stabiliser's output added
to its reference; it gives the field voltage `fld`. Its states are a tuple: the reference blocks'
(`REF`: transducer xm, lead-lags x1, x2, the regulator lag ef) or every block's (`FULL`: and the
rate feedback's or inner PI's xf, the rotating exciter's xe). Every function is branch-free where
a loop over candidates runs it (plain compare-and-select, not numba's min/max, which carry NaN
branches), so that LLVM vectorises the loop across candidates; `st4` (ST4_*, a constant of each
variant) folds the potential-source stage in or out.
"""
from __future__ import annotations

import math

from .jit import njit
from .layout import (
    D_ACON,
    D_DCON,
    D_E0,
    D_EFD0,
    D_IT2,
    D_IT4,
    D_ITE,
    D_ITEX,
    D_ITF,
    D_ITR,
    D_KAVR,
    D_KC,
    D_KCAC,
    D_KCIN,
    D_KD,
    D_KDT,
    D_KE,
    D_KFT,
    D_KG,
    D_KI1,
    D_KIM,
    D_KPM,
    D_KPV,
    D_LIMOUT,
    D_OUTK,
    D_P1,
    D_PID,
    D_R1,
    D_R2,
    D_RATE,
    D_SEA,
    D_SEB,
    D_ST4,
    D_TDON,
    D_TRON,
    D_VBMAX,
    D_VMMAX,
    D_VMMIN,
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
    PI_TRACK,
)

#: the potential-source stage in a variant (a constant of its code): no candidate has it; some may
#: (selected per candidate); every valid candidate has it (ESST4B: no rotating exciter, the
#: ceilings not on the regulator lag)
ST4_NONE, ST4_SOME, ST4_ALL = 0, 1, 2

# ---- the blocks ---------------------------------------------------------------------------------


@njit
def lead_lag_or_pi(D, c, e, x1, x2):
    """The first lead-lag, or the PI / PID regulator in its place: (output, its unlimited sum).
    Lead-lag: x1 + R1 (e - x1) (P1 = KDT = 0, no limits); PI: x1 + KPI e (R1 = 0), limited; the
    PID adds its derivative KDT (e - x2), x2 its filter of e (ANDES' PIDTrackAW)."""
    ys = x1 + D[D_R1, c] * (e - x1) + D[D_P1, c] * e + D[D_KDT, c] * (e - x2)
    y = ys if ys < D[D_Y1MAX, c] else D[D_Y1MAX, c]
    y = y if y > D[D_Y1MIN, c] else D[D_Y1MIN, c]
    return y, ys


@njit
def exciter_feedback(D, c, xe, ifd):
    """The rotating exciter's feedback into its integrator: KE x + SE(x) x, + KD Ifd (KD = 0 but
    for an AC exciter)."""
    dx = xe - D[D_SEA, c]
    dx = dx if dx > 0.0 else 0.0
    return D[D_KE, c] * xe + D[D_SEB, c] * dx * dx + D[D_KD, c] * ifd


@njit
def feedback_source(D, c, ef, xe, ifd):
    """What the rate feedback differentiates: the regulator output, the DC exciter's Efd or the AC
    exciter's VFE (selected, not branched)."""
    src = ef + D[D_DCON, c] * (xe - ef)
    return src + D[D_ACON, c] * (exciter_feedback(D, c, xe, ifd) - src)


@njit
def regulator_input(D, c, drive, ifd):
    """The regulator lag's input: the (delayed) regulator output, or for the ST5B regulator that
    output limited to [VRMIN, VRMAX] less KC*Ifd."""
    dl = drive if drive < D[D_VRMAX, c] else D[D_VRMAX, c]
    dl = dl if dl > D[D_VRMIN, c] else D[D_VRMIN, c]
    return drive + D[D_VRIN, c] * (dl - drive) - D[D_KCIN, c] * ifd


@njit
def ceilings_at(D, c, vt, ifd):
    """Exciter ceilings (hi, lo) at terminal voltage `vt` and field current `ifd`: VRMAX, VRMIN,
    scaled by Vt when VRVT = 1 (bus-fed), the upper one less KC*Ifd."""
    sc = 1.0 + D[D_VRVT, c] * (vt - 1.0)
    sc = sc if sc > 1.0e-3 else 1.0e-3
    return D[D_VRMAX, c] * sc - D[D_KC, c] * ifd, D[D_VRMIN, c] * sc


@njit
def rectifier(ve, kc_ifd):
    """VE FEX(KC Ifd / VE): the rectifier regulation characteristic of IEEE 421.5 (VE at least
    1e-6). Branch-free selects."""
    ve = ve if ve > 1.0e-6 else 1.0e-6
    x = kc_ifd / ve
    q = 0.75 - x * x
    q = q if q > 0.0 else 0.0
    f = 1.732 * (1.0 - x)
    f = f if x <= 1.0 else 0.0
    f = math.sqrt(q) if x <= 0.75 else f
    f = 1.0 - 0.577 * x if x <= 0.433 else f
    f = 1.0 if x <= 0.0 else f
    return ve * f


@njit
def potential_source(D, c, ef, xf, vt, ifd, hi, lo):
    """The potential-source output stage: (Efd = VB VM, VM, its unlimited sum). VB = KP Vt
    FEX(KC Ifd / (KP Vt)) at most VBMAX; the inner PI VM = KPM (VA - KG Efd) + xf (xf its
    integrator, VA the regulator lag `ef`) with Efd = VB VM solved in closed form, then VM limited
    to [VMMIN, VMMAX] and to [lo, hi] / VB (the diagnosis' ceiling_limit on Efd)."""
    vb = rectifier(D[D_KPV, c] * vt, D[D_KC, c] * ifd)
    vb = vb if vb < D[D_VBMAX, c] else D[D_VBMAX, c]
    kpm = D[D_KPM, c]
    vm = (kpm * ef + xf) / (1.0 + kpm * D[D_KG, c] * vb)
    vm = vm if vm < D[D_VMMAX, c] else D[D_VMMAX, c]
    vm = vm if vm > D[D_VMMIN, c] else D[D_VMMIN, c]
    r = 1.0 / (vb if vb > 1.0e-9 else 1.0e-9)   # one division for both bounds
    vm = vm if vm < hi * r else hi * r
    vm = vm if vm > lo * r else lo * r
    fld = vb * vm
    return fld, vm, kpm * (ef - D[D_KG, c] * fld) + xf, vb


@njit
def non_windup(D, c, de, ef, hi, lo, dhi, dlo):
    """The non-windup ceiling on the regulator lag: at a limit efd may not pass it, and follows it
    where it moves at `dhi` / `dlo` (NaN: no movement). Not when the ceilings clamp the output
    (D_LIMOUT: the lag winds up beyond them, ESST1A/EXST1)."""
    dhi = dhi if dhi == dhi else 0.0  # inf * 0 (no ceiling, fixed limits) is no movement
    dlo = dlo if dlo == dlo else 0.0
    nw = D[D_LIMOUT, c] == 0.0
    de = (de if de < dhi else dhi) if (ef >= hi and nw) else de
    de = (de if de > dlo else dlo) if (ef <= lo and nw) else de
    return de


@njit
def limit_motion(D, c, dvt, difd):
    """How fast the ceilings move (dhi, dlo) when Vt and Ifd change at dvt, difd: with Vt for a
    bus-fed exciter, with Ifd through the commutation drop."""
    dsc = D[D_VRVT, c] * dvt
    return D[D_VRMAX, c] * dsc - D[D_KC, c] * difd, D[D_VRMIN, c] * dsc


@njit
def slewed(D, c, drive, ef):
    """The regulator lag's derivative (drive - ef) / TE within the slew limit +-RATE."""
    rate = D[D_RATE, c]
    de = (drive - ef) * D[D_ITE, c]
    de = de if de < rate else rate
    return de if de > -rate else -rate


@njit
def vr_of(D, c, u, xm, x1, x2, vt, vf):
    """The regulator output VR = KAVR y2 at reference u, transducer state xm, lead-lag states and
    rate feedback vf (the dead time's history reads it)."""
    tron = D[D_TRON, c]
    e = u - (tron * xm + (1.0 - tron) * vt) - vf
    y1 = lead_lag_or_pi(D, c, e, x1, x2)[0]
    return D[D_KAVR, c] * (x2 + D[D_R2, c] * (y1 - x2))

# ---- the reference blocks alone (REF: xm, x1, x2, ef) -----------------------------------------


@njit
def ref_load(S, c):
    return S[0, c], S[1, c], S[2, c], S[3, c]


@njit
def ref_store(S, c, x):
    S[0, c] = x[0]
    S[1, c] = x[1]
    S[2, c] = x[2]
    S[3, c] = x[3]


@njit
def ref_axpy(x, k, h):
    return x[0] + h * k[0], x[1] + h * k[1], x[2] + h * k[2], x[3] + h * k[3]


@njit
def ref_combine(x, a, b, c, d, h6):
    return (x[0] + h6 * (a[0] + 2.0 * b[0] + 2.0 * c[0] + d[0]), x[1] + h6 * (a[1] + 2.0 * b[1] + 2.0 * c[1] + d[1]),
            x[2] + h6 * (a[2] + 2.0 * b[2] + 2.0 * c[2] + d[2]), x[3] + h6 * (a[3] + 2.0 * b[3] + 2.0 * c[3] + d[3]))


@njit
def ref_rhs(D, c, u, vrd, x, vt, ifd, hi, lo, st4):
    """The reference blocks' derivatives (transducer, two lead-lags, the regulator lag within its
    slew limit, the dead time's delayed VR `vrd` where D_TDON; its non-windup ceilings are
    `ref_limit`'s: how a limit moves is the machine's to say) and the field voltage (the lag's
    state)."""
    xm, x1, x2, ef = x
    tron = D[D_TRON, c]
    e = u - (tron * xm + (1.0 - tron) * vt)
    y1 = x1 + D[D_R1, c] * (e - x1)
    vr = D[D_KAVR, c] * (x2 + D[D_R2, c] * (y1 - x2))
    de = slewed(D, c, vr + D[D_TDON, c] * (vrd - vr), ef)
    return ((vt - xm) * D[D_ITR, c], (e - x1) * D[D_IT2, c], (y1 - x2) * D[D_IT4, c], de), ef


@njit
def ref_limit(D, c, dx, x, hi, lo, dhi, dlo, st4):
    """`ref_rhs`'s derivatives with the regulator lag's non-windup ceilings, which move at dhi,
    dlo."""
    return dx[0], dx[1], dx[2], non_windup(D, c, dx[3], x[3], hi, lo, dhi, dlo)


@njit
def ref_output(D, c, x, vt, ifd, hi, lo, st4):
    return x[3]


@njit
def ref_clamp(D, c, x, hi, lo, st4):
    """The regulator lag held inside its ceilings after a step."""
    ef = x[3] if x[3] > lo else lo
    ef = ef if ef < hi else hi
    return x[0], x[1], x[2], ef


@njit
def ref_slope(D, c, x, dx, vt, ifd, st4):
    """The output's time derivative (for the recorder-skew readout): the lag's."""
    return dx[3]


@njit
def ref_vr(D, c, u, x, vt, ifd):
    return vr_of(D, c, u, x[0], x[1], x[2], vt, 0.0)


@njit
def ref_park(D, c):
    """The reference blocks' states at the steady state."""
    return D[D_VT0, c], D[D_E0, c], D[D_X20, c], D[D_EFD0, c]

# ---- every block (FULL: xm, x1, x2, ef, xf, xe) -----------------------------------------------


@njit
def full_load(S, c):
    return S[0, c], S[1, c], S[2, c], S[3, c], S[4, c], S[5, c]


@njit
def full_store(S, c, x):
    S[0, c] = x[0]
    S[1, c] = x[1]
    S[2, c] = x[2]
    S[3, c] = x[3]
    S[4, c] = x[4]
    S[5, c] = x[5]


@njit
def full_axpy(x, k, h):
    return (x[0] + h * k[0], x[1] + h * k[1], x[2] + h * k[2], x[3] + h * k[3], x[4] + h * k[4],
            x[5] + h * k[5])


@njit
def full_combine(x, a, b, c, d, h6):
    return (x[0] + h6 * (a[0] + 2.0 * b[0] + 2.0 * c[0] + d[0]), x[1] + h6 * (a[1] + 2.0 * b[1] + 2.0 * c[1] + d[1]),
            x[2] + h6 * (a[2] + 2.0 * b[2] + 2.0 * c[2] + d[2]), x[3] + h6 * (a[3] + 2.0 * b[3] + 2.0 * c[3] + d[3]),
            x[4] + h6 * (a[4] + 2.0 * b[4] + 2.0 * c[4] + d[4]), x[5] + h6 * (a[5] + 2.0 * b[5] + 2.0 * c[5] + d[5]))


@njit
def full_output(D, c, x, vt, ifd, hi, lo, st4):
    """The field voltage: VB VM of the potential-source stage, the DC exciter's Efd, the AC
    exciter's VE FEX, else the regulator output, clamped to the ceilings when they clamp the
    output (D_LIMOUT) rather than the lag (selected, not branched)."""
    ef = x[3]
    if st4 == ST4_ALL:
        return potential_source(D, c, ef, x[4], vt, ifd, hi, lo)[0]
    efc = ef if ef > lo else lo
    efc = efc if efc < hi else hi
    efc = ef + D[D_LIMOUT, c] * (efc - ef)
    fld = efc + D[D_DCON, c] * (x[5] - efc)
    fld = fld + D[D_ACON, c] * (rectifier(x[5], D[D_KCAC, c] * ifd) - fld)
    if st4 == ST4_SOME:
        fld = fld + D[D_ST4, c] * (potential_source(D, c, ef, x[4], vt, ifd, hi, lo)[0] - fld)
    return fld


@njit
def full_rhs(D, c, u, vrd, x, vt, ifd, hi, lo, st4):
    """Every block's derivatives at Vt and Ifd, and the field voltage: the transducer, the
    regulator (lead-lags, or the PI / PID), the rate feedback, the regulator lag (slew limit;
    the ST5B regulator's input limit and commutation drop; its non-windup ceilings are
    `full_limit`'s), the DC or AC exciter, or the potential-source stage with its inner PI."""
    xm, x1, x2, ef, xf, xe = x
    tron = D[D_TRON, c]
    vm = tron * xm + (1.0 - tron) * vt
    src = ef if st4 == ST4_ALL else feedback_source(D, c, ef, xe, ifd)
    e = u - vm - D[D_KFT, c] * (src - xf)
    y1, ys1 = lead_lag_or_pi(D, c, e, x1, x2)
    y2 = x2 + D[D_R2, c] * (y1 - x2)
    vr = D[D_KAVR, c] * y2
    dxm = (vt - xm) * D[D_ITR, c]
    # lead-lag 1, or the PI's integrator with tracking anti-windup (ANDES' PITrackAW)
    dx1 = (e - x1) * D[D_IT2, c] + D[D_KI1, c] * (e - PI_TRACK * (ys1 - y1))
    # lead-lag 2, or the PID's derivative filter (it follows the error)
    dx2 = (y1 + D[D_PID, c] * (e - y1) - x2) * D[D_IT4, c]
    drive = vr + D[D_TDON, c] * (vrd - vr)
    if st4 != ST4_ALL:   # the ST5B regulator's limit and commutation drop at the lag's input
        drive = regulator_input(D, c, drive, ifd)
    de = slewed(D, c, drive, ef)
    if st4 == ST4_ALL:
        # the potential-source stage alone (ESST4B): Efd = VB VM, xf the inner PI's integrator
        # (tracking anti-windup as ANDES' PITrackAW); the lag is not limited; no rotating exciter
        fld, vm4, ys4, _vb = potential_source(D, c, ef, xf, vt, ifd, hi, lo)
        dxf = D[D_KIM, c] * (ef - D[D_KG, c] * fld - PI_TRACK * (ys4 - vm4))
        return (dxm, dx1, dx2, de, dxf, 0.0), fld
    efc = ef if ef > lo else lo
    efc = efc if efc < hi else hi
    efc = ef + D[D_LIMOUT, c] * (efc - ef)
    fld = efc + D[D_DCON, c] * (xe - efc)
    fld = fld + D[D_ACON, c] * (rectifier(xe, D[D_KCAC, c] * ifd) - fld)
    dxe = (efc - exciter_feedback(D, c, xe, ifd)) * D[D_ITEX, c]
    dxf = (src - xf) * D[D_ITF, c]
    if st4 == ST4_SOME:   # the potential-source stage where a candidate has it (selected)
        s4 = D[D_ST4, c]
        f4, vm4, ys4, _vb = potential_source(D, c, ef, xf, vt, ifd, hi, lo)
        fld = fld + s4 * (f4 - fld)
        dxf = dxf + s4 * (D[D_KIM, c] * (ef - D[D_KG, c] * f4 - PI_TRACK * (ys4 - vm4)) - dxf)
    return (dxm, dx1, dx2, de, dxf, dxe), fld


@njit
def full_limit(D, c, dx, x, hi, lo, dhi, dlo, st4):
    """`full_rhs`'s derivatives with the regulator lag's non-windup ceilings, which move at dhi,
    dlo (not on ESST4B's lag, whose ceilings act on VM)."""
    if st4 == ST4_ALL:
        return dx
    return dx[0], dx[1], dx[2], non_windup(D, c, dx[3], x[3], hi, lo, dhi, dlo), dx[4], dx[5]


@njit
def full_clamp(D, c, x, hi, lo, st4):
    """The regulator lag held inside its ceilings after a step, unless they clamp the output
    (D_LIMOUT) or the lag is ESST4B's (not limited)."""
    if st4 == ST4_ALL:
        return x
    z = x[3] if x[3] > lo else lo
    z = z if z < hi else hi
    return x[0], x[1], x[2], z + D[D_LIMOUT, c] * (x[3] - z), x[4], x[5]


@njit
def full_slope(D, c, x, dx, vt, ifd, st4):
    """The output's time derivative (for the recorder-skew readout): the regulator lag's, the
    DC exciter's, OUTK times the AC exciter's VE's, or VB dVM/dt of the potential-source stage
    (VB's own slow change with Vt and Ifd left out; 0 while VM is at a limit)."""
    slope = dx[3] + D[D_DCON, c] * (D[D_OUTK, c] * dx[5] - dx[3])
    if st4 == ST4_NONE:
        return slope
    hi, lo = ceilings_at(D, c, vt, ifd)
    f4, vm, ys, vb = potential_source(D, c, x[3], x[4], vt, ifd, hi, lo)
    kpm = D[D_KPM, c]
    sl = vb * (kpm * dx[3] + dx[4]) / (1.0 + kpm * D[D_KG, c] * vb)
    sl = sl if vm < D[D_VMMAX, c] else 0.0   # nested selects: `and` would branch (no vectorising)
    sl = sl if vm > D[D_VMMIN, c] else 0.0
    sl = sl if f4 < hi else 0.0
    sl = sl if f4 > lo else 0.0
    return sl if st4 == ST4_ALL else slope + D[D_ST4, c] * (sl - slope)


@njit
def full_vr(D, c, u, x, vt, ifd):
    return vr_of(D, c, u, x[0], x[1], x[2], vt, D[D_KFT, c] * (feedback_source(D, c, x[3], x[5], ifd) - x[4]))


@njit
def full_park(D, c):
    """Every block's states at the steady state (`derive`): where a run starts and where a failed
    candidate is parked."""
    return D[D_VT0, c], D[D_E0, c], D[D_X20, c], D[D_EFD0, c], D[D_XF0, c], D[D_XE0, c]
