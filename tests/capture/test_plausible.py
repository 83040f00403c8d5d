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
from bench_ctl.units.unit import reference_unit
from records import diagnosis_json


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


def test_report_refuses_unreadable_constraints_and_a_flat_record(tmp_path, cap, capsys):
    csv = _write(tmp_path, "cap.csv", cap)
    assert main(["identify", str(csv), "--json", str(tmp_path / "r.json"), "--evals", "64",
                 "--no-progress"]) in (0, 1)
    result = json.loads((tmp_path / "r.json").read_text())
    bad = dict(result, constraints="TA2 <= TA1")
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    capsys.readouterr()
    # constraints that are not a list of objects: the result is refused, the key named (it was a
    # FAIL report saying they "cannot be checked"; a result of the wrong shape is not reported on)
    assert main(["report", str(tmp_path / "bad.json"), "-o", str(tmp_path / "bad.html")]) == 2
    assert "key 'constraints' must be a list of an object" in capsys.readouterr().err
    assert not (tmp_path / "bad.html").exists()
    # a capture whose efd never responds (its result forged to match the file): refused as identify
    # refuses it (issue 24 item 12: it was a FAIL report with "inf nan", rc 1), nothing written
    flat = Capture(cap.time, cap.usetp, np.full(cap.n, 1.0) + 0.002 * np.cos(np.arange(cap.n)))
    fcsv = write_capture(tmp_path / "flat.csv", {"time": flat.time, "usetp": flat.usetp, "efd": flat.efd}, {})[0]
    from bench_ctl.limits import sha256_file

    forged = dict(result)
    forged["captures"] = [dict(result["captures"][0], path=str(fcsv), sha256=sha256_file(fcsv), meta={})]
    (tmp_path / "forged.json").write_text(json.dumps(forged))
    capsys.readouterr()
    assert main(["report", str(tmp_path / "forged.json"), "-o", str(tmp_path / "flat.html")]) == 2
    assert "does not respond" in capsys.readouterr().err and not (tmp_path / "flat.html").exists()
    # and a broken cell (1e308) likewise, named by row and column
    big = write_capture(tmp_path / "big.csv", {"time": cap.time, "usetp": cap.usetp,
                                               "efd": np.where(np.arange(cap.n) == 700, 1e308, cap.efd)}, {})[0]
    forged["captures"] = [dict(result["captures"][0], path=str(big), sha256=sha256_file(big), meta={})]
    (tmp_path / "big.json").write_text(json.dumps(forged))
    assert main(["report", str(tmp_path / "big.json"), "-o", str(tmp_path / "big.html")]) == 2
    assert "row 702, column 'efd': 1e+308" in capsys.readouterr().err and not (tmp_path / "big.html").exists()


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


# ---- issue 24 items 11-14: the time unit from the record as a whole; import checks as identify
# does; the sidecar's test description is validated; a report warns of another capture's
# diagnosis; a result finds its capture from any working directory

def _fast(rate_hz, duration_s=3.0):
    """A 5 %, 1 s pulse of the reference unit recorded at `rate_hz`, time in s."""
    return synthetic_capture(reference_unit(), duration=duration_s, rate=rate_hz, seed=4)


def test_a_10khz_record_with_a_time_axis_in_ms_is_caught_and_one_in_s_passes(tmp_path, capsys):
    """A 10 kHz (or faster) recorder's ms axis has a step of 0.1 (0.05 at 20 kHz): plausible as a
    step, but the record lasts 3000 "s" and its 1 s pulse 1000 "s" (diagnose said dead_time,
    identify fitted it with rc 0)."""
    c = _fast(10_000.0)
    assert implausible(c) is None                       # a genuine 10 kHz record in seconds passes
    for rate in (10_000.0, 20_000.0):
        ms = _fast(rate)
        csv = _write(tmp_path, f"ms{int(rate)}.csv", ms, time=ms.time * 1000.0)
        for argv in (["identify", str(csv), "--evals", "64", "--no-progress"], ["diagnose", str(csv)]):
            assert main(argv) == 2
            err = capsys.readouterr().err
            assert "is the time column in ms?" in err and f"ms{int(rate)}.csv" in err, err
    # a short ms record that passes the duration check is caught by its pulse's width
    short = synthetic_capture(reference_unit(), duration=0.4, rate=10_000.0, seed=4, start=0.1, width=0.07)
    err = implausible(Capture(short.time * 1000.0, short.usetp, short.efd))
    assert err is not None and "between its edges" in str(err) and "in ms?" in str(err)
    # the sidecar's rate against the CSV's step: named as such
    (tmp_path / "side.csv").write_bytes(csv.read_bytes())
    (tmp_path / "side.json").write_text(json.dumps({"rate_hz": 20_000.0}))
    assert main(["identify", str(tmp_path / "side.csv"), "--evals", "64", "--no-progress"]) == 2
    assert "rate_hz 20000.0 disagrees" in capsys.readouterr().err


def test_import_applies_the_same_checks(tmp_path, capsys):
    """`import` accepted an ms axis or 1e308 with rc 0; now refused before anything is written,
    named by the source's row and column."""
    c = _fast(10_000.0)

    def export(name, t_scale=1.0, efd=c.efd):
        lines = ["t,EFD,U"] + [f"{float(t) * t_scale!r},{float(e)!r},{float(u)!r}"
                               for t, e, u in zip(c.time, efd, c.usetp)]
        (tmp_path / name).write_text("\n".join(lines) + "\n")
        return ["import", str(tmp_path / name), "--map", "efd=EFD", "--map", "usetp=U", "--time-column", "t"]

    assert main(export("ms.csv", t_scale=1000.0) + ["-o", str(tmp_path / "a.csv")]) == 2
    assert "is the time column in ms?" in capsys.readouterr().err and not (tmp_path / "a.csv").exists()
    big = np.where(np.arange(c.n) == 700, 1e308, c.efd)
    assert main(export("big.csv", efd=big) + ["-o", str(tmp_path / "b.csv")]) == 2
    err = capsys.readouterr().err
    assert "big.csv, row 702, column 'EFD': 1e+308" in err and not (tmp_path / "b.csv").exists(), err
    argv = export("ok.csv")
    assert main(argv + ["-o", str(tmp_path / "ok.csv.out.csv")]) == 0
    # a test description that is not the record's
    assert main(argv + ["--test", "pulse:start=1.0,amplitude=0.05,width=0.3", "-o", str(tmp_path / "c.csv")]) == 2
    assert "--test, key 'test.width_s': 0.3 s, but the usetp pulse lasts 1 s" in capsys.readouterr().err


@pytest.mark.parametrize("test,expect", [
    ({"kind": "pulse", "amplitude_pu": -5, "start_s": 1.0, "width_s": 1.0}, "key 'test.amplitude_pu': -5 pu is not"),
    ({"kind": "pulse", "amplitude_pu": 0.05, "start_s": 1.0, "width_s": -1},
     "key 'test.width_s': -1 s: a pulse's width"),
    ({"kind": "pulse", "amplitude_pu": 0.05, "start_s": 99, "width_s": 1.0}, "key 'test.start_s': 99 s lies outside"),
    ({"kind": "pulse", "amplitude_pu": -0.05, "start_s": 1.0, "width_s": 1.0}, "but usetp steps by 0.05 pu"),
    ({"kind": "pulse", "amplitude_pu": 0.05, "start_s": 1.0, "width_s": 0.001}, "but the usetp pulse lasts 1 s"),
    ({"kind": "pulse", "amplitude_pu": "big", "start_s": 1.0, "width_s": 1.0}, "'big' is not a finite number"),
    ({"kind": "sine"}, "'sine' is not a test bench-ctl knows"),
])
def test_sidecar_test_metadata_is_validated_before_a_report_copies_it(tmp_path, cap, capsys, test, expect):
    csv = write_capture(tmp_path / "cap.csv", {"time": cap.time, "usetp": cap.usetp, "efd": cap.efd}, {"test": test})[0]
    assert main(["identify", str(csv), "--evals", "64", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "cap.json, key" in err and expect in err, err
    # a result made before the sidecar was edited: the report refuses too (rc 2), nothing written
    good = write_capture(tmp_path / "good.csv", {"time": cap.time, "usetp": cap.usetp, "efd": cap.efd},
                         {"test": {"kind": "pulse", "amplitude_pu": 0.05, "start_s": 1.0, "width_s": 1.0}})[0]
    assert main(["identify", str(good), "--evals", "64", "--no-progress", "--json", str(tmp_path / "r.json")]) in (0, 1)
    side = json.loads((tmp_path / "good.json").read_text())
    (tmp_path / "good.json").write_text(json.dumps({**side, "test": test}))
    capsys.readouterr()
    assert main(["report", str(tmp_path / "r.json"), "-o", str(tmp_path / "r.html")]) == 2
    assert expect in capsys.readouterr().err and not (tmp_path / "r.html").exists()


def test_report_with_another_captures_diagnosis_warns_on_the_console(tmp_path, cap, capsys):
    """The report only noted it in the HTML; the console now says it, and the other record's noise
    floor is not used to judge this fit."""
    from bench_ctl.limits import sha256_file

    one = _write(tmp_path, "one.csv", cap)
    two = _write(tmp_path, "two.csv", synthetic_capture(reference_unit(), duration=3.0, rate=500.0, seed=9))
    assert main(["identify", str(one), "--evals", "64", "--no-progress", "--json", str(tmp_path / "r.json")]) in (0, 1)
    diag = diagnosis_json(capture={"path": str(two), "sha256": sha256_file(two)}, verdict="none", noise_floor=1e-9)
    (tmp_path / "d.json").write_text(json.dumps(diag))
    capsys.readouterr()
    rc = main(["report", str(tmp_path / "r.json"), "--diagnosis", str(tmp_path / "d.json"),
               "-o", str(tmp_path / "r.html")])
    printed = capsys.readouterr()
    assert rc in (0, 1)
    assert "WARNING: --diagnosis" in printed.err and "not on a capture of this result" in printed.err
    assert "WARN: diagnosis of this record" in printed.out
    assert "noise floor 1e-09" not in printed.out     # its floor (1e-9 pu^2) would make any fit a failure
    assert "not on a capture of this result" in (tmp_path / "r.html").read_text(encoding="utf-8")


def test_a_result_finds_its_capture_from_any_working_directory(tmp_path, cap, monkeypatch, capsys):
    """The result stored its capture path relative to the working directory: `cd / && report`
    failed. It is now relative to the result file (its folder can be moved as a whole)."""
    (tmp_path / "caps").mkdir()
    (tmp_path / "results").mkdir()
    _write(tmp_path / "caps", "c.csv", cap)
    monkeypatch.chdir(tmp_path)
    assert main(["identify", "caps/c.csv", "--evals", "64", "--no-progress", "--json", "results/r.json"]) in (0, 1)
    assert json.loads((tmp_path / "results" / "r.json").read_text())["captures"][0]["path"] == "../caps/c.csv"
    monkeypatch.chdir("/")
    capsys.readouterr()
    assert main(["report", str(tmp_path / "results" / "r.json"), "-o", str(tmp_path / "results" / "r.html")]) in (0, 1)
    moved = tmp_path / "moved"
    moved.mkdir()
    for name in ("results", "caps"):
        (tmp_path / name).rename(moved / name)
    assert main(["report", str(moved / "results" / "r.json"), "-o", str(moved / "r2.html")]) in (0, 1)
    assert "error" not in capsys.readouterr().err


def test_a_20khz_step_record_with_a_time_axis_in_ms_is_caught_as_a_pulse_is(tmp_path, capsys):
    """Issue 48 item 11: a 20 kHz step record in ms (5801 samples, 0.29 s) imported as "5800
    samples at 20 Hz" with exit 0: its step has no second edge to be too far from the first, but
    its efd takes ~11 "s" to reach half of its response; the same record in seconds passes."""
    for rate in (20_000.0, 10_000.0):
        c = synthetic_capture(reference_unit(), duration=0.29, rate=rate, seed=4, start=0.1, width=None)
        assert implausible(c) is None
        err = implausible(Capture(c.time * 1000.0, c.usetp, c.efd))
        assert err is not None and "to reach half of its response" in str(err) and "in ms?" in str(err), err
    # through the import, as the probe did it: refused before anything is written
    lines = ["t_ms,EFD,U"] + [f"{float(t) * 1000.0!r},{float(e)!r},{float(u)!r}"
                              for t, e, u in zip(c.time, c.efd, c.usetp)]
    (tmp_path / "step_ms.csv").write_text("\n".join(lines) + "\n")
    assert main(["import", str(tmp_path / "step_ms.csv"), "--map", "efd=EFD", "--map", "usetp=U",
                 "--time-column", "t_ms", "-o", str(tmp_path / "s.csv")]) == 2
    err = capsys.readouterr().err
    assert "is the time column in ms?" in err and not (tmp_path / "s.csv").exists()
    # a slow DC exciter's response in seconds still passes (IEEEX1 with TE and KA at the slow ends of
    # their bounds: half of its response after 0.76 s)
    assert main(["simulate", "--model", "IEEEX1", "--set", "TE=3.0", "--set", "KA=5", "--width", "8", "--duration",
                 "12", "--rate", "1000", "-o", str(tmp_path / "dc.csv")]) == 0
    from bench_ctl.capture import read_capture
    assert implausible(read_capture(tmp_path / "dc.csv")) is None
