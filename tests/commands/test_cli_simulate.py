"""`bench-ctl simulate` end to end: capture + sidecar, effects, refusal to overwrite, bad input."""
from __future__ import annotations

import json
import re

import numpy as np

from bench_ctl.capture import read_capture
from bench_ctl.cli import main


def test_simulate_writes_capture_with_effects(tmp_path):
    out = tmp_path / "cap.csv"
    rc = main(["simulate", "--effect", "ceiling_limit:VRMAX=2.8,VRMIN=-1.0", "--effect", "dead_time:TD=0.015",
               "--noise", "0", "--lsb", "0", "--duration", "5", "-o", str(out)])
    assert rc == 0
    cap = read_capture(out)
    assert cap.n == 5001 and cap.dt == 0.001
    assert np.max(cap.efd) <= 2.8 + 1e-12           # the ceiling is on
    assert np.isclose(np.max(cap.efd), 2.8)
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["effects"]["dead_time"] == {"TD": 0.015}
    assert meta["test"] == {"kind": "pulse", "amplitude_pu": 0.05, "start_s": 1.0, "width_s": 1.0}


def test_simulate_noise_and_quantisation(tmp_path):
    ideal, noisy = tmp_path / "a.csv", tmp_path / "b.csv"
    assert main(["simulate", "--noise", "0", "--lsb", "0", "--duration", "3", "-o", str(ideal)]) == 0
    assert main(["simulate", "--seed", "1", "--duration", "3", "-o", str(noisy)]) == 0
    a, b = read_capture(ideal), read_capture(noisy)
    resid = b.efd - a.efd
    assert 0.008 < np.std(resid) < 0.012
    lsb = 20.0 / 4096
    assert np.allclose(np.round(b.efd / lsb) * lsb, b.efd)
    assert np.array_equal(a.usetp, b.usetp)          # the setpoint is recorded exactly


def test_simulate_refuses_overwrite_and_bad_effect(tmp_path, capsys):
    out = tmp_path / "cap.csv"
    assert main(["simulate", "--duration", "3", "-o", str(out)]) == 0
    assert main(["simulate", "--duration", "3", "-o", str(out)]) == 2
    assert "never overwritten" in capsys.readouterr().err
    assert main(["simulate", "--effect", "backlash:B=1", "-o", str(tmp_path / "x.csv")]) == 2
    assert "unknown effect 'backlash'" in capsys.readouterr().err
    assert main(["simulate", "--effect", "dead_time:TD=5", "-o", str(tmp_path / "y.csv")]) == 2
    assert "outside its physical range" in capsys.readouterr().err


def test_simulate_partly_given_effect_and_repeated_effect_options(tmp_path):
    """--set VRMAX=2.8 leaves VRMIN neutral (-inf, written as null); two --effect options for
    one effect add up."""
    out = tmp_path / "a.csv"
    assert main(["simulate", "--set", "VRMAX=2.8", "--duration", "3", "-o", str(out)]) == 0
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["effects"]["ceiling_limit"] == {"VRMAX": 2.8, "VRMIN": None}
    out2 = tmp_path / "b.csv"
    assert main(["simulate", "--effect", "ceiling_limit:VRMAX=2.8", "--effect", "ceiling_limit:VRMIN=-1.0",
                 "--duration", "3", "-o", str(out2)]) == 0
    meta = json.loads(out2.with_suffix(".json").read_text())
    assert meta["effects"]["ceiling_limit"] == {"VRMAX": 2.8, "VRMIN": -1.0}


def test_simulate_refuses_non_finite_options_and_a_saturation_that_would_be_off(tmp_path, capsys):
    for args, msg in ((["--noise", "nan"], "--noise nan must be a finite number"),
                      (["--rate", "0.001"], "fewer than 2 samples"),
                      (["--effect", "saturation:S10=0.3,S12=0.1"], "breaks S12 >= 1.44*S10")):
        out = tmp_path / "x.csv"
        assert main(["simulate", *args, "--duration", "3", "-o", str(out)]) == 2, args
        assert msg in capsys.readouterr().err
        assert not out.exists()


ONLINE_SETS = ["XD=1.8", "XQ=1.7", "XDP=0.3", "XQP=0.55", "XDPP=0.25", "XLS=0.15", "Tq0p=0.4", "Tq0pp=0.05", "H=3",
               "XE=0.4", "P0=0.8", "Q0=0.2", "FN=60"]


def test_simulate_online_records_p_q_and_ifd(tmp_path):
    """The unit on the grid (issue 27): the capture holds P, Q and Ifd at the operating point asked
    for, and a raised reference raises Q."""
    out = tmp_path / "online.csv"
    sets = [a for s in ONLINE_SETS for a in ("--set", s)]
    rc = main(["simulate", "--online", "--model", "SEXS", *sets, "--amplitude", "0.02", "--start", "1", "--width", "3",
               "--duration", "5", "--noise", "0", "--lsb", "0", "-o", str(out)])
    assert rc == 0
    cap = read_capture(out)
    p, q, ifd = (cap.channel(name) for name in ("p", "q", "ifd"))
    assert np.allclose(p[:900], 0.8, atol=1e-9) and np.allclose(q[:900], 0.2, atol=1e-9)
    assert np.allclose(cap.vt[:900], 1.0, atol=1e-9)
    assert q[3900] - q[900] > 0.03                      # the 2 % step raised Q
    assert ifd[3900] > ifd[900]
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["test"]["online"] is True
    assert meta["unit"]["grid"]["XE"] == 0.4


def test_simulate_online_names_what_the_unit_lacks(tmp_path, capsys):
    from importlib import resources
    text = resources.files("bench_ctl.data").joinpath("reference_unit.toml").read_text("utf-8")
    bare = tmp_path / "bare.toml"   # the reference unit without its [grid] data
    bare.write_text(re.sub(r"\n\[grid\]\n(?:\w+ = .*\n)+", "\n", text))
    rc = main(["simulate", "--online", "--unit", str(bare), "--set", "XE=0.2", "-o", str(tmp_path / "x.csv")])
    assert rc == 2
    err = capsys.readouterr().err
    assert "on line needs XD, XQ, XDP, XQP, XDPP, XLS, Tq0p, Tq0pp, H, P0, Q0" in err
    assert not (tmp_path / "x.csv").exists()
