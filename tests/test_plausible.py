"""Implausible captures are refused naming what is wrong; the report fails what it cannot check
(issue 15 item 4)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from bench_ctl.capture import Capture, write_capture
from bench_ctl.capture.plausible import implausible
from bench_ctl.cli import main
from bench_ctl.identification.synthetic import synthetic_capture
from bench_ctl.model.unit import reference_unit


@pytest.fixture(scope="module")
def cap():
    return synthetic_capture(reference_unit(), duration=3.0, rate=500.0, seed=4)


def _write(d, name, cap, **cols):
    data = {"time": cap.time, "usetp": cap.usetp, "efd": cap.efd, **cols}
    return write_capture(d / name, data, {})[0]


def test_a_plausible_capture_passes(cap):
    assert implausible(cap) is None


@pytest.mark.parametrize("change,expect", [
    (lambda c: {"time": c.time * 1000.0}, "sample step 2 s is outside"),
    (lambda c: {"efd": np.where(np.arange(c.n) == 700, 1e308, c.efd)}, "row 702, column 'efd': 1e+308"),
    (lambda c: {"efd": np.full(c.n, 1.0) + 0.01 * np.sin(np.arange(c.n))}, "efd does not respond"),
    (lambda c: {"usetp": np.full(c.n, 1.0)}, "usetp never changes"),
    (lambda c: {"usetp": c.usetp * 100.0}, "column 'usetp'"),
])
def test_identify_and_diagnose_refuse_an_implausible_capture(tmp_path, cap, capsys, change, expect):
    csv = _write(tmp_path, "bad.csv", cap, **change(cap))
    for argv in (["identify", str(csv), "--evals", "64", "--no-progress"], ["diagnose", str(csv)]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert expect in err and "bad.csv" in err, err


def test_report_fails_a_flat_record_and_unreadable_constraints(tmp_path, cap):
    csv = _write(tmp_path, "cap.csv", cap)
    assert main(["identify", str(csv), "--json", str(tmp_path / "r.json"), "--evals", "64",
                 "--no-progress"]) in (0, 1)
    result = json.loads((tmp_path / "r.json").read_text())
    bad = dict(result, constraints="TA2 <= TA1")
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    assert main(["report", str(tmp_path / "bad.json"), "-o", str(tmp_path / "bad.html")]) == 1
    html = (tmp_path / "bad.html").read_text(encoding="utf-8")
    assert "cannot be checked" in html
    # a capture whose efd never responds (its result forged to match the file): FAIL, not PASS
    flat = Capture(cap.time, cap.usetp, np.full(cap.n, 1.0) + 0.002 * np.cos(np.arange(cap.n)))
    fcsv = write_capture(tmp_path / "flat.csv", {"time": flat.time, "usetp": flat.usetp, "efd": flat.efd}, {})[0]
    from bench_ctl.capture.capture import sha256_file

    forged = dict(result)
    forged["captures"] = [dict(result["captures"][0], path=str(fcsv), sha256=sha256_file(fcsv), meta={})]
    (tmp_path / "forged.json").write_text(json.dumps(forged))
    assert main(["report", str(tmp_path / "forged.json"), "-o", str(tmp_path / "flat.html")]) == 1
    assert "does not respond" in (tmp_path / "flat.html").read_text(encoding="utf-8")


@pytest.mark.timeout(30)
def test_a_capture_linked_to_a_device_is_refused_at_once(tmp_path, capsys):
    """A capture symlinked to /dev/zero used to eat memory at 0.6 GB/s; import hung."""
    link = tmp_path / "zero.csv"
    link.symlink_to("/dev/zero")
    assert main(["identify", str(link), "--evals", "64", "--no-progress"]) == 2
    assert "not a regular file" in capsys.readouterr().err
    assert main(["import", str(link), "-o", str(tmp_path / "out.csv"), "--map", "efd=EFD",
                 "--map", "usetp=U", "--time-column", "t"]) == 2
    assert "not a regular file" in capsys.readouterr().err
    (tmp_path / "unit.toml").symlink_to("/dev/zero")
    assert main(["diagnose", str(link), "--unit", str(tmp_path / "unit.toml")]) == 2
