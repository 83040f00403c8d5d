"""MVMO and the methods the reference paper compared it with, behind one interface.

`run_optimizer(name, problem, max_evals=..., seed=...)` runs one of

* ``mvmo``: MVMO-SH (`bench_ctl.identification.mvmo`) on the closed-loop objective, under the
  unit's bounds and constraints; one kernel call per generation. It searches the log of every
  parameter with a positive lower bound (`SearchSpace`; option ``space="linear"`` turns that
  off): the gains and time constants span one to two decades and the objective's valleys are
  far straighter in log coordinates.
* ``de``: scipy's differential evolution on the same objective, bounds and constraints
  (`LinearConstraint`), vectorised (`updating="deferred"`), population and generations chosen
  so the evaluations stay within the budget; no polishing (it would spend evaluations outside
  the budget).
* ``local``: what PowerFactory's identification object does: a gradient (trust-region
  least-squares) search on the residuals from the unit's `value` start point, with only the
  positivity of each parameter as bounds. It knows nothing of the unit's constraints or bounds;
  the result lists the constraints it broke.
* ``open-loop``: what the Simulink workflow was forced into when the AVR input was not measured:
  the closed loop is simulated with the unit's TYPICAL parameters to produce a pseudo-measured
  terminal voltage, the AVR input is reconstructed from it, and the AVR + exciter alone are fitted
  open loop (bounded least squares) to the recorded efd. The error of the pseudo-measurement is
  what costs accuracy. The fitted set is then scored on the closed-loop objective like the others.

Every evaluation (closed- or open-loop candidate, finite-difference column) counts toward
`max_evals`, which is never exceeded. `progress(nfev, best_objective)` is called as the run
goes (for a progress bar).
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from scipy import optimize as sopt
from scipy import signal

from bench_ctl.model.params import AVR_PARAMS, RECORD_PARAMS

from . import mvmo
from .constraints import LinearConstraint
from .problem import Problem

logger = logging.getLogger(__name__)

__all__ = ["OPTIMIZERS", "OptimResult", "run_optimizer", "OpenLoopModel"]

OPTIMIZERS = ("mvmo", "de", "local", "open-loop")

Progress = Callable[[int, float], Any]


@dataclass(frozen=True, eq=False)
class OptimResult:
    """What one optimizer run produced. `objective` is the closed-loop OF at `x`."""
    name: str
    x: np.ndarray
    objective: float
    nfev: int
    history: list[tuple[int, float]]
    wall_s: float
    settings: dict[str, Any]
    seed: int | None
    message: str = ""
    constraints_violated: list[str] = field(default_factory=list)
    failed: bool = False  # the best point could not be simulated (or no finite objective)


class _Budget(Exception):
    """Raised inside scipy callbacks when the evaluation budget is used up."""


class _Tracker:
    """Counts evaluations, keeps the best closed-loop objective and the history."""

    def __init__(self, max_evals: int, progress: Progress | None):
        self.max_evals, self.progress = max_evals, progress
        self.nfev = 0
        self.best_f = math.inf
        self.best_x: np.ndarray | None = None
        self.history: list[tuple[int, float]] = []

    @property
    def remaining(self) -> int:
        return self.max_evals - self.nfev

    def record(self, X: np.ndarray, f: np.ndarray) -> None:
        self.nfev += X.shape[0]
        j = int(np.argmin(f))
        if f[j] < self.best_f:
            self.best_f, self.best_x = float(f[j]), X[j].copy()
        self.history.append((self.nfev, self.best_f))
        if self.progress is not None:
            self.progress(self.nfev, self.best_f)


def run_optimizer(name: str, problem: Problem, *, max_evals: int, seed: int | None = 0,
                  x0: Sequence[float] | None = None, progress: Progress | None = None,
                  options: Mapping[str, Any] | None = None) -> OptimResult:
    """Run optimizer `name` (one of OPTIMIZERS) on `problem` within `max_evals` evaluations.

    x0: a start point (MVMO: joins the initial swarm; de: joins the initial population; local
    and open-loop: the start, default the unit's values). options: method-specific settings
    (MVMO options dict; de: popsize, mutation, recombination; local: fd_step).
    """
    if name not in OPTIMIZERS:
        raise ValueError(f"unknown optimizer {name!r}; choose one of {', '.join(OPTIMIZERS)}")
    if isinstance(max_evals, bool) or not isinstance(max_evals, (int, np.integer)) or max_evals < 1:
        raise ValueError(f"max_evals={max_evals!r}: need an integer >= 1")
    fn = {"mvmo": _run_mvmo, "de": _run_de, "local": _run_local, "open-loop": _run_open_loop}[name]
    t0 = time.perf_counter()
    res = fn(problem, int(max_evals), seed, None if x0 is None else np.asarray(x0, float),
             progress, dict(options or {}))
    wall = time.perf_counter() - t0
    x, f, nfev, hist, settings, msg = res
    violated = problem.violated(x)
    failed = not math.isfinite(f) or f >= problem.penalty_base
    logger.info("%s: objective %.6g after %d evaluations in %.2f s%s", name, f, nfev, wall,
                f"; violates {violated}" if violated else "")
    return OptimResult(name=name, x=np.asarray(x, float), objective=float(f), nfev=int(nfev),
                       history=[(int(n), float(v)) for n, v in hist], wall_s=wall,
                       settings=settings, seed=seed, message=msg, constraints_violated=violated,
                       failed=failed)


# ---------------------------------------------------------------------- MVMO

#: MVMO options used for identification unless overridden (see `mvmo.DEFAULT_OPTIONS`).
#: particles 32: a generation is one kernel call, and the kernel's cost per candidate falls with
#: the batch size (candidates are its inner, vectorised loop); local_search_evals 500: longer
#: polishing along the KAVR-TA4 ridge of this objective. Figures: docs/benchmarks.md, "MVMO
#: defaults and MVMO_OPTIONS".
MVMO_OPTIONS: dict[str, Any] = {"particles": 32, "local_search_evals": 500}


class SearchSpace:
    """The variables MVMO searches: ln x for parameters with a positive lower bound (time
    constants and gains spanning decades), x itself for the others.

    A linear constraint between two log variables with a zero bound (`TA2 <= TA1`, `S12 >=
    1.44*S10`) or on one log variable stays linear in the search space; any other becomes a
    callable violation evaluated in the original units.
    """

    def __init__(self, problem: Problem, space: str):
        if space not in ("log", "linear"):
            raise ValueError(f"MVMO option space={space!r}: choose 'log' or 'linear'")
        lo, hi = problem.lower, problem.upper
        self.log = (lo > 0) if space == "log" else np.zeros(problem.d, bool)
        self.bounds = [(math.log(a), math.log(b)) if g else (a, b) for a, b, g in zip(lo, hi, self.log)]
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

    def to_x(self, Z: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.exp(np.where(self.log, Z, 0.0)), Z)

    def to_z(self, X: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.log(np.where(self.log, X, 1.0)), X)


#: share of the budget (at most EDGE_POLISH_MAX evaluations) of the joint least-squares polish
#: that follows an MVMO search with the edge instants held at mid-interval
EDGE_POLISH_SHARE = 0.15
EDGE_POLISH_MAX = 200


def _run_mvmo(problem: Problem, max_evals: int, seed: int | None, x0: np.ndarray | None,
              progress: Progress | None, options: dict[str, Any]):
    """MVMO; with setpoint edge instants among the names (and the option `edges` = "polish", the
    default), MVMO searches the model parameters with each edge held at the middle of its
    interval, then one least-squares polish moves everything, edges included. The edge offsets
    barely shape the objective's landscape; searched by MVMO they only thin its budget.

    When the unit's structure declares near-symmetric time constants (`Structure.swaps`) and both
    are fitted, the same polish is run again from the point with the two exchanged, and the better
    end kept (`_swap_restarts`), with the evaluations the polish left unused. Figures for both:
    docs/benchmarks.md, "Identification: edge instants held, swap restarts"."""
    opts = dict(options)
    mode = str(opts.pop("edges", "polish"))
    if mode not in ("polish", "search"):
        raise ValueError(f"MVMO option edges={mode!r}: choose 'polish' or 'search'")
    edge = [i for i, n in enumerate(problem.names) if n in RECORD_PARAMS]
    n_pol = min(EDGE_POLISH_MAX, int(EDGE_POLISH_SHARE * max_evals))
    swaps = _swaps(problem)
    if mode == "search" or not edge or n_pol < 3 * (problem.d + 1):
        x, f, nfev, history, settings, msg = _run_mvmo_plain(problem, max_evals, seed, x0, progress, opts)
        return _swap_restarts(problem, swaps, max_evals, x, f, nfev, history, settings, msg, progress)
    mid = {problem.names[i]: 0.5 * (problem.lower[i] + problem.upper[i]) for i in edge}
    sub = problem.held(mid)
    model = [i for i in range(problem.d) if i not in edge]
    x0s = None if x0 is None else np.asarray(x0, float)[model]
    xs, fs, nfev, history, settings, msg = _run_mvmo_plain(sub, max_evals - n_pol, seed, x0s, progress, opts)
    x = np.empty(problem.d)
    x[model] = xs
    x[edge] = [mid[problem.names[i]] for i in edge]
    xp, fp, n, steps, pol_msg = _polish(problem, x, nfev, n_pol, progress, fs)
    x, f = (xp, fp) if fp < fs else (x, fs)
    settings = {**settings, "edges": {"search": "held at mid-interval", "polish": "joint least squares "
                                      "(trf) of every parameter, edges included", "polish_evals": n - nfev,
                                      "polish_message": pol_msg}}
    return _swap_restarts(problem, swaps, max_evals, x, f, n, list(history) + steps, settings, msg, progress)


def _polish(problem: Problem, x: np.ndarray, nfev: int, budget: int, progress: Progress | None,
            shown: float = math.inf) -> tuple[np.ndarray, float, int, list[tuple[int, float]], str]:
    """One joint least-squares polish of every parameter from x, after nfev evaluations, within
    `budget` evaluations: (its best feasible point, that point's objective (inf: none), the
    evaluations so far, its history steps, scipy's message). Progress and history show the best
    objective found so far, never above `shown` (the best before the polish)."""
    offset = nfev

    def shifted(n: int, best: float) -> None:
        if progress is not None:
            progress(offset + n, min(best, shown))

    tr = _Tracker(budget, shifted)

    def score(X: np.ndarray, R: np.ndarray, failed: np.ndarray) -> np.ndarray:
        return np.where(failed, problem.penalty_base, np.einsum("ij,ij->i", R, R))

    # lsmr: the exact solver's SVD of the (samples x parameters) Jacobian cost 17 ms an iteration
    msg = _least_squares(problem.residuals, x, problem.lower, problem.upper, tr, score, 1e-6, "lsmr")
    steps = [(offset + n, min(v, shown)) for n, v in tr.history]
    if tr.best_x is None or problem.violated(tr.best_x):
        return x, math.inf, offset + tr.nfev, steps, msg
    return np.clip(tr.best_x, problem.lower, problem.upper), tr.best_f, offset + tr.nfev, steps, msg


def _swaps(problem: Problem) -> list[tuple[str, int, int]]:
    """The structure's near-symmetric pairs (`Structure.swaps`) whose two parameters are fitted,
    as (note, index, index) into the problem's names."""
    names = list(problem.names)
    return [(note, names.index(a), names.index(b)) for note, a, b in problem.unit.structure.kernel_swaps(names)]


def _swap_restarts(problem: Problem, swaps: list[tuple[str, int, int]], max_evals: int, x: np.ndarray,
                   f: float, nfev: int, history: list, settings: dict[str, Any], msg: str,
                   progress: Progress | None):
    """For each near-symmetric pair, the polish from x with the pair exchanged (clipped into the
    bounds), sharing the evaluations left of `max_evals`; the better end is kept. MVMO's swarm
    collapses into one basin, and for such a pair the exchanged basin can hold a local optimum
    (docs/benchmarks.md, "Identification: edge instants held, swap restarts")."""
    tried = []
    for k, (note, i, j) in enumerate(swaps):
        budget = (max_evals - nfev) // (len(swaps) - k)
        if budget < 3 * (problem.d + 1):
            tried.append({"swap": note, "skipped": f"{max_evals - nfev} evaluations left of {max_evals}"})
            continue
        xs = x.copy()
        xs[i], xs[j] = x[j], x[i]
        xs = np.clip(xs, problem.lower, problem.upper)
        entry: dict[str, Any] = {"swap": note, "start": problem.params(xs), "objective_before": float(f)}
        violated = problem.violated(xs)
        if violated:
            entry["skipped"] = f"the exchanged point violates {', '.join(violated)}"
        else:
            xn, fn, nfev, steps, _ = _polish(problem, xs, nfev, budget, progress, f)
            history = list(history) + steps
            entry.update({"objective": float(fn), "kept": bool(fn < f)})
            if fn < f:
                x, f = xn, fn
        tried.append(entry)
    if tried:
        settings = {**settings, "swap_restarts": tried}
    return x, f, nfev, history, settings, msg


def _run_mvmo_plain(problem: Problem, max_evals: int, seed: int | None, x0: np.ndarray | None,
                    progress: Progress | None, options: dict[str, Any]):
    opts = {**MVMO_OPTIONS, **options}
    space = SearchSpace(problem, str(opts.pop("space", "log")))
    cb = None
    if progress is not None:
        def cb(nfev: int, z: np.ndarray, f: float) -> None:
            progress(nfev, f)
    z0 = None if x0 is None else space.to_z(np.clip(x0, problem.lower, problem.upper))
    r = mvmo.minimize(lambda Z: problem.objective(space.to_x(Z)), space.bounds,
                      constraints=space.constraints, max_evals=max_evals, seed=seed,
                      vectorized=True, options=opts or None, callback=cb, x0=z0)
    x = np.clip(space.to_x(r.x), problem.lower, problem.upper)
    settings = {**r.settings, "space": {n: ("log" if g else "linear") for n, g in zip(problem.names, space.log)}}
    return x, r.fun, r.nfev, r.history, settings, r.message


# ---------------------------------------------------------------------- differential evolution

def _run_de(problem: Problem, max_evals: int, seed: int | None, x0: np.ndarray | None,
            progress: Progress | None, options: dict[str, Any]):
    d = problem.d
    popsize = int(options.pop("popsize", 5))  # multiplier of d, as scipy's
    mutation = options.pop("mutation", (0.5, 1.0))
    recombination = float(options.pop("recombination", 0.7))
    strategy = str(options.pop("strategy", "best1bin"))
    if options:
        raise ValueError(f"unknown de option(s) {sorted(options)}")
    npop = popsize * d
    if max_evals < npop:
        raise ValueError(f"max_evals={max_evals} is below one DE population ({npop})")
    # infeasible trial vectors are not evaluated by scipy, so generations are cheaper than npop:
    # allow plenty and stop on the budget (a generation cut by the budget scores its rest +inf)
    maxiter = 4 * max(1, max_evals // npop)
    tr = _Tracker(max_evals, progress)

    def fun(xt: np.ndarray) -> np.ndarray:
        X = np.asarray(xt, float).reshape(d, -1).T
        if X.shape[0] == 0:
            return np.empty(0)
        if X.shape[0] > tr.remaining:  # never exceed the budget: the rest scores +inf
            f = np.full(X.shape[0], np.inf)
            k = tr.remaining
            if k > 0:
                f[:k] = problem.objective(X[:k])
                tr.record(X[:k], f[:k])
            return f
        f = problem.objective(X)
        tr.record(X, f)
        return f

    cons = ()
    if problem.constraints:
        A = np.array([c.coef for c in problem.constraints])
        b = np.array([c.rhs for c in problem.constraints])
        cons = (sopt.LinearConstraint(A, -np.inf, b),)
    init: Any = "latinhypercube"
    if x0 is not None:
        rng = np.random.default_rng(seed)
        lo, hi = problem.lower, problem.upper
        pop = lo + rng.random((npop, d)) * (hi - lo)
        pop[0] = np.clip(x0, lo, hi)
        init = pop
    res = sopt.differential_evolution(
        fun, problem.bounds, strategy=strategy, maxiter=maxiter, popsize=popsize, tol=0.0,
        atol=0.0, mutation=mutation, recombination=recombination, seed=seed, polish=False,
        init=init, constraints=cons, updating="deferred", vectorized=True,
        callback=lambda *a, **k: tr.remaining <= 0)
    if tr.remaining <= 0 and "Maximum number" not in str(res.message):
        res.message = "evaluation budget used up"
    settings = {"algorithm": "scipy.optimize.differential_evolution", "strategy": strategy,
                "popsize": popsize, "population": npop, "maxiter": maxiter, "mutation": mutation,
                "recombination": recombination, "polish": False, "updating": "deferred",
                "max_evals": max_evals, "seed": seed}
    # the best candidate evaluated (no extra, uncounted simulation to score it again)
    x = tr.best_x if tr.best_x is not None else np.asarray(res.x, float)
    f = tr.best_f if tr.best_x is not None else float(problem.objective(x[None])[0])
    return x, f, tr.nfev, tr.history, settings, str(res.message)


# ---------------------------------------------------------------------- local (PowerFactory-like)

def _least_squares(resid: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], x_start: np.ndarray,
                   lb: np.ndarray, ub: np.ndarray, tr: _Tracker,
                   score: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
                   fd_step: float, tr_solver: str = "exact") -> str:
    """Trust-region reflective least squares with batched forward-difference Jacobians.

    `resid(X)` -> (R (n, m), failed (n,)) evaluates a population at once; `score(X)` gives the
    closed-loop objective recorded in the tracker for each evaluated point (may be the squared
    residual sum itself)."""
    cache: dict[bytes, np.ndarray] = {}

    def evaluate(X: np.ndarray) -> np.ndarray:
        if X.shape[0] > tr.remaining:
            raise _Budget
        R, failed = resid(X)
        f = score(X, R, failed)
        tr.record(X, f)
        return R

    def fun(x: np.ndarray) -> np.ndarray:
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = evaluate(x[None])[0]
        return cache[key]

    def jac(x: np.ndarray) -> np.ndarray:
        r0 = fun(x)
        h = fd_step * np.maximum(np.abs(x), 1e-3)
        h = np.where(x + h > ub, -h, h)  # stay inside the bounds
        R = evaluate(x[None, :] + np.diag(h))
        return (R - r0[None, :]).T / h[None, :]

    try:
        res = sopt.least_squares(fun, x_start, jac=jac, bounds=(lb, ub), method="trf",
                                 x_scale="jac", max_nfev=10 * tr.max_evals, ftol=1e-10,
                                 xtol=1e-10, gtol=1e-10, tr_solver=tr_solver)
        return str(res.message)
    except _Budget:
        return "evaluation budget used up"


def _run_local(problem: Problem, max_evals: int, seed: int | None, x0: np.ndarray | None,
               progress: Progress | None, options: dict[str, Any]):
    fd_step = float(options.pop("fd_step", 1e-6))
    if options:
        raise ValueError(f"unknown local option(s) {sorted(options)}")
    tr = _Tracker(max_evals, progress)
    x_start = problem.x_start() if x0 is None else np.asarray(x0, float)
    d = problem.d
    lb, ub = np.full(d, 1e-9), np.full(d, np.inf)  # positivity only, as PowerFactory
    edge = np.array([n in RECORD_PARAMS for n in problem.names])  # edge offsets: their interval
    lb[edge], ub[edge] = problem.lower[edge], problem.upper[edge]
    x_start = np.where(edge, np.clip(x_start, lb, ub), np.maximum(x_start, 2e-9))

    def score(X: np.ndarray, R: np.ndarray, failed: np.ndarray) -> np.ndarray:
        f = np.einsum("ij,ij->i", R, R)
        return np.where(failed, problem.penalty_base, f)

    msg = _least_squares(problem.residuals, x_start, lb, ub, tr, score, fd_step)
    x = tr.best_x if tr.best_x is not None else x_start
    # its score is the sum of squared residuals = the objective: no extra, uncounted simulation
    f = tr.best_f if tr.best_x is not None else float(problem.objective(x[None])[0])
    settings = {"algorithm": "scipy.optimize.least_squares (trf), batched forward differences",
                "bounds": "positivity only (x > 0)", "start": problem.params(x_start),
                "fd_step": fd_step, "max_evals": max_evals}
    return x, f, tr.nfev, tr.history, settings, msg


# ---------------------------------------------------------------------- open loop (Simulink-like)

class OpenLoopModel:
    """AVR + exciter alone, driven by an AVR input rebuilt from a pseudo-measured Vt.

    For each capture the closed loop is simulated with `typical` (all kernel values, normally the
    unit's) to get Vt_pseudo; the AVR input deviation is
    de = (usetp - usetp_pre) - (Vt_pseudo - Vt0) and the model output is
    efd = efd0 + G(s) de, G = KAVR (1 + s TA1)/(1 + s TA2) (1 + s TA3)/(1 + s TA4) / (1 + s TE),
    discretised exactly at the capture's step: zero-order hold for the setpoint part (as the
    kernel applies it), first-order hold for the smooth Vt part.
    """

    def __init__(self, problem: Problem, typical: Mapping[str, float]):
        # the method works on the recorded setpoint as sampled: edge offsets stay at their start (0)
        missing = [n for n in problem.names if n not in AVR_PARAMS and n not in RECORD_PARAMS]
        if missing:
            raise ValueError(f"the open-loop method fits the AVR only; it cannot fit {missing}")
        self.problem = problem
        self.typical = dict(typical)
        x_typ = np.array([self.typical[n] for n in problem.names])
        sims = problem.simulate(x_typ)
        self.inputs, self.efd0 = [], []
        for r, s in zip(problem.records, sims):
            if s["fail_step"] >= 0:
                raise ValueError("the typical parameters do not give a stable closed loop; "
                                 "cannot build the pseudo-measurement")
            vt0 = self.typical["Vt0"]
            # the setpoint part is a zero-order hold, the pseudo-measured Vt is smooth
            self.inputs.append(((r.usetp - r.usetp_pre)[: r.i1], (s["vt"] - vt0)[: r.i1]))
            self.efd0.append(float(s["efd"][0]))

    def full_values(self, X: np.ndarray) -> np.ndarray:
        """(n, 6) KAVR, TA1..TA4, TE per candidate (fitted names from X, others typical)."""
        X = np.atleast_2d(X)
        out = np.empty((X.shape[0], len(AVR_PARAMS)))
        for j, n in enumerate(AVR_PARAMS):
            out[:, j] = X[:, self.problem.names.index(n)] if n in self.problem.names else self.typical[n]
        return out

    def simulate(self, X: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        """Open-loop efd per capture (each (n, i1)) and a per-candidate invalid flag."""
        V = self.full_values(X)
        bad = ~np.all(np.isfinite(V), axis=1) | np.any(V[:, [0, 2, 4, 5]] <= 0, axis=1) \
            | np.any(V[:, [1, 3]] < 0, axis=1)
        outs = []
        for r, (du, dv), e0 in zip(self.problem.records, self.inputs, self.efd0):
            Y = np.full((V.shape[0], du.size), e0)
            for i, (k, t1, t2, t3, t4, te) in enumerate(V):
                if bad[i]:
                    continue
                num = k * np.polymul([t1, 1.0], [t3, 1.0])
                den = np.polymul(np.polymul([t2, 1.0], [t4, 1.0]), [te, 1.0])
                bz, az, _ = signal.cont2discrete((num, den), r.dt, method="zoh")
                bf, af, _ = signal.cont2discrete((num, den), r.dt, method="foh")
                Y[i] += signal.lfilter(bz[0], az, du) - signal.lfilter(bf[0], af, dv)
            outs.append(Y)
        return outs, bad

    def residuals(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted residuals of the open-loop output against the recorded efd (trapezoid)."""
        outs, bad = self.simulate(X)
        parts = []
        for r, Y in zip(self.problem.records, outs):
            c = np.ones(r.i1 - r.i0)
            c[0] = c[-1] = 0.5
            w = np.sqrt(r.alpha * self.problem.w_efd * c * r.dt)
            parts.append(w * (Y[:, r.i0: r.i1] - r.efd[r.i0: r.i1]))
        R = np.hstack(parts)
        bad = bad | ~np.all(np.isfinite(R), axis=1) | np.any(np.abs(R) > 1e6, axis=1)
        R = np.where(bad[:, None], 1e6, R)
        return R, bad


def _run_open_loop(problem: Problem, max_evals: int, seed: int | None, x0: np.ndarray | None,
                   progress: Progress | None, options: dict[str, Any]):
    fd_step = float(options.pop("fd_step", 1e-6))
    if options:
        raise ValueError(f"unknown open-loop option(s) {sorted(options)}")
    typical = problem.unit.values()
    model = OpenLoopModel(problem, typical)
    tr = _Tracker(max_evals, progress)
    x_start = np.clip(problem.x_start() if x0 is None else np.asarray(x0, float),
                      problem.lower, problem.upper)

    def score(X: np.ndarray, R: np.ndarray, failed: np.ndarray) -> np.ndarray:
        # the method only sees its open-loop error; the tracker keeps that as its history
        return np.where(failed, np.inf, np.einsum("ij,ij->i", R, R))

    msg = _least_squares(model.residuals, x_start, problem.lower, problem.upper, tr, score, fd_step)
    x = tr.best_x if tr.best_x is not None else x_start
    f = float(problem.objective(x[None])[0])  # scored in closed loop like the other methods
    settings = {"algorithm": "open-loop AVR fit: scipy.optimize.least_squares (trf), bounds",
                "pseudo_measurement": "Vt simulated in closed loop with the unit's typical values",
                "typical": {n: typical[n] for n in AVR_PARAMS}, "discretisation": "exact: ZOH (setpoint), FOH (Vt)",
                "open_loop_objective": tr.best_f, "fd_step": fd_step, "max_evals": max_evals,
                "history_is": "open-loop objective"}
    return x, f, tr.nfev, tr.history, settings, msg
