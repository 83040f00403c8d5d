"""One capture prepared for the kernel, and its views: a time window, a decimated copy.
`Problem` holds one `FitRecord` per capture.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from bench_ctl.capture import Capture
from bench_ctl.engine import edge_plan
from bench_ctl.engine.runner import Edges
from bench_ctl.exitcodes import BadInput
from bench_ctl.signals.edges import Edge

__all__ = ["FitRecord", "apply_window", "decimated", "segment_window", "ProblemError"]


class ProblemError(BadInput):
    """Names, bounds, weights or a window that cannot define an identification problem. A message
    that names parameters is a `Note` (`bench_ctl.model.dialect`), the names data, said in a
    structure's names by the writer that reports it; a capture's path is its prose, said as it is."""


@dataclass(frozen=True, eq=False)
class FitRecord:
    """One capture prepared for the kernel (window applied as the index range [i0, i1))."""
    usetp: np.ndarray
    efd: np.ndarray
    vt: np.ndarray | None
    dt: float
    usetp_pre: float
    alpha: float
    i0: int
    i1: int
    source: str
    edges: Edges = field(default_factory=edge_plan.none)
    edge_list: tuple[Edge, ...] = ()
    edge_slots: tuple[int | None, ...] = ()
    #: an on-line record: the machine on the grid (a row of `params.MACHINE_PARAMS`, the record's
    #: pre-step P0, Q0 in it), the record's pre-step Vt (the kernel's Vt0) and its Q; else None
    machine: np.ndarray | None = None
    vt0: float | None = None
    q: np.ndarray | None = None
    #: the machine columns of the [grid] values the problem fits (`Problem.grid_names`)
    grid_cols: tuple[int, ...] = ()
    #: an on-line record's stabiliser output as recorded, less its pre-step level (None: not
    #: recorded, or the record was taken with the PSS's output switched off)
    vs: np.ndarray | None = None

    @property
    def full(self) -> bool:
        return self.i0 == 0 and self.i1 == self.efd.size

    @property
    def n_scored(self) -> float:
        """How many samples the objective and the MSE count."""
        return float(self.i1 - self.i0)

    @property
    def scored_s(self) -> float:
        """Seconds of record the objective integrates (the trapezoid: half a step at each end)."""
        return float((self.i1 - self.i0 - 1) * self.dt)

    def edges_upto(self, n: int) -> Edges:
        """The edges inside the first n samples (a run that stops at a window's end)."""
        return edge_plan.upto(self.edges, n)


def apply_window(r: FitRecord, window: tuple[float, float] | None, cap: Capture) -> FitRecord:
    n = cap.efd.size
    if window is None:
        return replace(r, i0=0, i1=n)
    t0, t1 = (float(v) for v in window)
    t = cap.time - cap.time[0]
    i0 = int(np.searchsorted(t, t0 - 1e-9 * r.dt, side="left"))
    i1 = int(np.searchsorted(t, t1 + 1e-9 * r.dt, side="right"))
    if not (t0 < t1) or i1 - i0 < 2:
        raise ProblemError(f"{cap.source or 'capture'}: fit window ({t0}, {t1}) s (from the record's "
                           f"start) holds {max(0, i1 - i0)} samples; need t0 < t1 and at least 2")
    return replace(r, i0=i0, i1=i1)


def decimated(r: FitRecord, q: int, n_max: int | None, offset: int) -> FitRecord:
    """Every q-th sample of `r` from offset (mod q) up to n_max, the window carried over."""
    n = r.efd.size if n_max is None else min(int(n_max), r.efd.size)
    first = offset % q if q > 1 else 0
    idx = np.arange(first, n, max(1, q))
    if q <= 1 and n == r.efd.size:
        return r
    if idx.size < 2:
        raise ProblemError(f"{r.source}: decimating by {q} leaves {idx.size} sample(s)")
    edges = edge_plan.upto(edge_plan.decimated(r.edges, q, offset, r.dt), idx.size)
    i0 = int(np.searchsorted(idx, r.i0))
    i1 = int(np.searchsorted(idx, r.i1))
    return replace(r, usetp=np.ascontiguousarray(r.usetp[idx]), efd=np.ascontiguousarray(r.efd[idx]),
                   vt=None if r.vt is None else np.ascontiguousarray(r.vt[idx]), dt=r.dt * q, i0=i0,
                   i1=max(i1, i0 + 2), edges=edges,
                   q=None if r.q is None else np.ascontiguousarray(r.q[idx]),
                   vs=None if r.vs is None else np.ascontiguousarray(r.vs[idx]))


def segment_window(seg: slice, cap: Capture) -> tuple[float, float]:
    i0, i1, step = seg.indices(cap.efd.size)
    if step != 1 or i1 - i0 < 2:
        raise ProblemError(f"segment {seg!r}: need a contiguous slice of at least 2 samples")
    return (float(i0 * cap.dt), float((i1 - 1) * cap.dt))
