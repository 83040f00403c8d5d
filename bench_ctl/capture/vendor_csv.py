"""Reading a recorder's own CSV export (vendor column names, `;` or tab separators, decimal
comma, date + clock-time columns) into time + named columns, with the file line of each row.

No mapping, scaling or resampling here (see `importer`); every refusal names file, row and
column. A clock column a spreadsheet shortened to MM:SS.f is refused with what its own span says,
unless the recorder's rate is given (`rate_hz`): time is then rebuilt as k / rate and checked
against the file's marks (`bench_ctl.capture.rate`), as it is for a full clock or a seconds column
given a rate.
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

from bench_ctl.capture import rate as rate_base
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
    #: the first sample's time of day (s) when time came from a full clock column (clock windows)
    clock0_s: float | None = None


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


def _rebuilt(time: np.ndarray, info: dict[str, Any], table: TextTable, column: str, rate_hz: float | None,
             resolution_s: float, what: str) -> tuple[np.ndarray, dict[str, Any]]:
    """`time` as read, or rebuilt from the recorder's rate and checked against it (rate given)."""
    if rate_hz is None:
        return time, info
    t, check = rate_base.rebuild(time, rate_hz, resolution_s, file=table.file, lines=table.lines,
                                 column=column, what=what)
    return t, {**info, "method": f"rebuilt from the recorder's rate: t = k / {rate_hz:g} Hz ({info['method']} "
                                 "checked against it)", "rebuilt": check}


def _time(table: TextTable, *, time_column: str | None, date_column: str | None,
          clock_column: str | None, date_format: str, decimal: str, rate_hz: float | None = None
          ) -> tuple[np.ndarray, dict[str, Any], float | None]:
    info: dict[str, Any]
    if time_column is not None:
        _require(table, time_column, "time column")
        t = parse_numeric(table, time_column, decimal=decimal)
        info = {"method": "seconds column", "time_column": time_column, "unit": "s", "origin": "as in the source"}
        if rate_hz is not None:
            t0 = float(t[0])
            rel, info = _rebuilt(t - t0, info, table, time_column, rate_hz,
                                 rate_base.decimals_resolution(table.cells[time_column]), "seconds column")
            return rel + t0, info, None
        return t, info, None
    assert clock_column is not None
    _require(table, clock_column, "clock column")
    cells = table.cells[clock_column]
    if cells and rate_base.SHORT_CLOCK.fullmatch(cells[0]):
        marks, resolution = rate_base.short_clock_seconds(cells, table.lines, table.file, clock_column)
        if rate_hz is None:
            raise rate_base.short_clock_refusal(table.file, cells[0], int(table.lines[0]), clock_column, marks,
                                                resolution)
        info = {"method": "clock column", "clock_column": clock_column,
                "clock_format": "MM:SS.f: shortened by a spreadsheet (the hours and the precision below "
                                f"{resolution:g} s lost)", "origin": "t = 0 s at the first sample"}
        t, info = _rebuilt(marks, info, table, clock_column, rate_hz, resolution, "shortened clock column")
        return t, info, None
    ns = _clock_ns(table, clock_column, decimal)
    info = {"clock_column": clock_column, "origin": "t = 0 s at the first sample"}
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
    digits = 0 if rate_hz is None else max(len(re.split(r"[.,]", c)[1]) if re.search(r"[.,]", c) else 0
                                           for c in cells)
    t, info = _rebuilt(rel.astype(np.float64) / _NS_PER_S, info, table, clock_column, rate_hz, 10.0 ** -digits,
                       "clock column")
    return t, info, start_ns / _NS_PER_S


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
    rate_hz: float | None = None,
) -> RawRecord:
    """Time in s (from `time_column`, or from `clock_column` [+ `date_column`] relative to the
    first sample, exact to the nanosecond; with `rate_hz`, k / rate checked against them) and the
    numeric, finite values of `columns`."""
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
    time, info, clock0 = _time(table, time_column=time_column, date_column=date_column,
                               clock_column=clock_column, date_format=date_format, decimal=decimal,
                               rate_hz=rate_hz)
    values = {name: parse_numeric(table, name, decimal=decimal) for name in columns}
    used = set(columns) | {c for c in (time_column, date_column, clock_column) if c}
    return RawRecord(file=file, time=time, columns=values, rows=table.lines, row_kind="row",
                     time_info=info,
                     unused_columns=tuple(c for c in table.header if c not in used),
                     time_column=time_column or str(clock_column), clock0_s=clock0)
