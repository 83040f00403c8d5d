"""Re-simulating the identified model on its captures and computing what the report shows.

`analyse` takes a result (`IdentificationResult`, schema bench-ctl/result/1), verifies its captures, simulates the
model from `params` + `fixed` with `bench_ctl.engine.simulate.simulate` (it does not call the
identification code, so the report is an independent check of the figures it prints), computes
the error figures, re-evaluates the constraints and sets up the pass / fail checks.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench_ctl.diagnosis.diagnosis_file import Diagnosis
from bench_ctl.engine.simulate import operating_point, simulate, simulate_on_line
from bench_ctl.identification.result_file import IdentificationResult
from bench_ctl.identification.timing import fitted_edge_plan
from bench_ctl.report import checks as chk
from bench_ctl.report.inputs import (
    LoadedCapture,
    ReportError,
    check_result,
    load_captures,
    model_values,
    same_file,
)
from bench_ctl.report.metrics import (
    DEFAULT_EDGE_WINDOW_S,
    ErrorFigures,
    edge_times,
    error_figures,
    setpoint_edges,
    trapezoid_sq,
    window_slice,
)
from bench_ctl.signals.acceptance import Acceptance, AcceptanceError, acceptance_limits, evaluate
from bench_ctl.signals.edges import EdgeSearch
from bench_ctl.timestamps import utc_now_text
from bench_ctl.units.switched import grid_as_recorded
from bench_ctl.units.unit import outside_bounds

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CaptureAnalysis:
    loaded: LoadedCapture
    efd_sim: np.ndarray
    vt_sim: np.ndarray
    fail_step: int
    edges: EdgeSearch       # the setpoint's edges (`metrics.setpoint_edges`)
    figures: ErrorFigures
    suffix: str  # "" for a single capture, else "_<1-based index>"
    fit_mse: float        # MSE over the fit window (= figures.mse without a window)
    fit_objective: float  # objective over the fit window (unweighted by the capture weight)
    acceptance: Acceptance  # IEC 61400-27-2 windows (bench_ctl.signals.acceptance)
    online: dict[str, np.ndarray] | None = None   # an on-line record's simulated p, q, vs, ifd

    @property
    def residual(self) -> np.ndarray:
        return self.loaded.capture.efd - self.efd_sim

    @property
    def label(self) -> str:
        return f"capture {self.loaded.index + 1} ({self.loaded.path.name})"


@dataclass(frozen=True)
class ReportData:
    result: IdentificationResult
    diagnosis: Diagnosis | None
    values: dict[str, float]
    captures: tuple[CaptureAnalysis, ...]
    mse: float                       # mean over captures of the fit-window MSE (re-simulated)
    objective: float                 # sum over captures of weight * fit-window objective
    fit_window: tuple[float, float] | None  # s from each record's start, as identification used
    constraints: list[dict[str, Any]]
    checks: list[chk.Check]
    verdict: str
    noise_floor: float | None
    noise_source: str
    window_s: float
    noise_ratio_limit: float
    report_command: str
    generated_utc: str


def _num(x: Any, default: float) -> float:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else default


def analyse(result: IdentificationResult, *, diagnosis: Diagnosis | None = None,
            base_dir: Path | None = None, where: str = "result",
            window_s: float = DEFAULT_EDGE_WINDOW_S,
            noise_ratio_limit: float = chk.DEFAULT_NOISE_RATIO_LIMIT,
            report_command: str = "", confine: Sequence[Path] | None = None) -> ReportData:
    """Verify the captures of `result`, re-simulate, compute every figure and the checks.

    `where` names the result in error messages (its file name); `base_dir` is where relative
    capture paths are looked for when they do not exist relative to the current directory;
    `confine`: the folders capture paths must stay inside (`inputs.load_captures`).
    Raises `ReportError` (see `inputs`) for input that cannot be reported on.
    """
    check_result(result, where)
    view = result.kernel_view()   # the result's values in the kernel's names
    values = model_values(view["params"], view["fixed"], where)
    loaded = load_captures(result, where, base_dir, confine)
    unit = result.unit
    w_efd, w_vt = _num(unit.weights.get("efd"), 1.0), _num(unit.weights.get("vt"), 0.0)
    window = _fit_window(result.fit_window, where)
    try:
        limits = acceptance_limits(unit.acceptance.to_json() if unit.acceptance else None, f"{where}: unit")
    except AcceptanceError as exc:
        raise ReportError(str(exc)) from None
    grid = unit.grid or {}
    analyses = [_analyse_capture(lc, values, window, where, window_s=window_s, w_efd=w_efd,
                                 w_vt=w_vt, single=len(loaded) == 1, limits=limits, grid=grid) for lc in loaded]
    failures = [f"{a.loaded.path.name}: the model blew up at t = "
                f"{a.loaded.capture.time[a.fail_step]:.3f} s" for a in analyses if a.fail_step >= 0]
    mse = float(np.mean([a.fit_mse for a in analyses]))
    objective = float(sum(a.loaded.entry.weight * a.fit_objective for a in analyses))
    constraints = chk.recheck_constraints([c.to_json() for c in result.constraints], values)
    unit_cons = unit.constraints
    if not constraints and unit_cons:
        failures.append(f"the unit has constraints ({', '.join(map(str, unit_cons))}) but the result "
                        "reports none: they cannot be checked")
    other = _diagnosis_of_another(diagnosis, loaded)
    noise_floor, noise_source = _noise_floor(None if other else diagnosis, analyses)
    ident = result.identifiability
    if result.failed is True:
        failures.insert(0, f"identification reported a failed fit: {result.message or ''}")
    checks = chk.summary_checks(
        sim_failures=failures, mse_recomputed=mse, mse_reported=result.mse,
        constraints=constraints, noise_floor=noise_floor, noise_source=noise_source,
        noise_ratio_limit=noise_ratio_limit, determined=ident.determined if ident else None,
        at_bounds=chk.params_at_bounds(result.params, result.bounds),
        outside_bounds=outside_bounds(result.params, result.bounds),
        n_captures=len(analyses))
    checks.append(_acceptance_check(analyses))
    if other:
        checks.append(chk.Check("diagnosis of this record", "warn", other))
    return ReportData(result=result, diagnosis=diagnosis, values=values,
                      captures=tuple(analyses), mse=mse, objective=objective, fit_window=window,
                      constraints=constraints, checks=checks, verdict=chk.overall(checks),
                      noise_floor=noise_floor, noise_source=noise_source, window_s=window_s,
                      noise_ratio_limit=noise_ratio_limit, report_command=report_command,
                      generated_utc=utc_now_text())


def _analyse_capture(lc: LoadedCapture, values: dict[str, float],
                     window: tuple[float, float] | None, where: str, *, window_s: float,
                     w_efd: float, w_vt: float, single: bool,
                     limits: Mapping[str, Any] | None = None, grid: Mapping[str, float] | None = None
                     ) -> CaptureAnalysis:
    cap = lc.capture
    # the setpoint edges at the instants the fit found (none recorded: the zero-order hold)
    try:
        spec, offsets = fitted_edge_plan(lc.entry.edges, cap.n)
    except (KeyError, TypeError, ValueError) as exc:
        raise ReportError(f"{where}: captures[{lc.index}].edges: unreadable edge entry ({exc})") from None
    sim = simulate_record({**values, **offsets}, cap, grid or {}, spec, where)
    efd, vt, fail = sim["efd"], sim["vt"], sim["fail_step"]
    edges = setpoint_edges(cap.time, cap.usetp)
    figs = error_figures(cap.time, cap.efd, efd, edges, window_s=window_s, w_efd=w_efd,
                         vt_meas=cap.vt, vt_sim=vt, w_vt=w_vt)
    sl = window_slice(cap.time, window)
    if sl.stop - sl.start < 2:
        raise ReportError(f"{where}: fit_window {list(window or ())} holds fewer than 2 samples "
                          f"of {lc.path}")
    if window is None:
        fit_mse, fit_obj = figs.mse, figs.objective
    else:
        r = cap.efd[sl] - efd[sl]
        fit_mse = float(np.mean(r * r))
        fit_obj = w_efd * trapezoid_sq(r, cap.dt)
        if w_vt and cap.vt is not None:
            fit_obj += w_vt * trapezoid_sq(cap.vt[sl] - vt[sl], cap.dt)
    suffix = "" if single else f"_{lc.index + 1}"
    acc = evaluate(cap.time, cap.efd, efd, *edge_times(edges), limits)
    online = {k: sim[k] for k in ("p", "q", "vs", "ifd")} if "p" in sim else None
    return CaptureAnalysis(lc, efd, vt, fail, edges, figs, suffix, fit_mse, fit_obj, acc, online)


def _acceptance_check(analyses: list[CaptureAnalysis]) -> chk.Check:
    """One line for the summary: every window of every capture within its limits."""
    bad = [f"{a.loaded.path.name} {w.name}: " + ", ".join(
               f"{f} {w.figures[f]:.3g} > {w.limits[f]:g}" for f in w.figures if not w.passed[f])
           for a in analyses for w in a.acceptance.windows if w.ok is False]
    if not any(w.n for a in analyses for w in a.acceptance.windows):
        return chk.Check("numeric acceptance (IEC 61400-27-2)", "n/a", "no samples in any window")
    if bad:
        return chk.Check("numeric acceptance (IEC 61400-27-2)", "fail", "; ".join(bad))
    n = sum(1 for a in analyses for w in a.acceptance.windows if w.n)
    return chk.Check("numeric acceptance (IEC 61400-27-2)", "pass",
                     f"MXE, ME, MAE within the limits in all {n} windows; see Numeric acceptance")


def _fit_window(value: Any, where: str) -> tuple[float, float] | None:
    if value is None:
        return None
    vals = [_num(v, math.nan) for v in value] if isinstance(value, list) else []
    if len(vals) != 2 or any(math.isnan(v) for v in vals) or not vals[0] < vals[1]:
        raise ReportError(f"{where}: fit_window must be null or [t0, t1] in s with t0 < t1, "
                          f"got {value!r}")
    return vals[0], vals[1]


def _diagnosis_of_another(diagnosis: Diagnosis | None, loaded: list[LoadedCapture]) -> str:
    """'' when there is no diagnosis or it was made on a capture of the result (by SHA-256), else
    what the reader must be told: its noise floor and effects describe another record."""
    if diagnosis is None:
        return ""
    cap = diagnosis.capture
    if any(same_file(cap, lc) for lc in loaded):
        return ""
    sha = cap.sha256 or "?"
    return (f"the diagnosis was made on {cap.path or '?'} (SHA-256 {sha[:16]}...), not on a capture "
            "of this result: its verdict and effects describe another record, and its noise floor is "
            "not used here")


def _noise_floor(diagnosis: Diagnosis | None,
                 analyses: list[CaptureAnalysis]) -> tuple[float | None, str]:
    if diagnosis is not None:
        nf = diagnosis.noise_floor
        if nf is not None and nf > 0:
            return float(nf), "from the diagnosis"
    own = [a.figures.noise_floor for a in analyses]
    if own and all(v is not None for v in own):
        return float(np.mean(own)), "variance of the measured efd before the trigger"
    return None, "not available"


def simulate_record(values: Mapping[str, float], cap: Any, grid: Mapping[str, float], spec: Any,
                    where: str) -> dict[str, Any]:
    """efd, vt and fail_step of the fitted values on a capture: at no load, or on the grid when
    the capture has P and Q (from its own operating point and the result's [grid], the stabiliser
    as the record was taken: `grid_as_recorded`; then p, q, vs and ifd too)."""
    p, q = cap.channel("p"), cap.channel("q")
    if p is None or q is None or cap.vt is None:
        efd, vt, fail = simulate(values, cap.usetp, cap.dt, edges=spec)
        return {"efd": efd, "vt": vt, "fail_step": fail}
    try:
        point = operating_point(cap.usetp, p, q, cap.vt, float(cap.dt))
        return simulate_on_line(values, grid_as_recorded(grid, cap), point, cap.usetp, cap.dt, edges=spec)
    except (KeyError, ValueError) as exc:
        raise ReportError(f"{where}: an on-line capture (p and q) re-simulated on the grid: {exc}") from None
