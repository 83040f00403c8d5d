"""A time base rebuilt from the recorder's own rate (`bench-ctl import --rate HZ`), and the
shortened clock column it answers (issue 49 item 4).

A trending recorder samples evenly, but its export's clock is often the host's, stamped when a
block arrived (jitter that is not the sampling's), and a spreadsheet that saved the export may
have shortened the clock to `MM:SS.f` (`07:10.2`): the hours and everything below 0.1 s are lost,
and the minutes wrap at the hour. Where the samples are evenly spaced the truer time base is
t = k / rate. `rebuild` makes it and checks it against what the file's own time marks say: every
mark within its resolution plus two samples of the rebuilt instant, otherwise the rows are not
evenly spaced at that rate (a gap, another rate) and the file is refused at the first row that
disagrees. Nothing here guesses the rate: the user states it (the refusal of a shortened clock
says what the clock's own span gives).
"""
from __future__ import annotations

import re
from typing import Any

import numpy as np

from bench_ctl.capture.errors import CaptureError

#: a clock cell a spreadsheet shortened: MM:SS with an optional fraction, no hours
SHORT_CLOCK = re.compile(r"(\d{1,2}):(\d{2})(?:[.,](\d{1,9}))?")
#: the rebuilt instant may lie this many samples beyond the marks' resolution from the mark
SLACK_SAMPLES = 2.0


def short_clock_seconds(cells: list[str], lines: np.ndarray, file: str, column: str) -> tuple[np.ndarray, float]:
    """The MM:SS.f cells as seconds from the first, unwrapped at the hour (the hours are lost:
    a step back by more than half an hour is the next hour), and their resolution (s)."""
    out = np.empty(len(cells), dtype=np.float64)
    digits = 0
    for i, cell in enumerate(cells):
        m = SHORT_CLOCK.fullmatch(cell)
        if m is None or int(m.group(2)) > 59:
            raise CaptureError(file, "the clock column changes format here: MM:SS.f above, not here",
                               row=int(lines[i]), column=column)
        frac = m.group(3) or ""
        digits = max(digits, len(frac))
        out[i] = int(m.group(1)) * 60 + int(m.group(2)) + (int(frac) / 10 ** len(frac) if frac else 0.0)
    d = np.diff(out)
    wraps = np.concatenate([[0.0], np.cumsum(np.where(d < -1800.0, 3600.0, 0.0))])
    out = out + wraps
    return out - out[0], 10.0 ** -digits


def short_clock_refusal(file: str, cell: str, row: int, column: str, marks: np.ndarray,
                        resolution_s: float) -> CaptureError:
    """Why a shortened clock is not read as time, and what to give instead."""
    n = marks.size
    step = float(marks[-1] - marks[0]) / (n - 1) if n > 1 else float("nan")
    return CaptureError(file, f"clock time {cell!r} is MM:SS.f, not HH:MM:SS.f: a spreadsheet shortened this "
                        f"column (the hours are lost, and the precision below {resolution_s:g} s: the samples lie "
                        f"closer than the clock can tell). Over {n} rows the clock spans {marks[-1]:.1f} s, "
                        f"{step * 1e3:.4f} ms a row ({1 / step:.4g} Hz) at its {resolution_s:g} s resolution. If the "
                        "recorder sampled evenly, give its rate with --rate HZ: the time base is then rebuilt as "
                        "k / rate and checked against this clock", row=row, column=column)


def rebuild(marks_s: np.ndarray, rate_hz: float, resolution_s: float, *, file: str, lines: np.ndarray,
            column: str, what: str) -> tuple[np.ndarray, dict[str, Any]]:
    """t = k / rate_hz (k = 0 .. n-1), checked against `marks_s` (the file's own time, s from the
    first row, to `resolution_s`): every mark within resolution + SLACK_SAMPLES samples of it.
    Returns the time and the sidecar's account of it."""
    n = marks_s.size
    t = np.arange(n, dtype=np.float64) / rate_hz
    dev = (marks_s - marks_s[0]) - t
    tol = resolution_s + SLACK_SAMPLES / rate_hz
    bad = np.flatnonzero(np.abs(dev) > tol)
    span_step = float(marks_s[-1] - marks_s[0]) / (n - 1) if n > 1 else float("nan")
    if bad.size:
        k = int(bad[0])
        raise CaptureError(file, f"--rate {rate_hz:g}: the rows are not evenly spaced at that rate: the {what} puts "
                           f"this row {marks_s[k] - marks_s[0]:.4f} s after the first, {k} samples at {rate_hz:g} Hz "
                           f"are {t[k]:.4f} s (off by {dev[k]:+.4f} s, more than its {resolution_s:g} s resolution "
                           f"and {SLACK_SAMPLES:g} samples); over the whole file it gives {span_step * 1e3:.5f} ms a "
                           f"row ({1 / span_step:.6g} Hz): a gap, or another rate", row=int(lines[k]), column=column)
    return t, {"rate_hz": rate_hz, "checked_against": what, "resolution_s": resolution_s,
               "tolerance_s": tol, "max_deviation_s": float(np.max(np.abs(dev))) if n else 0.0,
               "span_step_s": span_step}


def decimals_resolution(cells: list[str]) -> float:
    """The resolution of a seconds column: the finest last digit its cells write (10^(e - d) for a
    mantissa of d fraction digits and an exponent e)."""
    finest = 0
    for cell in cells:
        mant, _, exp = cell.strip().partition("e") if "e" in cell else cell.strip().partition("E")
        parts = re.split(r"[.,]", mant)
        d = len(parts[1]) if len(parts) == 2 else 0
        try:
            e = int(exp) if exp else 0
        except ValueError:
            e = 0
        finest = max(finest, d - e)
    return 10.0 ** -finest
