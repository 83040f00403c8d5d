"""The candidate structures of `--model auto` (docs/decisions/0016-structure-selection.md): the
unit in every structure of the library, less one of each pair of pulse twins (`auto_models`),
each with the `--set` overrides it takes (`candidate_units`) and its limits fitted too when only
their typical values are known (`free_limits`).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

from bench_ctl.model.params import PARAMS
from bench_ctl.model.structures import DEFAULT as DEFAULT_MODEL
from bench_ctl.model.structures import STRUCTURES
from bench_ctl.units.overrides import apply_overrides, apply_own_overrides, with_model
from bench_ctl.units.unit import Bound, Unit

__all__ = ["LIMITS", "LIMIT_RANGE", "free_limits", "candidate_units", "auto_models", "twin_notes"]

#: the limits of a structure (standard names) `free_limits` identifies, and how far from the
#: typical value their bounds reach (a factor each way)
LIMITS = ("VRMAX", "VRMIN", "EMAX", "EMIN", "VMMAX", "VMMIN", "VAMAX", "VAMIN")
LIMIT_RANGE = 4.0
#: each lower limit's upper one (a lower limit at 0 is freed as far below it as the upper is above)
_UPPER = {"VRMIN": "VRMAX", "EMIN": "EMAX", "VMMIN": "VMMAX", "VAMIN": "VAMAX"}


def free_limits(unit: Unit, keep: Sequence[str] = ()) -> Unit:
    """`unit` with its structure's limits (`LIMITS`, those it simulates and holds fixed, except
    `keep`) identified too, from their value: an upper one within LIMIT_RANGE of it each way, a
    lower one from LIMIT_RANGE times it to 0, a lower one at 0 from minus its upper one to 0 (and
    the kernel's range). An engineer who does not
    know the exciter does not know its ceilings either, and a structure with a wrong ceiling can
    lose to a wrong structure whose ceiling is never reached."""
    st = unit.structure
    identify, fixed = dict(unit.identify), dict(unit.fixed)
    for name in LIMITS:
        if name not in st.names or name in keep:
            continue
        k = st.param(name).kernel
        if k is None or k in identify or k not in fixed or not math.isfinite(fixed[k]):
            continue
        v, info = fixed[k], PARAMS[k]
        if v > 0:
            lo, hi = v / LIMIT_RANGE, v * LIMIT_RANGE
        elif v < 0:   # a lower limit may be 0 (a one-quadrant bridge, a diode rectifier's exciter)
            lo, hi = v * LIMIT_RANGE, 0.0
        else:
            # a lower limit typically at 0 (AC8B's one-quadrant exciter field) may be below it: as
            # far below as the upper limit is above (the kernel's range at most)
            up = _UPPER.get(name)
            upper = unit.fixed.get(st.param(up).kernel or "", math.nan) if up in st.names else math.nan
            if not (math.isfinite(upper) and upper > 0):
                continue
            lo, hi = -upper, 0.0
        fixed.pop(k)
        identify[k] = Bound(v, max(lo, info.lo), min(hi, info.hi))
    return replace(unit, identify=identify, fixed=fixed)


def candidate_units(base: Unit, overrides: Sequence[str], *, given_model: bool
                    ) -> tuple[dict[str, Unit], list[str]]:
    """The unit `base` in every structure `auto_models` gives (on its generator), each with the
    `--set` overrides it has. The structure of a unit file or planning record (`given_model`:
    `base`'s own structure comes from one) keeps its limits as given, as do the names `--set`
    gives; the others start at their typical values with their limits fitted too
    (`free_limits`). Returns the units and a note per override a structure lacks, plus what each
    fitted structure stands for (`twin_notes`); an override no structure takes is an error
    (UnitError, from the reference structure)."""
    given = {item.split("=", 1)[0].split(".", 1)[0].strip() for item in overrides}
    units: dict[str, Unit] = {}
    skipped: dict[str, list[str]] = {}
    for name in auto_models(base.model):
        u, lacking = apply_own_overrides(with_model(base, name), overrides)
        for item in lacking:
            skipped.setdefault(item, []).append(name)
        units[name] = u if given_model and u.model == base.model else free_limits(u, keep=sorted(given))
    for item, names in skipped.items():
        if len(names) == len(units):   # no structure has it: the reference structure says why
            apply_overrides(with_model(base, DEFAULT_MODEL), [item])
    notes = [f"--set {item} not applied to {', '.join(names)} (not a parameter of theirs)"
             for item, names in skipped.items()]
    notes += twin_notes(list(units))
    return units, notes


def auto_models(given: str | None = None) -> list[str]:
    """The structures --model auto fits: the library, less one of each pair of pulse twins (the
    same equations on a pulse test, `Structure.pulse_twin`): the one that names its twin is left
    out, unless it is the unit's own (`given`)."""
    out = []
    for name, st in STRUCTURES.items():
        twin = st.pulse_twin
        if twin is not None and name != given:
            continue
        if any(o.pulse_twin == name and o.name == given for o in STRUCTURES.values()):
            continue
        out.append(name)
    return out


def twin_notes(fitted: Sequence[str]) -> list[str]:
    """What each fitted structure stands for beside itself (its pulse twins left out)."""
    out = []
    for name in fitted:
        st = STRUCTURES[name]
        pairs = [o.name for o in STRUCTURES.values() if o.pulse_twin == name and o.name not in fitted]
        if st.pulse_twin is not None and st.pulse_twin not in fitted:
            pairs.append(st.pulse_twin)
        for other in pairs:
            out.append(f"{name} stands for {other} too: on a pulse test they are the same equations, "
                       "their limits under other names (not fitted apart)")
    return out

