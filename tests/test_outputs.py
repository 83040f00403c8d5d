"""Outputs never destroy inputs (issue 15 item 3): a capture, its sidecar, a result, a unit file;
an existing output is replaced only with --force, and always through a temporary file."""
from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from bench_ctl.capture import write_capture
from bench_ctl.cli import main
from bench_ctl.identification.synthetic import synthetic_capture
from bench_ctl.model.unit import reference_unit
from bench_ctl.outputs import OutputRefused, guard_outputs, write_json


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    d = tmp_path_factory.mktemp("outputs")
    cap = synthetic_capture(reference_unit(), duration=3.0, rate=500.0, seed=2)
    csv, side = write_capture(d / "cap.csv", {"time": cap.time, "usetp": cap.usetp, "efd": cap.efd},
                              {"test": {"kind": "pulse"}})
    assert main(["identify", str(csv), "--json", str(d / "r.json"), "--evals", "64", "--no-progress"]) in (0, 1)
    return d, csv, side


@pytest.mark.parametrize("argv", [
    ["identify", "{csv}", "--json", "{side}", "--evals", "64", "--no-progress"],
    ["identify", "{csv}", "--json", "{csv}", "--evals", "64", "--no-progress", "--force"],
    ["report", "{d}/r.json", "-o", "{csv}", "--force"],
    ["report", "{d}/r.json", "-o", "{d}/r.json", "--force"],
    ["report", "{d}/r.json", "-o", "{d}/out.html", "--pdf", "{side}"],
    ["diagnose", "{csv}", "--json", "{side}", "--force"],
])
def test_an_output_on_an_input_is_refused_and_the_input_kept(made, argv, capsys):
    d, csv, side = made
    before = {p: _sha(p) for p in (csv, side, d / "r.json")}
    rc = main([a.format(d=d, csv=csv, side=side) for a in argv])
    assert rc == 2
    assert "would overwrite" in capsys.readouterr().err
    assert {p: _sha(p) for p in before} == before


def test_an_existing_output_needs_force(made, capsys):
    d, csv, _side = made
    out = d / "again.json"
    out.write_text("{}\n", encoding="utf-8")
    assert main(["identify", str(csv), "--json", str(out), "--evals", "64", "--no-progress"]) == 2
    assert "exists" in capsys.readouterr().err and out.read_text() == "{}\n"
    assert main(["identify", str(csv), "--json", str(out), "--evals", "64", "--no-progress", "--force"]) in (0, 1)
    assert '"schema"' in out.read_text()


def test_guard_names_the_option_and_refuses_a_missing_folder(tmp_path):
    with pytest.raises(OutputRefused, match="--json .*folder .* does not exist"):
        guard_outputs({"--json": tmp_path / "nope" / "r.json"}, [])
    with pytest.raises(OutputRefused, match="the same file"):
        guard_outputs({"-o": tmp_path / "a", "--pdf": tmp_path / "a"}, [])
    comtrade = tmp_path / "rec.cfg"
    with pytest.raises(OutputRefused, match="part of input"):
        guard_outputs({"--json": tmp_path / "rec.dat"}, [comtrade])


def test_write_json_leaves_no_temporary_file_and_refuses_nan(tmp_path):
    write_json(tmp_path / "x.json", {"a": 1})
    with pytest.raises(ValueError):
        write_json(tmp_path / "x.json", {"a": float("nan")})
    assert (tmp_path / "x.json").read_text() == '{\n "a": 1\n}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.json"]
