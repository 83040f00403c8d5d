"""The verdict: which effect explains the capture, how significant, how close another one is.

Each effect's entry of the ranked list (`rank_entries`) says whether it is significant (the rule
and its constants: `significance`); the verdict is the best-scored significant effect, or `none`
(`choose_verdict`); near-equal effects are `ambiguous`, with the test that would separate them.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from bench_ctl.identification.fit_check import aic, bic, block_deviance, score
from bench_ctl.identification.model_fits import ModelFit, Setup
from bench_ctl.model.effects import VOCABULARY
from bench_ctl.model.effects import separating_test as effect_separating_test
from bench_ctl.units.unit import Unit

from .diagnosis_file import AmbiguousPair, CheckEntry, EffectEntry, PartEntry
from .significance import AMBIGUOUS, significance, strong

__all__ = ["separating_test", "ambiguous_pairs", "gap", "rank_entries", "check_entry", "choose_verdict",
           "model_params"]

def separating_test(a: str, b: str) -> str:
    """The test that would separate effects `a` and `b` (their records hold it)."""
    return effect_separating_test(a, b)


def ambiguous_pairs(entries: Sequence[EffectEntry], tol: float = AMBIGUOUS) -> list[AmbiguousPair]:
    """The significant effects whose score is within `tol` of the best one's (entries ranked best
    first), each paired with the best one and the test that would separate the two."""
    top = next((e for e in entries if e.significant), None)  # the verdict's entry
    if top is None:
        return []
    return [AmbiguousPair([top.name, e.name], e.score - top.score, separating_test(top.name, e.name))
            for e in entries if e is not top and e.significant and e.score - top.score < tol]


def gap(mse_base: float | None, mse_eff: float | None, floor: float, floor_se: float
        ) -> tuple[float | None, float | None]:
    """gap_closed with the denominator kept at least one standard error of the floor; and raw."""
    if mse_base is None or mse_eff is None or not math.isfinite(mse_eff):
        return None, None
    num = mse_base - mse_eff
    den = mse_base - floor
    raw = num / den if den != 0 else None
    return num / max(den, floor * floor_se), raw


def model_params(unit: Unit, m: ModelFit) -> dict[str, float | None]:
    """The model's own fitted values in m: the unit's identified parameters and, on line, the
    [grid] values it fits (XE with --set XE.min/max), without which the model is not the one fitted."""
    params = m.params
    return {n: params[n] for n in (*unit.identified_names, *unit.grid_identify) if n in params}


def rank_entries(unit: Unit, st: Setup, base: ModelFit, fits: Mapping[str, ModelFit],
                 variants: Mapping[str, str]) -> list[EffectEntry]:
    """The ranked `effects` of the diagnosis (kernel names); `variants`: the variant kept for each
    effect that has variants (`Effect.variants`), by its label."""
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
            g_hold, g_hold_raw = gap(hold_b.mse, hold_m.mse, st.validation.check.holdout.noise_floor,
                                      st.check_se)
        params = m.effect_params()
        d_blocks = block_deviance(base, m)
        entries.append(EffectEntry(
            name=e, params=params, fixed=dict(m.fixed),
            avr_params=model_params(unit, m),
            mse=m.mse, mse_holdout=m.mse_check,
            gap_closed=None if at_floor else (g_check if use_check else g_fit),
            gap_closed_on=None if at_floor else ("check" if use_check else "fit"),
            gap_closed_fit=g_fit, gap_closed_fit_raw=g_fit_raw,
            gap_closed_check=g_check, gap_closed_check_raw=g_check_raw,
            gap_closed_holdout=g_hold if hold_b is not None else g_check,
            gap_closed_holdout_raw=g_hold_raw if hold_b is not None else g_check_raw,
            check=check_entry(m),
            score=score(m, n) - s_base if m.checks else math.inf,
            aic=aic(n, m.mse, m.k), bic=bic(n, m.mse, m.k),
            delta_bic=d_bic, delta_check=d_check, significant=significant,
            k=m.k, evaluations=m.evaluations, start={p: m.start.get(p) for p in params},
            # optional: absent when not checked (or a simulation failed)
            delta_blocks=d_blocks if math.isfinite(d_blocks) else None,
            variant=variants[e] if VOCABULARY[e].variants else None))
    entries.sort(key=lambda d: (d.score, -d.delta_bic))
    return entries


def check_entry(m: ModelFit) -> CheckEntry | None:
    if not m.checks:
        return None
    return CheckEntry(m.mse_check, tuple(PartEntry(p.label, p.n, p.mse) for p in m.checks),
                      tuple(PartEntry(p.label, p.n, p.mse) for p in m.blocks or ()))


def choose_verdict(entries: Sequence[EffectEntry], *, at_floor: bool, has_check: bool) -> str:
    """The verdict from the ranked `entries` (best score first): the best-scored significant
    effect (one scored higher but worse on the check, or breaking a constraint, must not hide
    it), or `none`. At the noise floor (within the floor estimate's uncertainty) only a strong
    improvement counts (`significance.strong`): the floor comes from ~1000 pre-trigger samples,
    the likelihood ratio from the whole record."""
    top = next((e for e in entries if e.significant), None)
    if top is None:
        return "none"
    counts = strong(top.delta_bic, top.delta_check, top.delta_blocks, has_check=has_check)
    return top.name if (counts or not at_floor) else "none"
