"""The identification problem: captures + unit -> the paper's objective over named parameters.

A `Problem` (built by `construction.make_problem`) binds one or several captures to a unit and a
list of parameter names to fit, and evaluates a whole population with ONE engine call per capture:

    OF(x) = sum_k alpha_k * integral sum_n w_n (y_n(x) - y_n,meas)^2 dt   (trapezoidal rule)

over captures k and signals n (efd with the unit's efd weight; vt when the capture has it and
its weight is > 0; Q of an on-line record, weight `q`, default 1; the stabiliser's output vs of an
on-line record that recorded it, weight `vs`, default `units.unit.VS_WEIGHT`),
docs/identification.md.

A capture with P and Q channels is an on-line record: it runs on the machine on the grid
(`bench_ctl.engine.machines.grid`, the unit's [grid] data) from the record's own pre-step P, Q and Vt.

Candidates the engine marks failed (unstable or invalid parameters) get a penalty larger than
any objective a finite simulation can produce, and larger the earlier they fail, so every
candidate stays rankable.

A fit window restricts the objective and the MSE to part of each record; the simulation always
starts at the record's first sample (initial steady state) and stops at the window's end. A
record can be decimated (`Problem.decimated`: every q-th sample, integrated at the coarser step,
the cheap copy the diagnosis searches on). Without a window the fast path runs the engine with
`store=False`; with one the traces are kept and the error is summed in numpy. Beside the
objective, the scores the diagnosis ranks models by (`mean_objective`, `mean_objective_of`,
`mse` of efd or vt). How the engine runs a batch (threads, vector width) is the engine's: a
`Problem` only asks it for a simulation (`engine.run`).
"""
from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np

from bench_ctl import engine
from bench_ctl.capture import Capture
from bench_ctl.engine.derived import saturation_ab
from bench_ctl.engine.machines.grid import steady_field
from bench_ctl.engine.simulate import base_row, param_matrix
from bench_ctl.model.dialect import Note
from bench_ctl.model.params import COL, KERNEL_PARAMS
from bench_ctl.units.unit import Unit

from .constraints import LinearConstraint
from .fit_record import FitRecord, ProblemError, apply_window, decimated
from .timing import EDGE_PARAMS, edges_entry

logger = logging.getLogger(__name__)

__all__ = ["Problem", "ProblemError"]


@dataclass(frozen=True, eq=False)
class Problem:
    """A bound identification problem; build it with `make_problem`.

    Attributes: `names` (fitted parameters, the order of x), `bounds` [(lo, hi)], `constraints`
    (LinearConstraint over `names`, for the optimizers), `fixed_constraints` (constraints left
    without a fitted parameter: (text, satisfied)), `weights` (alpha_k per capture), `w_efd`,
    `w_vt`, `base` (every kernel parameter value before x is applied), `usetp_pre` per capture,
    `captures`, `unit`, `window` ((t0, t1) or None).
    """

    captures: tuple[Capture, ...]
    unit: Unit
    names: tuple[str, ...]
    bounds: tuple[tuple[float, float], ...]
    constraints: tuple[LinearConstraint, ...]
    constraint_texts: tuple[str, ...]
    fixed_constraints: tuple[tuple[str, bool], ...]
    weights: tuple[float, ...]
    w_efd: float
    w_vt: float
    base: dict[str, float]
    records: tuple[FitRecord, ...] = field(repr=False)
    window: tuple[float, float] | None = None
    penalty_base: float = 1.0e20
    w_q: float = 0.0
    #: the trailing names that are [grid] values fitted on the on-line records (`Unit.grid_identify`)
    grid_names: tuple[str, ...] = ()
    #: the weight of the stabiliser's output, on the records that have one (`FitRecord.vs`)
    w_vs: float = 0.0

    # ------------------------------------------------------------------ basics
    @property
    def d(self) -> int:
        return len(self.names)

    @property
    def usetp_pre(self) -> tuple[float, ...]:
        return tuple(r.usetp_pre for r in self.records)

    @property
    def lower(self) -> np.ndarray:
        return np.array([b[0] for b in self.bounds])

    @property
    def upper(self) -> np.ndarray:
        return np.array([b[1] for b in self.bounds])

    def x_start(self) -> np.ndarray:
        """The start point from the unit: its `value` of each fitted name (else its base value,
        clipped into the bounds when it is not finite, e.g. VRMAX = inf)."""
        x = np.array([self.unit.identify[n].value if n in self.unit.identify else self.base[n]
                      for n in self.names], dtype=float)
        lo, hi = self.lower, self.upper
        bad = ~np.isfinite(x)
        x[bad] = np.where(x[bad] > 0, hi[bad], lo[bad])
        return x

    def values(self, x: Sequence[float]) -> dict[str, float]:
        """Every kernel parameter value with `x` applied to `names`."""
        x = np.asarray(x, dtype=float).reshape(-1)
        if x.size != self.d:
            raise ProblemError(Note(f"x has {x.size} values for {self.d} names {{}}", str(list(self.names))))
        out = dict(self.base)
        out.update({n: float(v) for n, v in zip(self.names, x)})
        return out

    def params(self, x: Sequence[float]) -> dict[str, float]:
        """The fitted parameters as a name -> value dict."""
        return {n: float(v) for n, v in zip(self.names, np.asarray(x, dtype=float).reshape(-1))}

    def model_params(self, x: Sequence[float]) -> dict[str, float]:
        """The fitted model parameters (without the record's edge offsets)."""
        return {n: v for n, v in self.params(x).items() if n not in EDGE_PARAMS}

    def edges(self, x: Sequence[float], std: dict[str, Any] | None = None) -> list[list[dict[str, Any]]]:
        """Per capture, its setpoint edges with the fitted instants at x (`timing.edges_entry`)."""
        values = self.params(x)
        return [edges_entry(r.edge_list, r.edge_slots, values, std) for r in self.records]

    def matrix(self, X: np.ndarray) -> np.ndarray:
        """Kernel parameter matrix of a population X (n, d); with fitted [grid] values, their
        columns follow the kernel's (`_simulate` puts them into the machine)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        if not self.grid_names:
            return param_matrix(self.base, self.names, X, row=self._base_row)
        k = len(self.names) - len(self.grid_names)
        return np.hstack([param_matrix(self.base, self.names[:k], X[:, :k], row=self._base_row), X[:, k:]])

    @cached_property
    def _base_row(self) -> np.ndarray:
        """`base` as a kernel parameter row, built once (`matrix` runs on every evaluation)."""
        return base_row(self.base)

    def held(self, values: dict[str, float]) -> Problem:
        """The same problem with the parameters in `values` no longer fitted but held there (they
        must not appear in a constraint with a fitted parameter)."""
        keep = [i for i, n in enumerate(self.names) if n not in values]
        drop = [i for i, n in enumerate(self.names) if n in values]
        for c in self.constraints:
            if np.any(c.coef[drop] != 0.0):
                raise ProblemError(Note("cannot hold {}: constraint {!r} links them", str(sorted(values)), c.expr))
        names = tuple(self.names[i] for i in keep)
        cons = tuple(LinearConstraint(expr=c.expr, coef=c.coef[keep], rhs=c.rhs, names=names)
                     for c in self.constraints)
        return replace(self, names=names, bounds=tuple(self.bounds[i] for i in keep), constraints=cons,
                       base={**self.base, **{k: float(v) for k, v in values.items()}})

    def with_window(self, window: tuple[float, float] | None) -> Problem:
        """The same problem with its objective and MSE over another time window (None = all)."""
        return replace(self, window=window, records=tuple(
            apply_window(r, window, c) for r, c in zip(self.records, self.captures)))

    def decimated(self, q: int, *, n_max: int | None = None, offset: int = 0) -> Problem:
        """Every q-th sample of each record from `offset` (give the leading edge's index so that it
        stays on the coarse grid), up to sample n_max: the kernel integrates at q times the step.
        The edges keep their nominal instants, so the EDGE offsets mean the same on both grids."""
        return replace(self, records=tuple(decimated(r, int(q), n_max, int(offset)) for r in self.records))

    def n_scored(self) -> list[float]:
        """Per capture, how many samples the objective and the MSE count."""
        return [r.n_scored for r in self.records]

    # ------------------------------------------------------------------ constraints
    def violations(self, x: Sequence[float]) -> dict[str, float]:
        """Violation (>= 0, original units) of each optimizer constraint at x."""
        xa = np.asarray(x, dtype=float).reshape(-1)
        return {c.expr: c.violation(xa) for c in self.constraints}

    def constraint_report(self, x: Sequence[float], tol: float = 1e-9) -> list[dict[str, Any]]:
        """[{expr, satisfied, margin}] for every constraint of the unit (margin >= 0 = slack)."""
        xa = np.asarray(x, dtype=float).reshape(-1)
        out = [{"expr": c.expr, "satisfied": bool(c.violation(xa) <= tol),
                "margin": float(c.rhs - c.coef @ xa)} for c in self.constraints]
        out += [{"expr": t, "satisfied": bool(ok), "margin": None} for t, ok in self.fixed_constraints]
        return out

    def violated(self, x: Sequence[float], tol: float = 1e-9) -> list[str]:
        return [c["expr"] for c in self.constraint_report(x, tol) if not c["satisfied"]]

    # ------------------------------------------------------------------ evaluation
    def objective(self, X: np.ndarray) -> np.ndarray:
        """The paper's OF for a population X (n, d) -> (n,); failed candidates get `penalty`."""
        return self._total(self.matrix(X))

    def penalty(self, fail_frac: np.ndarray) -> np.ndarray:
        """The objective of a candidate that failed to simulate: above any objective a finite
        simulation can produce, and higher the earlier it failed (`fail_frac`: the share of the
        records lost, summed over the captures), so that every candidate stays rankable. The one
        penalty of every fit (search, polish, diagnosis)."""
        return self.penalty_base * (1.0 + np.asarray(fail_frac, dtype=float))

    @property
    def scored_s(self) -> float:
        """Seconds of record the objective integrates (alpha-weighted over the captures, half a
        step at each window's end): a constant efd error e at weight 1 gives an objective of
        e**2 times this."""
        return float(sum(r.alpha * r.scored_s for r in self.records))

    def mean_objective(self, X: np.ndarray) -> np.ndarray:
        """The objective per second of scored record: with the default weights (efd 1, vt 0) the
        trapezoidal mean squared efd error, the figure the diagnosis ranks models by and compares
        with the noise floor."""
        return self.objective(X) / self.scored_s

    def mean_objective_of(self, values: Sequence[Mapping[str, float]]) -> np.ndarray:
        """`mean_objective` of whole parameter sets, each a name -> value map over `base` that may
        also set parameters this problem does not fit (the diagnosis scores the start points of
        every effect on the base model's problem this way, in one kernel call)."""
        P = np.vstack([param_matrix({**self.base, **{k: float(v) for k, v in row.items()}}) for row in values])
        return self._total(P) / self.scored_s

    def _total(self, P: np.ndarray) -> np.ndarray:
        parts, fail_frac = self._objective_parts(P)
        total = parts.sum(axis=0)
        bad = fail_frac > 0
        if bad.any():
            total = np.where(bad, self.penalty(fail_frac), total)
        return total

    def capture_objectives(self, x: Sequence[float]) -> list[float]:
        """alpha_k * integral of the weighted squared error, per capture (inf when it failed)."""
        P = self.matrix(np.asarray(x, dtype=float).reshape(1, -1))
        parts, _ = self._objective_parts(P, per_capture_fail=True)
        return [float(v) for v in parts[:, 0]]

    def _objective_parts(self, P: np.ndarray, per_capture_fail: bool = False
                         ) -> tuple[np.ndarray, np.ndarray]:
        n = P.shape[0]
        parts = np.zeros((len(self.records), n))
        fail_frac = np.zeros(n)  # sum over captures of the share of the record lost to a failure
        for k, r in enumerate(self.records):
            if r.full:
                out = _simulate(P, r, measured=True, w_efd=self.w_efd, w_vt=self.w_vt, w_q=self.w_q, w_vs=self.w_vs)
                obj = out["obj"]
            else:
                out, res = self._window_residuals(P, r)
                obj = np.einsum("ij,ij->i", res, res)
            failed = out["fail_step"] >= 0
            parts[k] = r.alpha * obj
            if per_capture_fail:
                parts[k] = np.where(failed, np.inf, parts[k])
            fail_frac += _lost(out["fail_step"], r)
        return parts, fail_frac

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return self.objective(X)

    def simulate(self, x: Sequence[float]) -> list[dict[str, Any]]:
        """Full-record traces per capture: [{efd, vt, fail_step}] (efd as recorded; an on-line
        record's p, q, vs, ifd too)."""
        return [{name: o[name][0] for name in ("efd", "vt", "p", "q", "vs", "ifd") if name in o}
                | {"fail_step": int(o["fail_step"][0])} for o in self._runs(np.reshape(x, (1, -1)))]

    def efd_traces(self, X: np.ndarray) -> list[np.ndarray]:
        """Per capture, the efd (as recorded) of every row of X over the full record: (n, T),
        in one kernel call a capture."""
        return [np.asarray(o["efd"]) for o in self._runs(X)]

    def _runs(self, X: np.ndarray) -> list[dict]:
        """Per capture, the kernel's (or the on-line machine's) full-record run of the rows of X."""
        P = self.matrix(np.atleast_2d(np.asarray(X, dtype=float)))
        return [_simulate(P, r) for r in self.records]

    def steady_efd(self, x: Sequence[float]) -> float:
        """The model's steady-state field voltage at x (pu): at no load Vt0 + Sat(Vt0); for an
        on-line first record the machine's at that record's P, Q and Vt (`online.derive_machine`)."""
        r = self.records[0]
        if r.machine is not None:
            P, M = _on_line_inputs(self.matrix(np.asarray(x, float)[None]), r)
            return float(steady_field(P, M)[0])
        v = self.values(x)
        a, b = saturation_ab(v["S10"], v["S12"])
        vt0 = v["Vt0"]
        return vt0 + (b * (vt0 - a) ** 2 if vt0 > a else 0.0)

    def mse(self, x: Sequence[float], signal: str = "efd") -> list[float]:
        """Per capture, mean squared sample error of `signal` (efd, vt, q or vs, whatever its weight)
        over the window (inf when the run failed, nan when the capture lacks the signal)."""
        return [float(v) for v in self.mse_many(np.asarray(x, dtype=float).reshape(1, -1), signal)[:, 0]]

    def mse_many(self, X: np.ndarray, signal: str = "efd") -> np.ndarray:
        """Per-capture MSE of `signal` for a population: shape (n_captures, n)."""
        if signal not in _SCORED:
            raise ValueError(f"signal {signal!r}: choose 'efd', 'vt', 'q' or 'vs'")
        P = self.matrix(X)
        rows = []
        for r in self.records:
            meas = _measured(r)[signal]
            if meas is None:
                rows.append(np.full(P.shape[0], np.nan))
                continue
            if r.full:
                out = _simulate(P, r, measured=True, **{f"w_{s}": float(s == signal) for s in _SCORED})
                m = out["sse_" + signal] / meas.size
            else:
                out = _simulate(P, r, r.i1)
                e = out[signal][:, r.i0: r.i1] - meas[r.i0: r.i1]
                m = np.mean(e * e, axis=1)
            rows.append(np.where(out["fail_step"] >= 0, np.inf, m))
        return np.array(rows)

    def residuals(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted residual vectors of a population whose squared sum is the objective.

        Returns (R (n, m), failed (n,) bool). Sample j of capture k, signal s enters as
        sqrt(alpha_k w_s c_j dt) (y - y_meas), c_j = 1/2 at the window's ends (trapezoid).
        Only efd and (when recorded and weighted) vt, Q and vs are included, in that order, capture
        by capture (`signals`).
        """
        R, f = self.residuals_and_objective(X)
        return R, f >= self.penalty_base

    def residuals_and_objective(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`residuals` and the objective they give (their squared sum; `penalty` for a failed
        candidate, whose residuals are those of its held outputs) - what the polish works on."""
        P = self.matrix(X)
        parts, fail_frac = [], np.zeros(P.shape[0])
        for r in self.records:
            out, res = self._window_residuals(P, r)
            parts.append(np.sqrt(r.alpha) * res)
            fail_frac += _lost(out["fail_step"], r)
        R = np.hstack(parts)
        f = np.einsum("ij,ij->i", R, R)
        return R, np.where(fail_frac > 0, self.penalty(fail_frac), f)

    def signals(self, r: FitRecord) -> list[str]:
        """The signals of record r in the residual vector, in order: efd, then vt, Q and vs when
        recorded and weighted."""
        return ["efd"] + (["vt"] if r.vt is not None and self.w_vt > 0 else []) \
            + (["q"] if r.q is not None and self.w_q > 0 else []) \
            + (["vs"] if r.vs is not None and self.w_vs > 0 else [])

    def residual_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For each entry of the `residuals` vector: its capture, its instant (s from the record's
        first sample) and the seconds of record it stands for (alpha c_j dt on a sample's efd
        row, 0 on its vt row), so that the squared residuals of any set of samples over their
        seconds are that set's `mean_objective`."""
        caps, times, secs = [], [], []
        for k, r in enumerate(self.records):
            n = r.i1 - r.i0
            c = np.ones(n)
            c[0] = c[-1] = 0.5
            t = (r.i0 + np.arange(n)) * r.dt
            sec = r.alpha * c * r.dt
            signals = len(self.signals(r))
            caps.append(np.full(n * signals, k))
            times.append(np.tile(t, signals))
            secs.append(np.concatenate([sec] + [np.zeros(n)] * (signals - 1)))
        return np.concatenate(caps), np.concatenate(times), np.concatenate(secs)

    def _window_residuals(self, P: np.ndarray, r: FitRecord) -> tuple[dict, np.ndarray]:
        out = _simulate(P, r, r.i1)
        c = np.ones(r.i1 - r.i0)
        c[0] = c[-1] = 0.5
        scale = np.sqrt(c * r.dt)
        weight = {"efd": self.w_efd, "vt": self.w_vt, "q": self.w_q, "vs": self.w_vs}
        meas = _measured(r)
        res = [math.sqrt(weight[s]) * scale * (out[s][:, r.i0: r.i1] - meas[s][r.i0: r.i1]) for s in self.signals(r)]
        return out, np.hstack(res)


def _lost(fail_step: np.ndarray, r: FitRecord) -> np.ndarray:
    """The share of the record each candidate lost to a failure (0 when it did not fail)."""
    if fail_step.size == 0 or fail_step.max() < 0:  # (most calls: none failed)
        return np.zeros(fail_step.shape)
    return np.where(fail_step >= 0, (r.i1 - np.minimum(fail_step, r.i1 - 1)) / max(1, r.i1), 0.0)


#: the signals an objective scores, in the engine's order
_SCORED = ("efd", "vt", "q", "vs")


def _measured(r: FitRecord) -> dict[str, np.ndarray | None]:
    """The record's scored signals as recorded (None: not recorded)."""
    return {"efd": r.efd, "vt": r.vt, "q": r.q, "vs": r.vs}


def _simulate(P: np.ndarray, r: FitRecord, n: int | None = None, *, measured: bool = False, w_efd: float = 1.0,
              w_vt: float = 0.0, w_q: float = 0.0, w_vs: float = 0.0) -> dict:
    """The candidates P over record r (its first n samples; all: without traces when `measured`,
    with the weighted errors of the signals it has): the engine at no load, or for an on-line
    record on the grid from the record's operating point."""
    n = r.usetp.size if n is None else int(n)
    machine = None
    if r.machine is not None:
        P, machine = _on_line_inputs(P, r)
    else:
        P = P[:, :len(KERNEL_PARAMS)]
    meas = _measured(r) if measured else None
    return engine.run(P, r.usetp[:n], r.dt, r.usetp_pre, machine=machine, measured=meas,
                      weights={"efd": w_efd, "vt": w_vt, "q": w_q, "vs": w_vs}, store=not measured,
                      edges=r.edges_upto(n))


def _on_line_inputs(P: np.ndarray, r: FitRecord) -> tuple[np.ndarray, np.ndarray]:
    """The kernel matrix (Vt0 the record's) and the machine matrix (fitted [grid] values in their
    columns) of the candidates P (`Problem.matrix`) on the on-line record r."""
    grid = P[:, len(KERNEL_PARAMS):]
    P = P[:, :len(KERNEL_PARAMS)].copy()
    P[:, COL["Vt0"]] = r.vt0
    M = np.repeat(r.machine[None, :], P.shape[0], axis=0)
    if grid.shape[1]:
        M[:, list(r.grid_cols)] = grid
    return P, M
