"""The chunk runner: a chunk of candidates over a record (time outer, candidates inner), whatever
the machine, and the parallel loop over chunks.

Per sample k: the recorded signals at the states of t_k (efd through the recorder's gain and skew,
Vt, P, Q, the stabiliser's output, Ifd; a failed candidate's held), their squared errors (the
trapezoid's half weight at both ends); the reference over [t_k, t_k+1) (the record's zero-order
hold with each setpoint edge at the candidate's fitted instant, or a ramp towards it); the dead
time's delayed VR at the stage times; one vectorised RK4 step of every candidate (`step.step_all`);
a step with a jump inside (a fitted edge instant, a delayed setpoint change) redone from t_k in
sub-steps between the jumps (`substep`); the histories the skew and the dead time read; a candidate
whose state leaves its sane range marked failed and parked at its initial state. Where nothing but
the no-load reference structure's own blocks act, spans of samples run in one compiled loop
(`span`).

A `Work` holds a chunk's state between calls: a run makes one per chunk and drops it; a plant keeps
one for its single candidate and advances it burst by burst (`advance`).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .exciter import ceilings_at
from .history import H_JF, H_VR_L, H_VR_R, K_DER_L, K_DER_R, K_EF, K_KF, delayed_vr, skewed
from .jit import njit
from .layout import (
    BLOWUP,
    CHUNK,
    D_EDGE0,
    D_GAIN,
    D_ITE,
    D_OUT0,
    D_RAMP,
    D_RATE,
    D_SKEW,
    D_TD,
    D_UREF0,
    D_VALID,
    D_VR0,
    EDGE_EPS,
    N_DERIVED,
    N_SCORED,
    N_SIGNALS,
    R_FLD,
    R_VS,
    S_EFD,
    S_IFD,
    S_P,
    S_Q,
    S_VS,
    S_VT,
)
from .span import W_FAILED, W_MAG, W_OUT, W_SSE, span_limited, span_unlimited
from .step import (
    N_INPUT,
    N_READOUT,
    N_ROWS,
    ROWS,
    exc_load,
    exc_park,
    exc_store,
    exc_vr,
    gen_alg_load,
    gen_alg_store,
    gen_flux,
    gen_load,
    gen_park,
    gen_signals,
    gen_store,
    gen_valid,
    pss_load,
    pss_park,
    pss_store,
    readout,
    step_all,
)
from .substep import breaks, substep

#: what a run can keep per sample (rows of `Out.keep`): the recorded signals (`layout.SIGNALS`,
#: the stabiliser's output among them), then what a plant reports besides: the field voltage
#: itself, E'q, the reference after the ramp, the plant's flags
K_FLD, K_EQP, K_UREF, K_FLAGS = range(N_SIGNALS, N_SIGNALS + 4)
N_KEEP = N_SIGNALS + 4
#: the plant's flag bits (K_FLAGS)
FLAG_CEILING, FLAG_RATE, FLAG_RAMP, FLAG_FAILED = 1, 2, 4, 8
#: is the no-load reference structure's span loop allowed in this variant (`variants` sets it)
SPAN = False
#: rows of a chunk's per-candidate scalars (`Work.cand`): the reference after the ramp, the
#: reference's target this step, whether an edge falls inside this step
C_UREF, C_TARGET, C_CROSS = range(3)


class Drive(NamedTuple):
    """What the candidates run on: the recorded setpoint (a sample per step of this call), its value
    before the test, the step (s), the measured efd, Vt, P, Q, vs and their weights (0: not scored),
    the recorded Vt and Ifd a played-back machine reads ((2, 1) otherwise)."""
    usetp: np.ndarray
    usetp_pre: float
    dt: float
    meas: np.ndarray
    w: np.ndarray
    ext: np.ndarray


class Edges(NamedTuple):
    """The record's setpoint edges (sample index, jump, nominal instant, slot of the candidate's
    offset) and the samples where some candidate's setpoint differs from the record's."""
    index: np.ndarray
    jump: np.ndarray
    nominal_s: np.ndarray
    slot: np.ndarray
    window: np.ndarray


class Switches(NamedTuple):
    """What a call computes: the dead time, skew and setpoint ramp of some candidate (their code is
    skipped otherwise), whether the span loop may run and whether without limits, the lengths of
    the dead time's and the skew's rings (steps)."""
    any_delay: bool
    any_skew: bool
    any_ramp: bool
    span: bool
    unlimited: bool
    ring: int
    ring_skew: int


class Out(NamedTuple):
    """What a run writes, a column (or entry) a candidate: `traces` (rows keep[K_*], columns the
    call's samples; (1, 1, 1) when nothing is kept), the squared errors of efd, Vt, P, Q, vs summed
    over the samples and at the record's ends (halved), the failure step (-1: none)."""
    traces: np.ndarray
    keep: np.ndarray
    sse: np.ndarray
    ends: np.ndarray
    fail_step: np.ndarray


class Work(NamedTuple):
    """A chunk's state between calls: its derived columns, states (at t_k; at t_k of a step redone
    in sub-steps; the initial ones a failed candidate is parked at), readouts (the same two
    times), step inputs, slopes, the span's rows (`span.W_*`), the recorded signals held, the
    per-candidate scalars (C_*), the dead time's and the skew's rings, scratch for a step's
    breaks, and (first sample, candidates, ring, skew ring)."""
    D: np.ndarray
    S: np.ndarray
    S0: np.ndarray
    X0: np.ndarray
    R: np.ndarray
    R0: np.ndarray
    U: np.ndarray
    M: np.ndarray
    W: np.ndarray
    held: np.ndarray
    cand: np.ndarray
    hist: np.ndarray
    skh: np.ndarray
    brk: np.ndarray
    meta: np.ndarray


@njit(nogil=True)
def new_work(D, lo, hi, L, Ls, ne, ext):
    """The Work of candidates lo..hi-1 of the transposed derived matrix D at their initial state
    (its readout; an invalid one failed), the rings full of the steady state's values."""
    m = hi - lo
    Dc = np.zeros((N_DERIVED, CHUNK))
    for q in range(N_DERIVED):   # (a loop: numpy's slice assignment compiles its shape errors' messages)
        for c in range(m):
            Dc[q, c] = D[q, lo + c]
    w = Work(Dc, np.zeros((N_ROWS, CHUNK)), np.zeros((N_ROWS, CHUNK)), np.zeros((N_ROWS, CHUNK)),
             np.zeros((N_READOUT, CHUNK)), np.zeros((N_READOUT, CHUNK)), np.zeros((N_INPUT, CHUNK)),
             np.zeros((2, CHUNK)), np.zeros((4, CHUNK)), np.zeros((N_SIGNALS, CHUNK)), np.zeros((3, CHUNK)),
             np.zeros((5, CHUNK, L)), np.zeros((7, CHUNK, Ls)), np.zeros((2, ne + 3)),
             np.array([lo, m, L, Ls], dtype=np.int64))
    for c in range(m):
        xa = exc_park(Dc, c)
        xg = gen_park(Dc, c)
        xs = pss_park(Dc, c)
        for S in (w.S, w.X0):
            exc_store(S, c, xa)
            gen_store(S, c, xg)
            pss_store(S, c, xs)
        _readout(w, c, ext, 0.0)
        w.cand[C_UREF, c] = Dc[D_UREF0, c]
        w.W[W_OUT, c] = Dc[D_GAIN, c] * w.R[R_FLD, c]
        if Dc[D_VALID, c] == 0.0 or not gen_valid(Dc, c):
            w.W[W_FAILED, c] = 1.0
        for q in range(L):
            w.hist[H_VR_R, c, q] = Dc[D_VR0, c]
            w.hist[H_VR_L, c, q] = Dc[D_VR0, c]
        for q in range(Ls):
            w.skh[K_EF, c, q] = Dc[D_OUT0, c]
    return w


@njit(inline=True)
def _readout(w, c, ext, t):
    """Candidate c's readout from its states (`step.readout`)."""
    alg, fld, vs = readout(w.D, c, exc_load(w.S, c), gen_load(w.S, c), pss_load(w.S, c), ext, t)
    gen_alg_store(w.R, c, alg)
    w.R[R_FLD, c] = fld
    w.R[R_VS, c] = vs


@njit(inline=True)
def record(w, drive, out, k, j, last, any_skew):
    """Sample k (column j of the call): the recorded signals at the states of t_k into w.held (a
    failed candidate's held), the kept traces and the squared errors."""
    D, R, W, held = w.D, w.R, w.W, w.held
    lo, m, Ls = w.meta[0], w.meta[1], w.meta[3]
    for c in range(m):
        if W[W_FAILED, c] == 0.0:
            y = R[R_FLD, c]
            if any_skew and D[D_SKEW, c] > 0.0:
                y = skewed(w.skh, c, Ls, k, k - D[D_SKEW, c] / drive.dt, drive.dt, D[D_OUT0, c])
            W[W_OUT, c] = D[D_GAIN, c] * y
            vt, ifd, p, q = gen_signals(gen_alg_load(R, c))
            held[S_VT, c] = vt
            held[S_P, c] = p
            held[S_Q, c] = q
            held[S_VS, c] = R[R_VS, c]
            held[S_IFD, c] = ifd
        held[S_EFD, c] = W[W_OUT, c]
    keep = out.keep
    for s in range(N_SIGNALS):
        if keep[s] >= 0:
            for c in range(m):
                out.traces[keep[s], lo + c, j] = held[s, c]
    if keep[K_FLD] >= 0 or keep[K_EQP] >= 0:
        for c in range(m):
            if keep[K_FLD] >= 0:
                out.traces[keep[K_FLD], lo + c, j] = R[R_FLD, c]
            if keep[K_EQP] >= 0:
                out.traces[keep[K_EQP], lo + c, j] = gen_flux(gen_load(w.S, c))
    for s in range(N_SCORED):
        ws = drive.w[s]
        if ws > 0.0:
            ym = drive.meas[s, j]
            for c in range(m):
                e = held[s, c] - ym
                if s == S_EFD:
                    W[W_SSE, c] += e * e
                else:
                    out.sse[s, lo + c] += e * e
            if k == 0 or k == last:   # the trapezoid's half weight at both ends
                for c in range(m):
                    e = held[s, c] - ym
                    out.ends[s, lo + c] += 0.5 * e * e


@njit(inline=True)
def reference(w, drive, edges, k, j, any_ramp):
    """The reference over [t_k, t_k+1) of every candidate into w.U (u0, u1): the zero-order hold of
    the record with each edge at its fitted instant (w.cand C_TARGET; C_CROSS where one falls
    inside the step), or a ramp towards it from the last reference. Returns whether some edge is
    near (the steps `edges.window` marks)."""
    D, U, cand = w.D, w.U, w.cand
    m = w.meta[1]
    dt = drive.dt
    base_u = drive.usetp[j] - drive.usetp_pre
    ne = edges.index.shape[0]
    inwin = ne > 0 and edges.window[j] != 0
    for c in range(m):
        cand[C_TARGET, c] = D[D_UREF0, c] + base_u
    if inwin:
        for c in range(m):
            corr = 0.0
            cross = 0.0
            for q in range(ne):
                ke = (edges.nominal_s[q] + D[D_EDGE0 + edges.slot[q], c]) / dt
                fit_on = 1.0 if ke <= k + EDGE_EPS else 0.0
                nom_on = 1.0 if k >= edges.index[q] else 0.0
                corr += edges.jump[q] * (fit_on - nom_on)
                if k + EDGE_EPS < ke < k + 1.0 - EDGE_EPS:
                    cross = 1.0
            cand[C_TARGET, c] += corr
            cand[C_CROSS, c] = cross
    for c in range(m):
        U[0, c] = cand[C_TARGET, c]
        U[1, c] = cand[C_TARGET, c]
    if any_ramp:
        for c in range(m):
            ramp = D[D_RAMP, c]
            if ramp < 1.0e300:
                st = cand[C_TARGET, c] - cand[C_UREF, c]
                st = min(max(st, -ramp * dt), ramp * dt)
                U[0, c] = cand[C_UREF, c]
                U[1, c] = cand[C_UREF, c] + st
    return inwin


@njit(inline=True)
def delay_inputs(w, k, dt):
    """The dead time: VR's right limit at t_k into the ring, the delayed VR at the stage times into
    w.U (v0, vm, v1)."""
    D, U, R, hist = w.D, w.U, w.R, w.hist
    m, L = w.meta[1], w.meta[2]
    for c in range(m):
        td = D[D_TD, c]
        if td > 0.0:
            alg = gen_alg_load(R, c)
            hist[H_VR_R, c, k % L] = exc_vr(D, c, U[0, c], exc_load(w.S, c), alg[0], alg[1])
            hist[H_JF, c, k % L] = 0.0
            base = k - td / dt
            U[2, c] = delayed_vr(hist, c, L, base, k, D[D_VR0, c], False)
            U[3, c] = delayed_vr(hist, c, L, base + 0.5, k, D[D_VR0, c], False)
            U[4, c] = delayed_vr(hist, c, L, base + 1.0, k, D[D_VR0, c], True)


@njit(inline=True)
def substeps(w, edges, k, dt, inwin, sw, ext):
    """Step k redone in sub-steps for every candidate with a jump inside it (`substep`)."""
    m = w.meta[1]
    for c in range(m):
        if w.W[W_FAILED, c] != 0.0:
            continue
        td_on = sw.any_delay and w.D[D_TD, c] > 0.0
        nbrk, base = breaks(w, edges, c, k, dt, inwin and w.cand[C_CROSS, c] != 0.0, td_on)
        if nbrk == 0:
            continue
        r = substep(w, c, k, dt, nbrk, w.cand[C_TARGET, c], w.U[0, c], base, td_on, sw.any_skew, ext)
        w.cand[C_UREF, c] = r[0]
        w.M[0, c] = r[1]
        w.M[1, c] = r[2]


@njit(inline=True)
def park_blown(w, out, k, ext):
    """Mark the candidates whose state's magnitude (w.W W_MAG) left the sane range failed at step k
    (unless they were already) and park them at their initial state, so that their arithmetic
    stays finite."""
    lo, m = w.meta[0], w.meta[1]
    for c in range(m):
        if not (w.W[W_MAG, c] < BLOWUP):
            if w.W[W_FAILED, c] == 0.0:
                w.W[W_FAILED, c] = 1.0
                out.fail_step[lo + c] = k
            for q in range(ROWS):
                w.S[q, c] = w.X0[q, c]
            _readout(w, c, ext, k * 1.0)


@njit(inline=True)
def after_step(w, out, k, sw, ext):
    """After step k: the skew's slopes, the blow-up test (a loop without calls or branches finds
    one, a loop with them handles it), the histories at t_k+1."""
    D, S, R, W, hist, skh = w.D, w.S, w.R, w.W, w.hist, w.skh
    m, L, Ls = w.meta[1], w.meta[2], w.meta[3]
    if sw.any_skew:
        for c in range(m):
            skh[K_DER_R, c, k % Ls] = w.M[0, c]
            skh[K_DER_L, c, (k + 1) % Ls] = w.M[1, c]
    blown = 0
    for c in range(m):
        mag = 0.0
        for q in range(ROWS):
            mag += abs(S[q, c])
        W[W_MAG, c] = mag
        blown += 0 if mag < BLOWUP else 1
    if blown:
        park_blown(w, out, k + 1, ext)
    if sw.any_skew:
        for c in range(m):
            skh[K_EF, c, (k + 1) % Ls] = R[R_FLD, c]
    if sw.any_delay:
        for c in range(m):
            if D[D_TD, c] > 0.0:  # left limit of VR at t_k+1 (state k+1, input of step k)
                alg = gen_alg_load(R, c)
                hist[H_VR_L, c, (k + 1) % L] = exc_vr(D, c, w.cand[C_UREF, c], exc_load(S, c), alg[0], alg[1])


@njit(inline=True)
def plant_outputs(w, out, j):
    """What a plant reports of step k (column j): the reference after the ramp and the flags: a
    ceiling reached, the slew limit acting, the ramp acting, failed."""
    D, S, R, cand = w.D, w.S, w.R, w.cand
    lo, m = w.meta[0], w.meta[1]
    keep = out.keep
    for c in range(m):
        if keep[K_UREF] >= 0:
            out.traces[keep[K_UREF], lo + c, j] = cand[C_UREF, c]
        if keep[K_FLAGS] >= 0:
            alg = gen_alg_load(R, c)
            hi, lo_ = ceilings_at(D, c, alg[0], alg[1])
            xa = exc_load(S, c)
            flags = 0.0
            if xa[3] >= hi or xa[3] <= lo_:
                flags += FLAG_CEILING
            vr = exc_vr(D, c, cand[C_UREF, c], xa, alg[0], alg[1])
            if abs((vr - xa[3]) * D[D_ITE, c]) > D[D_RATE, c]:
                flags += FLAG_RATE
            if cand[C_UREF, c] != cand[C_TARGET, c]:
                flags += FLAG_RAMP
            if w.W[W_FAILED, c] != 0.0:
                flags += FLAG_FAILED
            out.traces[keep[K_FLAGS], lo + c, j] = flags


@njit(nogil=True)
def advance(w, drive, edges, out, k0, n, last, sw):
    """Samples k0 .. k0+n-1 of the chunk and the steps after them (the last sample of the record,
    `last`, has none; -1: the record goes on, a plant's). Column j = k - k0 of the call's series
    (setpoint, measurements, window, traces) is sample k."""
    dt = drive.dt
    ext = drive.ext
    m = w.meta[1]
    ne = edges.index.shape[0]
    keep = out.keep
    plant = keep[K_UREF] >= 0 or keep[K_FLAGS] >= 0
    k = k0
    while k < k0 + n:
        j = k - k0
        if SPAN and sw.span and 0 < k < last and not (ne > 0 and edges.window[j] != 0):
            # a span of the reference structure's own steps, up to the next edge's window
            k1 = k + 1
            while k1 < last and k1 < k0 + n and not (ne > 0 and edges.window[k1 - k0] != 0):
                k1 += 1
            if sw.unlimited:
                done = span_unlimited(w.D, w.S, w.W, drive.usetp, drive.usetp_pre, dt, drive.meas[0], k, k1, k0, m,
                                      out.traces, keep, w.meta[0])
            else:
                done = span_limited(w.D, w.S, w.W, drive.usetp, drive.usetp_pre, dt, drive.meas[0], k, k1, k0, m,
                                    out.traces, keep, w.meta[0])
            if done < k1:
                park_blown(w, out, done, ext)
            for c in range(m):
                _readout(w, c, ext, done * 1.0)
            k = done
            continue
        record(w, drive, out, k, j, last, sw.any_skew)
        if k == last:
            break
        inwin = reference(w, drive, edges, k, j, sw.any_ramp)
        if sw.any_delay:
            delay_inputs(w, k, dt)
        if sw.any_skew:
            for c in range(m):
                w.skh[K_EF, c, k % w.meta[3]] = w.R[R_FLD, c]
                w.skh[K_KF, c, k % w.meta[3]] = 0.0
        redo = sw.any_delay or inwin
        if redo:
            for q in range(ROWS):
                for c in range(m):
                    w.S0[q, c] = w.S[q, c]
            for q in range(N_READOUT):
                for c in range(m):
                    w.R0[q, c] = w.R[q, c]
        step_all(w.D, w.S, w.R, w.U, w.M, k, dt, m, ext)
        for c in range(m):
            w.cand[C_UREF, c] = w.U[1, c]
        if redo:
            substeps(w, edges, k, dt, inwin, sw, ext)
        after_step(w, out, k, sw, ext)
        if plant:
            plant_outputs(w, out, j)
        k += 1
    return k
