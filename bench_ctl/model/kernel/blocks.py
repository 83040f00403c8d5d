"""The blocks of the kernel's unit, each in one place: its derived factors (array code, `derive_*`,
called by `derive` once a call) and its compiled algebra for one candidate `i` of the transposed
derived matrix D (`layout`), with its share of the output and the output's slope; the steady
state a run starts from.

The RK4 right-hand side (`rhs`) wires them; the plant (`plant_step`) and the open loop
(`open_loop`) reuse them, so the three compute the same numbers. The compiled ones are inlined
into their caller (`jit.njit`) and branch-free where a loop over candidates runs them, so that it
vectorises: plain compare-and-select rather than numba's min/max (which carry NaN branches).
"""
from __future__ import annotations

import math

import numpy as np

from .jit import njit
from .layout import (
    D_ACON,
    D_DCON,
    D_E0,
    D_EFD0,
    D_IT2,
    D_IT4,
    D_ITD0P,
    D_ITD0PP,
    D_ITE,
    D_ITEX,
    D_ITF,
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
    D_P1,
    D_PID,
    D_R1,
    D_R2,
    D_SATA,
    D_SATB,
    D_SATVT,
    D_SEA,
    D_SEB,
    D_ST4,
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
    EDGE_EPS,
    ST4_ALL,
)

#: the parameter matrix's columns by name (`derive`: a numba typed dict of float64 arrays)
Params = dict[str, np.ndarray]


@njit(fastmath=False)
def safe(valid: np.ndarray, x: np.ndarray) -> np.ndarray:
    """x where the candidate is valid, else 1 (a harmless factor)."""
    return np.where(valid, x, 1.0)


# ---- regulator: AVR lead-lags (or the ESST4B's PI), rate feedback ------------------------------


@njit(inline=False, fastmath=False)
def derive_regulator(D: np.ndarray, g: Params, valid: np.ndarray, st4: np.ndarray) -> np.ndarray:
    """The AVR: gain, lead-lags, the regulator lag. The first lead-lag is replaced by a PI where the
    potential-source stage is on (ESST4B) or where the PI's gains or the derivative are set (AC8B's
    PID: KPI, KII or KDR > 0); with the derivative (KDR > 0) the second lead-lag's state is the
    derivative's filter and the lead-lag itself bypassed. Returns where the PI is on."""
    pid = valid & ~st4 & (g["KDR"] > 0.0)
    pi = st4 | (valid & ((g["KPI"] > 0.0) | (g["KII"] > 0.0))) | pid
    D[:, D_KAVR] = safe(valid, g["KAVR"])
    D[:, D_R1] = np.where(pi, 0.0, safe(valid, g["TA1"] / g["TA2"]))
    D[:, D_IT2] = np.where(pi, 0.0, safe(valid, 1.0 / g["TA2"]))
    D[:, D_R2] = np.where(pid, 1.0, safe(valid, g["TA3"] / g["TA4"]))
    D[:, D_IT4] = np.where(pid, 1.0 / np.where(pid, g["TDR"], 1.0), safe(valid, 1.0 / g["TA4"]))
    D[:, D_ITE] = safe(valid, 1.0 / g["TE"])
    D[:, D_P1] = np.where(pi, g["KPI"], 0.0)
    D[:, D_KI1] = np.where(pi, g["KII"], 0.0)
    D[:, D_Y1MAX] = np.where(pi, g["VPMAX"], np.inf)
    D[:, D_Y1MIN] = np.where(pi, g["VPMIN"], -np.inf)
    D[:, D_PID] = pid.astype(np.float64)
    D[:, D_KDT] = np.where(pid, g["KDR"] / np.where(pid, g["TDR"], 1.0), 0.0)
    return pi


@njit(inline=False, fastmath=False)
def derive_rate_feedback(D: np.ndarray, g: Params, valid: np.ndarray) -> None:
    """Rate feedback KF s / (1 + s TF): KF / TF and 1 / TF, 0 without (KF = 0)."""
    fb = valid & (g["KF"] > 0.0)
    D[:, D_KFT] = np.where(fb, g["KF"] / np.where(fb, g["TF"], 1.0), 0.0)
    D[:, D_ITF] = np.where(fb, 1.0 / np.where(fb, g["TF"], 1.0), 0.0)


@njit()
def avr(D, i, uref, vm, x1, x2, vf):
    """AVR lead-lags: returns (VR, e, y1) for error e = uref - Vm - Vf (Vf: rate feedback).
    With a PI regulator the first lead-lag is the PI (KPI e + x1, + the PID's derivative) within
    its limits."""
    e = uref - vm - vf
    y1 = lead_lag_or_pi(D, i, e, x1, x2)[0]
    y2 = x2 + D[D_R2, i] * (y1 - x2)
    return D[D_KAVR, i] * y2, e, y1


@njit()
def lead_lag_or_pi(D, i, e, x1, x2):
    """The first lead-lag, or the PI / PID regulator in its place: (output, its unlimited sum).
    Lead-lag: x1 + R1 (e - x1) (P1 = KDT = 0, no limits); PI: x1 + KPI e (R1 = 0), limited; the
    PID adds its derivative KDT (e - x2), x2 its filter of e (ANDES' PIDTrackAW: a washout
    KDR s/(1 + s TDR) inside the limited sum)."""
    ys = x1 + D[D_R1, i] * (e - x1) + D[D_P1, i] * e + D[D_KDT, i] * (e - x2)
    y = ys if ys < D[D_Y1MAX, i] else D[D_Y1MAX, i]
    y = y if y > D[D_Y1MIN, i] else D[D_Y1MIN, i]
    return y, ys


@njit()
def lead_lag_2_input(D, i, e, y1):
    """What the second state follows: the first block's output (lead-lag 2), or the error (the PID's
    derivative filter); selected, not branched."""
    return y1 + D[D_PID, i] * (e - y1)


@njit()
def rate_feedback(D, i, ef, xf, xe, eqp, eqpp):
    """Rate feedback KF s/(1 + s TF) of the exciter output (DC), the AC exciter's VFE or the
    regulator output (static)."""
    ifd = field_current(D, i, eqp, eqpp, terminal_voltage(D, i, eqp, eqpp))
    return D[D_KFT, i] * (feedback_source(D, i, ef, xe, ifd) - xf)


@njit()
def feedback_source(D, i, ef, xe, ifd):
    """What the rate feedback differentiates: the regulator output, the DC exciter's Efd or the AC
    exciter's VFE = KE VE + SE(VE) + KD Ifd (selected, not branched)."""
    src = ef + D[D_DCON, i] * (xe - ef)
    return src + D[D_ACON, i] * (exciter_feedback(D, i, xe, ifd) - src)


@njit()
def exciter_feedback(D, i, xe, ifd):
    """The rotating exciter's feedback into its integrator: KE x + SE(x) x, + KD Ifd (KD = 0 but
    for an AC exciter)."""
    dx = xe - D[D_SEA, i]
    dx = dx if dx > 0.0 else 0.0
    return D[D_KE, i] * xe + D[D_SEB, i] * dx * dx + D[D_KD, i] * ifd

# ---- generator at no load: terminal voltage, field current -------------------------------------


@njit(inline=False, fastmath=False)
def saturation_ab(s10: np.ndarray, s12: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quadratic saturation Sat(x) = B (x - A)^2 for x > A through S(1.0) = S10, S(1.2) = S12."""
    on = (s10 > 0.0) & (s12 > s10)
    r = np.sqrt(np.where(on, s12, 1.0) / np.where(on, s10, 1.0))
    a = np.where(on, (r - 1.2) / np.where(on, r - 1.0, 1.0), 0.0)
    b = np.where(on, s10 / np.where(on, (1.0 - a) ** 2, 1.0), 0.0)
    return a, b


@njit(inline=False, fastmath=False)
def derive_generator(D: np.ndarray, g: Params, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The generator at no load (time constants, saturation, GENROU-like flux shares); returns Vt0
    and the field voltage it needs at the steady state."""
    a, b = saturation_ab(g["S10"], g["S12"])
    vt0 = safe(valid, g["Vt0"])
    sat0 = np.where(vt0 > a, b * (vt0 - a) ** 2, 0.0)
    D[:, D_ITD0P] = safe(valid, 1.0 / g["Td0p"])
    D[:, D_ITD0PP] = safe(valid, 1.0 / g["Td0pp"])
    D[:, D_SATA] = a
    D[:, D_SATB] = b
    D[:, D_VT0] = vt0
    D[:, D_KPP] = np.where(valid, g["KPP"], 0.0)
    # saturation on psi'' = Vt with a GENROU's flux share, on E'q for a GENSAL (SATEQ) or without one
    D[:, D_SATVT] = ((D[:, D_KPP] > 0.0) & ~(np.where(valid, g["SATEQ"], 0.0) > 0.5)).astype(np.float64)
    D[:, D_KDA] = np.where(valid, g["KDA"], 0.0)
    return vt0, vt0 + sat0


@njit()
def terminal_voltage(D, i, eqp, eqpp):
    """Terminal voltage at no load: E''q, or with a GENROU-like flux share KPP of E'q,
    Vt = KPP E'q + (1 - KPP) E''q."""
    return eqpp + D[D_KPP, i] * (eqp - eqpp)


@njit()
def field_current(D, i, eqp, eqpp, vt):
    """The no-load field current on the air-gap base: E'q + KDA (E'q - E''q) + Sat."""
    d = eqp + D[D_SATVT, i] * (vt - eqp) - D[D_SATA, i]
    d = d if d > 0.0 else 0.0
    return eqp + D[D_KDA, i] * (eqp - eqpp) + D[D_SATB, i] * d * d

# ---- exciter ceilings (ceiling_limit) ----------------------------------------------------------


@njit(inline=False, fastmath=False)
def derive_ceilings(D: np.ndarray, g: Params, valid: np.ndarray, dc: np.ndarray, st4: np.ndarray,
                    ac: np.ndarray) -> np.ndarray:
    """The ceilings, their variants (bus-fed, commutation) and whether they clamp the output rather
    than the regulator lag (LIMOUT; not with a DC exciter). The ST5B regulator (VRIN; a static
    exciter without the potential-source stage) moves the commutation drop KC*Ifd from the upper
    ceiling to the lag's input and limits the first lead-lag's output to [VRMIN, VRMAX]/KAVR.
    An AC exciter's KC is its rectifier's (`rectifier`), not on the ceiling.
    Returns where the ST5B regulator is on."""
    vrin = valid & ~dc & ~st4 & (g["VRIN"] > 0.5)
    D[:, D_VRMAX] = g["VRMAX"]
    D[:, D_VRMIN] = g["VRMIN"]
    D[:, D_VRVT] = np.where(valid, g["VRVT"], 0.0)
    D[:, D_KC] = np.where(valid & ~vrin & ~ac, g["KC"], 0.0)   # (an AC exciter's KC is its FEX's)
    D[:, D_LIMOUT] = np.where(valid & ~dc, g["LIMOUT"] > 0.5, False).astype(np.float64)
    D[:, D_VRIN] = vrin.astype(np.float64)
    D[:, D_KCIN] = np.where(vrin, g["KC"], 0.0)
    kavr = np.where(vrin, g["KAVR"], 1.0)
    D[:, D_Y1MAX] = np.where(vrin, g["VRMAX"] / kavr, D[:, D_Y1MAX])
    D[:, D_Y1MIN] = np.where(vrin, g["VRMIN"] / kavr, D[:, D_Y1MIN])
    return vrin


@njit()
def regulator_input(D, i, drive, ifd):
    """The regulator lag's input: the (delayed) regulator output, or for the ST5B regulator that
    output limited to [VRMIN, VRMAX] less KC*Ifd (selected, not branched, so loops vectorise)."""
    dl = drive if drive < D[D_VRMAX, i] else D[D_VRMAX, i]
    dl = dl if dl > D[D_VRMIN, i] else D[D_VRMIN, i]
    return drive + D[D_VRIN, i] * (dl - drive) - D[D_KCIN, i] * ifd


@njit()
def ceilings(D, i, eqp, eqpp):
    """Exciter ceilings (hi, lo): VRMAX, VRMIN, scaled by Vt when VRVT = 1 (bus-fed), the upper
    one less KC*Ifd, Ifd = E'q + Sat (the no-load field current on the air-gap base)."""
    vt = terminal_voltage(D, i, eqp, eqpp)
    return ceilings_at(D, i, vt, field_current(D, i, eqp, eqpp, vt))


@njit()
def ceilings_at(D, i, vt, ifd):
    """Exciter ceilings (hi, lo) at terminal voltage `vt` and field current `ifd` (`ceilings` at no
    load; the on-line machine gives its own)."""
    sc = 1.0 + D[D_VRVT, i] * (vt - 1.0)
    sc = sc if sc > 1.0e-3 else 1.0e-3
    return D[D_VRMAX, i] * sc - D[D_KC, i] * ifd, D[D_VRMIN, i] * sc


@njit()
def ceilings_ref(D, i, eqp, eqpp):
    """`ceilings` of the reference blocks only (no GENROU flux shares): the fast path.
    Exciter ceilings (hi, lo): VRMAX, VRMIN, scaled by Vt = E''q when VRVT = 1 (bus-fed), the
    upper one less KC*Ifd, Ifd = E'q + Sat(E'q) (the no-load field current on the air-gap base)."""
    d = eqp - D[D_SATA, i]
    d = d if d > 0.0 else 0.0
    ifd = eqp + D[D_SATB, i] * d * d
    sc = 1.0 + D[D_VRVT, i] * (eqpp - 1.0)
    sc = sc if sc > 1.0e-3 else 1.0e-3
    return D[D_VRMAX, i] * sc - D[D_KC, i] * ifd, D[D_VRMIN, i] * sc

# ---- potential-source stage (ESST4B) -----------------------------------------------------------


@njit(inline=False, fastmath=False)
def bridge_voltage_np(ve: np.ndarray, kc_ifd: np.ndarray, vbmax: np.ndarray) -> np.ndarray:
    """VB = VE FEX(KC Ifd / VE), at most VBMAX (numpy twin of `bridge_voltage`)."""
    ve = np.maximum(ve, 1.0e-6)
    x = kc_ifd / ve
    f = np.where(x <= 0.0, 1.0, np.where(x <= 0.433, 1.0 - 0.577 * x, np.where(
        x <= 0.75, np.sqrt(np.maximum(0.75 - x * x, 0.0)), np.where(x <= 1.0, 1.732 * (1.0 - x), 0.0))))
    return np.minimum(ve * f, vbmax)


@njit(inline=False, fastmath=False)
def derive_potential_source(D: np.ndarray, g: Params, valid: np.ndarray, dc: np.ndarray) -> np.ndarray:
    """The potential-source stage (ESST4B: KP > 0, no DC exciter): the bridge (KP, VBMAX), the
    inner PI and KG (its PI regulator in place of lead-lag 1 is `derive_regulator`'s); neutral
    elsewhere. Returns where on."""
    st4 = valid & ~dc & (g["KPV"] > 0.0)
    D[:, D_ST4] = st4.astype(np.float64)
    D[:, D_KPV] = np.where(st4, g["KPV"], 1.0)
    D[:, D_VBMAX] = np.where(st4, g["VBMAX"], np.inf)
    D[:, D_KPM] = np.where(st4, g["KPM"], 0.0)
    D[:, D_KIM] = np.where(st4, g["KIM"], 0.0)
    D[:, D_VMMAX] = np.where(st4, g["VMMAX"], np.inf)
    D[:, D_VMMIN] = np.where(st4, g["VMMIN"], -np.inf)
    D[:, D_KG] = np.where(st4, g["KG"], 0.0)
    return st4


@njit()
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


@njit()
def bridge_voltage(D, i, vt, ifd):
    """VB = VE FEX(IN), VE = KP Vt (no load: no current term), IN = KC Ifd / VE, at most VBMAX:
    the rectifier regulation characteristic of IEEE 421.5 (ESST4B; `rectifier`)."""
    vb = rectifier(D[D_KPV, i] * vt, D[D_KC, i] * ifd)
    return vb if vb < D[D_VBMAX, i] else D[D_VBMAX, i]


@njit()
def potential_source(D, i, ef, xf, vt, ifd, hi, lo):
    """The potential-source output stage: (Efd = VB VM, VM, its unlimited sum, VB). The inner PI
    VM = KPM (VA - KG Efd) + xf (xf its integrator, VA the regulator lag `ef`) with Efd = VB VM
    is solved in closed form, then VM limited (the limited VM is the consistent one: the sum
    falls as VM rises): to [VMMIN, VMMAX], and to [lo, hi] / VB, the diagnosis' `ceiling_limit`
    on Efd (`ceilings`; +-inf unless that effect is on), so that the effect bounds ESST4B's field
    voltage the way VB VMMAX does rather than the regulator lag VA."""
    vb = bridge_voltage(D, i, vt, ifd)
    kpm = D[D_KPM, i]
    vm = (kpm * ef + xf) / (1.0 + kpm * D[D_KG, i] * vb)
    vm = vm if vm < D[D_VMMAX, i] else D[D_VMMAX, i]
    vm = vm if vm > D[D_VMMIN, i] else D[D_VMMIN, i]
    r = 1.0 / (vb if vb > 1.0e-9 else 1.0e-9)   # one division for both bounds
    vm = vm if vm < hi * r else hi * r
    vm = vm if vm > lo * r else lo * r
    fld = vb * vm
    return fld, vm, kpm * (ef - D[D_KG, i] * fld) + xf, vb


@njit()
def output_slope(D, i, ef, xf, eqp, eqpp, def_, dxf, other, st4):
    """The output's time derivative for the recorder-skew readout: `other` (the DC exciter's or
    the regulator lag's), or for the potential-source stage VB dVM/dt (VB's own slow change with
    Vt and Ifd left out; 0 while VM is at a limit)."""
    vt = terminal_voltage(D, i, eqp, eqpp)
    hi, lo = ceilings(D, i, eqp, eqpp)
    f4, vm, ys, vb = potential_source(D, i, ef, xf, vt, field_current(D, i, eqp, eqpp, vt), hi, lo)
    kpm = D[D_KPM, i]
    sl = vb * (kpm * def_ + dxf) / (1.0 + kpm * D[D_KG, i] * vb)
    sl = sl if vm < D[D_VMMAX, i] else 0.0   # nested selects: `and` would branch (no vectorising)
    sl = sl if vm > D[D_VMMIN, i] else 0.0
    sl = sl if f4 < hi else 0.0
    sl = sl if f4 > lo else 0.0
    return sl if st4 == ST4_ALL else other + D[D_ST4, i] * (sl - other)

# ---- DC exciter; the field voltage, the kernel's output ----------------------------------------


@njit(inline=False, fastmath=False)
def exciter_saturation_ab(e1, se1, e2, se2) -> tuple[np.ndarray, np.ndarray]:
    """DC exciter saturation SE(Efd) Efd = B (Efd - A)^2 for Efd > A, through SE(E1) = SE1 and
    SE(E2) = SE2 (the quadratic form of IEEE 421.5 as PSS/E and ANDES' ExcQuadSat use it).
    Off (A = 0, B = 0) unless 0 < E1 < E2 and 0 < SE1 < SE2... with E2 SE2 > E1 SE1."""
    on = (e1 > 0) & (e2 > e1) & (se1 > 0) & (se2 * e2 > se1 * e1)
    r = np.sqrt(np.where(on, (e2 * se2) / np.where(on, e1 * se1, 1.0), 4.0))
    a = np.where(on, (r * e1 - e2) / np.where(on, r - 1.0, 1.0), 0.0)
    b = np.where(on, e1 * se1 / np.where(on, (e1 - a) ** 2, 1.0), 0.0)
    return a, b


@njit(inline=False, fastmath=False)
def derive_dc_exciter(D: np.ndarray, g: Params, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotating exciter (TEX > 0): 1 / TEX, KE, its saturation, and for an AC exciter (ACEX)
    KD and the rectifier's KC. Returns where one is on and where it is an AC exciter."""
    dc = valid & (g["TEX"] > 0.0)
    ac = dc & (g["ACEX"] > 0.5)
    sea, seb = exciter_saturation_ab(g["E1"], g["SE1"], g["E2"], g["SE2"])
    D[:, D_ITEX] = np.where(dc, 1.0 / np.where(dc, g["TEX"], 1.0), 0.0)
    D[:, D_DCON] = dc.astype(np.float64)
    D[:, D_KE] = np.where(dc, g["KE"], 0.0)
    D[:, D_SEA] = np.where(dc, sea, 0.0)
    D[:, D_SEB] = np.where(dc, seb, 0.0)
    D[:, D_ACON] = ac.astype(np.float64)
    D[:, D_KD] = np.where(ac, g["KD"], 0.0)
    D[:, D_KCAC] = np.where(ac, g["KC"], 0.0)
    return dc, ac


@njit()
def field_voltage(D, i, ef, eqp, eqpp, xf, xe):
    """The field voltage (the kernel's output): the DC exciter's, else the regulator output,
    clamped to the ceilings when they clamp the output (D_LIMOUT) rather than the lag, else
    (ESST4B) VB VM."""
    hi, lo = ceilings(D, i, eqp, eqpp)
    efc = ef if ef > lo else lo
    efc = efc if efc < hi else hi
    efc = ef + D[D_LIMOUT, i] * (efc - ef)
    if D[D_ST4, i] != 0.0:   # a branch: the loops that record the output do not vectorise
        vt = terminal_voltage(D, i, eqp, eqpp)
        return potential_source(D, i, ef, xf, vt, field_current(D, i, eqp, eqpp, vt), hi, lo)[0]
    if D[D_ACON, i] != 0.0:
        vt = terminal_voltage(D, i, eqp, eqpp)
        return rectifier(xe, D[D_KCAC, i] * field_current(D, i, eqp, eqpp, vt))
    return efc + D[D_DCON, i] * (xe - efc)

# ---- history reads: the dead time's delayed VR, the recorder skew's Hermite interpolation ------


@njit()
def delayed_vr(vr_r, vr_l, jf, vjl, vjr, c, L, tau_steps, k, vr0, left):
    """VR at time tau_steps * dt from the per-step history kept in rings of length L.

    Step j keeps the right limit at t_j (`vr_r`), the left limit at t_j+1 (`vr_l`) and, when the
    setpoint jumped inside it at fraction `jf` > 0, the left and right limits there (`vjl`,
    `vjr`); VR is linear between. `left` reads the left limit at a jump (the end of an RK
    (sub-)step sees the delayed signal just before a delayed jump, the start just after it)."""
    r = math.floor(tau_steps + 0.5)
    if abs(tau_steps - r) < EDGE_EPS:
        tau_steps = r
    if tau_steps < 0.0 or (left and tau_steps <= 0.0):
        return vr0
    j = int(math.ceil(tau_steps)) - 1 if left else int(math.floor(tau_steps))
    if j >= k:  # inside the current step (TD shorter than a step): hold the right limit
        return vr_r[c, k % L]
    s = tau_steps - j
    q = j % L
    f = jf[c, q]
    if f > 0.0:
        if s < f - EDGE_EPS or (left and s <= f + EDGE_EPS):
            return vr_r[c, q] + (vjl[c, q] - vr_r[c, q]) * (s / f)
        return vjr[c, q] + (vr_l[c, (j + 1) % L] - vjr[c, q]) * ((s - f) / (1.0 - f))
    return vr_r[c, q] * (1.0 - s) + vr_l[c, (j + 1) % L] * s


@njit()
def hermite(y0, m0, y1, m1, s, h):
    s2 = s * s
    s3 = s2 * s
    return ((2 * s3 - 3 * s2 + 1) * y0 + (s3 - 2 * s2 + s) * h * m0
            + (-2 * s3 + 3 * s2) * y1 + (s3 - s2) * h * m1)


# ---- the steady state ------------------------------------------------------------------------


@njit()
def steady_state(D, i):
    """The 8 states at the steady state at Vt0 (`derive`): where a run starts and where a failed
    candidate is parked so that its arithmetic stays finite."""
    vt0 = D[D_VT0, i]
    return vt0, D[D_E0, i], D[D_X20, i], D[D_EFD0, i], vt0, vt0, D[D_XF0, i], D[D_XE0, i]
