"""Reading a recorder's own CSV export (vendor column names, `;` or tab separators, decimal
comma, date + clock-time columns) into time + named columns, with the file line of each row.

No mapping, scaling or resampling here (see `importer`); every refusal names file, row and
column.
"""
from __future__ import annotations

import datetime as dt
import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench_ctl.capture.errors import CaptureError, shown, shown_names
from bench_ctl.capture.table import TextTable, decode_utf8, parse_numeric, read_limited, read_text_table

log = logging.getLogger(__name__)

_NS_PER_S = 1_000_000_000
_NS_PER_DAY = 86_400 * _NS_PER_S


@dataclass(frozen=True)
class RawRecord:
    """Time (s) and the requested columns of a source, before mapping and checks of the step."""

    file: str
    time: np.ndarray
    columns: dict[str, np.ndarray]  # source column name -> float64 values
    rows: np.ndarray  # file line (or sample number) of each sample
    row_kind: str
    time_info: dict[str, Any]
    unused_columns: tuple[str, ...]
    time_column: str = "time"  # the source column to name when time is refused


def _require(table: TextTable, name: str, role: str) -> None:
    if name not in table.header:
        raise CaptureError(table.file, f"no column of that name ({role}); the header has "
                           f"{shown_names(table.header)}", row=table.header_line, column=name)


def _clock_ns(table: TextTable, column: str, decimal: str) -> np.ndarray:
    marks = "." if decimal == "." else ".,"
    pattern = re.compile(rf"(\d{{1,2}}):(\d{{2}}):(\d{{2}})(?:[{re.escape(marks)}](\d{{1,9}}))?")
    out = np.empty(table.n_rows, dtype=np.int64)
    for i, cell in enumerate(table.cells[column]):
        m = pattern.fullmatch(cell)
        h, mi, s = (int(m.group(k)) for k in (1, 2, 3)) if m else (99, 99, 99)
        if m is None or h > 23 or mi > 59 or s > 59:
            raise CaptureError(table.file, f"clock time {shown(cell)} is not HH:MM:SS[.fraction] "
                               "(up to 9 fraction digits)", row=int(table.lines[i]),
                               column=column)
        frac = m.group(4) or ""
        out[i] = ((h * 60 + mi) * 60 + s) * _NS_PER_S + int(frac.ljust(9, "0"))
    return out


def _date_days(table: TextTable, column: str, date_format: str) -> tuple[np.ndarray, dt.date]:
    cache: dict[str, int] = {}
    out = np.empty(table.n_rows, dtype=np.int64)
    for i, cell in enumerate(table.cells[column]):
        if cell not in cache:
            try:
                cache[cell] = dt.datetime.strptime(cell, date_format).date().toordinal()
            except ValueError:
                raise CaptureError(table.file, f"date {shown(cell)} does not match the format "
                                   f"{date_format!r}", row=int(table.lines[i]),
                                   column=column) from None
        out[i] = cache[cell]
    return out - out[0], dt.date.fromordinal(int(out[0]))


def _time(table: TextTable, *, time_column: str | None, date_column: str | None,
          clock_column: str | None, date_format: str, decimal: str
          ) -> tuple[np.ndarray, dict[str, Any]]:
    if time_column is not None:
        _require(table, time_column, "time column")
        return parse_numeric(table, time_column, decimal=decimal), {
            "method": "seconds column", "time_column": time_column, "unit": "s",
            "origin": "as in the source"}
    assert clock_column is not None
    _require(table, clock_column, "clock column")
    ns = _clock_ns(table, clock_column, decimal)
    info: dict[str, Any] = {"clock_column": clock_column,
                            "origin": "t = 0 s at the first sample"}
    if date_column is not None:
        _require(table, date_column, "date column")
        days, first_date = _date_days(table, date_column, date_format)
        ns = ns + days * _NS_PER_DAY
        info.update(method="date + clock columns", date_column=date_column,
                    date_format=date_format)
    else:
        first_date = None
        info.update(method="clock column (no date: a record must not cross midnight)")
    rel = ns - ns[0]
    start_ns = int(ns[0]) % _NS_PER_DAY
    first = dt.time(start_ns // 3_600_000_000_000, start_ns // 60_000_000_000 % 60,
                    start_ns // _NS_PER_S % 60, start_ns % _NS_PER_S // 1000)
    info["first_sample"] = (dt.datetime.combine(first_date, first).isoformat()
                            if first_date else first.isoformat())
    if start_ns % 1000:
        info["first_sample_ns"] = int(start_ns % _NS_PER_S)
    return rel.astype(np.float64) / _NS_PER_S, info


def read_vendor_csv(
    path: str | Path,
    *,
    columns: Sequence[str],
    time_column: str | None = None,
    date_column: str | None = None,
    clock_column: str | None = None,
    date_format: str = "%Y-%m-%d",
    delimiter: str = ",",
    decimal: str = ".",
    header_line: int = 1,
) -> RawRecord:
    """Time in s (from `time_column`, or from `clock_column` [+ `date_column`] relative to the
    first sample, exact to the nanosecond) and the numeric, finite values of `columns`."""
    file = str(path)
    if time_column is None and clock_column is None:
        raise ValueError("give a time column, or a clock column (with or without a date column)")
    if time_column is not None and (clock_column or date_column):
        raise ValueError("give either a time column or date/clock columns, not both")
    if date_column is not None and clock_column is None:
        raise ValueError("a date column needs a clock column")
    table = read_text_table(file, decode_utf8(file, read_limited(path)),
                            delimiter=delimiter, header_line=header_line)
    for name in columns:
        _require(table, name, "mapped column")
    if table.n_rows == 0:
        raise CaptureError(file, "header only, no data rows")
    time, info = _time(table, time_column=time_column, date_column=date_column,
                       clock_column=clock_column, date_format=date_format, decimal=decimal)
    values = {name: parse_numeric(table, name, decimal=decimal) for name in columns}
    used = set(columns) | {c for c in (time_column, date_column, clock_column) if c}
    return RawRecord(file=file, time=time, columns=values, rows=table.lines, row_kind="row",
                     time_info=info,
                     unused_columns=tuple(c for c in table.header if c not in used),
                     time_column=time_column or str(clock_column))
