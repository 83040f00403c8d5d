"""Numeric acceptance of a simulated response against the measured one, per time window, in the
manner of IEC 61400-27-2 (issue 13).

NERC MOD-026 asks for a validated model but sets no numeric limit. IEC 61400-27-2:2020
("Electrical simulation models - Model validation"), which RTE's compliance checks use, splits a
test into windows — before the event, during it, after it — and judges in each the maximum error
MXE = max |sim - meas|, the mean error ME = |mean(sim - meas)| and the mean absolute error
MAE = mean |sim - meas|, each in per unit, against limits; a short zone after each event is left
out (the transient the standard judges separately). Here, for an AVR pulse or step test:

- windows: before = start .. leading edge, during = leading .. trailing edge, after = trailing
  edge .. end (a step: before and after the edge only);
- exclusion: `exclusion_s` after each edge (default 20 ms) is left out of the window it starts;
- figures in per unit of the step size: the largest deviation of the measured efd from its
  pre-trigger mean (so 0.05 is 5 % of the response the test produced);
- default limits (MXE / ME / MAE): before and after 0.05 / 0.02 / 0.03, during 0.08 / 0.05 /
  0.07; a unit file may set its own under `[acceptance]` (`acceptance_limits`); the report
  (`bench_ctl.report`) shows the table.

A window passes when every figure is at or below its limit; the test passes when every window
with samples does.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from bench_ctl.exitcodes import BadInput

FIGURES = ("MXE", "ME", "MAE")
WINDOWS = ("before", "during", "after")
DEFAULT_LIMITS: dict[str, dict[str, float]] = {
    "before": {"MXE": 0.05, "ME": 0.02, "MAE": 0.03},
    "during": {"MXE": 0.08, "ME": 0.05, "MAE": 0.07},
    "after": {"MXE": 0.05, "ME": 0.02, "MAE": 0.03},
}
DEFAULT_EXCLUSION_S = 0.02
SOURCE = ("Windows and figures after IEC 61400-27-2:2020, Electrical simulation models – Model "
          "validation (MXE, ME, MAE per window, short exclusion zones at the events), as used in "
          "RTE's compliance checks; the default limits are bench-ctl's reading of those checks "
          "(before/after 0.05 / 0.02 / 0.03, during 0.08 / 0.05 / 0.07 per unit) and belong in the "
          "unit file when the grid operator gives others. NERC MOD-026 sets no numeric limit.")


@dataclass(frozen=True)
class WindowResult:
    name: str
    t0: float
    t1: float
    n: int
    figures: dict[str, float]      # per unit of the step size; nan when the window is empty
    limits: dict[str, float]
    passed: dict[str, bool]

    @property
    def ok(self) -> bool | None:
        return None if self.n == 0 else all(self.passed.values())


@dataclass(frozen=True)
class Acceptance:
    step_pu: float
    exclusion_s: float
    windows: tuple[WindowResult, ...]

    @property
    def ok(self) -> bool:
        return all(w.ok is not False for w in self.windows) and any(w.n for w in self.windows)


class AcceptanceError(BadInput):
    """Limits that cannot be used; the message names the key."""


def acceptance_limits(raw: Any, where: str) -> dict[str, Any]:
    """The `[acceptance]` table of a unit file, checked, over the defaults:
    {before|during|after: {MXE, ME, MAE}, exclusion_s}."""
    out: dict[str, Any] = {w: dict(v) for w, v in DEFAULT_LIMITS.items()}
    out["exclusion_s"] = DEFAULT_EXCLUSION_S
    if raw is None:
        return out
    if not isinstance(raw, Mapping):
        raise AcceptanceError(f"{where}: acceptance must be a table, got {raw!r}")
    for key, value in raw.items():
        if key == "exclusion_s":
            out[key] = _positive(value, f"{where}: acceptance.exclusion_s", allow_zero=True)
            continue
        if key not in WINDOWS:
            raise AcceptanceError(f"{where}: acceptance.{key}: unknown; allowed: {', '.join(WINDOWS)}, exclusion_s")
        if not isinstance(value, Mapping):
            raise AcceptanceError(f"{where}: acceptance.{key} must be a table of MXE, ME, MAE")
        for fig, lim in value.items():
            if fig not in FIGURES:
                raise AcceptanceError(f"{where}: acceptance.{key}.{fig}: unknown figure; allowed: {', '.join(FIGURES)}")
            out[key][fig] = _positive(lim, f"{where}: acceptance.{key}.{fig}")
    return out


def _positive(value: Any, where: str, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or value < 0 or (value == 0 and not allow_zero):
        raise AcceptanceError(f"{where} = {value!r}: expected a positive number")
    return float(value)


def evaluate(time: np.ndarray, meas: np.ndarray, sim: np.ndarray, leading_s: float | None,
             trailing_s: float | None, limits: Mapping[str, Any] | None = None) -> Acceptance:
    """The acceptance table of one capture (see the module docstring)."""
    lim = acceptance_limits(limits, "acceptance")
    t = np.asarray(time, float)
    m = np.asarray(meas, float)
    s = np.asarray(sim, float)
    excl = float(lim["exclusion_s"])
    t_start, t_end = float(t[0]), math.inf  # the last window runs to the last sample
    if leading_s is None:
        bounds = [("before", t_start, t_end)]
        pre = np.ones_like(t, bool)
    else:
        bounds = [("before", t_start, leading_s)]
        if trailing_s is None:
            bounds.append(("after", leading_s, t_end))
        else:
            bounds += [("during", leading_s, trailing_s), ("after", trailing_s, t_end)]
        pre = t < leading_s
    base = float(np.mean(m[pre])) if pre.any() else float(m[0])
    step = float(np.max(np.abs(m - base)))
    step = step if step > 0 else 1.0
    out = []
    for name, a, b in bounds:
        start = a + (excl if name != "before" else 0.0)
        tol = 1e-9 * max(1.0, abs(start))  # a boundary on a sample instant, up to rounding
        sel = (t >= start - tol) & (t < b - tol)
        d = (s[sel] - m[sel]) / step
        n = int(sel.sum())
        figs = ({"MXE": float(np.max(np.abs(d))), "ME": float(abs(np.mean(d))), "MAE": float(np.mean(np.abs(d)))}
                if n else {f: math.nan for f in FIGURES})
        lims = {f: float(lim[name][f]) for f in FIGURES}
        out.append(WindowResult(name, start, min(b, float(t[-1])), n, figs, lims,
                                {f: bool(n and figs[f] <= lims[f]) for f in FIGURES}))
    return Acceptance(step, excl, tuple(out))
