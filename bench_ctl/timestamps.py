"""The one UTC timestamp format of every file bench-ctl writes.

ISO 8601 with an explicit offset, `2026-03-14T09:26:53+00:00` (`datetime.isoformat`), so that
`datetime.fromisoformat` reads it back on every supported Python: captures' `created_utc`,
results, diagnoses, reports, the bench lock, and - to the microsecond - each audit line and each
register write (`t_utc`). This module imports nothing of the project: drivers and every layer
above them may use it.
"""
from __future__ import annotations

import datetime as dt
import time

__all__ = ["utc_at_monotonic", "utc_now_text", "utc_text"]


def utc_text(moment: dt.datetime, timespec: str = "seconds") -> str:
    """`moment` (an aware datetime) in UTC as `YYYY-MM-DDTHH:MM:SS+00:00` (`timespec` as
    `datetime.isoformat` takes it: "seconds", "milliseconds", "microseconds")."""
    if moment.tzinfo is None:
        raise ValueError(f"{moment!r} has no time zone: a written timestamp is always UTC")
    return moment.astimezone(dt.UTC).isoformat(timespec=timespec)


def utc_now_text(timespec: str = "seconds") -> str:
    """Now, in the format of every file bench-ctl writes (see `utc_text`)."""
    return utc_text(dt.datetime.now(dt.UTC), timespec)


def utc_at_monotonic(t_mono: float, timespec: str = "microseconds") -> str:
    """The wall-clock time of the monotonic instant `t_mono` (`time.monotonic()` of this process),
    e.g. when a request frame left."""
    wall = time.time() - (time.monotonic() - t_mono)
    return utc_text(dt.datetime.fromtimestamp(wall, dt.UTC), timespec)
