"""Unit files: generator constants, parameters to identify, fixed parameters, constraints, effects.

A unit file is TOML (see `bench_ctl/data/reference_unit.toml`, the built-in default). Unknown keys
are errors. `--set NAME=VALUE` overrides and `--model` are changes to a unit read here
(`bench_ctl.units.overrides`).

The AVR / exciter structure is chosen with `[avr] model = "ESST1A"` (or `--model`); its parameters
are then named as the standard names them (KA, TC, TB, ...) in `[identify]`, `[fixed]`,
`constraints` and `--set`, and translated to the kernel's columns where they are read (a file here,
`--set` in `overrides`; `bench_ctl.model.structures`). The unit keeps the standard values too (`model_values`), for the
report and the PSS/E record. `[acceptance]` holds the grid operator's numeric acceptance limits
(`bench_ctl.signals.acceptance`).
"""
from __future__ import annotations

import math
import tomllib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

from bench_ctl.exitcodes import BadInput
from bench_ctl.limits import InputError, read_text
from bench_ctl.model.dialect import Dialect, dialect_of
from bench_ctl.model.effects import EFFECTS, effect
from bench_ctl.model.params import (
    AVR_PARAMS,
    GENERATOR_OPTIONAL,
    GENERATOR_PARAMS,
    MACHINE_CATALOGUE,
    MACHINE_PARAMS,
    PARAMS,
    neutral_values,
)
from bench_ctl.model.stabilisers import check_stabiliser, model_code
from bench_ctl.model.structures import DEFAULT as DEFAULT_MODEL
from bench_ctl.model.structures import Structure, StructureError, structure
from bench_ctl.model.unit_record import AcceptanceEntry, BoundEntry, UnitEntry
from bench_ctl.signals.acceptance import AcceptanceError, acceptance_limits


class UnitError(BadInput):
    """A unit file or override that cannot be used; the message names the file and key."""


@dataclass(frozen=True)
class Bound:
    value: float
    min: float
    max: float


@dataclass(frozen=True)
class Unit:
    name: str
    generator: dict[str, float]
    identify: dict[str, Bound]
    fixed: dict[str, float]
    constraints: tuple[str, ...]
    weights: dict[str, float]
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    source: str = "<built-in reference unit>"
    #: the AVR / exciter structure and the values of its parameters under their standard names
    model: str = DEFAULT_MODEL
    model_values: dict[str, float] = field(default_factory=dict)
    #: the numeric acceptance limits ([acceptance], checked; None = the defaults)
    acceptance: dict | None = None
    #: the machine on the grid and the grid ([grid], `online.MACHINE_PARAMS`; empty: no-load data only)
    grid: dict[str, float] = field(default_factory=dict)
    #: [grid] values fitted on an on-line record (`--set XE.min=0.05 --set XE.max=0.6`), with bounds
    grid_identify: dict[str, Bound] = field(default_factory=dict)

    @property
    def structure(self) -> Structure:
        return structure(self.model)

    def standard_values(self, kernel: Mapping[str, float] | None = None) -> dict[str, float]:
        """The structure's parameters under their standard names, from `kernel` values (default:
        the unit's own), the unit's standard values where the kernel does not simulate them."""
        return self.structure.std_values(self.values() if kernel is None else kernel, self.model_values)


    @property
    def identified_names(self) -> tuple[str, ...]:
        return tuple(self.identify)

    @property
    def bounds(self) -> list[tuple[float, float]]:
        return [(b.min, b.max) for b in self.identify.values()]

    def values(self) -> dict[str, float]:
        """Every kernel parameter: neutral effects, then generator, fixed, identified, effects on."""
        out = dict(neutral_values())
        out.update(self.generator)
        out.update(self.fixed)
        out.update({k: b.value for k, b in self.identify.items()})
        for params in self.effects.values():
            out.update(params)
        return out

    def with_effects(self, effects: Mapping[str, Mapping[str, float]], *,
                     check_constraints: bool = True) -> Unit:
        merged = {k: dict(v) for k, v in self.effects.items()}
        for name, params in effects.items():
            eff = effect(name)
            eff.check(dict(params))
            merged.setdefault(name, {}).update({k: float(v) for k, v in params.items()})
            missing = set(eff.params) - set(merged[name])
            if missing:
                # a partly given effect keeps the other parameters neutral
                merged[name].update({p: eff.neutral()[p] for p in missing})
            if check_constraints:  # e.g. saturation: S12 >= 1.44*S10, else the kernel has it off
                eff.check_constraints(merged[name])
        return replace(self, effects=merged)

    def entry(self) -> UnitEntry:
        """The unit as records write it, in the kernel's names (`bench_ctl.model.dialect` gives the
        structure's): a neutral limit (+-inf) is None."""
        acceptance = acceptance_limits(self.acceptance, self.source)
        return UnitEntry(
            name=self.name,
            source=self.source,
            generator=dict(self.generator),
            identify={k: BoundEntry(b.value, b.min, b.max) for k, b in self.identify.items()},
            fixed={k: _finite_or_none(v) for k, v in self.fixed.items()},
            constraints=list(self.constraints),
            weights=dict(self.weights),
            effects={k: {p: _finite_or_none(v) for p, v in ps.items()} for k, ps in self.effects.items()},
            model=self.model,
            model_values={k: _finite_or_none(v) for k, v in self.standard_values().items()},
            acceptance=AcceptanceEntry(**acceptance),
            grid=dict(self.grid),
            grid_identify={k: BoundEntry(b.value, b.min, b.max) for k, b in self.grid_identify.items()},
        )


def bounded_values(values: Mapping[str, object],
                   bounds: Mapping[str, object]) -> Iterator[tuple[str, float, float, float]]:
    """(name, value, min, max) for each numeric value with a [min, max] pair in `bounds` (as a
    result JSON writes them; anything else is skipped)."""
    for name, value in values.items():
        b = bounds.get(name)
        if isinstance(b, (list, tuple)) and len(b) == 2 and isinstance(value, (int, float)) \
                and not isinstance(value, bool):
            yield name, float(value), float(b[0]), float(b[1])


def outside_bounds(values: Mapping[str, object], bounds: Mapping[str, object]) -> list[str]:
    """'NAME = value [min, max]' for each value beyond its bounds (by more than rounding)."""
    return [f"{name} = {v:.6g} [{lo:g}, {hi:g}]" for name, v, lo, hi in bounded_values(values, bounds)
            if v < lo - 1e-9 * (hi - lo) or v > hi + 1e-9 * (hi - lo)]


def _finite_or_none(v: float) -> float | None:
    """JSON has no infinity: a neutral limit (+-inf) is written as null."""
    return v if math.isfinite(v) else None


_TOP_KEYS = {"name", "constraints", "generator", "identify", "fixed", "weights", "effects", "avr",
             "acceptance", "grid"}
_TABLE_KEYS = ("generator", "identify", "fixed", "weights", "effects", "avr", "acceptance", "grid")
#: the machine-on-the-grid parameters by name (their units, meanings and physical ranges)
MACHINE_INFO = {p.name: p for p in MACHINE_CATALOGUE}


def input_names(st: Structure) -> Dialect:
    """The names a unit's input speaks, structure `st`'s: the one place where a unit file
    (`unit_from_dict`) and `--set` (`overrides.apply_overrides`) take their dialect, to read a
    name in the kernel's (`Dialect.kernel_text`, `Dialect.refusal`, ...) and to say one in their
    messages (`check_unit`); the kernel's from there on."""
    return dialect_of(st)


def check_unit(unit: Unit, source: str, d: Dialect) -> Unit:
    """What a whole unit must satisfy, once every override is in: every AVR parameter given,
    identified values finite and inside their bounds, bounds and fixed values inside the
    physical ranges, fixed names apart from the generator's. Messages name parameters in `d`'s
    names, the ones the input (a file, `--set`) was read in."""
    for name in AVR_PARAMS:
        if name not in unit.identify and name not in unit.fixed:
            raise UnitError(f"{source}: AVR parameter {name} is neither under [identify] nor [fixed]")
    for name, b in unit.identify.items():
        shown = d.name(name)   # messages in the structure's names
        for what, v in (("min", b.min), ("max", b.max), ("value", b.value)):
            if not math.isfinite(v):
                raise UnitError(f"{source}: identify.{shown}.{what} = {v!r} must be finite")
            try:
                check_value(d, name, v, where=f"{source}: identify.{shown}.{what}: ")
            except ValueError as exc:
                raise UnitError(str(exc)) from None
        if not b.min <= b.value <= b.max:
            raise UnitError(f"{source}: identify.{shown}.value = {b.value!r} is outside its bounds "
                            f"[{b.min!r}, {b.max!r}]")
    for name, params in unit.effects.items():
        try:
            EFFECTS[name].check_constraints(params)
        except ValueError as exc:
            raise UnitError(f"{source}: {exc}") from None
    for name, v in unit.fixed.items():
        if name in unit.generator:
            raise UnitError(f"{source}: fixed.{name}: a generator constant; set it under [generator]")
        try:
            check_value(d, name, v, where=f"{source}: fixed.")
        except ValueError as exc:
            raise UnitError(str(exc)) from None
    try:
        check_stabiliser(unit.grid, where=f"{source}: grid.")
    except ValueError as exc:
        raise UnitError(str(exc)) from None
    return unit


def check_value(d: Dialect, kernel_name: str, value: float, where: str) -> None:
    """The kernel parameter's physical range check, its message naming the parameter as the
    structure does (ESST1A's `TA`, not the kernel's `TE`)."""
    info = PARAMS[kernel_name]
    name = d.name(kernel_name)
    if name != kernel_name:
        p = d.structure.param(name)
        info = replace(info, name=name, unit=p.unit, info=p.info)
    info.check(value, where=where)


#: the signals a unit's [weights] may weigh
WEIGHT_KEYS = {"efd", "vt", "q", "vs"}
#: the default weight of the stabiliser's output `vs`, counted only where a capture records it (0
#: otherwise). A reference step moves a PSS's output about a hundredth as much as efd (the PSS2B
#: records of tests/pss2_cases.py: 0.00075 against 0.13 pu rms over the response, 1/170), so that
#: at 1e4 its squared errors count comparably with efd's at 1 (a third as much there, as its noise
#: does: 5e-5 pu against efd's 0.01); not more, so that a noisier vs channel does not drown efd
VS_WEIGHT = 1.0e4


def _num(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UnitError(f"{where}: expected a number, got {value!r}")
    v = float(value)
    if math.isnan(v):
        raise UnitError(f"{where}: NaN is not a value")
    return v


def _translate(d: Dialect, data: Mapping, source: str) -> tuple[dict, dict[str, float]]:
    """A unit file of a standard structure in the kernel's names: [identify], [fixed] and the
    constraints renamed, the structure's settings fixed, its typical values where the file is
    silent. Returns (data, the standard values the file gave or implied)."""
    st = d.structure
    ident_raw = dict(data.get("identify", {}) or {})
    fixed_raw = dict(data.get("fixed", {}) or {})
    if "identify" not in data:
        ident_raw = {p.name: {"value": p.typical, "min": p.bounds[0], "max": p.bounds[1]}
                     for p in st.params if p.identify and p.bounds}
    std_vals: dict[str, float] = {}
    identify: dict[str, object] = {}
    for name, spec in ident_raw.items():
        try:
            identify[st.kernel_name(name)] = spec
        except StructureError as exc:
            raise UnitError(f"{source}: identify.{name}: {exc}") from None
        if isinstance(spec, Mapping) and "value" in spec:
            std_vals[name] = _num(spec["value"], f"{source}: identify.{name}.value")
    fixed: dict[str, object] = {}
    for name, v in fixed_raw.items():
        if name in st.names:
            std_vals[name] = _num(v, f"{source}: fixed.{name}")
        elif d.refusal(name):
            raise UnitError(f"{source}: fixed.{name}: {d.refusal(name)}")
        elif name in PARAMS:
            fixed[name] = v      # a kernel parameter the structure does not name (TD, ...)
        else:
            raise UnitError(f"{source}: fixed.{name}: model {st.name} has no parameter {name!r}; "
                            f"it has {', '.join(st.names)}")
    for p in st.params:
        if p.name not in ident_raw:
            std_vals.setdefault(p.name, p.typical)
    kern = st.kernel_values({k: v for k, v in std_vals.items() if k not in ident_raw})
    for k, v in kern.items():
        if k not in identify:
            fixed[k] = v
    constraints = [_rename(c, d, source) for c in data.get("constraints", list(st.constraints)) or []] \
        if isinstance(data.get("constraints", []), list) else data.get("constraints")
    out = {k: v for k, v in data.items() if k != "avr"}
    out.update(identify=identify, fixed=fixed, constraints=constraints)
    return out, std_vals


def _rename(text: object, d: Dialect, source: str) -> object:
    """A constraint's standard names in the kernel's ("TB1 <= TC1" -> "TA4 <= TA3"); a kernel
    name the structure calls otherwise is refused, naming the standard one."""
    if not isinstance(text, str):
        return text
    import re
    for word in re.findall(r"[A-Za-z_][A-Za-z0-9_]*", text):
        why = d.refusal(word)
        if why:
            raise UnitError(f"{source}: constraint {text!r}: {why}")
    return d.kernel_text(text)


def _acceptance(raw: object, source: str) -> dict | None:
    if raw is None:
        return None
    try:
        acceptance_limits(raw, source)
    except AcceptanceError as exc:
        raise UnitError(str(exc)) from None
    return {k: dict(v) if isinstance(v, Mapping) else v for k, v in raw.items()}


def unit_from_dict(data: Mapping, source: str) -> Unit:
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise UnitError(f"{source}: unknown key(s) {sorted(unknown)}; allowed: {sorted(_TOP_KEYS)}")
    for key in _TABLE_KEYS:
        if key in data and not isinstance(data[key], Mapping):
            raise UnitError(f"{source}: {key} must be a table ([{key}]), got {data[key]!r}")
    avr = dict(data.get("avr", {}))
    if set(avr) - {"model"}:
        raise UnitError(f"{source}: [avr] unknown key(s) {sorted(set(avr) - {'model'})}; allowed: ['model']")
    try:
        st = structure(avr.get("model") if isinstance(avr.get("model", ""), str) else repr(avr.get("model")))
    except StructureError as exc:
        raise UnitError(f"{source}: avr.model: {exc}") from None
    std_vals: dict[str, float] = {}
    d = input_names(st)   # the file speaks the structure's names: the kernel's from here on
    if not d.plain:
        data, std_vals = _translate(d, data, source)
    for name, ps in data.get("effects", {}).items():
        if not isinstance(ps, Mapping):
            raise UnitError(f"{source}: effects.{name} must be a table of its parameters, got {ps!r}")
    gen_raw = data.get("generator", {})
    bad = set(gen_raw) - set(GENERATOR_PARAMS) - set(GENERATOR_OPTIONAL)
    if bad:
        raise UnitError(f"{source}: [generator] unknown key(s) {sorted(bad)}; allowed: "
                        f"{list(GENERATOR_PARAMS + GENERATOR_OPTIONAL)}")
    generator = {k: _num(v, f"{source}: generator.{k}") for k, v in gen_raw.items()}
    missing = set(GENERATOR_PARAMS) - set(generator)
    if missing:
        raise UnitError(f"{source}: [generator] is missing {sorted(missing)}")
    for k, v in generator.items():
        try:
            PARAMS[k].check(v, where=f"{source}: generator.")
        except ValueError as exc:
            raise UnitError(str(exc)) from None

    identify: dict[str, Bound] = {}
    for name, spec in data.get("identify", {}).items():
        where = f"{source}: identify.{d.name(name)}"
        if name not in PARAMS:
            raise UnitError(f"{where}: unknown parameter; known: {', '.join(PARAMS)}")
        if not isinstance(spec, Mapping) or set(spec) - {"value", "min", "max"} or not {"min", "max"} <= set(spec):
            raise UnitError(f"{where}: expected a table with min, max and optional value, got {spec!r}")
        lo, hi = _num(spec["min"], where + ".min"), _num(spec["max"], where + ".max")
        val = _num(spec.get("value", 0.5 * (lo + hi)), where + ".value")
        if not lo < hi:
            raise UnitError(f"{where}: min {lo} must be below max {hi}")
        identify[name] = Bound(val, lo, hi)

    fixed = {}
    for name, v in data.get("fixed", {}).items():
        if name not in PARAMS:
            raise UnitError(f"{source}: fixed.{name}: unknown parameter; known: {', '.join(PARAMS)}")
        if name in identify:
            raise UnitError(f"{source}: fixed.{d.name(name)}: also listed under [identify]")
        fixed[name] = _num(v, f"{source}: fixed.{d.name(name)}")

    weights = {"efd": 1.0, "vt": 0.0}
    for name, v in data.get("weights", {}).items():
        if name not in WEIGHT_KEYS:
            raise UnitError(f"{source}: weights.{name}: unknown signal; allowed: {sorted(WEIGHT_KEYS)}")
        weights[name] = _num(v, f"{source}: weights.{name}")

    constraints = data.get("constraints", [])
    if not isinstance(constraints, list) or not all(isinstance(c, str) for c in constraints):
        raise UnitError(f"{source}: constraints must be a list of strings like \"TA2 <= TA1\"")

    unit = Unit(
        name=str(data.get("name", Path(source).stem)),
        generator=generator, identify=identify, fixed=fixed,
        constraints=tuple(constraints), weights=weights, source=source,
        model=st.name, model_values=std_vals, acceptance=_acceptance(data.get("acceptance"), source),
        grid=grid_values(data.get("grid", {}), source),
    )
    effects_raw = data.get("effects", {})
    for name in effects_raw:
        if name not in EFFECTS:
            raise UnitError(f"{source}: effects.{name}: unknown effect; known: {', '.join(EFFECTS)}")
    try:
        unit = unit.with_effects({k: {p: _num(v, f"{source}: effects.{k}.{p}") for p, v in ps.items()}
                                  for k, ps in effects_raw.items()})
    except UnitError:
        raise
    except ValueError as exc:
        raise UnitError(f"{source}: {exc}") from None
    return check_unit(unit, source, d)


def grid_values(raw: Mapping, source: str) -> dict[str, float]:
    """[grid]: the machine's on-line data, the grid to the infinite bus, the operating point, each
    checked against its physical range (a unit file's, or values read from a .dyr record)."""
    bad = set(raw) - set(MACHINE_PARAMS)
    if bad:
        raise UnitError(f"{source}: [grid] unknown key(s) {sorted(bad)}; allowed: {list(MACHINE_PARAMS)}")
    grid = {k: _num(v, f"{source}: grid.{k}") for k, v in raw.items() if k != "PSS_MODEL"}
    try:
        if "PSS_MODEL" in raw:   # the stabiliser's name ("PSS2B") or its code
            grid["PSS_MODEL"] = model_code(raw["PSS_MODEL"])
        for k, v in grid.items():
            MACHINE_INFO[k].check(v, where=f"{source}: grid.")
        check_stabiliser(grid, where=f"{source}: grid.")
    except ValueError as exc:
        raise UnitError(str(exc)) from None
    return grid


def load_unit(path: str | Path | None = None) -> Unit:
    """Load a unit file, or the built-in reference unit when `path` is None."""
    if path is None:
        text = resources.files("bench_ctl.data").joinpath("reference_unit.toml").read_text("utf-8")
        source = "<built-in reference unit>"
    else:
        p = Path(path)
        try:   # a regular file within the limit (not /dev/zero, not a capture)
            text = read_text(p, "a unit file")
        except InputError as exc:
            raise UnitError(str(exc)) from None
        source = str(p)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise UnitError(f"{source}: not valid TOML: {exc}") from None
    return unit_from_dict(data, source)


def reference_unit() -> Unit:
    return load_unit(None)
