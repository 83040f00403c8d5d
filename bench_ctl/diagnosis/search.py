"""How the diagnosis fits a model (the base model plus one or several effects) to the capture.

Every fit is identification's stack on identification's objective (`peers.run_optimizer`'s MVMO,
`polish.polish`, `SearchSpace`, docs/decisions/0015-one-fitting-stack.md); what is the
diagnosis' own is the strategy that drives each model to its local minimum, so that "base
model" and "base model + effect" differ by what the effect explains and not by how far an
optimiser happened to get (`fit_model`):

1. from each start (`starts.all_starts`) a profile polish (effect parameters held, model
   parameters free), then everything free - on the coarse record (every 4 ms, up to 3 s after
   the trailing edge), the edge instants held at the base fit's (a 4 ms grid cannot place them);
2. for the leaders not yet at the noise floor (`global_search`): MVMO over the whole box, and
   MVMO over the model parameters with the effect held at the local fit's values (a profile,
   then everything free), both started from the unit file's values;
3. the leaders polished on the full record with the edge instants free (`finish`, `refine`).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np

from bench_ctl.identification import options as mvmo_sets
from bench_ctl.identification.fit_check import checked
from bench_ctl.identification.model_fits import ModelFit, Views, added_params, edge_names, mid
from bench_ctl.identification.peers import run_optimizer
from bench_ctl.identification.polish import evaluate, polish
from bench_ctl.identification.problem import Problem
from bench_ctl.identification.result import Result
from bench_ctl.identification.space import SearchSpace

__all__ = ["fit", "fit_model", "global_search", "finish", "refine", "refine_base", "mean"]

#: the whole-box search of `_global`: independent MVMO runs sharing the budget (two smaller runs
#: find a narrow basin more often than one: docs/benchmarks.md, "Diagnosis constants")
RESTARTS = 2


def mean(p: Problem, res: Result) -> float:
    """The result's mean objective on p (inf when it failed to find a feasible, simulated point)."""
    return res.fun / p.scored_s if res.success and not res.violated else math.inf


def fit(p: Problem, *, x0: Sequence[float] | None, evals: int, seed: int, polish_evals: int,
        options: Mapping) -> Result:
    """MVMO with `evals` evaluations (x0 in its first swarm), then the polish from its best with
    `polish_evals` simulations: `run_optimizer("mvmo")` with the option set `options`."""
    return run_optimizer("mvmo", p, max_evals=int(evals) + int(polish_evals), seed=seed, x0=x0,
                         options={**options, "polish_evals": int(polish_evals)})


def _coarse(views: Views, p: Problem, held_edges: Mapping[str, float]) -> Problem:
    return views.coarse(p.held(dict(held_edges))) if held_edges else views.coarse(p)


def fit_model(views: Views, effects: Sequence[str], starts: Sequence[Mapping[str, float]], *, evals: int,
              seed: int, fixed: Mapping[str, float] | None = None, polish_coarse: int = 150,
              polish_fine: int = 60, multi: int = 8, floor_tol: float = 0.0, profile_evals: int = 0,
              check: bool = False, extra: Sequence[str] = (), profile: bool = True) -> ModelFit:
    """Fit the model + `effects` (steps 1-2 of the module docstring) from the first `multi` starts
    (maps of values; an edge instant it lacks starts mid-interval); the best coarse solution
    polished on the full record with `polish_fine` simulations (0: only evaluated there).
    profile=False: from each start everything free at once (no profile run first)."""
    fixed = dict(fixed or {})
    extra = tuple(extra)
    p = views.problem(effects, fixed, extra=extra)
    space = SearchSpace(p)
    edges = edge_names(p)
    middle = mid(p, edges)
    held_edges = {n: float(starts[0].get(n, middle[n])) for n in edges}
    pc = _coarse(views, p, held_edges)
    sc = SearchSpace(pc)
    nfev = 0
    counter = [0]
    cands: list[tuple[float, dict[str, float]]] = []
    eff_names = [n for n in pc.names if n not in views.model_start]
    short = max(3 * (sc.d + 1), polish_coarse // 3)
    for x0 in starts[:max(1, multi)]:
        # a profile (the effect parameters held at the start while the model parameters move, so
        # an effect that the model partly absorbs cannot slide back to its neutral value before
        # the model has left the base fit's basin), then everything free
        xp, f = dict(x0), math.inf
        if profile:
            prof_p = views.problem(effects, {**fixed, **{n: x0[n] for n in eff_names}}, with_effects=False,
                                   extra=extra)
            prof = _coarse(views, prof_p, held_edges)
            res = polish(prof, SearchSpace(prof).vector(x0), budget=short)
            nfev += res.nfev
            f = mean(prof, res)
            xp = {**dict(x0), **res.params()}
        res = polish(pc, sc.vector(xp), budget=polish_coarse)
        nfev += res.nfev
        f2 = mean(pc, res)
        cands.append((f2, res.params()) if f2 <= f else (f, {k: xp[k] for k in sc.names}))
    cands.sort(key=lambda c: c[0])
    if (evals > 0 or profile_evals > 0) and not cands[0][0] <= floor_tol:
        cands.append(_global(views, effects, fixed, pc, cands[0][1], evals=evals, profile_evals=profile_evals,
                             seed=seed, polish_coarse=polish_coarse, floor_tol=floor_tol, counter=counter,
                             held_edges=held_edges, extra=extra))
        cands.sort(key=lambda c: c[0])
    nfev += counter[0]
    best = {**held_edges, **cands[0][1]}
    fitted = finish(views, effects, fixed, space.vector(best), polish_fine=polish_fine, check=check, extra=extra)
    return replace(fitted, evaluations=fitted.evaluations + nfev,
                   start={n: float(starts[0].get(n, held_edges.get(n, math.nan))) for n in space.names})


def _global(views: Views, effects: Sequence[str], fixed: Mapping[str, float], pc: Problem,
            x0: Mapping[str, float], *, evals: int, profile_evals: int, seed: int, polish_coarse: int,
            floor_tol: float, counter: list[int], held_edges: Mapping[str, float],
            extra: Sequence[str] = ()) -> tuple[float, dict[str, float]]:
    """Step 2 on the coarse problem `pc` from the local fit x0. MVMO must not start from x0 itself:
    a local minimum in its first population pulls the whole swarm into that basin
    (docs/benchmarks.md, "Diagnosis constants"). The searches start from the unit file's values
    with x0's effect values instead:
    a. MVMO over the whole box (`RESTARTS` runs sharing `evals`, `options.WHOLE_BOX`), then the polish;
    b. unless a reached the floor: MVMO over the model parameters with the effect held at x0's
       values (a profile, `options.PROFILE`), then everything free.
    Returns the best (coarse mean objective, values) of x0, a and b."""
    sc = SearchSpace(pc)
    model = views.model_start
    eff_names = [n for n in sc.names if n not in model]
    best = (float(pc.mean_objective(sc.vector(x0)[None])[0]), dict(x0))
    if not sc.feasible(sc.vector(x0)[None])[0]:
        best = (math.inf, dict(x0))
    counter[0] += 1
    typical = {n: model.get(n, x0[n]) for n in sc.names}
    for r in range(RESTARTS if evals > 0 else 0):
        res = fit(pc, x0=sc.vector(typical), evals=evals // RESTARTS, seed=seed + 100 * r,
                  polish_evals=polish_coarse, options=mvmo_sets.WHOLE_BOX)
        counter[0] += res.nfev
        if mean(pc, res) < best[0]:
            best = (mean(pc, res), res.params())
        if best[0] <= floor_tol:
            break
    if profile_evals > 0 and eff_names and not best[0] <= floor_tol:
        prof_p = views.problem(effects, {**fixed, **{n: x0[n] for n in eff_names}}, with_effects=False, extra=extra)
        prof = _coarse(views, prof_p, held_edges)
        res = fit(prof, x0=SearchSpace(prof).vector(typical), evals=profile_evals, seed=seed + 1,
                  polish_evals=polish_coarse // 3, options=mvmo_sets.PROFILE)
        xp = {**{n: x0[n] for n in eff_names}, **res.params()}
        pol = polish(pc, sc.vector(xp), budget=polish_coarse)
        counter[0] += res.nfev + pol.nfev
        if mean(pc, pol) < best[0]:
            best = (mean(pc, pol), pol.params())
    return best


def global_search(views: Views, m: ModelFit, *, evals: int, profile_evals: int, seed: int, polish_coarse: int,
                  floor_tol: float) -> ModelFit:
    """Step 2 for a fit from `fit_model(..., evals=0, profile_evals=0)`; the better of the two."""
    p = views.problem(m.effects, m.fixed, extra=m.extra)
    params = m.params
    held_edges = {n: params[n] for n in edge_names(p)}
    pc = _coarse(views, p, held_edges)
    counter = [0]
    _f, values = _global(views, m.effects, m.fixed, pc, {n: params[n] for n in pc.names}, evals=evals,
                         profile_evals=profile_evals, seed=seed, polish_coarse=polish_coarse, floor_tol=floor_tol,
                         counter=counter, held_edges=held_edges, extra=m.extra)
    out = finish(views, m.effects, m.fixed, SearchSpace(p).vector({**held_edges, **values}), polish_fine=0,
                 extra=m.extra)
    if not out.mse < m.mse:
        return replace(m, evaluations=m.evaluations + counter[0] + out.evaluations)
    return replace(out, evaluations=m.evaluations + counter[0] + out.evaluations, start=m.start)


def finish(views: Views, effects: Sequence[str], fixed: Mapping[str, float], x0: np.ndarray, *,
           polish_fine: int, check: bool = False, noise_variance: float | None = None,
           extra: Sequence[str] = ()) -> ModelFit:
    """Polish x0 on the full record, edge instants free (`polish_fine` simulations; 0: evaluate x0
    as it is); with `check`, judge the result on the check (`fit_check.check_parts`); with the noise
    variance, the parameters' standard deviations from the polish."""
    p = views.problem(effects, fixed, extra=extra)
    x0 = np.asarray(x0, float)
    res = polish(p, x0, budget=polish_fine, noise_variance=noise_variance) if polish_fine > 0 else evaluate(p, x0)
    nfev = res.nfev
    if not res.success:   # nothing feasible found: x0 as it is, evaluated on the full record
        res = evaluate(p, x0)
        nfev += res.nfev
    mse = res.fun / p.scored_s if res.success else math.inf
    m = ModelFit(tuple(effects), res, mse, None, added_params(effects) + len(tuple(extra)), nfev,
                 fixed=dict(fixed), extra=tuple(extra))
    return checked(views, m) if check else m


def refine(views: Views, m: ModelFit, *, polish_fine: int) -> ModelFit:
    """Polish a fit (from the coarse record) on the full record."""
    p = views.problem(m.effects, m.fixed, extra=m.extra)
    out = finish(views, m.effects, m.fixed, SearchSpace(p).vector(m.params), polish_fine=polish_fine, extra=m.extra)
    if out.mse > m.mse:
        return m
    return replace(out, evaluations=out.evaluations + m.evaluations, start=m.start)


def refine_base(views: Views, base: ModelFit, candidates: Sequence[Mapping[str, float]], *,
                polish_evals: int) -> ModelFit | None:
    """The model parameters of the effect fits, tried in the base model (one kernel call); the best,
    when better than the base fit, polished. None when none is better."""
    p = views.problem((), base.fixed)
    space = SearchSpace(p)
    params = base.params
    X = np.array([space.vector({**params, **{n: c[n] for n in space.names if n in c}}) for c in candidates])
    m = p.mean_objective(X)
    i = int(np.argmin(m))
    if not m[i] < base.mse * (1.0 - 1e-4):
        return None
    res = polish(p, X[i], budget=polish_evals)
    f = mean(p, res)
    if not f < base.mse:
        return None
    return replace(base, fit=res, mse=f, checks=None, evaluations=base.evaluations + res.nfev + len(candidates))
