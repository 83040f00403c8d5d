"""Delimited text tables with their line numbers: the parsing shared by the capture reader and
the recorder-export importer.

Only splits and names cells; what a column must contain is the caller's business. Every
refusal is a `CaptureError` naming the file, the line (as a text editor numbers it) and, for a
cell, the column.
"""
from __future__ import annotations

import csv
import io
import logging
import os
import re
from dataclasses import dataclass

import numpy as np

from bench_ctl.capture.errors import SHOWABLE, CaptureError, shown
from bench_ctl.limits import LIMITS, InputError, read_bounded

log = logging.getLogger(__name__)

_DELIMITER_NAMES = {",": "comma", ";": "semicolon", "\t": "tab", "|": "pipe"}
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_NONFINITE = {"nan", "+nan", "-nan", "inf", "+inf", "-inf", "infinity", "+infinity", "-infinity"}


#: the largest capture file read (bytes): see `bench_ctl.limits`
MAX_INPUT_BYTES = LIMITS["a capture"]


def read_limited(path: str | os.PathLike[str], limit: int | None = None, kind: str = "a capture") -> bytes:
    """The bytes of a regular file of at most `limit` bytes (default: the limit of `kind`, see
    `bench_ctl.limits`); anything else (a device such as /dev/zero, a pipe, a folder, a larger
    file) is refused naming the file, before it is read."""
    try:
        return read_bounded(path, kind, limit)
    except InputError as exc:
        raise CaptureError(exc.file, exc.reason) from None


def delimiter_name(delimiter: str) -> str:
    """'comma' for ',' and so on; the character itself (quoted) for anything else."""
    return _DELIMITER_NAMES.get(delimiter, repr(delimiter))


@dataclass(frozen=True)
class TextTable:
    """A parsed table: header names, and per column the raw cell strings of the data rows."""

    file: str
    header: tuple[str, ...]
    header_line: int
    lines: np.ndarray  # int64, the line number of each data row
    cells: dict[str, list[str]]

    @property
    def n_rows(self) -> int:
        return int(self.lines.size)


def decode_utf8(file: str, data: bytes) -> str:
    """UTF-8 (an optional BOM is accepted) or a CaptureError naming the line of the bad byte."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise CaptureError(file, f"not UTF-8 text (byte offset {exc.start})", row=line) from None


def _foreign_delimiter(cell: str, delimiter: str) -> str | None:
    for cand in _DELIMITER_NAMES:
        if cand != delimiter and cand in cell:
            return cand
    return None


def read_text_table(
    file: str, text: str, *, delimiter: str = ",", header_line: int = 1
) -> TextTable:
    """Split `text` into a header (on line `header_line`, 1-based) and data rows.

    Refuses: an empty file, a header that is not `delimiter`-separated, empty or repeated
    column names, rows whose field count differs from the header, blank lines between data
    rows. Blank lines after the last data row are ignored. Cells keep their text, trimmed of
    surrounding blanks.
    """
    if header_line < 1:
        raise ValueError(f"header_line must be >= 1, got {header_line}")
    if not text.strip():
        raise CaptureError(file, "empty file")
    expected = f"expected {delimiter_name(delimiter)}-separated values"
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=delimiter, strict=True)
    try:
        header_row: list[str] | None = None
        for record in reader:
            if reader.line_num >= header_line:
                header_row = record
                break
        if header_row is None or not any(c.strip() for c in header_row):
            raise CaptureError(file, "no header row", row=header_line)
        header = tuple(c.strip() for c in header_row)
        if len(header) == 1:
            foreign = _foreign_delimiter(header[0], delimiter)
            if foreign is not None:
                raise CaptureError(
                    file,
                    f"{expected}; the header looks {delimiter_name(foreign)}-separated: "
                    f"{shown(header_row[0])}",
                    row=reader.line_num,
                )
        seen: set[str] = set()
        for name in header:
            if not name:
                raise CaptureError(file, "empty column name in the header", row=reader.line_num)
            if name in seen:
                raise CaptureError(file, "column name repeated in the header",
                                   row=reader.line_num, column=name if SHOWABLE.fullmatch(name) else None)
            seen.add(name)
        actual_header_line = reader.line_num
        lines: list[int] = []
        rows: list[list[str]] = []
        blank_line: int | None = None
        for record in reader:
            if not record or (len(record) == 1 and not record[0].strip()):
                if blank_line is None:
                    blank_line = reader.line_num
                continue
            if blank_line is not None:
                raise CaptureError(file, "blank line between data rows", row=blank_line)
            if len(record) != len(header):
                hint = ""
                foreign = _foreign_delimiter(record[0], delimiter) if len(record) == 1 else None
                if foreign is not None:
                    hint = f"; {expected}, this row looks {delimiter_name(foreign)}-separated"
                raise CaptureError(
                    file, f"{len(record)} fields, the header has {len(header)}{hint}",
                    row=reader.line_num,
                )
            lines.append(reader.line_num)
            rows.append([c.strip() for c in record])
    except csv.Error as exc:
        raise CaptureError(file, f"malformed CSV: {exc}", row=reader.line_num) from None
    cells = {name: [r[i] for r in rows] for i, name in enumerate(header)}
    return TextTable(file=file, header=header, header_line=actual_header_line,
                     lines=np.asarray(lines, dtype=np.int64), cells=cells)


def _parse_cell(cell: str, decimal: str) -> float | None:
    if decimal == "," and "." in cell:  # with a decimal comma a dot is a digit separator (1.234 = 1234)
        return None
    text = cell.replace(",", ".") if decimal == "," else cell
    if _NUMBER.fullmatch(text):
        return float(text)
    return None


def parse_numeric(
    table: TextTable, column: str, *, decimal: str = ".", finite: bool = True
) -> np.ndarray:
    """The cells of `column` as float64, or a CaptureError naming the row of the first bad cell.

    A cell is a plain decimal number (optional sign, fraction, exponent; with decimal=',' the
    comma is the decimal mark). `nan`/`inf` are refused when `finite` (the default) and kept
    otherwise; anything else (empty cell, text, hex, digit separators) is refused.
    """
    if decimal not in (".", ","):
        raise ValueError(f"decimal must be '.' or ',', got {decimal!r}")
    out = np.empty(table.n_rows, dtype=np.float64)
    for i, cell in enumerate(table.cells[column]):
        value = _parse_cell(cell, decimal)
        if value is not None:
            out[i] = value
            continue
        if cell.lower() in _NONFINITE:
            if finite:
                raise CaptureError(table.file, f"value {shown(cell)} is not finite",
                                   row=int(table.lines[i]), column=column)
            out[i] = float(cell)
            continue
        if not cell:
            reason = "empty cell, expected a number"
        else:
            reason = f"not a number: {shown(cell)}"
            if decimal == "." and re.fullmatch(r"[+-]?\d*,\d+", cell):
                reason += " (a decimal comma? it must be asked for explicitly)"
        raise CaptureError(table.file, reason, row=int(table.lines[i]), column=column)
    return out


def try_numeric(table: TextTable, column: str, *, decimal: str = ".") -> np.ndarray | None:
    """`column` as float64 (non-finite values kept) when every cell is a number, else None."""
    try:
        return parse_numeric(table, column, decimal=decimal, finite=False)
    except CaptureError:
        return None
