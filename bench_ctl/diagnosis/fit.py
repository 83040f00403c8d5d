"""Fitting a model (the unit's identified parameters, any effects, the setpoint edge instants) to
a capture: the diagnosis' optimisers on identification's objective.

The objective is identification's own `Problem` (`bench_ctl.identification.problem`): the same
kernel call, trapezoidal weighting, edge timing (`EDGE1`.. fitted in every fit), signal weights
and the same views of a record - the whole capture, a decimated copy for the searches
(`Problem.decimated`), windows left out for cross-validation (`Problem.excluding`) or scored
alone (`Problem.only`). A fix to the objective reaches identification and diagnosis alike.

What is the diagnosis' own: it needs every fit driven to its local minimum, so that the MSE of
"base model" and "base model + effect" differ by what the effect explains and not by how far an
optimizer happened to get. Tools: `fit` = MVMO (vectorised, one kernel call per generation,
optionally in a box around a start) followed by `polish`, a bounded least-squares run (scipy
`least_squares`, TRF) on the problem's weighted residuals, whose forward-difference Jacobian is
one kernel call of `d` candidates. Small kernel calls run on one thread (`SMALL_CALL`).

Parameters are searched in a normalised space `u` in [0, 1] (`Space`): logarithmic for strictly
positive parameters whose bounds span a decade or more (gains, time constants, rates), linear
otherwise. The problem's constraints are linear in the physical parameters.
"""
from __future__ import annotations

import logging
import math
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Iterator, Mapping, Sequence

import numba
import numpy as np
from scipy.optimize import least_squares

from bench_ctl.identification import mvmo
from bench_ctl.identification.problem import Problem
from bench_ctl.model.unit import Unit

log = logging.getLogger(__name__)

#: MVMO settings of the diagnosis' searches: the defaults (`mvmo.DEFAULT_OPTIONS`), whose local
#: searches from good particles late in the run find the AVR model's narrow basins more reliably
#: than one polish of the final best (docs/benchmarks.md, "MVMO defaults and MVMO_OPTIONS")
MVMO_OPTIONS: Mapping = {}

#: objective of a candidate whose simulation blew up (mse units; real MSEs are << 1)
FAIL_PENALTY = 1.0e3

LAGS = ("TA2", "TA4", "TE", "TR", "Td0pp")


def coarse_factor(unit: Unit, dt: float, target: float) -> int:
    """Decimation factor q for the coarse record: a step near `target` but not above the shortest
    lag the unit can have (RK4 at a step of one time constant is still accurate to ~2 % per step;
    at two it no longer decays right)."""
    shortest = math.inf
    values = unit.values()
    for name in LAGS:
        if name in unit.identify:
            lo = unit.identify[name].min
        else:
            lo = values.get(name, 0.0)
        if lo > 0:
            shortest = min(shortest, lo)
    step = min(target, shortest)
    return max(1, int(math.floor(step / dt + 1e-9)))


@dataclass(frozen=True, eq=False)
class Space:
    """The normalised search space of a problem: its names, bounds, constraints (A x <= b)."""

    names: tuple[str, ...]
    lo: np.ndarray
    hi: np.ndarray
    base: Mapping[str, float]
    log_scale: np.ndarray
    A: np.ndarray
    b: np.ndarray

    @staticmethod
    def of(problem: Problem) -> "Space":
        lo, hi = problem.lower, problem.upper
        log_scale = (lo > 0) & (hi / np.where(lo > 0, lo, 1.0) >= 10.0)
        A = np.array([c.coef for c in problem.constraints]).reshape(len(problem.constraints), problem.d)
        b = np.array([c.rhs for c in problem.constraints])
        return Space(problem.names, lo, hi, problem.base, log_scale, A, b)

    @property
    def d(self) -> int:
        return len(self.names)

    def to_x(self, U: np.ndarray) -> np.ndarray:
        U = np.clip(np.asarray(U, float), 0.0, 1.0)
        lin = self.lo + U * (self.hi - self.lo)
        with np.errstate(divide="ignore"):
            lg = self.lo * np.exp(U * np.log(np.where(self.log_scale, self.hi / self.lo, 1.0)))
        return np.where(self.log_scale, lg, lin)

    def to_u(self, X: np.ndarray) -> np.ndarray:
        X = np.clip(np.asarray(X, float), self.lo, self.hi)
        lin = (X - self.lo) / (self.hi - self.lo)
        with np.errstate(divide="ignore", invalid="ignore"):
            lg = np.log(X / self.lo) / np.log(np.where(self.log_scale, self.hi / self.lo, 2.0))
        return np.where(self.log_scale, lg, lin)

    def violation(self, X: np.ndarray) -> np.ndarray:
        """Sum of constraint violations (physical units) per candidate row."""
        X = np.atleast_2d(X)
        if not self.A.size:
            return np.zeros(X.shape[0])
        return np.maximum(0.0, X @ self.A.T - self.b).sum(axis=1)

    def vector(self, values: Mapping[str, float]) -> np.ndarray:
        """x from a name -> value map (a name it lacks: the problem's base value)."""
        return np.array([float(values.get(n, self.base[n])) for n in self.names])


#: below this many candidate-steps a kernel call runs on one thread: waking the worker threads
#: costs more than it saves for the small batches of the least-squares polish, several times
#: more when the machine is busy (docs/benchmarks.md, "Diagnosis constants")
SMALL_CALL = 300_000


@contextmanager
def _threads_for(n_cand: int, n_steps: int) -> Iterator[None]:
    if n_cand * n_steps >= SMALL_CALL or numba.get_num_threads() == 1:
        yield
        return
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(old)


def _steps(p: Problem) -> int:
    return max(r.i1 for r in p.records)


def mse_of(p: Problem, X: np.ndarray) -> np.ndarray:
    """Per-candidate MSE of efd over the problem's scored samples (its first capture); failed
    candidates get FAIL_PENALTY."""
    X = np.atleast_2d(X)
    with _threads_for(X.shape[0], _steps(p)):
        m = p.mse_many(X)[0]
    return np.where(np.isfinite(m), m, FAIL_PENALTY)


def simulate_efd(p: Problem, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Recorded-efd traces (n_cand, n) of the problem's first capture, and failure flags."""
    from bench_ctl.model.kernel import run_kernel
    r = p.records[0]
    X = np.atleast_2d(X)
    with _threads_for(X.shape[0], r.efd.size):
        out = run_kernel(p.matrix(X), r.usetp, r.dt, r.usetp_pre, edges=r.edges)
    return out["efd"], out["fail_step"] >= 0


@dataclass(frozen=True)
class FitResult:
    names: tuple[str, ...]
    x: np.ndarray
    mse: float
    evaluations: int
    feasible: bool
    message: str
    #: standard deviation of each parameter from the last polish's Jacobian (None: not known)
    std: Mapping[str, float] | None = field(default=None)

    def params(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, self.x)}


def fit(p: Problem, *, x0: Sequence[float] | None = None, evals: int = 400, seed: int = 0,
        box: float | None = None, polish_evals: int = 60, options: Mapping | None = None) -> FitResult:
    """MVMO (in a box of half-width `box` in normalised units around x0, or the full bounds)
    followed by a least-squares polish. `polish_evals` bounds the polish in kernel calls."""
    space = Space.of(p)
    d = space.d
    u0 = space.to_u(np.asarray(x0, float)) if x0 is not None else None
    lo_u = np.zeros(d)
    hi_u = np.ones(d)
    if box is not None and u0 is not None:
        lo_u = np.clip(u0 - box, 0.0, 1.0)
        hi_u = np.clip(u0 + box, 0.0, 1.0)
        hi_u = np.where(hi_u - lo_u < 1e-6, np.minimum(lo_u + 1e-3, 1.0), hi_u)
        lo_u = np.minimum(lo_u, hi_u - 1e-3)
    nfev = 0

    def fun(U: np.ndarray) -> np.ndarray:
        nonlocal nfev
        U = np.atleast_2d(U)
        nfev += U.shape[0]
        return mse_of(p, space.to_x(U))

    def viol(u: np.ndarray) -> float:
        return float(space.violation(space.to_x(u))[0])

    cons = (viol,) if space.A.size else ()
    best_u = u0
    best_f = math.inf
    if u0 is not None:
        best_f = float(fun(u0)[0])
        if space.violation(space.to_x(u0))[0] > 1e-9:
            best_f = math.inf
    if evals > 0:
        res = mvmo.minimize(fun, list(zip(lo_u, hi_u)), constraints=cons, max_evals=int(evals), seed=seed,
                            vectorized=True, x0=None if u0 is None else np.clip(u0, lo_u, hi_u),
                            options=dict(MVMO_OPTIONS if options is None else options))
        if res.feasible and res.fun < best_f:
            best_u, best_f = np.asarray(res.x, float), float(res.fun)
        elif best_u is None:
            best_u, best_f = np.asarray(res.x, float), float(res.fun)
    assert best_u is not None
    u, f, n_pol = polish(p, best_u, max_calls=polish_evals)
    nfev += n_pol
    if f < best_f:
        best_u, best_f = u, f
    x = space.to_x(best_u)
    feasible = bool(space.violation(x)[0] <= 1e-9)
    return FitResult(space.names, x, float(best_f), nfev, feasible, "")


@dataclass
class Polished:
    u: np.ndarray
    mse: float
    calls: int
    jac: np.ndarray | None = None   # d(residual)/du at u (residuals scaled so that sum r^2 ~ mse)
    n_eff: float = 0.0              # scored samples of the residual


def polish(p: Problem, u0: np.ndarray, *, max_calls: int = 60, step: float = 1e-5) -> tuple[np.ndarray, float, int]:
    """Bounded Gauss-Newton (TRF) from u0 on the problem's weighted residuals; returns (u, mse,
    simulations used); mse is inf when the result leaves the constraints (the caller keeps its
    feasible start)."""
    r = polish_full(p, u0, max_calls=max_calls, step=step)
    return r.u, r.mse, r.calls


def polish_full(p: Problem, u0: np.ndarray, *, max_calls: int = 60, step: float = 1e-5) -> Polished:
    """`polish`, also returning the Jacobian at the result (for the parameters' standard deviations)."""
    space = Space.of(p)
    d = space.d
    # the problem's residuals square-sum to its trapezoidal integral; over the scored duration
    # they square-sum to (about) the MSE, so the constraint penalty and tolerances mean the same
    dur = sum(r.n_scored * r.dt for r in p.records)
    scale = 1.0 / math.sqrt(max(dur, 1e-300))
    calls = 0
    cache: dict[bytes, np.ndarray] = {}

    def residual_batch(U: np.ndarray) -> np.ndarray:
        nonlocal calls
        X = space.to_x(U)
        with _threads_for(U.shape[0], _steps(p)):
            R, failed = p.residuals(X)
        calls += U.shape[0]
        R = R * scale
        R[failed] += math.sqrt(FAIL_PENALTY / R.shape[1])
        pen = 10.0 * space.violation(X)
        return np.concatenate([R, pen[:, None]], axis=1)

    def f(u: np.ndarray) -> np.ndarray:
        key = u.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = residual_batch(u[None, :])[0]
        return cache[key]

    def jac(u: np.ndarray) -> np.ndarray:
        r0 = f(u)
        h = np.where(u + step <= 1.0, step, -step)
        U = np.repeat(u[None, :], d, axis=0) + np.diag(h)
        R = residual_batch(U)
        return ((R - r0[None, :]) / h[:, None]).T

    J = None
    try:
        res = least_squares(f, np.clip(u0, 0.0, 1.0), jac=jac, bounds=(0.0, 1.0), method="trf",
                            x_scale="jac", max_nfev=max(2, max_calls // (d + 1)), ftol=1e-7, xtol=1e-7)
        u = np.clip(res.x, 0.0, 1.0)
        J = np.asarray(res.jac)[:-1] if res.jac is not None else None
    except (ValueError, np.linalg.LinAlgError) as exc:  # pragma: no cover - defensive
        log.debug("polish failed: %s", exc)
        u = np.asarray(u0, float)
    x = space.to_x(u)
    mse = float(mse_of(p, x)[0])
    calls += 1
    if space.violation(x)[0] > 1e-9:
        mse = math.inf  # the caller keeps the feasible start
    n_eff = sum(r.n_scored for r in p.records)
    return Polished(u, mse, calls, J, n_eff)


def std_of(p: Problem, pol: Polished, noise_variance: float) -> dict[str, float]:
    """Standard deviations (physical units) of the parameters at a polished point, from its
    Jacobian (Gauss-Newton: var(u) = sigma^2 (J^T J)^-1 / n with J of the MSE-scaled residuals);
    a parameter at a bound or not determined gets NaN."""
    space = Space.of(p)
    if pol.jac is None or pol.n_eff <= 0:
        return {n: math.nan for n in space.names}
    J = pol.jac
    try:
        cov_u = np.linalg.pinv(J.T @ J) * noise_variance / pol.n_eff
    except np.linalg.LinAlgError:  # pragma: no cover - defensive
        return {n: math.nan for n in space.names}
    sd_u = np.sqrt(np.maximum(np.diag(cov_u), 0.0))
    x = space.to_x(pol.u)
    # dx/du: linear (hi - lo), logarithmic x ln(hi / lo)
    ratio = np.where(space.log_scale, space.hi, 2.0) / np.where(space.log_scale, space.lo, 1.0)
    dxdu = np.where(space.log_scale, x * np.log(ratio), space.hi - space.lo)
    return {n: float(v) for n, v in zip(space.names, sd_u * np.abs(dxdu))}
