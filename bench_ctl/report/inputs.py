"""Reading what a report is made from: the result JSON, the optional diagnosis JSON, and the
captures the result names (checked against their SHA-256 before anything is simulated).

Everything refused here is a `ReportError` whose message names the file and the key or value;
the `report` command turns it into exit code 2. Nothing is repaired: a capture whose bytes do
not hash to the result's `sha256`, or whose sample count / rate disagree with the result, is
refused, because the report would otherwise certify a fit on data it was not made on.
"""
from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench_ctl.capture import Capture, CaptureError, capture_sha256, read_capture
from bench_ctl.capture.plausible import implausible
from bench_ctl.diagnosis.diagnosis_file import CaptureRef, Diagnosis, read_diagnosis
from bench_ctl.exitcodes import BadInput
from bench_ctl.identification.result_file import CaptureEntry, IdentificationResult, read_result
from bench_ctl.limits import InputError
from bench_ctl.model.params import KERNEL_PARAMS, PARAMS, neutral_values
from bench_ctl.records import FormatError

log = logging.getLogger(__name__)

class ReportError(BadInput):
    """Input a report cannot be made from; the message names the file and key."""


def load_result(path: str | os.PathLike[str]) -> IdentificationResult:
    """Read a result JSON file: every key checked (`IdentificationResult.from_json`)."""
    try:
        return read_result(path)
    except (InputError, FormatError) as exc:
        raise ReportError(str(exc)) from None


def load_diagnosis(path: str | os.PathLike[str]) -> Diagnosis:
    """Read a diagnosis JSON file: every key checked (`Diagnosis.from_json`)."""
    try:
        return read_diagnosis(path)
    except (InputError, FormatError) as exc:
        raise ReportError(str(exc)) from None


def check_result(result: IdentificationResult, where: str) -> None:
    """What the report needs beyond the format: at least one capture."""
    if not result.captures:
        raise ReportError(f"{where}: key 'captures' must be a non-empty list")


def model_values(params: Mapping[str, Any], fixed: Mapping[str, Any], where: str) -> dict[str, float]:
    """Every kernel parameter for the re-simulation: neutral effects, then `fixed` (null = the
    parameter's infinite neutral value, as the contract writes inf), then the identified `params`."""
    values: dict[str, float] = dict(neutral_values())
    for section, table in (("fixed", fixed), ("params", params)):
        for name, value in table.items():
            key = f"{where}: {section}.{name}"
            if name not in PARAMS:
                raise ReportError(f"{key}: unknown model parameter; known: {', '.join(PARAMS)}")
            if value is None:
                neutral = PARAMS[name].neutral
                if neutral is None or math.isfinite(neutral):
                    raise ReportError(f"{key}: null is only allowed for a parameter whose "
                                      "neutral value is infinite")
                values[name] = neutral
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value):
                raise ReportError(f"{key}: expected a number, got {value!r}")
            values[name] = float(value)
    missing = [n for n in KERNEL_PARAMS if n not in values]
    if missing:
        raise ReportError(f"{where}: no value for model parameter(s) {missing} in 'params' "
                          "or 'fixed'")
    return values


@dataclass(frozen=True)
class LoadedCapture:
    """One capture the result names, read and verified."""
    index: int
    path: Path
    sha256: str
    capture: Capture
    entry: CaptureEntry


def resolve_capture_path(raw: str, base_dir: Path | None) -> Path:
    """A capture path as written in the result: absolute; or relative to the result file's folder
    `base_dir` (as `identify --json` writes it); else, for a result written before that, relative
    to the current directory."""
    path = Path(raw)
    if path.is_absolute() or base_dir is None:
        return path
    beside = base_dir / path
    if beside.exists() or not path.exists():
        return beside
    return path


def outside(path: Path, roots: Sequence[Path]) -> bool:
    """Whether `path` (its real location, symbolic links followed) lies outside every folder of
    `roots`."""
    real = path.resolve()
    return not any(real.is_relative_to(Path(r).resolve()) for r in roots)


def load_captures(result: IdentificationResult, where: str,
                  base_dir: Path | None = None, confine: Sequence[Path] | None = None) -> list[LoadedCapture]:
    """Read every capture of the result, refusing a missing file, a SHA-256 / n / rate mismatch
    and a record that is not a plausible setpoint test (`bench_ctl.capture.plausible`). With
    `confine` (the `report` command: the result's folder and the working folder) a capture path
    that leads outside those folders is refused before the file is opened: a result is a file
    anyone can hand over, and its paths must not make the report read (and hash) another file. A
    hash that differs is said without the file's own hash."""
    out = []
    for i, entry in enumerate(result.captures):
        key = f"{where}: captures[{i}]"
        if not entry.path:
            raise ReportError(f"{key}.path: the result names no capture file (it was identified in memory)")
        path = resolve_capture_path(entry.path, base_dir)
        if confine is not None and outside(path, confine):
            raise ReportError(f"{key}.path: {entry.path} leads outside the result's folder and the working folder "
                              f"({', '.join(str(Path(r)) for r in confine)}); not read (give --allow-outside to "
                              "read captures elsewhere)")
        if not path.is_file():
            raise ReportError(f"{key}.path: capture file {path} not found")
        if not entry.sha256:
            raise ReportError(f"{key}.sha256: the result records no SHA-256 for {path}, so the "
                              "capture cannot be verified")
        expected = entry.sha256.lower()
        actual = capture_sha256(path)
        if actual != expected:
            raise ReportError(f"{key}.sha256: capture {path} is not the file identified: its SHA-256 is not the "
                              f"result's {expected}")
        try:
            capture = read_capture(path)
        except CaptureError as exc:
            raise ReportError(f"{key}: {exc}") from None
        n = entry.n
        if n != capture.n:
            raise ReportError(f"{key}.n: result says {n} samples, {path} has {capture.n}")
        rate = entry.rate_hz
        if not math.isclose(float(rate), capture.rate_hz, rel_tol=1e-6):
            raise ReportError(f"{key}.rate_hz: result says {rate} Hz, {path} has "
                              f"{capture.rate_hz:g} Hz")
        err = implausible(capture)
        if err is not None:   # refused as identify refuses it: no report on a broken record
            raise ReportError(f"{key}: {err}")
        log.debug("capture %d %s verified (sha256 %s)", i, path, actual)
        out.append(LoadedCapture(i, path, actual, capture, entry))
    return out


def same_file(a: CaptureRef | None, b: LoadedCapture) -> bool:
    """Whether a diagnosis' capture refers to this capture (by hash)."""
    return a is not None and (a.sha256 or "").lower() == b.sha256
