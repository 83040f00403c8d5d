"""The check's records: what a fitted model was judged on (`CheckDescription`: the windows left
out, the holdout, the interleaved blocks) and over which span it was fitted (`Validation`), as
the diagnosis file and the structure selection write them (docs/formats.md, "Diagnosis JSON").
"""
from __future__ import annotations

from dataclasses import dataclass

from bench_ctl.records import Record

__all__ = ["Span", "CheckWindow", "HoldoutCheck", "BlocksCheck", "CheckDescription", "Validation"]


@dataclass(frozen=True, eq=False)
class Span(Record):
    t0: float
    t1: float


@dataclass(frozen=True, eq=False)
class CheckWindow(Record):
    """A window of the capture left out of the fit in turn and scored."""
    label: str
    t0: float
    t1: float


@dataclass(frozen=True, eq=False)
class HoldoutCheck(Record):
    """The holdout capture as the check uses it."""
    capture: str | None
    t0: float
    t1: float
    noise_floor: float | None


@dataclass(frozen=True, eq=False)
class BlocksCheck(Record):
    """The interleaved blocks: their length and how many halves the record is dealt into."""
    seconds: float
    folds: int


@dataclass(frozen=True, eq=False)
class CheckDescription(Record):
    """What each model was judged on (`fit_check.describe_check`)."""
    kind: str
    windows: tuple[CheckWindow, ...]
    how: str
    holdout: HoldoutCheck | None
    vt: bool
    blocks: BlocksCheck | None = None   # absent in files written before the interleaved blocks

    OMITTED_WHEN_NONE = ("blocks",)


@dataclass(frozen=True, eq=False)
class Validation(Record):
    kind: str
    fit: Span
    check: CheckDescription
