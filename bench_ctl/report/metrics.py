"""Error figures of a fit: where the setpoint pulse edges are, MSE / RMSE / NRMSE, peak error,
the objective, and how the residual's energy splits over the segments of the response.

Definitions (they are printed in the report too):
- residual r = efd measured - efd simulated, sample by sample;
- MSE = mean(r^2) over all samples (the paper's figure), RMSE = sqrt(MSE);
- NRMSE = RMSE / (max - min of the measured efd);
- objective = trapezoidal integral of w_efd r^2 (+ w_vt r_vt^2 when vt is weighted and recorded);
- segments: pre-trigger [start, leading edge), leading edge [edge, edge + window), plateau
  [edge + window, trailing edge), trailing edge [trailing, trailing + window), recovery [..., end];
  share = sum of r^2 in the segment / sum of r^2 over the record.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench_ctl.signals import edges as edge_finder
from bench_ctl.signals.edges import EdgeSearch

DEFAULT_EDGE_WINDOW_S = 0.2
MIN_NOISE_SAMPLES = 20


def setpoint_edges(time: np.ndarray, usetp: np.ndarray) -> EdgeSearch:
    """The test's edges in the recorded setpoint, by the one finder (`bench_ctl.signals.edges`):
    its `lead` and `trail` (None: a step), each first showing at sample `index`, time `hi_s`."""
    return edge_finder.find_edges(np.asarray(time, float), np.asarray(usetp, float), kind=edge_finder.SETPOINT)


def edge_times(edges: EdgeSearch) -> tuple[float | None, float | None]:
    """The instants of the first samples showing the leading and the trailing edge (None: none)."""
    lead, trail = edges.pulse()
    return (None if lead is None else lead.nominal_s), (None if trail is None else trail.nominal_s)


@dataclass(frozen=True)
class Segment:
    name: str
    t0: float
    t1: float
    n: int
    share: float  # of the residual energy
    mse: float    # mean squared residual within the segment (nan when empty)


@dataclass(frozen=True)
class ErrorFigures:
    mse: float
    rmse: float
    nrmse: float
    efd_range: float
    peak_abs: float
    peak_signed: float
    peak_time_s: float
    objective: float
    segments: tuple[Segment, ...]
    noise_floor: float | None  # variance of the measured efd before the trigger
    noise_samples: int


def trapezoid_sq(r: np.ndarray, dt: float) -> float:
    sq = np.asarray(r, float) ** 2
    return float(dt * (sq.sum() - 0.5 * (sq[0] + sq[-1])))


def window_slice(time: np.ndarray, window: tuple[float, float] | None) -> slice:
    """Samples of a fit window given in seconds from the record's start (both ends included,
    to within 1e-9 of a step), as identification selects them; the whole record for None."""
    if window is None:
        return slice(0, time.size)
    t = np.asarray(time, float) - time[0]
    dt = float(t[-1]) / (t.size - 1)
    i0 = int(np.searchsorted(t, window[0] - 1e-9 * dt, side="left"))
    i1 = int(np.searchsorted(t, window[1] + 1e-9 * dt, side="right"))
    return slice(i0, i1)


def segment_bounds(time: np.ndarray, edges: EdgeSearch,
                   window_s: float = DEFAULT_EDGE_WINDOW_S) -> list[tuple[str, float, float]]:
    """(name, t0, t1) of each segment (`model.edges.record_segments`, the edge parts `window_s`
    long); samples with t0 <= t < t1 belong to it (the last one includes the final sample)."""
    time = np.asarray(time, float)
    n = time.size
    if edges.lead is None:
        return [("whole record", float(time[0]), float(time[-1]))]
    dt = float(time[-1] - time[0]) / (n - 1)
    parts = edge_finder.record_segments(n, edges.lead.index, edges.trail_index,
                                        int(round(window_s / dt)), keep_empty=True)
    return [(name, float(time[a]), float(time[b]) if b < n else float(time[-1])) for name, a, b in parts]


def error_figures(time: np.ndarray, efd_meas: np.ndarray, efd_sim: np.ndarray, edges: EdgeSearch,
                  *, window_s: float = DEFAULT_EDGE_WINDOW_S, w_efd: float = 1.0,
                  vt_meas: np.ndarray | None = None, vt_sim: np.ndarray | None = None,
                  w_vt: float = 0.0) -> ErrorFigures:
    time = np.asarray(time, float)
    meas = np.asarray(efd_meas, float)
    r = meas - np.asarray(efd_sim, float)
    dt = float(time[-1] - time[0]) / (time.size - 1)
    sq = r * r
    total = float(sq.sum())
    mse = float(sq.mean())
    rng = float(meas.max() - meas.min())
    k = int(np.argmax(np.abs(r)))
    obj = w_efd * trapezoid_sq(r, dt)
    if w_vt and vt_meas is not None and vt_sim is not None:
        obj += w_vt * trapezoid_sq(np.asarray(vt_meas, float) - np.asarray(vt_sim, float), dt)
    segments = []
    bounds = segment_bounds(time, edges, window_s)
    for j, (name, t0, t1) in enumerate(bounds):
        last = j == len(bounds) - 1
        mask = (time >= t0) & ((time <= t1) if last else (time < t1))
        n = int(mask.sum())
        seg_sq = float(sq[mask].sum())
        segments.append(Segment(name, t0, t1, n, seg_sq / total if total > 0 else 0.0,
                                seg_sq / n if n else float("nan")))
    noise, n_pre = None, 0
    if edges.lead is not None:
        n_pre = edges.lead.index
        if n_pre >= MIN_NOISE_SAMPLES:
            noise = float(np.var(meas[:n_pre], ddof=1))
    return ErrorFigures(mse=mse, rmse=float(np.sqrt(mse)),
                        nrmse=float(np.sqrt(mse) / rng) if rng > 0 else float("nan"),
                        efd_range=rng, peak_abs=float(abs(r[k])), peak_signed=float(r[k]),
                        peak_time_s=float(time[k]), objective=obj, segments=tuple(segments),
                        noise_floor=noise, noise_samples=n_pre)
