"""Import of a real recorder export (vendor CSV, or COMTRADE .cfg + .dat) as a capture.

Maps vendor column names to `usetp` / `efd` / `vt` and the named channels `ifd`, `p`, `q`, `vr`, `vs`,
builds time from a seconds column or from date + clock-time columns, puts efd (and ifd) on the
model's base (a factor, a base in volts or rated-field units, `auto` from the pre-step level at
no load, or the factor a no-load import found: `field_base`), synthesises `usetp` from a test
description when there is no setpoint channel - with its edges found in the record when the
description has no start (`found_test`) - and resamples (linear interpolation) only when asked:
jittered time without a resample request is refused with the row. A long export is cut to the
test's window when asked (`window`); a time base is rebuilt from the recorder's rate when asked
(`rate`: a clock a spreadsheet shortened is refused without it); a pre-step part that is not
steady is warned of, with a window that leaves it out (`steady`). A record with P and Q (or a
loaded P or Q) is of the unit on line: vt's amplitude check knows it, and the no-load base
(`auto`) is refused there. The record must pass the plausibility checks identify makes
(`bench_ctl.capture.plausible`: time unit, physical values, the test description) before it is
written; whether it holds a test at all is left to the commands that fit it. The sidecar's
`import` block records each of these steps.
"""
from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal

import numpy as np

from bench_ctl.capture import comtrade_io
from bench_ctl.capture.capture import CHANNEL_UNITS, Capture, read_capture, write_capture
from bench_ctl.capture.errors import CaptureError, SpecError
from bench_ctl.capture.field_base import EfdBase, NoLoad, auto_factor, explicit_block, from_no_load, pre_step
from bench_ctl.capture.found_test import FoundTest, find_test, tolerance_on
from bench_ctl.capture.held import HELD_TREATMENTS, held_channels, interpolated
from bench_ctl.capture.plausible import implausible
from bench_ctl.capture.steady import pre_step_steadiness
from bench_ctl.capture.timebase import check_time, resample_linear, step_stats
from bench_ctl.capture.vendor_csv import RawRecord, read_vendor_csv
from bench_ctl.capture.window import Window, cut
from bench_ctl.limits import sha256_file
from bench_ctl.signals.edges import SETPOINT, find_edges

log = logging.getLogger(__name__)

RESAMPLE_METHOD = "linear interpolation"
MAX_GAP_RATIO = 2.0  # a source step above this many median steps is a dropout, not jitter
#: a mapped P or Q whose median lies this far from zero (pu, or whatever --scale made it) is a
#: loaded unit's, on line (P and Q both mapped: on line whatever their level, as every fit reads it)
ON_LINE_MIN_PU = 0.02


def _finite(value: Any, what: str, *, positive: bool = False, nonzero: bool = False) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SpecError(f"{what} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise SpecError(f"{what} must be > 0, got {value!r}")
    if nonzero and value == 0:
        raise SpecError(f"{what} must not be 0")


@dataclass(frozen=True)
class TestDescription:
    """The test as the user describes it when the record has no setpoint channel.

    usetp = usetp0_pu, + amplitude_pu from start_s (capture time) on; for a pulse, back to
    usetp0_pu at start_s + width_s. A sample within 1e-6 steps of an edge counts as after it.
    The stated instants are nominal: fits search each edge within `edge_tolerance_s`.
    Without `start_s` the edges are found in the record (`found_test`; a pulse's width may then
    be left out too, or is checked against the found one).
    """

    __test__ = False  # not a pytest test class

    kind: Literal["step", "pulse"]
    amplitude_pu: float
    start_s: float | None = None
    width_s: float | None = None
    usetp0_pu: float = 1.0
    #: how far each edge may lie from the stated instant (s); None: one source sample. Every fit
    #: searches the edge instants within it (bench_ctl.identification.timing).
    edge_tolerance_s: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("step", "pulse"):
            raise SpecError(f"test kind must be 'step' or 'pulse', got {self.kind!r}")
        if self.start_s is not None:
            _finite(self.start_s, "test start_s")
        _finite(self.amplitude_pu, "test amplitude_pu", nonzero=True)
        _finite(self.usetp0_pu, "test usetp0_pu")
        if self.kind == "pulse":
            if self.width_s is None and self.start_s is not None:
                raise SpecError("a pulse test needs width_s (or neither start nor width: both found)")
            if self.width_s is not None:
                _finite(self.width_s, "test width_s", positive=True)
        elif self.width_s is not None:
            raise SpecError("a step test has no width_s")
        if self.edge_tolerance_s is not None:
            _finite(self.edge_tolerance_s, "test edge_tolerance_s", positive=True)

    def usetp(self, time: np.ndarray, *, file: str = "<test description>") -> np.ndarray:
        """The setpoint on `time` (uniform). Refuses edges outside the record."""
        if self.start_s is None:
            raise SpecError("the test's start is not known yet: find it in the record first")
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

    columns: capture name (`efd` required, `usetp`, `vt`, `ifd`, `p`, `q`, `vr`, `vs`) -> source column /
    channel name.
    Time: `time_column` (s), or `clock_column` (HH:MM:SS.ffff) with an optional `date_column`
    (`date_format`, strptime); CSV only - COMTRADE brings its own time.
    delimiter / decimal (`.` or `,`) / header_line: how the CSV is written.
    efd_base_scale: efd is multiplied by it (rated-field base -> model base).
    efd_base: or the base: auto (from the pre-step level and `no_load`), volts or rated-field units.
    scale: factors for the other mapped channels (e.g. kV -> pu).
    ifd_auto: put ifd on the model's base from its pre-step level, as efd_base auto (`no_load`).
    no_load: the model's no-load field (Vt0, Sat) from the unit, needed by `auto`.
    resample_hz: resample onto this rate (linear interpolation); None refuses jitter.
    test: the test, needed when `usetp` is not mapped (then synthesised), recorded always.
    keep_columns: other source columns to keep as extra capture columns (numeric).
    window: the test's part of a long export (`bench_ctl.capture.window`), cut first.
    rate_hz: the recorder's rate: time rebuilt as k / rate and checked against the file's own
    time marks (CSV only; `bench_ctl.capture.rate`).
    ifd_from: the no-load capture whose `import.ifd_base` factor puts ifd on the model's base.
    held: a channel the recorder refreshes slower than it writes rows (`bench_ctl.capture.held`):
    "keep" its rows as written (a warning), or "interpolate" each repeated row between the fresh
    rows around it.
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
    efd_base: EfdBase | None = None
    scale: Mapping[str, float] = field(default_factory=dict)
    ifd_auto: bool = False
    no_load: NoLoad | None = None
    resample_hz: float | None = None
    test: TestDescription | None = None
    keep_columns: tuple[str, ...] = ()
    window: Window | None = None
    rate_hz: float | None = None
    ifd_from: str | None = None
    held: str = "keep"

    def __post_init__(self) -> None:
        comtrade_io.check_mapping(self.columns, required=("efd",))
        if "usetp" not in self.columns and self.test is None:
            raise SpecError("no usetp column mapped and no test description to synthesise it")
        if len(self.delimiter) != 1 or self.delimiter in "\"\r\n":
            raise SpecError(f"delimiter must be one character, got {self.delimiter!r}")
        if self.decimal not in (".", ","):
            raise SpecError(f"decimal must be '.' or ',', got {self.decimal!r}")
        if self.decimal == self.delimiter:
            raise SpecError("a decimal comma needs a delimiter other than ','")
        _finite(self.efd_base_scale, "efd_base_scale", nonzero=True)
        if self.efd_base is not None and self.efd_base_scale != 1.0:
            raise SpecError("give either the efd base or efd_base_scale, not both")
        if self.ifd_auto and ("ifd" not in self.columns or "ifd" in self.scale):
            raise SpecError("ifd auto needs ifd mapped and no other scale for it")
        if self.ifd_from is not None and ("ifd" not in self.columns or "ifd" in self.scale or self.ifd_auto):
            raise SpecError("ifd from a no-load import needs ifd mapped and no other scale for it")
        if self.rate_hz is not None:
            _finite(self.rate_hz, "rate_hz", positive=True)
        if self.held not in HELD_TREATMENTS:
            raise SpecError(f"held {self.held!r}: choose {' or '.join(HELD_TREATMENTS)}")
        if (self.ifd_auto or (self.efd_base is not None and self.efd_base.mode == "auto")) \
                and self.no_load is None:
            raise SpecError("an auto base needs the unit's no-load field (no_load)")
        for our, factor in self.scale.items():
            if our == "efd":
                raise SpecError("scale efd with efd_base_scale")
            if our not in self.columns:
                raise SpecError(f"scale given for {our!r}, which is not mapped")
            _finite(factor, f"scale for {our!r}", nonzero=True)
        if self.resample_hz is not None:
            _finite(self.resample_hz, "resample_hz", positive=True)
        clash = set(self.keep_columns) & (set(self.columns.values()) | {"time", "usetp", "efd", "vt",
                                                                          *CHANNEL_UNITS})
        if clash:
            raise SpecError(f"keep_columns {sorted(clash)} are mapped or capture names")
        object.__setattr__(self, "columns", MappingProxyType(dict(self.columns)))
        object.__setattr__(self, "scale", MappingProxyType(dict(self.scale)))
        object.__setattr__(self, "keep_columns", tuple(self.keep_columns))


def _read_source(src: Path, spec: ImportSpec) -> tuple[RawRecord, dict[str, Any]]:
    """The source as a RawRecord of source-named columns, and the sidecar's source block."""
    block: dict[str, Any] = {"path": str(src.resolve()), "sha256": sha256_file(src)}
    if src.suffix.lower() == ".cfg":
        if spec.time_column or spec.date_column or spec.clock_column or spec.rate_hz is not None:
            raise SpecError("a COMTRADE record brings its own time and rate: no time/date/clock column, no --rate")
        table = comtrade_io.load_comtrade_table(src, uniform=False)  # checked below, or resampled
        scaled = ({"efd"} if spec.efd_base_scale != 1.0 or spec.efd_base is not None else set()) \
            | ({"ifd"} if spec.ifd_auto or spec.ifd_from is not None else set())
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
                          header_line=spec.header_line, rate_hz=spec.rate_hz)
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


def on_line_of(spec: ImportSpec, raw: Mapping[str, np.ndarray]) -> dict[str, Any] | None:
    """Whether the record is of the unit on line (the sidecar's `import.on_line`; None: not, or it
    cannot tell): P and Q both mapped, or one of them with a median at least ON_LINE_MIN_PU away
    from zero (a loaded unit)."""
    have = {k: float(np.median(raw[k])) for k in ("p", "q") if k in raw}
    loaded = [k for k, v in have.items() if abs(v) >= ON_LINE_MIN_PU]
    if len(have) < 2 and not loaded:
        return None
    why = "P and Q recorded" if len(have) == 2 else f"{loaded[0].upper()} away from zero"
    medians = {"p_median": have.get("p"), "q_median": have.get("q")}   # the sidecar's keys
    return {**{k: v for k, v in medians.items() if v is not None},
            "columns": {k: spec.columns[k] for k in have}, "why": why}


def _the_test(file: str, spec: ImportSpec, rec: RawRecord, raw: Mapping[str, np.ndarray],
              grid: np.ndarray, on_line: bool = False, origin_s: float | None = None
              ) -> tuple[TestDescription | None, FoundTest | None]:
    """The test to synthesise usetp from: as described, or with its edges found in the record
    (no start given); None when usetp is recorded."""
    test = spec.test
    if "usetp" in spec.columns or test is None or test.start_s is not None:
        return test, None
    channels = {k: v for k, v in raw.items() if k in ("vr", "efd", "vt", "ifd")}
    found = find_test(file, rec.time, channels, kind=test.kind, amplitude_pu=test.amplitude_pu,
                      width_s=test.width_s, columns=spec.columns, rows=rec.rows, on_line=on_line,
                      origin_s=origin_s)
    tol = max(tolerance_on(grid, found.edges), test.edge_tolerance_s or 0.0)
    found.block["tolerance_s"] = tol
    found.block["tolerance_given_s"] = test.edge_tolerance_s
    return TestDescription(kind=found.kind, amplitude_pu=test.amplitude_pu,  # type: ignore[arg-type]
                           start_s=found.start_s, width_s=found.width_s, usetp0_pu=test.usetp0_pu,
                           edge_tolerance_s=tol), found


def _first_edge_lo(test: TestDescription | None, found: FoundTest | None, rec: RawRecord,
                   raw: Mapping[str, np.ndarray], source_step: float) -> float | None:
    """The earliest instant of the first setpoint edge: found, described, or in the recorded usetp."""
    if found is not None:
        return found.first_lo_s
    if "usetp" in raw:
        lead, _ = find_edges(rec.time, raw["usetp"], kind=SETPOINT).pulse()
        return None if lead is None else lead.earliest_s
    if test is not None and test.start_s is not None:
        return test.start_s - (test.edge_tolerance_s or source_step)
    return None


def _not_on_line(file: str, what: str, on_line: dict[str, Any]) -> CaptureError:
    """The refusal of a no-load base (`auto`) on a record of the unit on line."""
    level = ", ".join(f"{k[0].upper()} {v:.4g}" for k, v in on_line.items() if k.endswith("_median"))
    option = "--efd-base auto" if what == "efd" else "--scale ifd=auto"
    given = "--efd-base from:NOLOAD.csv (or the base itself: <X>V, <X>rf)" if what == "efd" else \
        "--scale ifd=from:NOLOAD.csv (or its factor: --scale ifd=K)"
    return CaptureError(file, f"{option}: the record is of the unit on line ({on_line['why']}: {level}, medians in the "
                        f"columns' units): the no-load base {what}0 = Vt0 + Sat(Vt0) does not hold for a loaded unit, "
                        f"whose field is larger (armature reaction). Import the unit's no-load step with {option} and "
                        f"give that import here: {given}")


def _field_factors(file: str, spec: ImportSpec, rec: RawRecord, raw: Mapping[str, np.ndarray],
                   edge_lo: float | None, on_line: dict[str, Any] | None = None
                   ) -> tuple[dict[str, float], dict[str, Any], dict[str, Any] | None]:
    """The factors of efd (and ifd when auto) and the sidecar blocks saying how they were found."""
    auto = spec.efd_base is not None and spec.efd_base.mode == "auto"
    if on_line is not None and (auto or spec.ifd_auto):
        raise _not_on_line(file, "efd" if auto else "ifd", on_line)
    if (auto or spec.ifd_auto) and edge_lo is None:
        raise CaptureError(file, "no setpoint edge in the record: an auto base needs the pre-step part")
    vt_pre = None
    if "vt" in raw and edge_lo is not None:
        try:
            vt_pre = float(np.mean(pre_step(file, rec.time, raw["vt"], edge_lo, "vt")))
        except CaptureError:
            if auto or spec.ifd_auto:
                raise
    col = spec.columns
    if auto:
        assert spec.no_load is not None and edge_lo is not None
        efd, efd_block = auto_factor(file, "efd", col["efd"], rec.time, raw["efd"], edge_lo, spec.no_load, vt_pre)
    else:
        base = spec.efd_base
        made = None
        if base is not None and base.mode == "from":
            efd, made = from_no_load(base, "efd", col["efd"])
        else:
            efd = spec.efd_base_scale if base is None else 1.0 / float(base.value)  # type: ignore[arg-type]
        efd_block = explicit_block(base, efd, file=file, time=rec.time, x=rec.columns[col["efd"]], edge_lo_s=edge_lo,
                                   no_load=spec.no_load, vt_pre=vt_pre, block=made, on_line=on_line is not None)
    factors = {"efd": efd}
    ifd_block = None
    if spec.ifd_auto:
        assert spec.no_load is not None and edge_lo is not None
        factors["ifd"], ifd_block = auto_factor(file, "ifd", col["ifd"], rec.time, raw["ifd"], edge_lo,
                                                spec.no_load, vt_pre)
    elif spec.ifd_from is not None:
        factors["ifd"], ifd_block = from_no_load(EfdBase("from", path=spec.ifd_from), "ifd", col["ifd"])
    return factors, efd_block, ifd_block


def import_export(
    src_path: str | os.PathLike[str], spec: ImportSpec, out_csv_path: str | os.PathLike[str]
) -> Capture:
    """Import `src_path` as described by `spec`, write the capture to `out_csv_path` (+ its
    sidecar; never over an existing one) and return it as read back from disk."""
    src = Path(src_path)
    file = str(src)
    rec, source_block = _read_source(src, spec)
    origin_s = float(rec.time[0])                 # the export's first sample (windows count from it)
    check_time(rec.time, uniform=False, file=rec.file, rows=rec.rows, row_kind=rec.row_kind,
               column=rec.time_column)
    window_block = None
    if spec.window is not None:
        rec, window_block = cut(rec, spec.window, file)
    # a channel refreshed slower than the rows, on the rows as written; with `held` interpolate,
    # its repeated rows put between the fresh ones before anything else reads it
    held = held_channels({our: rec.columns[name] for our, name in spec.columns.items()}, spec.columns)
    held["treatment"] = spec.held
    if spec.held == "interpolate" and held["held"]:
        fixed = {spec.columns[c]: interpolated(rec.time, rec.columns[spec.columns[c]]) for c in held["held"]}
        rec = replace(rec, columns={**rec.columns, **fixed})
    where = {"file": rec.file, "rows": rec.rows, "row_kind": rec.row_kind,
             "column": rec.time_column}
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
    # the mapped channels on the source's own time stamps, scaled (efd and ifd only by the sign
    # of their factor: their base is found below): where the edges are found
    raw = {our: rec.columns[name] * spec.scale.get(our, 1.0) for our, name in spec.columns.items()}
    raw["efd"] = raw["efd"] * math.copysign(1.0, spec.efd_base_scale)
    on_line = on_line_of(spec, raw)
    test, found = _the_test(file, spec, rec, raw, time, on_line is not None, origin_s)
    edge_lo = _first_edge_lo(test, found, rec, raw, stats["median_s"])
    factors, efd_block, ifd_block = _field_factors(file, spec, rec, raw, edge_lo, on_line)
    steady = None
    if edge_lo is not None:
        hi = found.edges[0].latest_s if found is not None else edge_lo
        steady = pre_step_steadiness(rec.time, raw, spec.columns, edge_lo, hi, float(rec.time[-1]), origin_s)
    data: dict[str, np.ndarray] = {"time": time}
    for our, name in spec.columns.items():
        data[our] = cols[name] * factors.get(our, spec.scale.get(our, 1.0))
    if "usetp" not in data:
        assert test is not None
        data["usetp"] = test.usetp(time, file=file)
    for name in spec.keep_columns:
        data[name] = cols[name]
    source = "found in the record" if found is not None else "user description"
    test_meta = None if test is None else {**asdict(test), "source": source}
    meta: dict[str, Any] = {
        "units": {"time": "s", **{our: "pu" for our in ("usetp", "efd", "vt", *CHANNEL_UNITS)
                                  if our in data}},
        "import": {
            "source": source_block,
            "columns": dict(spec.columns),
            "kept_columns": list(spec.keep_columns),
            "dropped_columns": list(c for c in rec.unused_columns
                                    if c not in spec.keep_columns),
            "time": rec.time_info,
            "source_step_s": stats,
            "efd_base_scale": factors["efd"],
            "efd_base": efd_block,
            "scale": {**spec.scale, **factors},
            "resampled": resampled,
            "usetp_synthesised": "usetp" not in spec.columns,
            "test": test_meta,
            "window": window_block,
            "on_line": on_line,
            "pre_step_steady": steady,
            "held_samples": held,
        },
    }
    if ifd_block is not None:
        meta["import"]["ifd_base"] = ifd_block
    if found is not None:
        meta["import"]["edges_found"] = found.block
    if test_meta is not None:
        meta["test"] = test_meta
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
