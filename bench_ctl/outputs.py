"""Every file a command writes goes through here (docs/safety.md: never overwrite a capture;
one guard for every file, side files included).

The rules, for a result, a capture and its sidecar, a report and each of its figures, a PDF, a
.dyr, a batch summary alike:

- never an input: not one of the command's inputs (a capture, its sidecar, its COMTRADE pair, a
  result, a diagnosis, a unit file, a manifest), also not through a link that leads to one;
- never an existing file without `force` (the command's `--force`);
- never through a symbolic link: an output path that is a link is refused, `--force` or not;
- atomically: a temporary file in the same folder, fsynced, then linked into place (refused if
  the name appeared meanwhile) or, with `force`, renamed over the old file; an interrupted
  command leaves the old file or the new one, never half of one;
- one permission policy: a new file gets 0666 minus the umask, as any tool's (0644 under the
  usual umask 022). Nothing bench-ctl writes is secret (results, captures, reports hold test
  data and command lines), so no file is made private on its own.

`Outputs` holds a command's inputs and `force`; `claim` checks a path before any work (refusals
name the option and the path), `write_bytes` / `write_text` / `write_json` write one. A folder
that cannot be written (read-only file system, no permission) is refused at `claim`, so a long
fit never ends in a traceback for want of a writable folder.
"""
from __future__ import annotations

import contextlib
import errno
import json
import os
import secrets
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from bench_ctl.exitcodes import BadInput

__all__ = ["OutputRefused", "Outputs", "guard_outputs", "input_family", "write_bytes", "write_json",
           "write_text", "why_not_written", "writing", "path_from"]

#: the files that belong to an input: a capture CSV's sidecar, a COMTRADE record's other half
_FAMILY = {".csv": (".json",), ".cfg": (".dat", ".json"), ".dat": (".cfg", ".json"), ".cff": (".json",)}



#: how a command with --force says what to do about an existing output
FORCE_HINT = "give --force to replace an earlier output"
#: ... and one without (a capture, an import, a simulation)
NEVER_HINT = "it is never overwritten: choose another name"


class OutputRefused(BadInput):
    """An output path that would destroy an input or an earlier result, or cannot be written."""


def input_family(path: str | os.PathLike[str]) -> list[Path]:
    """The input and the files that go with it (sidecar, COMTRADE pair), resolved."""
    p = Path(path).resolve()
    return [p] + [p.with_suffix(s) for s in _FAMILY.get(p.suffix.lower(), ())]


def why_not_written(exc: OSError, path: str | os.PathLike[str]) -> str:
    """One line for an OSError met while writing `path` (disk full, read-only, permission)."""
    what = {errno.ENOSPC: "no space left on the device", errno.EROFS: "read-only file system",
            errno.EDQUOT: "disk quota exceeded"}.get(exc.errno or 0, exc.strerror or str(exc))
    return f"cannot write {exc.filename or path}: {what}"


def path_from(output: str | os.PathLike[str], path: str | os.PathLike[str]) -> str:
    """`path` as the file `output` records it: relative to `output`'s folder, with forward
    slashes, so the pair can move as a whole and be read from any working directory; absolute
    where there is no relative path (another drive)."""
    absolute = os.path.abspath(path)
    try:
        return Path(os.path.relpath(absolute, Path(os.path.abspath(output)).parent)).as_posix()
    except ValueError:
        return absolute


@contextlib.contextmanager
def writing(path: str | os.PathLike[str] | None, what: str = "") -> Iterator[None]:
    """Inside it, an OSError met while writing `path` (a full disk, a folder gone read-only)
    becomes an `OutputRefused` saying why in one line (`why_not_written`, after `what`), which a
    command ends on as bad input (exit 2)."""
    try:
        yield
    except OSError as exc:
        raise OutputRefused(what + why_not_written(exc, path or "")) from None


def _probe_folder(folder: Path) -> str | None:
    """None when a file can be created in `folder` (tried, then removed), else why not."""
    tmp = folder / f".bench-ctl-probe.{os.getpid()}.{secrets.token_hex(4)}"
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        return {errno.EROFS: "read-only file system", errno.EACCES: "permission denied",
                errno.EPERM: "permission denied", errno.ENOSPC: "no space left on the device",
                errno.EDQUOT: "disk quota exceeded"}.get(exc.errno or 0, exc.strerror or str(exc))
    os.close(fd)
    os.unlink(tmp)
    return None


def _nearest_folder(p: Path) -> Path:
    """`p`'s folder, or its nearest existing ancestor when the writer creates the folder."""
    q = p.parent
    while not q.exists() and q != q.parent:
        q = q.parent
    return q


class Outputs:
    """The outputs of one command: its inputs (protected, with their families) and `force`.

    `make_folders`: the writer creates a missing output folder (else a missing folder is
    refused at `claim`)."""

    def __init__(self, inputs: Iterable[str | os.PathLike[str] | None] = (), *, force: bool = False,
                 make_folders: bool = False, replace_hint: str = FORCE_HINT) -> None:
        self.force = force
        self.make_folders = make_folders
        self.replace_hint = replace_hint
        self._protected: dict[Path, Path] = {}
        self._claimed: dict[Path, str] = {}
        self._probed: dict[Path, str | None] = {}
        self.protect(inputs)

    def protect(self, inputs: Iterable[str | os.PathLike[str] | None]) -> None:
        """Add inputs (and their sidecars / COMTRADE halves) that no output may replace."""
        for raw in inputs:
            if raw is None:
                continue
            for member in input_family(raw):
                self._protected.setdefault(member, Path(raw))

    def claim(self, option: str, raw: str | os.PathLike[str] | None) -> Path | None:
        """Check that `raw` may be written as the output of `option` (see the module docstring);
        OutputRefused names the option and the path. None: the output was not asked for."""
        if raw is None:
            return None
        given = Path(raw)
        label = f"{option} {raw}" if option else str(raw)
        link = f" (a symbolic link to {os.readlink(given)})" if given.is_symlink() else ""
        p = given.resolve()
        if p in self._protected:
            src = self._protected[p]
            what = "input " + str(src) if src.resolve() == p else f"part of input {src}"
            raise OutputRefused(f"{label}{link}: would overwrite {what}; choose another path "
                                "(an input is never overwritten, --force or not)")
        if link:
            raise OutputRefused(f"{label}: is a symbolic link (to {os.readlink(given)}); an output is never "
                                "written through a link, --force or not: remove the link or choose another path")
        if p in self._claimed:
            if self._claimed[p] == label:
                return p
            raise OutputRefused(f"{label}: the same file as {self._claimed[p]}")
        if not self.make_folders and not p.parent.is_dir():
            raise OutputRefused(f"{label}: folder {p.parent} does not exist")
        if p.is_dir():
            raise OutputRefused(f"{label}: is a folder")
        if p.exists() and not self.force:
            raise OutputRefused(f"{label}: exists; refusing to replace it ({self.replace_hint})")
        folder = _nearest_folder(p)
        if folder not in self._probed:
            self._probed[folder] = _probe_folder(folder)
        if self._probed[folder] is not None:
            raise OutputRefused(f"{label}: cannot write in {folder}: {self._probed[folder]}")
        self._claimed[p] = label
        return p

    def claim_all(self, outputs: Mapping[str, str | os.PathLike[str] | None]) -> None:
        for option, raw in outputs.items():
            self.claim(option, raw)

    def _check(self, path: str | os.PathLike[str]) -> None:
        p = Path(path).resolve()
        if p not in self._claimed:
            self.claim("", path)

    def write_bytes(self, path: str | os.PathLike[str], data: bytes) -> Path:
        self._check(path)
        if self.make_folders:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        return write_bytes(path, data, force=self.force)

    def write_text(self, path: str | os.PathLike[str], text: str) -> Path:
        return self.write_bytes(path, text.encode("utf-8"))

    def write_json(self, path: str | os.PathLike[str], data: Any) -> Path:
        return self.write_bytes(path, _json_bytes(data))


def guard_outputs(outputs: Mapping[str, str | os.PathLike[str] | None],
                  inputs: Iterable[str | os.PathLike[str] | None], *, force: bool = False,
                  make_folders: bool = False, replace_hint: str = FORCE_HINT) -> Outputs:
    """Refuse (OutputRefused, naming the option and the path) what `outputs` must not be.
    `outputs` maps an option name (e.g. "--json") to its path (None: not asked for). Returns the
    `Outputs` that writes them."""
    out = Outputs(inputs, force=force, make_folders=make_folders, replace_hint=replace_hint)
    out.claim_all(outputs)
    return out


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _exists_error(p: Path) -> OutputRefused:
    return OutputRefused(f"{p}: exists; refusing to replace it (give --force to replace an earlier output)")


def write_bytes(path: str | os.PathLike[str], data: bytes, *, force: bool = False) -> Path:
    """Write `data` to `path` atomically (see the module docstring): never through a symbolic
    link; an existing file only with `force` (else OutputRefused, also when the name appears
    while writing). The new file's permissions follow the umask."""
    p = Path(path)
    if p.is_symlink():
        raise OutputRefused(f"{p}: is a symbolic link (to {os.readlink(p)}); an output is never written "
                            "through a link")
    folder = p.parent if str(p.parent) else Path(".")
    tmp = folder / f".{p.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if force:
            os.replace(tmp, p)       # replaces a name, never follows a link
        else:
            try:
                os.link(tmp, p)      # atomic, and fails when the name exists (a link included)
            except FileExistsError:
                raise _exists_error(p) from None
            except OSError as exc:
                if exc.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK, errno.ENOSYS):
                    raise
                if os.path.lexists(p):   # a file system without hard links: check, then rename
                    raise _exists_error(p) from None
                os.replace(tmp, p)
    finally:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
    _fsync_dir(folder)
    return p


def write_text(path: str | os.PathLike[str], text: str, *, force: bool = False) -> Path:
    """UTF-8 text, written as `write_bytes` writes."""
    return write_bytes(path, text.encode("utf-8"), force=force)


def _json_bytes(data: Any) -> bytes:
    return (json.dumps(data, indent=1, allow_nan=False) + "\n").encode("utf-8")


def write_json(path: str | os.PathLike[str], data: Any, *, force: bool = False) -> Path:
    """JSON (no NaN / inf: strict), written as `write_bytes` writes."""
    return write_bytes(path, _json_bytes(data), force=force)
