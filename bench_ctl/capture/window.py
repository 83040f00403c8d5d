"""The test's window out of a long export (`bench-ctl import --window START:END`, issue 49
item 4).

Real exports hold minutes of operation around the test (a slow reference change, a Q change
before the step, a second test after it). `START:END` says which part is the test: seconds from
the export's first sample (`120:150`, `120.5:`), or clock times of the export's own clock column
(`12:53:58.5:12:54:30`, HH:MM:SS[.f], the day of the first sample; not with a clock a spreadsheet
shortened). An open end is the export's end. The window is cut before anything else looks at the
record (the edges, the efd base, the steadiness of the pre-step part, a resampling); the capture
keeps the export's time axis (its first sample at START), and the sidecar's `import.window` says
what was cut.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from bench_ctl.capture.errors import CaptureError, SpecError
from bench_ctl.capture.vendor_csv import RawRecord

#: the fewest samples a window may keep
MIN_SAMPLES = 20
_CLOCK = r"\d{1,2}:\d{2}:\d{2}(?:[.,]\d{1,9})?"
_SECONDS = r"[+]?(?:\d+\.?\d*|\.\d+)"
_BOUND = rf"(?:{_CLOCK}|{_SECONDS})"
_SYNTAX = re.compile(rf"\s*({_BOUND})?\s*:\s*({_BOUND})?\s*")


@dataclass(frozen=True)
class Bound:
    kind: str          # "s" (seconds from the first sample) or "clock" (time of day, s)
    value: float
    text: str


@dataclass(frozen=True)
class Window:
    """START:END as given (`text`); a missing bound is the export's start / end."""

    text: str
    start: Bound | None
    end: Bound | None


def _bound(text: str | None) -> Bound | None:
    if text is None:
        return None
    if re.fullmatch(_CLOCK, text):
        h, m, s = text.replace(",", ".").split(":")
        if int(h) > 23 or int(m) > 59 or float(s) >= 60.0:
            raise SpecError(f"{text!r} is not a clock time (HH:MM:SS[.f])")
        return Bound("clock", int(h) * 3600 + int(m) * 60 + float(s), text)
    return Bound("s", float(text), text)


def parse_window(text: str) -> Window:
    """`START:END`: seconds from the export's first sample or HH:MM:SS[.f] clock times, either
    bound may be left out (`120:` is from 120 s to the end). ValueError when malformed."""
    m = _SYNTAX.fullmatch(text)
    if m is None or (m.group(1) is None and m.group(2) is None):
        raise SpecError(f"{text!r}: expected START:END, seconds from the export's first sample (120:150) or "
                         "clock times (12:53:58.5:12:54:30); either may be left out")
    w = Window(text.strip(), _bound(m.group(1)), _bound(m.group(2)))
    if w.start is not None and w.end is not None and w.start.kind == w.end.kind and w.end.value <= w.start.value:
        raise SpecError(f"{text!r}: the window ends before it starts")
    return w


def _seconds(b: Bound, rec: RawRecord, file: str) -> float:
    """A bound as seconds from the export's first sample."""
    if b.kind == "s":
        return b.value
    if rec.clock0_s is None:
        raise CaptureError(file, f"--window {b.text}: a clock time needs the export's own clock column (the time "
                           "here is a seconds column, or a clock a spreadsheet shortened): give seconds from "
                           "the first sample instead")
    return b.value - rec.clock0_s


def cut(rec: RawRecord, window: Window, file: str) -> tuple[RawRecord, dict[str, Any]]:
    """The part of `rec` inside `window`, and the sidecar's `import.window`. Refused (naming the
    export's span) when a bound lies outside the export or too few samples remain."""
    rel = rec.time - rec.time[0]
    span = float(rel[-1])
    a = 0.0 if window.start is None else _seconds(window.start, rec, file)
    b = span if window.end is None else _seconds(window.end, rec, file)
    where = f"--window {window.text}"
    for what, v, bound in (("start", a, window.start), ("end", b, window.end)):
        if bound is not None and not 0.0 <= v <= span:
            raise CaptureError(file, f"{where}: its {what} ({bound.text}) lies {v:.3f} s from the export's first "
                               f"sample, outside the export (0 .. {span:.3f} s)")
    if b <= a:
        raise CaptureError(file, f"{where}: it ends ({b:.3f} s) before it starts ({a:.3f} s)")
    keep = np.flatnonzero((rel >= a) & (rel <= b))
    if keep.size < MIN_SAMPLES:
        raise CaptureError(file, f"{where}: {keep.size} samples between {a:.3f} and {b:.3f} s, fewer than "
                           f"{MIN_SAMPLES}")
    k0, k1 = int(keep[0]), int(keep[-1]) + 1
    info = dict(rec.time_info)
    info["origin"] = f"{info.get('origin', '')}; the window starts at t = {float(rec.time[k0]):.6g} s".lstrip("; ")
    out = replace(rec, time=rec.time[k0:k1], columns={k: v[k0:k1] for k, v in rec.columns.items()},
                  rows=rec.rows[k0:k1], time_info=info,
                  clock0_s=None if rec.clock0_s is None else rec.clock0_s + float(rel[k0]))
    block = {"given": window.text, "start_s": float(rel[k0]), "end_s": float(rel[k1 - 1]),
             "first_row": int(rec.rows[k0]), "last_row": int(rec.rows[k1 - 1]), "samples": k1 - k0,
             "export_samples": int(rec.time.size), "export_span_s": span,
             "axis": "the export's: seconds from its first sample"}
    return out, block
