"""Identification end to end: known parameters recovered from synthetic captures, the result
JSON (docs/formats.md) and the `bench-ctl identify` command with its exit codes.

The truth is chosen so that a 4 s record determines all six parameters (TA3 < TA2, so the lead
swap is ruled out by TA2 <= TA1; TA4 = 2 s is seen within the record); the noise is the
recorder's (0.01 pu + 12-bit quantisation), whose variance is the floor an MSE can reach.
"""
from __future__ import annotations

import json
import math

import pytest

from bench_ctl.capture import write_capture
from bench_ctl.cli import main
from bench_ctl.engine.simulate import RecorderModel
from bench_ctl.identification.identify import identify, run_identification
from bench_ctl.identification.synthetic import noise_variance, synthetic_capture
from truth import TRUTH

SCHEMA_KEYS = {"schema", "software_version", "command_line", "created_utc", "unit", "captures",
               "params", "fixed", "bounds", "constraints", "objective", "mse", "evaluations",
               "wall_s", "compile_s", "optimizer", "history", "identifiability"}
IDENT_KEYS = {"sensitivity", "std", "rel_std", "correlation", "names", "determined",
              "equivalent_sets", "notes"}


@pytest.fixture(scope="module")
def cap(truth_unit):
    return synthetic_capture(truth_unit, duration=4.0, rate=500.0, seed=2)


@pytest.fixture(scope="module")
def fitted(unit, cap):
    return run_identification([cap], unit, optimizer="mvmo", max_evals=2000, seed=0,
                              command_line="test")


def test_mvmo_recovers_the_parameters_the_capture_determines(fitted, cap):
    r = fitted.result.to_json()
    var = noise_variance(RecorderModel())
    # the MSE reaches the noise floor (a fit may dip slightly below it: it also fits the noise)
    assert 0.9 * var < r["mse"] < 1.05 * var
    ident = r["identifiability"]
    determined = [n for n, ok in ident["determined"].items() if ok]
    assert {"TA2", "TA3", "TE"} <= set(determined)
    for name in determined:
        err = abs(r["params"][name] - TRUTH[name])
        assert err <= 4.0 * ident["std"][name], (name, r["params"][name], ident["std"][name])
    assert all(c["satisfied"] for c in r["constraints"])
    assert fitted.ok


def test_result_dict_has_every_schema_key_and_is_strict_json(fitted):
    r = fitted.result.to_json()
    assert SCHEMA_KEYS <= set(r)
    assert IDENT_KEYS <= set(r["identifiability"])
    assert r["schema"] == "bench-ctl/result/1"
    assert set(r["params"]) == set(TRUTH)
    assert set(r["fixed"]) >= {"Td0p", "Td0pp", "Vt0", "VRMAX"} and r["fixed"]["VRMAX"] is None
    # MVMO spends its share of the budget; the joint polish of the edge instants that follows
    # may end before the rest is used (a Jacobian batch that no longer fits, or convergence)
    assert 1900 <= r["evaluations"] <= 2000 and r["optimizer"]["name"] == "mvmo"
    assert r["wall_s"] > 0 and r["compile_s"] >= 0
    hist = r["history"]
    assert hist[-1][0] == r["evaluations"] and all(a[1] >= b[1] for a, b in zip(hist, hist[1:]))
    assert r["objective"] == pytest.approx(hist[-1][1])
    c = r["captures"][0]
    assert c["n"] == 2001 and c["rate_hz"] == pytest.approx(500.0) and c["weight"] == 1.0
    json.dumps(r, allow_nan=False)


def test_identify_returns_the_result_dict_and_compares(unit, cap):
    r = identify([cap], unit, optimizer="local", max_evals=150, seed=1, compare=["open-loop"]).to_json()
    assert r["optimizer"]["name"] == "local"
    assert [c["optimizer"] for c in r["comparison"]] == ["local", "open-loop"]
    for c in r["comparison"]:
        assert c["evaluations"] <= 150 and math.isfinite(c["mse"])


def test_cli_end_to_end_writes_json_and_plot(tmp_path, cap):
    csv, _ = write_capture(tmp_path / "pulse.csv", cap)
    out, png = tmp_path / "result.json", tmp_path / "fit.png"
    rc = main(["identify", str(csv), "--evals", "300", "--seed", "3", "--optimizer", "mvmo",
               "--json", str(out), "--plot", str(png), "--no-progress"])
    assert rc == 0
    r = json.loads(out.read_text())
    assert SCHEMA_KEYS <= set(r)
    # the capture's path relative to the result file (issue 24 item 14)
    assert r["captures"][0]["path"] == "pulse.csv" and len(r["captures"][0]["sha256"]) == 64
    assert r["command_line"].startswith("bench-ctl identify ") and "--evals 300" in r["command_line"]
    assert r["optimizer"]["seed"] == 3 and r["evaluations"] == 300
    assert png.stat().st_size > 10_000


def test_cli_exit_1_when_the_fit_breaks_a_constraint(tmp_path, cap, capsys):
    # the local (PowerFactory-like) method started at the lead-swapped set (TA1 0.1, TA3 1.0)
    # converges to that equally good set, which breaks TA2 <= TA1
    csv, _ = write_capture(tmp_path / "pulse.csv", cap)
    rc = main(["identify", str(csv), "--optimizer", "local", "--evals", "200", "--no-progress",
               "--set", "TA1.min=0.01", "--set", "TA1=0.1", "--set", "TA3=1.0", "--set", "TA2=0.3",
               "--set", "TA4=2.0", "--set", "TE=0.03", "--json", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert rc == 1
    assert "TA2 <= TA1" in err
    r = json.loads((tmp_path / "r.json").read_text())
    assert [c["expr"] for c in r["constraints"] if not c["satisfied"]] == ["TA2 <= TA1"]


def test_cli_exit_1_when_the_fit_leaves_its_bounds(tmp_path, cap, capsys):
    # the truth has KAVR 200; bounded to 150, the local method (positivity only, as PowerFactory)
    # goes past the bound to the truth: the result is written but not accepted
    csv, _ = write_capture(tmp_path / "pulse.csv", cap)
    rc = main(["identify", str(csv), "--optimizer", "local", "--evals", "200", "--no-progress",
               "--set", "KAVR.max=150", "--set", "KAVR=100", "--json", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert rc == 1 and "outside its bounds: KAVR = " in err and "[50, 150]" in err
    r = json.loads((tmp_path / "r.json").read_text())
    assert r["params"]["KAVR"] > 150


@pytest.mark.parametrize("args, message", [
    (["--set", "FOO=1"], "FOO"),
    (["--set", "KAVR.min=900"], "min"),
    (["--unit", "missing.toml"], "missing.toml"),
])
def test_cli_bad_input_exit_2(tmp_path, cap, capsys, args, message):
    csv, _ = write_capture(tmp_path / "pulse.csv", cap)
    rc = main(["identify", str(csv), "--evals", "50", "--no-progress", *args])
    assert rc == 2
    assert message in capsys.readouterr().err


def test_cli_bad_capture_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("time,usetp,efd\n0,1,1\n0.001,1,nan\n0.002,1,1\n")
    assert main(["identify", str(bad), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "bad.csv" in err
    assert main(["identify", str(tmp_path / "none.csv"), "--no-progress"]) == 2
