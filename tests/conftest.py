"""Fixtures shared by the tests: the reference unit and a synthetic truth; around every test, the
check that each result or diagnosis it wrote reads back into its class and gives the same JSON
(docs/formats.md); and around the session, the check that nothing compiled inside the tests
(tests/compile_guard.py)."""
from __future__ import annotations

from pathlib import Path

import pytest

from bench_ctl import outputs
from bench_ctl.units.overrides import apply_overrides
from bench_ctl.units.unit import Unit, reference_unit
from compile_guard import Guard
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


#: the compile guard of this session (the controller's; None in a pytest-xdist worker)
_guard: Guard | None = None
_guard_lines: list[str] = []


@pytest.hookimpl(wrapper=True)
def pytest_sessionstart(session: pytest.Session):
    result = yield   # pytest-xdist's workers start first: the guard's imports (1 s) overlap theirs
    global _guard
    if not hasattr(session.config, "workerinput"):
        _guard = Guard.start()
    return result


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if _guard is not None:
        _guard.runs.append((report.nodeid, report.start, report.stop))


def pytest_sessionfinish(session: pytest.Session) -> None:
    global _guard_lines
    if _guard is None:
        return
    failed, _guard_lines = _guard.finish()
    if failed and session.exitstatus == pytest.ExitCode.OK:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter) -> None:
    if _guard_lines:
        terminalreporter.write_sep("=", "compile guard")
        for line in _guard_lines:
            terminalreporter.write_line(line)
