"""Identification on line (issue 27, item 3 in part): a capture with P and Q channels runs on the
machine on the grid from its own pre-step operating point, the objective weighs Q beside efd, and
the report re-simulates it the same way."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bench_ctl.capture import Capture
from bench_ctl.engine.machines.grid import TYPICAL_MACHINE
from bench_ctl.engine.simulate import RecorderModel, pulse_usetp, synthetic_record
from bench_ctl.identification.construction import ProblemError, make_problem
from bench_ctl.identification.identify import run_identification
from bench_ctl.report.analysis import simulate_record
from bench_ctl.units.overrides import apply_overrides, with_model
from bench_ctl.units.unit import reference_unit

TRUE = {"K": 200.0, "TA": 1.0, "TB": 10.0, "TE": 0.05}


def _unit(values=TRUE, grid=TYPICAL_MACHINE):
    unit = with_model(reference_unit(), "SEXS")
    return apply_overrides(unit, [f"{k}={v}" for k, v in {**values, **grid}.items()] + ["Vt0=1.02"])


def _capture(noise: float, seed: int = 4) -> Capture:
    t, usetp = pulse_usetp(amplitude=0.02, width=2.0, start=0.5, duration=4.0, rate=1000.0, usetp0=1.02)
    rec = synthetic_record(_unit(), t, usetp, RecorderModel(noise, 0.0), seed, online=True)
    return Capture(time=rec["time"], usetp=rec["usetp"], efd=rec["efd"], vt=rec["vt"],
                   extra={k: rec[k] for k in ("p", "q", "ifd")}, source="online.csv")


def test_online_record_runs_from_its_own_operating_point():
    cap = _capture(0.0)
    # the unit's own operating point is not the record's: the record's pre-step P, Q, Vt count
    unit = apply_overrides(_unit(), ["P0=0.1", "Q0=-0.3", "Vt0=1.0"])
    prob = make_problem([cap], unit)
    r = prob.records[0]
    assert r.machine is not None and r.vt0 == pytest.approx(1.02, abs=1e-12)
    x = prob.x_start()
    assert prob.mse(x, "efd")[0] < 1e-20 and prob.mse(x, "q")[0] < 1e-20
    assert prob.signals(r) == ["efd", "q"]   # Q weighted by default on line, Vt as the unit says
    # the report re-simulates it on the grid (and at no load it would not reproduce it)
    sim = simulate_record(prob.values(x), cap, unit.grid, None, "test")
    assert sim["fail_step"] < 0
    for name in ("efd", "vt", "p", "q"):
        assert np.abs(sim[name] - cap.columns()[name]).max() < 1e-12, name


def test_online_identification_reaches_the_noise():
    cap = _capture(0.01)
    start = _unit({"K": 120.0, "TA": 2.0, "TB": 5.0, "TE": 0.1})
    ident = run_identification([cap], start, max_evals=600, seed=1)
    best = ident.best
    values = ident.problem.params(best.x)
    mse = ident.problem.mse(best.x)[0]
    assert mse < 1.05 * 0.01 ** 2, mse
    assert values["TE"] == pytest.approx(0.05, rel=0.1)
    assert values["KAVR"] * values["TA1"] / values["TA2"] == pytest.approx(20.0, rel=0.05)   # the high-frequency gain


def test_online_record_needs_the_machine_and_all_three_channels():
    cap = _capture(0.0)
    bare = replace(with_model(reference_unit(), "SEXS"), grid={})   # no machine data
    with pytest.raises(ProblemError, match="on-line record .*needs XD, XQ, XDP, XQP, XDPP, XLS, Tq0p, Tq0pp, H, XE"):
        make_problem([cap], bare)
    half = Capture(time=cap.time, usetp=cap.usetp, efd=cap.efd, vt=cap.vt, extra={"p": cap.channel("p")},
                   source="half.csv")
    with pytest.raises(ProblemError, match="half.csv: an on-line record needs p, q and vt; it has p, vt"):
        make_problem([half], _unit())


def test_report_of_an_online_result_shows_p_q_and_the_mode(tmp_path):
    """simulate --online, identify, report: the report re-simulates on the grid (its MSE check
    passes) and has an on-line section with the mode in P measured and simulated."""
    import re

    from bench_ctl.cli import main

    sets = [a for k, v in {**TYPICAL_MACHINE, "FN": 60.0}.items() for a in ("--set", f"{k}={v}")]
    cap, res, html = tmp_path / "on.csv", tmp_path / "result.json", tmp_path / "report.html"
    assert main(["simulate", "--online", "--model", "SEXS", *sets, "--amplitude", "0.05", "--start", "1",
                 "--width", "5", "--duration", "8", "--noise", "0.002", "--seed", "3", "-o", str(cap)]) == 0
    assert main(["identify", str(cap), "--model", "SEXS", *sets, "--evals", "300", "--json", str(res)]) in (0, 1)
    assert main(["report", str(res), "-o", str(html)]) == 0
    text = html.read_text()
    assert 'id="sec-online"' in text and (tmp_path / "report_online.png").is_file()
    hz = {k: float(v) for k, v in re.findall(r'id="mode-(measured|simulated)-hz" data-value="([^"]+)"', text)}
    assert set(hz) == {"measured", "simulated"} and abs(hz["measured"] - hz["simulated"]) < 0.02
    assert 0.5 < hz["measured"] < 3.0
    assert "reported MSE reproduced" in text and "FAIL: reported MSE" not in text


def test_the_grid_reactance_is_fitted_on_line_when_unknown():
    """XE unknown (`--set XE.min=... XE.max=...`): fitted with the exciter on an on-line record
    (the truth 0.2, the start 0.6); refused on a no-load record."""
    cap = _capture(0.005)
    unit = apply_overrides(_unit(), ["XE=0.6", "XE.min=0.05", "XE.max=0.8", "TE=0.08"])
    ident = run_identification([cap], unit, max_evals=600, seed=2)
    xe = ident.result.unit.grid["XE"]
    assert xe == pytest.approx(TYPICAL_MACHINE["XE"], rel=0.05), xe
    assert "XE" not in ident.result.params and ident.result.unit.grid_identify["XE"].max == 0.8
    assert ident.problem.mse(ident.best.x)[0] < 1.1 * 0.005 ** 2
    no_load = Capture(time=cap.time, usetp=cap.usetp, efd=cap.efd, vt=cap.vt, source="no_load.csv")
    with pytest.raises(ProblemError, match="XE fitted .*only an on-line record"):
        make_problem([no_load], unit)


def test_a_no_load_pulse_and_an_on_line_step_of_one_unit_fit_together():
    """Several records in one fit (issue 27, item 3): the no-load pulse and the on-line step share the
    excitation system's values; each runs on its own generator, and the fit reaches both noises."""
    t, usetp = pulse_usetp(amplitude=0.05, width=1.0, start=0.5, duration=4.0, rate=1000.0, usetp0=1.02)
    rec = synthetic_record(_unit(), t, usetp, RecorderModel(0.01, 0.0), 7)
    no_load = Capture(time=rec["time"], usetp=rec["usetp"], efd=rec["efd"], vt=rec["vt"], source="noload.csv")
    on_line = _capture(0.01)
    start = _unit({"K": 120.0, "TA": 2.0, "TB": 5.0, "TE": 0.1})
    ident = run_identification([no_load, on_line], start, max_evals=800, seed=1)
    prob = ident.problem
    assert [r.machine is not None for r in prob.records] == [False, True]
    mse = prob.mse(ident.best.x)
    assert len(mse) == 2 and all(m < 1.05 * 0.01 ** 2 for m in mse), mse
    values = prob.params(ident.best.x)
    assert values["TE"] == pytest.approx(0.05, rel=0.1)


PSS = ("PSS_MODEL=IEEEST", "PSS_KS=5", "PSS_T1=0.2", "PSS_T2=0.05", "PSS_T3=0.2", "PSS_T4=0.05", "PSS_TW=5",
       "PSS_LSMAX=0.1")


@pytest.mark.parametrize("switch", ["off", "on"])
def test_a_record_taken_with_the_pss_off_is_fitted_and_reported_as_taken(switch):
    """A unit with a stabiliser; its step recorded with the PSS's output switched off (the first
    step of pss_step, `test.pss_on` false in the sidecar) or on. Identification and the report
    simulate each as it was taken (`grid_as_recorded`): exact at the true values. The same record
    said to be taken the other way is missed by far: the stabiliser's action is no rounding."""
    unit = apply_overrides(_unit(), list(PSS))
    t, usetp = pulse_usetp(amplitude=0.02, width=3.0, start=0.5, duration=4.0, rate=1000.0, usetp0=1.02)
    taken = unit if switch == "on" else apply_overrides(unit, ["PSS_LSMAX=0"])
    rec = synthetic_record(taken, t, usetp, RecorderModel(0.0, 0.0), 0, online=True)

    def capture(pss_on: bool) -> Capture:
        return Capture(time=rec["time"], usetp=rec["usetp"], efd=rec["efd"], vt=rec["vt"],
                       extra={k: rec[k] for k in ("p", "q", "ifd")}, meta={"test": {"pss_on": pss_on}},
                       source="pss.csv")

    right, wrong = capture(switch == "on"), capture(switch != "on")
    fits = {}
    for name, cap in (("right", right), ("wrong", wrong)):
        prob = make_problem([cap], unit)
        x = prob.x_start()
        fits[name] = prob.mse(x, "efd")[0]
        sim = simulate_record(prob.values(x), cap, unit.grid, None, "test")
        fits[name + "_report"] = float(np.mean((sim["efd"] - rec["efd"]) ** 2))
    assert fits["right"] < 1e-20 and fits["right_report"] < 1e-20, fits
    assert fits["wrong"] > 1e-6 and fits["wrong_report"] > 1e-6, fits
