"""The setpoint edges of a capture as fit parameters (docs/model.md, "Edge timing").

Every fit (identification, the diagnosis' base and effect fits) carries the instant of each
setpoint edge as a parameter: `EDGE1`.. hold the fitted instant minus the nominal one (s).

- Recorded setpoint: a change first seen at sample k happened in (t[k-1], t[k]]: the offset is
  searched in [-dt, 0].
- Setpoint described by the user (`import --test`, no setpoint channel): the edge is known to
  within the test's `edge_tolerance_s` when given, else one sample of the source recorder (the
  import's median source step, the capture's step when it was not resampled): the offset is
  searched in [-tol, +tol].

`edges_entry` / `edge_spec_of` write and read the per-capture `edges` list of the result and
diagnosis JSON ({index, jump_pu, nominal_s, fitted_s, offset_s, std_s, lo_s, hi_s, how,
fitted}), so a report re-simulates with the instants the fit found.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bench_ctl.capture import Capture
from bench_ctl.signals.edges import EDGE_PARAMS, EdgeSpec, find_setpoint_edges

__all__ = ["Edge", "record_edges", "edge_spec", "edges_entry", "edge_spec_of", "EDGE_PARAMS"]


@dataclass(frozen=True)
class Edge:
    """One setpoint edge of a capture and the interval its instant is searched in."""
    index: int          # first sample showing the new setpoint
    jump: float         # pu
    nominal_s: float    # t[index] - t[0]
    lo_s: float         # offset bounds (s) relative to nominal_s
    hi_s: float
    how: str            # "recorded" (usetp channel) or "described" (user's test description)


def _described_tolerance(capture: Capture) -> float | None:
    """The edge tolerance (s) of a capture whose setpoint was synthesised from a test
    description, None when usetp was recorded."""
    meta = capture.meta if isinstance(capture.meta, Mapping) else {}
    imp = meta.get("import") if isinstance(meta.get("import"), Mapping) else {}
    if not imp.get("usetp_synthesised"):
        return None
    test = imp.get("test") if isinstance(imp.get("test"), Mapping) else {}
    tol = test.get("edge_tolerance_s")
    if isinstance(tol, (int, float)) and not isinstance(tol, bool) and math.isfinite(tol) and tol > 0:
        return float(tol)
    step = imp.get("source_step_s")
    if isinstance(step, Mapping) and isinstance(step.get("median_s"), (int, float)) and step["median_s"] > 0:
        return max(float(step["median_s"]), float(capture.dt))
    return float(capture.dt)


def record_edges(capture: Capture) -> list[Edge]:
    """The setpoint edges of `capture` with the interval each instant is searched in."""
    u = np.asarray(capture.usetp, float)
    idx = find_setpoint_edges(u)
    tol = _described_tolerance(capture)
    dt = float(capture.dt)
    out = []
    for k in idx.tolist():
        lo, hi, how = (-dt, 0.0, "recorded") if tol is None else (-tol, tol, "described")
        out.append(Edge(int(k), float(u[k] - u[k - 1]), float(k * dt), lo, hi, how))
    # neighbouring edges may not swap order: each searches at most half the gap to the next
    for i in range(len(out) - 1):
        gap = (out[i + 1].index - out[i].index) * dt
        half = 0.45 * gap
        a, b = out[i], out[i + 1]
        out[i] = Edge(a.index, a.jump, a.nominal_s, max(a.lo_s, -half), min(a.hi_s, half), a.how)
        out[i + 1] = Edge(b.index, b.jump, b.nominal_s, max(b.lo_s, -half), min(b.hi_s, half), b.how)
    return out


def edge_spec(edges: Sequence[Edge], slots: Sequence[int]) -> EdgeSpec:
    """The kernel's view of `edges`, whose offsets sit in the EDGE columns `slots`."""
    return EdgeSpec(np.array([e.index for e in edges], dtype=np.int64),
                    np.array([e.jump for e in edges]), np.array([e.nominal_s for e in edges]),
                    np.array(list(slots), dtype=np.int64))


def edges_entry(edges: Sequence[Edge], slots: Sequence[int | None], values: Mapping[str, float],
                std: Mapping[str, Any] | None = None) -> list[dict[str, Any]]:
    """The JSON list of a capture's edges: nominal and fitted instants (s from the record's first
    sample), the offset's std (s) when known, its search interval, recorded or described. An edge
    without a slot was not fitted (fitted_s = nominal_s)."""
    out = []
    for e, slot in zip(edges, slots):
        name = EDGE_PARAMS[slot] if slot is not None else None
        off = float(values.get(name, 0.0)) if name else 0.0
        sd = (std or {}).get(name) if name else None
        out.append({"index": e.index, "jump_pu": e.jump, "nominal_s": e.nominal_s,
                    "fitted_s": e.nominal_s + off, "offset_s": off,
                    "std_s": float(sd) if isinstance(sd, (int, float)) and math.isfinite(sd) else None,
                    "lo_s": e.lo_s, "hi_s": e.hi_s, "how": e.how, "fitted": name is not None})
    return out


def edge_spec_of(entries: Sequence[Mapping[str, Any]] | None, n: int) -> tuple[EdgeSpec, dict[str, float]]:
    """(EdgeSpec, {EDGEi: offset}) from a JSON `edges` list (as `edges_entry` writes it), for a
    record of `n` samples; edges beyond the record or not fitted are left out."""
    rows = [e for e in (entries or []) if isinstance(e, Mapping) and e.get("fitted")
            and isinstance(e.get("index"), int) and 1 <= e["index"] < n]
    rows = rows[: len(EDGE_PARAMS)]
    spec = EdgeSpec(np.array([e["index"] for e in rows], dtype=np.int64),
                    np.array([float(e["jump_pu"]) for e in rows]),
                    np.array([float(e["nominal_s"]) for e in rows]), np.arange(len(rows)))
    return spec, {EDGE_PARAMS[i]: float(e["fitted_s"]) - float(e["nominal_s"]) for i, e in enumerate(rows)}
