"""MVMO and the methods the reference paper compared it with, behind one interface.

`run_optimizer(name, problem, max_evals=..., seed=...) -> Result` (pymoo's `minimize(problem,
algorithm, termination)`; `result.Result` after scipy's `OptimizeResult`) runs one of

* ``mvmo``: MVMO-SH (`bench_ctl.identification.mvmo`) on the closed-loop objective, under the
  unit's bounds and constraints; one kernel call per generation, in the search space
  (`space.SearchSpace`: the log of every parameter with a positive lower bound; option
  ``space="linear"`` turns that off), followed by the polish (`polish.polish`). Identification
  and the diagnosis both run it (docs/decisions/0015-one-fitting-stack.md).
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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from scipy import optimize as sopt
from scipy import signal

from bench_ctl.model.dialect import Note
from bench_ctl.model.params import AVR_PARAMS, RECORD_PARAMS

from . import mvmo
from .identifiability import exchanges
from .options import EDGE_POLISH_MAX, EDGE_POLISH_SHARE, IDENTIFY, RESTART_RESERVE_MAX, RESTART_RESERVE_SHARE
from .polish import Tracker, least_squares, polish
from .problem import Problem
from .result import Result
from .space import SearchSpace

logger = logging.getLogger(__name__)

__all__ = ["OPTIMIZERS", "run_optimizer", "OpenLoopModel"]

OPTIMIZERS = ("mvmo", "de", "local", "open-loop")

Progress = Callable[[int, float], Any]


def run_optimizer(name: str, problem: Problem, *, max_evals: int, seed: int | None = 0,
                  x0: Sequence[float] | None = None, progress: Progress | None = None,
                  options: Mapping[str, Any] | None = None) -> Result:
    """Run optimizer `name` (one of OPTIMIZERS) on `problem` within `max_evals` evaluations.

    x0: a start point (MVMO: joins the initial swarm; de: joins the initial population; local
    and open-loop: the start, default the unit's values). options: method-specific settings
    (MVMO: `mvmo.DEFAULT_OPTIONS` over `options.IDENTIFY`, and `space`, `edges`, `polish_evals`;
    de: popsize, mutation, recombination, strategy; local and open-loop: fd_step).
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
    x = np.asarray(res.x, float)
    violated = problem.violated(x)
    f = float(res.fun)
    logger.info("%s: objective %.6g after %d evaluations in %.2f s%s", name, f, res.nfev, wall,
                f"; violates {violated}" if violated else "")
    return replace(res, x=x, fun=f, nfev=int(res.nfev), success=math.isfinite(f) and f < problem.penalty_base,
                   names=problem.names, method=name, wall_s=wall, seed=seed, violated=tuple(violated),
                   history=tuple((int(n), float(v)) for n, v in res.history))


def _result(problem: Problem, x: np.ndarray, f: float, nfev: int, history: Sequence[tuple[int, float]],
            settings: Mapping[str, Any], message: str, **kw: Any) -> Result:
    return Result(x=np.asarray(x, float), fun=float(f), nfev=int(nfev), success=True, message=message,
                  names=problem.names, history=tuple(history), settings=dict(settings), **kw)


# ---------------------------------------------------------------------- MVMO

def _run_mvmo(problem: Problem, max_evals: int, seed: int | None, x0: np.ndarray | None,
              progress: Progress | None, options: dict[str, Any]) -> Result:
    """MVMO in the search space (`SearchSpace`), then the polish (`polish.polish`) of every
    parameter from its best point, then the restarts (`_restarts`): the polish from the start point
    x0 (the unit's values) when one is given, and from the structure's exchanged pairs.

    With setpoint edge instants among the names (and the option `edges` = "polish", the default),
    MVMO searches the model parameters with each edge held at the middle of its interval and the
    polish gets `EDGE_POLISH_SHARE` of the budget (at most `EDGE_POLISH_MAX`): the edge offsets
    barely shape the objective's landscape, searched by MVMO they only thin its budget. Option
    `polish_evals`: the polish's budget instead (the diagnosis' fits); a polish too small for
    three Jacobians is not run and MVMO gets the whole budget. The restarts get
    `RESTART_RESERVE_SHARE` of the budget (at most `RESTART_RESERVE_MAX`) when there is one (a
    start point, or exchanges the structure declares) and the caller left the split to MVMO (no
    `polish_evals`). Figures for the held edges and the restarts: docs/benchmarks.md,
    "Identification: edge instants held, restarts"."""
    opts = {**IDENTIFY, **options}
    mode = str(opts.pop("edges", "polish"))
    if mode not in ("polish", "search"):
        raise ValueError(f"MVMO option edges={mode!r}: choose 'polish' or 'search'")
    kind = str(opts.pop("space", "log"))
    n_pol = opts.pop("polish_evals", None)
    caller_split = n_pol is not None  # the diagnosis' searches divide their budget themselves
    edge = [i for i, n in enumerate(problem.names) if n in RECORD_PARAMS] if mode == "polish" else []
    if n_pol is None:
        n_pol = min(EDGE_POLISH_MAX, int(EDGE_POLISH_SHARE * max_evals)) if edge else 0
    n_pol = int(n_pol)
    if n_pol < 3 * (problem.d + 1) or n_pol >= max_evals:
        n_pol, edge = 0, []
    space = SearchSpace(problem, kind)
    swaps = _swaps(problem)
    start = None if x0 is None or caller_split else np.clip(np.asarray(x0, float), problem.lower, problem.upper)
    # the restarts' evaluations, kept from MVMO (what they leave is not spent); not where the
    # caller divides the budget (`polish_evals`: the diagnosis' effect searches)
    restarts = bool(swaps) or start is not None
    n_swap = min(RESTART_RESERVE_MAX, int(RESTART_RESERVE_SHARE * max_evals)) if restarts and not caller_split else 0
    # MVMO needs its whole swarm in the first generation (and three Jacobians' worth): the swap
    # restarts, then the polish, give way to it on a small budget (`identify --evals 32` runs)
    need = max(int(opts.get("particles", 1)), 3 * (problem.d + 1))
    if max_evals - n_pol - n_swap < need:
        n_swap = 0
    if max_evals - n_pol - n_swap < need and not caller_split:
        n_pol, edge = 0, []
    if not edge:
        res = _mvmo_search(problem, max_evals - n_pol - n_swap, seed, x0, progress, opts, kind)
        if n_pol:
            res = _polished(problem, res, n_pol, space, progress, "polish", {})
        return _restarts(problem, space, start, swaps, max_evals, res, progress)
    mid = {problem.names[i]: 0.5 * (problem.lower[i] + problem.upper[i]) for i in edge}
    sub = problem.held(mid)
    model = [i for i in range(problem.d) if i not in edge]
    x0s = None if x0 is None else np.asarray(x0, float)[model]
    rs = _mvmo_search(sub, max_evals - n_pol - n_swap, seed, x0s, progress, opts, kind)
    x = np.empty(problem.d)
    x[model] = rs.x
    x[edge] = [mid[problem.names[i]] for i in edge]
    res = replace(rs, x=x, names=problem.names)
    res = _polished(problem, res, n_pol, space, progress, "edges", {"search": "held at mid-interval"})
    return _restarts(problem, space, start, swaps, max_evals, res, progress)


def _polished(problem: Problem, res: Result, budget: int, space: SearchSpace, progress: Progress | None,
              key: str, note: dict[str, Any]) -> Result:
    """res followed by the polish from its point; the better end kept, the evaluations added and
    the polish described under settings[key]."""
    pol = polish(problem, res.x, budget=budget, space=space, progress=progress, nfev0=res.nfev, shown=res.fun)
    settings = {**res.settings, key: {**note, "polish": "joint least squares (trf) of every parameter in the "
                                      "search space", "polish_evals": pol.nfev, "polish_message": pol.message}}
    better = pol.success and pol.fun < res.fun
    return replace(pol if better else res, nfev=res.nfev + pol.nfev, settings=settings, message=res.message,
                   history=tuple(res.history) + tuple(pol.history), success=True)


def _restarts(problem: Problem, space: SearchSpace, start: np.ndarray | None, swaps: list[tuple[str, int, int]],
              max_evals: int, res: Result, progress: Progress | None) -> Result:
    """The polish from the start point (the unit's values, when the caller gave them), with its
    share of the evaluations left, the better end kept (`start_restart` in the settings); then the
    swap restarts (`_swap_restarts`) from the better. MVMO's swarm collapses into one basin, the
    same for a seed on any machine only up to the rounding: on a real record (the Mostar ESST5B
    no-load step) the base fit ended in one of three basins by seed (14.6x, 18.6x or 31.6x the
    noise floor), and the polish from the planning record's values reaches the best of them
    whatever the seed (docs/benchmarks.md, "Identification: edge instants held, restarts")."""
    if start is None:
        return _swap_restarts(problem, space, swaps, max_evals, res, progress)
    runs = 1 + _polished_swaps(problem, res.x, swaps)
    budget = (max_evals - res.nfev) // runs
    entry: dict[str, Any] = {"objective_before": float(res.fun)}
    if budget < 3 * (problem.d + 1):
        entry["skipped"] = f"{max_evals - res.nfev} evaluations left of {max_evals}"
        best = res
    else:
        pol = polish(problem, start, budget=budget, space=space, progress=progress, nfev0=res.nfev, shown=res.fun)
        fn = pol.fun if pol.success else math.inf
        entry.update({"objective": float(fn), "kept": bool(fn < res.fun)})
        kept = pol if fn < res.fun else res
        best = replace(kept, nfev=res.nfev + pol.nfev, history=tuple(res.history) + tuple(pol.history),
                       settings=res.settings, message=res.message, success=True)
    best = replace(best, settings={**best.settings, "start_restart": entry})
    return _swap_restarts(problem, space, swaps, max_evals, best, progress)


def _swaps(problem: Problem) -> list[tuple[str, int, int]]:
    """The structure's near-symmetric pairs (`Structure.swaps`) whose two parameters are fitted,
    as (note, index, index) into the problem's names."""
    names = list(problem.names)
    # the note is the structure's own text (its names): a `Note` without args, never re-translated
    return [(Note(note), names.index(a), names.index(b)) for note, a, b in problem.unit.structure.kernel_swaps(names)]


def _swap_restarts(problem: Problem, space: SearchSpace, swaps: list[tuple[str, int, int]], max_evals: int,
                   res: Result, progress: Progress | None) -> Result:
    """For each near-symmetric pair, the polish from res.x with the pair exchanged (clipped into
    the bounds), sharing the evaluations left of `max_evals`; the better end is kept. MVMO's swarm
    collapses into one basin, and for such a pair the exchanged basin can hold a local optimum
    (docs/benchmarks.md, "Identification: edge instants held, restarts"). A pair whose two
    exchanged values both lie outside their bounds is skipped (clipped, nothing of the exchange is
    left) and leaves its share to the others. An exchanged point that breaks a constraint (TA2 <=
    TA1 once TA2 holds TE's value) starts from it with another exchange applied that meets the
    constraint (`_repaired`), where one does."""
    tried = []
    x, f, nfev, history = res.x, res.fun, res.nfev, tuple(res.history)
    best = res
    for k, (note, i, j) in enumerate(swaps):
        xs, outside = _exchanged(problem, x, i, j)
        violated = problem.violated(xs)
        fixed = _repaired(problem, xs, (i, j)) if violated and len(outside) < 2 else None
        if fixed is not None:
            xs, violated = fixed[0], []
        entry: dict[str, Any] = {"swap": note, "start": problem.params(xs), "objective_before": float(f)}
        if fixed is not None:
            entry["with"] = fixed[1]
        if len(outside) == 2:
            entry["skipped"] = f"the exchanged values of {' and '.join(outside)} lie outside their bounds"
        elif violated:
            entry["skipped"] = f"the exchanged point violates {', '.join(violated)}"
        else:
            runs = 1 + _polished_swaps(problem, x, swaps[k + 1:])
            budget = (max_evals - nfev) // runs
            if budget < 3 * (problem.d + 1):
                tried.append({"swap": note, "skipped": f"{max_evals - nfev} evaluations left of {max_evals}"})
                continue
            pol = polish(problem, xs, budget=budget, space=space, progress=progress, nfev0=nfev, shown=f)
            nfev += pol.nfev
            history += tuple(pol.history)
            fn = pol.fun if pol.success else math.inf
            entry.update({"objective": float(fn), "kept": bool(fn < f)})
            if fn < f:
                x, f, best = pol.x, fn, pol
        tried.append(entry)
    settings = {**res.settings, "swap_restarts": tried} if tried else res.settings
    return replace(best, x=x, fun=f, nfev=nfev, history=history, settings=settings, message=res.message)


def _polished_swaps(problem: Problem, x: np.ndarray, swaps: list[tuple[str, int, int]]) -> int:
    """How many of `swaps` get a polish from x (not both exchanged values outside their bounds)."""
    return sum(len(_exchanged(problem, x, a, b)[1]) < 2 for _, a, b in swaps)


def _repaired(problem: Problem, xs: np.ndarray, held: tuple[int, int]) -> tuple[np.ndarray, str] | None:
    """xs, which breaks a constraint, with one more of the structure's exchanges applied
    (`identifiability.exchanges`) that leaves the pair `held` alone and gives a point inside the
    bounds and the constraints, and that exchange's note; None when none does. The reference's
    TA2 <-> TE puts TE's value into TA2, which can break TA2 <= TA1; exchanging the leads TA1 <->
    TA3 too (the same forward path) can meet it, and the exchanged basin is searched from there."""
    names = list(problem.names)
    for note, mapping in exchanges(problem):
        moved = [names.index(a) for a in mapping if a in names]
        if len(moved) != len(mapping) or set(moved) & set(held):
            continue
        x = xs.copy()
        for a, b in mapping.items():
            x[names.index(a)] = xs[names.index(b)]
        if np.all((problem.lower <= x) & (x <= problem.upper)) and not problem.violated(x):
            return x, note
    return None


def _exchanged(problem: Problem, x: np.ndarray, i: int, j: int) -> tuple[np.ndarray, list[str]]:
    """x with parameters i and j exchanged and clipped into the bounds, and the names of those whose
    exchanged value lay outside them."""
    xs = x.copy()
    xs[i], xs[j] = x[j], x[i]
    outside = [problem.names[n] for n in (i, j) if not problem.lower[n] <= xs[n] <= problem.upper[n]]
    return np.clip(xs, problem.lower, problem.upper), outside


def _mvmo_search(problem: Problem, max_evals: int, seed: int | None, x0: np.ndarray | None,
                 progress: Progress | None, opts: dict[str, Any], kind: str) -> Result:
    space = SearchSpace(problem, kind)
    cb = None
    if progress is not None:
        def cb(nfev: int, z: np.ndarray, f: float) -> None:
            progress(nfev, f)
    z0 = None if x0 is None else space.to_z(np.clip(x0, problem.lower, problem.upper))
    r = mvmo.minimize(lambda Z: problem.objective(space.to_x(Z)), space.bounds,
                      constraints=space.constraints, max_evals=max_evals, seed=seed,
                      vectorized=True, options=opts or None, callback=cb, x0=z0)
    x = np.clip(space.to_x(r.x), problem.lower, problem.upper)
    return _result(problem, x, r.fun, r.nfev, r.history, {**r.settings, "space": space.kind}, r.message)


# ---------------------------------------------------------------------- differential evolution

def _run_de(problem: Problem, max_evals: int, seed: int | None, x0: np.ndarray | None,
            progress: Progress | None, options: dict[str, Any]) -> Result:
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
    tr = Tracker(max_evals, progress)

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
    return _result(problem, x, f, tr.nfev, tr.history, settings, str(res.message))


# ---------------------------------------------------------------------- local (PowerFactory-like)

def _run_local(problem: Problem, max_evals: int, seed: int | None, x0: np.ndarray | None,
               progress: Progress | None, options: dict[str, Any]) -> Result:
    fd_step = float(options.pop("fd_step", 1e-6))
    if options:
        raise ValueError(f"unknown local option(s) {sorted(options)}")
    tr = Tracker(max_evals, progress)
    x_start = problem.x_start() if x0 is None else np.asarray(x0, float)
    d = problem.d
    lb, ub = np.full(d, 1e-9), np.full(d, np.inf)  # positivity only, as PowerFactory
    edge = np.array([n in RECORD_PARAMS for n in problem.names])  # edge offsets: their interval
    lb[edge], ub[edge] = problem.lower[edge], problem.upper[edge]
    x_start = np.where(edge, np.clip(x_start, lb, ub), np.maximum(x_start, 2e-9))

    def resid(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, f = problem.residuals_and_objective(X)  # f: the sum of squares, the penalty if failed
        tr.record(X, f)
        return R, f >= problem.penalty_base

    msg, _ = least_squares(resid, x_start, lb, ub, tr, _relative_steps(fd_step, ub))
    x = tr.best_x if tr.best_x is not None else x_start
    # its score is the sum of squared residuals = the objective: no extra, uncounted simulation
    f = tr.best_f if tr.best_x is not None else float(problem.objective(x[None])[0])
    settings = {"algorithm": "scipy.optimize.least_squares (trf), batched forward differences",
                "bounds": "positivity only (x > 0)", "start": problem.params(x_start),
                "fd_step": fd_step, "max_evals": max_evals}
    return _result(problem, x, f, tr.nfev, tr.history, settings, msg)


def _relative_steps(fd_step: float, ub: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """Forward-difference steps relative to |x| (at least fd_step * 1e-3), pointing inside ub."""
    def steps(x: np.ndarray) -> np.ndarray:
        h = fd_step * np.maximum(np.abs(x), 1e-3)
        return np.where(x + h > ub, -h, h)
    return steps


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
                   progress: Progress | None, options: dict[str, Any]) -> Result:
    fd_step = float(options.pop("fd_step", 1e-6))
    if options:
        raise ValueError(f"unknown open-loop option(s) {sorted(options)}")
    typical = problem.unit.values()
    model = OpenLoopModel(problem, typical)
    tr = Tracker(max_evals, progress)
    x_start = np.clip(problem.x_start() if x0 is None else np.asarray(x0, float),
                      problem.lower, problem.upper)

    def resid(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, failed = model.residuals(X)
        # the method only sees its open-loop error; the tracker keeps that as its history
        tr.record(X, np.where(failed, np.inf, np.einsum("ij,ij->i", R, R)))
        return R, failed

    msg, _ = least_squares(resid, x_start, problem.lower, problem.upper, tr, _relative_steps(fd_step, problem.upper))
    x = tr.best_x if tr.best_x is not None else x_start
    f = float(problem.objective(x[None])[0])  # scored in closed loop like the other methods
    settings = {"algorithm": "open-loop AVR fit: scipy.optimize.least_squares (trf), bounds",
                "pseudo_measurement": "Vt simulated in closed loop with the unit's typical values",
                "typical": {n: typical[n] for n in AVR_PARAMS}, "discretisation": "exact: ZOH (setpoint), FOH (Vt)",
                "open_loop_objective": tr.best_f, "fd_step": fd_step, "max_evals": max_evals,
                "history_is": "open-loop objective"}
    return _result(problem, x, f, tr.nfev, tr.history, settings, msg)
