"""The unit as records write it (a result's, a diagnosis' and a simulated capture's `unit`):
`Unit.entry` builds it in the kernel's names, `Dialect.unit` gives it in the structure's
(docs/formats.md, "Result JSON")."""
from __future__ import annotations

from dataclasses import dataclass

from bench_ctl.records import Record

__all__ = ["BoundEntry", "AcceptanceEntry", "UnitKernelEntry", "UnitEntry"]


@dataclass(frozen=True, eq=False)
class BoundEntry(Record):
    """An identified value and its bounds, as a result's `unit.identify` writes it."""
    value: float
    min: float
    max: float


@dataclass(frozen=True, eq=False)
class AcceptanceEntry(Record):
    """The numeric acceptance limits of a unit (`bench_ctl.signals.acceptance`), per window."""
    before: dict[str, float]
    during: dict[str, float]
    after: dict[str, float]
    exclusion_s: float


@dataclass(frozen=True, eq=False)
class UnitKernelEntry(Record):
    """A standard structure's unit in the kernel's names (`unit.kernel`, for debugging)."""
    identify: dict[str, BoundEntry]
    fixed: dict[str, float | None]
    constraints: list[str]


@dataclass(frozen=True, eq=False)
class UnitEntry(Record):
    """The unit as a result, a diagnosis and a simulated capture's sidecar write it (`Unit.entry`);
    in the structure's names once written (`bench_ctl.model.dialect`), with the kernel's view under
    `kernel` for a standard structure. A neutral limit (+-inf) is null."""
    name: str
    source: str
    generator: dict[str, float]
    identify: dict[str, BoundEntry]
    fixed: dict[str, float | None]
    constraints: list[str]
    weights: dict[str, float]
    effects: dict[str, dict[str, float | None]]
    model: str
    model_values: dict[str, float | None]
    #: absent in files written before the acceptance limits and the unit on the grid
    acceptance: AcceptanceEntry | None = None
    grid: dict[str, float] | None = None
    grid_identify: dict[str, BoundEntry] | None = None
    kernel: UnitKernelEntry | None = None

    OMITTED_WHEN_NONE = ("acceptance", "grid", "grid_identify", "kernel")
