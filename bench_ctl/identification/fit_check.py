"""The check: a fitted model judged where it was not fitted, and the scores that rank models.

The parts (`check_parts`): the holdout capture when there is one (the model held, only its own
edge instants fitted), the recorded terminal voltage when there is one and the fit did not use it,
and always the cross-validation windows of the capture - the leading edge, the plateau and the
trailing edge in turn (never the recovery: `CV_SEGMENTS`): the model re-fitted with the
window left out of the objective (the simulation running through it) and scored on it, the re-fit
being the Gauss-Newton step from the model's fit over the other samples (one Jacobian serving all
windows), scored on its linear prediction where the step, simulated, does what the linear model
promised, else damped until it does (`_left_out`): on a real record, with limits reached and edges
between samples, the undamped prediction can be off by orders of magnitude. So an effect that
acts at the edges (a ceiling, a slew limit, a setpoint ramp, a delay) is judged on an edge the
fit never saw (docs/decisions/0010-diagnosis-one-objective-and-its-check.md,
0020-the-check-samples-every-regime.md).

Beside the windows, the interleaved blocks (`check_and_blocks`): the record cut into blocks of
`BLOCK_S`, every other block left out of the re-fit in turn (the same Gauss-Newton step) and scored.
Every regime of the record - the pre-step level, each edge, the plateau, the recovery - is in both
the fitted and the judged half, so an effect whose evidence lives in one regime (saturation seen
only on the plateau, a ceiling reached on one edge) is judged on samples of that regime it was not
fitted to, where a left-out window would ask it to extrapolate. It is not part of the score; the
verdict uses it only to accept such an effect (`significance.significance`).

Ranking (`score`): BIC on the capture (n ln(mse) + k ln(n), k = added parameters) plus the
predictive deviance on the check, the sum over its parts of n_i ln(mse_i).

What every model of a capture is fitted and checked on (`prepare`): its setpoint edges, efd's noise
floor, the fit's floor and the `Setup` with the check's windows; the diagnosis and the structure
selection both start from it.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from bench_ctl.capture import Capture
from bench_ctl.signals.edges import EdgeSearch
from bench_ctl.units.unit import VS_WEIGHT, Unit

from .check_records import BlocksCheck, CheckDescription, CheckWindow, HoldoutCheck, Span, Validation
from .construction import scored_vs
from .localize import DiagnosisError, NoiseFloor, noise_floor, pulse_edges, segments
from .model_fits import Budget, ModelFit, Part, Setup, Views, Window, coarse_factor, mid
from .polish import FD_STEP, polish
from .problem import Problem
from .result import Result
from .space import SearchSpace

__all__ = ["check_parts", "checked", "check_deviance", "block_deviance", "describe_check", "fit_holdout", "bic",
           "aic", "score", "BLOCK_S", "BLOCK_FOLDS"]

#: Levenberg damping of the leave-window-out step, relative to the mean curvature: a parameter
#: that only the left-out window determines (an edge instant, a limit reached only there) stays
#: where the full fit put it instead of taking an arbitrary step
LEAVE_OUT_DAMPING = 1e-6
#: the interleaved blocks: their length (s) and how many halves (folds) the record is dealt into
BLOCK_S = 0.05
BLOCK_FOLDS = 2
#: the leave-out re-fit's damping, as multiples of LEAVE_OUT_DAMPING, tried in turn (`_left_out`)
DAMPING_STEPS = (1.0, 1e2, 1e4, 1e6)
#: a step's linear prediction is trusted when, simulated, the step gains on the other samples at
#: least this share of what the linear model promised (a trust-region ratio)
TRUST = 0.5


def fit_holdout(views: Views, values: Mapping[str, float]) -> tuple[Problem, Result]:
    """The holdout with the model held at `values`, its edge instants polished from mid-interval."""
    h = views.holdout_problem(values)
    x0 = SearchSpace(h).vector(mid(h, h.names))
    return h, polish(h, x0, budget=views.holdout_calls)


def check_parts(views: Views, p: Problem, x: np.ndarray, *, linear: bool = False) -> tuple[Part, ...]:
    """The model at x judged where it was not fitted (module docstring); `linear`: every left-out
    part scored on the linear prediction of its re-fit, trusted or not (`_left_out`)."""
    return check_and_blocks(views, p, x, linear=linear)[0]


def check_and_blocks(views: Views, p: Problem, x: np.ndarray, *, linear: bool = False
                     ) -> tuple[tuple[Part, ...], tuple[Part, ...]]:
    """The check's parts and the interleaved blocks' parts of the model at x (module docstring)."""
    parts: list[Part] = []
    if views.holdout is not None:
        h, res = fit_holdout(views, p.values(x))
        parts.append(Part("holdout", h.n_scored()[0], res.fun / h.scored_s if res.success else math.inf))
    windows, blocks = _left_out(views, p, x, linear=linear)
    parts += windows
    vt = _vt_part(views, p, x)
    if vt is not None:
        parts.append(vt)
    return tuple(parts), tuple(blocks)


def _vt_part(views: Views, p: Problem, x: np.ndarray) -> Part | None:
    """The recorded terminal voltage, when the capture has it and the fit did not use it (vt
    weight 0): how well the model predicts it. It separates effects that look alike in efd but
    act apart on the machine, e.g. a dead time in the loop (Vt follows the delayed efd) from a
    recorder skew of the efd channel (Vt follows the real, earlier one)."""
    if views.capture.vt is None or p.w_vt > 0:
        return None
    return Part("vt", float(views.capture.vt.size), p.mse(x, signal="vt")[0])


def _left_out(views: Views, p: Problem, x: np.ndarray, *, linear: bool = False) -> tuple[list[Part], list[Part]]:
    """Per window, then per half of the interleaved blocks: the mean objective on the left-out
    samples of the model re-fitted without them, as the linear prediction of the Gauss-Newton step
    from x over the other samples (exact for a model linear in its parameters; the full fit is the
    start, so the step is small). The step is trusted when, simulated, it gains on the other
    samples at least `TRUST` of what the linear model promised; if not (a real record with limits
    reached and edges between samples, where the undamped prediction can be off by orders of
    magnitude) it is damped further (`DAMPING_STEPS`, Levenberg-Marquardt's trust region), and with
    no damping trusted the part is scored on x itself. `linear`: the undamped prediction always
    (the structure selection's check: docs/decisions/0020). A kernel call for the Jacobian, one for
    the undamped steps and, where one broke its promise, one for the damped steps."""
    space = SearchSpace(p)
    z = space.to_z(np.asarray(x, float))
    span = space.zhi - space.zlo
    h = FD_STEP * span
    h = np.where(z + h <= space.zhi, h, -h)
    Z = np.vstack([z[None, :], z[None, :] + np.diag(h)])
    R, failed = p.residuals(space.to_x(Z))
    cap, t, sec = p.residual_rows()
    rows = cap == 0
    R, t, sec = R[:, rows], t[rows], sec[rows]
    if failed[0]:
        return [Part(w.label, 0.0, math.inf) for w in views.windows], []
    r0 = R[0]
    # per unit of each variable's range (the damping below must weigh the variables alike: per
    # unit of z an edge offset's column, in seconds, would outweigh every other one)
    J = ((R[1:] - r0[None, :]) / (h / span)[:, None]).T    # (rows, d)
    eps = 1e-9 * views.capture.dt
    parts: list[tuple[str, np.ndarray]] = []
    for w in views.windows:
        inw = (t >= w.t0 - eps) & (t <= w.t1 + eps)
        if inw.any() and not inw.all():
            parts.append((w.label, inw))
    n_windows = len(parts)
    fold = np.floor((t - t[0]) / BLOCK_S + 1e-9).astype(np.int64) % BLOCK_FOLDS
    parts += [(f"blocks_{f + 1}", fold == f) for f in range(BLOCK_FOLDS)
              if (fold == f).any() and not (fold == f).all()]
    if not parts:
        return [], []
    m = np.asarray((1.0,) if linear else DAMPING_STEPS, float)
    du = np.array([_steps(J, r0, out, m) for _, out in parts])     # (parts, dampings, d)
    before = [float(r0[~out] @ r0[~out]) for _, out in parts]
    pred = [[r0 + J @ du[i, j] for j in range(m.size)] for i in range(len(parts))]
    promised = [[before[i] - float(pred[i][j][~out] @ pred[i][j][~out]) for j in range(m.size)]
                for i, (_, out) in enumerate(parts)]
    sims: dict[tuple[int, int], np.ndarray | None] = {}   # a simulated step's residuals (None: failed)

    def simulate(steps: list[tuple[int, int]]) -> None:
        if steps:
            Zc = np.clip(z[None, :] + np.array([du[i, j] for i, j in steps]) * span[None, :], space.zlo, space.zhi)
            Rs, fs = p.residuals(space.to_x(Zc))
            sims.update({ij: (None if f else r) for ij, r, f in zip(steps, Rs[:, rows], fs)})

    def kept(i: int, j: int) -> bool:
        """The step keeps its promise (or promises nothing); needs its simulation."""
        if linear or promised[i][j] <= 1e-12 * max(before[i], 1e-300):
            return True
        r = sims.get((i, j))
        out = parts[i][1]
        return r is not None and before[i] - float(r[~out] @ r[~out]) >= TRUST * promised[i][j]

    # the undamped steps first; the damped ones only for the parts whose undamped step broke its promise
    if not linear and m.size:
        simulate([(i, 0) for i in range(len(parts))])
        simulate([(i, j) for i in range(len(parts)) if not kept(i, 0) for j in range(1, m.size)])
    out_parts = []
    for i, (label, out) in enumerate(parts):
        best = r0    # no damping trusted: the re-fit does not leave the fit (infinite damping)
        for j in range(m.size):
            if kept(i, j):
                best = pred[i][j]
                break
        seconds = float(sec[out].sum())
        n = float(np.count_nonzero(sec[out]))
        out_parts.append(Part(label, n, float(best[out] @ best[out]) / seconds if seconds > 0 else math.inf))
    return out_parts[:n_windows], out_parts[n_windows:]


def _steps(J: np.ndarray, r0: np.ndarray, out: np.ndarray, dampings: np.ndarray) -> np.ndarray:
    """The Levenberg-damped Gauss-Newton steps over the rows not in `out` (per unit of each
    variable's range), one for each multiple of `LEAVE_OUT_DAMPING` in `dampings`."""
    d = J.shape[1]
    Jr, rr = J[~out], r0[~out]
    A, g = Jr.T @ Jr, Jr.T @ rr
    curvature = max(float(np.trace(A)) / max(d, 1), 1e-300)
    steps = np.zeros((len(dampings), d))
    for k, damping in enumerate(dampings):
        try:
            steps[k] = -np.linalg.solve(A + damping * LEAVE_OUT_DAMPING * curvature * np.eye(d), g)
        except np.linalg.LinAlgError:
            pass    # no step: the re-fit stays at the fit
    return steps


def check_deviance(ref: ModelFit, m: ModelFit) -> float:
    """How much better m predicts the check than ref: sum over the parts of n_i ln(ref_i / m_i)
    (-inf when m failed on a part, +inf when only ref did)."""
    if not ref.checks or not m.checks:
        return -math.inf
    return _deviance(ref.checks, m.checks)


def _deviance(ref: tuple[Part, ...], m: tuple[Part, ...]) -> float:
    total = 0.0
    for a in ref:
        b = next((p for p in m if p.label == a.label), None)
        if b is None:
            continue
        if not math.isfinite(b.mse):
            return -math.inf
        if not math.isfinite(a.mse):
            return math.inf
        total += a.n * math.log(max(a.mse, 1e-300) / max(b.mse, 1e-300))
    return total


def block_deviance(ref: ModelFit, m: ModelFit) -> float:
    """How much better m predicts the interleaved blocks than ref (as `check_deviance`)."""
    if not ref.blocks or not m.blocks:
        return -math.inf
    return _deviance(ref.blocks, m.blocks)


def checked(views: Views, m: ModelFit) -> ModelFit:
    """`m` with its check and interleaved blocks computed (once)."""
    if m.checks is not None:
        return m
    p = views.problem(m.effects, m.fixed, extra=m.extra)
    params = m.params
    x = np.array([params[n] for n in p.names])
    parts, blocks = check_and_blocks(views, p, x)
    return replace(m, checks=parts, blocks=blocks)


def bic(n: int, mse: float, k: int) -> float:
    return n * math.log(mse) + k * math.log(n)


def aic(n: int, mse: float, k: int) -> float:
    return n * math.log(mse) + 2 * k


def score(m: ModelFit, n: int) -> float:
    """Lower is better: BIC on the capture plus the predictive deviance on the check."""
    s = bic(n, m.mse, m.k)
    for part in m.checks or ():
        s += part.n * math.log(part.mse) if 0 < part.mse < math.inf else (math.inf if part.mse > 0 else -math.inf)
    return s


def describe_check(views: Views, holdout: HoldoutCheck | None) -> CheckDescription:
    """The diagnosis' `check`: what each model was judged on (`holdout`: the holdout capture as the
    check uses it)."""
    return CheckDescription(
        kind=("holdout + windows" if views.holdout is not None else "windows") if views.windows else "holdout",
        windows=tuple(CheckWindow(w.label, w.t0, w.t1) for w in views.windows),
        how="each window in turn left out of the fit (the simulation runs through it; the re-fit is the "
            "Gauss-Newton step from the model's fit over the other samples, its linear prediction, damped "
            "until the simulated step does what the prediction promised) and scored on it; the holdout "
            "scored with the model held, its edge instants fitted; a recorded Vt the fit did not use "
            "scored as predicted; beside them, not in the score, the interleaved blocks: each half left out "
            "of the re-fit in turn and scored",
        holdout=holdout,
        vt=bool(views.capture.vt is not None and float(views.unit.weights.get("vt", 0.0)) == 0.0),
        blocks=BlocksCheck(BLOCK_S, BLOCK_FOLDS),
    )


# ---------------------------------------------------------------------- what every model is checked on

#: cross-validation windows: the segments of the record (localize.segments) each left out in turn.
#: Not the recovery: it is most of the record and holds what determines the slow time constants,
#: so the rest cannot predict it for any model; it stays in every fit (docs/decisions/0010).
CV_SEGMENTS = ("leading_edge", "plateau", "trailing_edge")


def _windows(capture: Capture, edges: EdgeSearch) -> tuple[Window, ...]:
    dt = capture.dt
    return tuple(Window(s.name, s.k0 * dt, (s.k1 - 1) * dt) for s in segments(capture.n, dt, edges)
                 if s.name in CV_SEGMENTS and s.k1 - s.k0 >= 5)


def _fit_floor(capture: Capture, unit: Unit, edges: EdgeSearch, efd_floor: NoiseFloor, source: str) -> NoiseFloor:
    """The noise floor of the mean objective every fit is ranked by: efd's at its weight, plus
    Vt's at its weight when the unit weights a recorded Vt (the default: efd's alone), plus on line
    Q's at its weight (default 1: `Problem`'s) and the stabiliser output's where a fit scores it
    (`scored_vs`; weight `vs`, default `VS_WEIGHT`)."""
    weighted = [(float(unit.weights.get("efd", 1.0)), efd_floor)]
    w_vt = float(unit.weights.get("vt", 0.0))
    if capture.vt is not None and w_vt > 0.0:
        weighted.append((w_vt, noise_floor(capture.vt, capture.dt, edges, source)))
    w_q = float(unit.weights.get("q", 1.0))
    if capture.on_line and w_q > 0.0:
        weighted.append((w_q, noise_floor(capture.channel("q"), capture.dt, edges, source)))
    w_vs, vs = float(unit.weights.get("vs", VS_WEIGHT)), scored_vs(capture)
    if vs is not None and w_vs > 0.0:
        weighted.append((w_vs, noise_floor(vs, capture.dt, edges, source)))
    return replace(efd_floor, variance=sum(w * f.variance for w, f in weighted),
                   rel_se=max(f.rel_se for _, f in weighted))


def _setup(capture: Capture, holdout: Capture | None, unit: Unit, edges: EdgeSearch, floor: NoiseFloor,
           budget: Budget) -> Setup:
    windows = _windows(capture, edges)
    if not windows:
        raise DiagnosisError(f"{capture.source or 'capture'}: too short after the setpoint change for a check")
    q = coarse_factor(unit, capture.dt, budget.coarse_dt)
    k_on, k_off = edges.lead.index, edges.trail_index
    if k_off is not None:  # both setpoint edges on the coarse grid, or the trailing one moves
        q = math.gcd(q, k_off - k_on) or 1
    n_coarse = capture.n if k_off is None else min(capture.n, k_off + int(round(budget.coarse_tail_s / capture.dt)))
    views = Views(unit, capture, holdout, q, n_coarse, edges.lead.index, windows)
    check_floor, check_se = floor.variance, floor.rel_se
    hold = None
    if holdout is not None:
        h_src = holdout.source or "holdout"
        h_edges = pulse_edges(holdout.usetp, h_src)
        h_floor = _fit_floor(holdout, unit, h_edges, noise_floor(holdout.efd, holdout.dt, h_edges, h_src), h_src)
        n_w = sum(int(round((w.t1 - w.t0) / capture.dt)) + 1 for w in windows)
        check_floor = (h_floor.variance * holdout.n + floor.variance * n_w) / (holdout.n + n_w)
        check_se = max(h_floor.rel_se, floor.rel_se)
        hold = HoldoutCheck(holdout.source or None, 0.0, float(holdout.time[-1] - holdout.time[0]), h_floor.variance)
    floor_tol = floor.variance * (1.0 + budget.floor_sigmas * math.sqrt(floor.rel_se ** 2 + 2.0 / capture.n))
    validation = Validation("holdout + windows" if holdout is not None else "windows",
                            Span(0.0, (capture.n - 1) * capture.dt), describe_check(views, hold))
    return Setup(views, capture.n, floor, check_floor, check_se, floor_tol, validation)


def prepare(capture: Capture, unit: Unit, *, holdout: Capture | None = None, budget: Budget | None = None
            ) -> tuple[EdgeSearch, NoiseFloor, Setup]:
    """What every model of `capture` is fitted and checked on: the setpoint edges, efd's noise
    floor (pre-trigger) and the `Setup` (views, the fit's floor, the check's windows)."""
    budget = budget if budget is not None else Budget()
    src = capture.source or "capture"
    if holdout is not None and holdout.on_line != capture.on_line:
        kind = {True: "an on-line", False: "a no-load"}
        raise DiagnosisError(f"{holdout.source or 'the holdout'} is {kind[holdout.on_line]} record and {src} "
                             f"{kind[capture.on_line]} one: a holdout is a record of the same test")
    edges = pulse_edges(capture.usetp, src)
    efd_floor = noise_floor(capture.efd, capture.dt, edges, src)
    floor = _fit_floor(capture, unit, edges, efd_floor, src)
    return edges, efd_floor, _setup(capture, holdout, unit, edges, floor, budget)
