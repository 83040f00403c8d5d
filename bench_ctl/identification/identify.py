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
from pathlib import Path
from typing import Any

import numpy as np

import bench_ctl
from bench_ctl import engine
from bench_ctl.capture import Capture
from bench_ctl.engine import optimisation_note
from bench_ctl.engine.simulate import param_matrix
from bench_ctl.limits import sha256_file
from bench_ctl.model.dialect import result_to_std
from bench_ctl.model.params import GENERATOR_OPTIONAL, RECORD_PARAMS
from bench_ctl.records import plain
from bench_ctl.timestamps import utc_now_text
from bench_ctl.units.unit import Unit
from bench_ctl.units.unit import outside_bounds as values_outside_bounds

from .identifiability import analyse
from .peers import OPTIMIZERS, Progress, run_optimizer
from .problem import Problem, make_problem
from .result import Result
from .result_file import RESULT_SCHEMA, IdentificationResult

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


def _capture_entry(c: Capture, mse: float, obj: float, weight: float,
                   edges: list[dict[str, Any]]) -> dict[str, Any]:
    sha = c.meta.get("csv_sha256") if isinstance(c.meta, Mapping) else None
    if sha is None and c.source and Path(c.source).is_file():
        sha = sha256_file(c.source)
    return {"path": c.source, "sha256": sha, "n": int(c.n), "rate_hz": float(c.rate_hz),
            "meta": dict(c.meta), "mse": _none_if_inf(mse), "objective": _none_if_inf(obj),
            "weight": float(weight), "edges": edges}


def result_for_file(result: IdentificationResult, result_path: str | os.PathLike[str]) -> IdentificationResult:
    """`result` as written to `result_path`: each capture path relative to the result file's
    folder (issue 24 item 14), so the result still finds its captures from any working directory
    and when the folder is moved as a whole. A path with no relative form (another drive) stays
    absolute; a capture held in memory (no path) stays so."""
    folder = Path(os.path.abspath(result_path)).parent
    caps = []
    for c in result.captures:
        if c.path:
            absolute = os.path.abspath(c.path)
            try:
                c = replace(c, path=Path(os.path.relpath(absolute, folder)).as_posix())
            except ValueError:
                c = replace(c, path=absolute)
        caps.append(c)
    return replace(result, captures=tuple(caps))


def _model_only(ident: dict[str, Any]) -> dict[str, Any]:
    """The identifiability block over the model parameters: the edge offsets were analysed with
    them (their std goes to `edges`) but are the record's timing, not parameters of the unit."""
    names = list(ident.get("names", []))
    keep = [i for i, n in enumerate(names) if n not in RECORD_PARAMS]
    if len(keep) == len(names):
        return ident
    out = dict(ident)
    out["names"] = [names[i] for i in keep]
    for key in ("sensitivity", "std", "rel_std", "determined", "reasons"):
        if isinstance(out.get(key), Mapping):
            out[key] = {n: v for n, v in out[key].items() if n not in RECORD_PARAMS}
    corr = out.get("correlation")
    if isinstance(corr, list) and len(corr) == len(names):
        out["correlation"] = [[corr[i][j] for j in keep] for i in keep]
    out["equivalent_sets"] = [{**e, "params": {n: v for n, v in e.get("params", {}).items()
                                               if n not in RECORD_PARAMS}}
                              for e in out.get("equivalent_sets", []) if isinstance(e, Mapping)]
    return out


def _run_summary(problem: Problem, r: Result) -> dict[str, Any]:
    mses = problem.mse(r.x)
    return {"optimizer": r.method, "mse": _none_if_inf(float(np.mean(mses))),
            "objective": _none_if_inf(r.fun), "evaluations": r.nfev, "wall_s": r.wall_s,
            "constraints_violated": list(r.violated), "params": problem.model_params(r.x),
            "failed": not r.success, "message": r.message}


def run_identification(*args: Any, **kwargs: Any) -> Identification:
    """`_run_identification` with BLAS on one thread: the least-squares steps' dot products then
    sum in one order, so a capture gives the same result alone, in a batch worker (where Dask
    sets one BLAS thread) or on a machine with more cores (docs/decisions/0008, appendix)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return _run_identification(*args, **kwargs)


def model_entry(unit: Unit, kernel_values: Mapping[str, float], identified: Sequence[str],
                determined: Mapping[str, bool]) -> dict[str, Any]:
    """The result's `model`: the structure, its parameters under their standard names (fitted
    values where identified), which ones were identified and which the captures determined."""
    st = unit.structure
    values = st.std_values(kernel_values, unit.model_values)
    ident_std = [unit.std_name(n) for n in identified if n not in RECORD_PARAMS]
    return {
        "name": st.name,
        "title": st.title,
        "dyr_model": st.dyr_model,
        "params": {k: _none_if_inf(float(v)) for k, v in values.items()},
        "units": {p.name: p.unit for p in st.params},
        "identified": ident_std,
        "determined": {unit.std_name(n): bool(v) for n, v in determined.items() if n not in RECORD_PARAMS},
        "simulated": [p.name for p in st.params if p.kernel is not None],
        "generator": {k: _none_if_inf(float(kernel_values[k])) for k in ("Td0p", "Td0pp", "Vt0", *GENERATOR_OPTIONAL)
                      if k in kernel_values},
    }


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
        ident = {"names": list(prob.names), "sensitivity": {}, "std": {}, "rel_std": {},
                 "correlation": [], "determined": {n: False for n in prob.names},
                 "equivalent_sets": [], "notes": ["not analysed: the fit failed"]}
    fixed = {k: _none_if_inf(v) for k, v in prob.base.items()
             if k not in prob.names and k not in RECORD_PARAMS and k not in prob.grid_names}
    # [grid] values fitted on line go to the unit's [grid], not among the model's parameters
    params = prob.model_params(x)
    unit_entry = prob.unit.to_dict()
    unit_entry["grid"].update({k: params.pop(k) for k in prob.grid_names})
    edges = prob.edges(x, ident.get("std"))
    ident = _model_only(ident)
    result: dict[str, Any] = {
        "schema": RESULT_SCHEMA,
        "software_version": bench_ctl.__version__,
        "command_line": command_line,
        "created_utc": utc_now_text(),
        "unit": unit_entry,
        "captures": [_capture_entry(c, m, o, w, e) for c, m, o, w, e
                     in zip(prob.captures, mses, objs, prob.weights, edges)],
        "params": params,
        "fixed": fixed,
        "bounds": {n: [lo, hi] for n, (lo, hi) in zip(prob.names, prob.bounds)
                   if n not in RECORD_PARAMS and n not in prob.grid_names},
        "edges": [{"capture": i, **e} for i, es in enumerate(edges) for e in es],
        "constraints": prob.constraint_report(x),
        "objective": _none_if_inf(best.fun),
        "mse": _none_if_inf(float(np.mean(mses))),
        "evaluations": best.nfev,
        "wall_s": best.wall_s,
        "compile_s": compile_s,
        "optimizer": {"name": best.method, "settings": dict(best.settings), "seed": seed},
        "history": [[n, _none_if_inf(v)] for n, v in best.history],
        "identifiability": ident,
        "fit_window": list(prob.window) if prob.window is not None else None,
        "failed": not best.success,
        "message": best.message,
    }
    result["model"] = model_entry(prob.unit, {**prob.base, **result["params"]}, prob.names,
                                  ident.get("determined") or {})
    if len(runs) > 1:
        result["comparison"] = [_run_summary(prob, r) for r in runs]
    result = result_to_std(prob.unit.structure, result)   # the boundary: the structure's names
    return Identification(result=IdentificationResult.from_json(plain(result), "the identification result"),
                          problem=prob, best=best, runs=tuple(runs))


def identify(captures: Sequence[Capture], unit: Unit, *, optimizer: str = "mvmo",
             max_evals: int = 1000, seed: int | None = 0, x0: Sequence[float] | None = None,
             progress: Progress | None = None, command_line: str = "",
             compare: Sequence[str] = (), options: Mapping[str, Any] | None = None) -> IdentificationResult:
    """The result ("bench-ctl/result/1") of identifying `unit` from `captures`."""
    return run_identification(captures, unit, optimizer=optimizer, compare=compare,
                              max_evals=max_evals, seed=seed, x0=x0, progress=progress,
                              command_line=command_line, options=options).result
