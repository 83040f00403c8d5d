"""Import of a real recorder export (vendor CSV, or COMTRADE .cfg + .dat) as a capture.

Maps vendor column names to `usetp` / `efd` / `vt`, builds time from a seconds column or from
date + clock-time columns, scales efd from the rated-field base to the model base, synthesises
`usetp` from a test description when there is no setpoint channel, and resamples (linear
interpolation) only when asked: jittered time without a resample request is refused with the
row. The record must pass the plausibility checks identify makes (`bench_ctl.capture.plausible`:
time unit, physical values, the test description) before it is written; whether it holds a test
at all is left to the commands that fit it. The sidecar's `import` block records each of these steps.
"""
from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal

import numpy as np

from bench_ctl.capture import comtrade_io
from bench_ctl.capture.capture import Capture, read_capture, sha256_file, write_capture
from bench_ctl.capture.errors import CaptureError
from bench_ctl.capture.plausible import implausible
from bench_ctl.capture.timebase import check_time, resample_linear, step_stats
from bench_ctl.capture.vendor_csv import RawRecord, read_vendor_csv

log = logging.getLogger(__name__)

RESAMPLE_METHOD = "linear interpolation"
MAX_GAP_RATIO = 2.0  # a source step above this many median steps is a dropout, not jitter


def _finite(value: Any, what: str, *, positive: bool = False, nonzero: bool = False) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{what} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise ValueError(f"{what} must be > 0, got {value!r}")
    if nonzero and value == 0:
        raise ValueError(f"{what} must not be 0")


@dataclass(frozen=True)
class TestDescription:
    """The test as the user describes it when the record has no setpoint channel.

    usetp = usetp0_pu, + amplitude_pu from start_s (capture time) on; for a pulse, back to
    usetp0_pu at start_s + width_s. A sample within 1e-6 steps of an edge counts as after it.
    The stated instants are nominal: fits search each edge within `edge_tolerance_s`.
    """

    __test__ = False  # not a pytest test class

    kind: Literal["step", "pulse"]
    start_s: float
    amplitude_pu: float
    width_s: float | None = None
    usetp0_pu: float = 1.0
    #: how far each edge may lie from the stated instant (s); None: one source sample. Every fit
    #: searches the edge instants within it (bench_ctl.identification.timing).
    edge_tolerance_s: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("step", "pulse"):
            raise ValueError(f"test kind must be 'step' or 'pulse', got {self.kind!r}")
        _finite(self.start_s, "test start_s")
        _finite(self.amplitude_pu, "test amplitude_pu", nonzero=True)
        _finite(self.usetp0_pu, "test usetp0_pu")
        if self.kind == "pulse":
            if self.width_s is None:
                raise ValueError("a pulse test needs width_s")
            _finite(self.width_s, "test width_s", positive=True)
        elif self.width_s is not None:
            raise ValueError("a step test has no width_s")
        if self.edge_tolerance_s is not None:
            _finite(self.edge_tolerance_s, "test edge_tolerance_s", positive=True)

    def usetp(self, time: np.ndarray, *, file: str = "<test description>") -> np.ndarray:
        """The setpoint on `time` (uniform). Refuses edges outside the record."""
        step = float(time[1] - time[0])
        tol = 1e-6 * step
        t0, t1 = float(time[0]), float(time[-1])
        end = None if self.width_s is None else self.start_s + self.width_s
        for name, edge in (("start", self.start_s), ("end", end)):
            if edge is not None and not (t0 + step - tol <= edge <= t1 + tol):
                raise CaptureError(file, f"test description: {name} of the {self.kind} at "
                                   f"{edge!r} s lies outside the record ({t0!r}..{t1!r} s, "
                                   "at least one sample before the start)")
        on = time >= self.start_s - tol
        if end is not None:
            on &= time < end - tol
        return self.usetp0_pu + self.amplitude_pu * on.astype(np.float64)


@dataclass(frozen=True)
class ImportSpec:
    """What to do with a recorder export. Nothing here is guessed from the file.

    columns: capture name (`efd` required, `usetp`, `vt`) -> source column / channel name.
    Time: `time_column` (s), or `clock_column` (HH:MM:SS.ffff) with an optional `date_column`
    (`date_format`, strptime); CSV only - COMTRADE brings its own time.
    delimiter / decimal (`.` or `,`) / header_line: how the CSV is written.
    efd_base_scale: efd is multiplied by it (rated-field base -> model base).
    scale: factors for `usetp` / `vt` (e.g. kV -> pu).
    resample_hz: resample onto this rate (linear interpolation); None refuses jitter.
    test: the test, needed when `usetp` is not mapped (then synthesised), recorded always.
    keep_columns: other source columns to keep as extra capture columns (numeric).
    """

    columns: Mapping[str, str]
    time_column: str | None = None
    date_column: str | None = None
    clock_column: str | None = None
    date_format: str = "%Y-%m-%d"
    delimiter: str = ","
    decimal: str = "."
    header_line: int = 1
    efd_base_scale: float = 1.0
    scale: Mapping[str, float] = field(default_factory=dict)
    resample_hz: float | None = None
    test: TestDescription | None = None
    keep_columns: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        comtrade_io.check_mapping(self.columns, required=("efd",))
        if "usetp" not in self.columns and self.test is None:
            raise ValueError("no usetp column mapped and no test description to synthesise it")
        if len(self.delimiter) != 1 or self.delimiter in "\"\r\n":
            raise ValueError(f"delimiter must be one character, got {self.delimiter!r}")
        if self.decimal not in (".", ","):
            raise ValueError(f"decimal must be '.' or ',', got {self.decimal!r}")
        if self.decimal == self.delimiter:
            raise ValueError("a decimal comma needs a delimiter other than ','")
        _finite(self.efd_base_scale, "efd_base_scale", nonzero=True)
        for our, factor in self.scale.items():
            if our == "efd":
                raise ValueError("scale efd with efd_base_scale")
            if our not in self.columns:
                raise ValueError(f"scale given for {our!r}, which is not mapped")
            _finite(factor, f"scale for {our!r}", nonzero=True)
        if self.resample_hz is not None:
            _finite(self.resample_hz, "resample_hz", positive=True)
        clash = set(self.keep_columns) & (set(self.columns.values()) | {"time", "usetp", "efd",
                                                                          "vt"})
        if clash:
            raise ValueError(f"keep_columns {sorted(clash)} are mapped or capture names")
        object.__setattr__(self, "columns", MappingProxyType(dict(self.columns)))
        object.__setattr__(self, "scale", MappingProxyType(dict(self.scale)))
        object.__setattr__(self, "keep_columns", tuple(self.keep_columns))


def _read_source(src: Path, spec: ImportSpec) -> tuple[RawRecord, dict[str, Any]]:
    """The source as a RawRecord of source-named columns, and the sidecar's source block."""
    block: dict[str, Any] = {"path": str(src.resolve()), "sha256": sha256_file(src)}
    if src.suffix.lower() == ".cfg":
        if spec.time_column or spec.date_column or spec.clock_column:
            raise ValueError("a COMTRADE record brings its own time: no time/date/clock column")
        table = comtrade_io.load_comtrade_table(src, uniform=False)  # checked below, or resampled
        scaled = {"efd"} if spec.efd_base_scale != 1.0 else set()
        cols = {ch: comtrade_io.channel_values(table, our, ch, our in scaled | set(spec.scale))
                for our, ch in spec.columns.items()}
        for name in spec.keep_columns:
            cols[name] = comtrade_io.channel_values(table, name, name, scaled=True)
        unused = tuple(k for k in (*table.analog, *table.status) if k not in cols)
        block.update(format="comtrade", comtrade=table.info)
        rec = RawRecord(file=table.dat_file, time=table.time, columns=cols,
                        rows=np.arange(1, table.time.size + 1), row_kind=table.row_kind,
                        time_info={"method": "comtrade sample rate / timestamps",
                                   "origin": f"as in the record: the first sample at "
                                             f"{float(table.time[0])!r} s"},
                        unused_columns=unused)
        return rec, block
    rec = read_vendor_csv(src, columns=[*spec.columns.values(), *spec.keep_columns],
                          time_column=spec.time_column, date_column=spec.date_column,
                          clock_column=spec.clock_column, date_format=spec.date_format,
                          delimiter=spec.delimiter, decimal=spec.decimal,
                          header_line=spec.header_line)
    block.update(format="csv", delimiter=spec.delimiter, decimal=spec.decimal,
                 header_line=spec.header_line)
    return rec, block


def _resample(rec: RawRecord, rate_hz: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    d = np.diff(rec.time)
    median = float(np.median(d))
    gaps = np.flatnonzero(d > MAX_GAP_RATIO * median)
    if gaps.size:
        i = int(gaps[0])
        raise CaptureError(rec.file, f"gap of {d[i]:.9g} s before this {rec.row_kind} (median "
                           f"step {median:.9g} s): a dropout is not interpolated across",
                           row=int(rec.rows[i + 1]), row_kind=rec.row_kind,
                           column=rec.time_column)
    return resample_linear(rec.time, rec.columns, rate_hz)


def import_export(
    src_path: str | os.PathLike[str], spec: ImportSpec, out_csv_path: str | os.PathLike[str]
) -> Capture:
    """Import `src_path` as described by `spec`, write the capture to `out_csv_path` (+ its
    sidecar; never over an existing one) and return it as read back from disk."""
    src = Path(src_path)
    rec, source_block = _read_source(src, spec)
    where = {"file": rec.file, "rows": rec.rows, "row_kind": rec.row_kind,
             "column": rec.time_column}
    check_time(rec.time, uniform=False, **where)
    stats = step_stats(rec.time)
    resampled: dict[str, Any] | bool = False
    if spec.resample_hz is not None:
        time, cols = _resample(rec, spec.resample_hz)
        resampled = {"from_step_s": stats, "from_samples": int(rec.time.size),
                     "to_rate_hz": spec.resample_hz, "to_samples": int(time.size),
                     "method": RESAMPLE_METHOD}
    else:
        check_time(rec.time, **where)
        time, cols = rec.time, dict(rec.columns)
    data: dict[str, np.ndarray] = {"time": time}
    for our, name in spec.columns.items():
        factor = spec.efd_base_scale if our == "efd" else spec.scale.get(our, 1.0)
        data[our] = cols[name] * factor
    if "usetp" not in data:
        assert spec.test is not None
        data["usetp"] = spec.test.usetp(time, file=str(src))
    for name in spec.keep_columns:
        data[name] = cols[name]
    test = None if spec.test is None else {**asdict(spec.test), "source": "user description"}
    meta: dict[str, Any] = {
        "units": {"time": "s", **{our: "pu" for our in ("usetp", "efd", "vt") if our in data}},
        "import": {
            "source": source_block,
            "columns": dict(spec.columns),
            "kept_columns": list(spec.keep_columns),
            "dropped_columns": list(c for c in rec.unused_columns
                                    if c not in spec.keep_columns),
            "time": rec.time_info,
            "source_step_s": stats,
            "efd_base_scale": spec.efd_base_scale,
            "scale": {"efd": spec.efd_base_scale, **spec.scale},
            "resampled": resampled,
            "usetp_synthesised": "usetp" not in spec.columns,
            "test": test,
        },
    }
    if test is not None:
        meta["test"] = test
    # the checks identify, diagnose and report make, before anything is written: a time axis in
    # ms, a broken cell (1e308), a test description that is not this record's (whether the record
    # holds a test at all, a moving setpoint and a responding efd, is the fits' to refuse)
    draft = Capture(time=time, usetp=data["usetp"], efd=data["efd"], vt=data.get("vt"), meta=meta,
                    source=rec.file)
    n = int(np.asarray(time).size)
    err = implausible(draft, rows=np.arange(1, n + 1) if resampled else rec.rows,
                      row_kind="resampled sample" if resampled else rec.row_kind, test_where="--test",
                      response=False)
    if err is not None:
        if err.column in spec.columns:   # the source's column, as every other refusal names it
            raise CaptureError(err.file, err.reason, row=err.row, column=spec.columns[err.column],
                               row_kind=rec.row_kind if not resampled else "resampled sample",
                               column_kind="channel" if source_block.get("format") == "comtrade" else "column")
        raise err
    csv_path, _ = write_capture(out_csv_path, data, meta)
    log.info("imported %s -> %s (%s)", src, csv_path,
             "resampled" if resampled else "not resampled")
    return read_capture(csv_path)
