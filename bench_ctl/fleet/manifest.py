"""The batch manifest: a CSV with a header; `capture` required (a path relative to the manifest),
optional `holdout`, `unit`, `model`, `set` (`NAME=VALUE` items separated by `;`) and `steps`
(`identify+diagnose+report`, the default; any of the three joined by `+`). Unknown columns and
bad values are refused naming the file, line and column. UTF-8, with or without the byte-order
mark Excel writes; at most the manifest limit of `bench_ctl.limits` (a device such as /dev/zero is
refused before it is read).

Each file a row names resolves inside the manifest's folder (links followed) unless
`allow_outside`: a row `../../../../etc/passwd` or `/etc/shadow` is not read. A row whose file lies
outside, is missing, is not a regular file or is too large stays in the list with its `problem`
(the batch reports it as an error row and runs the others); nothing of such a file is read. A row
that repeats an earlier one exactly (same capture, holdout, unit, model, set and steps) is run
once: the second would compute the same result into a second folder; `notes` says which. A row's
output folder is named from its capture's path, never as one of the batch's own files
(`RESERVED`: a capture `index.html.csv` gets the folder `index.html-2`, not one that would take
the place of the batch's index.html).
"""
from __future__ import annotations

import csv
import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path

from bench_ctl.exitcodes import BadInput
from bench_ctl.limits import LIMITS, InputError, read_text
from bench_ctl.model.structures import StructureError, structure

STEPS = ("identify", "diagnose", "report")
#: the batch's own files in its output folder: no capture's folder may take their name (compared
#: case-blind: a case-insensitive file system holds one of INDEX.HTML and index.html)
RESERVED = ("index.html", "summary.csv")
COLUMNS = ("capture", "holdout", "unit", "model", "set", "steps")
#: the kind (`bench_ctl.limits`) of the file each column names
_KIND = {"capture": "a capture", "holdout": "a capture", "unit": "a unit file"}


class ManifestError(BadInput):
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
    #: why the row cannot run (a file outside the folder, missing, ...); "" when it can
    problem: str = ""


def _name(capture: str, taken: set[str]) -> str:
    base = re.sub(r"[^A-Za-z0-9._-]+", "_", str(Path(capture).with_suffix(""))).strip("._") or "capture"
    name, k = base, 2
    while name.casefold() in {t.casefold() for t in taken} or name.casefold() in RESERVED:
        name, k = f"{base}-{k}", k + 1
    taken.add(name)
    return name


def _file(manifest: Path, base: Path, line: int, column: str, cell: str,
          allow_outside: bool) -> tuple[Path, str]:
    """The file a cell names (relative to the manifest's folder) and why it cannot be used ("" if
    it can). Only the file's metadata is looked at, never its content."""
    raw = Path(cell)
    path = raw if raw.is_absolute() else base / raw
    where = f"{manifest}, line {line}, column '{column}'"
    resolved = path.resolve()
    if not allow_outside and not resolved.is_relative_to(base):
        return path, (f"{where}: {cell} lies outside the manifest's folder {base}; not read (give "
                      "--allow-outside to read files elsewhere)")
    try:
        st = os.stat(path)
    except OSError as exc:
        return path, f"{where}: {cell}: {'not found' if isinstance(exc, FileNotFoundError) else exc.strerror}"
    if not stat.S_ISREG(st.st_mode):
        return path, f"{where}: {cell} is not a regular file (a device, pipe or folder)"
    limit = LIMITS[_KIND[column]]
    if st.st_size > limit:
        return path, f"{where}: {cell} has {st.st_size} bytes, more than the {limit} bytes {_KIND[column]} may have"
    return path, ""


def read_manifest(path: str | Path, *, allow_outside: bool = False,
                  notes: list[str] | None = None) -> list[Entry]:
    """The entries of the manifest at `path` (see the module docstring); `notes` (when given)
    receives a line for each repeated row run once."""
    path = Path(path)
    try:
        text = read_text(path, "a manifest")   # Excel's "CSV UTF-8" byte-order mark is dropped
    except InputError as exc:
        raise ManifestError(str(exc)) from None
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
    seen: dict[tuple, int] = {}
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
        model = None
        if cell.get("model"):
            try:
                model = structure(cell["model"]).name
            except StructureError as exc:
                raise ManifestError(f"{path}, line {i}, column 'model': {exc}") from None
        files: dict[str, Path | None] = {}
        problems = []
        for column in ("capture", "holdout", "unit"):
            if cell.get(column):
                files[column], problem = _file(path, base, i, column, cell[column], allow_outside)
                if problem:
                    problems.append(problem)
            else:
                files[column] = None
        steps = tuple(s for s in STEPS if s in steps)
        key = (*(str(f.resolve()) if f else None for f in files.values()), model, sets, steps)
        if key in seen:
            if notes is not None:
                notes.append(f"{path}, line {i} repeats line {seen[key]} (the same capture, holdout, unit, model, "
                             "set and steps): run once, the second would give the same result")
            continue
        seen[key] = i
        out.append(Entry(line=i, name=_name(cell["capture"], taken), capture=files["capture"],  # type: ignore[arg-type]
                         holdout=files["holdout"], unit=files["unit"], model=model,
                         overrides=sets, steps=steps, problem="; ".join(problems)))
    if not out:
        raise ManifestError(f"{path}: no capture listed")
    return out
