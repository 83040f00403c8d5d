"""Accuracy of the gap diagnosis on a small fixed-seed blind suite (issue 7, section 5).

One case per effect plus two effect-free cases (500 Hz, 8 s captures to keep the test near a
minute; the benchmark `benchmarks/diagnose_blind.py` runs the full suite at 1 kHz / 10 s). The
diagnosis only sees the captures and the reference unit; the truth is withheld in the Case.
"""
from __future__ import annotations

import pytest

from bench_ctl.diagnosis import diagnose
from bench_ctl.diagnosis.blind import NONE, SuiteConfig, make_suite, run_suite, score
from bench_ctl.model.effects import EFFECT_NAMES

CFG = SuiteConfig(rate_hz=500.0, duration_s=8.0)


@pytest.fixture(scope="module")
def scored():
    cases = make_suite(1, 2, seed=2024, cfg=CFG)
    assert [c.effect for c in cases] == list(EFFECT_NAMES) + [NONE, NONE]
    results = run_suite(cases, diagnose)
    return results, score(results)


def test_top1_over_the_eight_effects(scored):
    results, s = scored
    wrong = [(r.truth, r.verdict, r.ranking[:3]) for r in results if r.truth != NONE and r.verdict != r.truth]
    assert s["top1_correct"] >= 7, wrong


def test_none_on_effect_free_captures(scored):
    results, s = scored
    assert s["none_correct"] == s["none_cases"] == 2, [(r.case_id, r.verdict) for r in results if r.truth == NONE]


def test_gap_closed_on_the_holdout(scored):
    results, s = scored
    assert s["median_gap_closed"] >= 0.8, [(r.case_id, r.gap_closed_holdout) for r in results]
