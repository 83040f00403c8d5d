"""MVMO's evaluation within its budget and its local search: the candidates in normalised
variables, their constraint violations and ranking merit (`BatchProblem`), one run's evaluation
count, best point and history (`BudgetRun`), and the SLSQP polish of a particle's best
(`local_search`). `mvmo.minimize` drives them (the algorithm: `mvmo`'s docstring).
"""
from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy import optimize as _sopt

from .constraints import LinearConstraint

logger = logging.getLogger(__name__)

__all__ = ["StopSearch", "BatchProblem", "better", "BudgetRun", "local_search", "ConstraintLike"]

ConstraintLike = LinearConstraint | Callable[[np.ndarray], float]


# --------------------------------------------------------------------------- problem & evaluation

class StopSearch(Exception):
    """Raised inside a local search when its budget (or the run's) is used up."""


class BatchProblem:
    """Bounds, constraints and the (vectorised or not) objective in normalised space."""

    def __init__(self, fun: Callable, bounds: Sequence[Sequence[float]],
                 constraints: Sequence[ConstraintLike], vectorized: bool):
        b = np.asarray(bounds, dtype=float)
        if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] == 0:
            raise ValueError(f"bounds must be a sequence of (lo, hi) pairs, got shape {b.shape}")
        for i, (lo, hi) in enumerate(b):
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                raise ValueError(f"bounds[{i}] = ({lo}, {hi}): need finite lo < hi")
        self.lo, self.hi = b[:, 0], b[:, 1]
        self.span, self.d = self.hi - self.lo, b.shape[0]
        self.fun, self.vectorized = fun, vectorized
        self.tol, self.penalty = 0.0, 0.0  # set from the options by minimize()
        self.linear: list[LinearConstraint] = []
        self.callables: list[Callable[[np.ndarray], float]] = []
        for k, c in enumerate(constraints):
            if isinstance(c, LinearConstraint):
                if c.coef.size != self.d:
                    raise ValueError(f"constraint {c.expr!r} has {c.coef.size} coefficients "
                                     f"for {self.d} variables")
                self.linear.append(c)
            elif callable(c):
                self.callables.append(c)
            else:
                raise ValueError(f"constraints[{k}] is neither a LinearConstraint nor "
                                 f"callable: {c!r}")
        self.A = np.array([c.coef for c in self.linear]).reshape(len(self.linear), self.d)
        self.b = np.array([c.rhs for c in self.linear])
        self.n_nonfinite = 0

    def to_x(self, Z: np.ndarray) -> np.ndarray:
        return self.lo + Z * self.span

    def violations(self, X: np.ndarray) -> np.ndarray:
        """Per-candidate, per-constraint violations, shape (n, n_constraints)."""
        cols = [np.maximum(0.0, X @ self.A.T - self.b)] if self.linear else []
        for g in self.callables:
            v = np.array([float(g(x.copy())) for x in X])
            if np.any(np.isnan(v)) or np.any(v < 0):
                raise ValueError(f"constraint callable {g!r} returned {v} (need violation >= 0)")
            cols.append(v[:, None])
        return np.hstack(cols) if cols else np.zeros((X.shape[0], 0))

    def evaluate(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Objective, violation sum and max violation of normalised candidates ``Z``."""
        X = self.to_x(Z)
        n = X.shape[0]
        if self.vectorized:
            f = np.asarray(self.fun(X.copy()), dtype=float)
            if f.shape != (n,):
                raise ValueError(f"vectorized fun returned shape {f.shape} for {n} candidates; "
                                 f"expected ({n},)")
        else:
            f = np.empty(n)
            for j in range(n):
                fj = np.asarray(self.fun(X[j].copy()), dtype=float)
                if fj.size != 1:
                    raise ValueError(f"fun returned {fj.size} values for one candidate; "
                                     "use vectorized=True for batched objectives")
                f[j] = fj.reshape(())
        bad = ~np.isfinite(f)
        if bad.any():
            self.n_nonfinite += int(bad.sum())
            logger.debug("%d non-finite objective values treated as +inf", int(bad.sum()))
            f = np.where(bad, np.inf, f)
        viol = self.violations(X)
        return f, viol.sum(axis=1), (viol.max(axis=1) if viol.shape[1] else np.zeros(n))

    def merit(self, f: np.ndarray, vsum: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ranking key: (infeasible flag, objective or penalised objective)."""
        infeasible = vsum > self.tol
        return infeasible, np.where(infeasible, f + self.penalty * vsum, f)


def better(inf_a: bool, m_a: float, inf_b: bool, m_b: float) -> bool:
    return (not inf_a and inf_b) or (inf_a == inf_b and m_a < m_b)


class BudgetRun:
    """Counts evaluations, keeps the best (feasible first), history and callback."""

    def __init__(self, prob: BatchProblem, max_evals: int, callback: Callable | None):
        self.prob, self.max_evals, self.callback = prob, max_evals, callback
        self.nfev = 0
        self.history: list[tuple[int, float]] = []
        # best so far: (infeasible, merit, f, max violation, z)
        self.best: tuple[bool, float, float, float, np.ndarray] | None = None
        self.stopped = False

    @property
    def remaining(self) -> int:
        return self.max_evals - self.nfev

    def batch(self, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if Z.shape[0] > self.remaining:
            raise RuntimeError("internal error: batch would exceed max_evals")
        f, vsum, vmax = self.prob.evaluate(Z)
        self.nfev += Z.shape[0]
        inf, mer = self.prob.merit(f, vsum)
        j = int(np.lexsort((mer, inf))[0])
        if self.best is None or better(bool(inf[j]), mer[j], self.best[0], self.best[1]):
            self.best = (bool(inf[j]), float(mer[j]), float(f[j]), float(vmax[j]), Z[j].copy())
        self.history.append((self.nfev, self.best[2]))
        if self.callback is not None and self.callback(self.nfev, self.prob.to_x(self.best[4]),
                                                       self.best[2]):
            self.stopped = True
        return f, inf, mer


# --------------------------------------------------------------------------- local search

def local_search(run: BudgetRun, z0: np.ndarray, budget: int, fd_step: float, central: bool = False
                  ) -> tuple[tuple[np.ndarray, float, bool, float] | None, bool]:
    """SLSQP from ``z0`` (normalised) with bounds, linear and callable constraints.

    The gradient is a forward difference evaluated as one batch of ``d`` points (the value at
    ``z`` is cached from the line search), or with ``central`` a central one of ``2 d`` points
    (one-sided where a bound is within the step): exact for a quadratic, which is what lets the
    search follow an ill-conditioned valley to its floor. The objective is divided by ``|f(z0)|`` so that the
    tolerances are relative. Returns the best point evaluated (z, f, infeasible, merit) or
    None, and whether the search ended by itself (False when the budget cut it short, so that
    it is worth continuing later).
    """
    prob, d = run.prob, run.prob.d
    best: list[Any] = []  # [z, f, inf, merit]
    spent = [0]
    scale: list[float] = []
    cache: dict[bytes, float] = {}
    cut_short = [False]

    def evaluate(Z: np.ndarray) -> np.ndarray:
        if spent[0] + Z.shape[0] > budget or run.remaining < Z.shape[0] or run.stopped:
            cut_short[0] = True
            raise StopSearch
        f, inf, mer = run.batch(Z)
        spent[0] += Z.shape[0]
        for j in range(Z.shape[0]):
            if not best or better(bool(inf[j]), mer[j], best[2], best[3]):
                best[:] = [Z[j].copy(), float(f[j]), bool(inf[j]), float(mer[j])]
        if not np.all(np.isfinite(f)):
            raise StopSearch
        return f

    def value(z: np.ndarray) -> float:
        z = np.clip(z, 0.0, 1.0)
        key = z.tobytes()
        if key not in cache:
            if len(cache) > 16:
                cache.clear()
            cache[key] = float(evaluate(z[None, :])[0])
        if not scale:
            scale.append(abs(cache[key]) if cache[key] != 0.0 else 1.0)
        return cache[key] / scale[0]

    def gradient(z: np.ndarray) -> np.ndarray:
        z = np.clip(z, 0.0, 1.0)
        f = value(z)
        if central:
            up, down = np.minimum(z + fd_step, 1.0), np.maximum(z - fd_step, 0.0)
            fz = evaluate(np.vstack([np.where(np.eye(d, dtype=bool), up, z),
                                     np.where(np.eye(d, dtype=bool), down, z)])) / scale[0]
            return (fz[:d] - fz[d:]) / (up - down)
        steps = np.where(z + fd_step <= 1.0, fd_step, -fd_step)
        fz = evaluate(z + np.diag(steps)) / scale[0]
        return (fz - f) / steps

    cons: list[dict[str, Any]] = []
    if prob.linear:
        Az, bz = prob.A * prob.span, prob.b - prob.A @ prob.lo
        cons.append({"type": "ineq", "fun": lambda z: bz - Az @ z, "jac": lambda z: -Az})
    for g in prob.callables:
        cons.append({"type": "ineq", "fun": lambda z, g=g: -float(g(prob.to_x(z)))})
    message = "budget used"
    try:
        res = _sopt.minimize(value, z0, jac=gradient, method="SLSQP", bounds=[(0.0, 1.0)] * d,
                             constraints=cons, options={"maxiter": budget, "ftol": 1e-12})
        message = str(res.message)
    except StopSearch:
        if not cut_short[0]:
            message = "non-finite objective value"
    logger.debug("local search: %d evaluations, best %s (%s)", spent[0],
                 best[1] if best else None, message)
    return ((best[0], best[1], best[2], best[3]) if best else None), not cut_short[0]


