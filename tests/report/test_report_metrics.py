"""Report building blocks without rendering: edge detection and segments, the constraint
re-check, parameter reconstruction from a result, several captures in one result."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from bench_ctl.capture import write_capture
from bench_ctl.engine.simulate import RecorderModel, pre_trigger_mean, pulse_usetp, simulate, synthetic_record
from bench_ctl.identification.result_file import IdentificationResult
from bench_ctl.model.params import AVR_PARAMS, REFERENCE_VALUES, neutral_values
from bench_ctl.report import ReportError, analyse
from bench_ctl.report.checks import constraint_margin
from bench_ctl.report.document import Fig
from bench_ctl.report.inputs import model_values
from bench_ctl.report.metrics import edge_times, error_figures, segment_bounds
from bench_ctl.report.metrics import setpoint_edges as find_edges
from bench_ctl.report.outline import sections
from bench_ctl.units.unit import load_unit
from records import capture_entry, result_json, result_of


def test_edges_of_a_pulse_a_negative_pulse_a_step_and_nothing() -> None:
    t, u = pulse_usetp(amplitude=0.05, width=1.0, start=1.5, duration=5.0, rate=200.0)
    e = find_edges(t, u)
    assert (*edge_times(e), e.lead.index) == (1.5, 2.5, 300)
    assert e.lead.jump_pu == pytest.approx(0.05) and pre_trigger_mean(u, t[1] - t[0]) == 1.0
    t, u = pulse_usetp(amplitude=-0.02, width=0.3, start=0.5, duration=2.0, rate=1000.0)
    e = find_edges(t, u)
    assert edge_times(e) == (0.5, 0.8) and e.lead.jump_pu == pytest.approx(-0.02)
    t = np.arange(1000) / 1000.0
    u = np.where(t >= 0.25, 1.05, 1.0)
    e = find_edges(t, u)
    assert edge_times(e) == (0.25, None)
    assert [s[0] for s in segment_bounds(t, e)] == ["pre_trigger", "leading_edge", "plateau"]
    e = find_edges(t, np.ones_like(t))
    assert e.lead is None and segment_bounds(t, e) == [("whole record", 0.0, 0.999)]


def test_segments_cover_every_sample_once_and_shares_sum_to_one() -> None:
    rng = np.random.default_rng(3)
    t, u = pulse_usetp(amplitude=0.05, width=0.1, start=1.0, duration=3.0, rate=1000.0)
    meas = rng.normal(size=t.size)
    f = error_figures(t, meas, np.zeros_like(t), find_edges(t, u), window_s=0.2)
    # the pulse is shorter than the edge window: the leading edge ends at the trailing edge
    names = [s.name for s in f.segments]
    assert names == ["pre_trigger", "leading_edge", "plateau", "trailing_edge", "recovery"]
    assert [s.n for s in f.segments] == [1000, 100, 0, 200, 1701]
    assert sum(s.share for s in f.segments) == pytest.approx(1.0)
    assert f.mse == pytest.approx(np.mean(meas ** 2))
    assert f.noise_floor == pytest.approx(np.var(meas[:1000], ddof=1))


@pytest.mark.parametrize("expr, margin", [("TA2 <= TA1", 0.8), ("TA4 >= TA2", 9.8),
                                          ("0 <= TA2 <= TA1", 0.2), ("S12 >= 1.44*S10", 0.0),
                                          ("TA1 + TA3 <= 1", -0.5), ("TA2 < TA1 / 10", -0.1)])
def test_constraint_margin(expr: str, margin: float) -> None:
    values = {**REFERENCE_VALUES, "S10": 0.0, "S12": 0.0}
    assert constraint_margin(expr, values) == pytest.approx(margin)


@pytest.mark.parametrize("expr", ["TA2 == TA1", "XX <= TA1", "TA2 <=", "__import__('os')",
                                  "TA2 ** 2 <= TA1"])
def test_constraint_margin_refuses_what_it_cannot_evaluate(expr: str) -> None:
    assert constraint_margin(expr, REFERENCE_VALUES) is None


def test_model_values_from_result() -> None:
    fixed = {"Td0p": 7.5, "Td0pp": 0.05, "Vt0": 1.0, "VRMAX": None, "VRMIN": None, "RATE": 50.0}
    values = model_values({k: REFERENCE_VALUES[k] for k in AVR_PARAMS}, fixed, "r.json")
    assert values["VRMAX"] == math.inf and values["VRMIN"] == -math.inf
    assert values["RATE"] == 50.0 and values["TD"] == neutral_values()["TD"]
    with pytest.raises(ReportError, match=r"r.json: fixed.Td0p: null is only allowed"):
        model_values({}, {"Td0p": None}, "r.json")
    with pytest.raises(ReportError, match=r"r.json: params.KAVR: expected a number"):
        model_values({"KAVR": "200"}, fixed, "r.json")
    with pytest.raises(ReportError, match=r"no value for model parameter\(s\) \['KAVR'"):
        model_values({}, fixed, "r.json")


def test_two_captures_mean_mse_weighted_objective_and_figures_per_capture(tmp_path: Path) -> None:
    unit = load_unit(None)
    entries, mses, objs = [], [], []
    for i, (amp, weight) in enumerate([(0.05, 1.0), (-0.03, 0.5)]):
        t, u = pulse_usetp(amplitude=amp, width=0.5, start=0.5, duration=3.0, rate=500.0)
        rec = synthetic_record(unit, t, u, RecorderModel(), seed=i)
        csv, _ = write_capture(tmp_path / f"c{i}.csv", rec)
        sim, _, _ = simulate(unit.values(), u, 1 / 500.0)
        r = rec["efd"] - sim
        mses.append(float(np.mean(r ** 2)))
        objs.append(weight * float(np.trapezoid(r ** 2, dx=1 / 500.0)))
        entries.append(capture_entry(csv, weight=weight))
    values = unit.values()
    result = result_json(captures=entries, mse=float(np.mean(mses)),
                         objective=sum(objs), params={k: values[k] for k in AVR_PARAMS},
                         fixed={k: (None if math.isinf(v) else v) for k, v in values.items()
                                if k not in AVR_PARAMS})
    d = analyse(IdentificationResult.from_json(json.loads(json.dumps(result))))
    assert d.mse == pytest.approx(np.mean(mses), rel=1e-12)
    assert d.objective == pytest.approx(sum(objs), rel=1e-12)
    assert d.verdict == "PASS"
    figs = [b.name for s in sections(d) for b in s.blocks if isinstance(b, Fig)]
    assert figs == ["response_1", "residual_1", "edges_1", "response_2", "residual_2", "edges_2"]
    # a wrong reported MSE is caught
    result["mse"] *= 1.01
    bad = analyse(IdentificationResult.from_json(result))
    assert bad.verdict == "FAIL"
    assert [c.status for c in bad.checks if c.name == "reported MSE reproduced"] == ["fail"]


def test_sample_count_mismatch_is_refused(tmp_path: Path) -> None:
    t, u = pulse_usetp(duration=1.0, rate=100.0)
    csv, _ = write_capture(tmp_path / "c.csv", {"time": t, "usetp": u, "efd": np.ones_like(t)})
    values = load_unit(None).values()
    result = result_of(mse=0.0, objective=0.0,
                       params={k: v for k, v in values.items() if math.isfinite(v)},
                       fixed={k: None for k, v in values.items() if not math.isfinite(v)},
                       captures=[capture_entry(csv, n=5)])
    with pytest.raises(ReportError, match=r"captures\[0\].n: result says 5 samples, .*c.csv has 101"):
        analyse(result)


def test_fit_window_failed_flag_and_null_history(tmp_path: Path) -> None:
    unit = load_unit(None)
    t, u = pulse_usetp(amplitude=0.05, width=0.5, start=0.5, duration=3.0, rate=500.0)
    rec = synthetic_record(unit, t, u, RecorderModel(), seed=5)
    csv, _ = write_capture(tmp_path / "w.csv", rec)
    values = {**unit.values(), "KAVR": 170.0}
    sim, _, _ = simulate(values, u, 1 / 500.0)
    r = (rec["efd"] - sim)[250:1001]  # 0.5 s .. 2.0 s, both ends included
    result = result_json(fit_window=[0.5, 2.0], mse=float(np.mean(r ** 2)),
                         objective=float(np.trapezoid(r ** 2, dx=1 / 500.0)),
                         captures=[capture_entry(csv)],
                         params={k: values[k] for k in AVR_PARAMS},
                         fixed={k: (None if math.isinf(v) else v) for k, v in values.items()
                                if k not in AVR_PARAMS},
                         history=[[8, None], [16, 0.5], [24, 0.2]])
    d = analyse(IdentificationResult.from_json(result))
    # KAVR off by 15 %: far above the noise floor (a warning), and beyond the default numeric
    # acceptance limits (a failure), nothing else
    assert d.verdict == "FAIL", d.checks
    assert [c.name for c in d.checks if c.status == "warn"] == ["fit vs noise floor"]
    assert [c.name for c in d.checks if c.status == "fail"] == ["numeric acceptance (IEC 61400-27-2)"]
    assert d.objective == pytest.approx(result["objective"], rel=1e-12)
    assert d.mse == pytest.approx(result["mse"], rel=1e-12)  # over the window...
    assert d.captures[0].figures.mse == pytest.approx(np.mean((rec["efd"] - sim) ** 2), rel=1e-12)
    assert d.captures[0].figures.mse < 0.6 * d.mse  # ...and not over the whole record
    secs = {s.id: s for s in sections(d)}
    conv = [b for b in secs["convergence"].blocks if isinstance(b, Fig)]
    assert len(conv) == 1 and "1 history entries without" in conv[0].caption
    failed = analyse(IdentificationResult.from_json({**result, "failed": True, "message": "max_evals reached"}))
    assert failed.verdict == "FAIL"
    assert "failed fit: max_evals reached" in failed.checks[1].detail
    with pytest.raises(ReportError, match=r"fit_window must be null or \[t0, t1\]"):
        analyse(IdentificationResult.from_json({**result, "fit_window": [2.0, 0.5]}))


def test_a_value_outside_its_bounds_fails_the_report() -> None:
    """The `local` peer ignores bounds by design: such a result must not pass as validated."""
    from bench_ctl.report import checks as chk
    from bench_ctl.units.unit import outside_bounds

    bounds = {"KAVR": [50, 100], "TE": [0.002, 0.2]}
    assert outside_bounds({"KAVR": 100.0, "TE": 0.2}, bounds) == []   # on a bound: inside
    out = outside_bounds({"KAVR": 193.6, "TE": 0.02}, bounds)
    assert out == ["KAVR = 193.6 [50, 100]"]
    checks = chk.summary_checks(sim_failures=[], mse_recomputed=1e-4, mse_reported=1e-4, constraints=[],
                                noise_floor=None, noise_source="", noise_ratio_limit=2.0, determined=None,
                                at_bounds=[], n_captures=1, outside_bounds=out)
    assert chk.overall(checks) == "FAIL"
    assert [c.detail for c in checks if c.status == "fail"] == ["outside its bounds: KAVR = 193.6 [50, 100]"]
