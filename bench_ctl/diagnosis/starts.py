"""Where the diagnosis' fits of an effect start: the effect's values from the feature tests plus a
small grid (`effect_starts`), for limits on efd every assignment of the linear model's equivalent
lags to TE (`lag_variants`), all scored on the coarse record at once (`all_starts`).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from bench_ctl.identification.constraints import parse_constraints
from bench_ctl.identification.model_fits import Views
from bench_ctl.model.effects import EFFECTS, VOCABULARY
from bench_ctl.units.unit import Unit

__all__ = ["effect_starts", "lag_variants", "all_starts", "ORDER_SENSITIVE"]


def effect_starts(effect: str, hints: Mapping[str, float]) -> list[dict[str, float]]:
    """Starting values of an effect's parameters: from the feature tests plus a small grid (the
    effect's own, `Effect.starts`)."""
    if effect not in VOCABULARY:
        raise ValueError(f"unknown effect {effect!r}")
    return VOCABULARY[effect].starts(hints)


#: effects acting between the exciter lag TE and the record (limits on the efd state): for them
#: it matters which of the equivalent lags of the linear model is TE, so every assignment is tried
ORDER_SENSITIVE = tuple(e.name for e in EFFECTS.values() if e.order_sensitive)
VARIANT_LAGS = ("TA2", "TA4", "TE")


def lag_variants(unit: Unit, avr: Mapping[str, float]) -> list[dict[str, float]]:
    """The base model's parameters and the linear-equivalent sets with another lag in the TE slot.

    Without limits the model's transfer function is the same for any assignment of the lag time
    constants to TA2, TA4 and TE; a limit on efd (after TE) breaks that symmetry. Variants
    outside the unit's bounds or constraints are dropped."""
    out = [dict(avr)]
    lags = [n for n in VARIANT_LAGS if n in avr and n in unit.identify]
    if "TE" not in lags or len(lags) < 2:
        return out
    names = list(unit.identified_names)
    cons = parse_constraints(unit.constraints, names)
    for other in lags:
        if other == "TE":
            continue
        v = dict(avr)
        v["TE"], v[other] = avr[other], avr["TE"]
        rest = sorted(v[n] for n in lags if n != "TE")
        for n, val in zip([n for n in ("TA2", "TA4") if n in lags], rest):
            v[n] = val
        x = np.array([v[n] for n in names])
        inside = all(unit.identify[n].min <= v[n] <= unit.identify[n].max for n in names)
        if inside and all(c.violation(x) <= 1e-12 for c in cons):
            if all(any(abs(v[n] - w[n]) > 1e-9 * max(1.0, abs(w[n])) for n in lags) for w in out):
                out.append(v)
    return out


def all_starts(views: Views, avr_sets: Sequence[Mapping[str, float]], hints: Mapping[str, float],
               effects: Sequence[str] | None = None, fixed: Mapping[str, float] | None = None
               ) -> dict[str, list[dict[str, float]]]:
    """Starting points (model + effect parameters + edge instants) for every effect, best first by
    their mean objective on the coarse record: each effect start with the base parameters and,
    for the order-sensitive effects, with every lag variant. All starts of all effects are scored
    at once (`Problem.mean_objective_of`, one kernel call); an effect of the grid's (`frees_grid`,
    its values not the kernel's) in a call of its own. `effects`: default the record's vocabulary."""
    effects = views.vocabulary if effects is None else tuple(effects)
    result: dict[str, list[tuple[float, dict[str, float]]]] = {}
    for group in ([e for e in effects if not VOCABULARY[e].frees_grid],
                  *([e] for e in effects if VOCABULARY[e].frees_grid)):
        if not group:
            continue
        grid = tuple(e for e in group if VOCABULARY[e].frees_grid)
        coarse = views.coarse(views.problem(grid, fixed))
        rows, owners = [], []
        for e in group:
            sets = avr_sets if VOCABULARY[e].order_sensitive else avr_sets[:1]
            for avr in sets:
                for s in effect_starts(e, hints):
                    rows.append({**avr, **s})
                    owners.append((e, {**dict(avr), **s}))
        score = coarse.mean_objective_of(rows)
        for (e, s), m in zip(owners, score):
            result.setdefault(e, []).append((float(m), s))
    return {e: [s for _, s in sorted(v, key=lambda t: t[0])] for e, v in result.items()}
