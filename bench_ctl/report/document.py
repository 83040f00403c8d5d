"""The report as a list of sections made of simple blocks (headings, paragraphs, tables, figures),
so that the HTML and the PDF say exactly the same thing. Numbers are formatted here, once.
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

NOT_AVAILABLE = "not available"


@dataclass(frozen=True)
class Num:
    """A number cell; `key` becomes the HTML id (for tests and readers), the exact value goes
    into `data-value`."""
    value: float | int | None
    key: str | None = None
    digits: int = 6
    suffix: str = ""

    def text(self) -> str:
        return fmt(self.value, self.digits) + (self.suffix if self.value is not None else "")


@dataclass(frozen=True)
class Status:
    status: str  # pass | fail | warn | n/a


Cell = str | Num | Status | None


@dataclass(frozen=True)
class Heading:
    text: str


@dataclass(frozen=True)
class Para:
    text: str
    cls: str = ""  # "note", "na", "mono"


@dataclass(frozen=True)
class Table:
    headers: tuple[str, ...]
    rows: tuple[tuple[Cell, ...], ...]
    id: str = ""
    caption: str = ""
    kind: str = ""  # "kv": a key / value list (numbers not right-aligned)


@dataclass(frozen=True)
class Verdict:
    verdict: str  # PASS | FAIL
    text: str


@dataclass(frozen=True)
class Fig:
    name: str      # file name part: report_<name>.png
    caption: str
    draw: Callable[[Any], None] = field(compare=False, repr=False)
    size: tuple[float, float] | None = None  # inches, None = the default figure size


Block = Heading | Para | Table | Verdict | Fig


@dataclass(frozen=True)
class Section:
    id: str
    title: str
    blocks: tuple[Block, ...]


def fmt(value: Any, digits: int = 6) -> str:
    """One way of writing a value: 6 significant digits, infinity as ∞, None as a dash."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "∞" if value > 0 else "−∞"
        return f"{value:.{digits}g}"
    if isinstance(value, Mapping):
        return ", ".join(f"{k} = {{{fmt(v, digits)}}}" if isinstance(v, Mapping) else
                         f"{k} = {fmt(v, digits)}" for k, v in value.items())
    if isinstance(value, (list, tuple)):
        if all(not isinstance(v, (Mapping, list, tuple)) for v in value):
            return ", ".join(fmt(v, digits) for v in value)
        return json.dumps(value, ensure_ascii=False)
    return str(value)


def num(value: Any) -> float | None:
    """A JSON number as float (None for anything else, bools included)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


def table(headers: Sequence[str], rows: Sequence[Sequence[Cell]], id: str = "",
          caption: str = "", kind: str = "") -> Table:
    return Table(tuple(headers), tuple(tuple(r) for r in rows), id, caption, kind)


def flatten(meta: Mapping[str, Any], prefix: str = "") -> list[tuple[str, str]]:
    """Nested sidecar metadata as (dotted key, text) rows; lists of objects one row per item."""
    out: list[tuple[str, str]] = []
    for key, value in meta.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            out.extend(flatten(value, name + "."))
        elif isinstance(value, list) and value and any(isinstance(v, (Mapping, list)) for v in value):
            for i, item in enumerate(value):
                if isinstance(item, Mapping):
                    out.append((f"{name}[{i}]", fmt(item)))
                else:
                    out.append((f"{name}[{i}]", json.dumps(item, ensure_ascii=False)))
        else:
            out.append((name, fmt(value) if not (isinstance(value, Mapping)) else "{}"))
    return out
