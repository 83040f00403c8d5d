"""The chunk runner: one chunk of candidates over the whole record (time outer, candidates inner),
and the parallel loop over chunks.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from .blocks import avr, delayed_vr, field_voltage, hermite, rate_feedback, steady_state, terminal_voltage
from .jit import njit
from .layout import (
    BLOWUP,
    CHUNK,
    D_ACON,
    D_DCON,
    D_EDGE0,
    D_GAIN,
    D_ITR,
    D_KDA,
    D_KFT,
    D_KI1,
    D_KPP,
    D_LIMOUT,
    D_OUT0,
    D_P1,
    D_PID,
    D_RAMP,
    D_RATE,
    D_SKEW,
    D_ST4,
    D_TD,
    D_UREF0,
    D_VALID,
    D_VR0,
    D_VRIN,
    D_VRMAX,
    D_VRMIN,
    EDGE_EPS,
    N_STATES,
)
from .rk4 import rk4_all, rk4_all_ref, rk4_all_st4, rk4_all_st4_only, run_span_ref, run_span_unlimited, split_step


class Record(NamedTuple):
    """The record the candidates run on: the setpoint series, its value before the test, the
    step (s), the measured efd and Vt and their weights in the objective (0: not scored)."""
    usetp: np.ndarray
    usetp_pre: float
    dt: float
    efd: np.ndarray
    vt: np.ndarray
    w_efd: float
    w_vt: float


class Switches(NamedTuple):
    """What a run computes: `store` the traces; the dead time, recorder skew, setpoint ramp of
    some candidate (their code is skipped otherwise)
    the lengths of the dead time's and the
    skew's history rings (steps)."""
    store: bool
    any_delay: bool
    any_skew: bool
    any_ramp: bool
    ring: int
    ring_skew: int


class Edges(NamedTuple):
    """The record's setpoint edges (`EdgeSpec`: sample index, jump, nominal instant, slot of the
    candidate's offset) and the steps where some candidate's setpoint differs from the record's."""
    index: np.ndarray
    jump: np.ndarray
    nominal_s: np.ndarray
    slot: np.ndarray
    window: np.ndarray


class Outputs(NamedTuple):
    """What the kernel returns, one row (or entry) a candidate: efd, Vt traces ((1, 1) when not
    stored), sums of squared errors, the objective, the failure step (-1: none)."""
    efd: np.ndarray
    vt: np.ndarray
    sse_efd: np.ndarray
    sse_vt: np.ndarray
    obj: np.ndarray
    fail_step: np.ndarray



@njit()
def park_blown(D, S, mag, failed, fail_step, lo, m, k):
    """Mark the candidates whose state's magnitude `mag` left the sane range failed at step k
    (unless they were already) and park their state at the steady state, so that its arithmetic
    stays finite."""
    for c in range(m):
        if not (mag[c] < BLOWUP):
            if failed[c] == 0.0:
                failed[c] = 1.0
                fail_step[lo + c] = k
            x = steady_state(D, c)
            for q in range(N_STATES):
                S[q, c] = x[q]


@njit(inline=False, nogil=True)
def run_chunk(D, lo, hi, record, switches, edges, out):
    """Candidates lo..hi-1 (D: their columns of the transposed derived matrix) over the record:
    writes their columns of `out`. See `Record`, `Switches`, `Edges`, `Outputs`."""
    usetp, usetp_pre, dt, efd_meas, vt_meas, w_efd, w_vt = record
    store, any_delay, any_skew, any_ramp, L, Ls = switches
    eidx, ejump, etn, eslot, ewin = edges
    efd_out, vt_out, sse_efd, sse_vt, obj, fail_step = out
    T = usetp.shape[0]
    m = hi - lo
    # the RK4 loops see every array with CHUNK columns (`fixed_views`); columns m.. are never used
    Dm = D
    D = np.zeros((Dm.shape[0], CHUNK))
    D[:, :m] = Dm
    S = np.zeros((10, CHUNK))       # states xm, x1, x2, VR lag, E'q, E''q, rate feedback, DC Efd;
    #                                 the output's derivative at step start, end
    S0 = np.empty((8, m))           # state at t_k, kept for split steps
    uref = np.empty(m)
    U = np.zeros((2, CHUNK))        # setpoint reference at the start and the end of the step
    ua = U[0]
    ub = U[1]
    V = np.zeros((3, CHUNK))        # delayed VR at stage times 0, 1/2, 1
    W = np.zeros((4, CHUNK))        # per candidate: the output, failed (1.0), the sum of squared
    out_e = W[0]                    # efd errors, the state's magnitude after a step (blow-up test)
    failed = W[1]
    sse_e = W[2]
    mag = W[3]
    e_first = np.zeros(m)
    e_last = np.zeros(m)
    # VR right/left limits per step (dead time)
    vr_r = np.zeros((m, L))
    vr_l = np.zeros((m, L))
    # a jump inside a step
    jf = np.zeros((m, L))
    vjl = np.zeros((m, L))
    vjr = np.zeros((m, L))
    ne = eidx.shape[0]
    tg0 = np.empty(m)
    cross = np.zeros(m, np.bool_)
    bs = np.empty(ne + 3)
    bj = np.empty(ne + 3)
    # efd history (skew)
    ef_h = np.zeros((m, Ls))
    der_r = np.zeros((m, Ls))
    der_l = np.zeros((m, Ls))
    kf = np.zeros((m, Ls))
    kef = np.zeros((m, Ls))
    kdl = np.zeros((m, Ls))
    kdr = np.zeros((m, Ls))
    for c in range(m):
        i = lo + c
        x = steady_state(D, c)
        for q in range(N_STATES):
            S[q, c] = x[q]
        uref[c] = D[D_UREF0, c]
        out_e[c] = D[D_GAIN, c] * D[D_OUT0, c]
        if D[D_VALID, c] == 0.0:
            failed[c] = 1.0
            fail_step[i] = 0
        for q in range(L):
            vr_r[c, q] = D[D_VR0, c]
            vr_l[c, q] = D[D_VR0, c]
        for q in range(Ls):
            ef_h[c, q] = D[D_OUT0, c]
    # the full blocks when some candidate of the chunk uses a block of the standard structures
    # and the potential-source stage: where some candidate has it, or for all (an invalid candidate,
    # failed from the start, does not count: what it computes is not used)
    full = False
    st4 = False
    st4_all = True
    for c in range(m):
        if (D[D_KFT, c] != 0.0 or D[D_DCON, c] != 0.0 or D[D_LIMOUT, c] != 0.0 or D[D_KPP, c] != 0.0
                or D[D_KDA, c] != 0.0 or D[D_ST4, c] != 0.0 or D[D_VRIN, c] != 0.0 or D[D_ACON, c] != 0.0
                or D[D_P1, c] != 0.0 or D[D_KI1, c] != 0.0 or D[D_PID, c] != 0.0):
            full = True
        if D[D_ST4, c] != 0.0:
            st4 = True
        if D[D_VALID, c] != 0.0 and (D[D_ST4, c] == 0.0 or D[D_LIMOUT, c] == 0.0 or D[D_DCON, c] != 0.0):
            st4_all = False
    ref = not full and not st4
    # the steps of a reference-only chunk where nothing else acts run in one compiled loop
    # (`run_span_ref`): outside the edges' windows, when no candidate has a dead time, skew or
    # ramp and Vt is not scored
    span = ref and not any_skew and not any_delay and not any_ramp and w_vt == 0.0
    unlimited = True   # no candidate has a slew limit or a finite ceiling
    for c in range(m):
        if D[D_RATE, c] < math.inf or D[D_VRMAX, c] < math.inf or D[D_VRMIN, c] > -math.inf:
            unlimited = False
    resume = 0   # the first step this loop runs itself (the ones before ran in a span)
    for k in range(T):
        if k < resume:
            continue
        if span and 0 < k < T - 1 and not (ne > 0 and ewin[k] != 0):
            k1 = k + 1
            while k1 < T - 1 and not (ne > 0 and ewin[k1] != 0):
                k1 += 1
            if unlimited:
                resume = run_span_unlimited(D, S, W, usetp, efd_meas, k, k1, usetp_pre, dt, m, store, efd_out,
                                            vt_out, lo)
            else:
                resume = run_span_ref(D, S, W, usetp, efd_meas, k, k1, usetp_pre, dt, m, store, efd_out, vt_out, lo)
            if resume < k1:
                park_blown(D, S, mag, failed, fail_step, lo, m, resume)
            continue
        # ---- record sample k (states at t_k); failed candidates hold their last output ----
        if any_skew:
            for c in range(m):
                i = lo + c
                skew = D[D_SKEW, c]
                y = field_voltage(D, c, S[3, c], S[4, c], S[5, c], S[6, c], S[7, c])
                if skew > 0.0:
                    tau = k - skew / dt
                    if tau <= 0.0:
                        y = D[D_OUT0, c]
                    else:
                        j = int(math.floor(tau))
                        if j < k:
                            q = j % Ls
                            s = tau - j
                            f = kf[c, q]
                            if f <= 0.0:
                                y = hermite(ef_h[c, q], der_r[c, q], ef_h[c, (j + 1) % Ls],
                                             der_l[c, (j + 1) % Ls], s, dt)
                            elif s < f:  # a setpoint jump inside that step: the efd kink kept
                                y = hermite(ef_h[c, q], der_r[c, q], kef[c, q], kdl[c, q], s / f, f * dt)
                            else:
                                y = hermite(kef[c, q], kdr[c, q], ef_h[c, (j + 1) % Ls],
                                             der_l[c, (j + 1) % Ls], (s - f) / (1.0 - f), (1.0 - f) * dt)
                if failed[c] == 0.0:
                    out_e[c] = D[D_GAIN, c] * y
        elif ref:
            # the reference blocks alone (no output clamp, DC or AC exciter, potential source):
            # the output is the regulator lag's state
            for c in range(m):
                y = D[D_GAIN, c] * S[3, c]
                out_e[c] = out_e[c] if failed[c] != 0.0 else y
        else:
            for c in range(m):
                if failed[c] == 0.0:
                    out_e[c] = D[D_GAIN, c] * field_voltage(D, c, S[3, c], S[4, c], S[5, c], S[6, c], S[7, c])
        if store:
            for c in range(m):
                efd_out[lo + c, k] = out_e[c]
                vt_out[lo + c, k] = terminal_voltage(D, c, S[4, c], S[5, c])
        if w_efd > 0.0:
            em = efd_meas[k]
            for c in range(m):
                d = out_e[c] - em
                sse_e[c] += d * d
            if k == 0 or k == T - 1:
                for c in range(m):
                    d = out_e[c] - em
                    if k == 0:
                        e_first[c] += w_efd * d * d
                    else:
                        e_last[c] += w_efd * d * d
        if w_vt > 0.0:
            vmeas = vt_meas[k]
            for c in range(m):
                d = terminal_voltage(D, c, S[4, c], S[5, c]) - vmeas
                sse_vt[lo + c] += d * d
            if k == 0 or k == T - 1:
                for c in range(m):
                    d = terminal_voltage(D, c, S[4, c], S[5, c]) - vmeas
                    if k == 0:
                        e_first[c] += w_vt * d * d
                    else:
                        e_last[c] += w_vt * d * d
        if k == T - 1:
            break
        # ---- setpoint over [t_k, t_k+1): ZOH target (each edge moved to its fitted instant),
        # or a ramp towards it ----
        base_u = usetp[k] - usetp_pre
        for c in range(m):
            tg0[c] = D[D_UREF0, c] + base_u
        inwin = ne > 0 and ewin[k] != 0
        if inwin:
            for c in range(m):
                corr = 0.0
                cr = False
                for j in range(ne):
                    ke = (etn[j] + D[D_EDGE0 + eslot[j], c]) / dt
                    fit_on = 1.0 if ke <= k + EDGE_EPS else 0.0
                    nom_on = 1.0 if k >= eidx[j] else 0.0
                    corr += ejump[j] * (fit_on - nom_on)
                    if k + EDGE_EPS < ke < k + 1.0 - EDGE_EPS:
                        cr = True
                tg0[c] += corr
                cross[c] = cr
        for c in range(m):
            ua[c] = tg0[c]
            ub[c] = tg0[c]
        if any_ramp:
            for c in range(m):
                i = lo + c
                ramp = D[D_RAMP, c]
                if ramp < 1.0e300:
                    step = min(max(ub[c] - uref[c], -ramp * dt), ramp * dt)
                    ua[c] = uref[c]
                    ub[c] = uref[c] + step
        # ---- dead time: VR right limit at t_k, delayed VR at the stage times ----
        if any_delay:
            for c in range(m):
                i = lo + c
                td = D[D_TD, c]
                if td > 0.0:
                    vm0 = S[0, c] if D[D_ITR, c] > 0.0 else terminal_voltage(D, c, S[4, c], S[5, c])
                    vf = rate_feedback(D, c, S[3, c], S[6, c], S[7, c], S[4, c], S[5, c])
                    vr_r[c, k % L] = avr(D, c, ua[c], vm0, S[1, c], S[2, c], vf)[0]
                    jf[c, k % L] = 0.0
                    base = k - td / dt
                    V[0, c] = delayed_vr(vr_r, vr_l, jf, vjl, vjr, c, L, base, k, D[D_VR0, c], False)
                    V[1, c] = delayed_vr(vr_r, vr_l, jf, vjl, vjr, c, L, base + 0.5, k, D[D_VR0, c], False)
                    V[2, c] = delayed_vr(vr_r, vr_l, jf, vjl, vjr, c, L, base + 1.0, k, D[D_VR0, c], True)
        # ---- RK4 step, one fused straight-line body per candidate (vectorises across c) ----
        if any_skew:
            for c in range(m):
                ef_h[c, k % Ls] = field_voltage(D, c, S[3, c], S[4, c], S[5, c], S[6, c], S[7, c])
                kf[c, k % Ls] = 0.0
        if any_delay or inwin:
            for c in range(m):
                for q in range(8):
                    S0[q, c] = S[q, c]
        if st4 and st4_all:
            rk4_all_st4_only(D, S, U, V, dt, m)
        elif st4:
            rk4_all_st4(D, S, U, V, dt, m)
        elif full:
            rk4_all(D, S, U, V, dt, m)
        else:
            rk4_all_ref(D, S, U, V, dt, m)
        for c in range(m):
            uref[c] = ub[c]
        # ---- steps with a jump inside: the setpoint at a fitted edge instant, the delayed VR at
        # a delay that is not a whole number of steps; such a step is redone from t_k in
        # sub-steps between the jumps ----
        if any_delay or inwin:
            for c in range(m):
                if failed[c] != 0.0:
                    continue
                nbrk = 0
                if inwin and cross[c]:
                    for j in range(ne):
                        ke = (etn[j] + D[D_EDGE0 + eslot[j], c]) / dt
                        if k + EDGE_EPS < ke < k + 1.0 - EDGE_EPS:
                            bs[nbrk] = ke - k
                            bj[nbrk] = ejump[j]
                            nbrk += 1
                td = D[D_TD, c]
                base = 0.0
                td_on = any_delay and td > 0.0
                if td_on:
                    base = k - td / dt
                    j0 = int(math.floor(base))
                    frac = base - j0
                    if j0 + 1 < k:
                        # the delayed sample boundary: a break only where VR jumps there (a
                        # setpoint change on that sample). Elsewhere VR is continuous, only its
                        # slope between the samples changes, and the step's three delayed reads
                        # (`V`) carry it: a break there cost a scalar redo of every step of
                        # every candidate with a dead time (docs/benchmarks.md, "The kernel")
                        q1 = (j0 + 1) % L
                        if frac >= EDGE_EPS and vr_r[c, q1] != vr_l[c, q1]:
                            bs[nbrk] = 1.0 - frac
                            bj[nbrk] = 0.0
                            nbrk += 1
                        if j0 >= 0:
                            f = jf[c, j0 % L]
                            if f > frac + EDGE_EPS:
                                bs[nbrk] = f - frac
                                bj[nbrk] = 0.0
                                nbrk += 1
                        if j0 + 1 >= 0:
                            f = jf[c, (j0 + 1) % L]
                            if f > 0.0 and f < frac - EDGE_EPS:
                                bs[nbrk] = 1.0 - frac + f
                                bj[nbrk] = 0.0
                                nbrk += 1
                if nbrk == 0:
                    continue
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
                r = split_step(D, c, k, dt, S, S0, nbrk, bs, bj, tg0[c], ua[c], base, td_on, L,
                                vr_r, vr_l, jf, vjl, vjr, any_skew, Ls, kf, kef, kdl, kdr)
                uref[c] = r[0]
                ub[c] = r[0]
                S[8, c] = r[1]
                S[9, c] = r[2]
        if any_skew:
            for c in range(m):
                der_r[c, k % Ls] = S[8, c]
                der_l[c, (k + 1) % Ls] = S[9, c]
        # a blow-up is rare: found by a loop without calls or branches, handled by one with them
        blown = 0
        for c in range(m):
            mag[c] = (abs(S[0, c]) + abs(S[1, c]) + abs(S[2, c]) + abs(S[3, c]) + abs(S[4, c]) + abs(S[5, c])
                      + abs(S[6, c]) + abs(S[7, c]))
            blown += 0 if mag[c] < BLOWUP else 1
        if blown:
            park_blown(D, S, mag, failed, fail_step, lo, m, k + 1)
        if any_skew:
            for c in range(m):
                ef_h[c, (k + 1) % Ls] = field_voltage(D, c, S[3, c], S[4, c], S[5, c], S[6, c], S[7, c])
        if any_delay:
            for c in range(m):
                i = lo + c
                if D[D_TD, c] > 0.0:  # left limit of VR at t_k+1 (state k+1, input of step k)
                    vm = S[0, c] if D[D_ITR, c] > 0.0 else terminal_voltage(D, c, S[4, c], S[5, c])
                    vf = rate_feedback(D, c, S[3, c], S[6, c], S[7, c], S[4, c], S[5, c])
                    vr_l[c, (k + 1) % L] = avr(D, c, ub[c], vm, S[1, c], S[2, c], vf)[0]
    for c in range(m):
        i = lo + c
        if w_efd > 0.0:  # (a span sums the efd errors whatever the weight)
            sse_efd[i] = sse_e[c]
        obj[i] = dt * (w_efd * sse_efd[i] + w_vt * sse_vt[i] - 0.5 * (e_first[c] + e_last[c]))


@njit(inline=False, fastmath=False, parallel=True, nogil=True)
def run_chunks(D, chunk, record, switches, edges, out):
    """Every chunk of `chunk` candidates of D (transposed derived matrix), in parallel."""
    n = D.shape[1]
    nchunks = (n + chunk - 1) // chunk
    for b in nb.prange(nchunks):
        lo = b * chunk
        hi = min(n, lo + chunk)
        run_chunk(np.ascontiguousarray(D[:, lo:hi]), lo, hi, record, switches, edges, out)
