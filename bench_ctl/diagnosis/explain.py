"""Several effects at once (`explained_by`): from the verdict, effects are added one at a time,
every parameter re-fitted jointly, while the next one is significant on the fit and on the check;
after each addition an earlier effect that no longer earns its place is dropped (one that stood in
for the effect just added). Then what is left: the error against the noise floor and where it lies.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Mapping

from bench_ctl.capture import Capture
from bench_ctl.identification.fit_check import bic, check_deviance, checked, score
from bench_ctl.identification.localize import localization
from bench_ctl.identification.model_fits import Budget, ModelFit, Setup
from bench_ctl.identification.space import SearchSpace
from bench_ctl.identification.threads import map_fits
from bench_ctl.model.effects import VOCABULARY
from bench_ctl.signals.edges import EDGE_PARAMS, EdgeSearch

from .diagnosis_file import Left, Step, StepCheck
from .search import finish, fit_model, refine
from .significance import Significance, kept_without_check, significance, step_gain
from .starts import effect_starts
from .verdict import check_entry, model_params

__all__ = ["sequence", "explained_by"]

log = logging.getLogger(__name__)


def combine(st: Setup, current: ModelFit, c: str, single: ModelFit, hints: Mapping[str, float],
            budget: Budget, seed: int) -> ModelFit:
    """current + effect c, every parameter re-fitted jointly on the coarse record from current's
    values with c's own fit and with c's feature starts (the single fit may have missed an effect
    that another one hid), then evaluated on the full record (not polished there yet)."""
    starts = [{**current.params, **single.effect_params()}]
    # a grid effect's values trade against the grid's already fitted (XE against a stabiliser's
    # gain): its single fit, made with the grid as the unit file had it, is no good start, so
    # every start of its grid is tried
    grid = effect_starts(c, hints)
    starts += [{**current.params, **s} for s in (grid if VOCABULARY[c].frees_grid else grid[:1])]
    return fit_model(st.views, current.effects + (c,), starts, evals=0, seed=seed,
                     fixed={**current.fixed, **single.fixed}, extra=current.extra + single.extra,
                     polish_coarse=budget.polish_coarse // 2, polish_fine=0, multi=len(starts), profile=False)


def without(st: Setup, m: ModelFit, e: str, budget: Budget, *, check: bool = True) -> ModelFit:
    """m with effect e taken out (its parameters back to neutral), the rest re-fitted; checked
    unless the fit loses so much (`significance.kept_without_check`) that the check could not change
    the answer."""
    effects = tuple(x for x in m.effects if x != e)
    fixed = {k: v for k, v in m.fixed.items() if k not in VOCABULARY[e].options}
    extra = tuple(x for x in m.extra if x not in VOCABULARY[e].options)
    p = st.views.problem(effects, fixed, extra=extra)
    out = finish(st.views, effects, fixed, SearchSpace(p).vector(m.params), polish_fine=budget.combo_polish,
                 extra=extra)
    if not check or kept_without_check(bic(st.n, out.mse, out.k) - bic(st.n, m.mse, m.k)):
        return out
    return checked(st.views, out)


def sequence(st: Setup, fits: Mapping[str, ModelFit], verdict: str, hints: Mapping[str, float], budget: Budget,
             seed: int) -> tuple[list[dict], ModelFit]:
    """The effects that together explain the record: from the verdict, screen every other effect
    jointly re-fitted on the coarse record, polish the two best on the full record, and add the
    first whose step is significant on the fit and on the check; after each addition drop an
    earlier effect whose removal the fit and the check do not notice."""
    current = checked(st.views, fits[verdict])
    steps = [{"added": verdict, "model": current, "dropped": [], "fit_gain": None, "check_gain": None}]
    dropped_all: set[str] = set()
    min_gain = step_gain(st.n)
    while len(current.effects) < budget.max_sequence:
        cands = [c for c in st.views.vocabulary if c not in current.effects and c not in dropped_all]
        if not cands:
            break
        # the current model polished as far as each candidate will be: a gain is then the effect's
        ref = refine(st.views, current, polish_fine=budget.combo_polish)
        if ref is not current:
            current = checked(st.views, ref)
        # each candidate, and then each of the two best, apart from the others (`threads`)
        screened = sorted(map_fits(lambda c, now=current: combine(st, now, c, fits[c], hints, budget, seed), cands),
                          key=lambda m: bic(st.n, m.mse, m.k))
        for m in screened:
            log.info("explained_by after %s: + %s screened, fit gain %.1f", "+".join(current.effects), m.effects[-1],
                     bic(st.n, current.mse, current.k) - bic(st.n, m.mse, m.k))
        accepted, gains, best_score = None, (0.0, 0.0), math.inf
        better_current = None
        # the two best on the coarse screen are polished and checked
        for m, reduced, judged in map_fits(lambda m, now=current: _judged(st, now, m, budget, min_gain),
                                           screened[:2]):
            if reduced is not None and (better_current is None or reduced.mse < better_current.mse):
                better_current = reduced
            if judged is not None:
                g, sc = judged
                if g.significant and g.fit > min_gain and sc < best_score:
                    accepted, gains, best_score = m, (g.fit, g.check), sc
        if accepted is None and better_current is not None:
            current = checked(st.views, better_current)   # the re-fit without the candidate is better
        if accepted is None:
            break
        current = accepted
        dropped = []
        for e in current.effects[:-1]:
            reduced = without(st, current, e, budget)
            g = significance(st, reduced, current) if reduced.checks else Significance(math.inf, math.inf, True)
            log.info("explained_by: without %s the fit loses %.1f, the check %.1f", e, g.fit, g.check)
            if not g.significant:
                log.info("explained_by: %s dropped after %s was added", e, current.effects[-1])
                dropped.append(e)
                current = reduced
        dropped_all.update(dropped)
        steps.append({"added": accepted.effects[-1], "model": current, "dropped": dropped,
                      "fit_gain": gains[0], "check_gain": gains[1]})
    if current.effects == steps[-1]["model"].effects:
        # the last step as far as it was polished (the next round's refine): the figures `left` gives
        steps[-1]["model"] = current
    return steps, current


def _judged(st: Setup, current: ModelFit, m: ModelFit, budget: Budget, min_gain: float
            ) -> tuple[ModelFit, ModelFit | None, tuple[Significance, float] | None]:
    """One of `sequence`'s two best candidates: polished, and judged against the current model
    and the model re-fitted without the candidate from m's own values (what the joint re-fit gained
    by moving the other parameters further is not the candidate's). Returns m polished (and
    checked when judged), that re-fit when it beats the current model but m gains nothing over it,
    and the significance and score change when m was judged."""
    m = refine(st.views, m, polish_fine=budget.combo_polish)
    c = m.effects[-1]
    if bic(st.n, current.mse, current.k) - bic(st.n, m.mse, m.k) <= min_gain:
        return m, None, None
    reduced = without(st, m, c, budget, check=False)
    ref = reduced if bic(st.n, reduced.mse, reduced.k) < bic(st.n, current.mse, current.k) else current
    if bic(st.n, ref.mse, ref.k) - bic(st.n, m.mse, m.k) <= min_gain:
        log.info("explained_by after %s: + %s gains nothing over the model re-fitted without it",
                 "+".join(current.effects), c)
        return m, (reduced if ref is reduced else None), None
    m = checked(st.views, m)
    ref = checked(st.views, ref)
    g = significance(st, ref, m)
    # of the significant ones, the best on the fit and the check together
    sc = score(m, st.n) - score(ref, st.n)
    log.info("explained_by after %s: + %s fit gain %.1f check gain %.1f score %.1f -> %s",
             "+".join(current.effects), c, g.fit, g.check, sc, "significant" if g.significant else "refused")
    return m, None, (g, sc)


#: what is left after the explaining effects, over the noise floor, beyond which the rest is called
#: "a structure the vocabulary lacks"
LACKS = 2.0


def explained_by(st: Setup, base: ModelFit, steps: list[dict], final: ModelFit | None, capture: Capture,
                 edges: EdgeSearch) -> tuple[list[Step], Left]:
    """The effects that together explain the record (in the order added, each re-fitted jointly
    with those before it), and what is left after the last: its error against the noise floor and
    where in the record it lies."""
    floor = st.floor.variance
    span = base.mse - floor
    out = []
    prev = base
    for step in steps:
        m: ModelFit = step["model"]
        params = m.effect_params()
        params.update({k: v for k, v in m.fixed.items()})
        checks = check_entry(m)
        out.append(Step(
            name=step["added"], effects=list(m.effects), dropped=step["dropped"],
            params=params, avr_params=model_params(st.views.unit, m),
            mse=m.mse, mse_over_floor=m.mse / floor,
            gap_closed=(base.mse - m.mse) / span if span > 0 else None,
            edges={k: v for k, v in m.params.items() if k in EDGE_PARAMS},
            fit_gain=step["fit_gain"] if step["fit_gain"] is not None else
            bic(st.n, prev.mse, prev.k) - bic(st.n, m.mse, m.k),
            check=StepCheck(on=st.validation.kind, mse=m.mse_check, mse_before=prev.mse_check,
                            gain=step["check_gain"] if step["check_gain"] is not None else check_deviance(prev, m),
                            parts=checks.parts if checks is not None else None)))
        prev = m
    model = final if final is not None else base
    p = st.views.problem(model.effects, model.fixed, extra=model.extra)
    x = SearchSpace(p).vector(model.params)
    resid = p.simulate(x)[0]["efd"] - capture.efd
    ratio = model.mse / floor
    if model.mse <= st.floor_tol:
        note = "at the noise floor: nothing left to explain"
    elif ratio <= LACKS:
        note = f"{ratio:.2f} x the noise floor: close to it"
    else:
        note = (f"{ratio:.1f} x the noise floor: a structure the vocabulary lacks (or an effect it could "
                "not fit); see where it lies")
    left = Left(mse=model.mse, mse_over_floor=ratio, effects=list(model.effects), note=note,
                localization=localization(resid, capture.dt, edges))
    return out, left
