"""Setpoint edges of a record and their fitted instants (docs/model.md, "Edge timing").

A recorder samples `usetp` and `efd` together: a setpoint change first seen at sample k happened
somewhere in (t[k-1], t[k]]. The kernel's zero-order hold puts it at t[k]; at 1 kHz with a static
exciter the sub-sample instant moves efd by tenths of a pu at the edge, so every fit carries the
instant of each edge as a parameter (`EDGE1` .. `EDGE4`: fitted instant minus the nominal one, in
seconds) and the kernel moves the jump there, splitting the RK4 step at that instant.

`EdgeSpec` is what the kernel needs of a record: where its usetp jumps (sample index in that
record), by how much, the nominal instant (s from the record's first sample, which stays the same
on a decimated copy of the record), and which `EDGE` column of the parameter matrix holds the
offset. `find_setpoint_edges` finds the isolated jumps of a recorded setpoint.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .params import RECORD_PARAMS

#: kernel parameter columns that hold edge offsets (one per edge a fit can move)
EDGE_PARAMS: tuple[str, ...] = RECORD_PARAMS

#: a change of the recorded setpoint counts as an edge when larger than this share of the largest
#: change and this many times the median change (a noisy recorded setpoint jitters every sample)
_EDGE_SHARE = 0.2
_EDGE_OVER_MEDIAN = 20.0


@dataclass(frozen=True, eq=False)
class EdgeSpec:
    """Edges of one record as the kernel reads them (arrays of equal length, one row per edge)."""

    index: np.ndarray      # int64: first sample of this record that shows the new setpoint
    jump: np.ndarray       # float: usetp[index] - usetp[index - 1] (pu)
    nominal_s: np.ndarray  # float: nominal instant, s from the record's first sample
    slot: np.ndarray       # int64: 0..3, which EDGE column holds the offset

    def __post_init__(self) -> None:
        for name in ("index", "jump", "nominal_s", "slot"):
            kind = np.int64 if name in ("index", "slot") else np.float64
            object.__setattr__(self, name, np.ascontiguousarray(getattr(self, name), dtype=kind).reshape(-1))
        n = self.index.size
        if not (self.jump.size == self.nominal_s.size == self.slot.size == n):
            raise ValueError("edge arrays must have one entry per edge")
        if n and (self.slot.min() < 0 or self.slot.max() >= len(EDGE_PARAMS)):
            raise ValueError(f"edge slots must lie in 0..{len(EDGE_PARAMS) - 1}, got {self.slot.tolist()}")
        if n and self.index.min() < 1:
            raise ValueError("an edge needs a sample before it (index >= 1)")

    @property
    def n(self) -> int:
        return int(self.index.size)

    @staticmethod
    def none() -> "EdgeSpec":
        return EdgeSpec(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0))

    def decimated(self, q: int, offset: int, dt: float) -> "EdgeSpec":
        """The same edges on the record of every q-th sample from `offset` (fine step `dt`): each
        jump shows at the first kept sample at or after its fine index; the nominal instant stays
        the fine one, counted from the decimated record's first sample."""
        first = offset % q
        if q == 1 and first == 0:
            return self
        idx = -(-(self.index - first) // q)  # ceil
        keep = idx >= 1
        return EdgeSpec(idx[keep], self.jump[keep], self.nominal_s[keep] - first * dt, self.slot[keep])


def find_setpoint_edges(usetp: np.ndarray) -> np.ndarray:
    """Sample indices k (>= 1) where the setpoint jumps: usetp[k] differs from usetp[k-1] by more
    than a fifth of the largest change and twenty times the median change. Empty for a flat record."""
    u = np.asarray(usetp, float)
    if u.size < 2:
        return np.zeros(0, dtype=np.int64)
    d = np.abs(np.diff(u))
    big = float(d.max())
    if big <= 0.0:
        return np.zeros(0, dtype=np.int64)
    thr = max(_EDGE_SHARE * big, _EDGE_OVER_MEDIAN * float(np.median(d)))
    return (np.flatnonzero(d > thr) + 1).astype(np.int64)
