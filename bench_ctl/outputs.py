"""Writing what a command produces without losing what it read (docs/safety.md: never
overwrite a capture; bad input loses nothing).

`guard_outputs` refuses, before any work, an output that is one of the command's inputs (a
capture, its sidecar, its COMTRADE pair, a result, a unit file), two outputs on one path, an
output in a folder that does not exist, and an existing output unless `force`. `write_json`
writes through a temporary file in the same folder and renames it, so an interrupted command
leaves the old file or the new one, never half of one.
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any, Iterable, Mapping

__all__ = ["OutputRefused", "guard_outputs", "input_family", "write_json", "write_text"]

#: the files that belong to an input: a capture CSV's sidecar, a COMTRADE record's other half
_FAMILY = {".csv": (".json",), ".cfg": (".dat", ".json"), ".dat": (".cfg", ".json"), ".cff": (".json",)}


class OutputRefused(ValueError):
    """An output path that would destroy an input or an earlier result."""


def input_family(path: str | os.PathLike[str]) -> list[Path]:
    """The input and the files that go with it (sidecar, COMTRADE pair), resolved."""
    p = Path(path).resolve()
    return [p] + [p.with_suffix(s) for s in _FAMILY.get(p.suffix.lower(), ())]


def guard_outputs(outputs: Mapping[str, str | os.PathLike[str] | None],
                  inputs: Iterable[str | os.PathLike[str] | None], *, force: bool = False,
                  make_folders: bool = False) -> None:
    """Refuse (OutputRefused, naming the option and the path) what `outputs` must not be.
    `outputs` maps an option name (e.g. "--json") to its path (None: not asked for);
    `make_folders`: the writer creates a missing folder (else a missing folder is refused)."""
    protected: dict[Path, Path] = {}
    for raw in inputs:
        if raw is None:
            continue
        for member in input_family(raw):
            protected.setdefault(member, Path(raw))
    seen: dict[Path, str] = {}
    for option, raw in outputs.items():
        if raw is None:
            continue
        p = Path(raw).resolve()
        if p in protected:
            what = "it" if protected[p].resolve() == p else f"part of input {protected[p]}"
            raise OutputRefused(f"{option} {raw}: would overwrite {what}; choose another path "
                                "(an input is never overwritten, --force or not)")
        if p in seen:
            raise OutputRefused(f"{option} {raw}: the same file as {seen[p]}")
        seen[p] = f"{option} {raw}"
        if not make_folders and not p.parent.is_dir():
            raise OutputRefused(f"{option} {raw}: folder {p.parent} does not exist")
        if p.is_dir():
            raise OutputRefused(f"{option} {raw}: is a folder")
        if p.exists() and not force:
            raise OutputRefused(f"{option} {raw}: exists; refusing to replace it (give --force to replace "
                                "an earlier output)")


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write text atomically: a temporary file beside `path`, fsynced, then renamed over it."""
    p = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=p.name + ".", suffix=".tmp", dir=p.parent or ".")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json(path: str | os.PathLike[str], data: Any) -> None:
    """JSON (no NaN / inf: strict), written atomically."""
    write_text(path, json.dumps(data, indent=1, allow_nan=False) + "\n")
