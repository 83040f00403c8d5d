"""What a capture determines: uncertainty, flags for undetermined parameters, equivalent sets.

The predicted standard deviations are checked against an independent Monte-Carlo estimate
(the spread of fits over several noise realisations); the flags against situations whose
answer is known from the model's structure (a pole-zero cancellation, a record that ends before
the slow lag shows, the lead-lag symmetry of the reference AVR).
"""
from __future__ import annotations

import numpy as np
import pytest

from bench_ctl.identification.construction import make_problem
from bench_ctl.identification.identifiability import analyse
from bench_ctl.identification.peers import run_optimizer
from bench_ctl.identification.synthetic import synthetic_capture
from bench_ctl.units.overrides import apply_overrides
from bench_ctl.units.unit import reference_unit
from truth import TRUTH


def _unit_with(unit, values):
    return apply_overrides(unit, [f"{k}={v}" for k, v in values.items()])


def _x(problem, values):
    return np.array([values[n] for n in problem.names])


def test_well_determined_set_all_flags_true_and_std_matches_monte_carlo(unit):
    truth = _unit_with(unit, TRUTH)
    fits = []
    for seed in range(8):
        p = make_problem([synthetic_capture(truth, duration=3.0, rate=500.0, seed=100 + seed)], truth, fit_edges=False)
        # start at the truth: the Monte Carlo measures the noise's effect, not the optimizer
        fits.append(run_optimizer("local", p, max_evals=150, seed=0).x)
    a = analyse(p, _x(p, TRUTH)).to_json()
    assert all(a["determined"].values()), a["reasons"]
    spread = np.std(np.log(np.array(fits)), axis=0, ddof=1)
    pred = np.array([a["rel_std"][n] for n in p.names])
    # 8 samples: the sample std is within a factor ~2 of the true one with high probability
    ratio = spread / pred
    assert np.all(ratio > 0.35) and np.all(ratio < 2.2), dict(zip(p.names, ratio.round(2)))
    corr = np.array(a["correlation"])
    assert corr.shape == (6, 6) and np.allclose(corr, corr.T) and np.allclose(np.diag(corr), 1.0)
    assert all(v > 0 for v in a["sensitivity"].values())


def test_pole_zero_cancellation_is_flagged_as_a_singular_direction(unit):
    # TA1 = TA4: (1 + s TA1)/(1 + s TA4) cancels, only TA1 - TA4 = 0 is seen, not their value
    vals = {**TRUTH, "TA1": 1.5, "TA4": 1.5}
    truth = _unit_with(unit, vals)
    p = make_problem([synthetic_capture(truth, duration=3.0, rate=500.0, seed=1)], unit, fit_edges=False)
    a = analyse(p, _x(p, vals)).to_json()
    assert a["determined"]["TA1"] is False and a["determined"]["TA4"] is False
    assert any("singular direction" in r for r in a["reasons"]["TA1"])
    assert a["determined"]["TE"] and a["determined"]["TA2"]
    assert any("singular direction" in n and "TA1" in n and "TA4" in n for n in a["notes"])


def test_record_too_short_to_see_the_slow_lag(unit):
    # reference unit (TA4 = 10 s): a step recorded for 0.5 s after the edge cannot fix TA4 or KAVR
    truth = unit
    cap = synthetic_capture(truth, duration=1.5, rate=500.0, seed=2, width=None)
    p = make_problem([cap], unit, fit_edges=False)
    a = analyse(p, p.x_start()).to_json()
    assert a["determined"]["TA4"] is False and a["determined"]["KAVR"] is False
    assert a["rel_std"]["TA4"] is None or a["rel_std"]["TA4"] > 0.25
    # TE is well fixed by the record; only its exchange with TA2 (0.2 s <-> 0.02 s, both inside
    # the bounds) leaves it undetermined
    assert a["rel_std"]["TE"] < 0.25
    te = a["reasons"]["TE"]
    assert te and all(r.startswith("exchangeable (lag TA2 <-> bridge lag TE") for r in te)
    assert "TA4" in a["notes"][-1]
    # the same unit over a 10 s record does determine the lag better
    long = make_problem([synthetic_capture(truth, duration=10.0, rate=500.0, seed=2)], unit, fit_edges=False)
    b = analyse(long, long.x_start()).to_json()
    assert b["rel_std"]["TA4"] < (a["rel_std"]["TA4"] or np.inf)


def test_reference_unit_lead_swap_is_equivalent_and_allowed(unit):
    cap = synthetic_capture(unit, duration=3.0, rate=500.0, seed=3)
    p = make_problem([cap], unit, fit_edges=False)
    a = analyse(p, p.x_start()).to_json()
    sets = {e["note"]: e for e in a["equivalent_sets"]}
    lead = sets["leads TA1 <-> TA3 swapped"]
    assert lead["params"]["TA1"] == 0.5 and lead["params"]["TA3"] == 1.0
    assert lead["equivalent"] and lead["allowed"]
    assert a["determined"]["TA1"] is False and a["determined"]["TA3"] is False
    assert any("exchangeable" in r for r in a["reasons"]["TA1"])
    pair = sets["(TA1,TA2) <-> (TA3,TA4) swapped"]
    assert pair["equivalent"] and not pair["allowed"]
    assert set(pair["constraints_violated"]) == {"TA2 <= TA1", "TA4 >= TA2"}
    assert "ruled out" in pair["verdict"]
    # the MSE of an equivalent set equals the optimum's within the tolerance used
    assert abs(lead["mse"] - np.mean(p.mse(p.x_start()))) <= a["settings"]["equivalence_tol_mse"]


def test_constraints_rule_out_the_lead_swap_when_ta3_is_below_ta2(unit):
    truth = _unit_with(unit, TRUTH)  # TA3 = 0.1 < TA2 = 0.3: the swap would break TA2 <= TA1
    p = make_problem([synthetic_capture(truth, duration=3.0, rate=500.0, seed=4)], unit, fit_edges=False)
    a = analyse(p, _x(p, TRUTH)).to_json()
    lead = {e["note"]: e for e in a["equivalent_sets"]}["leads TA1 <-> TA3 swapped"]
    assert lead["equivalent"] and not lead["allowed"]
    assert lead["constraints_violated"] == ["TA2 <= TA1"]
    assert a["determined"]["TA1"] and a["determined"]["TA3"]


def test_a_changed_response_is_not_called_equivalent(unit):
    # swapping TA1 with TA2 (a lead with a lag) is not a symmetry: check the tolerance bites
    truth = _unit_with(unit, TRUTH)
    p = make_problem([synthetic_capture(truth, duration=3.0, rate=500.0, seed=4)], unit, fit_edges=False)
    x = _x(p, TRUTH)
    y = x.copy()
    y[1], y[2] = x[2], x[1]
    a = analyse(p, x).to_json()
    tol = a["settings"]["equivalence_tol_mse"]
    assert np.mean(p.mse(y)) - np.mean(p.mse(x)) > 10 * tol


def test_a_capture_of_weight_zero_changes_nothing(unit):
    """alpha = 0 takes a capture out of the objective: the uncertainty must be that of the other
    capture alone (no NaN sensitivities, no zero rows counted as degrees of freedom)."""
    truth = _unit_with(unit, TRUTH)
    cap = synthetic_capture(truth, duration=3.0, rate=500.0, seed=7)
    other = synthetic_capture(truth, duration=3.0, rate=500.0, seed=8)
    single = make_problem([cap], truth, fit_edges=False)
    alone = analyse(single, _x(single, TRUTH)).to_json()
    p = make_problem([cap, other], truth, weights=[1.0, 0.0], fit_edges=False)
    both = analyse(p, _x(p, TRUTH)).to_json()
    for key in ("sensitivity", "rel_std"):
        for n in p.names:
            assert both[key][n] == pytest.approx(alone[key][n], rel=1e-9), (key, n)


def test_every_declared_exchange_of_every_structure_is_examined():
    """Each structure's declared exchanges (`Structure.swaps`) are built and reported among the
    equivalent sets when both parameters are fitted (a pair of limits: with the limits fitted, as
    `--model auto` fits them), and named in the notes when one is not."""
    from bench_ctl.identification.candidates import free_limits
    from bench_ctl.model.structures import STRUCTURES
    from bench_ctl.units.overrides import with_model

    examined = 0
    for name, st in STRUCTURES.items():
        u = with_model(reference_unit(), name)
        cap = synthetic_capture(u, duration=3.0, rate=500.0, seed=11)
        for fitted in (u, free_limits(u)):
            p = make_problem([cap], fitted, fit_edges=False)
            a = analyse(p, p.x_start()).to_json()
            reported = {e["note"] for e in a["equivalent_sets"]}
            for note, pair in st.swaps:
                if not {st.kernel_name(n) for n in pair} <= set(p.names):
                    assert any(n.startswith(f"{note}: not examined") for n in a["notes"]), (name, note)
                    continue
                assert note in reported or any(n.startswith(f"{note}: gives the same point") for n in a["notes"]), \
                    (name, note)
                examined += 1
    assert examined >= 4  # the reference's two lag exchanges, IEEEX1's, ESST4B's limits

    u = reference_unit()
    p = make_problem([synthetic_capture(u, duration=3.0, rate=500.0, seed=11)], u, fit_edges=False,
                     names=["KAVR", "TA1", "TA2", "TA3", "TA4"])
    notes = analyse(p, p.x_start()).to_json()["notes"]
    for note, _pair in u.structure.swaps:
        assert f"{note}: not examined, TE not fitted" in notes


def test_reference_lag_exchanged_with_te_is_equivalent_and_within_the_bounds(unit):
    # the unit's values: TA2 = 0.2 s and TE = 0.02 s can trade places inside their bounds and
    # constraints; TA4 = 10 s cannot become TE (<= 0.2 s)
    p = make_problem([synthetic_capture(unit, duration=3.0, rate=500.0, seed=3)], unit, fit_edges=False)
    a = analyse(p, p.x_start()).to_json()
    sets = {e["note"][:12]: e for e in a["equivalent_sets"]}
    ta2 = sets["lag TA2 <-> "]
    assert ta2["params"]["TA2"] == 0.02 and ta2["params"]["TE"] == 0.2
    assert ta2["equivalent"] and ta2["allowed"]
    assert any("exchangeable (lag TA2 <-> bridge lag TE" in r for r in a["reasons"]["TE"])
    ta4 = sets["lag TA4 <-> "]
    assert ta4["equivalent"] and not ta4["in_bounds"] and ta4["constraints_violated"] == ["TA4 >= TA2"]
    assert ta4["verdict"] == "equally good but ruled out by constraints TA4 >= TA2; bounds"
    # at the identification tests' truth (TA2 = 0.3 s, TE = 0.03 s) the bounds tell them apart
    truth = _unit_with(unit, TRUTH)
    q = make_problem([synthetic_capture(truth, duration=3.0, rate=500.0, seed=4)], unit, fit_edges=False)
    b = analyse(q, _x(q, TRUTH)).to_json()
    e = {s["note"][:12]: s for s in b["equivalent_sets"]}["lag TA2 <-> "]
    assert e["equivalent"] and e["outside_bounds"] == ["TE = 0.3 outside [0.002, 0.2]"]
    assert b["determined"]["TA2"] and b["determined"]["TE"]


def test_notes_are_made_in_kernel_names_and_said_in_the_structures_by_the_writer():
    """IEEEX1's TE is the kernel's TEX and its TA the kernel's TE: a note on the kernel's TEX reads
    TE once the result's writer renames it, and the structure's own note on the TA <-> TE exchange
    is left as it is (a text translation of it would read "TA <-> ... TA")."""
    from bench_ctl.model.dialect import dialect_of
    from bench_ctl.units.overrides import with_model

    u = with_model(reference_unit(), "IEEEX1")
    p = make_problem([synthetic_capture(u, duration=3.0, rate=500.0, seed=11)], u, fit_edges=False)
    assert {"TE", "TEX"} <= set(p.names)
    x = p.x_start()
    x[list(p.names).index("TEX")] = p.lower[list(p.names).index("TEX")]    # the exciter's TE on its bound
    kernel = analyse(p, x)
    on_bound = [n for n in kernel.notes if "sits on its bound" in n]
    assert any(n.startswith("TEX = ") for n in on_bound), kernel.notes     # inside: the kernel's names
    said = kernel.renamed(dialect_of(u.structure)).to_json()
    assert any(n.startswith("TE = ") and "sits on its bound" in n for n in said["notes"]), said["notes"]
    assert not any("TEX" in n for n in said["notes"]), said["notes"]
    assert "TE" in said["determined"] and "TEX" not in said["determined"]
    swap_note = u.structure.swaps[0][0]     # "regulator lag TA <-> exciter time constant TE (...)"
    texts = [e["note"] for e in said["equivalent_sets"]] + said["notes"]
    assert any(t.startswith(swap_note) for t in texts), texts
    assert not any("exciter time constant TA" in t for t in texts), texts
