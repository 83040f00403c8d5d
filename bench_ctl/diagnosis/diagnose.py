"""Sim-to-real gap diagnosis of one capture: where the model misses, which effect, how far it shrinks.

`diagnose(capture, unit, holdout=...)` returns the diagnosis JSON (SCHEMA.md, schema
"bench-ctl/diagnosis/1"):

1. Base fit: the unit's identified parameters fitted by MVMO on the coarse record (started from
   the unit's values, or `base_params` when a previous identification is given) and polished by
   least squares on the full record; re-polished from an effect fit's AVR parameters when those
   fit the base model better (the base model is multimodal; the effect fits explore it too).
2. Noise floor (pre-trigger efd variance), localization (residual energy per segment and band),
   feature tests (flat top, delay, steady-state ratio, pre-trigger level, asymmetry, edge shape).
3. Every effect re-identified with the base model, warm-started from the base fit; ranked by BIC
   plus the predictive deviance on the check record; `none` when no effect is significant, or
   when the base model fits to the noise floor and no effect brings a strong (`STRONG`) gain; near-equal effects listed in `ambiguous` with the test that
   separates them; further effects added greedily while the check error keeps falling.

Fit / check split: with a holdout capture, every model is fitted on the whole capture and checked
on the whole holdout. Without one, models are fitted on the record up to the trailing edge plus
one pulse width (at least 0.5 s; both edges are in it) and checked on the rest of the record
(the recovery tail), which the fit never saw.
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
from bench_ctl.model.effects import EFFECTS, EFFECT_NAMES
from bench_ctl.model.kernel import saturation_ab
from bench_ctl.model.unit import Unit

from bench_ctl.identification.timing import edges_entry

from . import features as F
from .fit import (FitResult, Record, Space, coarse_factor, coarse_record, fit, mse_of, polish, record_of,
                  simulate_efd)
from .localize import DiagnosisError, Edges, NoiseFloor, find_edges, localization, noise_floor
from .effect_fits import (AMBIGUOUS, SIGNIFICANT, STRONG, Check, ModelFit, aic, all_starts, ambiguous_pairs, bic,
                    check_mse, fit_model, global_search, lag_variants, model_space, refine, refine_base, score)

log = logging.getLogger(__name__)

SCHEMA = "bench-ctl/diagnosis/1"


@dataclass(frozen=True)
class Budget:
    """Evaluations (simulations) per fit: MVMO evaluations and least-squares polish simulations."""
    base: int = 1000
    base_polish: int = 100
    effect: int = 600          # MVMO evaluations per leading effect (coarse record, whole box)
    profile: int = 600         # MVMO evaluations over the AVR parameters with the effect held
    global_top: int = 3        # effects (best after the local fits) that get the MVMO searches
    effect_polish: int = 60    # least-squares simulations on the full record per effect polished
    polish_top: int = 3        # effects polished on the full record (the best after the coarse fits)
    polish_coarse: int = 150   # least-squares simulations on the coarse record per start
    starts: int = 8            # starting points polished on the coarse record per effect
    coarse_dt: float = 0.004   # sample step of the coarse record (s), at most the unit's shortest
                               # lag (reference unit: TE >= 2 ms), see `fit.coarse_factor`
    coarse_tail_s: float = 3.0 # the coarse record ends this long after the trailing edge
    combo_polish: int = 60
    max_sequence: int = 3
    sequence_candidates: int = 4  # significant effects tried at each greedy step
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


def _split(capture: Capture, edges: Edges) -> int:
    """Samples used to fit when there is no holdout (see the module docstring)."""
    n, dt = capture.n, capture.dt
    if edges.k_off is not None:
        width = (edges.k_off - edges.k_on) * dt
        k = edges.k_off + int(round(max(width, 0.5) / dt))
    else:
        k = edges.k_on + int(round(0.6 * (n - edges.k_on)))
    k = min(k, n - max(20, int(0.2 * n)))
    if k <= edges.k_on + 10:
        raise DiagnosisError(f"{capture.source or 'capture'}: record too short after the setpoint change to "
                             f"split into a fitted part and a check part; give a holdout capture")
    return k


def _gap(mse_base: float | None, mse_eff: float | None, floor: float, floor_se: float) -> tuple[float | None, float | None]:
    """gap_closed with the denominator kept at least one standard error of the floor; and raw."""
    if mse_base is None or mse_eff is None or not math.isfinite(mse_eff):
        return None, None
    num = mse_base - mse_eff
    den = mse_base - floor
    raw = num / den if den != 0 else None
    return num / max(den, floor * floor_se), raw


@dataclass(frozen=True, eq=False)
class _Setup:
    """What every step works on: the records, the noise floor and its tolerance."""
    rec: Record          # the fit record (whole capture, or its first part without a holdout)
    coarse: Record       # its decimated copy for the searches
    full: Record         # the whole capture
    check: Check
    check_se: float
    validation: dict
    floor: NoiseFloor
    floor_tol: float     # base MSE up to this counts as "at the noise floor"


def _setup(capture: Capture, holdout: Capture | None, unit: Unit, edges: Edges, floor: NoiseFloor,
           budget: Budget) -> _Setup:
    src = capture.source or "capture"
    if holdout is not None:
        h_src = holdout.source or "holdout"
        h_floor = noise_floor(holdout.efd, holdout.dt, find_edges(holdout.usetp, h_src), h_src)
        rec = record_of(capture, label=src)
        # the holdout's own edges take the EDGE columns after the capture's
        check = Check(record_of(holdout, slot0=len(rec.edge_list)), 0, h_floor.variance, "holdout")
        check_se = h_floor.rel_se
        validation = {"kind": "holdout", "fit": {"t0": 0.0, "t1": float(capture.time[-1] - capture.time[0])},
                      "check": {"capture": holdout.source or None, "t0": 0.0,
                                "t1": float(holdout.time[-1] - holdout.time[0])}}
    else:
        k = _split(capture, edges)
        rec = record_of(capture, n=k, label=src)
        check = Check(record_of(capture), k, floor.variance, "tail")
        check_se = floor.rel_se
        # both windows include their ends (as fit windows do): the fit is samples 0 .. k-1
        validation = {"kind": "split", "fit": {"t0": 0.0, "t1": (k - 1) * capture.dt},
                      "check": {"capture": src, "t0": k * capture.dt, "t1": (capture.n - 1) * capture.dt}}
    q = coarse_factor(unit, capture.dt, budget.coarse_dt)
    if edges.k_off is not None:  # both setpoint edges on the coarse grid, or the trailing one moves
        q = math.gcd(q, edges.k_off - edges.k_on) or 1
    n_coarse = rec.n if edges.k_off is None else min(rec.n, edges.k_off + int(round(budget.coarse_tail_s / capture.dt)))
    coarse = coarse_record(rec, q=q, n_max=n_coarse, offset=edges.k_on)
    floor_tol = floor.variance * (1.0 + budget.floor_sigmas * math.sqrt(floor.rel_se ** 2 + 2.0 / rec.n))
    return _Setup(rec, coarse, record_of(capture, label=src), check, check_se, validation, floor, floor_tol)


def _fit_base(unit: Unit, st: _Setup, budget: Budget, seed: int,
              base_params: Mapping[str, float] | None) -> tuple[FitResult, ModelFit]:
    """MVMO on the coarse record from the unit's values (or `base_params`), polish on the full one."""
    space = model_space(unit, (), unit.values())
    x0 = [float((base_params or {}).get(n, unit.identify[n].value)) for n in space.names]
    res = fit(space, st.coarse, x0=x0, evals=budget.base, seed=seed, polish_evals=budget.polish_coarse)
    u, f, calls = polish(space, st.rec, space.to_u(res.x), max_calls=budget.base_polish)
    x = space.to_x(u)
    if not math.isfinite(f):  # the polish left the constraints: keep the global search's result
        x, f = res.x, float(mse_of(space, res.x, st.rec)[0])
    res = FitResult(space.names, x, f, res.evaluations + calls, bool(space.violation(x)[0] <= 1e-9), "")
    return res, _as_model(unit, res, st)


def _fit_edge_instants(unit: Unit, st: _Setup, base_fit: FitResult, budget: Budget
                       ) -> tuple[Unit, FitResult, list[dict[str, Any]]]:
    """The instant of every setpoint edge (DESIGN.md section 4), fitted with the base model: on the
    fit record jointly with the AVR parameters (a least-squares polish from the base fit), on a
    holdout with the model held (its edges are the holdout's own timing). Returns the unit with
    the offsets as fixed values (EDGE1..; every later fit and check holds them), the base fit
    after the polish, and the JSON `edges` list."""
    fixed: dict[str, float] = {}
    out: list[dict[str, Any]] = []
    names_e = st.full.edge_names()
    model = base_fit
    if names_e:
        space = Space(tuple(base_fit.names) + names_e,
                      np.concatenate([model_space(unit, (), unit.values()).lo, [e.lo_s for e in st.full.edge_list]]),
                      np.concatenate([model_space(unit, (), unit.values()).hi, [e.hi_s for e in st.full.edge_list]]),
                      unit.values(), tuple(unit.constraints))
        x0 = np.concatenate([base_fit.x, np.zeros(len(names_e))])
        u, f, calls = polish(space, st.rec, space.to_u(x0), max_calls=budget.base_polish)
        x = space.to_x(u)
        if not math.isfinite(f):
            x, f = x0, float(mse_of(space, x0, st.rec)[0])
        d = len(base_fit.names)
        fixed.update(zip(names_e, (float(v) for v in x[d:])))
        model = FitResult(base_fit.names, x[:d], f, base_fit.evaluations + calls,
                          bool(space.violation(x)[0] <= 1e-9), "")
        out += [{"capture": "capture", **e} for e in edges_entry(st.full.edge_list, list(range(len(names_e))), fixed)]
    if st.check.label == "holdout" and st.check.record.edge_list:
        rec_h = st.check.record
        names_h = rec_h.edge_names()
        space = Space(names_h, np.array([e.lo_s for e in rec_h.edge_list]), np.array([e.hi_s for e in rec_h.edge_list]),
                      {**unit.values(), **model.params(), **fixed})
        u, f, _calls = polish(space, rec_h, space.to_u(np.zeros(len(names_h))), max_calls=budget.base_polish)
        xh = space.to_x(u) if math.isfinite(f) else np.zeros(len(names_h))
        fixed.update(zip(names_h, (float(v) for v in xh)))
        out += [{"capture": "holdout", **e} for e in edges_entry(rec_h.edge_list, rec_h.edges.slot.tolist(), fixed)]
    if not fixed:
        return unit, base_fit, out
    return replace(unit, fixed={**unit.fixed, **fixed}), model, out


def _as_model(unit: Unit, res: FitResult, st: _Setup) -> ModelFit:
    space = model_space(unit, (), unit.values())
    return ModelFit((), res.params(), res.mse, check_mse(space, res.x, st.check), 0, res.evaluations, res.feasible)


def _features(capture: Capture, model: np.ndarray, edges: Edges, floor: NoiseFloor,
              values: Mapping[str, float], n_fit: int) -> tuple[list[F.Feature], dict[str, float]]:
    """The feature tests, and the hints they give the effect fits' starting values; they read
    only the fit record (`n_fit` samples: without a holdout the rest is the check record)."""
    capture = replace(capture, time=capture.time[:n_fit], usetp=capture.usetp[:n_fit],
                      efd=capture.efd[:n_fit], vt=None if capture.vt is None else capture.vt[:n_fit],
                      extra={})
    model = model[:n_fit]
    sigma = math.sqrt(floor.variance)
    efd_pre = float(np.mean(capture.efd[:floor.n]))
    efd_se = sigma / math.sqrt(floor.n)
    vt_pre = float(np.mean(capture.vt[:floor.n])) if capture.vt is not None else None
    feats = [
        F.flat_top(capture.efd, model, capture.dt, edges, sigma),
        F.delay(capture.efd, model, capture.dt, edges, sigma),
        F.steady_state_ratio(efd_pre, efd_se, vt_pre, values["Vt0"]),
        F.pre_trigger_level(efd_pre, efd_se, _efd0_model(values)),
        F.asymmetry(capture.efd, model, capture.dt, edges, sigma),
        F.edge_shape(capture.efd, model, capture.dt, edges, sigma, edges.amplitude),
    ]
    fv = {f.name: f.values for f in feats}
    hints = {
        "top_level": fv["flat_top"]["top_level"], "bottom_level": fv["flat_top"]["bottom_level"],
        "delay_s": fv["delay"]["delay_s"],
        "sat0": efd_pre - fv["steady_state_ratio"]["vt"],
        "slope_up": fv["asymmetry"].get("slope_up", math.nan),
        "slope_down": fv["asymmetry"].get("slope_down", math.nan),
        "gain": fv["pre_trigger_level"]["ratio"],
    }
    return feats, hints


def _fit_effects(unit: Unit, st: _Setup, base: ModelFit, hints: Mapping[str, float], budget: Budget,
                 seed: int) -> dict[str, ModelFit]:
    """Every effect: local fits from the starts (coarse), MVMO for the leaders, polish of the leaders."""
    values = unit.values()
    n, n_c = st.rec.n, st.check.n
    starts = all_starts(unit, values, st.coarse, lag_variants(unit, base.params), hints)
    fits: dict[str, ModelFit] = {}
    for i, e in enumerate(EFFECT_NAMES):
        t0 = time.perf_counter()
        fits[e] = fit_model(unit, values, (e,), st.rec, st.coarse, st.check, starts[e], evals=0, seed=seed + 1 + i,
                            polish_coarse=budget.polish_coarse, polish_fine=0, multi=budget.starts)
        log.info("effect %s: mse %.4g check %s (%d evaluations, %.1f s)", e, fits[e].mse, fits[e].mse_check,
                 fits[e].evaluations, time.perf_counter() - t0)
    # global searches (MVMO) for the leaders that are not yet at the noise floor
    ranked = sorted(fits, key=lambda e: score(fits[e], n, n_c))
    for i, e in enumerate(ranked[:budget.global_top]):
        if fits[e].mse <= st.floor_tol:
            continue
        t0 = time.perf_counter()
        fits[e] = global_search(unit, values, fits[e], st.rec, st.coarse, st.check, evals=budget.effect,
                                profile_evals=budget.profile, seed=seed + 11 + i,
                                polish_coarse=budget.polish_coarse, floor_tol=st.floor_tol)
        log.info("effect %s global search: mse %.4g (%.1f s)", e, fits[e].mse, time.perf_counter() - t0)
    # the leaders (and every effect close to the best) get the least-squares polish on the full
    # record; so does a nested model worse than the base model there: its coarse-record solution
    # did not carry over (e.g. a lag near the coarse step)
    ranked = sorted(fits, key=lambda e: score(fits[e], n, n_c))
    best_score = score(fits[ranked[0]], n, n_c)
    for j, e in enumerate(ranked):
        if (j < budget.polish_top or score(fits[e], n, n_c) - best_score < 2 * SIGNIFICANT
                or fits[e].mse > base.mse):
            fits[e] = refine(unit, values, fits[e], st.rec, st.check, polish_fine=budget.effect_polish)
    return fits


BUS_FED = "bus-fed: VRMAX*Vt, VRMIN*Vt"


def _ceiling_variant(unit: Unit, st: _Setup, fits: dict[str, ModelFit], budget: Budget, seed: int
                     ) -> tuple[Unit, str]:
    """The ceiling of a bus-fed static exciter (limits x Vt, VRVT = 1) tried beside the fixed one,
    from the fixed fit's values; the better scored is kept (`fits` updated) and, when bus-fed,
    the unit carries VRVT = 1 for the rest of the diagnosis. Returns (unit, variant)."""
    fixed = fits["ceiling_limit"]
    n, n_c = st.rec.n, st.check.n
    values = {**unit.values(), "VRVT": 1.0}
    bus = fit_model(unit, values, ("ceiling_limit",), st.rec, st.coarse, st.check, [dict(fixed.params)], evals=0,
                    seed=seed + 41, polish_coarse=budget.polish_coarse, polish_fine=budget.effect_polish)
    log.info("ceiling variants: fixed mse %.4g, bus-fed mse %.4g", fixed.mse, bus.mse)
    if bus.feasible and score(bus, n, n_c) < score(fixed, n, n_c):
        fits["ceiling_limit"] = bus
        return replace(unit, fixed={**unit.fixed, "VRVT": 1.0}), BUS_FED
    return unit, "fixed limits"


def _entries(unit: Unit, st: _Setup, base: ModelFit, fits: Mapping[str, ModelFit]) -> list[dict]:
    """The ranked `effects` list of the JSON."""
    n, n_c = st.rec.n, st.check.n
    bic_base = bic(n, base.mse, 0)
    s_base = score(base, n, n_c)
    check, floor = st.check, st.floor
    use_check = base.mse_check is not None and base.mse_check > check.floor * (1 + 3 * st.check_se)
    # a base model at the noise floor leaves no gap: a fraction of (nearly) nothing would be noise
    # scaled up (values like -60), so the headline gap_closed is None; the raw figures stay below
    at_floor = base.mse <= st.floor_tol
    entries = []
    for e, m in fits.items():
        d_bic = bic_base - bic(n, m.mse, m.k)
        d_check = (n_c * math.log(base.mse_check / m.mse_check)
                   if (m.mse_check and base.mse_check and math.isfinite(m.mse_check)) else -math.inf)
        significant = d_bic > SIGNIFICANT and d_check > 0.0 and m.feasible
        g_check, g_check_raw = _gap(base.mse_check, m.mse_check, check.floor, st.check_se)
        g_fit, g_fit_raw = _gap(base.mse, m.mse, floor.variance, floor.rel_se)
        entries.append({
            "name": e, "params": m.effect_params(),
            "avr_params": {p: m.params[p] for p in unit.identified_names},
            "mse": m.mse, "mse_holdout": m.mse_check,
            "gap_closed": None if at_floor else (g_check if use_check else g_fit),
            "gap_closed_on": None if at_floor else (check.label if use_check else "fit"),
            "gap_closed_fit": g_fit, "gap_closed_fit_raw": g_fit_raw,
            "gap_closed_holdout": g_check, "gap_closed_holdout_raw": g_check_raw,
            "score": score(m, n, n_c) - s_base, "aic": aic(n, m.mse, m.k), "bic": bic(n, m.mse, m.k),
            "delta_bic": d_bic, "delta_check": d_check, "significant": bool(significant),
            "k": m.k, "evaluations": m.evaluations, "start": {p: m.start[p] for p in m.effect_params()},
        })
    entries.sort(key=lambda d: d["score"])
    return entries


def choose_verdict(entries: list[dict], *, at_floor: bool, has_check: bool) -> str:
    """The verdict from the ranked `entries` (best score first): the best-scored SIGNIFICANT
    effect (one scored higher but worse on the check record, or breaking a constraint, must not
    hide it), or `none`. At the noise floor (within the floor estimate's uncertainty) only a
    strong improvement counts: the floor comes from ~1000 pre-trigger samples, the likelihood
    ratio from the whole record."""
    top = next((e for e in entries if e["significant"]), None)
    if top is None:
        return "none"
    strong = top["delta_bic"] > STRONG and (not has_check or top["delta_check"] > SIGNIFICANT)
    return top["name"] if (strong or not at_floor) else "none"


def _sequence(unit: Unit, st: _Setup, fits: Mapping[str, ModelFit], entries: list[dict], verdict: str,
              budget: Budget, seed: int) -> list[dict]:
    """Add effects greedily to the verdict while both the fit (BIC) and the check error improve."""
    n, n_c = st.rec.n, st.check.n
    current = fits[verdict]
    sequence = [{"added": verdict, "mse": current.mse, "mse_holdout": current.mse_check,
                 "params": current.effect_params()}]
    cands = [d["name"] for d in entries if d["significant"] and d["name"] != verdict]
    while len(current.effects) < budget.max_sequence and cands and current.mse > st.floor_tol:
        best = None
        for c in cands[:budget.sequence_candidates]:
            x0 = dict(current.params)
            x0.update({p: fits[c].params[p] for p in EFFECTS[c].params})
            m = fit_model(unit, unit.values(), current.effects + (c,), st.rec, st.coarse, st.check, [x0], evals=0,
                          seed=seed, polish_coarse=budget.polish_coarse, polish_fine=budget.combo_polish)
            if best is None or score(m, n, n_c) < score(best, n, n_c):
                best = m
        assert best is not None
        gain_fit = bic(n, current.mse, current.k) - bic(n, best.mse, best.k)
        gain_check = (n_c * math.log(current.mse_check / best.mse_check)
                      if current.mse_check and best.mse_check else -math.inf)
        if not (gain_fit > SIGNIFICANT and gain_check > SIGNIFICANT):
            break
        current = best
        cands.remove(best.effects[-1])
        sequence.append({"added": best.effects[-1], "mse": best.mse, "mse_holdout": best.mse_check,
                         "params": best.effect_params()})
    return sequence, current


#: what is left after the explaining effects, over the noise floor, beyond which the rest is called
#: "a structure the vocabulary lacks"
LACKS = 2.0


def _explained_by(unit: Unit, st: _Setup, base: ModelFit, sequence: list[dict], final: ModelFit | None,
                  capture: Capture, edges: Edges) -> tuple[list[dict], dict]:
    """The effects that together explain the record (in the order added, each re-fitted jointly
    with those before it), and what is left after the last: its error against the noise floor and
    where in the record it lies."""
    floor = st.floor.variance
    span = base.mse - floor
    steps = []
    for step in sequence:
        params = dict(step.get("params", {}))
        if step["added"] == "ceiling_limit" and unit.fixed.get("VRVT") == 1.0:
            params["VRVT"] = 1.0  # the bus-fed variant
        steps.append({"name": step["added"], "params": params, "mse": step["mse"],
                      "mse_over_floor": step["mse"] / floor,
                      "gap_closed": (base.mse - step["mse"]) / span if span > 0 else None,
                      "check": {"on": st.check.label, "mse": step["mse_holdout"],
                                "mse_base": base.mse_check}})
    model = final if final is not None else base
    space = model_space(unit, model.effects, unit.values())
    x = np.array([model.params[n] for n in space.names])
    resid = simulate_efd(space, x, st.full)[0][0] - capture.efd
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
    return steps, left


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
    unit_in = unit

    t0 = time.perf_counter()
    base_fit, base = _fit_base(unit, st, budget, seed, base_params)
    unit, base_fit, edge_entries = _fit_edge_instants(unit, st, base_fit, budget)
    base = _as_model(unit, base_fit, st)
    base_space = model_space(unit, (), unit.values())
    log.info("base fit: mse %.4g (%d evaluations, %.1f s)", base.mse, base.evaluations, time.perf_counter() - t0)
    model = simulate_efd(base_space, base_fit.x, st.full)[0][0]
    feats, hints = _features(capture, model, edges, floor, unit.values(), st.rec.n)

    fits = _fit_effects(unit, st, base, hints, budget, seed)
    unit, ceiling_variant = _ceiling_variant(unit, st, fits, budget, seed)
    # the base fit may sit in a worse basin than the AVR parameters an effect fit reached
    better = refine_base(unit, unit.values(), st.rec, base_fit.x, [m.params for m in fits.values()],
                         polish_evals=budget.base_polish)
    if better is not None and better.mse < base_fit.mse:
        log.info("base fit improved from the effect fits: mse %.4g -> %.4g", base_fit.mse, better.mse)
        base_fit = replace(better, evaluations=base_fit.evaluations + better.evaluations)
        base = _as_model(unit, base_fit, st)
        model = simulate_efd(base_space, base_fit.x, st.full)[0][0]
    loc = localization(model - capture.efd, capture.dt, edges)

    entries = _entries(unit, st, base, fits)
    for e in entries:
        if e["name"] == "ceiling_limit":
            e["variant"] = ceiling_variant
    at_floor = base.mse <= st.floor_tol
    verdict = choose_verdict(entries, at_floor=at_floor, has_check=base.mse_check is not None)
    ambiguous = ambiguous_pairs(entries) if verdict != "none" else []
    sequence, final = (_sequence(unit, st, fits, entries, verdict, budget, seed) if verdict != "none"
                       else ([], None))
    explained, left = _explained_by(unit, st, base, sequence, final, capture, edges)

    return {
        "schema": SCHEMA,
        "software_version": getattr(bench_ctl, "__version__", "0.1.0"),
        "command_line": command_line,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "capture": _capture_ref(capture),
        "holdout": _capture_ref(holdout),
        "unit": unit_in.to_dict(),
        "validation": st.validation,
        "edges": edge_entries,
        "base": {"params": base.params, "mse": base.mse, "mse_holdout": base.mse_check,
                 "evaluations": base.evaluations, "at_noise_floor": bool(at_floor)},
        "noise_floor": floor.variance,
        "noise_floor_detail": {"samples": floor.n, "t0": floor.t0, "t1": floor.t1, "rel_se": floor.rel_se,
                               "holdout": st.check.floor if holdout is not None else None},
        "localization": loc,
        "features": [f.to_dict() for f in feats],
        "effects": entries,
        "ambiguous": ambiguous,
        "sequence": sequence,
        "explained_by": explained,
        "left": left,
        "verdict": verdict,
        "criteria": {"significant_delta": SIGNIFICANT, "strong_delta": STRONG, "ambiguous_delta": AMBIGUOUS,
                     "floor_sigmas": budget.floor_sigmas,
                     "score": "BIC on the fit record + n ln(mse) on the check record, relative to the base model"},
        "wall_s": time.perf_counter() - t_start,
    }
