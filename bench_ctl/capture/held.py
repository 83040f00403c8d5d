"""Channels the recorder refreshes slower than it writes rows (`bench-ctl import`, issue 49 item 4).

A trending recorder writes every channel on every row, but some channels come from a device that
updates them less often: the row then repeats the channel's last value. On the Mostar unit's exports
(4.8 ms a row) the field voltage and current repeat the row before in about 28 % of the rows, also
while the field voltage jumps at a step's edge; P, Q, Vt and the stator current repeat only where they
are flat (their quantisation). Such a channel shows an edge up to a row late, as a staircase that no
model of the unit follows: what a diagnosis leaves in the first samples after each edge is partly this.
The import measures it and warns; with `--held interpolate` it puts each repeated row of a held
channel between the fresh rows around it (linear in time), before anything else reads the channel.
That is no neutral repair: an edge then spreads over the held rows. On the Mostar on-line 5 % step
it lowers what the diagnosis leaves after its last explained step, with the same effects; on the
no-load 10 % step the diagnosis reads the spread edge as a setpoint ramp where the rows as written
gave a recorder time skew (the held rows' own signature: the channel shows an edge late). The
figures: docs/benchmarks.md (real_online.py, diagnose_seeds.py).

The rule, per mapped channel other than usetp: a row "moves fast" when the channel changes over the
two rows around it by more than FAST_STEPS times its typical row-to-row change (the median of its
non-zero changes: the noise, or the quantisation step); the channel is held when at least MIN_FAST
rows move fast and at least SHARE of those repeat the row before. A quantised channel repeats where it
is flat, never while it moves fast; a held one repeats at any speed.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

#: what `--held` does with a held channel's repeated rows
HELD_TREATMENTS = ("keep", "interpolate")
FAST_STEPS = 10.0
MIN_FAST = 10
SHARE = 0.15


def held_channels(channels: Mapping[str, np.ndarray], columns: Mapping[str, str]) -> dict[str, Any]:
    """The sidecar's `import.held_samples`: per mapped channel (our name -> its source column in
    `columns`, the values on the source's own rows in `channels`) the share of rows that repeat the
    one before, overall and among the rows that move fast, the longest run of one value, and whether
    the channel is held (module docstring); `held` lists those."""
    rows = []
    for name, column in columns.items():
        if name == "usetp" or name not in channels:
            continue
        v = np.asarray(channels[name], float)
        if v.size < 3:
            continue
        step = np.abs(np.diff(v))
        moved = step[step > 0]
        repeat = np.r_[False, step == 0]
        typical = float(np.median(moved)) if moved.size else 0.0
        around = np.r_[0.0, np.abs(v[2:] - v[:-2]), 0.0]
        fast = around > FAST_STEPS * typical if typical > 0 else np.zeros(v.size, bool)
        n_fast = int(np.count_nonzero(fast))
        share_fast = float(np.mean(repeat[fast])) if n_fast else None
        starts = np.flatnonzero(np.r_[True, ~repeat[1:]])
        longest = int(np.max(np.diff(np.r_[starts, v.size])))
        rows.append({"channel": name, "column": column, "share": float(np.mean(repeat)),
                     "fast_rows": n_fast, "share_fast": share_fast, "longest_run": longest,
                     "held": bool(n_fast >= MIN_FAST and share_fast is not None and share_fast >= SHARE)})
    return {"rule": f"held: >= {SHARE:g} of the rows that move more than {FAST_STEPS:g} x the typical change "
                    f"(at least {MIN_FAST}) repeat the row before",
            "channels": rows, "held": [r["channel"] for r in rows if r["held"]]}


def interpolated(time: np.ndarray, values: np.ndarray) -> np.ndarray:
    """values with every row that repeats the row before replaced by the straight line between the
    fresh rows around it (in time); the rows after the last fresh one keep its value."""
    v = np.asarray(values, float)
    fresh = np.r_[True, v[1:] != v[:-1]]
    return np.interp(np.asarray(time, float), np.asarray(time, float)[fresh], v[fresh])


def warning_lines(block: Mapping[str, Any]) -> list[str]:
    """The console's lines for the held channels (nothing when none is): a warning when kept as
    written, a note of what was interpolated otherwise."""
    lines = []
    for r in block.get("channels", ()):
        if not r["held"]:
            continue
        what = (f"{r['channel']} (column {r['column']!r}) repeats the row before in {100 * r['share_fast']:.0f} % of "
                f"the rows where it moves fast ({100 * r['share']:.0f} % of all, one value for up to "
                f"{r['longest_run']} rows): the recorder refreshes it slower than it writes rows")
        if block.get("treatment") == "interpolate":
            lines.append(f"note: {what}; each repeated row interpolated between the fresh rows around it (--held "
                         "interpolate)")
        else:
            lines.append(f"warning: {what}, so an edge shows up to a row late there, as a staircase no model "
                         "follows (a diagnosis may name it a time skew); --held interpolate puts each repeated row "
                         "between the fresh rows around it (the edge then spreads over them, as a short ramp)")
    return lines
