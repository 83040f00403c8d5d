"""Where the model misses: the noise floor, the test's edges, residual energy per segment and band.

The noise floor is the variance of the recorded efd before the first setpoint change (a straight
line removed first, so a slow drift of the recorder does not count as noise): the smallest MSE a
model can reach on that record. The record is cut at the setpoint edges into pre_trigger,
leading_edge, plateau, trailing_edge and recovery; each segment's share of the residual energy
(sum of squared residuals) says where the model misses. The residual's spectrum gives the share
per frequency band (slow: below 1 Hz, loop dynamics: 1-10 Hz, fast: above 10 Hz).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from bench_ctl.exitcodes import BadInput
from bench_ctl.signals import edges as model_edges
from bench_ctl.signals.edges import EdgeSearch

from .result_file import BandShare, Localization, SegmentShare

log = logging.getLogger(__name__)

#: guard samples left out before the first setpoint change (the response may start there)
PRE_GUARD = 2
#: length of the leading/trailing edge segments (s), at most a quarter of the pulse width
EDGE_S = 0.2
BANDS_HZ = (("slow", 0.0, 1.0), ("loop", 1.0, 10.0), ("fast", 10.0, math.inf))


class DiagnosisError(BadInput):
    """A capture the diagnosis cannot use; the message names the capture and what is wrong."""


@dataclass(frozen=True)
class NoiseFloor:
    variance: float      # pu^2
    n: int               # samples used
    t0: float
    t1: float
    rel_se: float        # relative standard error of the variance estimate, sqrt(2 / (n - 2))


def pulse_edges(usetp: np.ndarray, source: str = "capture") -> EdgeSearch:
    """The test's setpoint edges, by the one edge finder (`bench_ctl.signals.edges.find_edges`, a
    setpoint channel on a sample-index axis): its `lead` (always there: a record without one is
    refused) and `trail` (None for a step test)."""
    u = np.asarray(usetp, float)
    found = model_edges.find_edges(np.arange(u.size, dtype=float), u, kind=model_edges.SETPOINT)
    if found.lead is None:
        raise DiagnosisError(f"{source}: usetp never changes; the diagnosis needs a step or pulse test")
    return found


def noise_floor(efd: np.ndarray, dt: float, edges: EdgeSearch, source: str = "capture") -> NoiseFloor:
    """Variance of the detrended pre-trigger efd samples."""
    n = edges.lead.index - PRE_GUARD
    if n < 20:
        raise DiagnosisError(f"{source}: only {max(n, 0)} pre-trigger samples before the first setpoint "
                             f"change at t = {edges.lead.index * dt:.3f} s; at least 20 are needed for the noise floor")
    y = np.asarray(efd[:n], float)
    t = np.arange(n) * dt
    coef = np.polyfit(t, y, 1)
    res = y - np.polyval(coef, t)
    var = float(np.sum(res * res) / (n - 2))
    if var <= 0.0:  # a perfectly flat (noise-free, unquantised) record: floor at one LSB of a float
        var = float(np.finfo(float).eps * max(1.0, float(np.mean(y * y))))
    return NoiseFloor(var, n, 0.0, (n - 1) * dt, math.sqrt(2.0 / (n - 2)))


@dataclass(frozen=True)
class Segment:
    name: str
    k0: int
    k1: int  # exclusive


def segments(n: int, dt: float, edges: EdgeSearch) -> list[Segment]:
    """pre_trigger, leading_edge, plateau, trailing_edge, recovery (step test: the first three);
    the edge parts EDGE_S long, at most a quarter of the pulse (`model.edges.record_segments`)."""
    k_on, k_off = edges.lead.index, edges.trail_index
    w = max(1, int(round(min(EDGE_S, 0.25 * ((k_off if k_off is not None else n) - k_on) * dt) / dt)))
    return [Segment(name, a, b) for name, a, b in model_edges.record_segments(n, k_on, k_off, w)]


def segment_shares(residual: np.ndarray, dt: float, segs: list[Segment]) -> list[SegmentShare]:
    r2 = np.asarray(residual, float) ** 2
    total = float(r2.sum())
    return [SegmentShare(s.name, s.k0 * dt, s.k1 * dt, e / total if total > 0 else 0.0, e / (s.k1 - s.k0))
            for s, e in ((s, float(r2[s.k0:s.k1].sum())) for s in segs)]


def band_shares(residual: np.ndarray, dt: float) -> list[BandShare]:
    """Share of the residual energy per band from the one-sided power spectrum (Parseval)."""
    r = np.asarray(residual, float)
    n = r.size
    spec = np.abs(np.fft.rfft(r)) ** 2
    weight = np.full(spec.size, 2.0)
    weight[0] = 1.0
    if n % 2 == 0:
        weight[-1] = 1.0
    power = spec * weight
    f = np.fft.rfftfreq(n, dt)
    total = float(power.sum())
    nyq = 0.5 / dt
    out = []
    for name, f0, f1 in BANDS_HZ:
        if f0 >= nyq:
            continue
        sel = (f >= f0) & (f < f1)
        out.append(BandShare(name, f0, min(f1, nyq), float(power[sel].sum()) / total if total > 0 else 0.0))
    return out


def localization(residual: np.ndarray, dt: float, edges: EdgeSearch) -> Localization:
    segs = segments(residual.size, dt, edges)
    return Localization(tuple(segment_shares(residual, dt, segs)), tuple(band_shares(residual, dt)))


def where_lines(loc: Localization, floor: float | None, *, indent: str = "  ") -> list[str]:
    """A residual's `localization` in words: the segments holding at least 5 % of its energy, the
    largest first (their interval, share and error over the noise floor), and its bands."""
    segs = sorted(loc.segments, key=lambda g: -g.share)

    def x_floor(g: SegmentShare) -> str:
        return f"{g.mse / floor:.3g}" if floor else "-"
    lines = [f"{indent}what is left, where: " + ", ".join(
        f"{g.name.replace('_', ' ')} {g.t0:.2f}-{g.t1:.2f} s {100 * g.share:.0f} % ({x_floor(g)}x floor)"
        for g in segs if g.share >= 0.05)]
    if loc.bands:
        lines.append(f"{indent}by band: " + ", ".join(
            f"{b.name} ({b.f0_hz:g}-{b.f1_hz:g} Hz) {100 * b.share:.0f} %" for b in loc.bands))
    return lines
