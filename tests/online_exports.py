"""Trending-recorder exports shaped like a real unit's commissioning exports (the Mostar unit's
on-line and no-load steps: its `SFS_*` column names, a date and a 7-digit clock column, 4.8 ms a
row with the host's stamps wandering around it, minutes of operation around the test), with
synthetic numbers: first-order responses around levels of the same size, and seeded noise. Not a
plant model: the import's checks look at levels, edges and time, which these hold.

`Export` says what to make: on line (P, Q recorded; the grid holds Vt: vt moves `vt_share` of the
step) or at no load (vt moves the step); a field-current regulator's step (ifd moves the step) or
an AVR's; a Q change before the test; a second test; the clock shortened to MM:SS.f as a
spreadsheet saves it; rows dropped (a gap); a channel refreshed every other row, or quantised.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

STEP_S = 0.0048                 # the recorder's 4.8 ms a row
RATE_HZ = 1.0 / STEP_S
CLOCK0_S = 12 * 3600 + 52 * 60 + 35.2364630
COLUMNS = ["SFS_Reg_Uc", "SFS_Meas_IfRel", "SFS_Meas_UgRel", "SFS_Meas_UfRel", "SFS_Meas_IgRel", "SFS_Meas_QRel",
           "SFS_Meas_PRel"]
#: the import options of such an export
CLOCK_ARGS = ["--date-column", "date", "--clock-column", "time", "--date-format", "%d.%m.%Y"]
MAPS = ["--map", "efd=SFS_Meas_UfRel", "--map", "vt=SFS_Meas_UgRel", "--map", "vr=SFS_Reg_Uc",
        "--map", "ifd=SFS_Meas_IfRel"]
PQ_MAPS = ["--map", "p=SFS_Meas_PRel", "--map", "q=SFS_Meas_QRel"]


@dataclass(frozen=True)
class Export:
    on_line: bool = True
    duration_s: float = 50.0
    #: the tests: (start s, hold s or None for a step left on), each +amplitude
    tests: tuple[tuple[float, float | None], ...] = ((35.0, 5.0),)
    amplitude: float = 0.1
    #: vt's settled share of the step (on line the grid holds it), and whether ifd moves the step
    #: (a field-current regulator's test) or less (an AVR's)
    vt_share: float = 0.07
    ifd_moves_step: bool = True
    #: a Q change before the test: (from s, to s, by how much, pu), vt and efd following it
    q_change: tuple[float, float, float] | None = None
    short_clock: bool = False
    drop_rows: tuple[int, int] | None = None
    #: the field voltage's forcing at each edge (its sign; decaying in 50 ms), pu of the export
    efd_kick: float = 0.0
    #: columns the recorder refreshes every other row (the row between repeats the one before)
    held: tuple[str, ...] = ()
    #: columns written rounded to this step (a quantised channel: it repeats where it is flat)
    quantum: dict[str, float] = field(default_factory=dict)
    seed: int = 0
    extra: dict[str, float] = field(default_factory=dict)


def _lag(t: np.ndarray, t0: float, tau: float) -> np.ndarray:
    x = np.clip((t - t0) / tau, 0.0, None)
    return np.where(t >= t0, 1.0 - np.exp(-x), 0.0)


def _response(t: np.ndarray, e: Export, tau: float) -> np.ndarray:
    """The tests as a sum of first-order steps (up at each start, down at start + hold)."""
    out = np.zeros_like(t)
    for start, hold in e.tests:
        out += _lag(t, start, tau)
        if hold is not None:
            out -= _lag(t, start + hold, tau)
    return out


def _kick(t: np.ndarray, e: Export, tau: float) -> np.ndarray:
    """A regulator's kick at each edge (its sign), decaying with tau: the regulator output jumps
    beyond its new level and settles, so that its level before a return is no ceiling."""
    out = np.zeros_like(t)
    for start, hold in e.tests:
        for at, sign in ((start, 1.0), (None if hold is None else start + hold, -1.0)):
            if at is not None:
                out += sign * np.where(t >= at, np.exp(-np.clip(t - at, 0.0, None) / tau), 0.0)
    return out


def _clock(seconds: float, short: bool) -> str:
    if short:   # a spreadsheet's MM:SS.f: the hours and all but one fraction digit dropped
        tenths = int(math.floor(seconds * 10.0 + 1e-9))
        return f"{tenths // 600 % 60:02d}:{tenths // 10 % 60:02d}.{tenths % 10:d}"
    ticks = int(round(seconds * 1e7))
    whole, frac = divmod(ticks, 10**7)
    return f"{whole // 3600:02d}:{whole // 60 % 60:02d}:{whole % 60:02d}.{frac:07d}"


def channels(e: Export) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(time s from the first row, evenly 4.8 ms apart; the columns of the export)."""
    rng = np.random.default_rng(e.seed)
    n = int(e.duration_s / STEP_S) + 1
    t = np.arange(n) * STEP_S
    a = e.amplitude
    step_fast, step_slow = _response(t, e, 0.03), _response(t, e, 0.6)
    q_pre = np.zeros(n)
    if e.q_change is not None:
        t0, t1, dq = e.q_change
        q_pre = dq * np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
    p0, q0 = (0.2, -0.01) if e.on_line else (0.0, 0.0)
    vt_gain = e.vt_share if e.on_line else 1.0
    ifd_gain = a if e.ifd_moves_step else 0.4 * a
    cols = {
        "SFS_Reg_Uc": 1.0 + 5.0 * a * step_fast + 10.0 * a * _kick(t, e, 0.05) + 2.0 * q_pre
        + rng.normal(0.0, 0.02, n),
        "SFS_Meas_IfRel": 0.50 + ifd_gain * step_slow + 0.9 * q_pre + rng.normal(0.0, 4e-4, n),
        "SFS_Meas_UgRel": 0.98 + vt_gain * a * step_slow + 0.1 * q_pre + rng.normal(0.0, 2e-4, n),
        "SFS_Meas_UfRel": 0.375 + 0.7 * a * step_slow + e.efd_kick * _kick(t, e, 0.05) + 0.6 * q_pre
        + rng.normal(0.0, 0.004, n),
        "SFS_Meas_IgRel": 0.2 + 0.3 * a * step_slow + rng.normal(0.0, 0.002, n),
        "SFS_Meas_QRel": q0 + 1.2 * a * step_slow + q_pre + rng.normal(0.0, 0.002, n),
        "SFS_Meas_PRel": p0 + rng.normal(0.0, 0.003, n),
    }
    return t, cols


def write(path: Path, e: Export) -> Path:
    """The export as the recorder writes it: date, time (the host's stamps: the even sampling
    plus a wander of +-0.25 ms), then COLUMNS."""
    t, cols = channels(e)
    for c in e.held:
        cols[c] = np.repeat(cols[c][::2], 2)[:t.size]
    for c, q in e.quantum.items():
        cols[c] = np.round(cols[c] / q) * q
    rng = np.random.default_rng(e.seed + 1000)
    stamps = CLOCK0_S + t + rng.uniform(-2.5e-4, 2.5e-4, t.size)
    keep = np.ones(t.size, bool)
    if e.drop_rows is not None:
        keep[e.drop_rows[0]:e.drop_rows[1]] = False
    lines = [",".join(["date", "time", *COLUMNS])]
    for k in np.flatnonzero(keep):
        lines.append(",".join(["20.09.2015", _clock(float(stamps[k]), e.short_clock)]
                              + [f"{float(cols[c][k]):.9f}" for c in COLUMNS]))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
