"""Setpoint edges of a record and their fitted instants (docs/model.md, "Edge timing").

A recorder samples `usetp` and `efd` together: a setpoint change first seen at sample k happened
somewhere in (t[k-1], t[k]]. The kernel's zero-order hold puts it at t[k]; at 1 kHz with a static
exciter the sub-sample instant moves efd by tenths of a pu at the edge, so every fit carries the
instant of each edge as a parameter (`EDGE1` .. `EDGE4`: fitted instant minus the nominal one, in
seconds) and the kernel moves the jump there, splitting the RK4 step at that instant.

What the engine needs of a record's edges (where its usetp jumps, by how much, the nominal
instant, which `EDGE` column holds the offset) is its plan, `bench_ctl.engine.edge_plan`.

`find_edges` is the one finder of a test's edges, in any channel: a recorded setpoint (the fits'
edge instants, the report's segments, the plausibility checks, the diagnosis' windows, a run's
recorded pulse) or, when a record has no setpoint channel, the channel that responds first (the
regulator output, efd, Vt: the import). It returns each edge's first showing sample, the steady
levels around it and the interval its instant lies in (`Edge`, docs/model.md "Edge timing");
`EdgeSearch.pulse()` (`lead`, `trail`) picks the leading and the trailing edge of a pulse or step.
`find_setpoint_edges` gives the first samples of a setpoint's edges it finds (each one a kernel
edge with its own offset).

The edges' three types: `Edge` (one edge, as the finder found it and as a fit carries it and a
result writes it), `EdgeSearch` (what the finder found in one channel: its edges, the noise, the
threshold) and the engine's `bench_ctl.engine.runner.Edges` (a record's edges as the engine runs
them, built by `bench_ctl.engine.edge_plan`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench_ctl.model.params import RECORD_PARAMS
from bench_ctl.records import Record

#: kernel parameter columns that hold edge offsets (one per edge a fit can move)
EDGE_PARAMS: tuple[str, ...] = RECORD_PARAMS


def find_setpoint_edges(usetp: np.ndarray) -> np.ndarray:
    """The first sample k (>= 1) showing each edge of a recorded setpoint, as `find_edges` finds
    them (a setpoint channel, on the samples' axis). Empty for a flat record."""
    u = np.asarray(usetp, float)
    found = find_edges(np.arange(u.size, dtype=float), u, kind=SETPOINT)
    return np.array([e.index for e in found.edges], dtype=np.int64)


# ------------------------------------------------------------------ the test's edges, any channel
#
# The one place that finds where a test's edges are: in a recorded setpoint (the report's segments,
# the plausibility checks, the diagnosis' windows, the procedure's recorded pulse) and, when a
# record has no setpoint channel, in the channels that respond to it (the import).

#: what a channel is, for the finder: a setpoint (steps, no dynamics), the exciter's output (the
#: regulator output or efd: fast, may sit at a limit), or the terminal voltage (a lagged response)
SETPOINT, EXCITER, VOLTAGE = "setpoint", "exciter", "voltage"
CHANNEL_KINDS = (SETPOINT, EXCITER, VOLTAGE)

#: a steady window: SETPOINT_STEADY samples of a setpoint, else STEADY_S seconds and at least
#: MIN_STEADY samples (at most MAX_STEADY), whose standard deviation is at most STEADY_SIGMAS noise
SETPOINT_STEADY = 4
STEADY_S = 0.05
MIN_STEADY = 10
MAX_STEADY = 200
STEADY_SIGMAS = 2.0
#: a sample departs when it lies more than THRESHOLD_SIGMAS noise from the steady level before it;
#: the PERSIST samples after it must depart the same way (one spike is no edge)
THRESHOLD_SIGMAS = 5.0
PERSIST = 2
#: an edge departs, within SIZE_S after it and before the next departure, by at least MIN_SHARE of
#: the largest departure found
MIN_SHARE = 0.3
SIZE_S = 1.0
#: an exciter channel held, after an edge, within this share of its range (plus the threshold) of
#: the highest (lowest) value of the record the edge drove it to sits at its ceiling (floor):
#: leaving it is the channel coming off its limit, not an edge
LIMIT_SHARE = 0.02
#: the front: a change that starts like c (t - t0)^p with p at most FRONT_ORDER (a jump through the
#: exciter's lag: 1; Vt behind the generator's subtransient lag and the exciter: 2 to 3) crosses the
#: threshold h at t1 and RISE_LEVELS x h at t2 no sooner than (t2 - t1) / (RISE_LEVELS^(1/p) - 1)
#: after its start: the instant's interval starts that long before t1
FRONT_ORDER = {SETPOINT: 1.0, EXCITER: 3.0, VOLTAGE: 4.0}
RISE_LEVELS = 4.0


@dataclass(frozen=True, eq=False, kw_only=True)
class Edge(Record):
    """One edge of a test: the first sample that shows it, the interval its instant lies in and,
    in a fit, the instant the fit found. The JSON keys of a result's and a diagnosis' edges
    (docs/formats.md, "Result JSON").

    The finder (`find_edges`, how "found") gives it in any channel: the change first shows at
    sample `index` (it departs from the last steady level before it by more than the threshold,
    and stays away), nominal_s = time[index]; it happened in [nominal_s + lo_s, nominal_s + hi_s]
    (`earliest_s`, `latest_s`): hi_s = 0, lo_s reaches back to the sample before it or earlier by
    the time the front can have spent below the threshold (from how fast it climbs from 1 to
    RISE_LEVELS thresholds, for a front of order FRONT_ORDER; nothing for a jump); jump_pu is
    level_after - level_before. A fit's edge (`bench_ctl.identification.timing.record_edges`, how
    "recorded" or "described") holds the recorded jump and the interval its instant is searched in.
    """
    #: which capture it belongs to, in a list of several captures' edges (a result's: the index;
    #: a diagnosis': "capture" / "holdout"); absent in a capture's own list
    capture: int | str | None = None
    index: int                  # first sample showing the change
    jump_pu: float              # the step's size: usetp[index] - usetp[index - 1] (found: level_after - level_before)
    nominal_s: float            # time of sample `index` (a fit's: index * dt, s from the record's first sample)
    fitted_s: float             # the instant the fit found (nominal_s when not fitted)
    offset_s: float             # fitted_s - nominal_s
    std_s: float | None         # the offset's standard deviation, when known
    lo_s: float                 # the instant's interval (s) relative to nominal_s
    hi_s: float
    how: str                    # "found" (by the finder), "recorded" (usetp channel) or "described" (user's test)
    fitted: bool                # its instant was fitted (at most four edges over a fit's captures)
    #: the finder's (in memory only, never written): the mean of the steady window before it, the
    #: farthest from it within SIZE_S and before the next departure (signed), the median of the
    #: second half of the stretch up to the next edge (channel units; NaN on a fit's edge)
    level_before: float = math.nan
    departure: float = math.nan
    level_after: float = math.nan

    OMITTED_WHEN_NONE = ("capture",)
    IN_MEMORY = ("level_before", "departure", "level_after")

    @property
    def sign(self) -> int:
        """+1 up, -1 down (the finder's departure; a fit's edge: its jump)."""
        d = self.departure if math.isfinite(self.departure) else self.jump_pu
        return 1 if d > 0 else -1

    @property
    def earliest_s(self) -> float:
        """The earliest the instant can be (nominal_s + lo_s)."""
        return self.nominal_s + self.lo_s

    @property
    def latest_s(self) -> float:
        """The latest the instant can be (nominal_s + hi_s)."""
        return self.nominal_s + self.hi_s

    @property
    def instant_s(self) -> float:
        """The middle of the interval."""
        return 0.5 * (self.earliest_s + self.latest_s)

    @property
    def uncertainty_s(self) -> float:
        """Half the interval's width: the instant is instant_s +- uncertainty_s."""
        return 0.5 * (self.hi_s - self.lo_s)


@dataclass(frozen=True)
class EdgeSearch:
    """What `find_edges` found in one channel and how."""

    channel: str
    kind: str
    edges: tuple[Edge, ...]
    noise: float            # the channel's noise (standard deviation, channel units)
    threshold: float        # departure that counts (channel units)
    steady_samples: int     # length of the steady window before an edge

    def method(self) -> str:
        return (f"first sample departing more than {self.threshold:.3g} ({THRESHOLD_SIGMAS:g} x noise "
                f"{self.noise:.3g}) from the mean of the last {self.steady_samples} steady samples before it, "
                f"and the {PERSIST} after it too; edges at least {MIN_SHARE:g} of the largest departure"
                + ("; leaving a limit is no edge" if self.kind == EXCITER else "")
                + "; the instant lies between the sample before it, less the time a front of order "
                f"{FRONT_ORDER[self.kind]:g} climbing as fast as seen from 1 to {RISE_LEVELS:g} thresholds "
                "spends below the first, and that sample")

    @property
    def lead(self) -> Edge | None:
        """The leading edge of the pulse or step (`pulse`)."""
        return self.pulse()[0]

    @property
    def trail(self) -> Edge | None:
        """The pulse's trailing edge (None: a step, or nothing)."""
        return self.pulse()[1]

    @property
    def trail_index(self) -> int | None:
        """The first sample showing the trailing edge (None: a step, or nothing)."""
        trail = self.trail
        return None if trail is None else trail.index

    def pulse(self, sign: int | None = None) -> tuple[Edge | None, Edge | None]:
        """(leading, trailing): the first edge (of `sign` when given) and the first later edge
        going the other way (None: a step, or nothing)."""
        lead = next((e for e in self.edges if sign is None or e.sign == sign), None)
        if lead is None:
            return None, None
        trail = next((e for e in self.edges if e.index > lead.index and e.sign == -lead.sign), None)
        return lead, trail


def _rolling(x: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation (ddof 1) of x[k - w:k] for k = w .. n - 1."""
    ref = float(np.median(x))
    y = x - ref
    c1 = np.concatenate([[0.0], np.cumsum(y)])
    c2 = np.concatenate([[0.0], np.cumsum(y * y)])
    k = np.arange(w, x.size)
    s1 = c1[k] - c1[k - w]
    s2 = c2[k] - c2[k - w]
    var = np.maximum((s2 - s1 * s1 / w) / (w - 1), 0.0)
    return s1 / w + ref, np.sqrt(var)


def steady_samples(time: np.ndarray, kind: str) -> int:
    """Length of the steady window before an edge for a channel of `kind` on `time`."""
    if kind == SETPOINT:
        return SETPOINT_STEADY
    step = float(np.median(np.diff(time)))
    return int(min(MAX_STEADY, max(MIN_STEADY, round(STEADY_S / step))))


def _crossing(t: np.ndarray, d: np.ndarray, k0: int, level: float) -> float:
    """When the departure d (sample k0 on) first reaches `level`: interpolated between the samples
    around it (inf when it never does)."""
    above = np.flatnonzero(d[k0:] >= level)
    if above.size == 0:
        return math.inf
    j = k0 + int(above[0])
    if j == 0 or d[j - 1] >= level:
        return float(t[j])
    a = max(float(d[j - 1]), 0.0) if j - 1 >= 0 else 0.0
    a = min(a, level)
    f = (level - a) / (float(d[j]) - a) if d[j] > a else 1.0
    return float(t[j - 1] + f * (t[j] - t[j - 1]))


def find_edges(time: np.ndarray, x: np.ndarray, *, kind: str = SETPOINT, channel: str = "usetp") -> EdgeSearch:
    """The edges of a step or pulse test in one channel (see `Edge`, `EdgeSearch.method`).

    `time` strictly increasing (uniform or not: a raw export's own time stamps), `x` the channel,
    `kind` SETPOINT, EXCITER (the regulator output, efd) or VOLTAGE (vt). The noise is the median
    standard deviation of non-overlapping steady-window-long stretches; a steady window has a
    standard deviation of at most STEADY_SIGMAS noise. An edge is the first sample that departs
    from the mean of the last steady window before it (which lies after the previous edge) by
    more than THRESHOLD_SIGMAS noise, with the PERSIST samples after it, and whose departure
    reaches MIN_SHARE of the largest. Edges of either sign, in time order; none on a flat or too
    short record.
    """
    if kind not in CHANNEL_KINDS:
        raise ValueError(f"channel kind {kind!r}: expected one of {CHANNEL_KINDS}")
    t = np.asarray(time, float)
    x = np.asarray(x, float)
    n = x.size
    w = steady_samples(t, kind) if n > 1 else 1
    if n < w + PERSIST + 2 or t.size != n:
        return EdgeSearch(channel, kind, (), 0.0, 0.0, w)
    span = float(np.max(x) - np.min(x))
    tiny = 1e-6 * span + 1e-12 * max(1.0, float(np.max(np.abs(x))))
    mean, std = _rolling(x, w)                   # row j: the window [j, j + w) before sample j + w
    noise = float(np.median(std[::w]))
    h = max(THRESHOLD_SIGMAS * noise, tiny)
    steady = std <= STEADY_SIGMAS * noise + tiny
    # the last steady window ending at or before each sample k (its row, -1 for none)
    rows = np.where(steady, np.arange(steady.size), -1)
    last = np.full(n, -1, dtype=np.int64)
    last[w:] = np.maximum.accumulate(rows)
    k_all = np.arange(w, n - PERSIST)
    ref_row = last[k_all]
    has_ref = ref_row >= 0
    level_k = np.where(has_ref, mean[np.maximum(ref_row, 0)], np.nan)
    size_n = max(w, int(round(SIZE_S / float(np.median(np.diff(t))))))
    hi_x, lo_x = float(np.max(x)), float(np.min(x))
    departs = np.zeros(k_all.size, dtype=np.int64)
    for sign in (1, -1):
        ok = has_ref & (sign * (x[k_all] - level_k) > h)
        for j in range(1, PERSIST + 1):
            ok &= sign * (x[k_all + j] - level_k) > h
        departs[ok] = sign
    found: list[tuple[int, int, float, float]] = []   # (index, sign, level, size)
    prev = -1
    for j in np.flatnonzero(departs):
        k, sign, row = int(k_all[j]), int(departs[j]), int(ref_row[j])
        if row < prev:                               # its reference window starts before the previous edge
            continue
        level = float(level_k[j])
        prev = k
        if kind == EXCITER and found and found[-1][1] == -sign and (
                level >= hi_x - h - LIMIT_SHARE * span if sign < 0 else level <= lo_x + h + LIMIT_SHARE * span):
            continue                                 # coming off the limit the last edge drove it to
        found.append((k, sign, level, 0.0))
    if not found:
        return EdgeSearch(channel, kind, (), noise, h, w)
    # each departure's size: the farthest the channel goes from its level before the next one
    found = [(k, sign, level, float(np.max(sign * (x[k:min(k + size_n, nxt)] - level))))
             for (k, sign, level, _), nxt in zip(found, [f[0] for f in found[1:]] + [n])]
    biggest = max(f[3] for f in found)
    found = [f for f in found if f[3] >= MIN_SHARE * biggest]
    p = FRONT_ORDER[kind]
    edges = []
    for i, (k, sign, level, size) in enumerate(found):
        end = found[i + 1][0] if i + 1 < len(found) else n
        after = float(np.median(x[k + (end - k) // 2:end]))
        d = sign * (x[:min(n, k + size_n)] - level)
        t1 = _crossing(t, d, k, h)
        level2 = max(2.0 * h, min(RISE_LEVELS * h, 0.5 * size))
        t2 = _crossing(t, d, k, level2)
        hidden = (t2 - t1) / ((level2 / h) ** (1.0 / p) - 1.0) if math.isfinite(t2) else float(t[k] - t[k - 1])
        lo = min(float(t[k - 1]), t1 - hidden)
        at = float(t[k])
        edges.append(Edge(index=k, jump_pu=after - level, nominal_s=at, fitted_s=at, offset_s=0.0, std_s=None,
                          lo_s=lo - at, hi_s=0.0, how="found", fitted=False, level_before=level,
                          departure=sign * size, level_after=after))
    return EdgeSearch(channel, kind, tuple(edges), noise, h, w)


#: the parts of a step / pulse record, in time order (a step test has the first three)
SEGMENT_NAMES = ("pre_trigger", "leading_edge", "plateau", "trailing_edge", "recovery")


def record_segments(n: int, lead: int, trail: int | None, edge_samples: int, *,
                  keep_empty: bool = False) -> list[tuple[str, int, int]]:
    """The record of `n` samples cut at its edges into (name, k0, k1), samples k0 <= k < k1:
    pre_trigger [0, lead), leading_edge the `edge_samples` after the leading edge (never past the
    trailing one), plateau up to the trailing edge (the record's end for a step), then
    trailing_edge (`edge_samples`) and recovery. Empty parts are left out unless `keep_empty` (a
    report lists every part of a pulse, an empty plateau too). The one segmentation
    the diagnosis' localisation and the report's error figures share."""
    w = max(1, int(edge_samples))
    end = trail if trail is not None else n
    cuts = [("pre_trigger", 0, lead), ("leading_edge", lead, min(lead + w, end)),
            ("plateau", min(lead + w, end), end)]
    if trail is not None:
        cuts += [("trailing_edge", trail, min(trail + w, n)), ("recovery", min(trail + w, n), n)]
    return [(name, a, b) for name, a, b in cuts if keep_empty or b > a]
