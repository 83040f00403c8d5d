"""The setpoint edges of a capture as fit parameters (docs/model.md, "Edge timing").

Every fit (identification, the diagnosis' base and effect fits) carries the instant of each
setpoint edge as a parameter: `EDGE1`.. hold the fitted instant minus the nominal one (s).

- Recorded setpoint: a change first seen at sample k (the one edge finder's,
  `bench_ctl.signals.edges.find_setpoint_edges`) happened in (t[k-1], t[k]]: the offset is searched
  in [-dt, 0].
- Setpoint described by the user (`import --test`, no setpoint channel): the edge is known to
  within the test's `edge_tolerance_s` when given, else one sample of the source recorder (the
  import's median source step, the capture's step when it was not resampled): the offset is
  searched in [-tol, +tol].

A fit's edges are `bench_ctl.signals.edges.Edge` records, as the result and diagnosis JSON
write them (a capture's `edges`: {index, jump_pu, nominal_s, fitted_s, offset_s, std_s, lo_s,
hi_s, how, fitted}); `record_edges` gives them unfitted, `edges_entry` with the instants a fit found, and
`fitted_edge_plan` reads them back for the engine, so a report re-simulates with those instants.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from bench_ctl.capture import Capture
from bench_ctl.engine import edge_plan
from bench_ctl.engine.runner import Edges
from bench_ctl.signals.edges import EDGE_PARAMS, Edge, find_setpoint_edges

__all__ = ["record_edges", "edge_plan_of", "edges_entry", "fitted_edge_plan"]


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
        nominal = float(k * dt)
        out.append(Edge(index=int(k), jump_pu=float(u[k] - u[k - 1]), nominal_s=nominal, fitted_s=nominal,
                        offset_s=0.0, std_s=None, lo_s=lo, hi_s=hi, how=how, fitted=False))
    # neighbouring edges may not swap order: each searches at most half the gap to the next
    for i in range(len(out) - 1):
        gap = (out[i + 1].index - out[i].index) * dt
        half = 0.45 * gap
        a, b = out[i], out[i + 1]
        out[i] = replace(a, lo_s=max(a.lo_s, -half), hi_s=min(a.hi_s, half))
        out[i + 1] = replace(b, lo_s=max(b.lo_s, -half), hi_s=min(b.hi_s, half))
    return out


def edge_plan_of(edges: Sequence[Edge], slots: Sequence[int]) -> Edges:
    """The engine's plan of `edges` (`bench_ctl.engine.edge_plan`), whose offsets sit in the EDGE
    columns `slots`."""
    return edge_plan.build(np.array([e.index for e in edges], dtype=np.int64),
                           np.array([e.jump_pu for e in edges]), np.array([e.nominal_s for e in edges]),
                           np.array(list(slots), dtype=np.int64))


def edges_entry(edges: Sequence[Edge], slots: Sequence[int | None], values: Mapping[str, float],
                std: Mapping[str, Any] | None = None) -> list[Edge]:
    """A capture's edges with the fit's instants: nominal and fitted instants (s from the record's
    first sample), the offset's std (s) when known, its search interval, recorded or described.
    An edge without a slot was not fitted (fitted_s = nominal_s)."""
    out = []
    for e, slot in zip(edges, slots):
        name = EDGE_PARAMS[slot] if slot is not None else None
        off = float(values.get(name, 0.0)) if name else 0.0
        sd = (std or {}).get(name) if name else None
        out.append(replace(e, fitted_s=e.nominal_s + off, offset_s=off,
                           std_s=float(sd) if isinstance(sd, (int, float)) and math.isfinite(sd) else None,
                           fitted=name is not None))
    return out


def fitted_edge_plan(entries: Sequence[Edge] | None, n: int) -> tuple[Edges, dict[str, float]]:
    """(the engine's plan, {EDGEi: offset}) from a capture's edges as a result or diagnosis holds them
    (`edges_entry`), for a record of `n` samples; edges beyond the record or not fitted are left
    out."""
    rows = [e for e in (entries or []) if e.fitted and 1 <= e.index < n]
    rows = rows[: len(EDGE_PARAMS)]
    plan = edge_plan.build(np.array([e.index for e in rows], dtype=np.int64), np.array([e.jump_pu for e in rows]),
                           np.array([e.nominal_s for e in rows]), np.arange(len(rows)))
    return plan, {EDGE_PARAMS[i]: e.fitted_s - e.nominal_s for i, e in enumerate(rows)}
