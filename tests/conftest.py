"""Fixtures shared by the tests: the reference unit and a synthetic truth; and, around every
test, the check that each result or diagnosis it wrote reads back into its class and gives the
same JSON (docs/formats.md)."""
from __future__ import annotations

from pathlib import Path

import pytest

from bench_ctl import outputs
from bench_ctl.units.overrides import apply_overrides
from bench_ctl.units.unit import Unit, reference_unit
from records import assert_round_trip
from truth import TRUTH

RECORD_TAGS = ("bench-ctl/result/", "bench-ctl/diagnosis/")


@pytest.fixture(autouse=True)
def written_records_read_back(monkeypatch: pytest.MonkeyPatch):
    """Every result and diagnosis a test writes (through the output guard, in this process) reads
    back into `IdentificationResult` / `Diagnosis` and writes the same JSON."""
    written: list[Path] = []

    def keep(path: Path, data: object) -> Path:
        if isinstance(data, dict) and str(data.get("schema", "")).startswith(RECORD_TAGS):
            written.append(Path(path))
        return path

    guarded, plain = outputs.Outputs.write_json, outputs.write_json
    monkeypatch.setattr(outputs.Outputs, "write_json", lambda self, path, data: keep(guarded(self, path, data), data))
    monkeypatch.setattr(outputs, "write_json", lambda path, data, **kw: keep(plain(path, data, **kw), data))
    yield written
    for path in written:
        if path.exists():   # a test may have removed it on purpose
            assert_round_trip(path)


@pytest.fixture(scope="session")
def unit() -> Unit:
    return reference_unit()


@pytest.fixture(scope="session")
def truth_unit(unit: Unit) -> Unit:
    return apply_overrides(unit, [f"{k}={v}" for k, v in TRUTH.items()])
