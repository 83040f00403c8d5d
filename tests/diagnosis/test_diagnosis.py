"""Unit tests of the gap diagnosis: noise floor, edges, localization, feature tests, gap formula,
lag variants, the JSON contract and the command line."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bench_ctl.capture import Capture, write_capture
from bench_ctl.diagnosis import SCHEMA, Budget, DiagnosisError, diagnose
from bench_ctl.diagnosis import features as F
from bench_ctl.diagnosis.blind import SuiteConfig, make_case
from bench_ctl.diagnosis.starts import lag_variants
from bench_ctl.diagnosis.verdict import choose_verdict
from bench_ctl.diagnosis.verdict import gap as _gap
from bench_ctl.engine.simulate import pulse_usetp, simulate
from bench_ctl.identification.localize import BANDS_HZ, band_shares, localization, noise_floor, segments
from bench_ctl.identification.localize import pulse_edges as find_edges
from bench_ctl.identification.threads import set_fit_threads
from bench_ctl.units.unit import load_unit

DT = 0.001


@pytest.fixture(scope="module")
def unit():
    return load_unit(None)


@pytest.fixture(scope="module")
def pulse():
    t, u = pulse_usetp(amplitude=0.05, width=1.0, start=1.0, duration=6.0, rate=1000.0)
    return t, u


# ---------------------------------------------------------------- edges and noise floor

def test_find_edges_pulse_and_step(pulse):
    _, u = pulse
    e = find_edges(u)
    assert (e.lead.index, e.trail_index) == (1000, 2000)
    assert e.lead.jump_pu == pytest.approx(0.05)
    step = np.where(np.arange(3000) >= 500, 1.05, 1.0)
    s = find_edges(step)
    assert s.lead.index == 500 and s.trail_index is None
    with pytest.raises(DiagnosisError, match="never changes"):
        find_edges(np.ones(100))


def test_noise_floor_removes_drift_and_estimates_variance(pulse):
    _, u = pulse
    rng = np.random.default_rng(1)
    sigma = 0.02
    efd = 1.0 + 0.05 * np.arange(u.size) * DT + rng.normal(0, sigma, u.size)  # drift 0.05 pu/s
    nf = noise_floor(efd, DT, find_edges(u))
    assert nf.n == 1000 - 2
    # within 4 standard errors of the true variance; the drift would add ~0.0002 pu^2 if kept
    assert abs(nf.variance - sigma ** 2) < 4 * nf.rel_se * sigma ** 2
    assert nf.rel_se == pytest.approx(math.sqrt(2 / (nf.n - 2)))


def test_noise_floor_needs_pre_trigger_samples():
    u = np.where(np.arange(500) >= 10, 1.05, 1.0)
    with pytest.raises(DiagnosisError, match="pre-trigger samples"):
        noise_floor(np.ones(500), DT, find_edges(u))


# ---------------------------------------------------------------- localization

def test_segment_shares_sum_to_one_and_locate_the_residual(pulse):
    _, u = pulse
    e = find_edges(u)
    rng = np.random.default_rng(2)
    r = rng.normal(0, 0.01, u.size)
    loc = localization(r, DT, e)
    names = [s.name for s in loc.segments]
    assert names == ["pre_trigger", "leading_edge", "plateau", "trailing_edge", "recovery"]
    assert sum(s.share for s in loc.segments) == pytest.approx(1.0)
    assert sum(b.share for b in loc.bands) == pytest.approx(1.0)
    # segments tile the record
    segs = segments(u.size, DT, e)
    assert segs[0].k0 == 0 and segs[-1].k1 == u.size
    assert all(a.k1 == b.k0 for a, b in zip(segs, segs[1:]))
    # a residual only in the trailing edge segment
    r2 = np.zeros(u.size)
    r2[2000:2100] = 0.1
    shares = {s.name: s.share for s in localization(r2, DT, e).segments}
    assert shares["trailing_edge"] == pytest.approx(1.0)
    assert shares["plateau"] == 0.0


@pytest.mark.parametrize("freq, band", [(0.3, "slow"), (4.0, "loop"), (40.0, "fast")])
def test_band_shares_put_a_sine_in_its_band(freq, band):
    t = np.arange(8000) * DT
    shares = {b.name: b.share for b in band_shares(np.sin(2 * np.pi * freq * t), DT)}
    assert set(shares) == {name for name, _, _ in BANDS_HZ}
    assert shares[band] > 0.95


# ---------------------------------------------------------------- feature tests

@pytest.fixture(scope="module")
def traces(unit, pulse):
    t, u = pulse
    free, _, _ = simulate(unit.values(), u, DT)
    lim = unit.with_effects({"ceiling_limit": {"VRMAX": 2.6, "VRMIN": -0.5}})
    clipped, _, _ = simulate(lim.values(), u, DT)
    rng = np.random.default_rng(3)
    noise = rng.normal(0, 0.01, u.size)
    return {"u": u, "free": free, "clipped": clipped, "noise": noise, "edges": find_edges(u)}


def test_flat_top_detects_a_clamped_response_only(traces):
    e, sigma = traces["edges"], 0.01
    hit = F.flat_top(traces["clipped"] + traces["noise"], traces["free"], DT, e, sigma)
    assert hit.detected
    assert hit.values["top_level"] == pytest.approx(2.6, abs=0.02)
    assert hit.values["bottom_level"] == pytest.approx(-0.5, abs=0.02)
    miss = F.flat_top(traces["free"] + traces["noise"], traces["free"], DT, e, sigma)
    assert not miss.detected


def test_delay_measures_a_shift(traces):
    e, free = traces["edges"], traces["free"]
    shift = 20
    late = np.concatenate([np.full(shift, free[0]), free[:-shift]]) + traces["noise"]
    d = F.delay(late, free, DT, e, 0.01)
    assert d.detected
    assert d.values["delay_s"] == pytest.approx(shift * DT, abs=2 * DT)
    same = F.delay(free + traces["noise"], free, DT, e, 0.01)
    assert not same.detected
    assert abs(same.values["delay_s"]) <= 2 * DT


def test_level_features_against_the_model():
    se = 0.01 / math.sqrt(998)
    assert F.pre_trigger_level(1.05, se, 1.0).detected
    assert F.pre_trigger_level(1.05, se, 1.0).values["ratio"] == pytest.approx(1.05)
    assert not F.pre_trigger_level(1.0003, se, 1.0).detected
    assert F.steady_state_ratio(1.08, se, 1.0, 1.0).detected
    assert not F.steady_state_ratio(1.0, se, None, 1.0).detected
    assert not F.steady_state_ratio(0.95, se, 1.0, 1.0).detected  # below 1 is no saturation


def test_asymmetry_and_edge_shape(unit, traces, pulse):
    e = traces["edges"]
    one_sided = unit.with_effects({"ceiling_limit": {"VRMAX": 20.0, "VRMIN": -0.3}})
    _, u = pulse
    low, _, _ = simulate(one_sided.values(), u, DT)
    assert F.asymmetry(low + traces["noise"], traces["free"], DT, e, 0.01).detected
    assert not F.asymmetry(traces["free"] + traces["noise"], traces["free"], DT, e, 0.01).detected
    ramped, _, _ = simulate(unit.with_effects({"setpoint_ramp": {"RAMP": 0.25}}).values(), u, DT)
    shape = F.edge_shape(ramped + traces["noise"], traces["free"], DT, e, 0.01, 0.05)
    assert shape.detected and shape.values["leading_straightness"] > 0.65
    assert not F.edge_shape(traces["free"] + traces["noise"], traces["free"], DT, e, 0.01, 0.05).detected
    slew, _, _ = simulate(unit.with_effects({"rate_limit": {"RATE": 20.0}}).values(), u, DT)
    capped = F.edge_shape(slew + traces["noise"], traces["free"], DT, e, 0.01, 0.05)
    assert capped.detected and capped.values["leading_slope"] == pytest.approx(20.0, rel=0.1)


# ---------------------------------------------------------------- gap, lag variants

def test_verdict_is_the_best_significant_effect_not_the_best_scored():
    from bench_ctl.diagnosis.diagnosis_file import EffectEntry
    from records import effect_json

    def e(name, score, d_bic, d_check, significant):
        return EffectEntry.from_json(effect_json(name, score=score, delta_bic=d_bic, delta_check=d_check,
                                                 significant=significant))
    # A fits the fit record far better but is worse on the check record: not significant
    entries = [e("A", -195.0, 200.0, -5.0, False), e("B", -80.0, 50.0, 30.0, True),
               e("C", 3.0, -3.0, 0.0, False)]
    assert choose_verdict(entries, at_floor=False, has_check=True) == "B"
    # at the noise floor B is not strong enough (delta BIC 50 < 100); nothing significant: none
    assert choose_verdict(entries, at_floor=True, has_check=True) == "none"
    assert choose_verdict([entries[0], entries[2]], at_floor=False, has_check=True) == "none"
    strong = [e("A", -195.0, 200.0, -5.0, False), e("B", -300.0, 320.0, 40.0, True)]
    assert choose_verdict(strong, at_floor=True, has_check=True) == "B"


def test_an_effect_the_windows_cannot_judge_is_accepted_on_the_interleaved_blocks():
    """A one-regime effect: the fit and the interleaved blocks gain, the windows (which leave its
    regime out) do not. Accepted on a strong gain on the blocks, refused on a weak one; at the
    noise floor only a strong gain on either counts."""
    from types import SimpleNamespace

    from bench_ctl.diagnosis.significance import ONE_REGIME_GAIN, SIGNIFICANT, significance
    from bench_ctl.identification.model_fits import ModelFit, Part

    n = 5000
    st = SimpleNamespace(n=n)

    def fit(mse, k, windows, blocks, violated=()):
        return ModelFit((), SimpleNamespace(violated=violated), mse, tuple(Part(f"w{i}", 100.0, w)
                        for i, w in enumerate(windows)), k, 0,
                        blocks=tuple(Part(f"blocks_{i + 1}", n / 2, b) for i, b in enumerate(blocks)))

    base = fit(1e-3, 0, (1e-3, 2e-3), (1e-3, 1e-3))
    # the windows a little worse (-2 x 100 ln 1.1 = -19), the blocks far better (2 x 2500 ln 2 = 3466)
    one_regime = fit(5e-4, 2, (1.1e-3, 2.2e-3), (5e-4, 5e-4))
    g_fit, g_check, ok = significance(st, base, one_regime)
    assert g_fit > SIGNIFICANT and g_check < 0 and ok
    # the blocks only a little better (2 x 2500 ln 1.01 = 50 < ONE_REGIME_GAIN): refused
    weak = fit(5e-4, 2, (1.1e-3, 2.2e-3), (0.99e-3, 0.99e-3))
    assert 0 < 5000 * math.log(1 / 0.99) < ONE_REGIME_GAIN and not significance(st, base, weak)[2]
    # a constraint broken: refused whatever the blocks say
    assert not significance(st, base, fit(5e-4, 2, (1.1e-3, 2.2e-3), (5e-4, 5e-4), violated=("TA",)))[2]

    from bench_ctl.diagnosis.diagnosis_file import EffectEntry
    from records import effect_json

    def e(name, d_bic, d_check, d_blocks):
        return EffectEntry.from_json(effect_json(name, score=-d_bic, delta_bic=d_bic, delta_check=d_check,
                                                 delta_blocks=d_blocks, significant=True))
    assert choose_verdict([e("saturation", 300.0, -19.0, 3466.0)], at_floor=True, has_check=True) == "saturation"
    assert choose_verdict([e("saturation", 300.0, -19.0, 50.0)], at_floor=True, has_check=True) == "none"


def test_what_is_left_is_said_where_it_lies():
    """The residual's localization in words: segments holding >= 5 % of the energy, largest first,
    each over the noise floor; then the bands."""
    from bench_ctl.identification.localize import where_lines
    from bench_ctl.identification.result_file import Localization

    loc = {"segments": [{"name": "pre_trigger", "t0": 0.0, "t1": 1.0, "share": 0.03, "mse": 1e-4},
                        {"name": "leading_edge", "t0": 1.0, "t1": 1.2, "share": 0.6, "mse": 5e-3},
                        {"name": "trailing_edge", "t0": 2.0, "t1": 2.2, "share": 0.37, "mse": 2e-3}],
           "bands": [{"name": "slow", "f0_hz": 0.0, "f1_hz": 1.0, "share": 0.1},
                     {"name": "fast", "f0_hz": 10.0, "f1_hz": 100.0, "share": 0.9}]}
    where, bands = where_lines(Localization.from_json(loc), 1e-4)
    assert where == ("  what is left, where: leading edge 1.00-1.20 s 60 % (50x floor), "
                     "trailing edge 2.00-2.20 s 37 % (20x floor)")
    assert bands == "  by band: slow (0-1 Hz) 10 %, fast (10-100 Hz) 90 %"


def test_ambiguity_is_judged_around_the_verdict_not_the_best_score():
    from bench_ctl.diagnosis.diagnosis_file import EffectEntry
    from bench_ctl.diagnosis.verdict import ambiguous_pairs
    from records import effect_json

    entries = [EffectEntry.from_json(effect_json(name, score=score, significant=sig)) for name, score, sig in
               (("time_skew", -195.0, False), ("dead_time", -80.0, True), ("transducer_lag", -78.0, True),
                ("saturation", -20.0, True))]
    pairs = ambiguous_pairs(entries)
    assert [p.effects for p in pairs] == [["dead_time", "transducer_lag"]]
    assert pairs[0].score_difference == 2.0


def test_gap_closed_formula():
    g, raw = _gap(3e-4, 1.5e-4, 1e-4, 0.05)
    assert g == pytest.approx((3e-4 - 1.5e-4) / (3e-4 - 1e-4)) and raw == pytest.approx(g)
    # base at the floor: the denominator is kept at one standard error of the floor, raw undefined
    g, raw = _gap(1e-4, 0.9e-4, 1e-4, 0.05)
    assert g == pytest.approx(0.1e-4 / (1e-4 * 0.05)) and raw is None
    assert _gap(None, 1e-4, 1e-4, 0.05) == (None, None)


def test_lag_variants_share_the_linear_response(unit, pulse):
    _, u = pulse
    avr = {"KAVR": 150.0, "TA1": 1.2, "TA2": 0.08, "TA3": 0.6, "TA4": 8.0, "TE": 0.03}
    variants = lag_variants(unit, avr)
    assert len(variants) == 2 and variants[1]["TE"] == 0.08 and variants[1]["TA2"] == 0.03
    ref = None
    for v in variants:
        vals = unit.values()
        vals.update(v)
        efd, _, _ = simulate(vals, u, DT)
        ref = efd if ref is None else ref
        assert np.max(np.abs(efd - ref)) < 1e-6
    # with a ceiling the two are different models
    outs = []
    for v in variants:
        vals = unit.values()
        vals.update(v)
        vals.update({"VRMAX": 2.0, "VRMIN": -0.5})
        outs.append(simulate(vals, u, DT)[0])
    assert np.max(np.abs(outs[0] - outs[1])) > 0.05


# ---------------------------------------------------------------- the JSON contract and the CLI

SMALL = SuiteConfig(rate_hz=500.0, duration_s=8.0)
FAST = Budget(base=600, effect=200)


@pytest.fixture(scope="module")
def ceiling_case():
    return make_case("ceiling_limit", 11, SMALL)


@pytest.fixture(scope="module")
def diag(unit, ceiling_case):
    set_fit_threads(2)   # the effects' fits side by side, whatever the machine
    try:
        return diagnose(ceiling_case.capture, unit, holdout=ceiling_case.holdout, budget=FAST, command_line="test")
    finally:
        set_fit_threads(None)


def _figures(d) -> dict:
    """The diagnosis' JSON without when it was made and how long it took."""
    j = d.to_json()
    return {k: v for k, v in j.items() if k not in ("created_utc", "wall_s")}


def test_the_effects_fitted_side_by_side_give_the_answer_of_one_thread(unit, ceiling_case, diag):
    set_fit_threads(1)
    try:
        alone = diagnose(ceiling_case.capture, unit, holdout=ceiling_case.holdout, budget=FAST, command_line="test")
    finally:
        set_fit_threads(None)
    assert _figures(alone) == _figures(diag)


def test_diagnosis_json_keys(diag):
    assert diag.schema == SCHEMA
    scores = [e.score for e in diag.effects]
    assert scores == sorted(scores)
    diag = diag.to_json()
    for key in ("schema", "software_version", "command_line", "created_utc", "capture", "holdout", "base",
                "noise_floor", "localization", "features", "effects", "ambiguous", "sequence", "verdict"):
        assert key in diag
    assert set(diag["base"]) >= {"params", "mse", "mse_holdout"}
    assert {s["name"] for s in diag["localization"]["segments"]} == {
        "pre_trigger", "leading_edge", "plateau", "trailing_edge", "recovery"}
    for f in diag["features"]:
        assert set(f) >= {"name", "detected", "evidence"} and f["evidence"]
    assert len(diag["effects"]) == 8
    for e in diag["effects"]:
        assert set(e) >= {"name", "params", "mse", "mse_holdout", "gap_closed", "score", "aic"}
    json.dumps(diag, allow_nan=False)  # strict JSON: inf / nan written as null


def test_diagnosis_finds_the_ceiling_and_reports_the_gap(diag, ceiling_case):
    assert diag.verdict == "ceiling_limit"
    top = diag.effects[0]
    assert top.params["VRMAX"] == pytest.approx(ceiling_case.effect_params["VRMAX"], abs=0.03)
    # gap_closed on the holdout, recomputed from the reported figures (the holdout part of the check)
    floor_h = diag.noise_floor_detail.holdout
    hold = {e: next(p.mse for p in c.check.parts if p.label == "holdout") for e, c in
            (("base", diag.base), ("top", top))}
    expect = (hold["base"] - hold["top"]) / (hold["base"] - floor_h)
    assert top.gap_closed_holdout == pytest.approx(expect)
    assert top.gap_closed_holdout > 0.8
    assert diag.sequence[0].added == "ceiling_limit"
    assert [s.name for s in diag.explained_by] == ["ceiling_limit"]
    # the last step is the model `left` speaks of (polished as far as the sequence went), with its
    # own parameters: the model an engineer takes away
    assert diag.explained_by[-1].mse == diag.left.mse
    last = diag.explained_by[-1].avr_params
    assert set(last) == set(diag.base.params) and last != diag.base.params
    # the check: the holdout and the capture's windows, each window left out of a re-fit
    labels = [p.label for p in top.check.parts]
    assert labels == ["holdout", "leading_edge", "plateau", "trailing_edge", "vt"]  # vt: recorded, not fitted
    assert diag.validation.kind == "holdout + windows"
    # beside the check, the interleaved blocks: two halves of the record, each scored left out
    blocks = top.check.blocks
    assert [b.label for b in blocks] == ["blocks_1", "blocks_2"]
    assert sum(b.samples for b in blocks) == pytest.approx(ceiling_case.capture.n, abs=2)
    assert top.delta_blocks > 0 and diag.check.blocks.to_json() == {"seconds": 0.05, "folds": 2}


def test_a_left_out_part_is_scored_on_the_linear_prediction_only_where_it_holds(unit, ceiling_case, monkeypatch):
    """Far from the optimum (the unit file's values) the undamped Gauss-Newton step of a left-out
    re-fit does not do, simulated, what its linear prediction promised: the check damps it until it
    does, and with no damping trusted scores the model as it is (its mean objective over the part's
    samples; the two halves of the blocks are then the whole record). The structure selection's
    `linear` check scores the undamped prediction, which is other figures there."""
    from bench_ctl.identification import fit_check as check
    from bench_ctl.identification.fit_check import prepare

    _, _, st = prepare(ceiling_case.capture, unit)
    p = st.views.problem(())
    x = p.x_start()
    R, _ = p.residuals(x[None, :])
    cap, t, sec = p.residual_rows()
    r = R[0][cap == 0]
    t, sec = t[cap == 0], sec[cap == 0]
    itself = {}
    for w in st.views.windows:
        inw = (t >= w.t0 - 1e-12) & (t <= w.t1 + 1e-12)
        itself[w.label] = float(r[inw] @ r[inw] / sec[inw].sum())

    monkeypatch.setattr(check, "TRUST", math.inf)          # no step trusted
    windows, blocks = check._left_out(st.views, p, x)
    assert [w.label for w in windows] == list(itself)
    for w in windows:
        assert w.mse == pytest.approx(itself[w.label], rel=1e-12)
    whole = sum(b.mse * b.n for b in blocks) / sum(b.n for b in blocks)
    assert whole == pytest.approx(float(p.mean_objective(x[None, :])[0]), rel=0.02)
    monkeypatch.undo()

    linear = check.check_parts(st.views, p, x, linear=True)
    assert any(abs(a.mse / itself[a.label] - 1.0) > 0.01 for a in linear if a.label in itself)
    damped, _ = check._left_out(st.views, p, x)
    assert all(np.isfinite(w.mse) for w in damped)
    # the damped re-fit's figures stay within an order of the model's own error there
    assert max(w.mse for w in damped) < 10 * max(itself.values())


@pytest.mark.slow
def test_diagnosis_without_holdout_checks_on_windows_of_the_record(unit, ceiling_case):
    """No holdout: every model is fitted on the whole capture and judged by cross-validation over
    its windows; the ceiling acts at the edges, so that is where its check gain lies."""
    d = diagnose(ceiling_case.capture, unit, budget=FAST)
    v = d.validation
    cap = ceiling_case.capture
    assert v.kind == "windows" and d.holdout is None
    assert v.fit.to_json() == {"t0": 0.0, "t1": pytest.approx((cap.n - 1) * cap.dt)}
    wins = {w.label: (w.t0, w.t1) for w in v.check.windows}
    assert list(wins) == ["leading_edge", "plateau", "trailing_edge"]
    assert wins["leading_edge"][0] == pytest.approx(1.0, abs=cap.dt) and wins["trailing_edge"][0] == pytest.approx(
        2.0, abs=cap.dt)
    assert d.verdict == "ceiling_limit"
    top = d.effect("ceiling_limit")
    base_parts = {p.label: p.mse for p in d.base.check.parts}
    top_parts = {p.label: p.mse for p in top.check.parts}
    gain = {k: base_parts[k] / top_parts[k] for k in base_parts}
    assert gain["leading_edge"] > 2.0 and gain["trailing_edge"] > 2.0, gain
    # the report re-simulates the base fit over the whole record with the fitted edge instants
    from bench_ctl.commands.diagnose import base_result
    from bench_ctl.engine.simulate import simulate
    from bench_ctl.identification.timing import fitted_edge_plan

    res = base_result(d, cap, unit)
    assert res.fit_window is None
    spec, offsets = fitted_edge_plan(res.captures[0].edges, cap.n)
    assert set(offsets) == {"EDGE1", "EDGE2"} and all(-cap.dt <= v <= 0 for v in offsets.values())
    efd, _, _ = simulate({**unit.values(), **d.base.params, **offsets}, cap.usetp, cap.dt, edges=spec)
    e2 = (cap.efd - efd) ** 2
    assert np.mean(e2) == pytest.approx(res.mse, rel=1e-9)
    # the diagnosis' mse is the objective per second: the trapezoidal mean of the squared error
    assert (np.sum(e2) - 0.5 * (e2[0] + e2[-1])) / (cap.n - 1) == pytest.approx(d.base.mse, rel=1e-9)


@pytest.mark.slow
def test_effect_free_capture_gives_none(unit):
    case = make_case("none", 12, SMALL)
    d = diagnose(case.capture, unit, holdout=case.holdout, budget=FAST)
    assert d.verdict == "none"
    assert d.sequence == () and d.ambiguous == ()
    assert d.base.mse < 1.2 * d.noise_floor
    # no gap to close: the headline fraction is withheld, the raw figures stay for the record
    assert d.base.at_noise_floor is True
    assert all(e.gap_closed is None and e.gap_closed_on is None for e in d.effects)
    assert all(e.gap_closed_fit is not None for e in d.effects)


@pytest.mark.slow
def test_cli_writes_the_diagnosis(tmp_path, ceiling_case):
    from bench_ctl.cli import main
    main_csv, _ = write_capture(tmp_path / "main.csv", ceiling_case.capture)
    hold_csv, _ = write_capture(tmp_path / "hold.csv", ceiling_case.holdout)
    out = tmp_path / "diag.json"
    html = tmp_path / "diag.html"
    rc = main(["diagnose", str(main_csv), "--holdout", str(hold_csv), "--json", str(out), "--report", str(html)])
    assert rc == 1  # an effect was found
    d = json.loads(out.read_text())
    assert d["schema"] == SCHEMA and d["verdict"] == "ceiling_limit"
    page = html.read_text()
    assert 'id="diagnosis-effects"' in page and "ceiling_limit" in page
    assert d["capture"]["sha256"] and d["holdout"]["path"].endswith("hold.csv")
    assert "diagnose" in d["command_line"]
    assert main(["diagnose", str(tmp_path / "missing.csv")]) == 2
    # a --result that is not an identification result: refused before any work, naming it
    for i, bad in enumerate(("[1, 2]", '{"params": {"KAVR": null}}')):
        res = tmp_path / f"bad{i}.json"
        res.write_text(bad)
        assert main(["diagnose", str(main_csv), "--result", str(res)]) == 2


def test_capture_without_pre_trigger_is_refused(unit):
    t = np.arange(2000) * DT
    u = np.where(t >= 0.005, 1.05, 1.0)
    cap = Capture(t, u, np.ones_like(t), source="short.csv")
    with pytest.raises(DiagnosisError, match="short.csv"):
        diagnose(cap, unit)


def test_ambiguous_pairs_name_the_separating_test():
    from dataclasses import replace

    from bench_ctl.diagnosis.diagnosis_file import EffectEntry
    from bench_ctl.diagnosis.significance import AMBIGUOUS
    from bench_ctl.diagnosis.verdict import ambiguous_pairs
    from records import effect_json
    entries = [EffectEntry.from_json(effect_json(name, score=score, significant=sig)) for name, score, sig in
               (("dead_time", -500.0, True), ("time_skew", -500.0 + AMBIGUOUS / 2, True),
                ("setpoint_ramp", -500.0 + AMBIGUOUS / 3, False), ("rate_limit", -400.0, True))]
    amb = ambiguous_pairs(entries)
    assert [a.effects for a in amb] == [["dead_time", "time_skew"]]
    assert "second channel" in amb[0].separating_test
    entries[0] = replace(entries[0], significant=False)
    assert ambiguous_pairs(entries) == []
