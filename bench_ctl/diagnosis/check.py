"""The check: a fitted model judged where it was not fitted, and the scores that rank models.

The parts (`check_parts`): the holdout capture when there is one (the model held, only its own
edge instants fitted), the recorded terminal voltage when there is one and the fit did not use it,
and always the cross-validation windows of the capture - the leading edge, the plateau and the
trailing edge in turn (never the recovery: `diagnose.CV_SEGMENTS`): the model re-fitted with the
window left out of the objective (the simulation running through it) and scored on it, the re-fit
being the Gauss-Newton step from the model's fit over the other samples, one Jacobian serving all
windows. So an effect that acts at the edges (a ceiling, a slew limit, a setpoint ramp, a delay)
is judged on an edge the fit never saw
(docs/decisions/0010-diagnosis-one-objective-and-its-check.md).

Ranking (`score`): BIC on the capture (n ln(mse) + k ln(n), k = added parameters) plus the
predictive deviance on the check, the sum over its parts of n_i ln(mse_i).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from bench_ctl.identification.polish import FD_STEP, polish
from bench_ctl.identification.problem import Problem
from bench_ctl.identification.result import Result
from bench_ctl.identification.space import SearchSpace

from .models import ModelFit, Part, Views, mid

__all__ = ["check_parts", "checked", "check_deviance", "describe_check", "fit_holdout", "bic", "aic", "score"]

#: Levenberg damping of the leave-window-out step, relative to the mean curvature: a parameter
#: that only the left-out window determines (an edge instant, a limit reached only there) stays
#: where the full fit put it instead of taking an arbitrary step
LEAVE_OUT_DAMPING = 1e-6


def fit_holdout(views: Views, values: Mapping[str, float]) -> tuple[Problem, Result]:
    """The holdout with the model held at `values`, its edge instants polished from mid-interval."""
    h = views.holdout_problem(values)
    x0 = SearchSpace(h).vector(mid(h, h.names))
    return h, polish(h, x0, budget=views.holdout_calls)


def check_parts(views: Views, p: Problem, x: np.ndarray) -> tuple[Part, ...]:
    """The model at x judged where it was not fitted (module docstring)."""
    parts: list[Part] = []
    if views.holdout is not None:
        h, res = fit_holdout(views, p.values(x))
        parts.append(Part("holdout", h.n_scored()[0], res.fun / h.scored_s if res.success else math.inf))
    parts += _left_out(views, p, x)
    vt = _vt_part(views, p, x)
    if vt is not None:
        parts.append(vt)
    return tuple(parts)


def _vt_part(views: Views, p: Problem, x: np.ndarray) -> Part | None:
    """The recorded terminal voltage, when the capture has it and the fit did not use it (vt
    weight 0): how well the model predicts it. It separates effects that look alike in efd but
    act apart on the machine, e.g. a dead time in the loop (Vt follows the delayed efd) from a
    recorder skew of the efd channel (Vt follows the real, earlier one)."""
    if views.capture.vt is None or p.w_vt > 0:
        return None
    return Part("vt", float(views.capture.vt.size), p.mse(x, signal="vt")[0])


def _left_out(views: Views, p: Problem, x: np.ndarray) -> list[Part]:
    """Per window: the mean objective on the window of the model re-fitted without it, as the
    Gauss-Newton step from x over the other samples (exact for a model linear in its parameters;
    the full fit is the start, so the step is small). One kernel call of d + 1 candidates."""
    space = SearchSpace(p)
    d = space.d
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
        return [Part(w.label, 0.0, math.inf) for w in views.windows]
    r0 = R[0]
    # per unit of each variable's range (the damping below must weigh the variables alike: per
    # unit of z an edge offset's column, in seconds, would outweigh every other one)
    J = ((R[1:] - r0[None, :]) / (h / span)[:, None]).T    # (rows, d)
    eps = 1e-9 * views.capture.dt
    out = []
    for w in views.windows:
        inw = (t >= w.t0 - eps) & (t <= w.t1 + eps)
        if not inw.any() or inw.all():
            continue
        Jr, rr = J[~inw], r0[~inw]
        A = Jr.T @ Jr
        lam = LEAVE_OUT_DAMPING * max(float(np.trace(A)) / max(d, 1), 1e-300)
        try:
            du = -np.linalg.solve(A + lam * np.eye(d), Jr.T @ rr)
        except np.linalg.LinAlgError:
            du = np.zeros(d)
        pred = r0[inw] + J[inw] @ du
        seconds = float(sec[inw].sum())
        n = float(np.count_nonzero(sec[inw]))
        out.append(Part(w.label, n, float(pred @ pred) / seconds if seconds > 0 else math.inf))
    return out


def check_deviance(ref: ModelFit, m: ModelFit) -> float:
    """How much better m predicts the check than ref: sum over the parts of n_i ln(ref_i / m_i)
    (-inf when m failed on a part, +inf when only ref did)."""
    if not ref.checks or not m.checks:
        return -math.inf
    total = 0.0
    for a in ref.checks:
        b = m.part(a.label)
        if b is None:
            continue
        if not math.isfinite(b.mse):
            return -math.inf
        if not math.isfinite(a.mse):
            return math.inf
        total += a.n * math.log(max(a.mse, 1e-300) / max(b.mse, 1e-300))
    return total


def checked(views: Views, m: ModelFit) -> ModelFit:
    """`m` with its check computed (once)."""
    if m.checks is not None:
        return m
    p = views.problem(m.effects, m.fixed, extra=m.extra)
    params = m.params
    x = np.array([params[n] for n in p.names])
    return replace(m, checks=check_parts(views, p, x))


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


def describe_check(views: Views) -> dict[str, Any]:
    """The JSON `check`: what each model was judged on."""
    return {
        "kind": ("holdout + windows" if views.holdout is not None else "windows") if views.windows else "holdout",
        "windows": [{"label": w.label, "t0": w.t0, "t1": w.t1} for w in views.windows],
        "how": "each window in turn left out of the fit (the simulation runs through it; the re-fit is the "
               "Gauss-Newton step from the model's fit over the other samples) and scored on it; the holdout "
               "scored with the model held, its edge instants fitted; a recorded Vt the fit did not use "
               "scored as predicted",
        "holdout": (views.holdout.source or "holdout") if views.holdout is not None else None,
        "vt": bool(views.capture.vt is not None and float(views.unit.weights.get("vt", 0.0)) == 0.0),
    }
