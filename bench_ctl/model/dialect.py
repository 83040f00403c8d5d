"""One dialect a user reads: a structure's own names at every boundary, the kernel's inside.

Inside bench-ctl a unit's values are kernel parameters (`bench_ctl.model.params`, the columns of
the kernel's matrix); a user reads and writes a standard structure's IEEE 421.5 / PSS/E names
(`bench_ctl.model.structures`): ESST1A's `KA`, `TA`, `TB1` are the kernel's `KAVR`, `TE`, `TA4`.
A structure's `Dialect` (`dialect_of`, taken where an input is parsed or a record written) is
the one place that translates, in each direction, and it is applied at the boundaries only:

- kernel -> standard, where a record is written: a result, a diagnosis, a `--model auto`
  candidate and a simulated capture's unit are built in kernel names and renamed once by the one
  writer (`bench_ctl.identification.result_file.written`, through their records'
  `renamed(dialect)`: `name`, `text`, `keys`, `fixed`, `unit`; the kernel's own view goes under a
  `kernel` key, for debugging); texts a record carries that name parameters (the
  identifiability notes) are made as `Note`s, prose with the kernel names as data, and said in
  the structure's names by the same writer (`say`: the names translated, never the prose); so is
  a refusal of the problem a unit gives (constraints that contradict each other inside the
  bounds), its message a `Note` too (a capture's path in its prose is said as it is), by the same
  writer where the unit was loaded (the `identify` command) or the diagnosis is written
  (`bench_ctl.diagnosis.diagnose.diagnose`);
- standard -> kernel, where an input is parsed: unit files and `--set` (`bench_ctl.units.unit`,
  `bench_ctl.units.overrides`, their dialect taken in one place, `bench_ctl.units.unit.input_names`:
  `kernel_text`, `refusal` of a kernel name, naming the standard one), and a result read back
  (`kernel_sections`: its values for the report's re-simulation, `export --dyr` and
  `diagnose --result`, through `IdentificationResult.kernel_view`).

The REFERENCE structure's names are the kernel's (it is the paper's model): there both views are
the same and nothing is renamed. A result written before the standard names (no `kernel` key) is
read in the kernel's names (docs/formats.md).
"""
from __future__ import annotations

import dataclasses
import functools
import re
from collections.abc import Mapping
from typing import Any

from .effects import EFFECTS
from .params import GENERATOR_OPTIONAL, GENERATOR_PARAMS, PARAMS, RECORD_PARAMS
from .structures import DEFAULT, Structure, StructureError, structure
from .unit_record import UnitEntry, UnitKernelEntry

__all__ = ["Dialect", "Note", "dialect_of", "kernel_sections", "prose", "structure_of", "shared_names", "slots"]

_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def shared_names() -> tuple[str, ...]:
    """Names every structure shares with the kernel: the generator's, the effects' (their options
    included; docs/model.md) and the record's edge offsets (`EDGE1`..: the fitted instant of a
    setpoint edge less its nominal sample, the same for every structure)."""
    return (*GENERATOR_PARAMS, *GENERATOR_OPTIONAL,
            *(p for e in EFFECTS.values() for p in (*e.params, *e.options)), *RECORD_PARAMS)


class Note(str):
    """A text that names parameters, made inside in the kernel's names and said in a structure's
    by the writer (`Dialect.say`): prose with a `{}` slot for each of `args`, an arg being a kernel
    name, a formula in kernel names (a constraint's text) or another `Note`. Only the args are
    translated, never the prose. As a `str` it is the text in the kernel's names (what a record of
    the reference structure writes); a note without args is its text as it is (a structure's
    declared exchange, in its own names)."""

    template: str
    args: tuple[str, ...]

    def __new__(cls, template: str, *args: str) -> Note:
        self = super().__new__(cls, template.format(*args) if args else template)
        self.template, self.args = template, args
        return self

    def __getnewargs__(self) -> tuple[str, ...]:   # pickled (a worker's result) with its args
        return (self.template, *self.args)

    def render(self, d: Dialect) -> str:
        """The text with every arg in the structure of `d`'s names."""
        if not self.args:
            return self.template
        return self.template.format(*(a.render(d) if isinstance(a, Note) else d.text(a) for a in self.args))


def prose(text: object) -> str:
    """`text` (a path, a value, a unit's name) for a `Note`'s prose, said as it is: its braces
    doubled, so that none is read as a slot."""
    return str(text).replace("{", "{{").replace("}", "}}")


def slots(n: int, sep: str = ", ") -> str:
    """`n` slots of a `Note` separated by `sep` (a list of names: `slots(len(names))`)."""
    return sep.join(["{}"] * n)


@functools.cache
def _dialect(name: str) -> Dialect:
    return Dialect(structure(name))


def dialect_of(st: Structure) -> Dialect:
    """The dialect of structure `st` (one per structure)."""
    return _dialect(st.name)


class Dialect:
    """A structure's names as its user reads them, and the kernel's they stand for."""

    def __init__(self, st: Structure) -> None:
        self.structure = st
        #: the structure speaks the kernel's names (REFERENCE): nothing to translate
        self.plain = st.name == DEFAULT

    # ------------------------------------------------------------ kernel -> standard (output)
    def name(self, kernel: str) -> str:
        """The standard name of a kernel parameter the structure drives; other names unchanged."""
        return kernel if self.plain else (self.structure.std_name(kernel) or kernel)

    def text(self, text: str) -> str:
        """A text in kernel names (a constraint, `TE <= TA4`) in the structure's (`TA <= TB1`); all
        names at once, so a swap (IEEEX1: kernel TE is TA, TEX is TE) cannot chain."""
        if self.plain:
            return text
        return _WORD.sub(lambda m: self.structure.std_name(m.group(0)) or m.group(0), text)

    def say(self, text: str) -> str:
        """A text a record carries, in the structure's names: a `Note` rendered (its args
        translated, its prose as it is); any other text as it is."""
        return text.render(self) if isinstance(text, Note) and not self.plain else str(text)

    def keys(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """A table keyed by kernel names, keyed by the structure's."""
        return {self.name(k): v for k, v in values.items()}

    def deep(self, x: Any) -> Any:
        """`x` (nested JSON objects, lists, texts) with every name in a key or a text in the
        structure's: for an object a record copies whole (an optimizer's settings); a `Note` in it
        is said (`say`), its prose left as it is."""
        if isinstance(x, Mapping):
            return {(self.text(k) if isinstance(k, str) else k): self.deep(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [self.deep(v) for v in x]
        return self.say(x) if isinstance(x, Note) else self.text(x) if isinstance(x, str) else x

    def fixed(self, kernel: Mapping[str, Any], std_values: Mapping[str, Any], skip: set[str]) -> dict[str, Any]:
        """A `fixed` table in the structure's names: its parameters not in `skip` (standard values),
        then the names all structures share (generator, effects, dead time, ...). Kernel names its
        parameters drive or its settings fix are left out (implied by the structure), so are other
        structures' blocks (neutral) and a shared name that is one of its standard names with
        another meaning (ESST4B's VRMAX is the kernel's VPMAX; the kernel's VRMAX, the diagnosis'
        ceiling, is under `unit.effects`)."""
        st = self.structure
        out = {p.name: std_values[p.name] for p in st.params if p.name not in skip and p.name in std_values}
        own = {p.kernel for p in st.params if p.kernel} | set(st.settings) | set(st.names)
        shared = set(shared_names())
        out.update({k: v for k, v in kernel.items() if k in shared and k not in own})
        return out

    def unit(self, entry: UnitEntry) -> UnitEntry:
        """A unit's entry (`Unit.entry`) in the structure's names; the kernel's identify, fixed and
        constraints under `kernel`."""
        if self.plain:
            return entry
        return dataclasses.replace(
            entry, identify=self.keys(entry.identify),
            fixed=self.fixed(entry.fixed, entry.model_values, {self.name(k) for k in entry.identify}),
            constraints=[self.text(c) for c in entry.constraints],
            kernel=UnitKernelEntry(dict(entry.identify), dict(entry.fixed), list(entry.constraints)))

    # ------------------------------------------------------------ standard -> kernel (input)
    def kernel_text(self, text: str) -> str:
        """A text in the structure's names (`TA <= TB1`) in the kernel's (`TE <= TA4`)."""
        if self.plain:
            return text
        st = self.structure
        return _WORD.sub(lambda m: (st.param(m.group(0)).kernel or m.group(0)) if m.group(0) in st.names
                         else m.group(0), text)

    def kernel_keys(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """Standard names -> kernel names; a parameter kept for the record only is left out."""
        if self.plain:
            return dict(values)
        st = self.structure
        out = {}
        for k, v in values.items():
            if k in st.names:
                kern = st.param(k).kernel
                if kern is not None:
                    out[kern] = v
            else:
                out[k] = v
        return out

    def refusal(self, name: str) -> str | None:
        """Why `name` is not a name of the structure when it is a kernel name the structure hides
        (the message names the standard one); None for any other name."""
        st = self.structure
        if self.plain or name in st.names:
            return None
        drivers = [p.name for p in st.params if p.kernel == name]
        if drivers:
            return f"{name} is the kernel's name; model {st.name} calls it {drivers[0]}: use {drivers[0]}"
        if name in st.settings:
            return (f"{name} is a kernel setting that model {st.name} fixes at {st.settings[name]:g}; "
                    f"its parameters are {', '.join(st.names)}")
        if name in PARAMS and name not in shared_names():
            return (f"{name} is a kernel parameter that model {st.name} does not have; its parameters are "
                    f"{', '.join(st.names)}")
        return None

    # ------------------------------------------------------------ the names a user reads
    def speaks(self, name: str) -> bool:
        """Whether `name` is one a user of the structure reads: its own or one all structures share
        (the reference structure: every kernel name)."""
        return name in PARAMS if self.plain else (name in self.structure.names or name in shared_names())

    def names(self) -> list[str]:
        """Every name a user of the structure may set: its own, then those all structures share
        (the reference structure: the kernel's)."""
        st = self.structure
        return list(PARAMS) if self.plain else [*st.names, *(n for n in shared_names() if n not in st.names)]

    def describe(self, name: str) -> tuple[str, str, float | None] | None:
        """(unit, meaning, neutral value) of a name as the structure's user reads it: its own
        parameter, else the kernel catalogue's (generator, effects); None for an unknown name."""
        st = self.structure
        if not self.plain and name in st.names:
            p = st.param(name)
            return p.unit, p.info, None
        info = PARAMS.get(name)
        return (info.unit, info.info, info.neutral) if info else None

    def hidden_kernel_names(self) -> tuple[str, ...]:
        """Kernel names a user of a standard structure never reads: every kernel parameter that
        is neither one of its names nor a name all structures share (`shared_names`), e.g. the ones
        its parameters drive under another name, its settings and other structures' blocks."""
        st = self.structure
        shared = set(shared_names())
        own = {p.kernel for p in st.params if p.kernel} | set(st.settings)
        return tuple(sorted(n for n in PARAMS if n not in st.names and (n not in shared or n in own)))


def structure_of(result: Mapping[str, Any]) -> Structure:
    """The structure a result or diagnosis names (`model.name`, else `unit.model`; REFERENCE)."""
    model = result.get("model") if isinstance(result.get("model"), Mapping) else {}
    unit = result.get("unit") if isinstance(result.get("unit"), Mapping) else {}
    return structure(model.get("name") or unit.get("model") or None)


def kernel_sections(result: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """`fixed` and `params` of an identification result (its JSON) in kernel names, values as
    written (null: an open limit): in a result of a standard structure every parameter of the
    structure becomes the kernel parameter it drives (one kept for the record only is left out),
    the structure's settings are added to `fixed`, and the unit's effects too (their names are the
    kernel's). A result without a `kernel` key was written in kernel names and is read as it is."""
    try:
        st = structure_of(result)
    except StructureError:
        st = structure(None)
    d = dialect_of(st)
    fixed = dict(result.get("fixed") or {})
    params = dict(result.get("params") or {})
    if d.plain or "kernel" not in result:
        return {"fixed": fixed, "params": params}
    kfixed: dict[str, Any] = dict(st.settings)
    kfixed.update(d.kernel_keys(fixed))
    unit = result.get("unit") if isinstance(result.get("unit"), Mapping) else {}
    for ps in (unit.get("effects") or {}).values():     # on top, as `Unit.values` has them
        if isinstance(ps, Mapping):
            kfixed.update(ps)
    kparams = d.kernel_keys(params)
    for lead, lag in st.lead_lags:      # a bypassed lead-lag (both 0 in the standard) is 1, 1
        merged = {**kfixed, **kparams}
        if merged.get(lead) == 0.0 and merged.get(lag) == 0.0:
            for n in (lead, lag):
                (kparams if n in kparams else kfixed)[n] = 1.0
    return {"fixed": {k: v for k, v in kfixed.items() if k not in kparams}, "params": kparams}
