"""The simulation engine: one compiled, batched simulation of every machine and block.

`run` simulates a population of parameter sets driven by one recorded setpoint series: the unit
at no load, on the grid (a machine matrix given), or its excitation system alone fed a record's
Vt and Ifd (`ext`). Time runs in the outer loop and candidates in the inner loop (states are
arrays over candidates), chunks of candidates run in parallel (docs/decisions/0003), shared out
between the calling thread and the engine's pool (`_share`); each call runs the variant its
candidates need (`variants`), compiled on first use.

The package, bottom up: `jit` (the one numba decorator, variants by constants, cache names),
`layout` (the derived columns `D_*`, rows, constants), `derived` (the derived matrix), `exciter`,
`machines`, `stabilisers` (the plug-ins of the seam), `history` (dead time and skew), `step` (the
RK4 step and its loop over candidates), `span` (the no-load reference structure's fast path),
`substep` (a step with jumps inside), `runner` (a chunk over the record, the parallel loop),
`variants`, `edge_plan` (the record's setpoint edges as `run` takes them), and here `run`.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor, wait

import numba as nb
import numpy as np

from bench_ctl.compile_notice import compiling

from . import edge_plan, layout
from .derived import derive
from .jit import optimisation_note
from .layout import (
    B_DELAY,
    B_FLUX,
    B_FULL,
    B_LIMITED,
    B_RAMP,
    B_SKEW,
    B_ST4,
    B_ST4_ONLY,
    CHUNK,
    D_BITS,
    D_EDGE0,
    D_SKEW,
    D_TD,
    D_VALID,
    LANES,
    N_SCORED,
    SIGNALS,
    X_FULL,
    X_REF,
    X_ST4,
    X_ST4_ONLY,
)
from .machines import grid
from .runner import N_KEEP, Drive, Edges, Out, Switches
from .span import W_FAILED, W_SSE
from .stabilisers import kind
from .variants import Key, variant

__all__ = ["run", "derive", "layout", "Key", "variant", "compiling", "optimisation_note", "CHUNK",
           "SIGNALS", "classify", "grid_key", "edge_window"]

#: below this many candidate-steps a call runs on one thread: waking the worker threads costs more
#: than it saves for the small batches of a polish, several times more when the machine is busy
SMALL_CALL = 300_000


def classify(D: np.ndarray) -> int:
    """The excitation system's class (`layout.X_*`) the candidates of the derived matrix D need:
    the reference blocks, the standard structures' without the potential-source stage, with it
    for some, with it alone for every valid candidate (an invalid one does not count)."""
    bits = D[:, D_BITS].astype(np.int64)
    union = int(np.bitwise_or.reduce(bits))   # (one reduction: a test per bit cost one each)
    if not union & B_ST4:
        return X_FULL if union & B_FULL else X_REF
    valid = D[:, D_VALID] != 0.0
    return X_ST4_ONLY if np.all(bits[valid] & B_ST4_ONLY) else X_ST4


def grid_key(D: np.ndarray) -> Key:
    """The variant the candidates of the derived matrix D run on the grid: their excitation
    system's class and their stabiliser (`stabilisers.kind`). A PSS2A / PSS2B runs on the
    standard-structure blocks or wider (the reference blocks' candidates on the full blocks, an
    ESST4B alone on the potential-source stage selected per candidate: the same results), so
    that it adds one variant to compile, two with an ESST4B."""
    x, pss = classify(D), kind(D)
    if pss == "pss2":
        x = {X_REF: X_FULL, X_ST4_ONLY: X_ST4}.get(x, x)
    return Key("grid", x, pss)


def edge_window(D: np.ndarray, edges: Edges, dt: float, T: int) -> np.ndarray:
    """1 for every step where some candidate's setpoint differs from the zero-order hold of the
    record (between an edge's nominal and fitted instants) or jumps inside the step."""
    win = np.zeros(T, dtype=np.uint8)
    if not edges.index.size or not D.shape[0]:
        return win
    # every edge's fitted sample for every candidate at once (the same arithmetic as one at a time)
    ke = (edges.nominal_s[:, None] + D[:, D_EDGE0 + edges.slot].T) / dt
    first, last = ke.min(axis=1).tolist(), ke.max(axis=1).tolist()
    for j, index in enumerate(edges.index.tolist()):
        lo = int(math.floor(min(first[j], float(index)))) - 1
        hi = int(math.ceil(max(last[j], float(index)))) + 1
        win[max(0, lo): max(0, min(T, hi + 1))] = 1
    return win


def _array(a: np.ndarray, dtype: type) -> np.ndarray:
    """`a` as the compiled code takes it: contiguous, of `dtype`, writable (numba types a read-only
    array apart from a writable one and would compile again for each mix)."""
    if type(a) is np.ndarray and a.dtype == dtype and a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.require(a, dtype, ("C", "W"))


def _padded(A: np.ndarray, k: int) -> np.ndarray:
    """A with k copies of its last row after it."""
    return np.concatenate((A, np.broadcast_to(A[-1:], (k, A.shape[1]))))


def _chunk(v, Dt: np.ndarray, lo: int, hi: int, drive: Drive, edges: Edges, out: Out, sw: Switches) -> None:
    """Candidates lo..hi-1 of the transposed derived matrix Dt over the whole record: their columns
    of `out` (two calls that release the GIL: chunks run side by side on threads)."""
    T = drive.usetp.shape[0]
    w = v.call("new_work", Dt, lo, hi, sw.ring, sw.ring_skew, edges.index.shape[0], drive.ext)
    out.fail_step[lo:hi][w.W[W_FAILED, :hi - lo] != 0.0] = 0
    v.call("advance", w, drive, edges, out, 0, T, T - 1, sw)
    if drive.w[0] > 0.0:
        out.sse[0, lo:hi] = w.W[W_SSE, :hi - lo]


_POOL: dict[int, ThreadPoolExecutor] = {}


def _pool(threads: int) -> ThreadPoolExecutor:
    """The threads chunks of one call run on (one pool a thread count, kept)."""
    pool = _POOL.get(threads)
    if pool is None:
        pool = _POOL[threads] = ThreadPoolExecutor(threads, thread_name_prefix="bench-ctl-engine")
    return pool


def _share(spans: list[tuple[int, int]], work: Callable[[int, int], None], threads: int) -> None:
    """`work(lo, hi)` for every span, taken in turn by the calling thread and threads - 1 of the
    pool's: the caller works instead of waiting (a call of two chunks wakes one thread, not two).
    A helper that has not started when the caller runs out of spans is cancelled, so that a call
    from a pool thread never waits for a free one."""
    todo = iter(spans)   # (next() on a list's iterator is atomic: each span is taken once)

    def drain() -> None:
        for lo, hi in todo:
            work(lo, hi)

    helpers = [_pool(threads - 1).submit(drain) for _ in range(min(threads, len(spans)) - 1)]
    try:
        drain()
    finally:
        started = [f for f in helpers if not f.cancel()]
        wait(started)
    for f in started:
        f.result()   # (a helper's error)


def run(P: np.ndarray, usetp: np.ndarray, dt: float, usetp_pre: float, *, machine: np.ndarray | None = None,
        ext: np.ndarray | None = None, measured: Mapping[str, np.ndarray | None] | None = None,
        weights: Mapping[str, float] | None = None, store: bool = True, edges: Edges | None = None,
        keep: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """Simulate the candidates P (n, len(KERNEL_PARAMS)) over the setpoint series `usetp` (step dt;
    `usetp_pre` before the test): at no load; on the grid M (`machine`, n rows of
    `params.MACHINE_PARAMS`); or the excitation system alone fed `ext` = (Vt, Ifd) recorded on
    the same samples.

    `edges`: the record's setpoint edges (`edge_plan`); each moves to its nominal instant plus the candidate's
    offset (EDGE1..); None: every change of usetp acts at the sample that shows it. `measured`:
    the recorded efd, vt, p, q, vs (the stabiliser's output) to score (None entries skipped),
    `weights` theirs (default efd 1, the others 0).

    Returns `fail_step` (-1: ran to the end; 0: invalid parameters) and, when `store`, the traces
    (n, T) of the `keep` signals (default efd and vt, on the grid p, q, vs and ifd too); with
    measurements `obj` (the trapezoidal integral of the weighted squared errors) and
    `sse_<signal>` for each measured signal with a weight."""
    P = np.asarray(P, dtype=np.float64)
    if P.ndim != 2:
        P = np.atleast_2d(P)
    n_asked = P.shape[0]
    short = n_asked % LANES
    if n_asked > 1 and short >= 2:   # two or more would run in the loops' scalar remainder
        P = _padded(P, LANES - short)
    if machine is not None:
        M = np.atleast_2d(np.asarray(machine, dtype=np.float64))
        if M.shape[0] != n_asked:
            raise ValueError(f"machine matrix has {M.shape[0]} rows for {n_asked} candidates")
        if P.shape[0] != n_asked:
            M = _padded(M, P.shape[0] - n_asked)
        D = grid.derive_grid(P, M)
        key = grid_key(D)
    else:
        D = derive(P)
        key = Key("recorded" if ext is not None else "noload", classify(D))
    out = _run(D, key, _array(usetp, np.float64), float(dt), float(usetp_pre), ext, measured, weights, store,
               edges, keep)
    if P.shape[0] == n_asked:
        return out
    return {k: v[:n_asked] for k, v in out.items()}


def _run(D, key, usetp, dt, usetp_pre, ext, measured, weights, store, edges, keep) -> dict[str, np.ndarray]:
    n = D.shape[0]
    T = usetp.shape[0]
    if T < 2:
        raise ValueError("a simulation needs at least two samples")
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"time step {dt!r} must be positive")
    edges = edge_plan.none() if edges is None else edges
    if edges.index.size and int(edges.index.max()) >= T:
        raise ValueError(f"edge at sample {int(edges.index.max())} lies beyond the record ({T} samples)")
    meas = np.zeros((N_SCORED, T))
    w = np.zeros(N_SCORED)
    weights = {"efd": 1.0, **dict(weights or {})}
    scored = []
    for q, name in enumerate(SIGNALS[:N_SCORED] if measured else ()):
        series = measured.get(name)
        if series is not None:
            series = np.asarray(series, dtype=np.float64)
            if series.shape != (T,):
                raise ValueError(f"measured {name} has {series.shape} samples, the setpoint {T}")
            meas[q] = series
            w[q] = float(weights.get(name, 0.0))
            if w[q] > 0.0:
                scored.append(q)
    scored_beyond_efd = any(q > 0 for q in scored)
    unknown = set(measured or ()) - set(SIGNALS[:N_SCORED])
    if unknown:
        raise ValueError(f"measured signal(s) {', '.join(sorted(unknown))}: a fit reads "
                         f"{', '.join(SIGNALS[:N_SCORED])}")
    if keep is None:
        keep = SIGNALS if key.machine == "grid" else ("efd", "vt")
    rows = np.full(N_KEEP, -1, dtype=np.int64)
    if store:
        for r, name in enumerate(keep):
            rows[SIGNALS.index(name)] = r
    traces = np.zeros((len(keep), n, T) if store else (1, 1, 1))
    sse = np.zeros((N_SCORED, n))
    ends = np.zeros((N_SCORED, n))
    fail_step = np.full(n, -1, dtype=np.int64)
    if n:
        bits = int(np.bitwise_or.reduce(D[:, D_BITS].astype(np.int64)))
        delay, skew, ramp = bool(bits & B_DELAY), bool(bits & B_SKEW), bool(bits & B_RAMP)
        # (B_DELAY, B_SKEW: some candidate's TD, SKEW > 0, `derived`; the rings' lengths need their largest)
        td_max = float(D[:, D_TD].max()) if delay else 0.0
        sk_max = float(D[:, D_SKEW].max()) if skew else 0.0
        sw = Switches(delay, skew, ramp, not (delay or skew or ramp or bits & B_FLUX or scored_beyond_efd),
                      not bits & B_LIMITED, int(math.ceil(td_max / dt)) + 3 if td_max > 0 else 1,
                      int(math.ceil(sk_max / dt)) + 3 if sk_max > 0 else 1)
        xt = _array(ext, np.float64) if ext is not None else np.zeros((2, 1))
        drive = Drive(usetp, usetp_pre, dt, meas, w, xt)
        window = edge_window(D, edges, dt, T) if edges.index.size else np.zeros(T, dtype=np.uint8)
        e = Edges(_array(edges.index, np.int64), _array(edges.jump, np.float64),
                  _array(edges.nominal_s, np.float64), _array(edges.slot, np.int64), window)
        o = Out(traces, rows, sse, ends, fail_step)
        Dt = np.ascontiguousarray(D.T)
        v = variant(key)
        # chunks of a fixed size, not from the thread count: a candidate then sits at the same
        # place of its chunk (vectorised body or remainder, which fast-math may round apart)
        # however many threads run; a call of 17-32 candidates runs as two halves on two threads
        # (a whole number of the loops' vectors each: the same results)
        threads = nb.get_num_threads() if n * T >= SMALL_CALL else 1
        chunk = CHUNK // 2 if CHUNK // 2 < n <= CHUNK and threads > 1 else CHUNK
        spans = [(lo, min(n, lo + chunk)) for lo in range(0, n, chunk)]
        if len(spans) == 1 or threads == 1:   # on this thread (waking a pool costs more than it saves)
            for lo, hi in spans:
                _chunk(v, Dt, lo, hi, drive, e, o, sw)
        else:
            _share(spans, lambda lo, hi: _chunk(v, Dt, lo, hi, drive, e, o, sw), threads)
    result = {"fail_step": fail_step}
    if store:
        result.update({name: traces[r] for r, name in enumerate(keep)})
    if scored or measured:
        result["obj"] = dt * (w @ (sse - ends))
        for q in scored:
            result[f"sse_{SIGNALS[q]}"] = sse[q]
    return result
