"""Helpers for tests that make result and diagnosis files by hand, and the round-trip check of
the files the end-to-end runs write (docs/formats.md: read back, they give the same JSON)."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from bench_ctl.capture import read_capture
from bench_ctl.diagnosis.diagnosis_file import DIAGNOSIS_SCHEMA, Diagnosis
from bench_ctl.identification.result_file import RESULT_SCHEMA, Identifiability, IdentificationResult, ModelEntry
from bench_ctl.limits import sha256_file
from bench_ctl.signals.edges import Edge
from bench_ctl.units.unit import reference_unit


def capture_entry(path: str | Path, **keys: Any) -> dict[str, Any]:
    """A result's `captures` entry for a capture file: its hash, size and rate as read; `keys`
    replace any of them."""
    cap = read_capture(path)
    return {"path": str(path), "sha256": sha256_file(path), "n": cap.n, "rate_hz": cap.rate_hz, "meta": {},
            "mse": None, "objective": None, "weight": 1.0, **keys}


def _in_order(cls: type, data: dict[str, Any]) -> dict[str, Any]:
    """`data` with its keys in the order the class writes them (unknown keys last)."""
    names = [f.name for f in dataclasses.fields(cls)]
    return {**{k: data[k] for k in names if k in data}, **{k: v for k, v in data.items() if k not in names}}


def unit_json(**keys: Any) -> dict[str, Any]:
    """A result's or diagnosis' `unit`: the reference unit as a result writes it, without its
    constraints (a result made by hand has none to report); `keys` replace any key."""
    return {**reference_unit().entry().to_json(), "constraints": [], **keys}


def edge_json(**keys: Any) -> dict[str, Any]:
    """One edge of a capture as a result writes it (not fitted); `keys` give the rest."""
    return _in_order(Edge, {"index": 1000, "jump_pu": 0.05, "nominal_s": 1.0, "fitted_s": 1.0, "offset_s": 0.0,
                            "std_s": None, "lo_s": -0.001, "hi_s": 0.0, "how": "recorded", "fitted": False, **keys})


def ident_json(names: list[str], **keys: Any) -> dict[str, Any]:
    """An `identifiability` block over `names` that determined nothing (a fit not analysed); `keys`
    give the rest."""
    return _in_order(Identifiability, {
        "names": names, "sensitivity": {}, "std": {}, "rel_std": {}, "correlation": [],
        "determined": {n: False for n in names}, "equivalent_sets": [], "notes": [], **keys})


def model_json(**keys: Any) -> dict[str, Any]:
    """A result's `model`: the reference structure with no parameter given; `keys` give the rest."""
    return _in_order(ModelEntry, {"name": "REFERENCE", "title": "", "dyr_model": None, "params": {}, "units": {},
                                  "identified": [], "determined": {}, "simulated": [], "generator": {}, **keys})


def result_json(**keys: Any) -> dict[str, Any]:
    """A complete result JSON object with neutral provenance and budget; `keys` give the rest."""
    return _in_order(IdentificationResult, {
        "schema": RESULT_SCHEMA, "software_version": "0.1.0", "command_line": "", "created_utc":
            "2025-01-01T00:00:00+00:00", "unit": unit_json(), "captures": [], "params": {}, "fixed": {},
            "bounds": {}, "constraints": [], "objective": None, "mse": None, "evaluations": 0, "wall_s": 0.0,
            "compile_s": 0.0, "optimizer": {"name": "mvmo", "settings": {}, "seed": 0}, "history": [],
            "fit_window": None, **keys})


def result_of(**keys: Any) -> IdentificationResult:
    return IdentificationResult.from_json(result_json(**keys), "test result")


def localization_json(**keys: Any) -> dict[str, Any]:
    return {"segments": [], "bands": [], **keys}


def diagnosis_json(**keys: Any) -> dict[str, Any]:
    """A complete diagnosis JSON object with empty tables; `keys` give the rest."""
    check = {"kind": "windows", "windows": [], "how": "", "holdout": None, "vt": False,
             "blocks": {"seconds": 0.05, "folds": 2}}
    return {"schema": DIAGNOSIS_SCHEMA, "software_version": "0.1.0", "command_line": "",
            "created_utc": "2025-01-01T00:00:00+00:00", "capture": {"path": None, "sha256": None}, "holdout": None,
            "unit": unit_json(), "validation": {"kind": "windows", "fit": {"t0": 0.0, "t1": 1.0}, "check": check},
            "check": check, "edges": [],
            "base": {"params": {}, "mse": None, "mse_holdout": None, "check": None, "evaluations": 0,
                     "at_noise_floor": False},
            "noise_floor": None,
            "noise_floor_detail": {"samples": 0, "t0": 0.0, "t1": 0.0, "rel_se": 0.0, "check": 0.0, "holdout": None},
            "localization": localization_json(),
            "features": [], "effects": [], "ambiguous": [], "sequence": [], "explained_by": [],
            "left": {"mse": None, "mse_over_floor": None, "effects": [], "note": "",
                     "localization": localization_json()},
            "verdict": "none",
            "criteria": {"significant_delta": 10.0, "check_gain": 2.0, "strong_delta": 100.0, "one_regime_gain": 100.0,
                         "ambiguous_delta": 6.0, "floor_sigmas": 3.0, "score": ""},
            "wall_s": 0.0, **keys}


def effect_json(name: str, **keys: Any) -> dict[str, Any]:
    """A complete `effects` entry of a diagnosis; `keys` give the figures."""
    return {"name": name, "params": {}, "fixed": {}, "avr_params": {}, "mse": None, "mse_holdout": None,
            "gap_closed": None, "gap_closed_on": None, "gap_closed_fit": None, "gap_closed_fit_raw": None,
            "gap_closed_check": None, "gap_closed_check_raw": None, "gap_closed_holdout": None,
            "gap_closed_holdout_raw": None, "check": None, "score": None, "aic": None, "bic": None,
            "delta_bic": None, "delta_check": None, "significant": False, "k": 1, "evaluations": 0, "start": {},
            **keys}   # variant, the one optional key, is the last one written


def step_json(name: str, **keys: Any) -> dict[str, Any]:
    """A complete step of a diagnosis' `explained_by`; `keys` give the figures."""
    return {"name": name, "effects": [name], "dropped": [], "params": {}, "mse": None, "mse_over_floor": None,
            "gap_closed": None, "edges": {}, "fit_gain": None,
            "check": {"on": "windows", "mse": None, "mse_before": None, "gain": None, "parts": None}, **keys}


def assert_round_trip(path: str | Path) -> IdentificationResult | Diagnosis:
    """The result or diagnosis file at `path` reads into its class and writes the same JSON."""
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    cls = Diagnosis if str(data.get("schema", "")).startswith("bench-ctl/diagnosis/") else IdentificationResult
    record = cls.from_json(data, str(path))
    assert record.to_json() == data, path
    assert json.dumps(record.to_json(), indent=1) == json.dumps(data, indent=1), path   # keys in the same order
    return record
