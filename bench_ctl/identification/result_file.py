"""The identification result as a typed value: what `identify --json` writes and `report`, `export`,
`diagnose --result` and the batch read (docs/formats.md, "Result JSON").

The writer (`identify.run_identification`) builds the records below in the kernel's names and
renames them once, into the structure's, with the unit's dialect (`written`: the one writer of
what a user reads, a result, a diagnosis, a simulated capture's unit, a refused problem; each
record's `renamed`, `bench_ctl.model.dialect`). `IdentificationResult.from_json(data, where)` checks every key (a
missing or wrong one is a `FormatError` naming the file and the key) and the schema tag;
`to_json()` gives the same JSON back. `read_result(path)` reads a file; `kernel_view()` gives its
values in the kernel's names again (the report's re-simulation, `export`, `diagnose --result`).
The parameter tables (`params`, `fixed`, `bounds`) are name -> value mappings; a capture's `meta`
(its sidecar) and an optimizer's `settings` are copied as they are (`JSON`).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import Any, TypeVar

from bench_ctl.limits import read_json
from bench_ctl.model.dialect import Dialect, Note, dialect_of, kernel_sections
from bench_ctl.model.structures import Structure, StructureError, structure
from bench_ctl.model.unit_record import UnitEntry
from bench_ctl.records import JSON, FormatError, Record, schema_version
from bench_ctl.signals.edges import Edge

__all__ = ["RESULT_SCHEMA", "SCHEMA_VERSION", "CaptureEntry", "ConstraintEntry", "OptimizerEntry",
           "EquivalentSet", "IdentifiabilitySettings", "Identifiability", "ModelEntry", "Comparison",
           "ResultKernel", "SegmentShare", "BandShare", "Localization", "Separation", "CandidateEntry",
           "SelectionEntry", "IdentificationResult", "read_result", "written"]

#: the version of the result format this bench-ctl writes and reads; bump it (and the docs) when
#: a key changes meaning or goes away
SCHEMA_VERSION = 1
RESULT_SCHEMA = f"bench-ctl/result/{SCHEMA_VERSION}"


@dataclass(frozen=True, eq=False)
class CaptureEntry(Record):
    """One capture the result was identified on. `path` is relative to the result file's folder
    once written (None for a capture held in memory); the report refuses a file whose SHA-256
    differs from `sha256` (`bench_ctl.capture.capture_sha256`)."""
    path: str | None
    sha256: str | None
    n: int
    rate_hz: float
    meta: dict[str, JSON]
    mse: float | None
    objective: float | None
    weight: float
    edges: tuple[Edge, ...] | None = None

    OMITTED_WHEN_NONE = ("edges",)


@dataclass(frozen=True, eq=False)
class ConstraintEntry(Record):
    """A constraint at the result: its text, whether it holds, its slack (None: no fitted
    parameter in it)."""
    expr: str
    satisfied: bool
    margin: float | None

    def renamed(self, d: Dialect) -> ConstraintEntry:
        return replace(self, expr=d.text(self.expr))


@dataclass(frozen=True, eq=False)
class OptimizerEntry(Record):
    """The optimizer that gave the result: its settings as it reports them (every option, the
    search space, the polishes, the swap restarts)."""
    name: str
    settings: dict[str, JSON]
    seed: int | None


@dataclass(frozen=True, eq=False)
class EquivalentSet(Record):
    """An exchange of equivalent parameters examined at the result (`identifiability`)."""
    params: dict[str, float]
    mse: float | None
    note: str
    equivalent: bool
    in_bounds: bool
    outside_bounds: list[str]
    constraints_violated: list[str]
    allowed: bool
    verdict: str

    def renamed(self, d: Dialect) -> EquivalentSet:
        return replace(self, params=d.keys(self.params), note=d.say(self.note),
                       outside_bounds=[d.say(o) for o in self.outside_bounds],
                       constraints_violated=[d.text(c) for c in self.constraints_violated],
                       verdict=d.say(self.verdict))


@dataclass(frozen=True, eq=False)
class IdentifiabilitySettings(Record):
    rel_step: float
    max_rel_std: float
    max_corr: float
    note_corr: float
    cond_limit: float
    equivalence_tol_mse: float


@dataclass(frozen=True, eq=False, kw_only=True)
class Identifiability(Record):
    """What the captures determine at the result (`identifiability.analyse`); a fit that failed
    has no `reasons`, `singular_values`, `residual_variance` nor `settings` (not analysed). Made
    in the kernel's names, its texts `Note`s (`bench_ctl.model.dialect.Note`), said in the
    structure's by `renamed`."""
    names: list[str]
    sensitivity: dict[str, float | None]
    std: dict[str, float | None]
    rel_std: dict[str, float | None]
    correlation: list[list[float]]
    determined: dict[str, bool]
    reasons: dict[str, list[str]] | None = None
    singular_values: list[float] | None = None
    residual_variance: float | None = None
    equivalent_sets: tuple[EquivalentSet, ...]
    notes: list[str]
    settings: IdentifiabilitySettings | None = None

    OMITTED_WHEN_NONE = ("reasons", "singular_values", "residual_variance", "settings")

    def renamed(self, d: Dialect) -> Identifiability:
        return replace(self, names=[d.name(n) for n in self.names], sensitivity=d.keys(self.sensitivity),
                       std=d.keys(self.std), rel_std=d.keys(self.rel_std), determined=d.keys(self.determined),
                       reasons=None if self.reasons is None else
                       {d.name(n): [d.say(r) for r in rs] for n, rs in self.reasons.items()},
                       equivalent_sets=tuple(e.renamed(d) for e in self.equivalent_sets),
                       notes=[d.say(n) for n in self.notes])


@dataclass(frozen=True, eq=False)
class ModelEntry(Record):
    """The structure of the result: its parameters under their standard names (fitted values
    where identified), which were identified and determined, which are simulated; the generator."""
    name: str
    title: str
    dyr_model: str | None
    params: dict[str, float | None]
    units: dict[str, str]
    identified: list[str]
    determined: dict[str, bool]
    simulated: list[str]
    generator: dict[str, float | None]


@dataclass(frozen=True, eq=False)
class Comparison(Record):
    """One optimizer run on the same problem (`comparison`, when several ran)."""
    optimizer: str
    mse: float | None
    objective: float | None
    evaluations: int
    wall_s: float
    constraints_violated: list[str]
    params: dict[str, float]
    failed: bool
    message: str

    def renamed(self, d: Dialect) -> Comparison:
        return replace(self, params=d.keys(self.params),
                       constraints_violated=[d.text(t) for t in self.constraints_violated])


@dataclass(frozen=True, eq=False)
class ResultKernel(Record):
    """A standard structure's result in the kernel's names (`kernel`, for debugging)."""
    params: dict[str, float]
    bounds: dict[str, list[float]]
    fixed: dict[str, float | None]
    constraints: tuple[ConstraintEntry, ...]


@dataclass(frozen=True, eq=False)
class SegmentShare(Record):
    """A part of the record (pre_trigger, leading_edge, plateau, trailing_edge, recovery) and its
    share of a residual's energy."""
    name: str
    t0: float
    t1: float
    share: float
    mse: float


@dataclass(frozen=True, eq=False)
class BandShare(Record):
    """A frequency band and its share of a residual's energy."""
    name: str
    f0_hz: float
    f1_hz: float
    share: float


@dataclass(frozen=True, eq=False)
class Localization(Record):
    """Where a residual lies: per segment of the record and per frequency band."""
    segments: tuple[SegmentShare, ...]
    bands: tuple[BandShare, ...]


@dataclass(frozen=True, eq=False)
class Separation(Record):
    """Where the best two structures differ most (`selection.separation`)."""
    models: list[str]
    segment: str
    t0: float
    t1: float
    x_floor: list[float]
    weight: float
    separated: bool
    #: both fit the segment at the noise floor (absent in files written before it was said)
    both_at_floor: bool | None = None

    OMITTED_WHEN_NONE = ("both_at_floor",)


@dataclass(frozen=True, eq=False, kw_only=True)
class CandidateEntry(Record):
    """One structure identified and checked by `--model auto`, in rank order."""
    rank: int
    model: str
    k: int
    inert: list[str]
    n: int
    mse: float | None
    x_floor: float | None
    check: dict[str, float | None]
    check_mse: float | None
    check_x_floor: float | None
    score: float | None
    score_difference: float | None
    equivalent: bool
    wall_s: float
    searches: int
    params: dict[str, float] | None = None
    kernel: dict[str, float | None] | None = None
    edges: list[tuple[Edge, ...]] | None = None
    constraints_violated: list[str] | None = None
    failed: bool | None = None
    error: str | None = None
    where: tuple[Localization, ...] | None = None
    at_bounds: list[str] | None = None

    OMITTED_WHEN_NONE = ("params", "kernel", "edges", "constraints_violated", "failed", "error", "where",
                         "at_bounds")

    def renamed(self, d: Dialect) -> CandidateEntry:
        """Its inert parameters (the scoring's, in the kernel's names) in the structure's; its
        `params` are its result's, written already, and `kernel` is the kernel's view."""
        return replace(self, inert=[d.name(n) for n in self.inert])


@dataclass(frozen=True, eq=False)
class SelectionEntry(Record):
    """`identify` / `diagnose --model auto`: every structure's fit and check, ranked."""
    verdict: str
    chosen: str
    equivalent: list[str]
    separation: Separation | None
    noise_floor: float
    candidates: tuple[CandidateEntry, ...]
    rule: str
    notes: list[str]


@dataclass(frozen=True, eq=False, kw_only=True)
class IdentificationResult(Record):
    """An identification result; each field is the key of the same name, in the order written
    (docs/formats.md). `edges`, `identifiability`, `failed`, `message`, `model` and `comparison`
    are absent from a diagnosis' base fit written as a result, `comparison` when one optimizer ran,
    `kernel` from a result of the reference structure (whose names are the kernel's)."""
    schema: str
    software_version: str
    command_line: str
    created_utc: str
    unit: UnitEntry
    captures: tuple[CaptureEntry, ...]
    params: dict[str, float]
    fixed: dict[str, float | None]
    bounds: dict[str, list[float]]
    edges: tuple[Edge, ...] | None = None
    constraints: tuple[ConstraintEntry, ...]
    objective: float | None
    mse: float | None
    evaluations: int
    wall_s: float
    compile_s: float
    optimizer: OptimizerEntry
    history: list[list[float | None]]
    identifiability: Identifiability | None = None
    fit_window: list[float] | None
    failed: bool | None = None
    message: str | None = None
    model: ModelEntry | None = None
    comparison: tuple[Comparison, ...] | None = None
    #: a standard structure's result: params, bounds, fixed and constraints in the kernel's names
    #: (the other keys speak the structure's own; docs/formats.md)
    kernel: ResultKernel | None = None
    #: `identify --model auto`: every structure's fit and check, ranked (docs/formats.md)
    selection: SelectionEntry | None = None

    OMITTED_WHEN_NONE = ("edges", "identifiability", "failed", "message", "model", "comparison", "kernel",
                         "selection")

    @classmethod
    def from_json(cls, data: Any, where: str = "") -> IdentificationResult:
        """The result in `data` (a JSON object); a file without `schema` is read as version 1."""
        where = where or "result"
        if not isinstance(data, dict):
            raise FormatError(f"{where}: expected a JSON object, got {type(data).__name__}")
        schema_version(data, "result", SCHEMA_VERSION, where)
        if "schema" in data:
            return super().from_json(data, where)
        try:
            return super().from_json({"schema": RESULT_SCHEMA, **data}, where)
        except FormatError as exc:
            raise FormatError(f"{exc} (the file has no 'schema' key: read as {RESULT_SCHEMA})") from None

    def renamed(self, d: Dialect) -> IdentificationResult:
        """The result built in the kernel's names, in the structure's (`params`, `bounds`, `fixed`,
        `constraints`, `identifiability`, `unit`, `comparison`, the optimizer's settings, the
        names `model` lists as identified and determined; its values are the structure's already);
        the kernel's view under `kernel`. The reference structure speaks the kernel's names: the
        result as it is."""
        if d.plain:
            return self
        params = d.keys(self.params)
        std_values = self.model.params if self.model is not None else {}
        return replace(
            self, unit=d.unit(self.unit), params=params, bounds=d.keys(self.bounds),
            fixed=d.fixed(self.fixed, std_values, set(params)),
            constraints=tuple(c.renamed(d) for c in self.constraints),
            identifiability=None if self.identifiability is None else self.identifiability.renamed(d),
            comparison=None if self.comparison is None else tuple(c.renamed(d) for c in self.comparison),
            optimizer=replace(self.optimizer, settings=d.deep(self.optimizer.settings)),
            model=None if self.model is None else replace(
                self.model, identified=[d.name(n) for n in self.model.identified],
                determined=d.keys(self.model.determined)),
            kernel=ResultKernel(dict(self.params), dict(self.bounds), dict(self.fixed), self.constraints))

    def describe(self, name: str) -> tuple[str, str, float | None] | None:
        """(unit, meaning, neutral value) of a parameter as the result names it (its structure's
        names; a structure this version lacks: the kernel's), None for a name it does not know
        (`Dialect.describe`)."""
        try:
            st = structure(self.model_name)
        except StructureError:
            st = structure(None)
        return dialect_of(st).describe(name)

    def kernel_view(self) -> dict[str, dict[str, Any]]:
        """`fixed` and `params` in the kernel's names, values as written (None: an open limit);
        see `bench_ctl.model.dialect.kernel_sections`."""
        return kernel_sections(self.to_json())

    @property
    def model_name(self) -> str:
        """The structure's name (`REFERENCE` when the result names none)."""
        return (self.model.name if self.model is not None else None) or "REFERENCE"

    @property
    def constraints_violated(self) -> list[str]:
        """The texts of the constraints the result reports as not satisfied."""
        return [c.expr for c in self.constraints if c.satisfied is not True]


R = TypeVar("R")


def written(record: R, st: Structure) -> R:
    """`record`, built in the kernel's names, as a user of structure `st` reads it: the one writer
    of the structure's names (docs/model.md, "One dialect"). A record (a result, a diagnosis, a
    selection's candidate, a unit's entry) is `renamed`; a refusal (`ProblemError`,
    `ConstraintError`) whose message is a `Note` is made again with it said (`Dialect.say`: its
    names translated, its prose, a capture's path, as it is), any other as it is."""
    d = dialect_of(st)
    if isinstance(record, BaseException):
        said = [d.say(a) if isinstance(a, Note) else a for a in record.args]
        return type(record)(*said) if said != list(record.args) else record
    if isinstance(record, UnitEntry):
        return d.unit(record)   # type: ignore[return-value]
    return record.renamed(d)   # type: ignore[attr-defined]


def read_result(path: str | os.PathLike[str]) -> IdentificationResult:
    """The result in a file (read bounded, `bench_ctl.limits`); `InputError` for a file that
    cannot be read or is not JSON, `FormatError` for one that is not a result, both naming it."""
    return IdentificationResult.from_json(read_json(path, "a result JSON"), os.fspath(path))
