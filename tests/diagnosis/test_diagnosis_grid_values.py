"""A diagnosis on line that fits the unit's [grid] values (XE with --set XE.min/max) writes them
with the model: the base fit's and every explained_by step's parameters carry the XE they were
fitted with, and the report's base result puts it under the unit's [grid], as an identification
does. Found on the Mostar on-line record: the file held only the exciter's values, so whoever
re-simulated the diagnosis' model (benchmarks/real_online.py) used another XE."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from andes_units import online_capture, online_unit
from bench_ctl.commands.diagnose import base_result
from bench_ctl.diagnosis.diagnose import diagnose
from bench_ctl.diagnosis.diagnosis_file import Diagnosis
from bench_ctl.diagnosis.verdict import model_params
from bench_ctl.units.overrides import apply_overrides

NOISE = {"noise": 0.01, "q_noise": 0.002, "vt_noise": 0.0005}


def _unit():
    return apply_overrides(online_unit("sexs_xe04"), ["XE=0.2", "XE.min=0.05", "XE.max=0.8"])


def test_the_model_s_values_include_the_grid_values_it_fits():
    unit = _unit()
    assert set(unit.grid_identify) == {"XE"}
    fitted = {**{n: 1.0 for n in unit.identified_names}, "XE": 0.41, "S10": 0.1, "EDGE1": 0.0}
    got = model_params(unit, SimpleNamespace(params=fitted))
    assert got == {**{n: 1.0 for n in unit.identified_names}, "XE": 0.41}
    # a unit that fits no [grid] value: the exciter's alone, as before
    plain = online_unit("sexs_xe04")
    assert model_params(plain, SimpleNamespace(params=fitted)) == {n: 1.0 for n in plain.identified_names}


@pytest.mark.slow   # one diagnosis on line (~20 s)
def test_a_diagnosis_that_fits_xe_writes_it_and_its_report_result_keeps_it_in_the_grid():
    cap = online_capture("sexs_xe04", seed=3, **NOISE)
    unit = _unit()
    d = diagnose(cap, unit, seed=0)
    base = d.to_json()["base"]["params"]
    assert base["XE"] == pytest.approx(0.4, rel=0.05)   # ANDES ran the unit through XE = 0.4
    r = base_result(Diagnosis.from_json(d.to_json(), "the diagnosis"), cap, unit).to_json()
    assert "XE" not in r["params"]
    assert r["unit"]["grid"]["XE"] == pytest.approx(base["XE"])
