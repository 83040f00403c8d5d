"""What both test sheets (no_load_pulse, online_step) read from the recorded setpoint, and how they
print a signed figure."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from bench_ctl.signals.edges import SETPOINT, find_edges

__all__ = ["RecordedPulse", "measure_pulse", "signed"]


@dataclass(frozen=True)
class RecordedPulse:
    """The pulse as the recorder saw it in usetp."""

    start_s: float
    width_s: float
    amplitude_pu: float
    baseline_pu: float


def measure_pulse(time_s: np.ndarray, usetp: np.ndarray, expected_pu: float,
                  pre_samples: int = 1) -> RecordedPulse:
    """The pulse in the recorded setpoint, by the shared edge finder (`bench_ctl.signals.edges`, a
    setpoint channel): the first edge departing from its level by more than half the expected
    amplitude, either way, and the first later edge back. Its start is the leading edge's first
    sample, its width the samples from there to the trailing edge's first sample (to the end of
    the record when usetp never came back) x the sample step, its amplitude the mean of usetp
    over those samples above the baseline (median of the first `pre_samples`, the pre-trigger
    part). ValueError when no edge departs that far."""
    time_s, usetp = np.asarray(time_s, float), np.asarray(usetp, float)
    baseline = float(np.median(usetp[:max(1, pre_samples)]))
    half = abs(expected_pu) / 2
    search = find_edges(time_s, usetp, kind=SETPOINT, channel="usetp")
    lead, trail = replace(search, edges=tuple(e for e in search.edges if abs(e.departure) > half)).pulse()
    if lead is None:
        raise ValueError(f"no pulse in usetp (no edge departs {half:g} pu from the level before it; "
                         f"initial {baseline:g} pu)")
    i0 = lead.index
    i1 = trail.index if trail is not None else usetp.size
    dt = float(time_s[1] - time_s[0])
    return RecordedPulse(start_s=float(time_s[i0]), width_s=(i1 - i0) * dt,
                         amplitude_pu=float(np.mean(usetp[i0:i1]) - baseline),
                         baseline_pu=baseline)


def signed(value: float, decimals: int) -> str:
    """`+1.2`, `-0.3`, and `0.0` for anything that rounds to zero (never `-0.0` or `5e-06`)."""
    text = f"{value:+.{decimals}f}"
    return text[1:] if float(text) == 0 else text
