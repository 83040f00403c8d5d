"""The one least-squares polish of every fit, and the engine the gradient peers share.

`polish(problem, x0, budget=...)` moves every fitted parameter from x0 by trust-region
reflective least squares (scipy `least_squares`, TRF) on the problem's residuals, whose squared
sum is `Problem.objective`: in the search space's coordinates (`SearchSpace`), inside the bounds,
with one more residual row carrying the constraints' violation and one the penalty of a
candidate that failed to simulate (`Problem.penalty`), so a step across a constraint or into an
unstable region is refused like any step that does not lower the objective. The forward-difference
Jacobian is one kernel call of d candidates (with d + 1 <= SPECULATE, made with its trial point in
one call). It takes at most budget / (d + 1) steps (a step: a Jacobian and a trial point), and
every simulation counts toward `budget`, which is never exceeded; the result is the best
feasible point evaluated (x0 itself when nothing better is found).
docs/decisions/0015-one-fitting-stack.md.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy import optimize as sopt

from .problem import Problem
from .result import Result
from .space import FEASIBLE_TOL, SearchSpace

logger = logging.getLogger(__name__)

__all__ = ["polish", "evaluate", "Tracker", "least_squares", "FD_STEP", "VIOLATION_WEIGHT", "SPECULATE"]

Progress = Callable[[int, float], Any]

#: forward-difference step of the polish, as a share of each variable's range in the search space
FD_STEP = 1e-5
#: weight of the constraints' violation row, against residuals scaled to a mean square (pu)
VIOLATION_WEIGHT = 10.0
#: convergence tolerances of the polish (relative change of the cost / of x, scaled gradient)
TOL = 1e-8
#: with at most this many candidates in a point and its difference steps together (d + 1), a trial
#: point is simulated with its steps in one kernel call: one call of up to 8 candidates costs
#: about what one of a single candidate does (`engine.layout.LANES`), and most trial points are accepted
#: and need their Jacobian next (docs/benchmarks.md, "Diagnosis constants")
SPECULATE = 8


class Budget(Exception):
    """Raised inside scipy's callbacks when the evaluation budget is used up."""


class Tracker:
    """Counts evaluations against a budget, keeps the best feasible point and the history."""

    def __init__(self, max_evals: int, progress: Progress | None = None):
        self.max_evals, self.progress = max_evals, progress
        self.nfev = 0
        self.best_f = math.inf
        self.best_x: np.ndarray | None = None
        self.history: list[tuple[int, float]] = []

    @property
    def remaining(self) -> int:
        return self.max_evals - self.nfev

    def record(self, X: np.ndarray, f: np.ndarray, feasible: np.ndarray | None = None) -> None:
        self.nfev += X.shape[0]
        g = f if feasible is None else np.where(feasible, f, math.inf)
        j = int(np.argmin(g))
        if g[j] < self.best_f:
            self.best_f, self.best_x = float(g[j]), X[j].copy()
        self.history.append((self.nfev, self.best_f))
        if self.progress is not None:
            self.progress(self.nfev, self.best_f)


def least_squares(resid: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], z0: np.ndarray, lb: np.ndarray,
                  ub: np.ndarray, tr: Tracker, steps: Callable[[np.ndarray], np.ndarray], *,
                  tr_solver: str = "exact", tol: float = 1e-10, max_steps: int | None = None
                  ) -> tuple[str, np.ndarray | None]:
    """TRF least squares with batched forward-difference Jacobians, within the tracker's budget.

    `resid(Z)` evaluates a population at once (and records it in the tracker) -> (R, failed);
    `steps(z)` gives the signed difference step of each variable at z; `max_steps` bounds scipy's
    own count of function evaluations (default: only the budget stops it). A difference that reaches
    a failed simulation says nothing of the derivative: its column is zero for that step (the
    penalty would otherwise make it huge, and x_scale="jac" would freeze the variable for good).
    Returns (scipy's message, the last Jacobian computed (None: none))."""
    cache: dict[bytes, np.ndarray] = {}
    differences: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    last_jac: list[np.ndarray | None] = [None]
    together = z0.size + 1 <= SPECULATE

    def evaluate(Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if Z.shape[0] > tr.remaining:
            raise Budget
        return resid(Z)

    def fun(z: np.ndarray) -> np.ndarray:
        key = z.tobytes()
        if key not in cache:
            cache.clear()
            differences.clear()
            if together and z.size + 1 <= tr.remaining:
                # the point and its difference steps in one kernel call (`SPECULATE`)
                h = steps(z)
                R, failed = evaluate(np.vstack([z[None, :], z[None, :] + np.diag(h)]))
                cache[key] = R[0]
                differences[key] = (R[1:], failed[1:], h)
            else:
                cache[key] = evaluate(z[None])[0][0]
        return cache[key]

    def jac(z: np.ndarray) -> np.ndarray:
        r0 = fun(z)
        key = z.tobytes()
        if key in differences:
            R, failed, h = differences[key]
        else:
            h = steps(z)
            R, failed = evaluate(z[None, :] + np.diag(h))
        J = (R - r0[None, :]).T / h[None, :]
        J[:, failed] = 0.0
        last_jac[0] = J
        return J

    try:
        res = sopt.least_squares(fun, z0, jac=jac, bounds=(lb, ub), method="trf", x_scale="jac",
                                 max_nfev=max_steps or 10 * tr.max_evals, ftol=tol, xtol=tol, gtol=tol,
                                 tr_solver=tr_solver)
        return str(res.message), last_jac[0]
    except Budget:
        return "evaluation budget used up", last_jac[0]


def evaluate(problem: Problem, x: Sequence[float], space: SearchSpace | None = None) -> Result:
    """x as it is: one simulation, its objective."""
    space = space or SearchSpace(problem)
    x = np.asarray(x, float).reshape(-1)
    f = float(problem.objective(x[None])[0])
    ok = math.isfinite(f) and f < problem.penalty_base
    return Result(x=x, fun=f, nfev=1, success=ok, message="evaluated", names=problem.names,
                  violated=tuple(problem.violated(x)))


def polish(problem: Problem, x0: Sequence[float], *, budget: int, space: SearchSpace | None = None,
           progress: Progress | None = None, nfev0: int = 0, shown: float = math.inf,
           noise_variance: float | None = None) -> Result:
    """The polish (module docstring) from x0 within `budget` simulations (fewer than d + 2: x0 is
    only evaluated). progress(nfev0 + n, best) is called as it goes, never above `shown` (the
    best objective before it). With `noise_variance` (of the mean objective, pu^2), the result
    carries each parameter's standard deviation from the Jacobian at x (Gauss-Newton)."""
    if budget < 1:
        raise ValueError(f"polish budget {budget!r}: need at least one simulation")
    space = space or SearchSpace(problem)
    x0 = space.clip(np.asarray(x0, float).reshape(-1))
    d = problem.d
    if budget < d + 2:
        return evaluate(problem, x0, space)

    def shifted(n: int, best: float) -> None:
        if progress is not None:
            progress(nfev0 + n, min(best, shown))

    tr = Tracker(int(budget), shifted)
    scale = 1.0 / math.sqrt(max(problem.scored_s, 1e-300))
    span = space.zhi - space.zlo

    def resid(Z: np.ndarray) -> np.ndarray:
        X = space.to_x(Z)
        R, f = problem.residuals_and_objective(X)
        failed = f >= problem.penalty_base
        viol = space.violation(X)
        tr.record(X, f, (viol <= FEASIBLE_TOL) & ~failed)
        extra = np.sqrt(np.where(failed, f, 0.0))
        return np.hstack([R * scale, (extra * scale)[:, None], (VIOLATION_WEIGHT * viol)[:, None]]), failed

    def steps(z: np.ndarray) -> np.ndarray:
        h = FD_STEP * span
        return np.where(z + h <= space.zhi, h, -h)

    msg, J = least_squares(resid, space.to_z(x0), space.zlo, space.zhi, tr, steps, tr_solver="exact", tol=TOL,
                           max_steps=max(2, budget // (d + 1)))
    history = tuple((nfev0 + n, min(v, shown)) for n, v in tr.history)
    if tr.best_x is None:
        return Result(x=x0, fun=math.inf, nfev=tr.nfev, success=False, message=f"{msg}; no feasible point",
                      names=problem.names, history=history, violated=tuple(problem.violated(x0)))
    x = space.clip(tr.best_x)
    std = None
    if J is not None and noise_variance is not None:
        std = _std(problem, space, x, J[:-2], noise_variance)
    return Result(x=x, fun=tr.best_f, nfev=tr.nfev, success=True, message=msg, names=problem.names, std=std,
                  jac=None if J is None else J[:-2], history=history, violated=tuple(problem.violated(x)),
                  settings={"solver": "scipy.optimize.least_squares (trf, exact)", "budget": int(budget)})


def _std(problem: Problem, space: SearchSpace, x: np.ndarray, J: np.ndarray, noise_variance: float
         ) -> dict[str, float]:
    """Gauss-Newton standard deviations (original units) from J of the residuals scaled to a mean
    square (each residual's noise variance is then about sigma^2 / n_scored): cov(z) = sigma^2
    (J^T J)^-1 / n_scored; a parameter the record does not determine gets a large or NaN value."""
    n_eff = float(sum(problem.n_scored()))
    if n_eff <= 0:
        return {n: math.nan for n in problem.names}
    try:
        cov = np.linalg.pinv(J.T @ J) * noise_variance / n_eff
    except np.linalg.LinAlgError:  # pragma: no cover - defensive
        return {n: math.nan for n in problem.names}
    sd_z = np.where(np.any(J != 0.0, axis=0), np.sqrt(np.maximum(np.diag(cov), 0.0)), np.nan)
    dxdz = np.where(space.log, x, 1.0)
    return {n: float(v) for n, v in zip(problem.names, sd_z * np.abs(dxdz))}
