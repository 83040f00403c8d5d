"""The one search space of every fit: identification's MVMO and polish, and the diagnosis'.

z = ln x for a parameter whose lower bound is positive (gains, time constants, rates, levels:
their valleys are far straighter in log coordinates), z = x for the others (edge offsets, limits
that may be negative, parameters whose neutral value is 0). docs/decisions/0015-one-fitting-stack.md.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from .constraints import LinearConstraint
from .problem import Problem

__all__ = ["SearchSpace", "FEASIBLE_TOL"]

#: a candidate whose constraint violations sum to at most this (original units) is feasible
FEASIBLE_TOL = 1e-9


class SearchSpace:
    """The variables a fit moves: `to_x` / `to_z`, the box `bounds` in z, the constraints as MVMO
    takes them (`constraints`) and as the polish penalises them (`violation`, original units).

    A linear constraint between two log variables with a zero bound (`TA2 <= TA1`, `S12 >=
    1.44*S10`) or on one log variable stays linear in z; any other becomes a callable violation
    evaluated in the original units. space="linear" searches x itself (an MVMO option).
    """

    def __init__(self, problem: Problem, space: str = "log"):
        if space not in ("log", "linear"):
            raise ValueError(f"search space {space!r}: choose 'log' or 'linear'")
        self.names = problem.names
        self.base = problem.base
        self.lo, self.hi = problem.lower, problem.upper
        lo, hi = self.lo, self.hi
        self.log = (lo > 0) if space == "log" else np.zeros(problem.d, bool)
        self.bounds = [(math.log(a), math.log(b)) if g else (a, b) for a, b, g in zip(lo, hi, self.log)]
        self.zlo = np.array([b[0] for b in self.bounds], dtype=float).reshape(problem.d)
        self.zhi = np.array([b[1] for b in self.bounds], dtype=float).reshape(problem.d)
        self.A = np.array([c.coef for c in problem.constraints]).reshape(len(problem.constraints), problem.d)
        self.b = np.array([c.rhs for c in problem.constraints])
        self.constraints: list[Any] = []
        for c in problem.constraints:
            nz = np.flatnonzero(c.coef)
            coef = c.coef
            if len(nz) == 2 and c.rhs == 0.0 and all(self.log[nz]) and coef[nz[0]] * coef[nz[1]] < 0:
                i, j = (nz[0], nz[1]) if coef[nz[0]] > 0 else (nz[1], nz[0])
                new = np.zeros(problem.d)
                new[i], new[j] = 1.0, -1.0  # a x_i <= b x_j  <=>  ln x_i - ln x_j <= ln(b/a)
                self.constraints.append(LinearConstraint(c.expr, new, math.log(-coef[j] / coef[i]), c.names))
            elif len(nz) == 1 and self.log[nz[0]] and coef[nz[0]] > 0 and c.rhs > 0:
                new = np.zeros(problem.d)
                new[nz[0]] = 1.0
                self.constraints.append(LinearConstraint(c.expr, new, math.log(c.rhs / coef[nz[0]]), c.names))
            else:
                self.constraints.append(lambda z, c=c: c.violation(self.to_x(z)))

    @property
    def d(self) -> int:
        return len(self.names)

    @property
    def kind(self) -> dict[str, str]:
        """name -> "log" or "linear" (for a result's settings)."""
        return {n: ("log" if g else "linear") for n, g in zip(self.names, self.log)}

    def to_x(self, Z: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.exp(np.where(self.log, Z, 0.0)), Z)

    def to_z(self, X: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.log(np.where(self.log, X, 1.0)), X)

    def clip(self, X: np.ndarray) -> np.ndarray:
        """X inside the bounds."""
        return np.clip(X, self.lo, self.hi)

    def violation(self, X: np.ndarray) -> np.ndarray:
        """Sum of the constraint violations (original units) of each candidate row of X."""
        X = np.atleast_2d(np.asarray(X, float))
        if not self.A.size:
            return np.zeros(X.shape[0])
        return np.maximum(0.0, X @ self.A.T - self.b).sum(axis=1)

    def feasible(self, X: np.ndarray) -> np.ndarray:
        return self.violation(X) <= FEASIBLE_TOL

    def vector(self, values: Mapping[str, float]) -> np.ndarray:
        """x from a name -> value map (a name it lacks: the problem's base value)."""
        return np.array([float(values.get(n, self.base[n])) for n in self.names])
