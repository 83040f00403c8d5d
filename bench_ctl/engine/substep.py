"""A step with jumps inside: where the setpoint jumps at a fitted edge instant, and where the dead
time's delayed VR jumps (a setpoint change, on a sample or at a fitted instant, seen through a
delay that is not a whole number of steps). Such a step of one candidate is redone from t_k in RK4
sub-steps between the jumps (`breaks` finds them, `substep` steps them).
"""
from __future__ import annotations

import math

from .history import H_JF, H_VJL, H_VJR, H_VR_L, H_VR_R, K_KDL, K_KDR, K_KEF, K_KF, delayed_vr
from .jit import njit
from .layout import D_EDGE0, D_RAMP, D_TD, D_VR0, EDGE_EPS, R_FLD, R_VS
from .step import (
    exc_load,
    exc_store,
    exc_vr,
    gen_alg_load,
    gen_alg_store,
    gen_load,
    gen_store,
    pss_load,
    pss_store,
    rk4,
)


@njit(inline=True)
def breaks(w, edges, c, k, dt, inwin, td_on):
    """The jumps inside step k of candidate c, sorted, into w.brk (row 0 the fraction of the step,
    row 1 the setpoint's jump there, 0 for a delayed jump); returns (how many, the dead time's
    read position base = k - TD / dt)."""
    D, hist, bs, bj = w.D, w.hist, w.brk[0], w.brk[1]
    L = w.meta[2]
    nbrk = 0
    if inwin:
        for j in range(edges.index.shape[0]):
            ke = (edges.nominal_s[j] + D[D_EDGE0 + edges.slot[j], c]) / dt
            if k + EDGE_EPS < ke < k + 1.0 - EDGE_EPS:
                bs[nbrk] = ke - k
                bj[nbrk] = edges.jump[j]
                nbrk += 1
    base = 0.0
    if td_on:
        base = k - D[D_TD, c] / dt
        j0 = int(math.floor(base))
        frac = base - j0
        if j0 + 1 < k:
            # the delayed sample boundary: a break only where VR jumps there (a setpoint change on
            # that sample); elsewhere VR is continuous, only its slope between the samples changes,
            # and the step's three delayed reads carry it
            q1 = (j0 + 1) % L
            if frac >= EDGE_EPS and hist[H_VR_R, c, q1] != hist[H_VR_L, c, q1]:
                bs[nbrk] = 1.0 - frac
                bj[nbrk] = 0.0
                nbrk += 1
            if j0 >= 0:
                f = hist[H_JF, c, j0 % L]
                if f > frac + EDGE_EPS:
                    bs[nbrk] = f - frac
                    bj[nbrk] = 0.0
                    nbrk += 1
            if j0 + 1 >= 0:
                f = hist[H_JF, c, (j0 + 1) % L]
                if f > 0.0 and f < frac - EDGE_EPS:
                    bs[nbrk] = 1.0 - frac + f
                    bj[nbrk] = 0.0
                    nbrk += 1
    for a in range(1, nbrk):  # insertion sort of the few break points
        sv = bs[a]
        jv = bj[a]
        b = a - 1
        while b >= 0 and bs[b] > sv:
            bs[b + 1] = bs[b]
            bj[b + 1] = bj[b]
            b -= 1
        bs[b + 1] = sv
        bj[b + 1] = jv
    return nbrk, base


@njit
def substep(w, c, k, dt, nbrk, target, uref, base, td_on, skew_on, ext):
    """Step k of candidate c from its state at t_k (w.S0, w.R0) in RK4 sub-steps between the break
    points (`breaks`): the setpoint's target jumps there by its jump, the delayed VR is read on
    either side. Writes the state and readout at t_k+1 (w.S, w.R); returns (the reference at
    t_k+1, the output's slope at t_k and at t_k+1). With `td_on` the regulator output's limits at
    a setpoint jump are kept for later delayed reads; with `skew_on` the efd kink at the (first)
    jump for the skew's readout."""
    D, hist, skh, bs, bj = w.D, w.hist, w.skh, w.brk[0], w.brk[1]
    L, Ls = w.meta[2], w.meta[3]
    xa, xg, xs = exc_load(w.S0, c), gen_load(w.S0, c), pss_load(w.S0, c)
    alg = gen_alg_load(w.R0, c)
    fld = w.R0[R_FLD, c]
    vs = w.R0[R_VS, c]
    ramp = D[D_RAMP, c]
    ramp_on = ramp < 1.0e300
    e0 = D[D_VR0, c]
    tg = target
    ur = uref
    sa = 0.0
    d_start = 0.0
    d_end = 0.0
    first = True
    pending = False
    for q in range(nbrk + 1):
        sb = bs[q] if q < nbrk else 1.0
        h = (sb - sa) * dt
        if h > 1.0e-12 * dt:
            if ramp_on:
                st = tg - ur
                lim = ramp * h
                st = st if st < lim else lim
                st = st if st > -lim else -lim
                ua = ur
                ub = ur + st
            else:
                ua = tg
                ub = tg
            v = (0.0, 0.0, 0.0)
            if td_on:
                v = (delayed_vr(hist, c, L, base + sa, k, e0, False),
                     delayed_vr(hist, c, L, base + 0.5 * (sa + sb), k, e0, False),
                     delayed_vr(hist, c, L, base + sb, k, e0, True))
            r = rk4(D, c, (k + sa, sb - sa, h), (ua, ub), v, xa, xg, xs, alg, ext)
            xa, xg, xs, alg, fld, vs = r[0], r[1], r[2], r[3], r[4], r[5]
            if first:
                d_start = r[6]
                first = False
            if pending:
                skh[K_KDR, c, k % Ls] = r[6]
                pending = False
            d_end = r[7]
            ur = ub
        if q < nbrk and bj[q] != 0.0:
            if td_on and not ramp_on:  # VR jumps here: keep both limits for the delayed reads
                hist[H_VJL, c, k % L] = exc_vr(D, c, tg, xa, alg[0], alg[1])
                hist[H_VJR, c, k % L] = exc_vr(D, c, tg + bj[q], xa, alg[0], alg[1])
                hist[H_JF, c, k % L] = sb
            if skew_on and skh[K_KF, c, k % Ls] == 0.0 and not first:
                skh[K_KF, c, k % Ls] = sb
                skh[K_KEF, c, k % Ls] = fld
                skh[K_KDL, c, k % Ls] = d_end
                pending = True
            tg += bj[q]
        sa = sb
    exc_store(w.S, c, xa)
    gen_store(w.S, c, xg)
    pss_store(w.S, c, xs)
    gen_alg_store(w.R, c, alg)
    w.R[R_FLD, c] = fld
    w.R[R_VS, c] = vs
    return (ur if ramp_on else tg), d_start, d_end

