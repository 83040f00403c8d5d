"""The diagnosis as a typed value: what `diagnose` returns and `diagnose --json` writes, and what
the report and the batch read (docs/formats.md, "Diagnosis JSON").

The diagnosis (`diagnose.diagnose`) builds the records below in the kernel's names and renames
them once, into the structure's, with the unit's dialect (`Diagnosis.renamed`,
`bench_ctl.model.dialect`). `Diagnosis.from_json(data, where)` checks every key (a missing or wrong
one is a `FormatError` naming the file and the key, e.g. `effects[2].score`) and the schema tag;
`to_json()` gives the same JSON back. `read_diagnosis(path)` reads a file. Non-finite numbers are
None (null).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import Any

from bench_ctl.identification.check_records import (
    BlocksCheck,
    CheckDescription,
    CheckWindow,
    HoldoutCheck,
    Span,
    Validation,
)
from bench_ctl.identification.result_file import Localization, SelectionEntry
from bench_ctl.limits import read_json
from bench_ctl.model.dialect import Dialect
from bench_ctl.model.unit_record import UnitEntry
from bench_ctl.records import FormatError, Record, schema_version
from bench_ctl.signals.edges import Edge

__all__ = ["DIAGNOSIS_SCHEMA", "SCHEMA_VERSION", "CaptureRef", "Span", "CheckWindow", "HoldoutCheck", "BlocksCheck",
           "CheckDescription", "Validation", "PartEntry", "CheckEntry", "BaseFit", "NoiseFloorDetail",
           "FeatureEntry", "EffectEntry", "AmbiguousPair", "SequenceEntry", "StepCheck", "Step", "Left",
           "Criteria", "DiagnosisKernel", "Vocabulary", "Diagnosis", "read_diagnosis"]

#: the version of the diagnosis format this bench-ctl writes and reads
SCHEMA_VERSION = 1
DIAGNOSIS_SCHEMA = f"bench-ctl/diagnosis/{SCHEMA_VERSION}"


@dataclass(frozen=True, eq=False)
class CaptureRef(Record):
    """A capture the diagnosis read: its path (relative to the diagnosis file's folder once
    written) and the SHA-256 of its file (`bench_ctl.capture.capture_sha256`)."""
    path: str | None
    sha256: str | None


@dataclass(frozen=True, eq=False)
class PartEntry(Record):
    """One part of a model's check (a window, the holdout, Vt) or one half of the blocks."""
    label: str
    samples: float
    mse: float | None


@dataclass(frozen=True, eq=False)
class CheckEntry(Record):
    """A model's check: its pooled mse, its parts, the interleaved blocks' halves."""
    mse: float | None
    parts: tuple[PartEntry, ...]
    blocks: tuple[PartEntry, ...] | None = None   # absent in files written before the blocks

    OMITTED_WHEN_NONE = ("blocks",)


@dataclass(frozen=True, eq=False)
class BaseFit(Record):
    """The unit's own model fitted to the capture (`base`)."""
    params: dict[str, float]
    mse: float | None
    mse_holdout: float | None
    check: CheckEntry | None
    evaluations: int
    at_noise_floor: bool

    def renamed(self, d: Dialect) -> BaseFit:
        return replace(self, params=d.keys(self.params))


@dataclass(frozen=True, eq=False)
class NoiseFloorDetail(Record):
    samples: int
    t0: float
    t1: float
    rel_se: float
    check: float
    holdout: float | None


@dataclass(frozen=True, eq=False)
class FeatureEntry(Record):
    """A feature test: what it found in the record, in words and in figures."""
    name: str
    detected: bool
    evidence: str
    values: dict[str, float | None]


@dataclass(frozen=True, eq=False)
class EffectEntry(Record):
    """One effect fitted with the base model (`effects`, ranked best first); `variant` only for
    `ceiling_limit`."""
    name: str
    params: dict[str, float | None]
    fixed: dict[str, float | None]
    avr_params: dict[str, float | None]
    mse: float | None
    mse_holdout: float | None
    gap_closed: float | None
    gap_closed_on: str | None
    gap_closed_fit: float | None
    gap_closed_fit_raw: float | None
    gap_closed_check: float | None
    gap_closed_check_raw: float | None
    gap_closed_holdout: float | None
    gap_closed_holdout_raw: float | None
    check: CheckEntry | None
    score: float | None
    aic: float | None
    bic: float | None
    delta_bic: float | None
    delta_check: float | None
    significant: bool
    k: int
    evaluations: int
    start: dict[str, float | None]
    delta_blocks: float | None = None   # the interleaved blocks' deviance gain (absent: not checked, or an older file)
    variant: str | None = None

    OMITTED_WHEN_NONE = ("variant", "delta_blocks")

    def renamed(self, d: Dialect) -> EffectEntry:
        return replace(self, avr_params=d.keys(self.avr_params))


@dataclass(frozen=True, eq=False)
class AmbiguousPair(Record):
    """Two significant effects whose scores are close, and the test that would tell them apart."""
    effects: list[str]
    score_difference: float
    separating_test: str


@dataclass(frozen=True, eq=False)
class SequenceEntry(Record):
    """A step of `explained_by` in short."""
    added: str
    mse: float | None
    mse_holdout: float | None
    params: dict[str, float | None]
    dropped: list[str]


@dataclass(frozen=True, eq=False)
class StepCheck(Record):
    """A step of `explained_by` on the check: its mse, the one before, the gain, the parts."""
    on: str
    mse: float | None
    mse_before: float | None
    gain: float | None
    parts: tuple[PartEntry, ...] | None


@dataclass(frozen=True, eq=False)
class Step(Record):
    """One step of `explained_by`: the effect `name` added, every parameter re-fitted jointly with
    the effects before it (`effects`), what it dropped, and its figures."""
    name: str
    effects: list[str]
    dropped: list[str]
    params: dict[str, float | None]
    mse: float | None
    mse_over_floor: float | None
    gap_closed: float | None
    edges: dict[str, float | None]
    fit_gain: float | None
    check: StepCheck
    avr_params: dict[str, float | None] | None = None   # the model's own parameters at this step

    OMITTED_WHEN_NONE = ("avr_params",)

    def renamed(self, d: Dialect) -> Step:
        return replace(self, avr_params=d.keys(self.avr_params)) if self.avr_params else self


@dataclass(frozen=True, eq=False)
class Left(Record):
    """What is left after the effects that explain the record, and where it lies."""
    mse: float | None
    mse_over_floor: float | None
    effects: list[str]
    note: str
    localization: Localization


@dataclass(frozen=True, eq=False)
class Criteria(Record):
    """The significance rule's constants (`significance`) and what the score is."""
    significant_delta: float
    check_gain: float
    strong_delta: float
    one_regime_gain: float
    ambiguous_delta: float
    floor_sigmas: float
    score: str


@dataclass(frozen=True, eq=False)
class DiagnosisKernel(Record):
    """A standard structure's diagnosis: the model parameters in the kernel's names."""
    base_params: dict[str, float | None]
    avr_params: dict[str, dict[str, float | None]]
    explained_by_avr_params: list[dict[str, float | None] | None]


@dataclass(frozen=True, eq=False)
class Vocabulary(Record):
    """The effects tried on the record, and why the others were not."""
    on_line: bool
    tried: list[str]
    not_tried: dict[str, str]


@dataclass(frozen=True, eq=False)
class Diagnosis(Record):
    """A diagnosis; each field is the key of the same name (docs/formats.md)."""
    schema: str
    software_version: str
    command_line: str
    created_utc: str
    capture: CaptureRef
    holdout: CaptureRef | None
    unit: UnitEntry
    validation: Validation
    check: CheckDescription
    edges: tuple[Edge, ...]
    base: BaseFit
    noise_floor: float | None
    noise_floor_detail: NoiseFloorDetail
    localization: Localization
    features: tuple[FeatureEntry, ...]
    effects: tuple[EffectEntry, ...]
    ambiguous: tuple[AmbiguousPair, ...]
    sequence: tuple[SequenceEntry, ...]
    explained_by: tuple[Step, ...]
    left: Left
    verdict: str
    criteria: Criteria
    wall_s: float
    #: a standard structure's diagnosis: the model parameters in the kernel's names
    kernel: DiagnosisKernel | None = None
    #: `diagnose --model auto`: the structures ranked before the first one was diagnosed (the
    #: result's `selection`, docs/formats.md)
    selection: SelectionEntry | None = None
    #: the effects tried on this record (`on_line`, `tried`) and those not, each with the reason
    #: (`not_tried`); absent in files before the diagnosis ran on line (every effect, at no load)
    vocabulary: Vocabulary | None = None

    OMITTED_WHEN_NONE = ("kernel", "selection", "vocabulary")

    @classmethod
    def from_json(cls, data: Any, where: str = "") -> Diagnosis:
        """The diagnosis in `data` (a JSON object); a file without `schema` is read as version 1."""
        where = where or "diagnosis"
        if not isinstance(data, dict):
            raise FormatError(f"{where}: expected a JSON object, got {type(data).__name__}")
        schema_version(data, "diagnosis", SCHEMA_VERSION, where)
        if "schema" in data:
            return super().from_json(data, where)
        try:
            return super().from_json({"schema": DIAGNOSIS_SCHEMA, **data}, where)
        except FormatError as exc:
            raise FormatError(f"{exc} (the file has no 'schema' key: read as {DIAGNOSIS_SCHEMA})") from None

    def renamed(self, d: Dialect) -> Diagnosis:
        """The diagnosis built in the kernel's names, in the structure's: the base fit's and each
        effect's model parameters, each step's and the unit. An effect's own parameters keep the
        effect's names (docs/model.md, "The eight effects"): they sit under the effect. The
        kernel's view of the model parameters under `kernel`. The reference structure speaks the
        kernel's names: the diagnosis as it is."""
        if d.plain:
            return self
        return replace(
            self, base=self.base.renamed(d), effects=tuple(e.renamed(d) for e in self.effects),
            explained_by=tuple(s.renamed(d) for s in self.explained_by), unit=d.unit(self.unit),
            kernel=DiagnosisKernel(base_params=dict(self.base.params),
                                   avr_params={e.name: dict(e.avr_params) for e in self.effects},
                                   explained_by_avr_params=[s.avr_params for s in self.explained_by]))

    def kernel_base_params(self) -> dict[str, float | None]:
        """The base fit's model parameters in the kernel's names."""
        return dict(self.kernel.base_params if self.kernel is not None else self.base.params)

    def effect(self, name: str) -> EffectEntry | None:
        """The entry of effect `name`, or None."""
        return next((e for e in self.effects if e.name == name), None)


def read_diagnosis(path: str | os.PathLike[str]) -> Diagnosis:
    """The diagnosis in a file (read bounded); `InputError` / `FormatError` naming it."""
    return Diagnosis.from_json(read_json(path, "a diagnosis JSON"), os.fspath(path))
