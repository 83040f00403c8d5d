"""Identify a unit's AVR parameters from captures and assemble the result JSON (docs/formats.md).

`run_identification` binds the captures and unit into a `Problem`, warms the kernel up (its
compile / cache-load time is reported as `compile_s`, outside `wall_s`), runs the chosen
optimizer and any others asked for comparison through `peers.run_optimizer`, analyses what the
captures determine at the optimum (`identifiability.analyse`) and returns everything;
`identify` returns only the result (`result_file.IdentificationResult`, "bench-ctl/result/1").
"""
from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

import bench_ctl
from bench_ctl import engine
from bench_ctl.capture import Capture, capture_sha256
from bench_ctl.engine import optimisation_note
from bench_ctl.engine.simulate import param_matrix
from bench_ctl.model.params import GENERATOR_OPTIONAL, RECORD_PARAMS
from bench_ctl.outputs import path_from
from bench_ctl.records import plain
from bench_ctl.signals.edges import Edge
from bench_ctl.timestamps import utc_now_text
from bench_ctl.units.unit import Unit
from bench_ctl.units.unit import outside_bounds as values_outside_bounds

from .construction import make_problem
from .identifiability import analyse, not_analysed
from .peers import OPTIMIZERS, Progress, run_optimizer
from .problem import Problem
from .result import Result
from .result_file import (
    RESULT_SCHEMA,
    CaptureEntry,
    Comparison,
    ConstraintEntry,
    Identifiability,
    IdentificationResult,
    ModelEntry,
    OptimizerEntry,
    written,
)

logger = logging.getLogger(__name__)

__all__ = ["Identification", "identify", "run_identification", "warm_up", "RESULT_SCHEMA"]

@dataclass(frozen=True, eq=False)
class Identification:
    """Everything one identification produced: the result and the objects behind it."""
    result: IdentificationResult
    problem: Problem
    best: Result
    runs: tuple[Result, ...]  # every optimizer run, the chosen one first

    @property
    def ok(self) -> bool:
        """The fit succeeded, satisfies every constraint and lies inside the bounds (exit code 0
        of the CLI; the `local` peer ignores bounds by design)."""
        return self.best.success and not self.result.constraints_violated and not self.outside_bounds

    @property
    def outside_bounds(self) -> list[str]:
        """'NAME = value [lo, hi]' for each identified value beyond its bounds."""
        return values_outside_bounds(self.result.params, self.result.bounds)


_warned = False


def warm_up(unit: Unit, problem: Problem | None = None) -> float:
    """Compile (or load from the cache) the engine's variant `problem`'s records run (or the
    unit's at no load), before a fit is timed; seconds (microseconds once this process has it).
    Warns (once a process) when numba runs without the optimisation the engine needs."""
    global _warned
    note = optimisation_note()
    if note and not _warned:
        logger.warning(note)
        _warned = True
    t0 = time.perf_counter()
    if problem is not None:
        problem.objective(problem.x_start()[None])
    else:
        engine.run(param_matrix(unit.values()), np.array([1.0, 1.0, 1.05, 1.05]), 1e-3, 1.0,
                   measured={"efd": np.ones(4)}, store=False)
    return time.perf_counter() - t0


def _none_if_inf(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def _capture_entry(c: Capture, mse: float, obj: float, weight: float, edges: list[Edge]) -> CaptureEntry:
    return CaptureEntry(path=c.source, sha256=capture_sha256(c.source), n=int(c.n), rate_hz=float(c.rate_hz),
                        meta=plain(dict(c.meta)), mse=_none_if_inf(mse), objective=_none_if_inf(obj),
                        weight=float(weight), edges=tuple(edges))


def result_for_file(result: IdentificationResult, result_path: str | os.PathLike[str]) -> IdentificationResult:
    """`result` as written to `result_path`: each capture path relative to the result file's
    folder (issue 24 item 14), so the result still finds its captures from any working directory
    and when the folder is moved as a whole. A path with no relative form (another drive) stays
    absolute; a capture held in memory (no path) stays so."""
    return replace(result, captures=tuple(replace(c, path=path_from(result_path, c.path)) if c.path else c
                                          for c in result.captures))


def _model_only(ident: Identifiability) -> Identifiability:
    """The identifiability block over the model parameters: the edge offsets were analysed with
    them (their std goes to `edges`) but are the record's timing, not parameters of the unit."""
    names = list(ident.names)
    keep = [i for i, n in enumerate(names) if n not in RECORD_PARAMS]
    if len(keep) == len(names):
        return ident

    def model(table: dict) -> dict:
        return {n: v for n, v in table.items() if n not in RECORD_PARAMS}
    corr = ident.correlation
    return replace(
        ident, names=[names[i] for i in keep], sensitivity=model(ident.sensitivity), std=model(ident.std),
        rel_std=model(ident.rel_std), determined=model(ident.determined),
        reasons=None if ident.reasons is None else model(ident.reasons),
        correlation=[[corr[i][j] for j in keep] for i in keep] if len(corr) == len(names) else corr,
        equivalent_sets=tuple(replace(e, params=model(e.params)) for e in ident.equivalent_sets))


def _run_summary(problem: Problem, r: Result) -> Comparison:
    mses = problem.mse(r.x)
    return Comparison(optimizer=r.method, mse=_none_if_inf(float(np.mean(mses))), objective=_none_if_inf(r.fun),
                      evaluations=int(r.nfev), wall_s=r.wall_s, constraints_violated=list(r.violated),
                      params=problem.model_params(r.x), failed=not r.success, message=r.message)


def run_identification(*args: Any, **kwargs: Any) -> Identification:
    """`_run_identification` with BLAS on one thread: the least-squares steps' dot products then
    sum in one order, so a capture gives the same result alone, in a batch worker (where Dask
    sets one BLAS thread) or on a machine with more cores (docs/decisions/0008, appendix)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return _run_identification(*args, **kwargs)


def model_entry(unit: Unit, kernel_values: Mapping[str, float], identified: Sequence[str],
                determined: Mapping[str, bool]) -> ModelEntry:
    """The result's `model`: the structure, its parameters under their standard names (fitted
    values where identified), which ones were identified and which the captures determined (in
    the kernel's names, as the rest of the result, until its writer renames it:
    `IdentificationResult.renamed`)."""
    st = unit.structure
    values = st.std_values(kernel_values, unit.model_values)
    return ModelEntry(
        name=st.name,
        title=st.title,
        dyr_model=st.dyr_model,
        params={k: _none_if_inf(float(v)) for k, v in values.items()},
        units={p.name: p.unit for p in st.params},
        identified=[n for n in identified if n not in RECORD_PARAMS],
        determined={n: bool(v) for n, v in determined.items() if n not in RECORD_PARAMS},
        simulated=[p.name for p in st.params if p.kernel is not None],
        generator={k: _none_if_inf(float(kernel_values[k])) for k in ("Td0p", "Td0pp", "Vt0", *GENERATOR_OPTIONAL)
                   if k in kernel_values},
    )


def _run_identification(captures: Sequence[Capture], unit: Unit, *, optimizer: str = "mvmo",
                       compare: Sequence[str] = (), max_evals: int = 1000, seed: int | None = 0,
                       x0: Sequence[float] | None = None, progress: Progress | None = None,
                       command_line: str = "", options: Mapping[str, Any] | None = None,
                       problem: Problem | None = None,
                       progress_factory: Any = None) -> Identification:
    """Identify `unit` from `captures` with `optimizer`; run `compare` methods on the same problem.

    problem: a ready `Problem` (else `make_problem(captures, unit)`); options: settings of the
    chosen optimizer (e.g. MVMO options). progress(nfev, best) is called during every run;
    progress_factory(name) -> progress callable, when given, makes one per optimizer run.
    """
    if optimizer not in OPTIMIZERS:
        raise ValueError(f"unknown optimizer {optimizer!r}; choose one of {', '.join(OPTIMIZERS)}")
    for name in compare:
        if name not in OPTIMIZERS:
            raise ValueError(f"unknown optimizer {name!r}; choose one of {', '.join(OPTIMIZERS)}")
    prob = problem if problem is not None else make_problem(captures, unit)
    compile_s = warm_up(prob.unit, prob)
    names = [optimizer] + [n for n in dict.fromkeys(compare) if n != optimizer]
    runs = []
    for name in names:
        cb = progress_factory(name) if progress_factory is not None else progress
        runs.append(run_optimizer(name, prob, max_evals=max_evals, seed=seed, x0=x0, progress=cb,
                                  options=options if name == optimizer else None))
    best = runs[0]
    x = best.x
    mses = prob.mse(x)
    objs = prob.capture_objectives(x)
    try:
        ident = analyse(prob, x) if best.success else None
    except (ValueError, np.linalg.LinAlgError) as exc:
        logger.warning("identifiability analysis failed: %s", exc)
        ident = None
    if ident is None:
        ident = not_analysed(prob.names)
    fixed = {k: _none_if_inf(v) for k, v in prob.base.items()
             if k not in prob.names and k not in RECORD_PARAMS and k not in prob.grid_names}
    # [grid] values fitted on line go to the unit's [grid], not among the model's parameters
    params = prob.model_params(x)
    unit_entry = prob.unit.entry()
    unit_entry = replace(unit_entry, grid={**(unit_entry.grid or {}), **{k: params.pop(k) for k in prob.grid_names}})
    edges = prob.edges(x, ident.std)
    ident = _model_only(ident)
    result = IdentificationResult(
        schema=RESULT_SCHEMA,
        software_version=bench_ctl.__version__,
        command_line=command_line,
        created_utc=utc_now_text(),
        unit=unit_entry,
        captures=tuple(_capture_entry(c, m, o, w, e) for c, m, o, w, e
                       in zip(prob.captures, mses, objs, prob.weights, edges)),
        params=params,
        fixed=fixed,
        bounds={n: [lo, hi] for n, (lo, hi) in zip(prob.names, prob.bounds)
                if n not in RECORD_PARAMS and n not in prob.grid_names},
        edges=tuple(replace(e, capture=i) for i, es in enumerate(edges) for e in es),
        constraints=tuple(ConstraintEntry(**c) for c in prob.constraint_report(x)),
        objective=_none_if_inf(best.fun),
        mse=_none_if_inf(float(np.mean(mses))),
        evaluations=int(best.nfev),
        wall_s=best.wall_s,
        compile_s=compile_s,
        optimizer=OptimizerEntry(name=best.method, settings=plain(dict(best.settings)), seed=seed),
        history=[[n, _none_if_inf(v)] for n, v in best.history],
        identifiability=ident,
        fit_window=list(prob.window) if prob.window is not None else None,
        failed=not best.success,
        message=best.message,
        model=model_entry(prob.unit, {**prob.base, **params}, prob.names, ident.determined),
        comparison=tuple(_run_summary(prob, r) for r in runs) if len(runs) > 1 else None,
    )
    # the boundary: the structure's names
    return Identification(result=written(result, prob.unit.structure), problem=prob, best=best, runs=tuple(runs))


def identify(captures: Sequence[Capture], unit: Unit, *, optimizer: str = "mvmo",
             max_evals: int = 1000, seed: int | None = 0, x0: Sequence[float] | None = None,
             progress: Progress | None = None, command_line: str = "",
             compare: Sequence[str] = (), options: Mapping[str, Any] | None = None) -> IdentificationResult:
    """The result ("bench-ctl/result/1") of identifying `unit` from `captures`."""
    return run_identification(captures, unit, optimizer=optimizer, compare=compare,
                              max_evals=max_evals, seed=seed, x0=x0, progress=progress,
                              command_line=command_line, options=options).result
