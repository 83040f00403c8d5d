"""Is this a record of a setpoint test at all? Checks a capture must pass before it is imported,
fitted, diagnosed or reported (issue 15 item 4, issue 24 items 11-13): each names what is wrong
and where.

- the time unit, decided from the record as a whole, not from the sample step alone: the step
  lies between 10 us and 0.1 s; the record lasts at most `MAX_RECORD_S` and its setpoint edges lie
  at most `MAX_EDGE_GAP_S` apart (a 10 s record at 20 kHz with a time axis in ms has a fine step
  of 0.05 "s" but lasts 10 000 "s", its 1 s pulse 1000 "s"), and efd reaches half of its response
  to the first setpoint edge within `MAX_HALF_RESPONSE_S` (a step has no second edge to be too far
  from the first: a 20 kHz step record with its time in ms lasts 290 "s" and passes the rest, but
  its efd takes 11 "s" to reach half of its response); the sidecar's rate must match the step (`read_capture`) and its
  test description the setpoint edges (below);
- efd, usetp and vt are physical: |efd| <= 100 pu, 0 < usetp, vt <= 5 pu (1e308 is a broken cell);
- the setpoint changes (a step or pulse test), and efd responds to the change: after it, efd
  leaves its pre-trigger level by more than 5 standard deviations of the pre-trigger noise and
  1 mpu (a flat efd is a dead channel or the wrong one);
- the sidecar's test description, when there is one, is a test and the one recorded: `kind` pulse
  or step; `amplitude_pu` finite, at most `MAX_AMPLITUDE_PU` and the setpoint's recorded jump
  (sign, and size within `AMPLITUDE_REL_TOL`); `width_s` > 0 and the recorded pulse's width;
  `start_s` inside the record and at the recorded first edge (counted from the record's start or
  in its own time). The report copies this description: a wrong one is refused, not reported.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from bench_ctl.capture.capture import Capture
from bench_ctl.capture.errors import CaptureError
from bench_ctl.signals.edges import SETPOINT, find_edges

MIN_STEP_S = 1.0e-5
MAX_STEP_S = 0.1
#: the longest record of a setpoint test: a pulse or step and the generator's settling (T'd0 up to
#: ~15 s, a few times over) with a pre-trigger take a minute or two; ten minutes is far beyond
MAX_RECORD_S = 600.0
#: the longest time between two setpoint edges (a pulse's width, a step held before the return)
MAX_EDGE_GAP_S = 60.0
#: after a setpoint edge efd reaches half of its largest departure (up to the next edge, within
#: MAX_EDGE_GAP_S) within this long: a static exciter within tens of ms (the Mostar unit's records:
#: 10-20 ms; the library's static structures at their typical values 3-33 ms), a rotating exciter
#: within a second (IEEEX1 typical 0.14 s, with TE = 3 s and KA = 5 at the ends of its bounds
#: 0.76 s); a time axis in ms makes it 1000 times slower (the reference unit at 20 kHz: 11 "s",
#: ESST5B's 3 ms: 3 "s")
MAX_HALF_RESPONSE_S = 1.5
#: ... judged only when that departure is this many times the pre-edge noise (a clear response)
HALF_RESPONSE_SIGMAS = 20.0
EFD_MAX_PU = 100.0
SIGNAL_MAX_PU = 5.0
RESPONSE_SIGMAS = 5.0
RESPONSE_MIN_PU = 1.0e-3
#: a setpoint test moves the setpoint by a few per cent; half of the rated voltage is no test
MAX_AMPLITUDE_PU = 0.5
#: the recorded jump and pulse width may differ this much (relative) from the described ones
AMPLITUDE_REL_TOL = 0.2
WIDTH_REL_TOL = 0.2
#: ... plus this much for the recorder's quantisation of usetp (pu) and its sampling (samples)
AMPLITUDE_ABS_TOL_PU = 2.0e-3
EDGE_TOL_SAMPLES = 5
#: the described start may lie this far from the recorded first edge (s), or 5 samples
START_TOL_S = 0.5

__all__ = ["check_plausible", "implausible", "setpoint_edges"]

_MS_HINT = " (is the time column in ms?)"


def _first_bad(values: np.ndarray, ok: np.ndarray) -> int | None:
    bad = np.flatnonzero(~ok)
    return int(bad[0]) if bad.size else None


def setpoint_edges(usetp: np.ndarray) -> np.ndarray:
    """Indices of the first sample showing each setpoint edge (the shared finder,
    `bench_ctl.signals.edges.find_edges`: a change spread over adjacent samples is one edge)."""
    u = np.asarray(usetp, float)
    found = find_edges(np.arange(u.size, dtype=float), u, kind=SETPOINT)
    return np.array([e.index for e in found.edges], dtype=np.int64)


def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def _test_meta(capture: Capture, file: str, where: str | None) -> CaptureError | None:
    """The sidecar's test description against the record (see the module docstring); `where`
    names the description (default: the capture's sidecar)."""
    test = capture.meta.get("test") if isinstance(capture.meta, Mapping) else None
    if test is None:
        return None
    side = where or (f"{file.rsplit('.', 1)[0]}.json" if file.lower().endswith(".csv") else f"{file} (sidecar)")

    def bad(key: str, why: str) -> CaptureError:
        return CaptureError(side, why, column=f"test.{key}", column_kind="key")

    if not isinstance(test, Mapping):
        return bad("", f"the test description must be an object, got {type(test).__name__}")
    kind = test.get("kind")
    if kind is not None and kind not in ("pulse", "step"):
        return bad("kind", f"{kind!r} is not a test bench-ctl knows (pulse, step)")
    t, u = np.asarray(capture.time, float), np.asarray(capture.usetp, float)
    dt = float(capture.dt)
    edges = setpoint_edges(u)
    values = {}
    for key in ("amplitude_pu", "width_s", "start_s"):
        if test.get(key) is not None:   # null: not described
            v = _num(test[key])
            if v is None or not math.isfinite(v):
                return bad(key, f"{test[key]!r} is not a finite number")
            values[key] = v
    a = values.get("amplitude_pu")
    if a is not None:
        if a == 0.0 or abs(a) > MAX_AMPLITUDE_PU:
            return bad("amplitude_pu", f"{a:g} pu is not a setpoint test's step (0 < |amplitude| <= "
                       f"{MAX_AMPLITUDE_PU:g} pu)")
        if edges.size:
            k = int(edges[0])
            jump = float(np.median(u[k:min(u.size, k + EDGE_TOL_SAMPLES)])
                         - np.median(u[max(0, k - EDGE_TOL_SAMPLES):k]))
            if abs(jump - a) > AMPLITUDE_REL_TOL * abs(a) + AMPLITUDE_ABS_TOL_PU:
                return bad("amplitude_pu", f"{a:g} pu, but usetp steps by {jump:.4g} pu at t = "
                           f"{t[k] - t[0]:.6g} s: the description is not this record's")
    w = values.get("width_s")
    if w is not None:
        if not w > 0.0:
            return bad("width_s", f"{w:g} s: a pulse's width must be > 0")
        if kind != "step" and edges.size:
            if edges.size < 2:
                return bad("width_s", f"{w:g} s, but usetp does not return within the record (one edge, at "
                           f"t = {t[edges[0]] - t[0]:.6g} s)")
            got = float(t[edges[1]] - t[edges[0]])
            if abs(got - w) > max(WIDTH_REL_TOL * w, EDGE_TOL_SAMPLES * dt):
                hint = _MS_HINT if 500.0 < got / w < 2000.0 else ""
                return bad("width_s", f"{w:g} s, but the usetp pulse lasts {got:.6g} s: the description "
                           f"is not this record's{hint}")
    s = values.get("start_s")
    if s is not None:
        dur = float(t[-1] - t[0])
        inside = (0.0 <= s <= dur) or (float(t[0]) <= s <= float(t[-1]))
        if not inside:
            return bad("start_s", f"{s:g} s lies outside the record (0 .. {dur:.6g} s)")
        if edges.size:
            k = int(edges[0])
            tol = max(START_TOL_S, EDGE_TOL_SAMPLES * dt)
            if min(abs(s - (t[k] - t[0])), abs(s - t[k])) > tol:
                return bad("start_s", f"{s:g} s, but usetp first changes at t = {t[k] - t[0]:.6g} s: the "
                           "description is not this record's")
    return None


def _slow_response(capture: Capture, file: str, edges: np.ndarray) -> CaptureError | None:
    """efd's response to the first setpoint edge, too slow for an exciter (see MAX_HALF_RESPONSE_S)."""
    if not edges.size or edges[0] < 2:
        return None
    t, efd = np.asarray(capture.time, float), np.asarray(capture.efd, float)
    k0 = int(edges[0])
    k1 = int(edges[1]) if edges.size > 1 else efd.size
    k1 = min(k1, int(np.searchsorted(t, t[k0] + MAX_EDGE_GAP_S, side="right")))
    pre = efd[:k0 - 1]
    level, noise = float(np.mean(pre)), float(np.std(pre))
    dev = np.abs(efd[k0:k1] - level)
    if dev.size < 2:
        return None
    peak = float(dev.max())
    if peak <= max(HALF_RESPONSE_SIGMAS * noise, RESPONSE_MIN_PU):
        return None
    half = int(np.flatnonzero(dev >= 0.5 * peak)[0])
    took = float(t[k0 + half] - t[k0])
    if took <= MAX_HALF_RESPONSE_S:
        return None
    return CaptureError(file, f"efd takes {took:.4g} s after the setpoint edge at t = {t[k0] - t[0]:.6g} s to reach "
                        f"half of its response ({peak:.3g} pu): an exciter responds within {MAX_HALF_RESPONSE_S:g} s"
                        f"{_MS_HINT}", column="time")


def implausible(capture: Capture, *, rows: np.ndarray | None = None, row_kind: str = "row",
                file: str | None = None, test_where: str | None = None,
                response: bool = True) -> CaptureError | None:
    """The first reason `capture` is not a plausible setpoint-test record (None: plausible).
    Rows are the 1-based lines of the capture CSV (header = line 1), or `rows[k]` (of kind
    `row_kind`) for sample k when given (an import names the source's rows); `file` the name to
    give (default: the capture's source); `test_where` where the test description came from
    (default: the sidecar beside the capture). `response=False` leaves out whether the record
    holds a test at all (the setpoint moves, efd responds): an import converts any record of the
    recorder, the fits refuse one that is no test."""
    file = file or capture.source or "<capture in memory>"
    dt = float(capture.dt)
    t = np.asarray(capture.time, float)

    def row(k: int) -> int:
        return int(rows[k]) if rows is not None else k + 2

    if not MIN_STEP_S <= dt <= MAX_STEP_S:
        hint = _MS_HINT if dt > MAX_STEP_S else ""
        return CaptureError(file, f"sample step {dt:.6g} s is outside {MIN_STEP_S:g}..{MAX_STEP_S:g} s for "
                            f"a recorder of a setpoint test{hint}", column="time")
    duration = float(t[-1] - t[0])
    if duration > MAX_RECORD_S:
        return CaptureError(file, f"the record lasts {duration:.6g} s, longer than a setpoint test's "
                            f"record ({MAX_RECORD_S:g} s at most){_MS_HINT}", column="time")
    checks = [("efd", capture.efd, lambda x: np.abs(x) <= EFD_MAX_PU, f"|efd| <= {EFD_MAX_PU:g} pu"),
              ("usetp", capture.usetp, lambda x: (x > 0) & (x <= SIGNAL_MAX_PU), f"0 < usetp <= {SIGNAL_MAX_PU:g} pu")]
    if capture.vt is not None:
        checks.append(("vt", capture.vt, lambda x: (x > 0) & (x <= SIGNAL_MAX_PU), f"0 < vt <= {SIGNAL_MAX_PU:g} pu"))
    for name, x, rule, text in checks:
        k = _first_bad(x, rule(np.asarray(x)))
        if k is not None:
            return CaptureError(file, f"{float(x[k])!r} at t = {t[k] - t[0]:.6g} s is not a physical value ({text})",
                                row=row(k), row_kind=row_kind, column=name)
    u = np.asarray(capture.usetp)
    moved = np.flatnonzero(np.abs(u - u[0]) > 1e-9)
    if not moved.size and response:
        return CaptureError(file, "usetp never changes: not a step or pulse test", column="usetp")
    edges = setpoint_edges(u)
    if edges.size > 1:
        gaps = np.diff(t[edges])
        i = int(np.argmax(gaps))
        if gaps[i] > MAX_EDGE_GAP_S:
            return CaptureError(file, f"the setpoint holds {gaps[i]:.6g} s between its edges at t = "
                                f"{t[edges[i]] - t[0]:.6g} s and {t[edges[i + 1]] - t[0]:.6g} s, longer than a "
                                f"setpoint test holds it ({MAX_EDGE_GAP_S:g} s at most){_MS_HINT}",
                                column="time")
    slow = _slow_response(capture, file, edges)
    if slow is not None:
        return slow
    if not response or not moved.size:
        return _test_meta(capture, file, test_where)
    k0 = int(moved[0])
    efd = np.asarray(capture.efd)
    pre = efd[: max(1, k0 - 1)]
    level, noise = float(np.mean(pre)), float(np.std(pre))
    dev = float(np.max(np.abs(efd[k0:] - level)))
    if dev <= max(RESPONSE_SIGMAS * noise, RESPONSE_MIN_PU):
        return CaptureError(file, f"efd does not respond to the setpoint change at t = "
                            f"{capture.time[k0] - capture.time[0]:.6g} s: it stays within {dev:.3g} pu of its "
                            f"pre-trigger level (noise {noise:.3g} pu); a dead or wrong channel?", column="efd")
    return _test_meta(capture, file, test_where)


def check_plausible(capture: Capture) -> None:
    """Raise the CaptureError of `implausible`, if any."""
    err = implausible(capture)
    if err is not None:
        raise err
