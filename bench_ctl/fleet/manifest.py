"""The batch manifest: a CSV with a header; `capture` required (a path relative to the manifest),
optional `holdout`, `unit`, `model`, `set` (`NAME=VALUE` items separated by `;`) and `steps`
(`identify+diagnose+report`, the default; any of the three joined by `+`). Unknown columns and
bad values are refused naming the file, line and column."""
from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

from bench_ctl.model.structures import StructureError, structure

STEPS = ("identify", "diagnose", "report")
COLUMNS = ("capture", "holdout", "unit", "model", "set", "steps")


class ManifestError(ValueError):
    """A manifest that cannot be run; the message names file, line and column."""


@dataclass(frozen=True)
class Entry:
    line: int                 # 1-based line of the manifest
    name: str                 # output folder name, unique in the batch
    capture: Path
    holdout: Path | None = None
    unit: Path | None = None
    model: str | None = None
    overrides: tuple[str, ...] = ()
    steps: tuple[str, ...] = STEPS


def _name(capture: str, taken: set[str]) -> str:
    base = re.sub(r"[^A-Za-z0-9._-]+", "_", str(Path(capture).with_suffix(""))).strip("._") or "capture"
    name, k = base, 2
    while name in taken:
        name, k = f"{base}-{k}", k + 1
    taken.add(name)
    return name


def read_manifest(path: str | Path) -> list[Entry]:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ManifestError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ManifestError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    rows = list(csv.reader(text.splitlines()))
    if not rows:
        raise ManifestError(f"{path}: empty; the first line must be a header with a 'capture' column")
    header = [h.strip() for h in rows[0]]
    unknown = [h for h in header if h not in COLUMNS]
    if unknown:
        raise ManifestError(f"{path}, line 1: unknown column(s) {unknown}; known: {', '.join(COLUMNS)}")
    if "capture" not in header:
        raise ManifestError(f"{path}, line 1: no 'capture' column")
    base = path.resolve().parent
    out: list[Entry] = []
    taken: set[str] = set()
    for i, row in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in row):
            continue
        if len(row) > len(header):
            raise ManifestError(f"{path}, line {i}: {len(row)} fields for {len(header)} columns")
        cell = {h: (row[j].strip() if j < len(row) else "") for j, h in enumerate(header)}
        if not cell["capture"]:
            raise ManifestError(f"{path}, line {i}, column 'capture': empty")
        steps = tuple(s.strip() for s in (cell.get("steps") or "+".join(STEPS)).split("+") if s.strip())
        bad = [s for s in steps if s not in STEPS]
        if bad or not steps:
            raise ManifestError(f"{path}, line {i}, column 'steps': {cell.get('steps')!r}; use "
                                f"{'+'.join(STEPS)} or a part of it")
        sets = tuple(s.strip() for s in (cell.get("set") or "").split(";") if s.strip())
        for s in sets:
            if "=" not in s:
                raise ManifestError(f"{path}, line {i}, column 'set': {s!r} is not NAME=VALUE")
        if cell.get("model"):
            try:
                structure(cell["model"])
            except StructureError as exc:
                raise ManifestError(f"{path}, line {i}, column 'model': {exc}") from None
        opt = lambda key: (base / cell[key]) if cell.get(key) else None  # noqa: E731
        out.append(Entry(line=i, name=_name(cell["capture"], taken), capture=base / cell["capture"],
                         holdout=opt("holdout"), unit=opt("unit"), model=cell.get("model") or None,
                         overrides=sets, steps=tuple(s for s in STEPS if s in steps)))
    if not out:
        raise ManifestError(f"{path}: no capture listed")
    return out
