"""The diagnosis on line (issue 27, item 5): an on-line record (P and Q recorded) is diagnosed on
the machine on the grid, with the effects the machine runs and the grid's own (`grid_reactance`:
the unit's XE other than the grid's; `pss`: a stabiliser the unit file lacks). Judged on ANDES'
on-line captures (tests/fixtures/andes_online), which no one here simulated."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from andes_units import online_capture, online_entry, online_unit
from bench_ctl.diagnosis.diagnose import diagnose
from bench_ctl.identification.fit_check import prepare
from bench_ctl.identification.localize import DiagnosisError
from bench_ctl.model.effects import vocabulary
from bench_ctl.units.overrides import apply_overrides

#: recorder noise of the captures: efd 0.01 pu, Q 0.002 pu, Vt 0.0005 pu
NOISE = {"noise": 0.01, "q_noise": 0.002, "vt_noise": 0.0005}


def test_the_vocabulary_on_line_is_what_the_machine_on_the_grid_runs():
    on, off = vocabulary(True), vocabulary(False)
    assert {"grid_reactance", "pss"} <= set(on) and not {"grid_reactance", "pss"} & set(off)
    assert not {"dead_time", "setpoint_ramp"} & set(on) and {"dead_time", "setpoint_ramp"} <= set(off)
    assert {"ceiling_limit", "saturation", "transducer_lag", "rate_limit", "recorder_gain",
            "time_skew"} <= set(on) & set(off)
    # a unit that already fits XE has no grid_reactance effect
    assert "grid_reactance" not in vocabulary(True, ("XE",))


def test_a_holdout_of_another_kind_is_refused():
    cap = online_capture("sexs_xe02")
    at_no_load = replace(cap, extra={}, source="noload.csv")
    with pytest.raises(DiagnosisError, match="noload.csv is a no-load record and .*sexs_xe02.csv an on-line one"):
        prepare(cap, online_unit("sexs_xe02"), holdout=at_no_load)


@pytest.mark.slow   # the same [grid]-value machinery as the stabiliser's below, which the quick tier runs
def test_a_wrong_grid_reactance_is_found_and_explains_the_record():
    """ANDES ran the unit through XE = 0.4; the unit file says 0.2. The diagnosis names the grid's
    reactance, finds 0.4, and what is left is the noise."""
    cap = online_capture("sexs_xe04", seed=3, **NOISE)
    unit = apply_overrides(online_unit("sexs_xe04"), ["XE=0.2"])
    d = diagnose(cap, unit, seed=0).to_json()
    assert d["verdict"] == "grid_reactance", [(e["name"], e["significant"]) for e in d["effects"]]
    top = next(e for e in d["effects"] if e["name"] == "grid_reactance")
    assert top["params"]["XE"] == pytest.approx(0.4, rel=0.02)
    assert top["gap_closed"] > 0.95
    assert [s["added"] for s in d["sequence"]] == ["grid_reactance"]
    assert d["explained_by"][-1]["mse_over_floor"] < 1.15
    assert not any(f["name"] == "steady_state_ratio" for f in d["features"])   # a no-load relation


def test_a_stabiliser_the_unit_file_lacks_is_found_with_its_settings():
    """ANDES ran the unit with an IEEEST (KS 10, two lead-lags 0.15 / 0.03 s, washout 10 s) the
    unit file does not have. The diagnosis names `pss`, finds its gain and lead-lags, and what is
    left is the noise."""
    name = "esst1a_xe02_pss"
    d = diagnose(online_capture(name, seed=3, **NOISE), online_unit(name), seed=0).to_json()
    assert d["verdict"] == "pss", [(e["name"], e["significant"]) for e in d["effects"]]
    fitted = d["explained_by"][-1]["params"]
    truth = online_entry(name)["pss_params"]
    assert fitted["PSS_KS"] == pytest.approx(truth["KS"], rel=0.05)
    for k in ("T1", "T2", "T3", "T4"):
        assert fitted[f"PSS_{k}"] == pytest.approx(truth[k], rel=0.1), k
    assert d["explained_by"][-1]["mse_over_floor"] < 1.15 < d["base"]["mse"] / d["noise_floor"]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["sexs_xe02", "esst1a_xe04"])
def test_an_on_line_record_the_model_explains_has_no_effect(name):
    d = diagnose(online_capture(name, seed=1, **NOISE), online_unit(name), seed=0).to_json()
    assert d["verdict"] == "none", [(e["name"], e["delta_bic"], e["delta_check"]) for e in d["effects"]]
    assert d["base"]["at_noise_floor"]


@pytest.mark.slow
def test_an_efd_channel_recorded_late_on_line_is_found_with_its_skew():
    """ANDES' on-line capture with its efd channel written 15 ms late (15 samples: the noise kept
    as drawn), the other channels on time: the diagnosis names the recorder skew, finds 15 ms, and
    what is left is the noise."""
    name = "esst1a_xe04"
    cap = online_capture(name, seed=3, **NOISE)
    k = round(0.015 / (cap.time[1] - cap.time[0]))
    late = replace(cap, efd=np.concatenate([np.full(k, cap.efd[0]), cap.efd[:-k]]))
    d = diagnose(late, online_unit(name), seed=0).to_json()
    assert d["verdict"] == "time_skew", [(e["name"], e["significant"]) for e in d["effects"]]
    assert d["explained_by"][-1]["params"]["SKEW"] == pytest.approx(0.015, abs=0.001)
    assert d["explained_by"][-1]["mse_over_floor"] < 1.15 < d["base"]["mse"] / d["noise_floor"]
