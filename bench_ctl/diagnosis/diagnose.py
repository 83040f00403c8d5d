"""Sim-to-real gap diagnosis of one capture: where the model misses, which effects, how far it shrinks.

`diagnose(capture, unit, holdout=...)` returns the diagnosis (`diagnosis_file.Diagnosis`, schema
"bench-ctl/diagnosis/1", docs/formats.md). On line only the test is simulated, from a few seconds
before the step (`span`). Every model is identification's `Problem` on the whole capture (the unit's
identified parameters, the effects' parameters and the instant of every setpoint edge,
`model_fits.Views`), fitted with identification's stack (`search`):

1. Base fit: exactly as `bench-ctl identify` fits it (from the unit's values, or `base_params`
   when a previous identification is given); re-polished from an effect fit's parameters when
   those fit the base model better (the base model is multimodal; the effect fits explore it too).
2. Noise floor (pre-trigger variance), localization (residual energy per segment and band),
   feature tests (flat top - also relative to a ceiling that moves with Vt -, delay, steady-state
   ratio, pre-trigger level, asymmetry, edge shape).
3. Every effect re-identified with the base model, warm-started from the base fit (`starts`,
   `search`); the ceiling also as a bus-fed exciter's (limits x Vt) and, with a recorded field
   current, with the commutation drop KC*Ifd; ranked by BIC plus the predictive deviance on the
   check (`check`); `none` when no effect is significant, or when the base model fits to the
   noise floor and no effect brings a strong gain; near-equal effects listed in `ambiguous` with
   the test that separates them (`verdict`). A verdict whose effect was not among the leaders
   searched (they lead on BIC, the verdict on BIC and the check) gets that search, and the
   effects are ranked again: it must not rest on a local fit (docs/lab/benchmarks-2026-11.md).
4. Several effects at once (`explained_by`, `explain`), and what is left.

The check (`fit_check.check_parts`): the cross-validation windows of the capture (leading edge,
plateau, trailing edge; each left out of a re-fit and scored: `fit_check.CV_SEGMENTS`, the recovery is
never one), the recorded Vt when the fit did not use it, and the holdout capture when one is
given.
"""
from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

import bench_ctl
from bench_ctl.capture import Capture, capture_sha256
from bench_ctl.identification.constraints import ConstraintError
from bench_ctl.identification.fit_check import bic, checked, fit_holdout, prepare
from bench_ctl.identification.localize import NoiseFloor, localization
from bench_ctl.identification.model_fits import Budget, ModelFit, Setup, Views
from bench_ctl.identification.peers import run_optimizer
from bench_ctl.identification.problem import ProblemError
from bench_ctl.identification.result_file import written
from bench_ctl.identification.space import SearchSpace
from bench_ctl.identification.threads import map_fits
from bench_ctl.model.effects import VOCABULARY
from bench_ctl.signals.edges import Edge, EdgeSearch
from bench_ctl.timestamps import utc_now_text
from bench_ctl.units.unit import Unit

from . import features as F
from .diagnosis_file import (
    DIAGNOSIS_SCHEMA,
    BaseFit,
    CaptureRef,
    Criteria,
    Diagnosis,
    NoiseFloorDetail,
    SequenceEntry,
    Vocabulary,
)
from .explain import explained_by, sequence
from .search import finish, fit_model, global_search, refine, refine_base
from .significance import close_to_best, criteria, worth_checking
from .span import PRE_STEP_S, cut_to_test, on_record
from .starts import all_starts, lag_variants
from .verdict import ambiguous_pairs, check_entry, choose_verdict, model_params, rank_entries

__all__ = ["SCHEMA", "Budget", "diagnose", "prepare", "choose_verdict"]

log = logging.getLogger(__name__)

SCHEMA = DIAGNOSIS_SCHEMA


def _capture_ref(c: Capture | None) -> CaptureRef | None:
    if c is None:
        return None
    return CaptureRef(c.source or None, capture_sha256(c.source))


#: effects checked after the single-effect fits: those that lower the BIC most
CHECKED = 4

def _fit_base(st: Setup, budget: Budget, seed: int, base_params: Mapping[str, float] | None) -> ModelFit:
    """The base model identified as `bench-ctl identify` does (`peers.run_optimizer("mvmo")` on the
    whole record), from the unit's values (or `base_params`), then polished once more for the
    parameters' standard deviations (docs/decisions/0010: the coarse-record search the effects use
    left an effect-free record further from the noise floor, and an effect then filled the rest)."""
    views = st.views
    p = views.problem(())
    space = SearchSpace(p)
    x0 = space.vector({n: float((base_params or {}).get(n, views.unit.identify[n].value))
                       for n in views.unit.identified_names})
    res = run_optimizer("mvmo", p, max_evals=budget.base, seed=seed, x0=x0)
    m = finish(views, (), {}, space.clip(res.x), polish_fine=budget.base_polish, noise_variance=st.floor.variance)
    return replace(m, evaluations=m.evaluations + res.nfev)


def _features(capture: Capture, model: np.ndarray, model_vt: np.ndarray, edges: EdgeSearch, floor: NoiseFloor,
              unit: Unit, efd0_model: float) -> tuple[list[F.Feature], dict[str, float]]:
    """The feature tests, and the hints they give the effect fits' starting values. On line the
    steady-state ratio is not tested (efd / Vt = 1 + Sat holds at no load only): the pre-trigger
    level against the model's steady state at the record's operating point stands for it."""
    values = unit.values()
    on_line = capture.on_line
    sigma = math.sqrt(floor.variance)
    efd_pre = float(np.mean(capture.efd[:floor.n]))
    efd_se = sigma / math.sqrt(floor.n)
    vt_pre = float(np.mean(capture.vt[:floor.n])) if capture.vt is not None else None
    vt = capture.vt if capture.vt is not None else model_vt
    feats = [
        F.flat_top(capture.efd, model, capture.dt, edges, sigma, vt=vt, vt_recorded=capture.vt is not None),
        F.delay(capture.efd, model, capture.dt, edges, sigma),
        *(() if on_line else (F.steady_state_ratio(efd_pre, efd_se, vt_pre, values["Vt0"]),)),
        F.pre_trigger_level(efd_pre, efd_se, efd0_model, on_line=on_line),
        F.asymmetry(capture.efd, model, capture.dt, edges, sigma),
        F.edge_shape(capture.efd, model, capture.dt, edges, sigma, edges.lead.jump_pu),
    ]
    fv = {f.name: f.values for f in feats}
    hints = {
        "top_level": fv["flat_top"]["top_level"], "bottom_level": fv["flat_top"]["bottom_level"],
        "top_level_vt": fv["flat_top"].get("top_level_vt", math.nan),
        "bottom_level_vt": fv["flat_top"].get("bottom_level_vt", math.nan),
        "delay_s": fv["delay"]["delay_s"],
        "sat0": efd_pre - fv["steady_state_ratio"]["vt"] if not on_line else math.nan,
        "slope_up": fv["asymmetry"].get("slope_up", math.nan),
        "slope_down": fv["asymmetry"].get("slope_down", math.nan),
        "gain": fv["pre_trigger_level"]["ratio"],
        "xe": float(unit.grid.get("XE", math.nan)),
    }
    return feats, hints


def _fit_effects(st: Setup, base: ModelFit, hints: Mapping[str, float], budget: Budget,
                 seed: int) -> tuple[dict[str, ModelFit], set[str]]:
    """Every effect: local fits from the starts (coarse), MVMO for the leaders, polish of the leaders;
    and the effects that had the MVMO searches (not at the floor after their local fits)."""
    views, n = st.views, st.n
    avr = {**base.params}
    starts = all_starts(views, lag_variants(st.views.unit, avr), hints)
    # each stage's fits share nothing: side by side on the machine's cores (`threads`), each with
    # the seed of its place
    def local(item: tuple[int, str]) -> ModelFit:
        i, e = item
        t0 = time.perf_counter()
        m = fit_model(views, (e,), [{**avr, **s} for s in starts[e]], evals=0, seed=seed + 1 + i,
                      polish_coarse=budget.polish_coarse, polish_fine=0, multi=budget.starts)
        log.info("effect %s: mse %.4g (%d evaluations, %.1f s)", e, m.mse, m.evaluations, time.perf_counter() - t0)
        return m

    vocabulary = views.vocabulary
    fits: dict[str, ModelFit] = dict(zip(vocabulary, map_fits(local, enumerate(vocabulary))))

    # global searches (MVMO) for the leaders that are not yet at the noise floor
    def search(item: tuple[int, str]) -> ModelFit:
        i, e = item
        t0 = time.perf_counter()
        m = global_search(views, fits[e], evals=budget.effect, profile_evals=budget.profile,
                          seed=seed + 11 + i, polish_coarse=budget.polish_coarse, floor_tol=st.floor_tol)
        log.info("effect %s global search: mse %.4g (%.1f s)", e, m.mse, time.perf_counter() - t0)
        return m

    ranked = sorted(fits, key=lambda e: bic(n, fits[e].mse, fits[e].k))
    leaders = [(i, e) for i, e in enumerate(ranked[:budget.global_top]) if fits[e].mse > st.floor_tol]
    fits.update(zip((e for _, e in leaders), map_fits(search, leaders)))
    searched = {e for _, e in leaders}
    # the leaders (and every effect close to the best) get the least-squares polish on the full
    # record, edge instants free; so does a nested model worse than the base model there: its
    # coarse-record solution did not carry over (e.g. a lag near the coarse step)
    ranked = sorted(fits, key=lambda e: bic(n, fits[e].mse, fits[e].k))
    best = bic(n, fits[ranked[0]].mse, fits[ranked[0]].k)
    polished = [e for j, e in enumerate(ranked)
                if (j < budget.polish_top or close_to_best(bic(n, fits[e].mse, fits[e].k) - best)
                    or fits[e].mse > base.mse)]
    fits.update(zip(polished, map_fits(lambda e: refine(views, fits[e], polish_fine=budget.effect_polish), polished)))
    return fits, searched


def _variants(st: Setup, fits: dict[str, ModelFit], budget: Budget, seed: int) -> dict[str, str]:
    """Each effect's variants (`Effect.variants`: the ceiling of a bus-fed static exciter, limits
    x Vt; with a recorded field current, also with the commutation drop KC*Ifd fitted) tried from
    the plain fit's values; the best by BIC is kept in `fits`. Returns each such effect's kept
    form by its label."""
    views, n = st.views, st.n

    def tried(e: str) -> tuple[ModelFit, str]:
        first = fits[e]
        eff = VOCABULARY[e]
        best, name = first, eff.plain
        for v in eff.variants:
            if v.needs is not None and v.needs not in views.capture.extra:
                continue
            start = {**first.params, **v.extra}
            m = fit_model(views, (e,), [start], evals=0, seed=seed + 41, fixed=dict(v.fixed), extra=tuple(v.extra),
                          polish_coarse=budget.polish_coarse, polish_fine=budget.effect_polish)
            log.info("%s variant %s: mse %.4g (%s %.4g)", e, v.label, m.mse, eff.plain, first.mse)
            if m.feasible and bic(n, m.mse, m.k) < bic(n, best.mse, best.k) - 2.0:
                best, name = m, v.label
        return best, name

    # each effect's variants apart from the others' (`threads`)
    with_variants = [e for e in fits if VOCABULARY[e].variants]
    kept = {}
    for e, (best, name) in zip(with_variants, map_fits(tried, with_variants)):
        fits[e] = best
        kept[e] = name
    return kept


def _edges(st: Setup, m: ModelFit) -> tuple[Edge, ...]:
    """Each setpoint edge of the capture at the base model's fit (nominal and fitted instant, std),
    and of the holdout (its instants fitted with the base model held)."""
    p = st.views.problem((), m.fixed)
    x = SearchSpace(p).vector(m.params)
    out = [replace(e, capture="capture") for e in p.edges(x, m.std)[0]]
    if st.views.holdout is not None:
        h, res = fit_holdout(st.views, p.values(x))
        out += [replace(e, capture="holdout") for e in h.edges(res.x)[0]]
    return tuple(out)


def diagnose(capture: Capture, unit: Unit, **kwargs: Any) -> Diagnosis:
    """`_diagnose` with BLAS on one thread (the same answer on any machine, alone or in a batch;
    see identification.identify.run_identification), said in the unit's structure's names: the
    diagnosis, built in the kernel's, renamed once, and a refusal of its problem (constraints
    that contradict each other, a bound) too, whose text names the kernel's parameters."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        try:   # the boundary: the structure's names (`written`)
            return written(_on_its_test(capture, unit, **kwargs), unit.structure)
        except (ProblemError, ConstraintError) as exc:
            raise written(exc, unit.structure) from None


def _on_its_test(capture: Capture, unit: Unit, *, holdout: Capture | None = None, **kwargs: Any) -> Diagnosis:
    """`_diagnose` on the test's part of an on-line capture and holdout (`span.cut_to_test`: not the
    operation before it, which every model holds at the record's operating point), its instants
    written in the whole records' seconds (`span.on_record`)."""
    part, k0 = cut_to_test(capture)
    hold, k0_h = cut_to_test(holdout)
    if k0:
        log.info("%s: diagnosed from %.2f s, %.1f s before the step (the %d samples before it, where every model "
                 "holds the operating point, are not simulated)", capture.source or "capture", k0 * capture.dt,
                 PRE_STEP_S, k0)
    d = _diagnose(part, unit, holdout=hold, **kwargs)
    return on_record(d, k0, capture.dt, k0_h, holdout.dt if holdout is not None else 0.0)


def _diagnose(capture: Capture, unit: Unit, *, holdout: Capture | None = None, seed: int = 0,
              budget: Budget | None = None, base_params: Mapping[str, float] | None = None,
              command_line: str = "") -> Diagnosis:
    """The diagnosis of `capture` against `unit` (see the module docstring); non-finite figures
    are None, as the JSON writes them."""
    t_start = time.perf_counter()
    budget = budget if budget is not None else Budget()
    edges, efd_floor, st = prepare(capture, unit, holdout=holdout, budget=budget)
    floor = st.floor
    views = st.views

    t0 = time.perf_counter()
    base = _fit_base(st, budget, seed, base_params)
    log.info("base fit: mse %.4g (%d evaluations, %.1f s)", base.mse, base.evaluations, time.perf_counter() - t0)
    p0 = views.problem(())
    s0 = SearchSpace(p0)
    traces = p0.simulate(s0.vector(base.params))[0]
    sim = traces["efd"]
    # the model's steady field voltage at the unit file's values (no load: Vt0 + Sat(Vt0); on line:
    # at the record's P, Q, Vt), against the recorded pre-trigger efd
    feats, hints = _features(capture, sim, traces["vt"], edges, efd_floor, unit, p0.steady_efd(p0.x_start()))

    fits, searched = _fit_effects(st, base, hints, budget, seed)
    variants = _variants(st, fits, budget, seed)
    # the base fit may sit in a worse basin than the model parameters an effect fit reached
    better = refine_base(views, base, [m.params for m in fits.values()], polish_evals=budget.base_polish)
    if better is not None:
        log.info("base fit improved from the effect fits: mse %.4g -> %.4g", base.mse, better.mse)
        base = finish(views, (), {}, s0.vector(better.params), polish_fine=budget.base_polish,
                      noise_variance=floor.variance)
        sim = p0.simulate(s0.vector(base.params))[0]["efd"]
    loc = localization(sim - capture.efd, capture.dt, edges)
    base = checked(views, base)
    # the check for the effects that improve the fit most (at most CHECKED; the others cannot be
    # significant or could not lead)
    n = st.n
    gains = sorted(((bic(n, base.mse, 0) - bic(n, m.mse, m.k), e) for e, m in fits.items()), reverse=True)
    to_check = [e for g, e in gains[:CHECKED] if worth_checking(g)]
    fits.update(zip(to_check, map_fits(lambda e: checked(views, fits[e]), to_check)))

    entries = rank_entries(unit, st, base, fits, variants)
    at_floor = base.mse <= st.floor_tol
    verdict = choose_verdict(entries, at_floor=at_floor, has_check=True)
    if verdict != "none" and verdict not in searched and fits[verdict].mse > st.floor_tol:
        # the verdict rests on a local fit (it led only on the check): it gets the leaders' search
        m = global_search(views, fits[verdict], evals=budget.effect, profile_evals=budget.profile, seed=seed + 31,
                          polish_coarse=budget.polish_coarse, floor_tol=st.floor_tol)
        m = refine(views, m, polish_fine=budget.effect_polish)
        log.info("verdict %s searched: mse %.4g -> %.4g", verdict, fits[verdict].mse, m.mse)
        if m.mse < fits[verdict].mse:
            fits[verdict] = checked(views, m)
            entries = rank_entries(unit, st, base, fits, variants)
            verdict = choose_verdict(entries, at_floor=at_floor, has_check=True)
    ambiguous = ambiguous_pairs(entries) if verdict != "none" else []
    steps, final = (sequence(st, fits, verdict, hints, budget, seed) if verdict != "none" else ([], None))
    explained, left = explained_by(st, base, steps, final, capture, edges)
    added = [SequenceEntry(s["added"], s["model"].mse, s["model"].mse_check, s["model"].effect_params(),
                           s["dropped"]) for s in steps]
    hold = st.validation.check.holdout
    diagnosis = Diagnosis(
        schema=SCHEMA,
        software_version=getattr(bench_ctl, "__version__", "0.1.0"),
        command_line=command_line,
        created_utc=utc_now_text(),
        capture=_capture_ref(capture),
        holdout=_capture_ref(holdout),
        unit=unit.entry(),
        validation=st.validation,
        check=st.validation.check,
        edges=_edges(st, base),
        base=BaseFit(params=model_params(unit, base), mse=base.mse, mse_holdout=base.mse_check,
                     check=check_entry(base), evaluations=int(base.evaluations), at_noise_floor=bool(at_floor)),
        noise_floor=floor.variance,
        noise_floor_detail=NoiseFloorDetail(samples=floor.n, t0=floor.t0, t1=floor.t1, rel_se=floor.rel_se,
                                            check=st.check_floor, holdout=hold.noise_floor if hold else None),
        localization=loc,
        features=tuple(f.entry() for f in feats),
        effects=tuple(entries),
        ambiguous=tuple(ambiguous),
        sequence=tuple(added),
        explained_by=tuple(explained),
        left=left,
        verdict=verdict,
        criteria=Criteria(**criteria(), floor_sigmas=budget.floor_sigmas,
                          score="BIC on the capture + sum over the check's parts of n ln(mse), relative to the "
                                "base model"),
        wall_s=time.perf_counter() - t_start,
        vocabulary=_vocabulary(views),
    )
    return diagnosis     # in the kernel's names: `diagnose` renames it


def _vocabulary(views: Views) -> Vocabulary:
    """The JSON `vocabulary`: the effects tried on this record and why the others were not."""
    tried = views.vocabulary
    why = {}
    for name, e in VOCABULARY.items():
        if name in tried:
            continue
        if views.on_line and not e.on_line:
            why[name] = "not tried on line yet"
        elif not views.on_line and not e.at_no_load:
            why[name] = "acts on line only"
        else:
            why[name] = "the unit fits " + ", ".join(e.params)
    return Vocabulary(views.on_line, list(tried), why)
