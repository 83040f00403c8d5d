"""Is the part of a record before the test steady? (`bench-ctl import`, issue 49 item 4)

Every fit takes the pre-step part for the unit's steady state (its operating point, the efd
level, the noise floor). A real export that holds minutes of operation around the test often is
not steady there: a slow reference change, a Q change before the step. The import warns and
suggests a window that leaves it out (`--window`); it refuses nothing (the user chooses).

The rule, per channel among vt, q and efd: the means of its BLOCK_S blocks before the first
edge (less the guard) may spread at most the band `max(SHARE x the channel's change over the
test, SIGMAS x the block means' noise)`; the channel's change over the test is its median over
RESPONSE_S after the leading edge less its mean over RESPONSE_S before it. The steady part is the
longest run of blocks ending at the edge within every channel's band; a window starting there is
suggested (it must leave at least MIN_PRE_S before the edge, or that is said too).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

#: the channels that respond to a voltage-reference step (P follows the turbine: its slow drift is
#: the governor's, not a pre-step part the AVR's fit cares about)
CHANNELS = ("vt", "q", "efd")
BLOCK_S = 1.0
SHARE = 0.2
SIGMAS = 4.0
RESPONSE_S = 2.0
GUARD_S = 0.05
#: a pre-step part shorter than this gives the fits little steady state to start from
MIN_PRE_S = 2.0


def _blocks(t: np.ndarray, x: np.ndarray, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Block means of x over [t0, t1) in BLOCK_S blocks ending at t1 (the first block may be
    partial and is dropped when shorter than half a block), the blocks' start times, and the noise
    of a block mean (the median within-block standard deviation over sqrt(samples))."""
    edges = t1 - BLOCK_S * np.arange(int(math.floor((t1 - t0) / BLOCK_S)) + 1)[::-1]
    means, starts, sds, ns = [], [], [], []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (t >= a) & (t < b)
        if np.count_nonzero(sel) >= 2:
            means.append(float(np.mean(x[sel])))
            starts.append(float(a))
            sds.append(float(np.std(x[sel], ddof=1)))
            ns.append(int(np.count_nonzero(sel)))
    if not means:
        return np.zeros(0), np.zeros(0), 0.0
    noise = float(np.median(sds)) / math.sqrt(float(np.median(ns)))
    return np.array(means), np.array(starts), noise


def pre_step_steadiness(time: np.ndarray, channels: Mapping[str, np.ndarray], columns: Mapping[str, str],
                        edge_lo_s: float, edge_hi_s: float, end_s: float, origin_s: float) -> dict[str, Any] | None:
    """The sidecar's `import.pre_step` (see the module docstring); None when the record has fewer
    than two blocks before the edge or none of the channels. `end_s` (the record's end) ends the
    suggested window, written in seconds from `origin_s` (the export's first sample)."""
    t = np.asarray(time, float)
    t0, t1 = float(t[0]), edge_lo_s - GUARD_S
    if t1 - t0 < 2 * BLOCK_S:
        return None
    rows = []
    steady_from = t0
    for name in CHANNELS:
        x = channels.get(name)
        if x is None:
            continue
        x = np.asarray(x, float)
        means, starts, noise = _blocks(t, x, t0, t1)
        if means.size < 2:
            continue
        before = x[(t >= edge_lo_s - RESPONSE_S) & (t < edge_lo_s)]
        after = x[(t > edge_hi_s) & (t <= edge_hi_s + RESPONSE_S)]
        response = abs(float(np.median(after)) - float(np.mean(before))) if before.size and after.size else 0.0
        band = max(SHARE * response, SIGMAS * noise)
        spread = float(means.max() - means.min())
        # the longest run of blocks ending at the edge within the band
        k = means.size - 1
        lo = hi = means[k]
        while k > 0 and max(hi, means[k - 1]) - min(lo, means[k - 1]) <= band:
            k -= 1
            lo, hi = min(lo, means[k]), max(hi, means[k])
        steady_from = max(steady_from, float(starts[k]) if k > 0 or spread > band else t0)
        i_min, i_max = int(np.argmin(means)), int(np.argmax(means))
        rows.append({"channel": name, "column": columns.get(name), "steady": bool(spread <= band),
                     "spread": spread, "band": band, "response": response, "block_noise": noise,
                     "min": float(means[i_min]), "min_at_s": float(starts[i_min]),
                     "max": float(means[i_max]), "max_at_s": float(starts[i_max]),
                     "first": float(means[0]), "last": float(means[-1])})
    if not rows:
        return None
    steady = all(r["steady"] for r in rows)
    out: dict[str, Any] = {"steady": steady, "t0_s": t0, "t1_s": t1, "block_s": BLOCK_S, "share": SHARE,
                           "sigmas": SIGMAS, "channels": rows, "steady_from_s": steady_from,
                           "steady_s": edge_lo_s - steady_from, "suggested_window": None}
    if not steady:
        start = math.floor((steady_from - origin_s) * 10.0) / 10.0
        out["suggested_window"] = f"{start:.1f}:{math.floor((end_s - origin_s) * 10.0) / 10.0:.1f}"
    return out


def warning_lines(block: Mapping[str, Any]) -> list[str]:
    """The console's warning for a pre-step part that is not steady (nothing when it is)."""
    if block.get("steady", True):
        return []
    moved = []
    for r in block["channels"]:
        if r["steady"]:
            continue
        first, last = ("min", "max") if r["min_at_s"] <= r["max_at_s"] else ("max", "min")
        moved.append(f"{r['channel']} moves from {r[first]:.4g} (t = {r[first + '_at_s']:.1f} s) to {r[last]:.4g} "
                     f"(t = {r[last + '_at_s']:.1f} s), {r['spread'] / r['band']:.1f} x what the test's own change "
                     "allows")
    lines = [f"warning: the part before the test (t = {block['t0_s']:.1f} .. {block['t1_s']:.1f} s) is not steady: "
             + "; ".join(moved) + ". Every fit takes it for the unit's steady state."]
    short = "" if block["steady_s"] >= MIN_PRE_S else (
        f" (it leaves only {block['steady_s']:.1f} s before the step, less than {MIN_PRE_S:g} s)")
    lines.append(f"  steady from t = {block['steady_from_s']:.1f} s: import the test alone with --window "
                 f"{block['suggested_window']} (seconds from the export's first sample){short}")
    return lines
