"""The model library: the AVR / exciter structures a unit can use (issue 13, docs/model.md).

Each structure lives in one file of this package and declares, once, its parameters under their
standard (IEEE 421.5 / PSS/E) names with unit, meaning, typical value and default identification
bounds (`blocks.Param`), its blocks in diagram order (`blocks.Transducer`, `LeadLag`,
`RegulatorLag`, ...) and its PSS/E dynamic data record; `declare` generates from the blocks the
kernel column each parameter drives, the kernel settings the structure implies and its block
diagram in words, so that they cannot drift. All structures run on the one compiled kernel
(`bench_ctl.engine`): its blocks are a superset (two lead-lags, a regulator lag whose
ceilings scale with Vt and drop by KC*Ifd, non-windup or output clamp, rate feedback, a DC
exciter with quadratic saturation, a potential-source stage with PI regulators and the output
VB VM), a structure picks and names the ones it has. The effects of
the diagnosis stay switchable on top of every structure.

Adding a structure: one file here with a `STRUCTURE = declare(...)`, its name in `_MODULES`,
and an ANDES fixture (benchmarks/andes_captures.py) that checks it (docs/decisions/0009).
"""
from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from bench_ctl.exitcodes import BadInput

from ..params import PARAMS
from .blocks import Block, Param, generate


class StructureError(BadInput):
    """An unknown structure or a parameter it does not have; the message names both."""


@dataclass(frozen=True)
class StdParam:
    """One parameter of a standard structure, under its standard name."""
    name: str
    unit: str
    info: str
    typical: float
    #: default identification bounds (the typical range); None: not identified by default
    bounds: tuple[float, float] | None = None
    #: the kernel parameter it drives; None: part of the record, not simulated (`note` says why)
    kernel: str | None = None
    identify: bool = False
    note: str = ""


@dataclass(frozen=True)
class Structure:
    name: str
    title: str
    diagram: tuple[str, ...]
    params: tuple[StdParam, ...]
    #: kernel values the structure implies (e.g. a lead-lag it lacks: TA3 = TA4 = 1)
    settings: Mapping[str, float] = field(default_factory=dict)
    constraints: tuple[str, ...] = ()
    #: the PSS/E model name of its dynamic data record (None: no standard record)
    dyr_model: str | None = None
    #: PSS/E fields that are not a parameter under the same name: field -> (to_dyr, from_dyr)
    dyr_special: Mapping[str, tuple[Callable[[Mapping[str, float]], float],
                                    Callable[[Mapping[str, float]], tuple[str, float]]]] = \
        field(default_factory=dict)
    #: kernel lead-lag pairs (lead, lag): both 0 in the standard means "no lead-lag" (1, 1 here)
    lead_lags: tuple[tuple[str, str], ...] = ()
    #: (note, (A, B)): two time constants whose exchange leaves the small-signal response (nearly)
    #: unchanged, so a fit can settle in the exchanged basin; identification restarts its
    #: polish from the exchanged point (`peers._swap_restarts`)
    swaps: tuple[tuple[str, tuple[str, str]], ...] = ()
    source: str = ""
    #: another structure whose equations this one's are on a pulse test (its limits under other
    #: names): `--model auto` fits one of the two and names the other with it
    pulse_twin: str | None = None
    #: the blocks in diagram order the mapping, settings and diagram were generated from
    blocks: tuple[Block, ...] = ()

    # ---- names ----
    def param(self, name: str) -> StdParam:
        for p in self.params:
            if p.name == name:
                return p
        drivers = [p.name for p in self.params if p.kernel == name]
        if drivers:   # a kernel name: say which of the structure's names it is
            raise StructureError(f"model {self.name} has no parameter {name!r}: {name} is the kernel's name, "
                                 f"{self.name} calls it {drivers[0]}; use {drivers[0]}")
        raise StructureError(f"model {self.name} has no parameter {name!r}; it has "
                             f"{', '.join(p.name for p in self.params)}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    def kernel_name(self, name: str) -> str:
        """The kernel parameter a standard name drives; an error for one that is not simulated."""
        p = self.param(name)
        if p.kernel is None:
            raise StructureError(f"model {self.name}: {name} is kept for the record but not simulated "
                                 f"({p.note or 'inactive in a no-load pulse test'}); it cannot be identified")
        return p.kernel

    def std_name(self, kernel: str) -> str | None:
        for p in self.params:
            if p.kernel == kernel:
                return p.name
        return None

    def typical(self) -> dict[str, float]:
        return {p.name: p.typical for p in self.params}

    def default_identified(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params if p.identify)

    # ---- values ----
    def kernel_values(self, std: Mapping[str, float]) -> dict[str, float]:
        """Kernel values for the simulated standard parameters in `std` plus the structure's
        settings; a lead-lag given as both time constants 0 (bypassed) becomes 1, 1."""
        out = dict(self.settings)
        for name, v in std.items():
            p = self.param(name)
            if p.kernel is not None:
                out[p.kernel] = float(v)
        return self.bypass_lead_lags(out)

    def bypass_lead_lags(self, kernel: Mapping[str, float]) -> dict[str, float]:
        """`kernel` (kernel names) with each of the structure's lead-lags given as both time
        constants 0 (a record's way of saying "none") run as 1, 1."""
        out = dict(kernel)
        for lead, lag in self.lead_lags:
            if out.get(lead) == 0.0 and out.get(lag) == 0.0:
                out[lead] = out[lag] = 1.0
        return out

    def std_values(self, kernel: Mapping[str, float], given: Mapping[str, float]) -> dict[str, float]:
        """Standard values: `given` (the unit's own, typical where absent), each simulated one
        replaced by the kernel's value unless it is a bypassed lead-lag that stayed bypassed."""
        out = {**self.typical(), **{k: float(v) for k, v in given.items()}}
        bypassed = {n for lead, lag in self.lead_lags
                    if kernel.get(lead) == 1.0 and kernel.get(lag) == 1.0
                    for n in (self.std_name(lead), self.std_name(lag))
                    if n is not None and out.get(n) == 0.0}
        for p in self.params:
            if p.kernel is not None and p.kernel in kernel and p.name not in bypassed:
                v = kernel[p.kernel]
                out[p.name] = float(v) if v is not None else out[p.name]
        return out

    # ---- the PSS/E record ----
    def dyr_values(self, std: Mapping[str, float], fields: tuple[str, ...]) -> dict[str, float]:
        out = {}
        for f in fields:
            if f in self.dyr_special:
                out[f] = float(self.dyr_special[f][0](std))
            elif f in std:
                out[f] = float(std[f])
            else:
                raise StructureError(f"model {self.name}: no value for the {self.dyr_model} field {f!r}")
        return out

    def from_dyr(self, values: Mapping[str, float]) -> dict[str, float]:
        out = {}
        for f, v in values.items():
            if f in self.dyr_special:
                name, value = self.dyr_special[f][1](values)
                out[name] = value
            elif f in self.names:
                out[f] = float(v)
        return out

    def kernel_swaps(self, fitted: Sequence[str]) -> list[tuple[str, str, str]]:
        """`swaps` whose two parameters are both among the `fitted` kernel names, as (note,
        kernel name, kernel name)."""
        out = []
        for note, (a, b) in self.swaps:
            ka, kb = self.kernel_name(a), self.kernel_name(b)
            if ka in fitted and kb in fitted:
                out.append((note, ka, kb))
        return out

    def describe(self, kernel: bool = False) -> str:
        """`bench-ctl models NAME`: in the structure's names; `kernel` adds the kernel parameter
        each one drives and the kernel settings the structure implies (debugging)."""
        lines = [f"{self.name}: {self.title}", ""]
        lines += ["Block diagram:"] + [f"  {d}" for d in self.diagram] + [""]
        kcol = f" {'kernel':<7}" if kernel else ""
        lines.append(f"{'parameter':<9} {'unit':<6} {'typical':>9}  {'bounds':<17}{kcol} meaning")
        for p in self.params:
            b = f"[{p.bounds[0]:g}, {p.bounds[1]:g}]" if p.bounds else "-"
            mark = "*" if p.identify else " "
            kern = f" {p.kernel or '-':<7}" if kernel else ""
            record = "" if p.kernel else " (record)"
            lines.append(f"{p.name + mark:<9} {p.unit:<6} {p.typical:>9g}  {b:<17}{kern} {p.info}{record}"
                         + (f" [{p.note}]" if p.note else ""))
        lines.append("")
        lines.append("* identified by default; (record): written to the .dyr, not simulated")
        if kernel and self.settings:
            lines.append("kernel settings: " + ", ".join(f"{k} = {v:g}" for k, v in self.settings.items()))
        if self.constraints:
            lines.append("constraints: " + ", ".join(self.constraints))
        if self.dyr_model:
            lines.append(f"PSS/E record: {self.dyr_model}")
        if self.source:
            lines.append(f"source: {self.source}")
        return "\n".join(lines)

    def check(self) -> None:
        """The declaration is coherent: kernel names exist, typical values inside the bounds and
        the kernel's physical ranges."""
        for p in self.params:
            if p.kernel is not None and p.kernel not in PARAMS:
                raise StructureError(f"model {self.name}: {p.name} drives unknown kernel parameter {p.kernel}")
            if p.bounds is not None and not (p.bounds[0] <= p.typical <= p.bounds[1]):
                raise StructureError(f"model {self.name}: typical {p.name} = {p.typical} outside {p.bounds}")
            if p.kernel is not None and math.isfinite(p.typical) and not (
                    p.typical == 0.0 and any(p.kernel in pair for pair in self.lead_lags)):
                PARAMS[p.kernel].check(p.typical, where=f"model {self.name}: {p.name} -> ")
        for _note, pair in self.swaps:
            for n in pair:
                self.kernel_name(n)


def declare(*, name: str, title: str, params: tuple[Param, ...], blocks: tuple[Block, ...],
            remarks: tuple[str, ...] = (), constraints: tuple[str, ...] = (), dyr_model: str | None = None,
            dyr_special: Mapping[str, tuple[Callable[[Mapping[str, float]], float],
                                            Callable[[Mapping[str, float]], tuple[str, float]]]] | None = None,
            swaps: tuple[tuple[str, tuple[str, str]], ...] = (), source: str = "",
            pulse_twin: str | None = None) -> Structure:
    """A structure from its parameters and blocks: each parameter drives the kernel parameter its
    block wires it to (none: kept for the record, its `note` says why), the settings and the
    diagram (plus `remarks`) are the blocks'."""
    placed, wiring, settings, lead_lags, lines = generate(blocks)
    names = {p.name for p in params}
    unknown = sorted(set(wiring) - names)
    if unknown:
        raise StructureError(f"model {name}: blocks use undeclared parameter(s) {unknown}")
    std = tuple(StdParam(p.name, p.unit, p.info, p.typical, p.bounds, wiring.get(p.name), p.identify, p.note)
                for p in params)
    for p in std:
        if p.kernel is None and not p.note:
            raise StructureError(f"model {name}: {p.name} drives no block; say why it is kept (note)")
    return Structure(name=name, title=title, diagram=lines + remarks, params=std, settings=settings,
                     constraints=constraints, dyr_model=dyr_model, dyr_special=dict(dyr_special or {}),
                     lead_lags=lead_lags, swaps=swaps, source=source, pulse_twin=pulse_twin, blocks=placed)


_MODULES = ("reference", "sexs", "exst1", "esst1a", "ieeex1", "esst4b", "esst5b", "exac1", "esac1a", "ac8b")
DEFAULT = "REFERENCE"


def _load() -> dict[str, Structure]:
    out: dict[str, Structure] = {}
    for mod in _MODULES:
        s: Structure = importlib.import_module(f"{__name__}.{mod}").STRUCTURE
        s.check()
        out[s.name] = s
    return out


STRUCTURES: dict[str, Structure] = _load()
for _s in STRUCTURES.values():
    if _s.pulse_twin is not None and _s.pulse_twin not in STRUCTURES:
        raise StructureError(f"model {_s.name}: its pulse twin {_s.pulse_twin} is not in the library")


def structure(name: str | None) -> Structure:
    key = (name or DEFAULT).strip().upper()
    aliases = {"ESDC1A": "IEEEX1", "REF": "REFERENCE", "ESAC8B": "AC8B"}
    key = aliases.get(key, key)
    try:
        return STRUCTURES[key]
    except KeyError:
        raise StructureError(f"unknown model {name!r}; known: {', '.join(STRUCTURES)}") from None
