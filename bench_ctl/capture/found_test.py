"""A test's edges found in a record that has no setpoint channel (`bench-ctl import --test
step:amplitude=0.1` without a start; docs/formats.md, "Edges found in the record").

The record's channels are searched in the order they respond to a setpoint change: the regulator
output `vr` (mapped with `--map vr=...`), then `efd`, then `vt`, each with the one edge finder
(`bench_ctl.signals.edges.find_edges`, on the source's own time stamps, before any resampling). The
first channel that shows an edge of the stated sign (and, for a pulse, its return) locates the
test; the others are said and why they did not. When the record has `vt`, it checks the amplitude:
vt's settled change over the edge must lie within AMPLITUDE_RANGE times the stated amplitude
(without vt only the sign is checked). On line the grid holds the terminal voltage and a reference
step moves vt by a fraction of it: vt below the range is then compared with what else the record
tells (the field current, the regulated quantity of a field-current regulator's step), and when
nothing matches the step is accepted with a note that the amplitude could not be checked (vt
above the range, or moving the other way, is still refused). A step whose return is in the record
is imported as a pulse (a step and its return), and said so. A record where no such edge is found
is refused naming the file and what was searched; a record whose channel shows edges beyond the
test's (a second test in one export) is refused too, with a window for each test (`--window`):
one capture holds one test.

Each found instant comes with the interval it lies in (`Edge.earliest_s`, `latest_s`); `tolerance_on`
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
from bench_ctl.signals.edges import EXCITER, VOLTAGE, Edge, EdgeSearch, find_edges

#: channels searched, in the order a setpoint change reaches them
SEARCH_ORDER: tuple[tuple[str, str], ...] = (("vr", EXCITER), ("efd", EXCITER), ("vt", VOLTAGE))
#: vt's settled change over the edge / the stated amplitude must lie in this range (a regulator
#: without integral action leaves a steady error; twice or half the step is another test)
AMPLITUDE_RANGE = (0.5, 1.5)
#: the level a channel steps from: its mean over this long before the edge (s)
PRE_S = 2.0
#: on line (the grid holds vt), the channels that can tell a reference step's size, in the order
#: tried, and what a match means
REFERENCE_CHANNELS: tuple[tuple[str, str], ...] = (
    ("ifd", "the field current's: a field-current (manual) regulator's reference step"),)
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
    edges: tuple[Edge, ...]
    block: dict[str, Any]

    @property
    def first_lo_s(self) -> float:
        """The earliest instant the first edge may have: the pre-step part ends here."""
        return self.edges[0].earliest_s


def _edge_row(e: Edge, label: str, rows: np.ndarray) -> dict[str, Any]:
    return {"edge": label, "row": int(rows[e.index]), "first_shows_s": e.nominal_s, "lo_s": e.earliest_s,
            "hi_s": e.latest_s, "instant_s": e.instant_s, "uncertainty_s": e.uncertainty_s,
            "level_before": e.level_before, "departure": e.departure, "level_after": e.level_after}


def _why_not(search: EdgeSearch, sign: int, kind: str) -> str:
    if not search.edges:
        return (f"nothing departs more than {search.threshold:.3g} ({search.threshold / max(search.noise, 1e-300):.3g}"
                f" x its noise) from a steady level")
    first = search.edges[0]
    if first.sign != sign:
        return (f"its first edge goes {'down' if sign > 0 else 'up'} (at t = {first.nominal_s:.4f} s), the stated "
                "amplitude the other way")
    lead, trail = search.pulse(sign)
    if kind == "pulse" and trail is None:
        return f"an edge at t = {lead.nominal_s:.4f} s but no return within the record"
    return ""


def _settled_change(time: np.ndarray, x: np.ndarray, lead: Edge, trail: Edge | None) -> float | None:
    """x's settled change over the leading edge: the median of the second half of the plateau
    (up to the trailing edge) less the mean over PRE_S before the edge (a long export's earlier
    operation is not the level the step starts from); None with too few samples."""
    pre = x[(time < lead.earliest_s) & (time >= lead.earliest_s - PRE_S)]
    end = trail.earliest_s if trail is not None else math.inf
    plateau = x[(time > lead.nominal_s) & (time < end)]
    if pre.size == 0 or plateau.size < 2:
        return None
    return float(np.median(plateau[plateau.size // 2:]) - np.mean(pre))


def _amplitude_check(time: np.ndarray, channels: Mapping[str, np.ndarray], columns: Mapping[str, str],
                     lead: Edge, trail: Edge | None, amplitude: float, on_line: bool) -> dict[str, Any]:
    """The amplitude against vt (see the module docstring); `ok` False refuses the record."""
    vt = channels.get("vt")
    if vt is None:
        return {"channel": None, "on_line": on_line, "ok": True,
                "note": "the record has no vt: only the sign of the edge was checked"}
    change = _settled_change(time, vt, lead, trail)
    if change is None:
        return {"channel": "vt", "on_line": on_line, "ok": True,
                "note": "too few vt samples before or after the edge to check the amplitude"}
    ratio = change / amplitude
    out: dict[str, Any] = {"channel": "vt", "stated_pu": amplitude, "change_pu": change, "ratio": ratio,
                           "accepted": list(AMPLITUDE_RANGE), "on_line": on_line,
                           "ok": bool(AMPLITUDE_RANGE[0] <= ratio <= AMPLITUDE_RANGE[1])}
    if out["ok"] or not on_line or not 0.0 < ratio < AMPLITUDE_RANGE[0]:
        return out
    # on line: the grid holds vt; what else does the record say of the step's size?
    for name, what in REFERENCE_CHANNELS:
        x = channels.get(name)
        moved = None if x is None else _settled_change(time, x, lead, trail)
        if moved is None:
            continue
        r = moved / amplitude
        ref = {"channel": name, "column": columns.get(name), "change": moved, "ratio": r,
               "ok": bool(AMPLITUDE_RANGE[0] <= r <= AMPLITUDE_RANGE[1])}
        out["reference"] = ref
        if ref["ok"]:
            out["ok"] = True
            out["note"] = (f"on line vt moves {ratio:.2f} x the stated amplitude (the grid holds it); {name} "
                           f"(column {columns.get(name)!r}) moves {moved:+.4g}, {r:.2f} x: the step is {what}")
            return out
    out["ok"] = True
    seen = "" if "reference" not in out else (
        f"; {out['reference']['channel']} moves {out['reference']['ratio']:.2f} x")
    out["note"] = (f"on line vt moves {ratio:.2f} x the stated amplitude: the grid holds the terminal voltage, "
                   f"so a reference step moves it by a fraction of the step; nothing else in the record gives "
                   f"the step's size{seen}: the amplitude is NOT checked, take it from the test sheet")
    return out


def _groups(edges: Sequence[Edge]) -> list[list[Edge]]:
    """The edges as tests: an edge and, when the next one goes the other way, its return."""
    out: list[list[Edge]] = []
    i = 0
    while i < len(edges):
        if i + 1 < len(edges) and edges[i + 1].sign == -edges[i].sign:
            out.append([edges[i], edges[i + 1]])
            i += 2
        else:
            out.append([edges[i]])
            i += 1
    return out


def _second_test(file: str, name: str, column: str | None, t: np.ndarray, search: EdgeSearch,
                 edges: Sequence[Edge], origin_s: float) -> CaptureError:
    """The refusal of a record whose channel shows edges beyond the test's, with a window
    (seconds from the export's first sample, at `origin_s`) for each test."""
    groups = _groups(search.edges)
    t0 = origin_s
    cuts = [float(t[0]) - t0] + [0.5 * (g[-1].nominal_s + h[0].earliest_s) - t0 for g, h in zip(groups, groups[1:])] \
        + [float(t[-1]) - t0]
    tests = []
    for g, a, b in zip(groups, cuts, cuts[1:]):
        what = " and ".join(f"{'up' if e.sign > 0 else 'down'} at t = {e.instant_s:.3f} s" for e in g)
        mark = " (the one found)" if any(e in edges for e in g) else ""
        tests.append(f"--window {math.floor(a * 100) / 100:.2f}:{math.floor(b * 100) / 100:.2f} ({what}{mark})")
    return CaptureError(file, f"{name} (column {column!r}) shows {len(search.edges)} edges, more than one test: "
                        "one capture holds one test (usetp would hold only the test found, and every fit would "
                        "take the others' response for an error of the model); import each with its own window "
                        "(seconds from the export's first sample): " + "; ".join(tests))


def find_test(file: str, time: np.ndarray, channels: Mapping[str, np.ndarray], *, kind: str,
              amplitude_pu: float, width_s: float | None, columns: Mapping[str, str],
              rows: np.ndarray | None = None, on_line: bool = False, origin_s: float | None = None) -> FoundTest:
    """Find the edges of a `kind` ("step" / "pulse") test of `amplitude_pu` in `channels`
    (capture names -> values on the source's `time`, already scaled by --scale); `columns` names
    the source column of each; `rows` the source row of each sample; `on_line`: the unit is
    synchronised (vt moves by a fraction of the step); `origin_s` the export's first sample (the
    windows a refusal suggests count from it; default the first of `time`). Refuses (CaptureError) when no channel shows
    the test, when vt contradicts the amplitude, a stated width, or when the channel shows another
    test too."""
    t = np.asarray(time, float)
    rows = np.arange(1, t.size + 1) if rows is None else np.asarray(rows)
    sign = 1 if amplitude_pu > 0 else -1
    searched: list[dict[str, Any]] = []
    chosen: tuple[str, EdgeSearch, Edge, Edge | None] | None = None
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
    check = _amplitude_check(t, channels, columns, lead, trail, amplitude_pu, on_line)
    if check.get("ok") is False:
        raise CaptureError(file, f"no {kind} of {amplitude_pu:+g} pu found in the record: the edge found in "
                           f"{name} (column {columns.get(name)!r}) at t = {lead.nominal_s:.4f} s moves vt by "
                           f"{check['change_pu']:+.4g} pu, {check['ratio']:.2f} times the stated amplitude "
                           f"({AMPLITUDE_RANGE[0]:g}..{AMPLITUDE_RANGE[1]:g} accepted"
                           + (", and on line no more than the step" if on_line else
                              "; on line, where the grid holds vt, map P and Q: --map p=.. --map q=..") + ")")
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
    if any(e not in edges for e in search.edges):
        raise _second_test(file, name, columns.get(name), t, search, edges,
                           float(t[0]) if origin_s is None else origin_s)
    block = {
        "channel": name, "column": columns.get(name), "kind": search.kind, "method": search.method(),
        "noise": search.noise, "threshold": search.threshold, "steady_samples": search.steady_samples,
        "edges": [_edge_row(e, label, rows) for e, label in zip(edges, ("leading", "trailing"))],
        "other_edges_s": [e.instant_s for e in search.edges if e not in edges],
        "amplitude_check": check, "described_as": kind, "imported_as": imported_as, "note": note,
        "searched": searched,
    }
    return FoundTest(imported_as, lead.instant_s, found_width, tuple(e for e in edges if e is not None), block)


def tolerance_on(grid: np.ndarray, edges: Sequence[Edge]) -> float:
    """The half-width of the search interval each edge needs on the capture's `grid`: the
    synthesised setpoint steps at the first grid sample at or after the found instant (its nominal
    instant), and the fits search nominal +- tolerance, which must cover [earliest_s, latest_s]."""
    g = np.asarray(grid, float)
    step = float(g[1] - g[0])
    tol = 0.0
    for e in edges:
        k = min(int(np.searchsorted(g, e.instant_s - 1e-6 * step, side="left")), g.size - 1)
        nominal = float(g[k])
        tol = max(tol, nominal - e.earliest_s, e.latest_s - nominal)
    return tol
