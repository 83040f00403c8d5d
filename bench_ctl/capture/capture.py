"""The capture: what the recorder produced and what identification reads (docs/formats.md).

On disk a capture is `NAME.csv` (UTF-8, comma-separated, one header row; `time` in s with a
uniform increasing step, `usetp` and `efd` in pu, optional `vt` in pu, the optional named
channels `ifd`, `p`, `q`, `vr`, `vs` in pu, other columns kept) and
an optional `NAME.json` sidecar whose `csv_sha256` pins the CSV. `read_capture` refuses bad
input with a `CaptureError` naming file, row and column, and repairs nothing; `write_capture`
never overwrites an existing capture and writes each file atomically.
"""
from __future__ import annotations

import csv
import errno
import hashlib
import io
import json
import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import bench_ctl
from bench_ctl import outputs
from bench_ctl.capture.errors import CaptureError, SpecError, shown_names
from bench_ctl.capture.table import decode_utf8, parse_numeric, read_limited, read_text_table, try_numeric
from bench_ctl.capture.timebase import check_time, step_tolerance
from bench_ctl.limits import sha256_file
from bench_ctl.timestamps import utc_now_text

log = logging.getLogger(__name__)

SCHEMA = "bench-ctl/capture/1"
REQUIRED_COLUMNS = ("time", "usetp", "efd")
OPTIONAL_COLUMNS = ("vt",)
CAPTURE_UNITS = {"time": "s", "usetp": "pu", "efd": "pu", "vt": "pu"}
#: optional named channels, kept in `Capture.extra` but numeric, finite and per unit like the
#: capture columns: the field current (air-gap-line base), active and reactive power (machine
#: base), the regulator output (the regulator's own base; used to find edges, not fitted), the
#: stabiliser's output (the PSS's signal added to the voltage reference, on the AVR's base: fitted
#: on line with efd, Vt and Q)
CHANNEL_UNITS = {"ifd": "pu", "p": "pu", "q": "pu", "vr": "pu", "vs": "pu"}
NAMED_UNITS = {**CAPTURE_UNITS, **CHANNEL_UNITS}
PER_UNIT_SPELLINGS = {"pu", "p.u.", "p.u", "pu."}
# sidecar keys write_capture computes itself (values passed in `meta` are replaced)
COMPUTED_META_KEYS = ("schema", "software_version", "created_utc", "csv_sha256", "rate_hz",
                      "n_samples", "columns", "units")


def _frozen_array(values: Any, name: str, owner: str, numeric: bool = True) -> np.ndarray:
    arr = np.array(values, dtype=np.float64 if numeric else None, copy=True)
    if arr.ndim != 1:
        raise CaptureError(owner, f"must be 1-D, got shape {arr.shape}", column=name)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Capture:
    """One recorded test. Arrays are float64, 1-D, equal length and read-only.

    `extra` holds the other columns (float64 when numeric, else str); `meta` the sidecar
    content ({} when there is none); `source` the path it was read from or written to.
    """

    time: np.ndarray
    usetp: np.ndarray
    efd: np.ndarray
    vt: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        owner = self.source or "<capture in memory>"
        for name in ("time", "usetp", "efd", "vt"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _frozen_array(value, name, owner))
        extra: dict[str, np.ndarray] = {}
        for name, values in self.extra.items():
            if not isinstance(name, str) or not name or name != name.strip():
                raise CaptureError(owner, "extra column names must be non-empty and unpadded",
                                   column=str(name))
            if name in REQUIRED_COLUMNS + OPTIONAL_COLUMNS:
                raise CaptureError(owner, "an extra column may not reuse a capture column name",
                                   column=name)
            arr = np.asarray(values)
            extra[name] = _frozen_array(arr, name, owner, numeric=arr.dtype.kind in "biuf")
        object.__setattr__(self, "extra", extra)
        object.__setattr__(self, "meta", dict(self.meta))
        n = self.time.size
        for name, arr in self.columns().items():
            if arr.size != n:
                raise CaptureError(owner, f"{arr.size} samples, time has {n}", column=name)
        if n < 2:
            raise CaptureError(owner, f"{n} sample(s); a capture needs at least 2")

    def channel(self, name: str) -> np.ndarray | None:
        """A capture column or named channel (`ifd`, `p`, `q`, `vr`, `vs`), None when not recorded."""
        return self.columns().get(name)

    @property
    def on_line(self) -> bool:
        """An on-line record: P and Q recorded (the unit synchronised)."""
        return self.channel("p") is not None and self.channel("q") is not None

    def unit(self, name: str) -> str | None:
        """The unit of a column: the sidecar's, else the capture's own (pu for the named
        channels), None for an extra column of unknown unit."""
        units = self.meta.get("units") if isinstance(self.meta.get("units"), Mapping) else {}
        if name in units:
            return str(units[name])
        return NAMED_UNITS.get(name) if name in self.columns() else None

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.time.size)

    @property
    def dt(self) -> float:
        """The uniform time step (s)."""
        return float(self.time[-1] - self.time[0]) / (self.n - 1)

    @property
    def rate_hz(self) -> float:
        """Sample rate (Hz)."""
        return 1.0 / self.dt

    def columns(self) -> dict[str, np.ndarray]:
        """All columns in file order: time, usetp, efd, [vt], extras."""
        cols = {"time": self.time, "usetp": self.usetp, "efd": self.efd}
        if self.vt is not None:
            cols["vt"] = self.vt
        cols.update(self.extra)
        return cols


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def capture_sha256(path: str | os.PathLike[str] | None) -> str | None:
    """The SHA-256 of a capture file, the one hash every result and diagnosis records and the
    report verifies: the file's bytes on disk are the truth (docs/formats.md, "Capture"); a
    sidecar's `csv_sha256` is checked against them when the capture is read, never taken in their
    place. None when there is no file (a capture held in memory, or named by a label); an
    `InputError` naming a file that cannot be read."""
    if not path or not Path(path).is_file():
        return None
    return sha256_file(path, "a capture")


def sidecar_path(csv_path: str | os.PathLike[str]) -> Path:
    """NAME.json beside NAME.csv."""
    return Path(csv_path).with_suffix(".json")


def _read_sidecar(path: Path) -> dict[str, Any]:
    file = str(path)
    text = decode_utf8(file, read_limited(path, kind="a sidecar"))
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CaptureError(file, f"invalid JSON: {exc.msg} (char {exc.colno})",
                           row=exc.lineno) from None
    if not isinstance(meta, dict):
        raise CaptureError(file, f"the sidecar must be a JSON object, got {type(meta).__name__}")
    return meta


def _check_units(meta: Mapping[str, Any], file: str) -> None:
    """A sidecar may state units; for the capture columns they must be s and pu."""
    units = meta.get("units")
    if units is None:
        return
    if not isinstance(units, Mapping):
        raise CaptureError(file, f"units must be an object, got {units!r}",
                           column="units", column_kind="key")
    for name, unit in units.items():
        expected = NAMED_UNITS.get(name)
        accepted = {"s"} if expected == "s" else PER_UNIT_SPELLINGS
        if expected is not None and str(unit).strip().lower() not in accepted:
            raise CaptureError(file, f"unit {unit!r} for {name!r}: a capture holds {name} in "
                               f"{expected}", column=f"units.{name}", column_kind="key")


def _check_rate(meta: Mapping[str, Any], capture: Capture, file: str) -> None:
    if "rate_hz" not in meta:
        return
    rate = meta["rate_hz"]
    if isinstance(rate, bool) or not isinstance(rate, (int, float)):
        raise CaptureError(file, f"rate_hz must be a number, got {rate!r}",
                           column="rate_hz", column_kind="key")
    tol_hz = step_tolerance(capture.time, capture.dt) / capture.dt**2
    if abs(rate - capture.rate_hz) > tol_hz:
        ms = rate > 0 and 500.0 < rate / capture.rate_hz < 2000.0
        raise CaptureError(file, f"rate_hz {rate!r} disagrees with the time step of the CSV "
                           f"({capture.rate_hz!r} Hz){' (is the time column in ms?)' if ms else ''}",
                           column="rate_hz", column_kind="key")


def read_capture(path: str | os.PathLike[str]) -> Capture:
    """Read `NAME.csv` and, when present, its `NAME.json` sidecar. See the module docstring."""
    path = Path(path)
    file = str(path)
    data = read_limited(path)
    meta: dict[str, Any] = {}
    side = sidecar_path(path)
    if side != path and side.exists():
        meta = _read_sidecar(side)
        expected = meta.get("csv_sha256")
        if expected is not None and sha256_bytes(data) != str(expected).lower():
            raise CaptureError(file, f"SHA-256 {sha256_bytes(data)} does not match csv_sha256 "
                               f"{expected} in {side}: the CSV changed after it was written")
    table = read_text_table(file, decode_utf8(file, data), delimiter=",")
    for name in REQUIRED_COLUMNS:
        if name not in table.header:
            raise CaptureError(file, "missing required column; the header has "
                               f"{shown_names(table.header)}", row=table.header_line, column=name)
    if table.n_rows == 0:
        raise CaptureError(file, "header only, no data rows")
    arrays = {name: parse_numeric(table, name)
              for name in REQUIRED_COLUMNS + OPTIONAL_COLUMNS if name in table.header}
    extra: dict[str, np.ndarray] = {name: parse_numeric(table, name)
                                    for name in CHANNEL_UNITS if name in table.header}
    for name in table.header:
        if name not in arrays and name not in extra:
            values = try_numeric(table, name)
            extra[name] = values if values is not None else np.array(table.cells[name])
    check_time(arrays["time"], file=file, rows=table.lines)
    capture = Capture(time=arrays["time"], usetp=arrays["usetp"], efd=arrays["efd"],
                      vt=arrays.get("vt"), extra=extra, meta=meta, source=file)
    _check_rate(meta, capture, str(side))
    _check_units(meta, str(side))
    log.debug("read %s: %d samples at %g Hz", file, capture.n, capture.rate_hz)
    return capture


def _as_capture(data: Capture | Mapping[str, Any], source: str) -> Capture:
    if isinstance(data, Capture):
        return data
    missing = [c for c in REQUIRED_COLUMNS if c not in data]
    if missing:
        raise CaptureError(source, "missing required column", column=missing[0])
    extra = {k: v for k, v in data.items() if k not in REQUIRED_COLUMNS + OPTIONAL_COLUMNS}
    return Capture(time=data["time"], usetp=data["usetp"], efd=data["efd"], vt=data.get("vt"),
                   extra=extra, source=source)


def _validate_for_write(capture: Capture, file: str) -> None:
    rows = np.arange(capture.n) + 2  # the line each sample will have in the file
    for name in REQUIRED_COLUMNS + OPTIONAL_COLUMNS + tuple(CHANNEL_UNITS):
        arr = capture.channel(name)
        if arr is None:
            continue
        if arr.dtype.kind not in "biuf":
            raise CaptureError(file, "a named channel must be numeric", column=name)
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            i = int(bad[0])
            raise CaptureError(file, f"value {arr[i]!r} is not finite", row=int(rows[i]),
                               column=name)
    check_time(capture.time, file=file, rows=rows)


def _csv_bytes(capture: Capture) -> bytes:
    cols = capture.columns()
    text_cols = []
    for arr in cols.values():
        if arr.dtype.kind == "f":
            text_cols.append([repr(v) for v in arr.tolist()])  # shortest exact round trip
        else:
            text_cols.append([str(v) for v in arr.tolist()])
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(list(cols))
    writer.writerows(zip(*text_cols))
    return buf.getvalue().encode("utf-8")


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (Path, os.PathLike)):
        return os.fspath(obj)
    raise TypeError(f"sidecar value of type {type(obj).__name__} is not JSON-serialisable")


def _refuse(target: Path) -> FileExistsError:
    return FileExistsError(errno.EEXIST, "refusing to overwrite an existing capture file",
                           str(target))


def _write_new(target: Path, payload: bytes, overwrite: bool) -> None:
    """Write through `bench_ctl.outputs` (a temporary file in the same folder, linked into place
    or, with `overwrite`, renamed over it; never through a symbolic link; permissions as the
    umask gives). Readers never see a half-written file."""
    if not overwrite and os.path.lexists(target):
        raise _refuse(target)
    try:
        outputs.write_bytes(target, payload, force=overwrite)
    except outputs.OutputRefused:
        raise _refuse(target) from None


def write_capture(
    path: str | os.PathLike[str],
    data: Capture | Mapping[str, Any],
    meta: Mapping[str, Any] | None = None,
    *,
    overwrite: bool = False,
) -> tuple[Path, Path]:
    """Write `data` to `path` (must end in .csv) and its sidecar `NAME.json`; return both paths.

    `data` is a Capture or a mapping of column name -> values (`time`, `usetp`, `efd`
    required, `vt` optional, others become extra columns). `meta` (default: the Capture's own
    meta, or {}) goes into the sidecar beside the computed keys `schema`, `software_version`,
    `created_utc`, `csv_sha256`, `rate_hz`, `n_samples`, `columns`, `units` (s / pu for the
    capture columns, plus units given in meta for extra columns), which replace any given;
    a given `rate_hz` or capture-column unit that disagrees is refused.
    The data is checked as `read_capture` would (finite, increasing uniform time) before
    anything is written. Refuses with FileExistsError when the CSV or the sidecar exists,
    unless `overwrite` (meant for tests only).
    """
    path = Path(path)
    if path.suffix.lower() != ".csv":
        raise SpecError(f"{path}: a capture file name must end in .csv")
    json_path = sidecar_path(path)
    if not overwrite:
        for target in (path, json_path):
            if os.path.lexists(target):
                raise _refuse(target)
    capture = _as_capture(data, str(path))
    _validate_for_write(capture, str(path))
    if meta is None:
        meta = capture.meta
    given = f"{json_path} (meta given to write_capture)"
    if "rate_hz" in meta:
        _check_rate(meta, capture, given)
    _check_units(meta, given)
    units = {name: unit for name, unit in NAMED_UNITS.items() if name in capture.columns()}
    units.update({k: v for k, v in dict(meta.get("units") or {}).items() if k not in units})
    payload = _csv_bytes(capture)
    sidecar: dict[str, Any] = {
        "schema": SCHEMA,
        "software_version": bench_ctl.__version__,
        "created_utc": utc_now_text(),
        "csv_sha256": sha256_bytes(payload),
        "rate_hz": capture.rate_hz,
        "n_samples": capture.n,
        "columns": list(capture.columns()),
        "units": units,
    }
    sidecar.update({k: v for k, v in meta.items() if k not in COMPUTED_META_KEYS})
    json_payload = (json.dumps(sidecar, indent=2, allow_nan=False, default=_json_default)
                    + "\n").encode("utf-8")
    _write_new(path, payload, overwrite)
    try:
        _write_new(json_path, json_payload, overwrite)
    except BaseException:
        path.unlink()  # the CSV we just created; do not leave a capture without its sidecar
        raise
    log.info("wrote capture %s (%d samples at %g Hz) and %s", path, capture.n,
             capture.rate_hz, json_path)
    return path, json_path
