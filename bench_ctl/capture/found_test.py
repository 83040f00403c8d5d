"""A test's edges found in a record that has no setpoint channel (`bench-ctl import --test
step:amplitude=0.1` without a start; docs/formats.md, "Edges found in the record").

The record's channels are searched in the order they respond to a setpoint change: the regulator
output `vr` (mapped with `--map vr=...`), then `efd`, then `vt`, each with the one edge finder
(`bench_ctl.signals.edges.find_edges`, on the source's own time stamps, before any resampling). The
first channel that shows an edge of the stated sign (and, for a pulse, its return) locates the
test; the others are said and why they did not. When the record has `vt`, it checks the amplitude:
vt's settled change over the edge must lie within AMPLITUDE_RANGE times the stated amplitude
(without vt only the sign is checked). A step whose return is in the record is imported as a pulse
(a step and its return), and said so. A record where no such edge is found is refused naming the
file and what was searched.

Each found instant comes with the interval it lies in (`FoundEdge.lo_s`, `hi_s`); `tolerance_on`
turns it into the test's `edge_tolerance_s` on the capture's time grid, so that every fit searches
each edge over the whole interval (bench_ctl/identification/timing.py).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bench_ctl.capture.errors import CaptureError
from bench_ctl.signals.edges import EXCITER, VOLTAGE, EdgeSearch, FoundEdge, find_edges

#: channels searched, in the order a setpoint change reaches them
SEARCH_ORDER: tuple[tuple[str, str], ...] = (("vr", EXCITER), ("efd", EXCITER), ("vt", VOLTAGE))
#: vt's settled change over the edge / the stated amplitude must lie in this range (a regulator
#: without integral action leaves a steady error; twice or half the step is another test)
AMPLITUDE_RANGE = (0.5, 1.5)
#: a stated pulse width must match the found one within this share, or EDGE_TOL_SAMPLES samples
WIDTH_REL_TOL = 0.2
EDGE_TOL_SAMPLES = 5


@dataclass(frozen=True)
class FoundTest:
    """The test as the record shows it: kind, start and width (s, the record's time axis) and
    the edges it was found from; `block` is the sidecar's `import.edges_found`."""

    kind: str
    start_s: float
    width_s: float | None
    edges: tuple[FoundEdge, ...]
    block: dict[str, Any]

    @property
    def first_lo_s(self) -> float:
        """The earliest instant the first edge may have: the pre-step part ends here."""
        return self.edges[0].lo_s


def _edge_row(e: FoundEdge, label: str, rows: np.ndarray) -> dict[str, Any]:
    return {"edge": label, "row": int(rows[e.index]), "first_shows_s": e.hi_s, "lo_s": e.lo_s,
            "hi_s": e.hi_s, "instant_s": e.instant_s, "uncertainty_s": e.uncertainty_s,
            "level_before": e.level_before, "departure": e.departure, "level_after": e.level_after}


def _why_not(search: EdgeSearch, sign: int, kind: str) -> str:
    if not search.edges:
        return (f"nothing departs more than {search.threshold:.3g} ({search.threshold / max(search.noise, 1e-300):.3g}"
                f" x its noise) from a steady level")
    first = search.edges[0]
    if first.sign != sign:
        return (f"its first edge goes {'down' if sign > 0 else 'up'} (at t = {first.hi_s:.4f} s), the stated "
                "amplitude the other way")
    lead, trail = search.pulse(sign)
    if kind == "pulse" and trail is None:
        return f"an edge at t = {lead.hi_s:.4f} s but no return within the record"
    return ""


def _amplitude_check(time: np.ndarray, vt: np.ndarray | None, lead: FoundEdge, trail: FoundEdge | None,
                     amplitude: float) -> dict[str, Any]:
    if vt is None:
        return {"channel": None, "note": "the record has no vt: only the sign of the edge was checked"}
    pre = vt[time < lead.lo_s]
    end = trail.lo_s if trail is not None else math.inf
    plateau = vt[(time > lead.hi_s) & (time < end)]
    if pre.size == 0 or plateau.size < 2:
        return {"channel": "vt", "note": "too few vt samples before or after the edge to check the amplitude"}
    change = float(np.median(plateau[plateau.size // 2:]) - np.mean(pre))
    return {"channel": "vt", "stated_pu": amplitude, "change_pu": change, "ratio": change / amplitude,
            "accepted": list(AMPLITUDE_RANGE),
            "ok": bool(AMPLITUDE_RANGE[0] <= change / amplitude <= AMPLITUDE_RANGE[1])}


def find_test(file: str, time: np.ndarray, channels: Mapping[str, np.ndarray], *, kind: str,
              amplitude_pu: float, width_s: float | None, columns: Mapping[str, str],
              rows: np.ndarray | None = None) -> FoundTest:
    """Find the edges of a `kind` ("step" / "pulse") test of `amplitude_pu` in `channels`
    (capture names -> values on the source's `time`, already scaled by --scale); `columns` names
    the source column of each; `rows` the source row of each sample. Refuses (CaptureError) when
    no channel shows the test, when vt contradicts the amplitude, or a stated width."""
    t = np.asarray(time, float)
    rows = np.arange(1, t.size + 1) if rows is None else np.asarray(rows)
    sign = 1 if amplitude_pu > 0 else -1
    searched: list[dict[str, Any]] = []
    chosen: tuple[str, EdgeSearch, FoundEdge, FoundEdge | None] | None = None
    for name, ch_kind in SEARCH_ORDER:
        if name not in channels:
            continue
        search = find_edges(t, channels[name], kind=ch_kind, channel=name)
        why = _why_not(search, sign, kind)
        searched.append({"channel": name, "column": columns.get(name), "found": not why,
                         **({"why_not": why} if why else {})})
        if not why:
            lead, trail = search.pulse(sign)
            assert lead is not None
            chosen = (name, search, lead, trail)
            break
    what = "; ".join(f"{s['channel']} (column {s['column']!r}): {s.get('why_not', 'found')}" for s in searched)
    if chosen is None:
        raise CaptureError(file, f"no {kind} of {amplitude_pu:+g} pu found in the record: searched {what} "
                           f"(map the regulator output with --map vr=COLUMN, or give the start: "
                           f"--test {kind}:start=S,...)")
    name, search, lead, trail = chosen
    check = _amplitude_check(t, channels.get("vt"), lead, trail, amplitude_pu)
    if check.get("ok") is False:
        raise CaptureError(file, f"no {kind} of {amplitude_pu:+g} pu found in the record: the edge found in "
                           f"{name} (column {columns.get(name)!r}) at t = {lead.hi_s:.4f} s moves vt by "
                           f"{check['change_pu']:+.4g} pu, {check['ratio']:.2f} times the stated amplitude "
                           f"({AMPLITUDE_RANGE[0]:g}..{AMPLITUDE_RANGE[1]:g} accepted)")
    imported_as, note = kind, None
    if kind == "step" and trail is not None:
        imported_as = "pulse"
        note = (f"a step and its return: imported as a pulse of width "
                f"{trail.instant_s - lead.instant_s:.4f} s")
    found_width = trail.instant_s - lead.instant_s if imported_as == "pulse" and trail is not None else None
    if kind == "pulse" and width_s is not None and found_width is not None:
        step = float(np.median(np.diff(t)))
        if abs(found_width - width_s) > max(WIDTH_REL_TOL * width_s, EDGE_TOL_SAMPLES * step):
            raise CaptureError(file, f"the pulse found in {name} (column {columns.get(name)!r}) lasts "
                               f"{found_width:.4f} s (t = {lead.instant_s:.4f} .. {trail.instant_s:.4f} s), "
                               f"not the stated width {width_s:g} s")
    edges = (lead,) if imported_as == "step" else (lead, trail)
    block = {
        "channel": name, "column": columns.get(name), "kind": search.kind, "method": search.method(),
        "noise": search.noise, "threshold": search.threshold, "steady_samples": search.steady_samples,
        "edges": [_edge_row(e, label, rows) for e, label in zip(edges, ("leading", "trailing"))],
        "other_edges_s": [e.instant_s for e in search.edges if e not in edges],
        "amplitude_check": check, "described_as": kind, "imported_as": imported_as, "note": note,
        "searched": searched,
    }
    return FoundTest(imported_as, lead.instant_s, found_width, tuple(e for e in edges if e is not None), block)


def tolerance_on(grid: np.ndarray, edges: Sequence[FoundEdge]) -> float:
    """The half-width of the search interval each edge needs on the capture's `grid`: the
    synthesised setpoint steps at the first grid sample at or after the found instant (its nominal
    instant), and the fits search nominal +- tolerance, which must cover [lo_s, hi_s]."""
    g = np.asarray(grid, float)
    step = float(g[1] - g[0])
    tol = 0.0
    for e in edges:
        k = min(int(np.searchsorted(g, e.instant_s - 1e-6 * step, side="left")), g.size - 1)
        nominal = float(g[k])
        tol = max(tol, nominal - e.lo_s, e.hi_s - nominal)
    return tol
