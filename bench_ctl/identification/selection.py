"""Which structure explains the record (`identify --model auto`): every candidate structure
identified on the captures as `bench-ctl identify` fits it, then judged by the diagnosis' check
and ranked by the diagnosis' score.

Each candidate is identified on the whole of every capture (`run_identification`: MVMO, its
polish and the exchange restarts); each fitted model is then checked on every capture as the
diagnosis checks a model (`fit_check.check_parts`: the leading edge, the plateau and the trailing
edge each left out of a re-fit and scored; a recorded Vt the fit did not use is scored and
shown, not counted: every candidate shares the generator that makes Vt from efd). The score is
the diagnosis' (`fit_check.score`) over those windows: BIC on the captures, n ln(mse) + k ln(n) with
k the structure's identified parameters that the record informs (a limit it never reaches moves
nothing and is not counted: `_inert`), plus the windows' sum of n_i ln(mse_i). So a structure with
more freedom earns it only by fitting better where it was fitted and predicting better where it was
not.

Two candidates whose fits differ by less than the noise (`EQUAL_FIT`, in n ln(mse) units) are
equivalent on this record: the simpler one ranks first and the other is named as fitting as well
(e.g. the reference structure, whose two lead-lags contain SEXS's one). The verdict: `explains`
when the best candidate's fit is at the noise floor (within its standard error), otherwise
`closest` with the factor left over the floor (docs/decisions/0016-structure-selection.md).
"""
from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from bench_ctl.capture import Capture
from bench_ctl.exitcodes import BadInput
from bench_ctl.signals.edges import EDGE_PARAMS
from bench_ctl.units.unit import Unit

from .construction import make_problem
from .fit_check import check_parts, prepare
from .identify import Identification, run_identification
from .localize import DiagnosisError, localization, where_lines
from .model_fits import Part, Setup
from .result_file import CandidateEntry, Localization, SelectionEntry, Separation, written
from .space import SearchSpace
from .threads import map_fits

__all__ = ["Candidate", "Selection", "select_structure", "rank_structures", "NoStructureFitted", "where_left",
           "separation_text", "EQUAL_FIT"]

log = logging.getLogger(__name__)

#: two fits whose n ln(mse) differ by less than this are equally good on the record (the same
#: scale as the diagnosis' AMBIGUOUS: -2 log-likelihood units)
EQUAL_FIT = 6.0
#: standard errors of the noise floor within which a fit counts as at the floor
FLOOR_SIGMAS = 3.0
#: a parameter is inert on a record when a change of this share of its value or of its bounds'
#: span (the larger), either way, moves its simulated efd by no more than INERT_TOL (relative to
#: the trace's peak): it is then not counted in the score's k (a freed limit the record never
#: reaches)
INERT_STEP = 1e-3
INERT_TOL = 1e-9
#: a fit with this many identified parameters on their bounds is suspect of a search caught in a
#: corner of the box (AC8B's derivative kick clipped by a ceiling on its lowest bound, with TE and
#: TDR on theirs): it gets a second search from the next seed and the better fit is kept
#: (`_searched_again`)
SUSPECT_AT_BOUNDS = 3
#: ... when its fit is within this factor of the best candidate's (a structure far behind would
#: not move up the ranking; on the Mostar record that spares the second search of the structures
#: at 4x-30x the best)
SUSPECT_RANGE = 4.0
@dataclass(frozen=True, eq=False)
class Candidate:
    """One structure identified on the captures and checked."""
    model: str
    ident: Identification | None     # None: it could not be set up or fitted (`error` says why)
    k: int                           # identified model parameters the record informs (not the edge
    #                                  instants, not `inert`)
    n: int                           # samples scored
    mse: float                       # mean objective over the captures (inf: failed)
    checks: tuple[Part, ...]         # the check's parts over every capture (a Vt part: shown, not scored)
    score: float                     # BIC + the check's deviance; lower is better (inf: failed)
    check_nll: float                 # the check's deviance: sum of n_i ln(mse_i) over its windows
    wall_s: float
    error: str | None = None
    #: per capture, where its residual lies (`localize.localization`: share and mse per segment
    #: of the response, share per frequency band)
    where: tuple[Localization, ...] = ()
    #: identified parameters (the kernel's names; the entry says them in the structure's) that move
    #: nothing on any capture at the fitted values (`_inert`), not counted in k
    inert: tuple[str, ...] = ()
    #: searches run: 2 when the first was suspect (`_searched_again`)
    searches: int = 1

    @property
    def at_bounds(self) -> list[str]:
        """Its identified parameters (standard names) that ended on a bound: the structure pressed
        to follow something it does not have."""
        return [] if self.ident is None else _at_bounds(self.ident)

    @property
    def check_mse(self) -> float | None:
        """The check's pooled mean objective over the left-out windows (not the Vt part)."""
        parts = [p for p in self.checks if p.label != "vt"]
        n = sum(p.n for p in parts)
        return sum(p.n * p.mse for p in parts) / n if n > 0 else None


@dataclass(frozen=True, eq=False)
class Selection:
    candidates: tuple[Candidate, ...]     # best first; failed ones last
    floor: float                          # noise floor of the mean objective (pooled over captures)
    floor_rel_se: float
    equivalent: tuple[str, ...]           # candidates that fit as well as the best one (more parameters)
    dt: float = 1.0                       # the first capture's sample step (s)

    @property
    def best(self) -> Candidate:
        return self.candidates[0]

    @property
    def verdict(self) -> str:
        b = self.best
        if not math.isfinite(b.mse):
            return "none_fitted"
        return "explains" if b.mse <= self.floor * (1.0 + FLOOR_SIGMAS * self.floor_rel_se) else "closest"

    def separation(self) -> Separation | None:
        """Where the best two differ most on the record: the segment of the first capture whose
        mse ratio, weighted by its samples, is largest, and whether that is beyond the noise
        (EQUAL_FIT in n ln mse) where at least one of the two misses the noise floor: two fits that
        are both at the floor in a segment (within FLOOR_SIGMAS standard errors) fit it equally
        well whatever their ratio, and the same equations there give such a pair (issue 48 item
        13). None with fewer than two fitted candidates."""
        fitted = [c for c in self.candidates if c.where and math.isfinite(c.mse)]
        if len(fitted) < 2:
            return None
        a, b = fitted[0], fitted[1]
        at_floor = self.floor * (1.0 + FLOOR_SIGMAS * self.floor_rel_se)
        best: tuple[float, bool, Any, Any] | None = None   # (weight, both at the floor, a's, b's)
        for sa, sb in zip(a.where[0].segments, b.where[0].segments):
            n = max(1.0, (sa.t1 - sa.t0) / max(self.dt, 1e-12))
            if sa.mse <= 0 or sb.mse <= 0:
                continue
            w = n * abs(math.log(sb.mse / sa.mse))
            both = sa.mse <= at_floor and sb.mse <= at_floor
            # a segment where one misses the floor ranks before any where both are at it
            if best is None or (best[1], -best[0]) > (both, -w):
                best = (w, both, sa, sb)
        if best is None:
            return None
        w, both, sa, sb = best
        return Separation(models=[a.model, b.model], segment=sa.name, t0=sa.t0, t1=sa.t1,
                          x_floor=[sa.mse / self.floor, sb.mse / self.floor], weight=w,
                          separated=bool(w > EQUAL_FIT and not both), both_at_floor=both)

    def entry(self, notes: Sequence[str] = ()) -> SelectionEntry:
        """The result's `selection` (docs/formats.md), with the notes of the `--set` values some
        structures lack."""
        best = self.best
        out = []
        for rank, c in enumerate(self.candidates, 1):
            fitted: dict[str, Any] = {}
            if c.ident is not None:
                r = c.ident.result
                # what re-simulates it (the report's residual of the best two): every kernel value
                # and the edge instants it fitted on each capture
                values = c.ident.problem.values(c.ident.best.x)
                fitted = dict(params=dict(r.params),
                              kernel={n: _finite(v) for n, v in values.items() if n not in EDGE_PARAMS},
                              edges=[tuple(cap.edges or ()) for cap in r.captures],
                              constraints_violated=r.constraints_violated, failed=bool(r.failed))
            entry = CandidateEntry(
                rank=rank, model=c.model, k=c.k, inert=list(c.inert), n=c.n,
                mse=_finite(c.mse), x_floor=_finite(c.mse / self.floor) if self.floor > 0 else None,
                check={p.label: _finite(p.mse) for p in c.checks},
                check_mse=_finite(c.check_mse) if c.check_mse is not None else None,
                check_x_floor=_finite(c.check_mse / self.floor) if c.check_mse is not None and self.floor > 0
                else None,
                score=_finite(c.score),
                score_difference=_finite(c.score - best.score) if c is not best else 0.0,
                equivalent=c.model in self.equivalent,
                wall_s=c.wall_s, searches=c.searches, **fitted,
                error=c.error or None,
                where=c.where or None, at_bounds=c.at_bounds if c.where else None)
            # a fitted candidate in the names of its unit's structure (its inert ones were scored in the kernel's)
            out.append(written(entry, c.ident.problem.unit.structure) if c.ident is not None else entry)
        return SelectionEntry(
            verdict=self.verdict,
            chosen=best.model,
            equivalent=list(self.equivalent),
            separation=self.separation(),
            noise_floor=self.floor,
            candidates=tuple(out),
            notes=list(notes),
            rule="each structure identified on the whole record, then scored as the diagnosis scores a "
                 "model: BIC on the record (n ln mse + k ln n, k its identified parameters that move the fit: a "
                 "limit the record never reaches is not counted) plus the "
                 "check's sum of n_i ln(mse_i) over the leading edge, plateau and trailing edge, each "
                 f"left out of a re-fit; lower is better. Fits within {EQUAL_FIT:g} (n ln mse) of the best "
                 "one are equivalent: the one with fewer parameters ranks first",
        )


def _finite(v: float | None) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None


def _capture_x(ident: Identification, i: int, setup: Setup) -> tuple[Any, np.ndarray]:
    """The problem of capture i alone (the candidate's identified names and its own edge
    instants) and the joint fit's values on it (edge slots mapped from the joint problem)."""
    joint = ident.problem
    params = joint.params(ident.best.x)
    p = setup.views.problem(())
    values = {n: params[n] for n in p.names if n not in EDGE_PARAMS}
    for s_joint, s_own in zip(joint.records[i].edge_slots, p.records[0].edge_slots):
        if s_own is not None:
            values[EDGE_PARAMS[s_own]] = params.get(EDGE_PARAMS[s_joint], 0.0) if s_joint is not None else 0.0
    return p, SearchSpace(p).clip(np.array([values[n] for n in p.names], float))


def _at_bounds(ident: Identification) -> list[str]:
    """The identified parameters (standard names) of a fit that ended on a bound."""
    r = ident.result
    out = []
    for name, v in r.params.items():
        lo, hi = r.bounds.get(name, (None, None))
        if lo is None or hi is None or not math.isfinite(v):
            continue
        tol = 1e-3 * (hi - lo)
        if v <= lo + tol or v >= hi - tol:
            out.append(name)
    return out


def _candidate(model: str, unit: Unit, captures: Sequence[Capture], *, max_evals: int, seed: int,
               command_line: str) -> Candidate:
    """`model` identified on the captures (`_fit`), then checked and scored (`_scored`)."""
    t0 = time.perf_counter()
    ident = _fit(unit, captures, max_evals=max_evals, seed=seed, command_line=command_line)
    if isinstance(ident, str):
        return Candidate(model, None, 0, 0, math.inf, (), math.inf, math.inf, time.perf_counter() - t0,
                         error=ident)
    return _scored(model, unit, captures, ident, t0)


def _fit(unit: Unit, captures: Sequence[Capture], *, max_evals: int, seed: int,
         command_line: str) -> Identification | str:
    """The unit identified on the captures as `identify` fits it, or why it could not be."""
    try:
        problem = make_problem(captures, unit)
        # the unit's values (typical, or a planning record's) join the initial swarm
        return run_identification(captures, unit, max_evals=max_evals, seed=seed, command_line=command_line,
                                  problem=problem, x0=problem.x_start())
    except BadInput as exc:   # a structure the captures cannot constrain (ProblemError, ...)
        return str(exc)


def _scored(model: str, unit: Unit, captures: Sequence[Capture], ident: Identification, t0: float) -> Candidate:
    """The fit `ident` checked on every capture and scored (module docstring); wall time from t0."""
    n_total, sum_nll, parts, where = 0, 0.0, [], []
    inert = {n for n in ident.problem.names if n not in EDGE_PARAMS}
    for i, cap in enumerate(captures):
        edges, _, setup = prepare(cap, unit)
        p, x = _capture_x(ident, i, setup)
        inert &= _inert(p, x)
        mse = float(p.mean_objective(x[None, :])[0])
        sim = p.simulate(x)[0]["efd"]
        where.append(localization(np.asarray(cap.efd, float) - sim, cap.dt, edges))
        n_i = cap.n
        n_total += n_i
        sum_nll += n_i * math.log(mse) if 0 < mse < math.inf else math.inf
        # the undamped linear prediction, as before decision 0020: on the ANDES records the damped
        # re-fit scored candidates whose step fails nearer their own fit, and put REFERENCE first on
        # 3 of 15 records, two of them missed (13 / 15 against 15 / 15 true first or equivalent)
        own = check_parts(setup.views, p, x, linear=True)
        parts += [Part(f"{part.label}" if len(captures) == 1 else f"{i}:{part.label}", part.n, part.mse)
                  for part in own]
    # the parameters the record informs: one that moves nothing on any capture (a limit never
    # reached) is not freedom the structure used, and BIC does not charge it
    k = sum(1 for n in ident.problem.names if n not in EDGE_PARAMS and n not in inert)
    mse_all = math.exp(sum_nll / n_total) if math.isfinite(sum_nll) else math.inf
    # the windows only: a recorded Vt follows efd through the generator every candidate shares, so
    # its prediction is the candidates' efd low-passed by T'd0, and its samples, counted as
    # independent, would outweigh the edges (on the Mostar record 5760 Vt samples against 2 x 40)
    check_nll = sum(part.n * math.log(part.mse) if 0 < part.mse < math.inf else math.inf for part in parts
                    if not part.label.endswith("vt"))
    score = sum_nll + k * math.log(n_total) + check_nll
    if ident.best.violated or math.isnan(score):   # an infeasible fit does not stand for the structure
        score = math.inf
    return Candidate(model, ident, k, n_total, mse_all, tuple(parts), score, check_nll, time.perf_counter() - t0,
                     where=tuple(where),
                     inert=tuple(n for n in ident.problem.names if n in inert))


def _inert(p: Any, x: np.ndarray) -> set[str]:
    """The names of problem p (edge instants aside) whose change by INERT_STEP of the larger of
    its value and its bounds' span, either way within its bounds, leaves the simulated efd at x as
    it is (within INERT_TOL of the trace's peak): a limit the response never reaches, a block the
    fitted values bypass. Their effect is nil there, not small."""
    x = np.asarray(x, float)
    rows, owner = [x], [-1]
    for j, name in enumerate(p.names):
        if name in EDGE_PARAMS:
            continue
        lo, hi = float(p.lower[j]), float(p.upper[j])
        step = INERT_STEP * max(abs(float(x[j])), hi - lo)
        for v in (min(float(x[j]) + step, hi), max(float(x[j]) - step, lo)):
            if v != x[j]:
                xs = x.copy()
                xs[j] = v
                rows.append(xs)
                owner.append(j)
    efd = p.efd_traces(np.array(rows))[0]     # every move in one kernel call
    tol = INERT_TOL * max(1.0, float(np.max(np.abs(efd[0]))))
    moved = np.max(np.abs(efd[1:] - efd[0]), axis=1) if len(rows) > 1 else np.zeros(0)
    owners = np.array(owner[1:], int)
    return {p.names[j] for j in set(owner[1:]) if float(np.max(moved[owners == j])) <= tol}


def select_structure(captures: Sequence[Capture], units: Mapping[str, Unit], *, max_evals: int = 1000,
                     seed: int = 0, command_line: str = "",
                     progress: Callable[[str, Candidate], None] | None = None) -> Selection:
    """Identify every unit of `units` (structure name -> unit in that structure) on `captures`,
    check and rank them (module docstring). progress(name, candidate) after each."""
    if not units:
        raise ValueError("no candidate structure")
    floors = []
    for cap in captures:
        unit = next(iter(units.values()))
        try:
            _, _, setup = prepare(cap, unit)
        except DiagnosisError as exc:
            raise ValueError(f"--model auto: {exc}") from None
        floors.append((setup.floor, cap.n))
    n_all = sum(n for _, n in floors)
    floor = sum(f.variance * n for f, n in floors) / n_all
    rel_se = max(f.rel_se for f, _ in floors)

    def fitted(name: str, c: Candidate) -> None:
        log.info("%s: mse %.4g (%.2f x floor), score %.1f, %.1f s", name, c.mse, c.mse / floor, c.score, c.wall_s)
        if progress is not None:
            progress(name, c)

    # the candidates share nothing: side by side on the machine's cores (`threads`)
    cands = map_fits(lambda name: _candidate(name, units[name], captures, max_evals=max_evals, seed=seed,
                                             command_line=command_line), list(units), fitted)
    return replace(rank(_searched_again(cands, units, captures, max_evals, seed, command_line), floor, rel_se),
                   dt=float(captures[0].dt))


def _searched_again(cands: list[Candidate], units: Mapping[str, Unit], captures: Sequence[Capture],
                    max_evals: int, seed: int, command_line: str) -> list[Candidate]:
    """The candidates, each suspect of a failed search replaced by the better of its two: a fit
    with SUSPECT_AT_BOUNDS or more parameters on their bounds (a corner of the box: AC8B's
    derivative kick clipped by a ceiling on its lowest bound, TE and TDR on theirs) that could still
    matter (within SUSPECT_RANGE of the best fit) gets a second search from the next seed."""
    fits = [c.mse for c in cands if c.ident is not None and math.isfinite(c.mse)]
    if not fits:
        return cands
    best = min(fits)
    suspects = [i for i, c in enumerate(cands) if c.ident is not None and math.isfinite(c.mse)
                and len(c.at_bounds) >= SUSPECT_AT_BOUNDS and c.mse <= SUSPECT_RANGE * best]

    def fit(i: int) -> tuple[Identification | str, float]:
        t0 = time.perf_counter()
        return _fit(units[cands[i].model], captures, max_evals=max_evals, seed=seed + 1,
                    command_line=command_line), time.perf_counter() - t0

    out = list(cands)
    better = []
    for i, (ident, fit_s) in zip(suspects, map_fits(fit, suspects)):
        first = cands[i]
        log.info("%s: %s on their bounds, searched again: objective %.4g then %.4g", first.model,
                 ", ".join(first.at_bounds), first.ident.best.fun,
                 math.inf if isinstance(ident, str) else ident.best.fun)
        out[i] = replace(first, searches=2, wall_s=first.wall_s + fit_s)
        if not isinstance(ident, str) and ident.best.fun < first.ident.best.fun:
            better.append((i, ident))
    # only the better fit of the two is checked and scored
    for (i, _), c in zip(better, map_fits(lambda b: _scored(out[b[0]].model, units[out[b[0]].model], captures,
                                                             b[1], time.perf_counter()), better)):
        out[i] = replace(c, searches=2, wall_s=out[i].wall_s + c.wall_s)
    return out


def rank(cands: Sequence[Candidate], floor: float, rel_se: float) -> Selection:
    """The candidates ranked by score; of those that fit and predict within EQUAL_FIT of the best
    one (`equal`), the one with the fewest parameters first, the others named `equivalent`."""
    ordered = sorted(cands, key=lambda c: (c.score, c.k))
    if not ordered or not math.isfinite(ordered[0].score):
        return Selection(tuple(ordered), floor, rel_se, ())
    top = ordered[0]

    def equal(c: Candidate) -> bool:   # fits and predicts as well as the best one
        return (math.isfinite(c.score) and abs(c.n * math.log(c.mse / top.mse)) < EQUAL_FIT
                and abs(c.check_nll - top.check_nll) < EQUAL_FIT)

    group = [c for c in ordered if equal(c)]
    simplest = min(group, key=lambda c: (c.k, c.score))
    ordered.remove(simplest)
    ordered.insert(0, simplest)
    equivalent = tuple(c.model for c in group if c is not simplest)
    return Selection(tuple(ordered), floor, rel_se, equivalent)


def where_left(sel: SelectionEntry) -> list[str]:
    """Where the first candidate leaves its residual (segments and bands of the first capture, in
    x the noise floor and share of the residual energy) and the values it pressed on a bound."""
    best = sel.candidates[0]
    if not best.where:
        return []
    lines = where_lines(best.where[0], sel.noise_floor or 0.0)
    if best.at_bounds:
        lines.append(f"  {best.model} pressed on a bound: {', '.join(best.at_bounds)} (it follows "
                     "something it does not have, or the bounds are too narrow for this unit)")
    return lines


def separation_text(sel: SelectionEntry) -> str:
    """Whether this record separates the best two, and where."""
    sep = sel.separation
    if not sep:
        return ""
    a, b = sep.models
    at = f"the {sep.segment.replace('_', ' ')} ({sep.t0:.2f}-{sep.t1:.2f} s: " \
         f"{_g(sep.x_floor[0])}x against {_g(sep.x_floor[1])}x the floor)"
    if sep.separated:
        return f"{a} and {b} differ most at {at}: this record separates them"
    if sep.both_at_floor:
        return (f"{a} and {b} both fit every part of this record at the noise floor (most apart at {at}): this "
                "record does not separate them; a test at another level (where a limit acts) or a holdout record "
                "would")
    return (f"{a} and {b} differ by less than the noise everywhere (most at {at}): this record does not "
            "separate them; a test at another level (where a limit acts) or a holdout record would")


def _g(v: float | None) -> str:
    return "-" if v is None else f"{v:.3g}"


class NoStructureFitted(BadInput):
    """Every candidate failed; the message names each one's error."""


def rank_structures(captures: Sequence[Capture], units: Mapping[str, Unit], notes: Sequence[str], *,
                    seed: int, command_line: str, max_evals: int = 1000,
                    progress: Callable[[str, Any], None] | None = None) -> tuple[Selection, SelectionEntry]:
    """The selection of `identify` / `diagnose --model auto` and its record with the `--set` notes.
    Raises NoStructureFitted when no candidate could be fitted, DiagnosisError for a capture the
    check cannot use."""
    sel = select_structure(captures, units, max_evals=max_evals, seed=seed, command_line=command_line,
                           progress=progress)
    if sel.best.ident is None:
        raise NoStructureFitted("no structure could be fitted: " + "; ".join(
            f"{c.model}: {c.error}" for c in sel.candidates))
    return sel, sel.entry(notes)
