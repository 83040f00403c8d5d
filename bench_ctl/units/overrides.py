"""Changes to a unit: `--set NAME=VALUE` overrides (`apply_overrides`) and another structure
(`--model`, `with_model`).

An override names what a unit file names, in the unit's structure's names (translated here to the
kernel's, as `unit.unit_from_dict` does for a file): a generator constant (`Td0p=6.0`), a fixed
parameter (`TR=0.01`), the value of an identified parameter (`KAVR=250`), a bound (`KAVR.min=20`),
a weight (`weights.vt=0.5`), an effect parameter (`VRMAX=2.8`, which switches its effect on) or a
[grid] value, fitted on line with bounds (`XE.min=0.05`). The whole unit is checked once all are
in (`unit.check_unit`). `--model auto` applies to each structure the overrides it has a name for
and leaves the others out (`apply_own_overrides`): the same parse, so the same names.
"""
from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import replace

from bench_ctl.model.dialect import Dialect
from bench_ctl.model.effects import EFFECTS
from bench_ctl.model.params import GENERATOR_OPTIONAL, MACHINE_PARAMS, PARAMS
from bench_ctl.model.stabilisers import model_code
from bench_ctl.model.structures import DEFAULT as DEFAULT_MODEL
from bench_ctl.model.structures import StructureError, structure

from .unit import (
    MACHINE_INFO,
    WEIGHT_KEYS,
    Bound,
    Unit,
    UnitError,
    check_unit,
    check_value,
    input_names,
    reference_unit,
    unit_from_dict,
)


def apply_overrides(unit: Unit, overrides: Iterable[str]) -> Unit:
    """Apply `--set NAME=VALUE` overrides (see the module docstring); unknown names are errors.
    The whole unit is checked once all are in (`KAVR.max=100 KAVR=80` is fine in that order)."""
    return _apply(unit, list(overrides), own_only=False)[0]


def apply_own_overrides(unit: Unit, overrides: Iterable[str]) -> tuple[Unit, list[str]]:
    """`--model auto`: the unit with the overrides that name something its structure has (its own
    standard names, the generator's, the effects', a weight; the reference structure: every
    kernel name), and the others, as given, which it leaves out."""
    return _apply(unit, list(overrides), own_only=True)


def _apply(unit: Unit, overrides: list[str], *, own_only: bool) -> tuple[Unit, list[str]]:
    """The --set parse: each override in the user's names, the kernel's from here on; (the unit,
    the overrides left out because the structure lacks the name, with `own_only`)."""
    names = input_names(unit.structure)   # the --set boundary: the user's names, the kernel's from here on
    taken: list[str] = []
    lacking: list[str] = []
    for item in overrides:
        key, _, raw = (s.strip() for s in item.partition("="))
        if own_only and not key.startswith("weights.") and not names.speaks(key.split(".", 1)[0]):
            lacking.append(item)
            continue
        taken.append(item)
        if "=" not in item:
            raise UnitError(f"--set {item!r}: expected NAME=VALUE")
        try:
            value = model_code(raw) if key == "PSS_MODEL" else float(raw)   # PSS_MODEL=PSS2B
        except ValueError as exc:
            raise UnitError(f"--set {item!r}: " + (str(exc) if key == "PSS_MODEL" else f"{raw!r} is not a number")) \
                from None
        if math.isnan(value):
            raise UnitError(f"--set {item!r}: NaN is not a value")
        try:
            unit = _apply_one(unit, names, key, value, item)
        except UnitError:
            raise
        except ValueError as exc:
            raise UnitError(str(exc)) from None
    if not taken:
        return unit, lacking
    return check_unit(_bypass_lead_lags(unit), f"{unit.source} with --set {' '.join(taken)}", names), lacking


def _bypass_lead_lags(unit: Unit) -> Unit:
    """A lead-lag of the structure set to both time constants 0 (`--set TB=0 --set TC=0`, a
    record's way of saying "none") runs as 1, 1, as the structure's typical 0, 0 and a .dyr's do
    (`Structure.kernel_values`); its standard values stay 0."""
    if unit.model == DEFAULT_MODEL:
        return unit
    fixed = unit.structure.bypass_lead_lags(unit.fixed)
    return replace(unit, fixed=fixed) if fixed != unit.fixed else unit


#: [grid] values an on-line record can determine (not the operating point, the frequency, the
#: stabiliser's model and its ramp-tracking filter's integers M, N)
GRID_FITTABLE = tuple(n for n in MACHINE_PARAMS if n not in ("P0", "Q0", "FN", "PSS_MODEL", "PSS2_M", "PSS2_N"))


def _grid_bound(unit: Unit, name: str, attr: str, value: float, item: str) -> Unit:
    """`--set XE.min=0.05` (or .max, .value): the [grid] value fitted on an on-line record within
    bounds (default: its physical range; start: its [grid] value, else the middle)."""
    if name not in GRID_FITTABLE or attr not in ("min", "max", "value"):
        raise UnitError(f"--set {item!r}: a [grid] value fitted on line takes .min, .max or .value; "
                        f"fittable: {', '.join(GRID_FITTABLE)}")
    info = MACHINE_INFO[name]
    info.check(value, where="--set ")
    given = name in unit.grid   # a start value given, else the middle of the bounds
    old = unit.grid_identify.get(name) or Bound(unit.grid.get(name, 0.0), info.lo, info.hi)
    b = replace(old, **{attr: value})
    if not b.min < b.max:
        raise UnitError(f"--set {item!r}: min {b.min} must be below max {b.max}")
    if attr != "value":
        b = replace(b, value=min(max(b.value, b.min), b.max) if given else 0.5 * (b.min + b.max))
    if not b.min <= b.value <= b.max:
        raise UnitError(f"--set {item!r}: {name} = {b.value} is outside its bounds [{b.min}, {b.max}]")
    grid = {**unit.grid, name: b.value} if given or attr == "value" else unit.grid
    return replace(unit, grid_identify={**unit.grid_identify, name: b}, grid=grid)


def with_model(unit: Unit, name: str) -> Unit:
    """The unit with another structure (`--model NAME`): the generator, weights and effects kept,
    the structure's default identified parameters, bounds and typical values."""
    st = structure(name)
    if st.name == unit.model:
        return unit
    data = {"name": unit.name, "generator": dict(unit.generator), "weights": dict(unit.weights),
            "avr": {"model": st.name}, "grid": dict(unit.grid)}
    if st.name == DEFAULT_MODEL:
        ref = reference_unit()
        data.update(identify={k: {"value": b.value, "min": b.min, "max": b.max} for k, b in ref.identify.items()},
                    fixed=dict(ref.fixed), constraints=list(ref.constraints))
    new = unit_from_dict(data, f"{unit.source} with --model {st.name}")
    return replace(new, effects={k: dict(v) for k, v in unit.effects.items()}, source=unit.source,
                   grid_identify=dict(unit.grid_identify))


def _std_to_kernel(names: Dialect, key: str, item: str) -> str:
    """`--set` names a standard parameter of the unit's structure: the kernel's name for it."""
    if names.plain:
        return key
    base, dot, attr = key.partition(".")
    st = names.structure
    if base in st.names:
        try:
            return st.kernel_name(base) + dot + attr
        except StructureError as exc:
            raise UnitError(f"--set {item!r}: {exc}") from None
    why = names.refusal(base)
    if why:
        raise UnitError(f"--set {item!r}: {why}")
    return key


def _apply_one(unit: Unit, names: Dialect, key: str, value: float, item: str) -> Unit:
    """`unit` with one override, `key` in the structure's `names` (`item`: the override as given,
    for messages, which name what the user wrote)."""
    std_key = key
    if unit.model != DEFAULT_MODEL and key in unit.structure.names and unit.structure.param(key).kernel is None:
        return replace(unit, model_values={**unit.model_values, key: value})  # for the record only
    key = _std_to_kernel(names, key, item)
    if unit.model != DEFAULT_MODEL and key != std_key and "." not in std_key:
        unit = replace(unit, model_values={**unit.model_values, std_key: value})
    if key in MACHINE_PARAMS:   # the machine on the grid, the grid, the operating point
        MACHINE_INFO[key].check(value, where="--set ")
        if key in unit.grid_identify:   # a fitted one: its start value
            return _grid_bound(unit, key, "value", value, item)
        return replace(unit, grid={**unit.grid, key: value})
    if "." in key and key.split(".", 1)[0] in MACHINE_PARAMS:   # XE.min=0.05: XE fitted on line
        name, attr = key.split(".", 1)
        return _grid_bound(unit, name, attr, value, item)
    if key.startswith("weights."):
        sig = key.split(".", 1)[1]
        if sig not in WEIGHT_KEYS:
            raise UnitError(f"--set {item!r}: unknown signal {sig!r}; allowed: {sorted(WEIGHT_KEYS)}")
        return replace(unit, weights={**unit.weights, sig: value})
    if "." in key:
        name, attr = key.split(".", 1)
        if name not in unit.identify or attr not in ("min", "max", "value"):
            shown = std_key.split(".", 1)[0]
            raise UnitError(f"--set {item!r}: {shown!r} is not an identified parameter with min/max/value"
                            f" (identified: {', '.join(names.name(n) for n in unit.identify)})")
        b = replace(unit.identify[name], **{attr: value})
        if not b.min < b.max:
            raise UnitError(f"--set {item!r}: min {b.min} must be below max {b.max}")
        return replace(unit, identify={**unit.identify, name: b})
    if key in unit.generator or key in GENERATOR_OPTIONAL:   # a generator constant stays with the generator
        PARAMS[key].check(value, where="--set ")
        return replace(unit, generator={**unit.generator, key: value})
    if key in unit.identify:
        return replace(unit, identify={**unit.identify, key: replace(unit.identify[key], value=value)})
    if key in unit.fixed:
        check_value(names, key, value, where="--set ")
        return replace(unit, fixed={**unit.fixed, key: value})
    for eff in EFFECTS.values():
        if key in eff.params:
            try:  # constraints between effect parameters: once all overrides are in
                return unit.with_effects({eff.name: {key: value}}, check_constraints=False)
            except ValueError as exc:
                raise UnitError(f"--set {item!r}: {exc}") from None
    if key in PARAMS:
        PARAMS[key].check(value, where="--set ")
        return replace(unit, fixed={**unit.fixed, key: value})
    known = names.names() + list(MACHINE_PARAMS)
    raise UnitError(f"--set {item!r}: unknown name {key!r}; known: {', '.join(known)}")
