"""Models fitted to a capture and what they are fitted and checked on: how every model sees the
capture (`Views`), one fitted model (`ModelFit`), the parts of its check (`Window`, `Part`), the
budget (`Budget`) and what every step works on (`Setup`); shared by the diagnosis and the
structure selection.

Every model is identification's `Problem` on the whole capture (the unit's identified
parameters, the effects' parameters, the instant of every setpoint edge) and every fit is
identification's fitting stack (`bench_ctl.identification.peers`, `.polish`):
docs/decisions/0010-diagnosis-one-objective-and-its-check.md, 0015-one-fitting-stack.md.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

from bench_ctl.capture import Capture
from bench_ctl.model.effects import VOCABULARY, vocabulary
from bench_ctl.signals.edges import EDGE_PARAMS
from bench_ctl.units.unit import Bound, Unit

from .check_records import Validation
from .construction import make_problem
from .localize import NoiseFloor
from .problem import Problem
from .result import Result

__all__ = ["Budget", "Window", "Part", "ModelFit", "Views", "Setup", "edge_names", "mid", "coarse_factor",
           "added_params"]

#: the lags whose lower bounds set the coarse record's step
LAGS = ("TA2", "TA4", "TE", "TR", "Td0pp")


def coarse_factor(unit: Unit, dt: float, target: float) -> int:
    """Decimation factor q for the coarse record: a step near `target` but not above the shortest
    lag the unit can have (RK4 at a step of one time constant is still accurate to ~2 % per step;
    at two it no longer decays right)."""
    shortest = math.inf
    values = unit.values()
    for name in LAGS:
        lo = unit.identify[name].min if name in unit.identify else values.get(name, 0.0)
        if lo > 0:
            shortest = min(shortest, lo)
    step = min(target, shortest)
    return max(1, int(math.floor(step / dt + 1e-9)))


@dataclass(frozen=True)
class Window:
    """A cross-validation window of the capture (s from its first sample, ends included)."""
    label: str
    t0: float
    t1: float


@dataclass(frozen=True)
class Part:
    """One part of a model's check: the holdout capture, a window left out of the fit, or the
    recorded Vt the fit did not use."""
    label: str
    n: float      # samples scored
    mse: float    # mean objective there (pu^2; the vt part: Vt's MSE); inf: the simulation failed


def added_params(effects: Sequence[str]) -> int:
    return sum(len(VOCABULARY[e].params) for e in effects)


@dataclass(frozen=True)
class ModelFit:
    """One model of the diagnosis fitted to the capture: the base model plus `effects` (a variant
    holding `fixed` values and fitting its `extra` parameters)."""
    effects: tuple[str, ...]
    fit: Result                        # the fit on the whole capture (every fitted parameter)
    mse: float                         # its mean objective (`Problem.mean_objective`; inf: failed)
    checks: tuple[Part, ...] | None    # None: not checked (yet)
    k: int                             # added (effect) parameters
    evaluations: int                   # simulations of every step that led to it
    start: dict[str, float] = field(default_factory=dict)
    fixed: dict[str, float] = field(default_factory=dict)   # the variant: values it holds (VRVT, ..)
    extra: tuple[str, ...] = ()        # a variant's own fitted parameters (KC), counted in k
    blocks: tuple[Part, ...] | None = None   # the interleaved blocks (fit_check.check_and_blocks)

    @property
    def params(self) -> dict[str, float]:
        """Every fitted parameter (model, effects, edge offsets)."""
        return self.fit.params()

    @property
    def feasible(self) -> bool:
        return not self.fit.violated

    @property
    def std(self) -> dict[str, float]:
        """Standard deviations of the parameters, from the last polish ({} when not computed)."""
        return dict(self.fit.std or {})

    def effect_params(self) -> dict[str, float]:
        params = self.params
        out = {p: params[p] for e in self.effects for p in VOCABULARY[e].params}
        out.update({p: params[p] for p in self.extra})
        return out

    @property
    def mse_check(self) -> float | None:
        """The check's pooled mean objective (the parts' sample-weighted mean; not the Vt part,
        another channel on another scale), None when not checked."""
        parts = [p for p in self.checks or () if p.label != "vt"]
        n = sum(p.n for p in parts)
        return sum(p.n * p.mse for p in parts) / n if n > 0 else None

    def part(self, label: str) -> Part | None:
        return next((p for p in self.checks or () if p.label == label), None)


@dataclass(eq=False)
class Views:
    """How every model sees the capture: its problem (names, bounds, constraints, edges), the
    coarse copy the searches run on, and the check (holdout, cross-validation windows)."""
    unit: Unit
    capture: Capture
    holdout: Capture | None
    q: int                             # decimation of the coarse record
    n_coarse: int                      # its last fine sample
    offset: int                        # a fine sample kept on the coarse grid (the leading edge)
    windows: tuple[Window, ...]
    holdout_calls: int = 24            # least-squares simulations for the holdout's edge instants
    _cache: dict = field(default_factory=dict, repr=False)

    @property
    def on_line(self) -> bool:
        """The capture is an on-line record (it has p and q): the machine on the grid runs it."""
        return self.capture.on_line

    @property
    def model_start(self) -> dict[str, float]:
        """The base model's fitted parameters (the unit's identified ones and the [grid] values it
        fits on line) at the unit file's values: every other fitted name is an effect's or an edge's."""
        values = self.unit.values()
        return {**{n: values[n] for n in self.unit.identify},
                **{n: b.value for n, b in self.unit.grid_identify.items()}}

    @property
    def vocabulary(self) -> tuple[str, ...]:
        """The effects tried on this record (`effects.vocabulary`: at no load, or on line)."""
        return vocabulary(self.on_line, tuple(self.unit.grid_identify))

    def problem(self, effects: Sequence[str] = (), fixed: Mapping[str, float] | None = None, *,
                with_effects: bool = True, extra: Sequence[str] = ()) -> Problem:
        """The model's problem on the capture: identified parameters + the effects' parameters
        and a variant's `extra` ones (with_effects=False: those held at `fixed`, a profile) + the
        edge instants."""
        fixed = dict(fixed or {})
        key = (tuple(effects), tuple(sorted(fixed.items())), with_effects, tuple(extra))
        p = self._cache.get(key)
        if p is None:
            names = list(self.unit.identified_names)
            grid = [e for e in effects if VOCABULARY[e].frees_grid]
            if with_effects:
                for e in effects:
                    if e not in grid:
                        names += [n for n in VOCABULARY[e].params if n not in names]
                names += [n for n in extra if n not in names]
            bounds = {n: b[n] for e in effects for b in (VOCABULARY[e].bounds,) for n in b if n in names}
            unit, values = self._grid_unit(grid, fixed, with_effects)
            p = make_problem([self.capture], unit, names=names, bounds=bounds, values=values or None)
            if len(self._cache) > 256:
                self._cache.clear()
            self._cache[key] = p
        return p

    def _grid_unit(self, grid: Sequence[str], fixed: Mapping[str, float], fitted: bool
                   ) -> tuple[Unit, dict[str, float]]:
        """The unit with the grid effects' [grid] values fitted within their bounds (from the
        unit's own, `fitted`) or held at `fixed`'s; and the kernel values `fixed` holds."""
        unit = self.unit
        names = {n for e in grid for n in VOCABULARY[e].params}
        for e in grid:
            for n in VOCABULARY[e].params:
                if fitted:
                    lo, hi = VOCABULARY[e].bounds[n]
                    start = min(max(float(fixed.get(n, unit.grid.get(n, 0.5 * (lo + hi)))), lo), hi)
                    unit = replace(unit, grid_identify={**unit.grid_identify, n: Bound(start, lo, hi)})
                elif n in fixed:
                    unit = replace(unit, grid={**unit.grid, n: float(fixed[n])})
        return unit, {k: v for k, v in fixed.items() if k not in names}

    def coarse(self, p: Problem) -> Problem:
        return p.decimated(self.q, n_max=self.n_coarse, offset=self.offset)

    def holdout_problem(self, values: Mapping[str, float]) -> Problem:
        """The holdout with the model held at `values`: only its own edge instants are fitted."""
        assert self.holdout is not None
        held = {k: v for k, v in values.items() if k not in EDGE_PARAMS}
        # no constraint: nothing of the model is fitted here (a fit left infeasible is still judged)
        return make_problem([self.holdout], self.unit, names=(), values=held, constraints=())


@dataclass(frozen=True)
class Budget:
    """Evaluations (simulations) per fit: MVMO evaluations and least-squares polish simulations."""
    base: int = 1000
    base_polish: int = 100
    effect: int = 600          # MVMO evaluations per leading effect (coarse record, whole box)
    profile: int = 600         # MVMO evaluations over the model parameters with the effect held
    global_top: int = 2        # effects (best after the local fits) that get the MVMO searches
    effect_polish: int = 60    # least-squares simulations on the full record per effect polished
    polish_top: int = 3        # effects polished on the full record (the best after the coarse fits)
    polish_coarse: int = 150   # least-squares simulations on the coarse record per start
    starts: int = 8            # starting points polished on the coarse record per effect
    coarse_dt: float = 0.004   # sample step of the coarse record (s), at most the unit's shortest
                               # lag (reference unit: TE >= 2 ms), see `coarse_factor`
    coarse_tail_s: float = 3.0 # the coarse record ends this long after the trailing edge
    combo_polish: int = 60
    max_sequence: int = 3
    floor_sigmas: float = 3.0


@dataclass(frozen=True, eq=False)
class Setup:
    """What every step works on: the views of the capture, the noise floors and the tolerance."""
    views: Views
    n: int               # samples of the capture (every model is fitted on all of them)
    floor: NoiseFloor    # of the mean objective (efd's, weighted; plus Vt's when Vt is fitted)
    check_floor: float   # the check's noise floor (pooled: holdout floor and the capture's)
    check_se: float
    floor_tol: float     # base MSE up to this counts as "at the noise floor"
    validation: Validation


def edge_names(p: Problem) -> list[str]:
    return [n for n in p.names if n in EDGE_PARAMS]


def mid(p: Problem, names: Sequence[str]) -> dict[str, float]:
    """The middle of each named parameter's bounds (where an edge instant starts)."""
    return {n: 0.5 * (lo + hi) for n, (lo, hi) in zip(p.names, p.bounds) if n in names}
