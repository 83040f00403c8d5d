"""Checks on a capture's time axis (increasing, uniform step) and the one repair the importer
may make when asked: linear resampling onto a uniform grid.

Uniform means every step is within `RELATIVE_JITTER` of the median step, plus the rounding of
float64 time values (a few ulps of the largest |t|). The median, not the mean, is the expected
step so that one gap is reported where it is instead of shifting every step.
"""
from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence

import numpy as np

from bench_ctl.capture.errors import CaptureError

log = logging.getLogger(__name__)

RELATIVE_JITTER = 1e-6
MIN_SAMPLES = 2


def _row(rows: Sequence[int] | np.ndarray | None, i: int) -> int:
    return int(rows[i]) if rows is not None else i + 1


def step_tolerance(time: np.ndarray, step: float) -> float:
    """Allowed deviation of one step from `step`: relative jitter plus float64 rounding."""
    scale = max(abs(float(time[0])), abs(float(time[-1])), abs(step))
    return RELATIVE_JITTER * abs(step) + 8.0 * np.finfo(np.float64).eps * scale


def step_stats(time: np.ndarray) -> dict[str, float]:
    """min / median / max of the time steps (s)."""
    d = np.diff(np.asarray(time, dtype=np.float64))
    return {"min_s": float(d.min()), "median_s": float(np.median(d)), "max_s": float(d.max())}


def check_time(
    time: np.ndarray,
    *,
    file: str,
    rows: Sequence[int] | np.ndarray | None = None,
    column: str = "time",
    row_kind: str = "row",
    uniform: bool = True,
) -> None:
    """Refuse fewer than 2 samples, a repeated or decreasing time, and (when `uniform`) a step
    off the median step. `rows[i]` is the row (line number) to name for sample `i`."""
    t = np.asarray(time, dtype=np.float64)
    if t.size < MIN_SAMPLES:
        raise CaptureError(file, f"{t.size} data row(s); a capture needs at least {MIN_SAMPLES}")
    d = np.diff(t)
    bad = np.flatnonzero(~(d > 0))
    if bad.size:
        i = int(bad[0])
        what = "repeated" if d[i] == 0 else "decreasing"
        raise CaptureError(
            file, f"{what} time: {float(t[i + 1])!r} s after {float(t[i])!r} s at {row_kind} "
            f"{_row(rows, i)}",
            row=_row(rows, i + 1), column=column, row_kind=row_kind,
        )
    if not uniform:
        return
    step = float(np.median(d))
    tol = step_tolerance(t, step)
    off = np.flatnonzero(np.abs(d - step) > tol)
    if off.size:
        i = int(off[0])
        raise CaptureError(
            file,
            f"non-uniform time step: {d[i]:.9g} s from the previous {row_kind}, expected "
            f"{step:.9g} s (the median step; tolerance {tol:.3g} s); {off.size} of {d.size} "
            f"steps are off, steps range {d.min():.9g}..{d.max():.9g} s "
            "(resampling is only done when asked for)",
            row=_row(rows, i + 1), column=column, row_kind=row_kind,
        )


def uniform_grid(t0: float, t_end: float, rate_hz: float) -> np.ndarray:
    """t0, t0 + 1/rate, ... up to t_end (inclusive within float rounding)."""
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"resample rate must be a positive number of Hz, got {rate_hz!r}")
    span = (t_end - t0) * rate_hz
    n = int(np.floor(span + 1e-9 * max(1.0, span))) + 1
    return t0 + np.arange(n, dtype=np.float64) / rate_hz


def resample_linear(
    time: np.ndarray, columns: Mapping[str, np.ndarray], rate_hz: float
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Linear interpolation of every column onto a uniform grid from time[0] at `rate_hz`.

    `time` must already be strictly increasing (see `check_time(uniform=False)`)."""
    grid = uniform_grid(float(time[0]), float(time[-1]), rate_hz)
    out = {name: np.interp(grid, time, np.asarray(values, dtype=np.float64))
           for name, values in columns.items()}
    log.debug("resampled %d samples to %d at %g Hz", len(time), grid.size, rate_hz)
    return grid, out
