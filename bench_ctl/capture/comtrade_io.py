"""COMTRADE (IEEE C37.111 .cfg + .dat) records read as captures, through a channel mapping.

Parsing is the PyPI `comtrade` package's; this module checks what that package lets pass
(a .dat shorter or longer than the .cfg declares, non-numeric ASCII fields, missing values,
several sample rates, channel time skew, units) and names the file, row or sample, and channel.
Time is the package's: from the sample rate, or from the sample timestamps when the .cfg
declares no rate; t = 0 at the first sample, the trigger time goes into `meta`.
"""
from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import comtrade
import numpy as np

from bench_ctl.capture.capture import PER_UNIT_SPELLINGS, Capture, sha256_bytes
from bench_ctl.capture.errors import CaptureError, SpecError, shown, shown_names
from bench_ctl.capture.table import decode_utf8, read_limited
from bench_ctl.capture.timebase import check_time

log = logging.getLogger(__name__)

#: what a channel can be mapped to: the capture columns and the named channels (capture.CHANNEL_UNITS)
CAPTURE_CHANNELS = ("usetp", "efd", "vt", "ifd", "p", "q", "vr", "vs")
_ANALOG_BYTES = {"BINARY": 2, "BINARY32": 4, "FLOAT32": 4}
_PARSE_ERRORS = (comtrade.ComtradeError, ValueError, IndexError, KeyError, TypeError)


@dataclass(frozen=True)
class ComtradeTable:
    """Every channel of a record, by channel name (a repeated name gets `#n`, its number)."""

    file: str  # the .cfg
    dat_file: str
    time: np.ndarray
    analog: dict[str, np.ndarray]
    status: dict[str, np.ndarray]
    channel_info: dict[str, dict[str, Any]]  # analog channel key -> n, unit, a, b, skew...
    info: dict[str, Any]  # record-level facts for the sidecar
    row_kind: str  # "row" (ASCII .dat line) or "sample" (binary)
    names: dict[str, list[str]] = field(default_factory=dict)  # channel name -> its keys

    def row(self, i: int) -> int:
        return i + 1  # no header in a .dat: line number == sample number


def _dat_path(cfg: Path) -> Path:
    ext = ".DAT" if cfg.suffix.isupper() else ".dat"
    return cfg.with_suffix(ext)


MISSING_ASCII = "99999"  # C37.111-1999: no data for this analog sample (ASCII files)


def _number(text: str) -> bool:
    try:
        return math.isfinite(float(text)) and "_" not in text
    except ValueError:
        return False


def _prescan_ascii(dat: str, text: str, cfg: comtrade.Cfg, total: int) -> None:
    names = [ch.name for ch in cfg.analog_channels]
    n_fields = 2 + cfg.analog_count + cfg.status_count
    lines = text.splitlines()
    while lines and not lines[-1].strip(" \t\x1a"):
        lines.pop()
    for lineno, line in enumerate(lines, start=1):
        fields = [f.strip() for f in line.split(",")]
        if len(fields) != n_fields:
            raise CaptureError(dat, f"{len(fields)} fields, the .cfg declares {n_fields} "
                               f"(sample number, timestamp, {cfg.analog_count} analog, "
                               f"{cfg.status_count} status)", row=lineno)
        if not fields[0].isdigit():
            raise CaptureError(dat, f"sample number {shown(fields[0])} is not an integer",
                               row=lineno)
        for k, name in enumerate(names):
            if fields[2 + k] == MISSING_ASCII and cfg.rev_year and int(cfg.rev_year) >= 1999:
                # the package compares the unstripped field: a padded 99999 would become data
                raise CaptureError(dat, "missing value (99999)", row=lineno, column=name,
                                   column_kind="channel")
            if not _number(fields[2 + k]):
                raise CaptureError(dat, f"not a number: {shown(fields[2 + k])}", row=lineno,
                                   column=name, column_kind="channel")
    if len(lines) != total:
        raise CaptureError(dat, f"{len(lines)} samples, the .cfg declares {total}")


def _prescan_binary(dat: str, size: int, cfg: comtrade.Cfg, total: int) -> None:
    row_size = 8 + cfg.analog_count * _ANALOG_BYTES[cfg.ft.upper()] \
        + 2 * math.ceil(cfg.status_count / 16)
    if size != total * row_size:
        raise CaptureError(dat, f"{size} bytes, the .cfg declares {total} samples of "
                           f"{row_size} bytes ({total * row_size} bytes)")


def _key(name: str, n: int, taken: set[str]) -> str:
    key = name if name and name not in taken and name not in ("time",) + CAPTURE_CHANNELS \
        else f"{name}#{n}"
    taken.add(key)
    return key


def load_comtrade_table(cfg_path: str | os.PathLike[str], *, uniform: bool = True) -> ComtradeTable:
    """Parse and check a .cfg and its .dat (same name); no mapping, no unit checks yet.
    `uniform` False accepts a jittered time base (an import that resamples checks it itself)."""
    cfg_file = Path(cfg_path)
    file = str(cfg_file)
    if cfg_file.suffix.lower() != ".cfg":
        raise CaptureError(file, "expected a COMTRADE .cfg file")
    dat_file = _dat_path(cfg_file)
    if not dat_file.exists():
        raise CaptureError(str(dat_file), "data file missing (the .dat beside the .cfg)")
    cfg_bytes, dat_bytes = read_limited(cfg_file), read_limited(dat_file)
    cfg_text = decode_utf8(file, cfg_bytes)
    cfg = comtrade.Cfg(ignore_warnings=True)
    try:
        cfg.read(cfg_text)
    except _PARSE_ERRORS as exc:
        raise CaptureError(file, f"cannot parse the .cfg: {exc}") from None
    ft = cfg.ft.upper()
    if ft not in ("ASCII",) + tuple(_ANALOG_BYTES):
        raise CaptureError(file, f"unsupported .dat file type {cfg.ft!r}")
    rates = [float(s) for s, _ in cfg.sample_rates]
    if len(set(rates)) > 1:
        raise CaptureError(file, f"several sample rates {rates}; a capture needs one step")
    total = int(cfg.sample_rates[-1][1])
    dat = str(dat_file)
    if ft == "ASCII":
        dat_content: str | bytes = decode_utf8(dat, dat_bytes)
        _prescan_ascii(dat, dat_content, cfg, total)
    else:
        dat_content = dat_bytes
        _prescan_binary(dat, len(dat_bytes), cfg, total)
    rec = comtrade.Comtrade(ignore_warnings=True, use_numpy_arrays=True,
                            use_double_precision=True)
    try:
        rec.read(cfg_text, dat_content)
    except _PARSE_ERRORS as exc:
        raise CaptureError(dat, f"cannot parse the .dat: {exc}") from None
    row_kind = "row" if ft == "ASCII" else "sample"
    time = np.asarray(rec.time, dtype=np.float64)
    check_time(time, file=dat, rows=np.arange(1, time.size + 1), row_kind=row_kind,
               column="timestamp" if cfg.timestamp_critical else "time", uniform=uniform)
    taken: set[str] = set()
    analog: dict[str, np.ndarray] = {}
    info: dict[str, dict[str, Any]] = {}
    names: dict[str, list[str]] = {}
    for ch, values in zip(cfg.analog_channels, rec.analog):
        key = _key(ch.name, ch.n, taken)
        analog[key] = np.asarray(values, dtype=np.float64)
        names.setdefault(ch.name, []).append(key)
        info[key] = {"channel": ch.name, "n": ch.n, "unit": ch.uu, "a": ch.a, "b": ch.b,
                     "skew_us": ch.skew, "primary": ch.primary, "secondary": ch.secondary,
                     "ps": ch.pors}
    status = {_key(ch.name, ch.n, taken): np.asarray(v, dtype=np.float64)
              for ch, v in zip(cfg.status_channels, rec.status)}
    record = {
        "cfg": file, "cfg_sha256": sha256_bytes(cfg_bytes),
        "dat": dat, "dat_sha256": sha256_bytes(dat_bytes),
        "station_name": cfg.station_name, "rec_dev_id": cfg.rec_dev_id,
        "rev_year": cfg.rev_year, "ft": cfg.ft, "frequency_hz": cfg.frequency,
        "sample_rates": [[float(s), int(e)] for s, e in cfg.sample_rates],
        "timestamp_critical": cfg.timestamp_critical, "time_multiplier": cfg.timemult,
        "start_timestamp": cfg.start_timestamp.isoformat(),
        "trigger_timestamp": cfg.trigger_timestamp.isoformat(),
        "trigger_time_s": rec.trigger_time,
    }
    return ComtradeTable(file=file, dat_file=dat, time=time, analog=analog, status=status,
                         channel_info=info, info=record, row_kind=row_kind, names=names)


def channel_values(table: ComtradeTable, our: str, channel: str, scaled: bool) -> np.ndarray:
    """The analog channel `channel` for capture column `our`, checked: it exists once, has no
    time skew, no missing values, and a per-unit unit unless `scaled` (converted by the
    caller's factor)."""
    keys = table.names.get(channel)
    if not keys:
        near = [n for n in table.names if n.lower() == channel.lower()]
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise CaptureError(table.file, f"no analog channel of that name for {our!r}{hint}; "
                           f"available: {shown_names(tuple(table.names)) if table.names else 'none'}",
                           column=channel, column_kind="channel")
    if len(keys) > 1:
        raise CaptureError(table.file, f"{len(keys)} analog channels have this name; the "
                           "mapping is ambiguous", column=channel, column_kind="channel")
    info = table.channel_info[keys[0]]
    if info["skew_us"]:
        raise CaptureError(table.file, f"time skew {info['skew_us']} us: channels are not "
                           "shifted in time here; align the record first",
                           column=channel, column_kind="channel")
    unit = str(info["unit"]).strip()
    if not scaled and unit.lower() not in PER_UNIT_SPELLINGS:  # a blank unit is not pu either
        raise CaptureError(table.file, f"unit {unit!r} is not per-unit; give a scale factor "
                           f"for {our!r} to convert it to pu", column=channel,
                           column_kind="channel")
    values = table.analog[keys[0]]
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        i = int(bad[0])
        raise CaptureError(table.dat_file, "missing value", row=table.row(i), column=channel,
                           row_kind=table.row_kind, column_kind="channel")
    return values


def _check_factors(scale: Mapping[str, float], mapping: Mapping[str, str]) -> None:
    for our, factor in scale.items():
        if our not in mapping:
            raise SpecError(f"scale given for {our!r}, which is not mapped")
        if isinstance(factor, bool) or not isinstance(factor, (int, float)) \
                or not math.isfinite(factor) or factor == 0:
            raise SpecError(f"scale for {our!r} must be a finite non-zero number, "
                             f"got {factor!r}")


def check_mapping(mapping: Mapping[str, str], required: tuple[str, ...]) -> None:
    for our in mapping:
        if our not in CAPTURE_CHANNELS:
            raise SpecError(f"mapping key {our!r}: expected one of {CAPTURE_CHANNELS}")
    for our in required:
        if our not in mapping:
            raise SpecError(f"mapping needs {our!r} (have {sorted(mapping)})")
    used = list(mapping.values())
    for name in used:
        if used.count(name) > 1:
            raise SpecError(f"channel {name!r} is mapped to more than one capture column")


def read_comtrade(
    cfg_path: str | os.PathLike[str],
    mapping: Mapping[str, str],
    *,
    scale: Mapping[str, float] | None = None,
) -> Capture:
    """A COMTRADE record as a Capture: `mapping` gives, for `usetp` and `efd` (required) and
    `vt`, `ifd`, `p`, `q`, `vr`, `vs` (optional), the analog channel name; `scale` multiplies a mapped channel after the
    .cfg's own a*x+b (needed for a channel whose unit is not pu). Unmapped analog and status
    channels become extra columns. A record without a setpoint channel is an import job
    (`bench_ctl.capture.importer` with a test description)."""
    scale = dict(scale or {})
    check_mapping(mapping, required=("usetp", "efd"))
    _check_factors(scale, mapping)
    table = load_comtrade_table(cfg_path)
    cols = {our: channel_values(table, our, ch, our in scale) * scale.get(our, 1.0)
            for our, ch in mapping.items()}
    mapped_keys = {table.names[ch][0] for ch in mapping.values()}
    extra = {k: v for k, v in table.analog.items() if k not in mapped_keys}
    extra.update(table.status)
    extra.update({our: v for our, v in cols.items() if our not in ("usetp", "efd", "vt")})
    meta = {
        "comtrade": table.info,
        "channels": {our: {**table.channel_info[table.names[ch][0]],
                           "scale": scale.get(our, 1.0)} for our, ch in mapping.items()},
        "units": {"time": "s", **{our: "pu" for our in mapping},
                  **{k: table.channel_info[k]["unit"] for k in extra if k in table.channel_info}},
    }
    log.debug("read COMTRADE %s: %d samples, mapping %s", table.file, table.time.size,
              dict(mapping))
    return Capture(time=table.time, usetp=cols["usetp"], efd=cols["efd"], vt=cols.get("vt"),
                   extra=extra, meta=meta, source=table.file)
