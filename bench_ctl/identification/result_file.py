"""The identification result as a typed value: what `identify --json` writes and `report`, `export`,
`diagnose --result` and the batch read (docs/formats.md, "Result JSON").

`IdentificationResult.from_json(data, where)` checks every key (a missing or wrong one is a
`FormatError` naming the file and the key) and the schema tag; `to_json()` gives the same JSON
back. `read_result(path)` reads a file. The parameter tables (`params`, `fixed`, `bounds`) stay
plain name -> value mappings; what fills them is identification's business.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from bench_ctl.limits import read_json
from bench_ctl.records import FormatError, Record, schema_version

__all__ = ["RESULT_SCHEMA", "SCHEMA_VERSION", "CaptureEntry", "IdentificationResult", "read_result"]

#: the version of the result format this bench-ctl writes and reads; bump it (and the docs) when
#: a key changes meaning or goes away
SCHEMA_VERSION = 1
RESULT_SCHEMA = f"bench-ctl/result/{SCHEMA_VERSION}"


@dataclass(frozen=True, eq=False)
class CaptureEntry(Record):
    """One capture the result was identified on. `path` is relative to the result file's folder
    once written (None for a capture held in memory); the report refuses a file whose SHA-256
    differs from `sha256`."""
    path: str | None
    sha256: str | None
    n: int
    rate_hz: float
    meta: dict[str, Any]
    mse: float | None
    objective: float | None
    weight: float
    edges: list[dict[str, Any]] | None = None

    OMITTED_WHEN_NONE = ("edges",)


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
    unit: dict[str, Any]
    captures: tuple[CaptureEntry, ...]
    params: dict[str, float]
    fixed: dict[str, float | None]
    bounds: dict[str, list[float]]
    edges: list[dict[str, Any]] | None = None
    constraints: list[dict[str, Any]]
    objective: float | None
    mse: float | None
    evaluations: int
    wall_s: float
    compile_s: float
    optimizer: dict[str, Any]
    history: list[list[float | None]]
    identifiability: dict[str, Any] | None = None
    fit_window: list[float] | None
    failed: bool | None = None
    message: str | None = None
    model: dict[str, Any] | None = None
    comparison: list[dict[str, Any]] | None = None
    #: a standard structure's result: params, bounds, fixed and constraints in the kernel's names
    #: (the other keys speak the structure's own; docs/formats.md)
    kernel: dict[str, Any] | None = None
    #: `identify --model auto`: every structure's fit and check, ranked (docs/formats.md)
    selection: dict[str, Any] | None = None

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

    @property
    def model_name(self) -> str:
        """The structure's name (`REFERENCE` when the result names none)."""
        return str((self.model or {}).get("name") or "REFERENCE")

    @property
    def constraints_violated(self) -> list[str]:
        """The texts of the constraints the result reports as not satisfied."""
        return [str(c.get("expr")) for c in self.constraints if c.get("satisfied") is not True]


def read_result(path: str | os.PathLike[str]) -> IdentificationResult:
    """The result in a file (read bounded, `bench_ctl.limits`); `InputError` for a file that
    cannot be read or is not JSON, `FormatError` for one that is not a result, both naming it."""
    return IdentificationResult.from_json(read_json(path, "a result JSON"), os.fspath(path))
