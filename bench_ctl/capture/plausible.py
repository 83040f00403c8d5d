"""Is this a record of a setpoint test at all? Checks a capture must pass before it is fitted,
diagnosed or reported (issue 15 item 4): each names what is wrong and where.

- the sample step lies between 10 us and 0.1 s (a step of 1 "s" is a time column in ms);
- efd, usetp and vt are physical: |efd| <= 100 pu, 0 < usetp, vt <= 5 pu (1e308 is a broken cell);
- the setpoint changes (a step or pulse test), and efd responds to the change: after it, efd
  leaves its pre-trigger level by more than 5 standard deviations of the pre-trigger noise and
  1 mpu (a flat efd is a dead channel or the wrong one).
"""
from __future__ import annotations

import numpy as np

from bench_ctl.capture.capture import Capture
from bench_ctl.capture.errors import CaptureError

MIN_STEP_S = 1.0e-5
MAX_STEP_S = 0.1
EFD_MAX_PU = 100.0
SIGNAL_MAX_PU = 5.0
RESPONSE_SIGMAS = 5.0
RESPONSE_MIN_PU = 1.0e-3

__all__ = ["check_plausible", "implausible"]


def _first_bad(values: np.ndarray, ok: np.ndarray) -> int | None:
    bad = np.flatnonzero(~ok)
    return int(bad[0]) if bad.size else None


def implausible(capture: Capture) -> CaptureError | None:
    """The first reason `capture` is not a plausible setpoint-test record (None: plausible).
    Rows are the 1-based lines of the capture CSV (header = line 1)."""
    file = capture.source or "<capture in memory>"
    dt = float(capture.dt)
    if not MIN_STEP_S <= dt <= MAX_STEP_S:
        hint = " (is the time column in ms?)" if dt > MAX_STEP_S else ""
        return CaptureError(file, f"sample step {dt:.6g} s is outside {MIN_STEP_S:g}..{MAX_STEP_S:g} s for "
                            f"a recorder of a setpoint test{hint}", column="time")
    checks = [("efd", capture.efd, lambda x: np.abs(x) <= EFD_MAX_PU, f"|efd| <= {EFD_MAX_PU:g} pu"),
              ("usetp", capture.usetp, lambda x: (x > 0) & (x <= SIGNAL_MAX_PU), f"0 < usetp <= {SIGNAL_MAX_PU:g} pu")]
    if capture.vt is not None:
        checks.append(("vt", capture.vt, lambda x: (x > 0) & (x <= SIGNAL_MAX_PU), f"0 < vt <= {SIGNAL_MAX_PU:g} pu"))
    for name, x, rule, text in checks:
        k = _first_bad(x, rule(np.asarray(x)))
        if k is not None:
            return CaptureError(file, f"{float(x[k])!r} is not a physical value ({text})", row=k + 2, column=name)
    u = np.asarray(capture.usetp)
    moved = np.flatnonzero(np.abs(u - u[0]) > 1e-9)
    if not moved.size:
        return CaptureError(file, "usetp never changes: not a step or pulse test", column="usetp")
    k0 = int(moved[0])
    efd = np.asarray(capture.efd)
    pre = efd[: max(1, k0 - 1)]
    level, noise = float(np.mean(pre)), float(np.std(pre))
    dev = float(np.max(np.abs(efd[k0:] - level)))
    if dev <= max(RESPONSE_SIGMAS * noise, RESPONSE_MIN_PU):
        return CaptureError(file, f"efd does not respond to the setpoint change at t = "
                            f"{capture.time[k0] - capture.time[0]:.6g} s: it stays within {dev:.3g} pu of its "
                            f"pre-trigger level (noise {noise:.3g} pu); a dead or wrong channel?", column="efd")
    return None


def check_plausible(capture: Capture) -> None:
    """Raise the CaptureError of `implausible`, if any."""
    err = implausible(capture)
    if err is not None:
        raise err
