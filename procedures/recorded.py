"""What both test sheets (no_load_pulse, online_step) share: what they read from the recorded
setpoint, how they print a signed figure, how they read while a timed write is due, and how they
carry trouble met after the test to the end so that the record is kept."""
from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from bench_ctl.runner.devices import TIMED_WRITE_GUARD_S, DeviceError
from bench_ctl.signals.edges import SETPOINT, find_edges

__all__ = ["RECOVERY_READ_ATTEMPTS", "Carried", "RecordedPulse", "link_free_at", "measure_pulse",
           "signed", "timed_write_cause"]

log = logging.getLogger(__name__)

#: tries of each read after the test (recovery): a lost reply is read again, not the end of the record
RECOVERY_READ_ATTEMPTS = 3


def link_free_at(deadline_mono: float, request_timeout_s: float) -> float:
    """When a write timed for `deadline_mono` asks for the link (one request timeout and the guard
    before it). A procedure's read while the write is due starts before then or not at all
    (`read_many(start_by=...)`): the one request that may still be in flight then ends (answered
    or timed out) before the deadline, and the link's lock gives the write the link right after
    it, so the read never delays the write. The same thread reads and then writes: a read that
    started later, or a second read after it, would."""
    return deadline_mono - TIMED_WRITE_GUARD_S - request_timeout_s


#: a timed write that asks for the link within this of its thread's previous request ending was
#: held up by that request (the link), not by this host
BUSY_GAP_S = 0.02


def timed_write_cause(record: Any) -> str:
    """Why a timed write (a WriteRecord with its deadline) left late: the link, when the write got
    the link late because a request in flight on it ended late, or asked for it late because its
    own thread's requests before it (the pulse write's reply and read-back) ended late: a slow
    device; else this host (it asked or sent late with the link free: the process or the machine
    stalled)."""
    at, ask, held = record.at_mono, record.t_ask_mono, record.t_link_mono
    prev = getattr(record, "t_prev_mono", None)
    if at is None or ask is None or held is None:
        return "this host: the process or the machine stalled"
    due = at - TIMED_WRITE_GUARD_S
    if ask > due and prev is not None and ask - prev < BUSY_GAP_S:
        return (f"the link: the requests before the restore (the pulse write's reply and read-back) ended "
                f"{signed((prev - at) * 1e3, 1)} ms from the deadline (a slow device)")
    if ask <= due < held:
        return (f"the link: a request in flight on it ended {signed((held - at) * 1e3, 1)} ms from the deadline "
                "(a slow device)")
    return "this host: the process or the machine stalled"


class Carried:
    """Trouble met after the test (a read lost for good during recovery, a failing heartbeat, a
    release the device did not confirm), noted and carried to the end so that the record is still
    downloaded and saved; the run then ends with exit 3 naming the first (`first`)."""

    def __init__(self, run: Any) -> None:
        self.run = run
        self.first: str | None = None
        self.count = 0
        self._beat_noted = False

    def note(self, what: str, exc: DeviceError) -> None:
        self.count += 1
        text = f"{what}: {exc.summary}"
        if self.first is None:
            self.first = f"{text} (the record was still downloaded and saved)"
        self.run.note("carried", what=what, error=type(exc).__name__, message=exc.summary, count=self.count)
        log.warning("after the test: %s; carried on so that the record is kept", text)

    def read(self, what: str, fn: Callable[[], float]) -> float:
        """`fn()` (a read with RECOVERY_READ_ATTEMPTS), NaN noted here when it fails for good."""
        try:
            return fn()
        except DeviceError as exc:
            self.note(what, exc)
            return math.nan

    def check(self, fn: Callable[[], None]) -> None:
        """`fn()` (the bench's heartbeat check), its error noted (once) instead of raised."""
        try:
            fn()
        except DeviceError as exc:
            if not self._beat_noted:
                self._beat_noted = True
                self.note("heartbeat", exc)


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
