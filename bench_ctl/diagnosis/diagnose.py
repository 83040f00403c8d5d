"""Sim-to-real gap diagnosis of one capture: where the model misses, which effects, how far it shrinks.

`diagnose(capture, unit, holdout=...)` returns the diagnosis JSON (docs/formats.md, schema
"bench-ctl/diagnosis/1"). Every model is fitted on the whole capture with identification's
objective (`identification.problem`: the unit's identified parameters, the effects' parameters
and the instant of every setpoint edge, `effect_fits.Views`):

1. Base fit: MVMO on the coarse record (started from the unit's values, or `base_params` when a
   previous identification is given), polished by least squares on the full record; re-polished
   from an effect fit's parameters when those fit the base model better (the base model is
   multimodal; the effect fits explore it too).
2. Noise floor (pre-trigger efd variance), localization (residual energy per segment and band),
   feature tests (flat top - also relative to a ceiling that moves with Vt -, delay, steady-state
   ratio, pre-trigger level, asymmetry, edge shape).
3. Every effect re-identified with the base model, warm-started from the base fit; the ceiling
   also as a bus-fed exciter's (limits x Vt) and, with a recorded field current, with the
   commutation drop KC*Ifd; ranked by BIC plus the predictive deviance on the check; `none` when
   no effect is significant, or when the base model fits to the noise floor and no effect brings
   a strong (`STRONG`) gain; near-equal effects listed in `ambiguous` with the test that
   separates them.
4. Several effects at once (`explained_by`): effects are added one at a time, all parameters
   re-fitted jointly, while the next one is significant on the fit and on the check; after each
   addition an earlier effect that no longer earns its place is dropped (one that stood in for
   the effect just added). Then what is left: the error against the noise floor and where it
   lies.

The check (`effect_fits.check_parts`): the cross-validation windows of the capture (leading
edge, plateau, trailing edge; each left out of a re-fit and scored: `CV_SEGMENTS`, the recovery
is never one), the recorded Vt when the fit did not use it, and the holdout capture when one is
given.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

import bench_ctl
from bench_ctl.capture import Capture
from bench_ctl.model.edges import EDGE_PARAMS
from bench_ctl.model.effects import EFFECTS, EFFECT_NAMES
from bench_ctl.model.kernel import saturation_ab
from bench_ctl.model.unit import Unit

from . import features as F
from .effect_fits import (AMBIGUOUS, CHECK_GAIN, SIGNIFICANT, STRONG, ModelFit, Views, Window, aic, all_starts,
                          ambiguous_pairs, bic, check_deviance, checked, describe_check, edge_names, effect_starts,
                          finish, fit_model, global_search, lag_variants, refine, refine_base, score)
from .fit import Space, coarse_factor, fit, simulate_efd
from .localize import DiagnosisError, Edges, NoiseFloor, find_edges, localization, noise_floor, segments

log = logging.getLogger(__name__)

SCHEMA = "bench-ctl/diagnosis/1"


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
                               # lag (reference unit: TE >= 2 ms), see `fit.coarse_factor`
    coarse_tail_s: float = 3.0 # the coarse record ends this long after the trailing edge
    combo_polish: int = 60
    max_sequence: int = 3
    sequence_candidates: int = 4  # effects tried at each step of explained_by
    floor_sigmas: float = 3.0


def _sha256(path: str) -> str | None:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def _capture_ref(c: Capture | None) -> dict | None:
    if c is None:
        return None
    return {"path": c.source or None, "sha256": (_sha256(c.source) if c.source else None)
            or c.meta.get("csv_sha256")}


def _efd0_model(values: Mapping[str, float]) -> float:
    a, b = saturation_ab(np.array([values["S10"]]), np.array([values["S12"]]))
    vt0 = values["Vt0"]
    sat = float(b[0] * (vt0 - a[0]) ** 2) if vt0 > a[0] else 0.0
    return vt0 + sat


def _gap(mse_base: float | None, mse_eff: float | None, floor: float, floor_se: float) -> tuple[float | None, float | None]:
    """gap_closed with the denominator kept at least one standard error of the floor; and raw."""
    if mse_base is None or mse_eff is None or not math.isfinite(mse_eff):
        return None, None
    num = mse_base - mse_eff
    den = mse_base - floor
    raw = num / den if den != 0 else None
    return num / max(den, floor * floor_se), raw


#: effects checked after the single-effect fits: those that lower the BIC most
CHECKED = 4

#: cross-validation windows: the segments of the record (localize.segments) each left out in turn.
#: Not the recovery: it is most of the record and holds what determines the slow time constants,
#: so the rest cannot predict it for any model; it stays in every fit (docs/decisions/0010).
CV_SEGMENTS = ("leading_edge", "plateau", "trailing_edge")


@dataclass(frozen=True, eq=False)
class _Setup:
    """What every step works on: the views of the capture, the noise floors and the tolerance."""
    views: Views
    n: int               # samples of the capture (every model is fitted on all of them)
    floor: NoiseFloor
    check_floor: float   # the check's noise floor (pooled: holdout floor and the capture's)
    check_se: float
    floor_tol: float     # base MSE up to this counts as "at the noise floor"
    validation: dict


def _windows(capture: Capture, edges: Edges) -> tuple[Window, ...]:
    dt = capture.dt
    return tuple(Window(s.name, s.k0 * dt, (s.k1 - 1) * dt) for s in segments(capture.n, dt, edges)
                 if s.name in CV_SEGMENTS and s.k1 - s.k0 >= 5)


def _setup(capture: Capture, holdout: Capture | None, unit: Unit, edges: Edges, floor: NoiseFloor,
           budget: Budget) -> _Setup:
    windows = _windows(capture, edges)
    if not windows:
        raise DiagnosisError(f"{capture.source or 'capture'}: too short after the setpoint change for a check")
    q = coarse_factor(unit, capture.dt, budget.coarse_dt)
    if edges.k_off is not None:  # both setpoint edges on the coarse grid, or the trailing one moves
        q = math.gcd(q, edges.k_off - edges.k_on) or 1
    n_coarse = capture.n if edges.k_off is None else min(capture.n, edges.k_off + int(round(budget.coarse_tail_s /
                                                                                            capture.dt)))
    views = Views(unit, capture, holdout, q, n_coarse, edges.k_on, windows)
    check_floor, check_se = floor.variance, floor.rel_se
    hold = None
    if holdout is not None:
        h_src = holdout.source or "holdout"
        h_floor = noise_floor(holdout.efd, holdout.dt, find_edges(holdout.usetp, h_src), h_src)
        n_w = sum(int(round((w.t1 - w.t0) / capture.dt)) + 1 for w in windows)
        check_floor = (h_floor.variance * holdout.n + floor.variance * n_w) / (holdout.n + n_w)
        check_se = max(h_floor.rel_se, floor.rel_se)
        hold = {"capture": holdout.source or None, "t0": 0.0, "t1": float(holdout.time[-1] - holdout.time[0]),
                "noise_floor": h_floor.variance}
    floor_tol = floor.variance * (1.0 + budget.floor_sigmas * math.sqrt(floor.rel_se ** 2 + 2.0 / capture.n))
    validation = {"kind": "holdout + windows" if holdout is not None else "windows",
                  "fit": {"t0": 0.0, "t1": (capture.n - 1) * capture.dt},
                  "check": {**describe_check(views), "holdout": hold}}
    return _Setup(views, capture.n, floor, check_floor, check_se, floor_tol, validation)


def _fit_base(st: _Setup, budget: Budget, seed: int, base_params: Mapping[str, float] | None) -> ModelFit:
    """The base model identified as `bench-ctl identify` does (MVMO on the whole record with the
    edge instants held mid-interval, then one joint least-squares polish, `peers.run_optimizer`),
    from the unit's values (or `base_params`), then the diagnosis' own polish for the standard
    deviations. (The coarse-record search the effects use left an effect-free record further from
    the noise floor than identification does, and an effect then filled the difference:
    docs/decisions/0010.)"""
    from bench_ctl.identification.peers import run_optimizer

    views = st.views
    p = views.problem(())
    space = Space.of(p)
    x0 = space.vector({n: float((base_params or {}).get(n, views.unit.identify[n].value))
                       for n in views.unit.identified_names})
    res = run_optimizer("mvmo", p, max_evals=budget.base, seed=seed, x0=x0)
    m = finish(views, (), {}, np.clip(res.x, space.lo, space.hi), polish_fine=budget.base_polish,
               noise_variance=st.floor.variance)
    return replace(m, evaluations=m.evaluations + res.nfev)


def _model_params(unit: Unit, m: ModelFit) -> dict[str, float]:
    return {n: m.params[n] for n in unit.identified_names}


def _features(capture: Capture, model: np.ndarray, model_vt: np.ndarray, edges: Edges, floor: NoiseFloor,
              values: Mapping[str, float]) -> tuple[list[F.Feature], dict[str, float]]:
    """The feature tests, and the hints they give the effect fits' starting values."""
    sigma = math.sqrt(floor.variance)
    efd_pre = float(np.mean(capture.efd[:floor.n]))
    efd_se = sigma / math.sqrt(floor.n)
    vt_pre = float(np.mean(capture.vt[:floor.n])) if capture.vt is not None else None
    vt = capture.vt if capture.vt is not None else model_vt
    feats = [
        F.flat_top(capture.efd, model, capture.dt, edges, sigma, vt=vt, vt_recorded=capture.vt is not None),
        F.delay(capture.efd, model, capture.dt, edges, sigma),
        F.steady_state_ratio(efd_pre, efd_se, vt_pre, values["Vt0"]),
        F.pre_trigger_level(efd_pre, efd_se, _efd0_model(values)),
        F.asymmetry(capture.efd, model, capture.dt, edges, sigma),
        F.edge_shape(capture.efd, model, capture.dt, edges, sigma, edges.amplitude),
    ]
    fv = {f.name: f.values for f in feats}
    hints = {
        "top_level": fv["flat_top"]["top_level"], "bottom_level": fv["flat_top"]["bottom_level"],
        "top_level_vt": fv["flat_top"].get("top_level_vt", math.nan),
        "bottom_level_vt": fv["flat_top"].get("bottom_level_vt", math.nan),
        "delay_s": fv["delay"]["delay_s"],
        "sat0": efd_pre - fv["steady_state_ratio"]["vt"],
        "slope_up": fv["asymmetry"].get("slope_up", math.nan),
        "slope_down": fv["asymmetry"].get("slope_down", math.nan),
        "gain": fv["pre_trigger_level"]["ratio"],
    }
    return feats, hints


def _fit_effects(st: _Setup, base: ModelFit, hints: Mapping[str, float], budget: Budget,
                 seed: int) -> dict[str, ModelFit]:
    """Every effect: local fits from the starts (coarse), MVMO for the leaders, polish of the leaders."""
    views, n = st.views, st.n
    avr = {**base.params}
    starts = all_starts(views, lag_variants(st.views.unit, avr), hints)
    fits: dict[str, ModelFit] = {}
    for i, e in enumerate(EFFECT_NAMES):
        t0 = time.perf_counter()
        fits[e] = fit_model(views, (e,), [{**avr, **s} for s in starts[e]], evals=0, seed=seed + 1 + i,
                            polish_coarse=budget.polish_coarse, polish_fine=0, multi=budget.starts)
        log.info("effect %s: mse %.4g (%d evaluations, %.1f s)", e, fits[e].mse, fits[e].evaluations,
                 time.perf_counter() - t0)
    # global searches (MVMO) for the leaders that are not yet at the noise floor
    ranked = sorted(fits, key=lambda e: bic(n, fits[e].mse, fits[e].k))
    for i, e in enumerate(ranked[:budget.global_top]):
        if fits[e].mse <= st.floor_tol:
            continue
        t0 = time.perf_counter()
        fits[e] = global_search(views, fits[e], evals=budget.effect, profile_evals=budget.profile,
                                seed=seed + 11 + i, polish_coarse=budget.polish_coarse, floor_tol=st.floor_tol)
        log.info("effect %s global search: mse %.4g (%.1f s)", e, fits[e].mse, time.perf_counter() - t0)
    # the leaders (and every effect close to the best) get the least-squares polish on the full
    # record, edge instants free; so does a nested model worse than the base model there: its
    # coarse-record solution did not carry over (e.g. a lag near the coarse step)
    ranked = sorted(fits, key=lambda e: bic(n, fits[e].mse, fits[e].k))
    best = bic(n, fits[ranked[0]].mse, fits[ranked[0]].k)
    for j, e in enumerate(ranked):
        if (j < budget.polish_top or bic(n, fits[e].mse, fits[e].k) - best < 2 * SIGNIFICANT
                or fits[e].mse > base.mse):
            fits[e] = refine(views, fits[e], polish_fine=budget.effect_polish)
    return fits


FIXED_LIMITS = "fixed limits"
BUS_FED = "bus-fed: VRMAX*Vt, VRMIN*Vt"
COMMUTATION = "bus-fed with commutation drop: VRMAX*Vt - KC*Ifd, VRMIN*Vt"


def _ceiling_variants(st: _Setup, fits: dict[str, ModelFit], budget: Budget, seed: int) -> str:
    """The ceiling of a bus-fed static exciter (limits x Vt, VRVT = 1) tried beside the fixed one
    from the fixed fit's values, and, when the capture records the field current (an `ifd`
    column), with the commutation drop KC*Ifd fitted too; the best by BIC is kept in `fits`.
    Returns the variant's name."""
    views, n = st.views, st.n
    fixed = fits["ceiling_limit"]
    tries = [(BUS_FED, {"VRVT": 1.0}, ())]
    if "ifd" in views.capture.extra:
        tries.append((COMMUTATION, {"VRVT": 1.0}, ("KC",)))
    best, name = fixed, FIXED_LIMITS
    for label, var, extra in tries:
        start = {**fixed.params, "KC": 0.05} if extra else dict(fixed.params)
        m = fit_model(views, ("ceiling_limit",), [start], evals=0, seed=seed + 41, fixed=var, extra=extra,
                      polish_coarse=budget.polish_coarse, polish_fine=budget.effect_polish)
        log.info("ceiling variant %s: mse %.4g (fixed limits %.4g)", label, m.mse, fixed.mse)
        if m.feasible and bic(n, m.mse, m.k) < bic(n, best.mse, best.k) - 2.0:
            best, name = m, label
    fits["ceiling_limit"] = best
    return name


def _significant(st: _Setup, ref: ModelFit, m: ModelFit) -> tuple[float, float, bool]:
    """(fit gain, check gain, significant) of m over ref: the BIC falls by more than SIGNIFICANT
    and the check's deviance by more than CHECK_GAIN."""
    gain_fit = bic(st.n, ref.mse, ref.k) - bic(st.n, m.mse, m.k)
    gain_check = check_deviance(ref, m)
    return gain_fit, gain_check, bool(gain_fit > SIGNIFICANT and gain_check > CHECK_GAIN and m.feasible)


def _entries(unit: Unit, st: _Setup, base: ModelFit, fits: Mapping[str, ModelFit], variant: str) -> list[dict]:
    """The ranked `effects` list of the JSON."""
    n = st.n
    s_base = score(base, n)
    floor = st.floor
    base_check = base.mse_check
    use_check = base_check is not None and base_check > st.check_floor * (1 + 3 * st.check_se)
    # a base model at the noise floor leaves no gap: a fraction of (nearly) nothing would be noise
    # scaled up (values like -60), so the headline gap_closed is None; the raw figures stay below
    at_floor = base.mse <= st.floor_tol
    entries = []
    for e, m in fits.items():
        d_bic, d_check, significant = _significant(st, base, m)
        g_check, g_check_raw = _gap(base_check, m.mse_check, st.check_floor, st.check_se)
        g_fit, g_fit_raw = _gap(base.mse, m.mse, floor.variance, floor.rel_se)
        hold_b, hold_m = base.part("holdout"), m.part("holdout")
        g_hold = g_hold_raw = None
        if hold_b is not None and hold_m is not None:
            g_hold, g_hold_raw = _gap(hold_b.mse, hold_m.mse, st.validation["check"]["holdout"]["noise_floor"],
                                      st.check_se)
        params = m.effect_params()
        entry = {
            "name": e, "params": params, "fixed": dict(m.fixed),
            "avr_params": _model_params(unit, m),
            "mse": m.mse, "mse_holdout": m.mse_check,
            "gap_closed": None if at_floor else (g_check if use_check else g_fit),
            "gap_closed_on": None if at_floor else ("check" if use_check else "fit"),
            "gap_closed_fit": g_fit, "gap_closed_fit_raw": g_fit_raw,
            "gap_closed_check": g_check, "gap_closed_check_raw": g_check_raw,
            "gap_closed_holdout": g_hold if hold_b is not None else g_check,
            "gap_closed_holdout_raw": g_hold_raw if hold_b is not None else g_check_raw,
            "check": _check_entry(m),
            "score": score(m, n) - s_base if m.checks else math.inf,
            "aic": aic(n, m.mse, m.k), "bic": bic(n, m.mse, m.k),
            "delta_bic": d_bic, "delta_check": d_check, "significant": significant,
            "k": m.k, "evaluations": m.evaluations, "start": {p: m.start.get(p) for p in params},
        }
        if e == "ceiling_limit":
            entry["variant"] = variant
        entries.append(entry)
    entries.sort(key=lambda d: (d["score"], -d["delta_bic"]))
    return entries


def _check_entry(m: ModelFit) -> dict[str, Any] | None:
    if not m.checks:
        return None
    return {"mse": m.mse_check, "parts": [{"label": p.label, "samples": p.n, "mse": p.mse} for p in m.checks]}


def choose_verdict(entries: list[dict], *, at_floor: bool, has_check: bool) -> str:
    """The verdict from the ranked `entries` (best score first): the best-scored SIGNIFICANT
    effect (one scored higher but worse on the check, or breaking a constraint, must not hide
    it), or `none`. At the noise floor (within the floor estimate's uncertainty) only a strong
    improvement counts: the floor comes from ~1000 pre-trigger samples, the likelihood ratio from
    the whole record."""
    top = next((e for e in entries if e["significant"]), None)
    if top is None:
        return "none"
    strong = top["delta_bic"] > STRONG and (not has_check or top["delta_check"] > SIGNIFICANT)
    return top["name"] if (strong or not at_floor) else "none"


def _combine(st: _Setup, current: ModelFit, c: str, single: ModelFit, hints: Mapping[str, float],
             budget: Budget, seed: int) -> ModelFit:
    """current + effect c, every parameter re-fitted jointly on the coarse record from current's
    values with c's own fit and with c's feature starts (the single fit may have missed an effect
    that another one hid), then evaluated on the full record (not polished there yet)."""
    starts = [{**current.params, **single.effect_params()}]
    starts += [{**current.params, **s} for s in effect_starts(c, hints)[:1]]
    return fit_model(st.views, current.effects + (c,), starts, evals=0, seed=seed,
                     fixed={**current.fixed, **single.fixed}, extra=current.extra + single.extra,
                     polish_coarse=budget.polish_coarse // 2, polish_fine=0, multi=len(starts), profile=False)


#: a fit loss this large when an effect is taken out keeps it without consulting the check
KEEP_WITHOUT_CHECK = 10 * STRONG
#: an effect added to others must explain at least this share of the error left: below it, the
#: differences between any plant and any model of it (integration, edge timing, a slightly other
#: limit rule) are of that size, and a flexible effect fits them (docs/decisions/0010, appendix)
STEP_REL = 0.01


def _without(st: _Setup, m: ModelFit, e: str, budget: Budget, *, check: bool = True) -> ModelFit:
    """m with effect e taken out (its parameters back to neutral), the rest re-fitted; checked
    unless the fit loses so much (KEEP_WITHOUT_CHECK) that the check could not change the answer."""
    effects = tuple(x for x in m.effects if x != e)
    fixed = {k: v for k, v in m.fixed.items() if k not in EFFECTS[e].options}
    extra = tuple(x for x in m.extra if x not in EFFECTS[e].options)
    p = st.views.problem(effects, fixed, extra=extra)
    out = finish(st.views, effects, fixed, Space.of(p).vector(m.params), polish_fine=budget.combo_polish, extra=extra)
    if not check or bic(st.n, out.mse, out.k) - bic(st.n, m.mse, m.k) > KEEP_WITHOUT_CHECK:
        return out
    return checked(st.views, out)


def _sequence(st: _Setup, fits: Mapping[str, ModelFit], verdict: str, hints: Mapping[str, float], budget: Budget,
              seed: int) -> tuple[list[dict], ModelFit]:
    """The effects that together explain the record: from the verdict, screen every other effect
    jointly re-fitted on the coarse record, polish the two best on the full record, and add the
    first whose step is significant on the fit and on the check; after each addition drop an
    earlier effect whose removal the fit and the check do not notice."""
    current = checked(st.views, fits[verdict])
    steps = [{"added": verdict, "model": current, "dropped": [], "fit_gain": None, "check_gain": None}]
    dropped_all: set[str] = set()
    step_gain = max(SIGNIFICANT, -st.n * math.log(1.0 - STEP_REL))
    while len(current.effects) < budget.max_sequence:
        cands = [c for c in EFFECT_NAMES if c not in current.effects and c not in dropped_all]
        if not cands:
            break
        # the current model polished as far as each candidate will be: a gain is then the effect's
        ref = refine(st.views, current, polish_fine=budget.combo_polish)
        if ref is not current:
            current = checked(st.views, ref)
        screened = sorted((_combine(st, current, c, fits[c], hints, budget, seed) for c in cands),
                          key=lambda m: bic(st.n, m.mse, m.k))
        for m in screened:
            log.info("explained_by after %s: + %s screened, fit gain %.1f", "+".join(current.effects), m.effects[-1],
                     bic(st.n, current.mse, current.k) - bic(st.n, m.mse, m.k))
        accepted, gains, best_score = None, (0.0, 0.0), math.inf
        better_current = None
        for m in screened[:2]:   # the two best on the coarse screen are polished and checked
            m = refine(st.views, m, polish_fine=budget.combo_polish)
            c = m.effects[-1]
            if bic(st.n, current.mse, current.k) - bic(st.n, m.mse, m.k) <= step_gain:
                continue
            # judged against the model without c re-fitted from m's own values as well: what the
            # joint re-fit gained by moving the other parameters further is not c's
            reduced = _without(st, m, c, budget, check=False)
            ref = reduced if bic(st.n, reduced.mse, reduced.k) < bic(st.n, current.mse, current.k) else current
            if bic(st.n, ref.mse, ref.k) - bic(st.n, m.mse, m.k) <= step_gain:
                log.info("explained_by after %s: + %s gains nothing over the model re-fitted without it",
                         "+".join(current.effects), c)
                if ref is reduced and (better_current is None or reduced.mse < better_current.mse):
                    better_current = reduced
                continue
            m = checked(st.views, m)
            ref = checked(st.views, ref)
            g = _significant(st, ref, m)
            # of the significant ones, the best on the fit and the check together
            sc = score(m, st.n) - score(ref, st.n)
            log.info("explained_by after %s: + %s fit gain %.1f check gain %.1f score %.1f -> %s",
                     "+".join(current.effects), c, g[0], g[1], sc, "significant" if g[2] else "refused")
            if g[2] and g[0] > step_gain and sc < best_score:
                accepted, gains, best_score = m, (g[0], g[1]), sc
        if accepted is None and better_current is not None:
            current = checked(st.views, better_current)   # the re-fit without the candidate is better
        if accepted is None:
            break
        current = accepted
        dropped = []
        for e in current.effects[:-1]:
            reduced = _without(st, current, e, budget)
            g = _significant(st, reduced, current) if reduced.checks else (math.inf, math.inf, True)
            log.info("explained_by: without %s the fit loses %.1f, the check %.1f", e, g[0], g[1])
            if not g[2]:
                log.info("explained_by: %s dropped after %s was added", e, current.effects[-1])
                dropped.append(e)
                current = reduced
        dropped_all.update(dropped)
        steps.append({"added": accepted.effects[-1], "model": current, "dropped": dropped,
                      "fit_gain": gains[0], "check_gain": gains[1]})
    return steps, current


#: what is left after the explaining effects, over the noise floor, beyond which the rest is called
#: "a structure the vocabulary lacks"
LACKS = 2.0


def _explained_by(st: _Setup, base: ModelFit, steps: list[dict], final: ModelFit | None, capture: Capture,
                  edges: Edges) -> tuple[list[dict], dict]:
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
        out.append({"name": step["added"], "effects": list(m.effects), "dropped": step["dropped"],
                    "params": params, "mse": m.mse, "mse_over_floor": m.mse / floor,
                    "gap_closed": (base.mse - m.mse) / span if span > 0 else None,
                    "edges": {k: m.params[k] for k in EDGE_PARAMS if k in m.params},
                    "fit_gain": step["fit_gain"] if step["fit_gain"] is not None else
                    bic(st.n, prev.mse, prev.k) - bic(st.n, m.mse, m.k),
                    "check": {"on": st.validation["kind"], "mse": m.mse_check, "mse_before": prev.mse_check,
                              "gain": step["check_gain"] if step["check_gain"] is not None else
                              check_deviance(prev, m), "parts": (_check_entry(m) or {}).get("parts")}})
        prev = m
    model = final if final is not None else base
    p = st.views.problem(model.effects, model.fixed, extra=model.extra)
    x = Space.of(p).vector(model.params)
    resid = simulate_efd(p, x)[0][0] - capture.efd
    ratio = model.mse / floor
    if model.mse <= st.floor_tol:
        note = "at the noise floor: nothing left to explain"
    elif ratio <= LACKS:
        note = f"{ratio:.2f} x the noise floor: close to it"
    else:
        note = (f"{ratio:.1f} x the noise floor: a structure the vocabulary lacks (or an effect it could "
                "not fit); see where it lies")
    left = {"mse": model.mse, "mse_over_floor": ratio, "effects": list(model.effects), "note": note,
            "localization": localization(resid, capture.dt, edges)}
    return out, left


def _edges_json(st: _Setup, m: ModelFit) -> list[dict[str, Any]]:
    """Each setpoint edge of the capture at the base model's fit (nominal and fitted instant, std),
    and of the holdout (its instants fitted with the base model held)."""
    p = st.views.problem((), m.fixed)
    x = Space.of(p).vector(m.params)
    out = [{"capture": "capture", **e} for e in p.edges(x, m.std)[0]]
    if st.views.holdout is not None:
        from .fit import polish
        h = st.views.holdout_problem(p.values(x))
        hs = Space.of(h)
        x0 = hs.vector({n: 0.5 * (lo + hi) for n, (lo, hi) in zip(h.names, h.bounds)})
        u, f, _ = polish(h, hs.to_u(x0), max_calls=st.views.holdout_calls)
        xh = hs.to_x(u) if math.isfinite(f) else x0
        out += [{"capture": "holdout", **e} for e in h.edges(xh)[0]]
    return out


def diagnose(*args: Any, **kwargs: Any) -> dict[str, Any]:
    """`_diagnose` with BLAS on one thread (the same answer on any machine, alone or in a batch;
    see identification.identify.run_identification)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return _diagnose(*args, **kwargs)


def _diagnose(capture: Capture, unit: Unit, *, holdout: Capture | None = None, seed: int = 0,
              budget: Budget = Budget(), base_params: Mapping[str, float] | None = None,
              command_line: str = "") -> dict[str, Any]:
    """The diagnosis of `capture` against `unit` (see the module docstring); a JSON-ready dict."""
    t_start = time.perf_counter()
    src = capture.source or "capture"
    edges = find_edges(capture.usetp, src)
    floor = noise_floor(capture.efd, capture.dt, edges, src)
    st = _setup(capture, holdout, unit, edges, floor, budget)
    views = st.views

    t0 = time.perf_counter()
    base = _fit_base(st, budget, seed, base_params)
    log.info("base fit: mse %.4g (%d evaluations, %.1f s)", base.mse, base.evaluations, time.perf_counter() - t0)
    p0 = views.problem(())
    sim = simulate_efd(p0, Space.of(p0).vector(base.params))[0][0]
    from bench_ctl.model.kernel import run_kernel
    r0 = p0.records[0]
    vt_model = run_kernel(p0.matrix(Space.of(p0).vector(base.params)), r0.usetp, r0.dt, r0.usetp_pre,
                          edges=r0.edges)["vt"][0]
    feats, hints = _features(capture, sim, vt_model, edges, floor, unit.values())

    fits = _fit_effects(st, base, hints, budget, seed)
    variant = _ceiling_variants(st, fits, budget, seed)
    # the base fit may sit in a worse basin than the model parameters an effect fit reached
    better = refine_base(views, base, [m.params for m in fits.values()], polish_evals=budget.base_polish)
    if better is not None:
        log.info("base fit improved from the effect fits: mse %.4g -> %.4g", base.mse, better.mse)
        base = finish(views, (), {}, Space.of(p0).vector(better.params), polish_fine=budget.base_polish,
                      noise_variance=floor.variance)
        sim = simulate_efd(p0, Space.of(p0).vector(base.params))[0][0]
    loc = localization(sim - capture.efd, capture.dt, edges)
    base = checked(views, base)
    # the check for the effects that improve the fit most (at most CHECKED; the others cannot be
    # significant or could not lead)
    n = st.n
    gains = sorted(((bic(n, base.mse, 0) - bic(n, m.mse, m.k), e) for e, m in fits.items()), reverse=True)
    for g, e in gains[:CHECKED]:
        if g > SIGNIFICANT:
            fits[e] = checked(views, fits[e])

    entries = _entries(unit, st, base, fits, variant)
    at_floor = base.mse <= st.floor_tol
    verdict = choose_verdict(entries, at_floor=at_floor, has_check=True)
    ambiguous = ambiguous_pairs(entries) if verdict != "none" else []
    steps, final = (_sequence(st, fits, verdict, hints, budget, seed) if verdict != "none" else ([], None))
    explained, left = _explained_by(st, base, steps, final, capture, edges)
    sequence = [{"added": s["added"], "mse": s["model"].mse, "mse_holdout": s["model"].mse_check,
                 "params": s["model"].effect_params(), "dropped": s["dropped"]} for s in steps]

    return {
        "schema": SCHEMA,
        "software_version": getattr(bench_ctl, "__version__", "0.1.0"),
        "command_line": command_line,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "capture": _capture_ref(capture),
        "holdout": _capture_ref(holdout),
        "unit": unit.to_dict(),
        "validation": st.validation,
        "check": st.validation["check"],
        "edges": _edges_json(st, base),
        "base": {"params": _model_params(unit, base), "mse": base.mse, "mse_holdout": base.mse_check,
                 "check": _check_entry(base), "evaluations": base.evaluations, "at_noise_floor": bool(at_floor)},
        "noise_floor": floor.variance,
        "noise_floor_detail": {"samples": floor.n, "t0": floor.t0, "t1": floor.t1, "rel_se": floor.rel_se,
                               "check": st.check_floor,
                               "holdout": (st.validation["check"]["holdout"] or {}).get("noise_floor")},
        "localization": loc,
        "features": [f.to_dict() for f in feats],
        "effects": entries,
        "ambiguous": ambiguous,
        "sequence": sequence,
        "explained_by": explained,
        "left": left,
        "verdict": verdict,
        "criteria": {"significant_delta": SIGNIFICANT, "check_gain": CHECK_GAIN, "strong_delta": STRONG,
                     "ambiguous_delta": AMBIGUOUS, "floor_sigmas": budget.floor_sigmas,
                     "score": "BIC on the capture + sum over the check's parts of n ln(mse), relative to the base "
                              "model"},
        "wall_s": time.perf_counter() - t_start,
    }
