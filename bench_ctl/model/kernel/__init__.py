"""The compiled, batched simulation kernel of the reference unit, its eight effects and the blocks
of the standard structures.

One call simulates a whole population of parameter sets driven by one recorded setpoint series.
Time runs in the outer loop and candidates in the inner loop (states are arrays over candidates),
chunks of candidates run in parallel (docs/decisions/0003).

Numerics: classical RK4 at the capture's sample step; the setpoint is zero-order hold (sample k
acts on [t_k, t_k+1)), so every input jump falls on a step boundary. The dead time delays the AVR
output VR; its history is kept as the right limit at t_j and the left limit at t_j+1 of every
step, so a delayed jump stays a jump instead of being smeared over a step. The efd recorder skew
reads the efd history by cubic Hermite interpolation with the one-sided derivatives of each step.
Non-smooth effects (non-windup ceiling, slew limit) are evaluated inside every RK stage and the
state is clamped after the step.

A candidate whose states leave a sane range (unstable loop, stiff parameters beyond what the step
resolves) is marked failed at that step and frozen; its outputs stay finite (held) and the caller
turns the failure step into a rankable penalty. No NaN ever leaves the kernel.

The package, bottom up: `layout` (the derived columns `D_*`, constants), `jit` (the numba
decorator, LLVM options, the stale-cache guard), `blocks` (each block in one place: its derived
factors, its compiled algebra, its steady state), `derive` (the derived matrix from a parameter
matrix), `rhs` (the blocks wired into derivatives), `rk4` (the RK4 step, the vectorised loops
over candidates, split steps), `chunk` (a chunk of candidates over the record, the parallel loop
over chunks), `precompile` (the large parts compiled side by side before a first run), and here
`run_kernel`.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..edges import EdgeSpec
from ..params import COL
from .blocks import (
    avr,
    ceilings,
    delayed_vr,
    exciter_saturation_ab,
    field_voltage,
    hermite,
    rate_feedback,
    saturation_ab,
    steady_state,
    terminal_voltage,
)
from .chunk import Edges, Outputs, Record, Switches, run_chunk, run_chunks
from .derive import derive
from .jit import DISPATCHERS, PARALLEL_LOCK, SOURCES, drop_stale_cache, njit, optimisation_note
from .layout import (
    BLOWUP,
    CHUNK,
    COLUMNS,
    D_E0,
    D_EDGE0,
    D_EFD0,
    D_GAIN,
    D_ITD0P,
    D_ITD0PP,
    D_ITE,
    D_ITR,
    D_KDA,
    D_KPP,
    D_LIMOUT,
    D_OUT0,
    D_RAMP,
    D_RATE,
    D_SATA,
    D_SATB,
    D_SATVT,
    D_SKEW,
    D_TD,
    D_UREF0,
    D_VALID,
    D_VT0,
    D_X20,
    D_XE0,
    D_XF0,
    EDGE_EPS,
    N_DERIVED,
)
from .precompile import compile_parts
from .rhs import rhs
from .rk4 import rk4_step_ref

__all__ = [
    # running it
    "run_kernel", "derive", "column", "optimisation_note", "saturation_ab", "exciter_saturation_ab",
    # its layout and constants
    "COLUMNS", "N_DERIVED", "CHUNK", "BLOWUP", "EDGE_EPS",
    "D_E0", "D_EDGE0", "D_EFD0", "D_GAIN", "D_ITD0P", "D_ITD0PP", "D_ITE", "D_ITR", "D_KDA", "D_KPP", "D_LIMOUT",
    "D_OUT0", "D_RAMP", "D_RATE", "D_SATA", "D_SATB", "D_SATVT", "D_SKEW", "D_TD", "D_UREF0", "D_VALID", "D_VT0",
    "D_X20", "D_XE0", "D_XF0",
    # its blocks, for the plant and the open loop
    "avr", "ceilings", "delayed_vr", "field_voltage", "hermite", "rate_feedback", "rhs", "rk4_step_ref",
    "steady_state", "terminal_voltage",
    # its compilation
    "compile_parts", "njit", "SOURCES", "drop_stale_cache", "PARALLEL_LOCK",
]

# numba keys each function's cache on its own file: the loops inline the blocks of sibling files
drop_stale_cache(tuple(DISPATCHERS), SOURCES, "kernel")


def edge_window(D: np.ndarray, edges: EdgeSpec, dt: float, T: int) -> np.ndarray:
    """1 for every step where some candidate's setpoint differs from the zero-order hold of the
    record (between an edge's nominal and fitted instants) or jumps inside the step."""
    win = np.zeros(T, dtype=np.uint8)
    for j in range(edges.n):
        ke = (edges.nominal_s[j] + D[:, D_EDGE0 + edges.slot[j]]) / dt
        lo = int(math.floor(min(float(ke.min()), float(edges.index[j])))) - 1
        hi = int(math.ceil(max(float(ke.max()), float(edges.index[j])))) + 1
        win[max(0, lo): max(0, min(T, hi + 1))] = 1
    return win




def _kernel_array(a: np.ndarray, dtype: type) -> np.ndarray:
    """`a` as the kernel's compiled code takes it: contiguous, of `dtype`, writable. numba types a
    read-only array (a capture's) apart from a writable one and compiles the chunk runner again for
    each mix of the record's three series; copying a read-only series (one pass over the record)
    keeps it to one compilation. (`a` itself when it is so already: np.require's checks cost
    microseconds, on every kernel call of every series.)"""
    if type(a) is np.ndarray and a.dtype == dtype and a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.require(a, dtype, ("C", "W"))


def run_kernel(P: np.ndarray, usetp: np.ndarray, dt: float, usetp_pre: float, *,
               efd_meas: np.ndarray | None = None, vt_meas: np.ndarray | None = None,
               w_efd: float = 1.0, w_vt: float = 0.0, store: bool = True, chunk: int | None = None,
               edges: EdgeSpec | None = None) -> dict[str, np.ndarray]:
    """Run the kernel on a parameter matrix P (n, len(KERNEL_PARAMS)).

    `edges`: the record's setpoint edges; each moves to its nominal instant plus the candidate's
    offset in column EDGE1.. (slot) of P, the step it falls in split there. None: every change
    of usetp acts at the sample that shows it (zero-order hold).

    Returns a dict with `efd`, `vt` (n, T) traces when `store`, and when measurements are given
    `obj` (trapezoidal integral of the weighted squared error), `sse_efd`, `sse_vt` (sums of
    squared sample errors) and always `fail_step` (-1 for candidates that did not fail).
    """
    D = derive(P)
    n = D.shape[0]
    usetp = _kernel_array(usetp, np.float64)
    T = usetp.shape[0]
    if T < 2:
        raise ValueError("a simulation needs at least two samples")
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"time step {dt!r} must be positive")
    td_max = float(np.max(D[:, D_TD])) if n else 0.0
    sk_max = float(np.max(D[:, D_SKEW])) if n else 0.0
    L = int(math.ceil(td_max / dt)) + 3 if td_max > 0 else 1
    Ls = int(math.ceil(sk_max / dt)) + 3 if sk_max > 0 else 1
    have_efd = efd_meas is not None
    have_vt = vt_meas is not None
    em = _kernel_array(efd_meas if have_efd else np.zeros(T), np.float64)
    vm = _kernel_array(vt_meas if have_vt else np.zeros(T), np.float64)
    if em.shape[0] != T or vm.shape[0] != T:
        raise ValueError("measured signals must have the same length as usetp")
    we = float(w_efd) if have_efd else 0.0
    wv = float(w_vt) if have_vt else 0.0
    shape = (n, T) if store else (1, 1)
    efd_out = np.zeros(shape)
    vt_out = np.zeros(shape)
    sse_efd = np.zeros(n)
    sse_vt = np.zeros(n)
    obj = np.zeros(n)
    fail_step = np.full(n, -1, dtype=np.int64)
    if chunk is None:
        # fixed, not from the thread count: a candidate then sits at the same place of its chunk
        # (vectorised body or remainder loop, which fastmath may round differently) however many
        # threads run, so a result is bit-identical alone, in a batch worker, on any machine
        chunk = CHUNK
        if CHUNK // 2 < n <= CHUNK and nb.get_num_threads() > 1:
            # one chunk's worth on two threads as two halves (a call of 32 candidates on a 10 s
            # record: 2.1 ms against 2.9 ms; the only split that depends on the threads). A half
            # is a whole number of the loops' vectors (`problem.LANES`), so every candidate runs
            # in the same kind of loop as in one chunk and the results are the same
            # (tests/model/test_kernel_robust.py compares them)
            chunk = CHUNK // 2
    if not 1 <= int(chunk) <= CHUNK:
        raise ValueError(f"chunk={chunk!r}: the kernel runs 1 to {CHUNK} candidates a chunk")
    edges = EdgeSpec.none() if edges is None else edges
    if edges.n and int(edges.index.max()) >= T:
        raise ValueError(f"edge at sample {int(edges.index.max())} lies beyond the record ({T} samples)")
    if n:
        Dt = np.ascontiguousarray(D.T)
        record = Record(usetp, float(usetp_pre), float(dt), em, vm, we, wv)
        switches = Switches(bool(store), td_max > 0, sk_max > 0, bool(np.any(D[:, D_RAMP] < 1.0e300)), L, Ls)
        window = edge_window(D, edges, float(dt), T) if edges.n else np.zeros(T, dtype=np.uint8)
        earr = Edges(_kernel_array(edges.index, np.int64), _kernel_array(edges.jump, np.float64),
                     _kernel_array(edges.nominal_s, np.float64), _kernel_array(edges.slot, np.int64), window)
        outputs = Outputs(efd_out, vt_out, sse_efd, sse_vt, obj, fail_step)
        if n <= chunk:  # one chunk: waking the thread pool costs more than it saves
            run_chunk(Dt, 0, n, record, switches, earr, outputs)
        else:
            with PARALLEL_LOCK:
                run_chunks(Dt, int(chunk), record, switches, earr, outputs)
    out = {"fail_step": fail_step}
    if store:
        out["efd"] = efd_out
        out["vt"] = vt_out
    if have_efd or have_vt:
        out["obj"] = obj
        out["sse_efd"] = sse_efd
        out["sse_vt"] = sse_vt
    return out


def column(name: str) -> int:
    """The column of kernel parameter `name` in a parameter matrix P."""
    return COL[name]
