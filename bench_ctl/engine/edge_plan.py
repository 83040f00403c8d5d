"""A record's setpoint edges as the engine is given them: the compiled `runner.Edges` tuple, built
and checked (`build`), empty (`none`), on a decimated copy of the record (`decimated`) or on its
first samples (`upto`).

An edge of the plan is where the record's usetp jumps (`index`, the first sample that shows the
new setpoint, >= 1), by how much (`jump`, pu), its nominal instant (`nominal_s`, s from the
record's first sample: on a decimated copy it stays the fine record's), and which `EDGE` column of
the parameter matrix holds the candidate's offset (`slot`). The plan's `window` is empty: `run`
marks there the steps its candidates' edges fall in (`edge_window`).
"""
from __future__ import annotations

import numpy as np

from bench_ctl.model.params import RECORD_PARAMS

from .runner import Edges

__all__ = ["build", "none", "decimated", "upto"]


def _no_window() -> np.ndarray:
    return np.zeros(0, dtype=np.uint8)


def build(index: np.ndarray, jump: np.ndarray, nominal_s: np.ndarray, slot: np.ndarray) -> Edges:
    """The plan of the edges given as arrays of equal length (one entry per edge): first sample
    showing it (>= 1), jump (pu), nominal instant (s from the record's first sample), EDGE slot
    (0 .. len(RECORD_PARAMS) - 1). Refuses arrays of unequal length, a slot out of range and an
    edge without a sample before it, naming the values."""
    ix = np.ascontiguousarray(index, dtype=np.int64).reshape(-1)
    jp = np.ascontiguousarray(jump, dtype=np.float64).reshape(-1)
    at = np.ascontiguousarray(nominal_s, dtype=np.float64).reshape(-1)
    sl = np.ascontiguousarray(slot, dtype=np.int64).reshape(-1)
    n = ix.size
    if not (jp.size == at.size == sl.size == n):
        raise ValueError(f"edge arrays must have one entry per edge: {n} indices, {jp.size} jumps, "
                         f"{at.size} nominal instants, {sl.size} slots")
    if n and (sl.min() < 0 or sl.max() >= len(RECORD_PARAMS)):
        raise ValueError(f"edge slots must lie in 0..{len(RECORD_PARAMS) - 1}, got {sl.tolist()}")
    if n and ix.min() < 1:
        raise ValueError(f"an edge needs a sample before it (index >= 1), got indices {ix.tolist()}")
    return Edges(ix, jp, at, sl, _no_window())


def none() -> Edges:
    """The plan of a record whose setpoint changes act at the samples that show them."""
    return build(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))


def _kept(edges: Edges, keep: np.ndarray, index: np.ndarray, nominal_s: np.ndarray) -> Edges:
    return Edges(np.ascontiguousarray(index[keep]), np.ascontiguousarray(edges.jump[keep]),
                 np.ascontiguousarray(nominal_s[keep]), np.ascontiguousarray(edges.slot[keep]), _no_window())


def decimated(edges: Edges, q: int, offset: int, dt: float) -> Edges:
    """The same edges on the record of every q-th sample from `offset` (fine step `dt`): each jump
    shows at the first kept sample at or after its fine index; the nominal instant stays the fine
    one, counted from the decimated record's first sample (an edge before it is left out)."""
    first = offset % q
    if q == 1 and first == 0:
        return edges
    idx = -(-(edges.index - first) // q)  # ceil
    return _kept(edges, idx >= 1, idx, edges.nominal_s - first * dt)


def upto(edges: Edges, n: int) -> Edges:
    """The edges inside the first n samples (a run that stops at a window's end)."""
    keep = edges.index < n
    if keep.all():
        return edges
    return _kept(edges, keep, edges.index, edges.nominal_s)
