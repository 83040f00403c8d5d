"""The no-load reference structure's fast path: a span of samples where nothing but its own blocks
acts (no dead time, skew, setpoint ramp or fitted edge; efd scored, nothing else) in one compiled
loop over time with a vectorised loop over the candidates inside: what the chunk runner does step
by step, without its per-step calls and small loops, which cost about as much as a step of one
candidate. The paper's unit spends most of an identification here.

Its right-hand side is the reference blocks' on the no-load generator, written out as a sum of
terms that do not wait on each other (the lead-lags' chain e -> y1 -> y2 -> VR is what a step of a
few candidates waits on), and `limited` (a constant of each loop's code) leaves out the slew limit
and the ceilings for candidates that have neither: the same numbers without a third of a step's
arithmetic.
"""
from __future__ import annotations

import math

from .jit import njit, specialise
from .layout import (
    BLOWUP,
    CHUNK,
    D_GAIN,
    D_IT2,
    D_IT4,
    D_ITD0P,
    D_ITD0PP,
    D_ITE,
    D_ITR,
    D_KAVR,
    D_KC,
    D_R1,
    D_R2,
    D_RATE,
    D_SATA,
    D_SATB,
    D_TDON,
    D_TRON,
    D_UREF0,
    D_VRMAX,
    D_VRMIN,
    D_VRVT,
    N_DERIVED,
)
from .step import N_ROWS, fixed_view, view_d, view_s

#: the rows of a chunk's W array: the efd output (held where failed), failed (1.0), the sum of
#: squared efd errors, the state's magnitude after a step (the blow-up test)
W_OUT, W_FAILED, W_SSE, W_MAG = range(4)
view_w = fixed_view(4)


@njit
def _ceilings(D, c, eqp, eqpp):
    """Exciter ceilings (hi, lo) of the reference model: VRMAX, VRMIN, scaled by Vt = E''q when
    VRVT = 1 (bus-fed), the upper one less KC*Ifd, Ifd = E'q + Sat(E'q)."""
    d = eqp - D[D_SATA, c]
    d = d if d > 0.0 else 0.0
    ifd = eqp + D[D_SATB, c] * d * d
    sc = 1.0 + D[D_VRVT, c] * (eqpp - 1.0)
    sc = sc if sc > 1.0e-3 else 1.0e-3
    return D[D_VRMAX, c] * sc - D[D_KC, c] * ifd, D[D_VRMIN, c] * sc


@njit
def _rhs(D, c, u, x0, x1, x2, ef, eqp, eqpp, limited):
    """Derivatives of (xm, x1, x2, efd, E'q, E''q) of the reference blocks on the no-load
    generator; `limited` False leaves out the slew limit and the ceilings."""
    tron = D[D_TRON, c]
    e = u - (tron * x0 + (1.0 - tron) * eqpp)
    r1 = D[D_R1, c]
    r2 = D[D_R2, c]
    y1 = x1 + r1 * (e - x1)
    dxm = (eqpp - x0) * D[D_ITR, c]
    dx1 = (e - x1) * D[D_IT2, c]
    dx2 = (y1 - x2) * D[D_IT4, c]
    ite = D[D_ITE, c]
    g = ite * (1.0 - D[D_TDON, c]) * D[D_KAVR, c]
    de = (g * r2 * r1) * e + (g * r2 * (1.0 - r1)) * x1 + (g * (1.0 - r2)) * x2 - ite * ef
    d = eqp - D[D_SATA, c]
    d = d if d > 0.0 else 0.0
    deqp = (ef - eqp - D[D_SATB, c] * d * d) * D[D_ITD0P, c]
    deqpp = (eqp - eqpp) * D[D_ITD0PP, c]
    if not limited:
        return dxm, dx1, dx2, de, deqp, deqpp
    # min(de, RATE), max(., -RATE), min(., dhi) at the upper ceiling, max(., dlo) at the lower one
    # is max(min(de, up), down) with up = min(RATE, dhi) and down = max(min(-RATE, dhi), dlo) (dhi
    # +inf off the upper ceiling, dlo -inf off the lower): the same value, with two selects on
    # the chain from de to the next stage instead of four. dhi, dlo are NaN only for an infinite
    # ceiling that does not move (inf * 0), which efd never reaches: the selection replaces them
    hi, lo = _ceilings(D, c, eqp, eqpp)
    dsc = D[D_VRVT, c] * deqpp
    dhi = D[D_VRMAX, c] * dsc - D[D_KC, c] * (1.0 + 2.0 * D[D_SATB, c] * d) * deqp
    dlo = D[D_VRMIN, c] * dsc
    rate = D[D_RATE, c]
    dhi = dhi if ef >= hi else math.inf
    dlo = dlo if ef <= lo else -math.inf
    up = rate if rate < dhi else dhi
    down = -rate if -rate < dhi else dhi
    down = down if down > dlo else dlo
    de = de if de < up else up
    de = de if de > down else down
    return dxm, dx1, dx2, de, deqp, deqpp


@njit
def _rk4(D, c, u, x0, x1, x2, x3, x4, x5, h, limited):
    """One RK4 step of length h at reference u (`_rhs`), the lag held inside its ceilings."""
    h2 = 0.5 * h
    a = _rhs(D, c, u, x0, x1, x2, x3, x4, x5, limited)
    b = _rhs(D, c, u, x0 + h2 * a[0], x1 + h2 * a[1], x2 + h2 * a[2], x3 + h2 * a[3], x4 + h2 * a[4], x5 + h2 * a[5],
             limited)
    k = _rhs(D, c, u, x0 + h2 * b[0], x1 + h2 * b[1], x2 + h2 * b[2], x3 + h2 * b[3], x4 + h2 * b[4], x5 + h2 * b[5],
             limited)
    d = _rhs(D, c, u, x0 + h * k[0], x1 + h * k[1], x2 + h * k[2], x3 + h * k[3], x4 + h * k[4], x5 + h * k[5],
             limited)
    h6 = h / 6.0
    y3 = x3 + h6 * (a[3] + 2 * b[3] + 2 * k[3] + d[3])
    y4 = x4 + h6 * (a[4] + 2 * b[4] + 2 * k[4] + d[4])
    y5 = x5 + h6 * (a[5] + 2 * b[5] + 2 * k[5] + d[5])
    if limited:
        hi, lo = _ceilings(D, c, y4, y5)
        y3 = y3 if y3 > lo else lo
        y3 = y3 if y3 < hi else hi
    return (x0 + h6 * (a[0] + 2 * b[0] + 2 * k[0] + d[0]), x1 + h6 * (a[1] + 2 * b[1] + 2 * k[1] + d[1]),
            x2 + h6 * (a[2] + 2 * b[2] + 2 * k[2] + d[2]), y3, y4, y5)


#: the span's limits: a constant of each of its two variants (`span_limited`, `span_unlimited`)
LIMITED = True


@njit(vector=True)
def span(D, S, W, usetp, usetp_pre, dt, efd_meas, k0, k1, j0, m, traces, keep, lo):
    """Samples and steps k0..k1-1 of a chunk of reference-structure candidates where nothing else
    acts: each sample's efd into the squared error (W_SSE; with traces kept, into rows keep[0]
    (efd) and keep[1] (Vt) of `traces`, columns k - j0), then the step. Returns the step count
    done: k1, or the step after which some candidate blew up (its state is at t_k+1; the caller
    parks it). Run as `span_limited`, or `span_unlimited` for a chunk none of whose candidates
    has a slew limit or a finite ceiling (the paper's unit)."""
    if (D.shape[0] != N_DERIVED or S.shape[0] != N_ROWS or W.shape[0] != 4
            or D.shape[1] != CHUNK or S.shape[1] != CHUNK or W.shape[1] != CHUNK):
        raise ValueError("engine chunk arrays of the wrong shape")
    D = view_d(D)
    S = view_s(S)
    W = view_w(W)
    ke, kv = keep[0], keep[1]
    for k in range(k0, k1):
        em = efd_meas[k - j0]
        base_u = usetp[k - j0] - usetp_pre
        if ke >= 0 or kv >= 0:  # a loop of its own: a trace's stores in the loop below stop its vectoriser
            for c in range(m):
                y = D[D_GAIN, c] * S[3, c]
                if ke >= 0:
                    traces[ke, lo + c, k - j0] = W[W_OUT, c] if W[W_FAILED, c] != 0.0 else y
                if kv >= 0:
                    traces[kv, lo + c, k - j0] = S[7, c]
        blown = 0
        for c in range(m):
            y = D[D_GAIN, c] * S[3, c]
            y = W[W_OUT, c] if W[W_FAILED, c] != 0.0 else y
            W[W_OUT, c] = y
            e = y - em
            W[W_SSE, c] += e * e
            r = _rk4(D, c, D[D_UREF0, c] + base_u, S[0, c], S[1, c], S[2, c], S[3, c], S[6, c], S[7, c], dt, LIMITED)
            S[0, c] = r[0]
            S[1, c] = r[1]
            S[2, c] = r[2]
            S[3, c] = r[3]
            S[6, c] = r[4]
            S[7, c] = r[5]
            mag = (abs(r[0]) + abs(r[1]) + abs(r[2]) + abs(r[3]) + abs(r[4]) + abs(r[5]) + abs(S[4, c])
                   + abs(S[5, c]))
            W[W_MAG, c] = mag
            blown += 0 if mag < BLOWUP else 1
        if blown:
            return k + 1
    return k1


span_limited = specialise(span, "limited", {"LIMITED": True})
span_unlimited = specialise(span, "unlimited", {"LIMITED": False})
