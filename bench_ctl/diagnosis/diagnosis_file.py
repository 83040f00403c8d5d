"""The diagnosis as a typed value: what `diagnose` returns and `diagnose --json` writes, and what
the report and the batch read (docs/formats.md, "Diagnosis JSON").

`Diagnosis.from_json(data, where)` checks every key (a missing or wrong one is a `FormatError`
naming the file and the key, e.g. `effects[2].score`) and the schema tag; `to_json()` gives the
same JSON back. `read_diagnosis(path)` reads a file. The ranked effects (`EffectEntry`), the
steps of `explained_by` (`Step`) and the base fit (`BaseFit`) are typed; the smaller tables
(localization, features, check, ...) stay JSON objects. Non-finite numbers are None (null).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from bench_ctl.limits import read_json
from bench_ctl.records import FormatError, Record, schema_version

__all__ = ["DIAGNOSIS_SCHEMA", "SCHEMA_VERSION", "BaseFit", "EffectEntry", "Step", "Diagnosis", "read_diagnosis"]

#: the version of the diagnosis format this bench-ctl writes and reads
SCHEMA_VERSION = 1
DIAGNOSIS_SCHEMA = f"bench-ctl/diagnosis/{SCHEMA_VERSION}"


@dataclass(frozen=True, eq=False)
class BaseFit(Record):
    """The unit's own model fitted to the capture (`base`)."""
    params: dict[str, float]
    mse: float | None
    mse_holdout: float | None
    check: dict[str, Any] | None
    evaluations: int
    at_noise_floor: bool


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
    check: dict[str, Any] | None
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
    check: dict[str, Any]
    avr_params: dict[str, float | None] | None = None   # the model's own parameters at this step

    OMITTED_WHEN_NONE = ("avr_params",)


@dataclass(frozen=True, eq=False)
class Diagnosis(Record):
    """A diagnosis; each field is the key of the same name (docs/formats.md)."""
    schema: str
    software_version: str
    command_line: str
    created_utc: str
    capture: dict[str, Any]
    holdout: dict[str, Any] | None
    unit: dict[str, Any]
    validation: dict[str, Any]
    check: dict[str, Any]
    edges: list[dict[str, Any]]
    base: BaseFit
    noise_floor: float | None
    noise_floor_detail: dict[str, Any]
    localization: dict[str, Any]
    features: list[dict[str, Any]]
    effects: tuple[EffectEntry, ...]
    ambiguous: list[dict[str, Any]]
    sequence: list[dict[str, Any]]
    explained_by: tuple[Step, ...]
    left: dict[str, Any]
    verdict: str
    criteria: dict[str, Any]
    wall_s: float
    #: a standard structure's diagnosis: the model parameters in the kernel's names
    kernel: dict[str, Any] | None = None
    #: `diagnose --model auto`: the structures ranked before the first one was diagnosed (the
    #: result's `selection`, docs/formats.md)
    selection: dict[str, Any] | None = None
    #: the effects tried on this record (`on_line`, `tried`) and those not, each with the reason
    #: (`not_tried`); absent in files before the diagnosis ran on line (every effect, at no load)
    vocabulary: dict[str, Any] | None = None

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

    def effect(self, name: str) -> EffectEntry | None:
        """The entry of effect `name`, or None."""
        return next((e for e in self.effects if e.name == name), None)


def read_diagnosis(path: str | os.PathLike[str]) -> Diagnosis:
    """The diagnosis in a file (read bounded); `InputError` / `FormatError` naming it."""
    return Diagnosis.from_json(read_json(path, "a diagnosis JSON"), os.fspath(path))
