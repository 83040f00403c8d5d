"""The identification problem: captures + unit -> the paper's objective over named parameters.

`make_problem` binds one or several captures to a unit and a list of parameter names to fit
(default: the unit's identified parameters; effect parameters such as VRMAX, TD may be added, so
the diagnosis can fit "reference model + effect"). The resulting `Problem` evaluates a whole
population with ONE kernel call per capture:

    OF(x) = sum_k alpha_k * integral sum_n w_n (y_n(x) - y_n,meas)^2 dt   (trapezoidal rule)

over captures k and signals n (efd with the unit's efd weight; vt when the capture has it and
its weight is > 0; Q of an on-line record, weight `q`, default 1), docs/identification.md.

A capture with P and Q channels is an on-line record: it runs on the machine on the grid
(`bench_ctl.engine.machines.grid`, the unit's [grid] data) from the record's own pre-step P, Q and Vt.

Candidates the kernel marks failed (unstable or invalid parameters) get a penalty larger than
any objective a finite simulation can produce, and larger the earlier they fail, so every
candidate stays rankable.

A fit window (`fit_window=(t0, t1)` in s, or `segment=slice(i0, i1)` in samples) restricts the
objective and the MSE to part of each record; the simulation always starts at the record's
first sample (initial steady state) and stops at the window's end. A record can be decimated
(`Problem.decimated`: every q-th sample, integrated at the coarser step, the cheap copy the
diagnosis searches on). Without a window the fast path runs the kernel with `store=False`; with
one the traces are kept and the error is summed in numpy. Beside the objective, the scores the
diagnosis ranks models by (`mean_objective`, `mean_objective_of`, `mse` of efd or vt).

Constraints are read from the unit's text (and those of any effect whose parameters are fitted)
over all kernel parameters, then reduced to the fitted names: a term on a parameter that is not
fitted becomes a constant. A constraint with no fitted parameter left is not handed to the
optimizer but still checked and reported (`fixed_constraints`).
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
from bench_ctl.engine.layout import BLOWUP
from bench_ctl.engine.machines.grid import machine_data, machine_matrix, steady_field, unit_machine
from bench_ctl.engine.simulate import base_row, operating_point, param_matrix, pre_trigger_mean
from bench_ctl.model.effects import EFFECTS
from bench_ctl.model.params import COL, KERNEL_PARAMS, MCOL, PARAMS
from bench_ctl.signals.edges import EDGE_PARAMS, Edge
from bench_ctl.units.unit import Unit

from .constraints import LinearConstraint, parse_constraints
from .records import ProblemError, Record, apply_window, decimated, segment_window
from .timing import edge_plan_of, edges_entry, record_edges

logger = logging.getLogger(__name__)

__all__ = ["Problem", "ProblemError", "make_problem", "default_bounds"]

#: the largest recorded-efd gain the kernel may apply (recorder_gain upper physical limit)
_MAX_GAIN = PARAMS["GAIN"].hi


def default_bounds(unit: Unit, name: str) -> tuple[float, float]:
    """Search bounds of `name`: the unit's [identify] bounds, else the bounds of its effect."""
    if name in unit.identify:
        b = unit.identify[name]
        return float(b.min), float(b.max)
    for eff in EFFECTS.values():
        if name in eff.bounds:
            lo, hi = eff.bounds[name]
            return float(lo), float(hi)
    raise ProblemError(f"no default bounds for {name!r}: it is neither identified in unit "
                       f"{unit.name!r} nor an effect parameter; pass bounds={{{name!r}: (lo, hi)}}")


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
    records: tuple[Record, ...] = field(repr=False)
    window: tuple[float, float] | None = None
    penalty_base: float = 1.0e20
    w_q: float = 0.0
    #: the trailing names that are [grid] values fitted on the on-line records (`Unit.grid_identify`)
    grid_names: tuple[str, ...] = ()

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
            raise ProblemError(f"x has {x.size} values for {self.d} names {list(self.names)}")
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
                raise ProblemError(f"cannot hold {sorted(values)}: constraint {c.expr!r} links them")
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
                out = _simulate(P, r, measured=True, w_efd=self.w_efd, w_vt=self.w_vt, w_q=self.w_q)
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
        record's p, q, ifd too)."""
        return [{name: o[name][0] for name in ("efd", "vt", "p", "q", "ifd") if name in o}
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
        """Per capture, mean squared sample error of `signal` (efd or vt, whatever its weight)
        over the window (inf when the run failed, nan when the capture lacks the signal)."""
        return [float(v) for v in self.mse_many(np.asarray(x, dtype=float).reshape(1, -1), signal)[:, 0]]

    def mse_many(self, X: np.ndarray, signal: str = "efd") -> np.ndarray:
        """Per-capture MSE of `signal` for a population: shape (n_captures, n)."""
        if signal not in ("efd", "vt", "q"):
            raise ValueError(f"signal {signal!r}: choose 'efd', 'vt' or 'q'")
        P = self.matrix(X)
        rows = []
        for r in self.records:
            meas = {"efd": r.efd, "vt": r.vt, "q": r.q}[signal]
            if meas is None:
                rows.append(np.full(P.shape[0], np.nan))
                continue
            if r.full:
                out = _simulate(P, r, measured=True, **{f"w_{s}": float(s == signal) for s in ("efd", "vt", "q")})
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
        Only efd and (when weighted) vt are included, in that order, capture by capture.
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

    def signals(self, r: Record) -> list[str]:
        """The signals of record r in the residual vector, in order: efd, then vt and Q when
        recorded and weighted."""
        return ["efd"] + (["vt"] if r.vt is not None and self.w_vt > 0 else []) \
            + (["q"] if r.q is not None and self.w_q > 0 else [])

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

    def _window_residuals(self, P: np.ndarray, r: Record) -> tuple[dict, np.ndarray]:
        out = _simulate(P, r, r.i1)
        c = np.ones(r.i1 - r.i0)
        c[0] = c[-1] = 0.5
        scale = np.sqrt(c * r.dt)
        weight = {"efd": self.w_efd, "vt": self.w_vt, "q": self.w_q}
        meas = {"efd": r.efd, "vt": r.vt, "q": r.q}
        res = [math.sqrt(weight[s]) * scale * (out[s][:, r.i0: r.i1] - meas[s][r.i0: r.i1]) for s in self.signals(r)]
        return out, np.hstack(res)


def _lost(fail_step: np.ndarray, r: Record) -> np.ndarray:
    """The share of the record each candidate lost to a failure (0 when it did not fail)."""
    if fail_step.size == 0 or fail_step.max() < 0:  # (most calls: none failed)
        return np.zeros(fail_step.shape)
    return np.where(fail_step >= 0, (r.i1 - np.minimum(fail_step, r.i1 - 1)) / max(1, r.i1), 0.0)


def _simulate(P: np.ndarray, r: Record, n: int | None = None, *, measured: bool = False, w_efd: float = 1.0,
              w_vt: float = 0.0, w_q: float = 0.0) -> dict:
    """The candidates P over record r (its first n samples; all: without traces when `measured`,
    with the weighted errors of the signals it has): the engine at no load, or for an on-line
    record on the grid from the record's operating point."""
    n = r.usetp.size if n is None else int(n)
    machine = None
    if r.machine is not None:
        P, machine = _on_line_inputs(P, r)
    else:
        P = P[:, :len(KERNEL_PARAMS)]
    meas = {"efd": r.efd, "vt": r.vt, "q": r.q} if measured else None
    return engine.run(P, r.usetp[:n], r.dt, r.usetp_pre, machine=machine, measured=meas,
                      weights={"efd": w_efd, "vt": w_vt, "q": w_q}, store=not measured, edges=r.edges_upto(n))


def _on_line_inputs(P: np.ndarray, r: Record) -> tuple[np.ndarray, np.ndarray]:
    """The kernel matrix (Vt0 the record's) and the machine matrix (fitted [grid] values in their
    columns) of the candidates P (`Problem.matrix`) on the on-line record r."""
    grid = P[:, len(KERNEL_PARAMS):]
    P = P[:, :len(KERNEL_PARAMS)].copy()
    P[:, COL["Vt0"]] = r.vt0
    M = np.repeat(r.machine[None, :], P.shape[0], axis=0)
    if grid.shape[1]:
        M[:, list(r.grid_cols)] = grid
    return P, M


# ---------------------------------------------------------------------- construction

def _reduce_constraints(texts: Sequence[str], names: Sequence[str], base: dict[str, float]
                        ) -> tuple[list[LinearConstraint], list[tuple[str, bool]]]:
    """Parse over all kernel parameters, keep fitted names, fold the rest into the bound."""
    full = parse_constraints(list(texts), KERNEL_PARAMS)
    idx = [KERNEL_PARAMS.index(n) for n in names]
    fitted, fixed = [], []
    for c in full:
        sub = c.coef[idx]
        rest = c.coef.copy()
        rest[idx] = 0.0
        const = 0.0
        for j in np.flatnonzero(rest):
            v = base[KERNEL_PARAMS[j]]
            if not math.isfinite(v):
                raise ProblemError(f"constraint {c.expr!r} uses {KERNEL_PARAMS[j]} = {v}, which is "
                                   "not fitted and not finite (fit it or give it a value)")
            const += rest[j] * v
        if np.any(sub != 0.0):
            fitted.append(LinearConstraint(expr=c.expr, coef=sub, rhs=c.rhs - const, names=tuple(names)))
        else:
            fixed.append((c.expr, bool(const <= c.rhs + 1e-9)))
    return fitted, fixed


def _check_feasible(fitted: Sequence[LinearConstraint], fixed: Sequence[tuple[str, bool]],
                    names: Sequence[str], bounds: Sequence[tuple[float, float]]) -> None:
    """Refuse, before any fit, constraints that no parameter set inside the bounds satisfies
    (a linear feasibility problem), or that the fixed values already break."""
    broken = [expr for expr, ok in fixed if not ok]
    if broken:
        raise ProblemError(f"constraint(s) {broken} are broken by the fixed parameter values; nothing "
                           "the fit can change satisfies them")
    if not fitted:
        return
    from scipy.optimize import linprog

    A = np.array([c.coef for c in fitted])
    b = np.array([c.rhs for c in fitted])
    res = linprog(np.zeros(len(names)), A_ub=A, b_ub=b, bounds=list(bounds), method="highs")
    if res.status == 2:
        box = ", ".join(f"{n} in [{lo:g}, {hi:g}]" for n, (lo, hi) in zip(names, bounds))
        raise ProblemError(f"the constraints {[c.expr for c in fitted]} contradict each other inside the "
                           f"bounds ({box}): no parameter set satisfies them all")


def make_problem(captures: Sequence[Capture], unit: Unit, *, names: Sequence[str] | None = None,
                 bounds: dict[str, tuple[float, float]] | None = None,
                 constraints: Sequence[str] | None = None, weights: Sequence[float] | None = None,
                 segment: slice | None = None, fit_window: tuple[float, float] | None = None,
                 values: dict[str, float] | None = None, fit_edges: bool = True) -> Problem:
    """Bind captures and a unit into a `Problem`.

    names: parameters to fit (default `unit.identified_names`; effect parameters allowed; none, when
    only the edge instants are fitted, e.g. a holdout's timing under a model held fixed).
    bounds: per-name (lo, hi) overriding `default_bounds`. constraints: texts (default: the
    unit's, plus those of every effect with a fitted parameter). weights: alpha_k per capture
    (default 1). segment / fit_window: restrict the objective and MSE (samples / seconds from
    the record's start). values: kernel parameter values overriding the unit's for the
    parameters that are not fitted (e.g. a previous fit's result). fit_edges: fit the instant
    of every setpoint edge (`EDGE1`.. appended to the names, bounds from `timing.record_edges`);
    at most four edges over all captures are fitted, the others stay at their nominal sample.
    """
    caps = tuple(captures)
    if not caps:
        raise ProblemError("no capture given")
    names_t = tuple(unit.identified_names if names is None else names)
    if set(names_t) & set(EDGE_PARAMS):
        raise ProblemError(f"{sorted(set(names_t) & set(EDGE_PARAMS))}: edge offsets are set from the "
                           "captures (fit_edges), not named")
    caps_edges: list[list[Edge]] = [record_edges(c) for c in caps] if fit_edges else [[] for _ in caps]
    caps_slots: list[list[int | None]] = []
    edge_bounds: dict[str, tuple[float, float]] = {}
    for edges in caps_edges:
        slots: list[int | None] = []
        for e in edges:
            if len(edge_bounds) < len(EDGE_PARAMS):
                slot = len(edge_bounds)
                edge_bounds[EDGE_PARAMS[slot]] = (e.lo_s, e.hi_s)
                slots.append(slot)
            else:
                slots.append(None)
        caps_slots.append(slots)
    if not names_t and not edge_bounds:
        raise ProblemError("no parameter to fit")
    if any(s is None for slots in caps_slots for s in slots):
        logger.warning("more than %d setpoint edges over the captures: the later ones stay at their "
                       "nominal sample", len(EDGE_PARAMS))
    for n in names_t:
        if n not in PARAMS:
            raise ProblemError(f"unknown parameter {n!r}; known: {', '.join(KERNEL_PARAMS)}")
    if len(set(names_t)) != len(names_t):
        raise ProblemError(f"parameter names repeat: {list(names_t)}")
    bounds = dict(bounds or {})
    unknown = set(bounds) - set(names_t)
    if unknown:
        raise ProblemError(f"bounds given for {sorted(unknown)}, which are not fitted ({list(names_t)})")
    bnds = []
    for n in names_t:
        lo, hi = (float(v) for v in bounds.get(n, default_bounds(unit, n)))
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ProblemError(f"bounds of {n}: need finite lo < hi, got ({lo}, {hi})")
        bnds.append((lo, hi))
    names_t = names_t + tuple(edge_bounds)
    for n in edge_bounds:
        lo, hi = edge_bounds[n]
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ProblemError(f"bounds of {n}: need finite lo < hi, got ({lo}, {hi})")
        bnds.append((lo, hi))
    base = unit.values()
    grid_names = tuple(unit.grid_identify)
    base.update({k: b.value for k, b in unit.grid_identify.items()})
    if values:
        bad = set(values) - set(KERNEL_PARAMS)
        if bad:
            raise ProblemError(f"values for unknown parameter(s) {sorted(bad)}")
        base.update({k: float(v) for k, v in values.items()})

    if constraints is None:
        texts = list(unit.constraints)
        for eff in EFFECTS.values():
            if set(eff.params) & set(names_t):
                texts += [t for t in eff.constraints if t not in texts]
    else:
        texts = list(constraints)
    fitted, fixed = _reduce_constraints(texts, names_t, base)
    if grid_names:   # the [grid] values fitted on line: after the kernel's, in no constraint
        fitted = [LinearConstraint(expr=c.expr, coef=np.concatenate([c.coef, np.zeros(len(grid_names))]), rhs=c.rhs,
                                   names=names_t + grid_names) for c in fitted]
        bnds += [(unit.grid_identify[k].min, unit.grid_identify[k].max) for k in grid_names]
        names_t = names_t + grid_names
    _check_feasible(fitted, fixed, names_t, bnds)

    if weights is None:
        alphas = [1.0] * len(caps)
    else:
        alphas = [float(w) for w in weights]
        if len(alphas) != len(caps) or not all(math.isfinite(a) and a >= 0 for a in alphas):
            raise ProblemError(f"weights {list(weights)}: need one finite value >= 0 per capture "
                               f"({len(caps)})")
    w_efd = float(unit.weights.get("efd", 1.0))
    w_vt = float(unit.weights.get("vt", 0.0))
    if w_efd < 0 or w_vt < 0 or (w_efd == 0 and w_vt == 0):
        raise ProblemError(f"signal weights {unit.weights}: need >= 0 and at least one > 0")
    if w_efd == 0 and not any(c.vt is not None for c in caps):
        raise ProblemError("efd weight is 0 and no capture has a vt channel: nothing to fit")
    w_q = float(unit.weights.get("q", 1.0))

    if segment is not None and fit_window is not None:
        raise ProblemError("give either segment or fit_window, not both")
    recs = []
    bound_total = 0.0
    for c, a, edges, slots in zip(caps, alphas, caps_edges, caps_slots):
        owner = c.source or "<capture in memory>"
        if c.n < 3:
            raise ProblemError(f"{owner}: {c.n} samples are too few to identify anything")
        dt = float(c.dt)
        usetp = np.ascontiguousarray(c.usetp, dtype=float)
        vt = np.ascontiguousarray(c.vt, dtype=float) if c.vt is not None else None
        moved = [(e, s) for e, s in zip(edges, slots) if s is not None]
        spec = edge_plan_of([e for e, _ in moved], [s for _, s in moved])
        r = Record(usetp=usetp, efd=np.ascontiguousarray(c.efd, dtype=float), vt=vt, dt=dt,
                    usetp_pre=pre_trigger_mean(usetp, dt), alpha=a, i0=0, i1=c.n, source=owner,
                    edges=spec, edge_list=tuple(edges), edge_slots=tuple(slots), **_on_line(c, unit, owner))
        window = segment_window(segment, c) if segment is not None else fit_window
        recs.append(apply_window(r, window, c))
        # a finite (non-failed) simulation keeps |states| < BLOWUP: bound its objective
        dur = dt * (c.n - 1)
        e_max = (_MAX_GAIN * BLOWUP + float(np.max(np.abs(c.efd)))) ** 2 * w_efd
        v_max = (BLOWUP + float(np.max(np.abs(vt)))) ** 2 * w_vt if vt is not None else 0.0
        q_max = (BLOWUP + float(np.max(np.abs(r.q)))) ** 2 * w_q if r.q is not None else 0.0
        bound_total += a * (e_max + v_max + q_max) * dur
    if grid_names and not any(r.machine is not None for r in recs):
        raise ProblemError(f"{', '.join(grid_names)} fitted (--set {grid_names[0]}.min/max): only an on-line record "
                           "(a capture with p and q) determines the grid; these captures are at no load")
    window_used = fit_window if segment is None else segment_window(segment, caps[0])
    return Problem(captures=caps, unit=unit, names=names_t, bounds=tuple(bnds),
                   constraints=tuple(fitted), constraint_texts=tuple(texts),
                   fixed_constraints=tuple(fixed), weights=tuple(alphas), w_efd=w_efd, w_vt=w_vt,
                   base=base, records=tuple(recs), window=window_used,
                   penalty_base=max(1.0e20, 10.0 * bound_total), w_q=w_q, grid_names=grid_names)


def _on_line(c: Capture, unit: Unit, owner: str) -> dict[str, Any]:
    """A capture with P and Q channels is an on-line record: the unit's machine on the grid at the
    record's pre-step P, Q and Vt (Record.machine, vt0, q); a no-load record: nothing."""
    p, q = c.channel("p"), c.channel("q")
    if p is None and q is None:
        return {}
    if p is None or q is None or c.vt is None:
        have = [name for name, x in (("p", p), ("q", q), ("vt", c.vt)) if x is not None]
        raise ProblemError(f"{owner}: an on-line record needs p, q and vt; it has {', '.join(have)}")
    point = operating_point(c.usetp, p, q, c.vt, float(c.dt))
    missing = [name for name in machine_data(unit) if name not in unit.grid and name not in unit.grid_identify]
    if missing:
        raise ProblemError(f"{owner} is an on-line record (it has p and q): the unit {unit.name!r} needs "
                           f"{', '.join(missing)} under [grid] or with --set (the machine's data also come "
                           "from a GENROU or GENSAL record with --from-dyr)")
    try:
        start = {k: b.value for k, b in unit.grid_identify.items()}
        machine = machine_matrix(unit_machine(unit, {**start, "P0": point["P0"], "Q0": point["Q0"]}))[0]
    except ValueError as exc:
        raise ProblemError(f"{owner}: {exc}") from None
    return {"machine": machine, "vt0": point["Vt0"], "q": np.ascontiguousarray(q, dtype=float),
            "grid_cols": tuple(MCOL[k] for k in unit.grid_identify)}

