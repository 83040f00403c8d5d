"""The verdict: which effect explains the capture, how significant, how close another one is.

An effect is significant when it lowers the BIC on the capture by more than `SIGNIFICANT` and
either the check's deviance by more than `CHECK_GAIN` (`check.score`) or the interleaved blocks'
deviance by more than `ONE_REGIME_GAIN` (an effect whose evidence lives in one regime, which a
left-out window can only judge by extrapolation: `check.check_and_blocks`); the verdict is the
best-scored significant effect, or `none` (`choose_verdict`); near-equal effects are `ambiguous`,
with the test that would separate them.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from bench_ctl.model.effects import VOCABULARY
from bench_ctl.model.effects import separating_test as effect_separating_test
from bench_ctl.units.unit import Unit

from .check import aic, bic, block_deviance, check_deviance, score
from .models import ModelFit, Setup

__all__ = ["SIGNIFICANT", "CHECK_GAIN", "STRONG", "ONE_REGIME_GAIN", "AMBIGUOUS", "separating_test", "ambiguous_pairs",
           "gap", "significance", "rank_entries", "check_entry", "choose_verdict", "model_params"]

#: BIC improvement (n ln mse units, i.e. -2 log-likelihood) an effect must bring to count
SIGNIFICANT = 10.0
#: improvement of the check's deviance an effect must bring to count (the check's samples were
#: not fitted: an effect that only fits noise does not improve them)
CHECK_GAIN = 2.0
#: BIC improvement that counts even when the base model is within the noise floor's uncertainty
#: (about a 1 % lower MSE on a 10 000-sample record)
STRONG = 100.0
#: improvement of the interleaved blocks' deviance that accepts an effect the windows cannot judge:
#: the blocks sample every regime in both halves, so they judge nearly where the fit was made and
#: must show a strong gain (as STRONG) where the windows need only CHECK_GAIN
ONE_REGIME_GAIN = 100.0
#: two effects whose scores differ by less than this explain the capture equally well
AMBIGUOUS = 6.0

def separating_test(a: str, b: str) -> str:
    """The test that would separate effects `a` and `b` (their records hold it)."""
    return effect_separating_test(a, b)


def ambiguous_pairs(entries: Sequence[Mapping], tol: float = AMBIGUOUS) -> list[dict]:
    """The significant effects whose score is within `tol` of the best one's (entries ranked best
    first), each paired with the best one and the test that would separate the two."""
    top = next((e for e in entries if e.get("significant")), None)  # the verdict's entry
    if top is None:
        return []
    return [{"effects": [top["name"], e["name"]], "score_difference": e["score"] - top["score"],
             "separating_test": separating_test(top["name"], e["name"])}
            for e in entries if e is not top and e.get("significant") and e["score"] - top["score"] < tol]


def gap(mse_base: float | None, mse_eff: float | None, floor: float, floor_se: float
        ) -> tuple[float | None, float | None]:
    """gap_closed with the denominator kept at least one standard error of the floor; and raw."""
    if mse_base is None or mse_eff is None or not math.isfinite(mse_eff):
        return None, None
    num = mse_base - mse_eff
    den = mse_base - floor
    raw = num / den if den != 0 else None
    return num / max(den, floor * floor_se), raw


def model_params(unit: Unit, m: ModelFit) -> dict[str, float]:
    params = m.params
    return {n: params[n] for n in unit.identified_names}


def significance(st: Setup, ref: ModelFit, m: ModelFit) -> tuple[float, float, bool]:
    """(fit gain, check gain, significant) of m over ref: the BIC falls by more than SIGNIFICANT
    and the check's deviance by more than CHECK_GAIN or the interleaved blocks' by more than
    ONE_REGIME_GAIN."""
    gain_fit = bic(st.n, ref.mse, ref.k) - bic(st.n, m.mse, m.k)
    gain_check = check_deviance(ref, m)
    judged = gain_check > CHECK_GAIN or block_deviance(ref, m) > ONE_REGIME_GAIN
    return gain_fit, gain_check, bool(gain_fit > SIGNIFICANT and judged and m.feasible)


def rank_entries(unit: Unit, st: Setup, base: ModelFit, fits: Mapping[str, ModelFit],
                 variants: Mapping[str, str]) -> list[dict]:
    """The ranked `effects` list of the JSON; `variants`: the variant kept for each effect that has
    variants (`Effect.variants`), by its label."""
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
        d_bic, d_check, significant = significance(st, base, m)
        g_check, g_check_raw = gap(base_check, m.mse_check, st.check_floor, st.check_se)
        g_fit, g_fit_raw = gap(base.mse, m.mse, floor.variance, floor.rel_se)
        hold_b, hold_m = base.part("holdout"), m.part("holdout")
        g_hold = g_hold_raw = None
        if hold_b is not None and hold_m is not None:
            g_hold, g_hold_raw = gap(hold_b.mse, hold_m.mse, st.validation["check"]["holdout"]["noise_floor"],
                                      st.check_se)
        params = m.effect_params()
        entry = {
            "name": e, "params": params, "fixed": dict(m.fixed),
            "avr_params": model_params(unit, m),
            "mse": m.mse, "mse_holdout": m.mse_check,
            "gap_closed": None if at_floor else (g_check if use_check else g_fit),
            "gap_closed_on": None if at_floor else ("check" if use_check else "fit"),
            "gap_closed_fit": g_fit, "gap_closed_fit_raw": g_fit_raw,
            "gap_closed_check": g_check, "gap_closed_check_raw": g_check_raw,
            "gap_closed_holdout": g_hold if hold_b is not None else g_check,
            "gap_closed_holdout_raw": g_hold_raw if hold_b is not None else g_check_raw,
            "check": check_entry(m),
            "score": score(m, n) - s_base if m.checks else math.inf,
            "aic": aic(n, m.mse, m.k), "bic": bic(n, m.mse, m.k),
            "delta_bic": d_bic, "delta_check": d_check, "significant": significant,
            "k": m.k, "evaluations": m.evaluations, "start": {p: m.start.get(p) for p in params},
        }
        d_blocks = block_deviance(base, m)
        if math.isfinite(d_blocks):    # optional: absent when not checked (or a simulation failed)
            entry["delta_blocks"] = d_blocks
        if VOCABULARY[e].variants:
            entry["variant"] = variants[e]
        entries.append(entry)
    entries.sort(key=lambda d: (d["score"], -d["delta_bic"]))
    return entries


def check_entry(m: ModelFit) -> dict[str, Any] | None:
    if not m.checks:
        return None
    return {"mse": m.mse_check, "parts": [{"label": p.label, "samples": p.n, "mse": p.mse} for p in m.checks],
            "blocks": [{"label": p.label, "samples": p.n, "mse": p.mse} for p in m.blocks or ()]}


def choose_verdict(entries: list[dict], *, at_floor: bool, has_check: bool) -> str:
    """The verdict from the ranked `entries` (best score first): the best-scored SIGNIFICANT
    effect (one scored higher but worse on the check, or breaking a constraint, must not hide
    it), or `none`. At the noise floor (within the floor estimate's uncertainty) only a strong
    improvement counts: the floor comes from ~1000 pre-trigger samples, the likelihood ratio from
    the whole record."""
    top = next((e for e in entries if e["significant"]), None)
    if top is None:
        return "none"
    strong = top["delta_bic"] > STRONG and (not has_check or top["delta_check"] > SIGNIFICANT
                                            or top.get("delta_blocks", -math.inf) > ONE_REGIME_GAIN)
    return top["name"] if (strong or not at_floor) else "none"
