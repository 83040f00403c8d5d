"""How large each kind of input file may be, and the one reader that holds to it (issue 24 item
17: `batch /dev/zero` read without end until the kernel killed it at 24 GB).

`read_bounded(path, kind)` refuses, before reading a byte, what is not a regular file (a device
such as /dev/zero, a pipe, a folder) and a file larger than the limit of its kind, then reads at
most that many bytes (a file that grows while read is refused too). The message names the file,
the kind and its limit. Each limit is generous for the real thing and far below a machine's
memory (the reasons beside `LIMITS`).
"""
from __future__ import annotations

import os
import stat

__all__ = ["LIMITS", "InputError", "read_bounded"]

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
    # a PSS/E .dyr of a whole interconnection holds some 10^5 records
    "a .dyr file": 64 * MIB,
}


class InputError(ValueError):
    """An input file refused before it was read; the message names the file, kind and limit."""


def read_bounded(path: str | os.PathLike[str], kind: str, limit: int | None = None) -> bytes:
    """The bytes of `path`, a regular file of at most `limit` bytes (default: the limit of `kind`,
    one of `LIMITS`); anything else is an `InputError` naming the file, kind and limit."""
    file = os.fspath(path)
    limit = LIMITS[kind] if limit is None else limit
    try:
        st = os.stat(file)
    except OSError as exc:
        raise InputError(f"{file}: cannot read: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{file}: not a regular file (a device, pipe or folder): {kind} is read from a file")
    if st.st_size > limit:
        raise InputError(f"{file}: {st.st_size} bytes, more than the {limit} bytes {kind} may have")
    try:
        with open(file, "rb") as f:
            data = f.read(limit + 1)
    except OSError as exc:
        raise InputError(f"{file}: cannot read: {exc.strerror or exc}") from None
    if len(data) > limit:
        raise InputError(f"{file}: more than the {limit} bytes {kind} may have (it grew while read)")
    return data
