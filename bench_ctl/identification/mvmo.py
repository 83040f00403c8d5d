"""MVMO / MVMO-SH: Mean-Variance Mapping Optimization with bounds and inequality constraints.

Implemented from the published description (Erlich, Venayagamoorthy & Worawat 2010; Rueda &
Erlich's swarm-hybrid MVMO-SH, 2013-2015) and docs/identification.md, not from the
authors' code. All search happens in ``z``, the variables normalised to ``[0, 1]`` by the
bounds:

* ``particles`` particles, each with an archive of its ``archive_size`` best solutions, sorted
  best first; a new solution enters a full archive only if it beats the worst entry.
* Per variable the archive gives a mean ``xbar`` and variance ``v``; shape ``s = -ln(v) * fs``
  (a zero variance keeps the last non-zero one; that starts at 1, i.e. a uniform draw).
* Asymmetric shape: a factor ``d`` per variable chases ``s`` (``d *= D`` when ``s > d`` else
  ``d /= D``, ``D = 1 + delta_d + 2 delta_d (r - 0.5)``) and replaces ``s1`` or ``s2`` at random.
* Offspring = parent with ``m`` variables re-drawn through the corrected mapping
  :func:`mapping` of a uniform number. The variables are chosen "random-sequential": one
  variable stepping through all of them in turn, the other ``m - 1`` at random.
* ``fs`` grows from ``fs_init`` to ``fs_final`` and ``m`` shrinks from ``m_init`` to
  ``m_final`` with the square of the used budget share ``t``: ``fs = fs_init + t^2 (fs_final -
  fs_init)``, ``m* = round(m_init - t^2 (m_init - m_final))``, ``m = round(m_final + r (m* -
  m_final))`` (``r`` uniform).
* Swarm hybrid: after ``independent_phase`` of the budget, particles are ranked by their best
  solution; the best ``round(g P)`` are good (``g = good_init - t^2 (good_init - good_final)``),
  the others bad. A good particle's parent is its own archive best; a bad particle's is the
  multi-parent crossover ``x_RG + beta (x_GB - x_LG)`` (a random good particle's best, the
  global best, the last good particle's best; ``beta`` uniform in ``[0, 2)``, drawn anew for
  every bad particle and generation), reflected back into ``[0, 1]``.
* Local search: once ``local_search_after`` of the budget is used, after each generation and
  with probability ``local_search_prob``, the best-ranked good particle whose best solution has
  not been polished yet starts SLSQP (scipy; bounds, linear constraints exactly, callables as
  inequality constraints) from that solution, with forward-difference gradients evaluated as
  ONE batch of ``d`` points, for at most ``local_search_evals`` evaluations. Its best point
  enters the particle's archive. A search that ended by itself marks the particle polished
  until it finds a new best; one cut short by its budget may be continued later.

Constraint handling: each candidate gets ``V``, the sum of its constraint violations (linear
constraints in their own units, callables as returned). ``V <= constraint_tol`` is feasible.
Ranking everywhere (archives, swarm, result): feasible beats infeasible; feasible ones by the
objective; infeasible ones by the penalised objective ``f + penalty * V``. Every evaluation,
local search included, counts toward ``max_evals``, which is never exceeded (the last
generation is truncated). Non-finite objective values rank as ``+inf``.

One generation = one offspring per particle = one call of ``fun`` when ``vectorized=True``;
the same points are evaluated in the same order either way, so both give the same result.

Choices of this implementation where the literature leaves room or was not at hand to check:
the ``beta`` range, SLSQP with batched forward differences as the local search and its
scheduling (one at a time, best unpolished good particle), the penalised ranking of infeasible
candidates, and the defaults in ``DEFAULT_OPTIONS`` (docs/benchmarks.md, "MVMO defaults and
option sets").

This module is the swarm and its main loop; the evaluation of the candidates within the budget,
their ranking and the local search are ``mvmo_search``'s.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from .mvmo_search import BatchProblem, BudgetRun, ConstraintLike, local_search

logger = logging.getLogger(__name__)

__all__ = ["DEFAULT_OPTIONS", "MVMOResult", "mapping", "minimize"]

#: Option defaults (why: docs/benchmarks.md, "MVMO defaults and option sets"). ``None`` means
#: derived from the number of variables ``d``: ``m_init = ceil(d / 2)``,
#: ``local_search_evals = 40 (d + 1)``.
DEFAULT_OPTIONS: Mapping[str, Any] = MappingProxyType(
    {
        "particles": 8,  # swarm size = batch size of a generation; 1 = single-particle MVMO
        "archive_size": 4,  # solutions kept per particle
        "fs_init": 1.0,  # shape scaling factor at the start ...
        "fs_final": 20.0,  # ... and at the end of the budget
        "m_init": None,  # variables re-drawn per offspring at the start ...
        "m_final": 1,  # ... and at the end
        "delta_d": 0.25,  # step of the asymmetric d-factor
        "good_init": 0.7,  # share of good particles at the start ...
        "good_final": 0.2,  # ... and at the end
        "independent_phase": 0.1,  # share of the budget before particles are ranked
        "local_search_after": 0.2,  # share of the budget before local searches may start
        "local_search_prob": 0.3,  # chance per generation of starting a local search
        "local_search_evals": None,  # evaluation budget of one local search
        "fd_step": 1e-7,  # finite-difference step of the local search, normalised units
        "fd_scheme": "forward",  # the local search's gradient: "forward" (d points) or "central" (2 d)
        "penalty": 1e3,  # weight of the violation sum when ranking infeasible candidates
        "constraint_tol": 1e-9,  # violation sum still counted as feasible
    }
)


@dataclass(frozen=True, eq=False)
class MVMOResult:
    """Outcome of :func:`minimize`; ``settings`` is JSON-ready (options, seed, budget)."""

    x: np.ndarray
    fun: float
    nfev: int
    history: list[tuple[int, float]]
    feasible: bool
    max_violation: float
    message: str
    settings: dict[str, Any] = field(default_factory=dict)


def mapping(u: np.ndarray | float, xbar: np.ndarray | float, s1: np.ndarray | float,
            s2: np.ndarray | float) -> np.ndarray:
    """MVMO mapping of a uniform number ``u`` in [0, 1] around the archive mean ``xbar``.

    ``h(u) = xbar (1 - exp(-u s1)) + (1 - xbar) exp(-(1 - u) s2)``, corrected to
    ``h(u) + (1 - h(1) + h(0)) u - h(0)`` so that 0 maps to 0 and 1 to 1; the result is
    monotone in ``u`` and stays in [0, 1] (rounding is clipped). ``s1 = s2 = 0`` gives ``u``.
    """
    u, xbar, s1, s2 = (np.asarray(a, dtype=float) for a in (u, xbar, s1, s2))

    def h(x: np.ndarray) -> np.ndarray:
        return xbar * (1.0 - np.exp(-x * s1)) + (1.0 - xbar) * np.exp(-(1.0 - x) * s2)

    h0, h1 = h(np.zeros_like(u)), h(np.ones_like(u))
    return np.clip(h(u) + (1.0 - h1 + h0) * u - h0, 0.0, 1.0)


# --------------------------------------------------------------------------- options

def _resolve_options(options: Mapping[str, Any] | None, d: int) -> dict[str, Any]:
    opts = dict(DEFAULT_OPTIONS)
    unknown = sorted(set(options or {}) - set(opts))
    if unknown:
        raise ValueError(f"unknown MVMO option(s) {unknown}; known: {sorted(opts)}")
    opts.update(options or {})
    if opts["m_init"] is None:
        opts["m_init"] = math.ceil(d / 2)
    if opts["local_search_evals"] is None:
        opts["local_search_evals"] = 40 * (d + 1)
    ints = ("particles", "archive_size", "m_init", "m_final", "local_search_evals")
    for k in ints:
        if isinstance(opts[k], bool) or not isinstance(opts[k], (int, np.integer)) or opts[k] < 1:
            raise ValueError(f"option {k}={opts[k]!r}: need an integer >= 1")
        opts[k] = int(opts[k])
    if opts["fd_scheme"] not in ("forward", "central"):
        raise ValueError(f"option fd_scheme={opts['fd_scheme']!r}: choose 'forward' or 'central'")
    for k in set(opts) - set(ints) - {"fd_scheme"}:
        if isinstance(opts[k], bool) or not isinstance(opts[k], (int, float, np.number)) \
                or not np.isfinite(opts[k]):
            raise ValueError(f"option {k}={opts[k]!r}: need a finite number")
        opts[k] = float(opts[k])
    if not opts["m_final"] <= opts["m_init"] <= d:
        raise ValueError(f"options m_final={opts['m_final']}, m_init={opts['m_init']}: need "
                         f"1 <= m_final <= m_init <= {d} (number of variables)")
    for k in ("good_init", "good_final", "independent_phase", "local_search_after",
              "local_search_prob"):
        if not 0.0 <= opts[k] <= 1.0:
            raise ValueError(f"option {k}={opts[k]}: need a value in [0, 1]")
    if opts["local_search_evals"] < d + 1:
        raise ValueError(f"option local_search_evals={opts['local_search_evals']}: need at least "
                         f"d + 1 = {d + 1} (one gradient)")
    for k in ("fs_init", "fs_final", "delta_d", "fd_step"):
        if opts[k] <= 0.0:
            raise ValueError(f"option {k}={opts[k]}: need a value > 0")
    if opts["penalty"] < 0 or opts["constraint_tol"] < 0:
        raise ValueError("options penalty and constraint_tol must be >= 0")
    return opts


# --------------------------------------------------------------------------- swarm

class _Swarm:
    """Particles' archives (normalised space) and the MVMO offspring rule, vectorised over
    particles (the optimizer's own cost must stay small beside a batched kernel call)."""

    def __init__(self, Z: np.ndarray, inf: np.ndarray, mer: np.ndarray, archive_size: int,
                 rng: np.random.Generator):
        P, d = Z.shape
        self.P, self.d, self.A, self.rng = P, d, archive_size, rng
        self.x = np.zeros((P, archive_size, d))
        self.inf = np.ones((P, archive_size), dtype=bool)  # empty slots: infeasible, +inf
        self.mer = np.full((P, archive_size), np.inf)
        self.n = np.ones(P, dtype=int)
        self.x[:, 0], self.inf[:, 0], self.mer[:, 0] = Z, inf, mer
        self.last_var = np.ones((P, d))  # last non-zero archive variance per variable
        self.dfac = np.ones((P, d))  # asymmetric d-factor
        self.seq = rng.integers(0, d, size=P)  # the sequentially stepping variable
        self.polished = np.zeros(P, dtype=bool)

    def ranked(self) -> np.ndarray:
        """Particle indices, best archive head first."""
        return np.lexsort((self.mer[:, 0], self.inf[:, 0]))

    def insert(self, rows: np.ndarray, Z: np.ndarray, inf: np.ndarray, mer: np.ndarray) -> None:
        """Offer candidate ``Z[k]`` to the archive of particle ``rows[k]`` (distinct rows)."""
        rows = np.asarray(rows, dtype=int)
        n = self.n[rows]
        full = n >= self.A
        w_inf, w_mer = self.inf[rows, -1], self.mer[rows, -1]
        beats_worst = (~inf & w_inf) | ((inf == w_inf) & (mer < w_mer))
        take = ~full | beats_worst
        rows, slot = rows[take], np.where(full, self.A - 1, n)[take]
        if rows.size == 0:
            return
        self.x[rows, slot] = Z[take]
        self.inf[rows, slot], self.mer[rows, slot] = inf[take], mer[take]
        self.n[rows] = np.minimum(self.n[rows] + 1, self.A)
        order = np.lexsort((self.mer[rows], self.inf[rows]), axis=-1)  # stable: empty slots last
        self.x[rows] = np.take_along_axis(self.x[rows], order[:, :, None], axis=1)
        self.inf[rows] = np.take_along_axis(self.inf[rows], order, axis=1)
        self.mer[rows] = np.take_along_axis(self.mer[rows], order, axis=1)
        self.polished[rows[order[:, 0] == slot]] = False  # a new best: worth a local search

    def offspring(self, parents: np.ndarray, m: np.ndarray, fs: float, delta_d: float
                  ) -> np.ndarray:
        """One child per particle: ``m[p]`` variables of ``parents[p]`` re-drawn by mapping."""
        rng, P, d = self.rng, self.P, self.d
        # random-sequential choice: the stepping variable always, then m - 1 random others
        keys = rng.random((P, d))
        keys[np.arange(P), self.seq % d] = -1.0
        self.seq += 1
        chosen = np.argsort(np.argsort(keys, axis=1), axis=1) < m[:, None]
        # archive statistics per particle and variable
        filled = (np.arange(self.A)[None, :] < self.n[:, None])[:, :, None]
        cnt = self.n[:, None].astype(float)
        xbar = np.where(filled, self.x, 0.0).sum(axis=1) / cnt
        var = np.where(filled, (self.x - xbar[:, None, :]) ** 2, 0.0).sum(axis=1) / cnt
        var = np.where(var > 0.0, var, self.last_var)
        self.last_var = var
        s = -np.log(var) * fs
        # asymmetric d-factor, updated for the chosen variables
        step = 1.0 + delta_d + 2.0 * delta_d * (rng.random((P, d)) - 0.5)
        dd = np.where(s > self.dfac, self.dfac * step, self.dfac / step)
        self.dfac = np.where(chosen & (s > 0.0), dd, self.dfac)
        dd = self.dfac
        first_side = rng.random((P, d)) >= 0.5
        s1 = np.where(s > 0.0, np.where(first_side, s, dd), s)
        s2 = np.where(s > 0.0, np.where(first_side, dd, s), s)
        return np.where(chosen, mapping(rng.random((P, d)), xbar, s1, s2), parents)


def _reflect(z: np.ndarray) -> np.ndarray:
    """Fold values back into [0, 1] by reflection at the bounds."""
    z = np.abs(z) % 2.0
    return np.where(z > 1.0, 2.0 - z, z)


# --------------------------------------------------------------------------- main loop

def minimize(fun: Callable[[np.ndarray], Any], bounds: Sequence[Sequence[float]], *,
             constraints: Sequence[ConstraintLike] = (), max_evals: int, seed: int | None,
             vectorized: bool = False, options: Mapping[str, Any] | None = None,
             callback: Callable[[int, np.ndarray, float], Any] | None = None,
             x0: Sequence[float] | np.ndarray | None = None) -> MVMOResult:
    """Minimise ``fun`` over the box ``bounds`` under ``constraints`` with MVMO-SH.

    ``fun(x)`` takes one parameter vector (``vectorized=False``) or an ``(n, d)`` array and
    returns ``n`` values (``vectorized=True``: one call per generation of ``particles``
    candidates, and one per gradient / line-search step of the local search).
    ``constraints``: :class:`LinearConstraint` (original units) or callables ``g(x)`` returning
    a violation ``>= 0`` (0 = satisfied). ``seed=None`` draws a seed and records it in
    ``settings`` so the run can be repeated. ``callback(nfev, best_x, best_fun)`` runs after
    every batch; a true return value stops the run. ``x0`` (within bounds) replaces one member
    of the initial population (warm start). ``options``: see ``DEFAULT_OPTIONS``; unknown keys
    are errors.

    Default choices: 8 particles (more give fewer generations per particle at a budget of 1000);
    one local search at a time from the best unpolished good particle after 20 % of the budget
    (without local search a pulse-response fit does not reach the true parameters' error);
    ``fs`` 1 -> 20, archive 4, ``delta_d`` 0.25, good share 0.7 -> 0.2. The figures behind
    them: docs/benchmarks.md, "MVMO defaults and option sets".
    """
    if isinstance(max_evals, bool) or not isinstance(max_evals, (int, np.integer)) or max_evals < 1:
        raise ValueError(f"max_evals={max_evals!r}: need an integer >= 1")
    max_evals = int(max_evals)
    if seed is None:
        seed = int(np.random.SeedSequence().entropy % (2**63))
    rng = np.random.default_rng(seed)
    prob = BatchProblem(fun, bounds, constraints, vectorized)
    d = prob.d
    opts = _resolve_options(options, d)
    prob.tol, prob.penalty = opts["constraint_tol"], opts["penalty"]
    P = opts["particles"]
    if max_evals < P:
        raise ValueError(f"max_evals={max_evals} is smaller than the swarm (particles={P})")

    run = BudgetRun(prob, max_evals, callback)
    Z = rng.random((P, d))
    if x0 is not None:
        x0a = np.asarray(x0, dtype=float)
        if x0a.shape != (d,):
            raise ValueError(f"x0 has shape {x0a.shape}, expected ({d},)")
        # against the given bounds: lo + (hi - lo) can round one step below hi
        out = np.flatnonzero(~((x0a >= prob.lo) & (x0a <= prob.hi)))
        if out.size:
            i = int(out[0])
            raise ValueError(f"x0[{i}] = {x0a[i]} outside bounds ({prob.lo[i]}, {prob.hi[i]})")
        Z[0] = np.clip((x0a - prob.lo) / prob.span, 0.0, 1.0)
    _, inf, mer = run.batch(Z)
    swarm = _Swarm(Z, inf, mer, opts["archive_size"], rng)

    while run.remaining > 0 and not run.stopped:
        t2 = (run.nfev / max_evals) ** 2
        fs = opts["fs_init"] + t2 * (opts["fs_final"] - opts["fs_init"])
        m_star = round(opts["m_init"] - t2 * (opts["m_init"] - opts["m_final"]))
        ranked = swarm.ranked()
        n_good = P
        if P > 1 and run.nfev >= opts["independent_phase"] * max_evals:
            g = opts["good_init"] - t2 * (opts["good_init"] - opts["good_final"])
            n_good = min(P, max(1, round(P * g)))
        good = ranked[:n_good]
        x_gb, x_lg = swarm.x[ranked[0], 0], swarm.x[ranked[n_good - 1], 0]

        parents = swarm.x[:, 0].copy()
        bad = ranked[n_good:]
        if bad.size:
            x_rg = swarm.x[good[rng.integers(n_good, size=bad.size)], 0]
            beta = 2.0 * rng.random(bad.size)[:, None]
            parents[bad] = _reflect(x_rg + beta * (x_gb - x_lg))
        m = np.rint(opts["m_final"] + rng.random(P) * (m_star - opts["m_final"]))
        children = swarm.offspring(parents, np.clip(m, 1, d).astype(int), fs, opts["delta_d"])

        n_eval = min(P, run.remaining)
        _, inf, mer = run.batch(children[:n_eval])
        swarm.insert(np.arange(n_eval), children[:n_eval], inf, mer)

        if (opts["local_search_prob"] > 0.0 and not run.stopped and run.remaining > d
                and run.nfev >= opts["local_search_after"] * max_evals):
            ranked = swarm.ranked()
            cands = [int(p) for p in ranked[:n_good] if not swarm.polished[p]]
            if cands and rng.random() < opts["local_search_prob"]:
                p = cands[0]
                found, finished = local_search(run, swarm.x[p, 0].copy(),
                                                 min(opts["local_search_evals"], run.remaining),
                                                 opts["fd_step"], opts["fd_scheme"] == "central")
                if found is not None:
                    swarm.insert(np.array([p]), found[0][None, :], np.array([found[2]]),
                                 np.array([found[3]]))
                swarm.polished[p] = finished

    assert run.best is not None
    b_inf, _, b_f, b_vmax, b_z = run.best
    msg = "stopped by callback" if run.stopped else "max_evals reached"
    if prob.n_nonfinite:
        msg += f"; {prob.n_nonfinite} non-finite objective values ranked as +inf"
    settings = {"algorithm": "MVMO-SH", "seed": seed, "max_evals": max_evals,
                "vectorized": bool(vectorized), "n_params": d,
                "n_constraints": len(prob.linear) + len(prob.callables), **opts}
    logger.info("MVMO: best %.6g after %d evaluations (%s)", b_f, run.nfev, msg)
    return MVMOResult(x=prob.to_x(b_z), fun=b_f, nfev=run.nfev, history=run.history,
                      feasible=not b_inf, max_violation=b_vmax, message=msg, settings=settings)
