"""The error types of the capture layer: bad input named by file, row and column, and a request
that cannot be carried out.

A `CaptureError` is a `ValueError` (a `BadInput`) whose message always starts with the file, then
(where they apply) the row - the 1-based line number a text editor shows, header included, or the
sample number of a binary COMTRADE record - and the column or channel name, then what is wrong. A
`SpecError` refuses what was asked of the layer before any file is read (an import's mapping, test
description, efd base or scale, a capture's file name).
"""
from __future__ import annotations

import os
import re

from bench_ctl.exitcodes import BadInput


class SpecError(BadInput):
    """An import or write request that cannot be carried out; the message says which part."""


class CaptureError(BadInput):
    """Refused capture input.

    Attributes keep the parts apart for callers that want them: `file`, `row` (int or None),
    `column` (str or None; a COMTRADE channel is named with column_kind="channel"), `reason` (the
    message without the location).
    """

    def __init__(
        self,
        file: str | os.PathLike[str],
        reason: str,
        *,
        row: int | None = None,
        column: str | None = None,
        row_kind: str = "row",
        column_kind: str = "column",
    ) -> None:
        self.file = os.fspath(file)
        self.row = row
        self.column = column
        self.reason = reason
        where = [self.file]
        if row is not None:
            where.append(f"{row_kind} {row}")
        if column is not None:
            where.append(f"{column_kind} {column!r}")
        super().__init__(f"{', '.join(where)}: {reason}")


#: what a refusal may quote of a file's content: a column name or a number, short
SHOWABLE = re.compile(r"[\w .,()\[\]/%+#°µ-]{0,40}")


def shown(text: object) -> str:
    """`text` quoted when it looks like a column name or a number, else only its length: a file
    that is not a capture (a row of a manifest pointing at /etc/shadow) is refused without its
    content reaching the console, a summary or a report (issue 24 item 9)."""
    s = str(text)
    if SHOWABLE.fullmatch(s):
        return repr(s)
    return f"<{len(s)} characters, not shown>"


def shown_names(names: list[str] | tuple[str, ...]) -> str:
    """The header's column names, or only how many when one of them does not look like a name."""
    if all(SHOWABLE.fullmatch(n) for n in names):
        return ", ".join(names)
    return f"{len(names)} column(s), not shown: they do not look like column names (is this a capture at all?)"
