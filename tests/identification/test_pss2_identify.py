"""Identification on line with the unit's PSS2B on (issue 49): an independent record (made outside
the engine by tests/independent_online.py, the PSS2B on, the step between two samples, noise and
12-bit quantisation) identified by `bench-ctl identify` with the unit file that names the PSS2B,
its KS1 fitted from a wrong planning value, reaches the noise floor; the same record identified
with the stabiliser left out of the unit does not (benchmarks/pss2_identify.py: every seed)."""
from __future__ import annotations

import json

import pytest

from bench_ctl.cli import main
from pss2_cases import KS1_PLANNED, make_case, pss_sets

EVALS = 400


def _identify(case, unit, out, sets) -> tuple[float, dict]:
    assert main(["identify", str(case.capture), "--unit", str(unit), *sets, "--evals", str(EVALS), "--seed", "0",
                 "--json", str(out), "--no-progress"]) in (0, 1)
    res = json.loads(out.read_text())
    return res["mse"] / case.noise_efd_var, res


def test_the_pss2b_in_the_unit_fits_an_independent_record_to_its_noise_and_leaving_it_out_does_not(tmp_path):
    case = make_case(tmp_path, 0)
    assert abs(case.pss["KS1"] / KS1_PLANNED - 1.0) > 0.2   # the planning value is not the truth
    assert case.step_s % 1e-3 > 1e-5                         # the step lies between two samples
    ratio, res = _identify(case, case.unit, tmp_path / "with.json", pss_sets())
    ks1 = res["unit"]["grid"]["PSS2_KS1"]
    print(f"PSS2B in the unit: efd MSE {ratio:.4f}x the noise, KS1 {ks1:.3f} (true {case.pss['KS1']:.3f})")
    assert ratio <= 1.05, ratio
    assert ks1 == pytest.approx(case.pss["KS1"], rel=0.1)
    for name in ("K", "TE"):
        assert res["params"][name] == pytest.approx(case.values[name], rel=0.1), name
    bare, _res = _identify(case, case.unit_without_pss, tmp_path / "without.json", [])
    print(f"PSS2B left out: efd MSE {bare:.4f}x the noise")
    assert bare > 1.15, bare


def test_the_stabilisers_two_leads_fitted_are_an_equivalent_set(tmp_path):
    """KS1, T1 and T3 of the PSS2B fitted: the two lead-lags are in series with nothing between them,
    so T1 and T3 exchanged give the same response; the identifiability analysis examines that
    exchange and finds it equally good and allowed (the record cannot tell which lead is which).
    The lags T2, T4 (not fitted) are not examined."""
    case = make_case(tmp_path, 0)
    _ratio, res = _identify(case, case.unit, tmp_path / "leads.json", pss_sets(("KS1", "T1", "T3")))
    sets = {s["note"]: s for s in res["identifiability"]["equivalent_sets"]}
    swap = sets["PSS2B PSS2_T1 <-> PSS2_T3 swapped (lead-lags in series)"]
    grid = res["unit"]["grid"]
    assert swap["equivalent"] and swap["allowed"], swap
    assert swap["params"]["PSS2_T1"] == pytest.approx(grid["PSS2_T3"]) and \
        swap["params"]["PSS2_T3"] == pytest.approx(grid["PSS2_T1"])
    assert not any("PSS2_T2" in note for note in sets)
