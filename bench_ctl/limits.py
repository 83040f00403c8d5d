"""Input files: how large each kind may be, and the one reader that holds to it (issue 24 item
17: `batch /dev/zero` read without end until the kernel killed it at 24 GB).

`read_bounded(path, kind)` refuses, before reading a byte, what is not a regular file (a device
such as /dev/zero, a pipe, a folder) and a file larger than the limit of its kind, then reads at
most that many bytes (a file that grows while read is refused too). `read_text` decodes what it
read as UTF-8 (a byte-order mark is not content), `read_json` parses that, and `sha256_file`
hashes a regular file in chunks. Every refusal is an `InputError` whose message starts with the
file, then says what is wrong (the kind and its limit, the byte and line of a bad character, the
line and column of bad JSON); each layer turns it into its own error type (`ConfigError`,
`UnitError`, `CaptureError`, ...) without changing the words. Each limit is generous for the
real thing and far below a machine's memory (the reasons beside `LIMITS`). This module imports
nothing of the project: drivers, the runner and the analysis all read through it.
"""
from __future__ import annotations

import hashlib
import json
import os
import stat
from typing import Any

from bench_ctl.exitcodes import BadInput

__all__ = ["LIMITS", "InputError", "decode_text", "read_bounded", "read_json", "read_text", "sha256_file"]

MIB = 1 << 20

#: kind -> the largest file of that kind (bytes)
LIMITS: dict[str, int] = {
    # a 10 s record at 1 kHz is about 0.5 MB, a 10 min record of eight channels at 10 kHz about
    # 400 MB (a recorder export or COMTRADE .dat likewise)
    "a capture": 512 * MIB,
    # a capture's JSON sidecar: the test, bench and unit description, every register write
    "a sidecar": 16 * MIB,
    # an identification result or a diagnosis: parameters, history, identifiability, edges
    "a result JSON": 64 * MIB,
    "a diagnosis JSON": 64 * MIB,
    # a batch manifest: one line per capture (100 000 lines of 160 characters)
    "a manifest": 16 * MIB,
    # a unit file is a page of TOML
    "a unit file": 1 * MIB,
    # a bench config is a page of TOML
    "a bench config": 1 * MIB,
    # a device profile (register map) is a few pages of TOML
    "a profile": 1 * MIB,
    # a PSS/E .dyr of a whole interconnection holds some 10^5 records
    "a .dyr file": 64 * MIB,
}


class InputError(BadInput):
    """An input file refused; `str()` is `FILE: REASON` (the file first), and `file` and `reason`
    keep the two apart for a layer that formats its own error (a `CaptureError`)."""

    def __init__(self, file: str | os.PathLike[str], reason: str) -> None:
        self.file = os.fspath(file)
        self.reason = reason
        super().__init__(f"{self.file}: {reason}")


def _regular(file: str, kind: str) -> os.stat_result:
    try:
        st = os.stat(file)
    except OSError as exc:
        raise InputError(file, f"cannot read: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(file, f"not a regular file (a device, pipe or folder): {kind} is read from a file")
    return st


def read_bounded(path: str | os.PathLike[str], kind: str, limit: int | None = None) -> bytes:
    """The bytes of `path`, a regular file of at most `limit` bytes (default: the limit of `kind`,
    one of `LIMITS`); anything else is an `InputError` naming the file, kind and limit."""
    file = os.fspath(path)
    limit = LIMITS[kind] if limit is None else limit
    st = _regular(file, kind)
    if st.st_size > limit:
        raise InputError(file, f"{st.st_size} bytes, more than the {limit} bytes {kind} may have")
    try:
        with open(file, "rb") as f:
            data = f.read(limit + 1)
    except OSError as exc:
        raise InputError(file, f"cannot read: {exc.strerror or exc}") from None
    if len(data) > limit:
        raise InputError(file, f"more than the {limit} bytes {kind} may have (it grew while read)")
    return data


def decode_text(file: str | os.PathLike[str], data: bytes) -> str:
    """`data` as UTF-8 text (a leading byte-order mark dropped: Excel's "CSV UTF-8" and Windows
    editors write one); an `InputError` naming the byte and line of the first bad one."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise InputError(file, f"not a UTF-8 text file (byte {exc.start}, line {line}): {exc.reason}") from None


def read_text(path: str | os.PathLike[str], kind: str, limit: int | None = None) -> str:
    """The text of a UTF-8 file of `kind` (read with `read_bounded`, decoded with `decode_text`)."""
    return decode_text(path, read_bounded(path, kind, limit))


def read_json(path: str | os.PathLike[str], kind: str, limit: int | None = None) -> Any:
    """The JSON value in a file of `kind` (`read_text`, then parsed); bad JSON is an `InputError`
    naming its line and column."""
    text = read_text(path, kind, limit)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(path, f"invalid JSON: {exc.msg} (line {exc.lineno}, column {exc.colno})") from None


def sha256_file(path: str | os.PathLike[str], kind: str = "an input") -> str:
    """Hex SHA-256 of a regular file's bytes, read in chunks of 1 MiB (a device such as /dev/zero
    is refused, never read without end); an `InputError` naming the file otherwise."""
    file = os.fspath(path)
    _regular(file, kind)
    h = hashlib.sha256()
    try:
        with open(file, "rb") as f:
            for chunk in iter(lambda: f.read(MIB), b""):
                h.update(chunk)
    except OSError as exc:
        raise InputError(file, f"cannot read: {exc.strerror or exc}") from None
    return h.hexdigest()
