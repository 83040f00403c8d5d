"""The kernel's right-hand side: the derivatives of the 8 states, the blocks (`blocks`) wired in
diagram order: the excitation system (`exciter`, `non_windup`) on the generator at no load
(`rhs`); `rhs_ref` is the reference structure's alone (6 states), the fast path.
"""
from __future__ import annotations

import math

from .blocks import (
    ceilings,
    ceilings_ref,
    exciter_feedback,
    feedback_source,
    field_current,
    lead_lag_2_input,
    lead_lag_or_pi,
    potential_source,
    rectifier,
    regulator_input,
    terminal_voltage,
)
from .jit import njit
from .layout import (
    D_ACON,
    D_DCON,
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
    D_KDA,
    D_KFT,
    D_KG,
    D_KI1,
    D_KIM,
    D_KPP,
    D_LIMOUT,
    D_R1,
    D_R2,
    D_RATE,
    D_SATA,
    D_SATB,
    D_SATVT,
    D_ST4,
    D_TDON,
    D_TRON,
    D_VRMAX,
    D_VRMIN,
    D_VRVT,
    PI_TRACK,
    ST4_ALL,
    ST4_SOME,
)


@njit()
def exciter(D, i, uref, vrd, xm, x1, x2, ef, xf, xe, vt, ifd, hi, lo, st4=ST4_SOME):
    """The excitation system's derivatives at terminal voltage `vt` and field current `ifd` (on the
    air-gap-line base), whatever generator gives them (`rhs`: at no load; the on-line machine,
    `bench_ctl.model.online`): (dxm, dx1, dx2, dVR-lag, field voltage, dxf, dxe). The regulator
    lag's derivative is slew-limited but not yet held at the ceilings `hi`, `lo` (`non_windup`:
    how a limit moves is the generator's to say). Branch-free so candidate loops vectorise; `st4`
    as in `rhs`."""
    tron = D[D_TRON, i]
    vm = tron * xm + (1.0 - tron) * vt
    src = ef if st4 == ST4_ALL else feedback_source(D, i, ef, xe, ifd)
    e = uref - vm - D[D_KFT, i] * (src - xf)
    y1, ys1 = lead_lag_or_pi(D, i, e, x1, x2)
    y2 = x2 + D[D_R2, i] * (y1 - x2)
    vr = D[D_KAVR, i] * y2
    dxm = (vt - xm) * D[D_ITR, i]
    # lead-lag 1, or the PI's integrator with tracking anti-windup (ANDES' PITrackAW)
    dx1 = (e - x1) * D[D_IT2, i] + D[D_KI1, i] * (e - PI_TRACK * (ys1 - y1))
    # lead-lag 2, or the PID's derivative filter
    dx2 = (lead_lag_2_input(D, i, e, y1) - x2) * D[D_IT4, i]
    tdon = D[D_TDON, i]
    drive = vr + tdon * (vrd - vr)
    if st4 != ST4_ALL:   # the ST5B regulator's limit and commutation drop at the lag's input
        drive = regulator_input(D, i, drive, ifd)
    # plain compare-and-select (numba's min/max carry NaN branches that stop the vectoriser)
    rate = D[D_RATE, i]
    de = (drive - ef) * D[D_ITE, i]
    de = de if de < rate else rate
    de = de if de > -rate else -rate
    # the field voltage: VB VM of the potential-source stage, the DC exciter's state, else the
    # regulator output (clamped when the ceilings clamp the output rather than the lag)
    limout = D[D_LIMOUT, i]
    if st4 == ST4_ALL:
        # the potential-source stage alone (ESST4B): Efd = VB VM, state 6 the inner PI's
        # integrator (tracking anti-windup as ANDES' PITrackAW); no DC exciter
        f4, vm4, ys4, _vb4 = potential_source(D, i, ef, xf, vt, ifd, hi, lo)
        fld = f4
        dxf = D[D_KIM, i] * (ef - D[D_KG, i] * f4 - PI_TRACK * (ys4 - vm4))
        dxe = 0.0
    else:
        efc = ef if ef > lo else lo
        efc = efc if efc < hi else hi
        efc = ef + limout * (efc - ef)
        dcon = D[D_DCON, i]
        fld = efc + dcon * (xe - efc)
        # the AC exciter's output VE FEX(KC Ifd / VE) (selected: the loop vectorises)
        fld = fld + D[D_ACON, i] * (rectifier(xe, D[D_KCAC, i] * ifd) - fld)
        dxe = (efc - exciter_feedback(D, i, xe, ifd)) * D[D_ITEX, i]
        dxf = (src - xf) * D[D_ITF, i]
        # the potential-source stage where a candidate has it, selected, not branched, so the
        # loop vectorises
        if st4 == ST4_SOME:
            s4 = D[D_ST4, i]
            f4, vm4, ys4, _vb4 = potential_source(D, i, ef, xf, vt, ifd, hi, lo)
            fld = fld + s4 * (f4 - fld)
            dxf = dxf + s4 * (D[D_KIM, i] * (ef - D[D_KG, i] * f4 - PI_TRACK * (ys4 - vm4)) - dxf)
    return dxm, dx1, dx2, de, fld, dxf, dxe


@njit()
def non_windup(D, i, de, ef, hi, lo, dhi, dlo):
    """The non-windup ceiling on the regulator lag: at a limit efd may not pass it, and follows it
    where it moves at `dhi` / `dlo` (NaN: no movement). Not when the ceilings clamp the output
    (D_LIMOUT: the lag winds up beyond them, ESST1A/EXST1)."""
    dhi = dhi if dhi == dhi else 0.0  # inf * 0 (no ceiling, fixed limits) is no movement
    dlo = dlo if dlo == dlo else 0.0
    nw = D[D_LIMOUT, i] == 0.0
    de = (de if de < dhi else dhi) if (ef >= hi and nw) else de
    de = (de if de > dlo else dlo) if (ef <= lo and nw) else de
    return de


@njit()
def rhs(D, i, uref, vrd, xm, x1, x2, ef, eqp, eqpp, xf, xe, st4=ST4_SOME):
    """Derivatives of (xm, x1, x2, VR lag (efd of a static exciter), E'q, E''q, rate feedback,
    DC exciter Efd): the excitation system (`exciter`) on the generator at no load; branch-free so
    candidate loops vectorise. `st4` (ST4_*, a constant where the caller passes one: the branches
    then fold away) includes the potential-source stage (ESST4B): a chunk without it does not pay
    for its square root and divisions (measured: 1.35x of a chunk's time), a chunk of ESST4B alone
    not for the DC exciter and the non-windup ceiling.

    `vrd` is the delayed VR (used when the candidate has a dead time, D_TDON = 1)."""
    vt = terminal_voltage(D, i, eqp, eqpp)
    ifd = field_current(D, i, eqp, eqpp, vt)
    hi, lo = ceilings(D, i, eqp, eqpp)
    dxm, dx1, dx2, de, fld, dxf, dxe = exciter(D, i, uref, vrd, xm, x1, x2, ef, xf, xe, vt, ifd, hi, lo, st4)
    # saturation of E'q (the reference model) or, with a GENROU-like flux share, of Vt = psi''
    satvt = D[D_SATVT, i]
    d = eqp + satvt * (vt - eqp) - D[D_SATA, i]
    d = d if d > 0.0 else 0.0
    deqp = (fld - eqp - D[D_KDA, i] * (eqp - eqpp) - D[D_SATB, i] * d * d) * D[D_ITD0P, i]
    deqpp = (eqp - eqpp) * D[D_ITD0PP, i]
    dvt = deqpp + D[D_KPP, i] * (deqp - deqpp)
    # non-windup ceiling: where the limits move, with Vt for a bus-fed exciter, with Ifd through
    # the commutation drop; fixed limits do not move. Not on ESST4B's regulator lag (its ceilings
    # act on VM)
    if st4 != ST4_ALL:
        dsc = D[D_VRVT, i] * dvt
        dhi = D[D_VRMAX, i] * dsc - D[D_KC, i] * (deqp + D[D_KDA, i] * (deqp - deqpp)
                                                  + 2.0 * D[D_SATB, i] * d * (deqp + satvt * (dvt - deqp)))
        de = non_windup(D, i, de, ef, hi, lo, dhi, D[D_VRMIN, i] * dsc)
    return dxm, dx1, dx2, de, deqp, deqpp, dxf, dxe


@njit()
def rhs_ref(D, i, uref, vrd, xm, x1, x2, ef, eqp, eqpp, limited):
    """`rhs` of the reference blocks only (6 states): the fast path of a chunk none of whose
    candidates uses a block of the standard structures (`run_chunk`). Derivatives of (xm, x1, x2,
    efd, E'q, E''q); branch-free so candidate loops vectorise.

    `vrd` is the delayed VR (used when the candidate has a dead time, D_TDON = 1). `limited`, a
    constant of the caller's code: False leaves out the slew limit and the ceilings, for
    candidates that have neither (RATE, VRMAX infinite, VRMIN minus infinite: the same numbers)."""
    tron = D[D_TRON, i]
    vm = tron * xm + (1.0 - tron) * eqpp
    e = uref - vm
    r1 = D[D_R1, i]
    r2 = D[D_R2, i]
    y1 = x1 + r1 * (e - x1)
    dxm = (eqpp - xm) * D[D_ITR, i]
    dx1 = (e - x1) * D[D_IT2, i]
    dx2 = (y1 - x2) * D[D_IT4, i]
    tdon = D[D_TDON, i]
    ite = D[D_ITE, i]
    # the lag's input (VR - efd) / TE, VR = KAVR y2 (or the delayed VR), written out as a sum of
    # terms that do not wait on each other: the lead-lags' chain e -> y1 -> y2 -> VR, one after
    # the other, is what a step of a few candidates waits on (the loop is bound by that latency,
    # not by its arithmetic; the coefficients come off the chain)
    g = ite * (1.0 - tdon) * D[D_KAVR, i]
    de = (g * r2 * r1) * e + (g * r2 * (1.0 - r1)) * x1 + (g * (1.0 - r2)) * x2 + (ite * tdon) * vrd - ite * ef
    d = eqp - D[D_SATA, i]
    d = d if d > 0.0 else 0.0
    deqp = (ef - eqp - D[D_SATB, i] * d * d) * D[D_ITD0P, i]
    deqpp = (eqp - eqpp) * D[D_ITD0PP, i]
    if not limited:
        return dxm, dx1, dx2, de, deqp, deqpp
    # the slew limit +-RATE, then the non-windup ceiling: at a limit efd may not pass it, and
    # follows it where it moves (with Vt for a bus-fed exciter, with Ifd through the commutation
    # drop); fixed limits do not move
    hi, lo = ceilings_ref(D, i, eqp, eqpp)
    dsc = D[D_VRVT, i] * deqpp
    dhi = D[D_VRMAX, i] * dsc - D[D_KC, i] * (1.0 + 2.0 * D[D_SATB, i] * d) * deqp
    dlo = D[D_VRMIN, i] * dsc
    # min(de, RATE), max(., -RATE), min(., dhi) at the upper ceiling, max(., dlo) at the lower one
    # is max(min(de, up), down) with up = min(RATE, dhi) and down = max(min(-RATE, dhi), dlo) (dhi
    # +inf off the upper ceiling, dlo -inf off the lower): the same value, with two selects on
    # the chain from de to the next stage instead of four. Plain compare-and-select (numba's
    # min/max carry NaN branches that stop the vectoriser). dhi, dlo are NaN only for an infinite
    # ceiling that does not move (inf * 0), which efd never reaches: the selection replaces them,
    # so they need no guard on the chain (`non_windup` keeps its guard)
    rate = D[D_RATE, i]
    dhi = dhi if ef >= hi else math.inf
    dlo = dlo if ef <= lo else -math.inf
    up = rate if rate < dhi else dhi
    down = -rate if -rate < dhi else dhi
    down = down if down > dlo else dlo
    de = de if de < up else up
    de = de if de > down else down
    return dxm, dx1, dx2, de, deqp, deqpp
