"""No `nan` in anything an engineer reads (issue 49 item 7): `diagnose` printed `10-90 % rise nan
ms` and `(base model nan ms, nan)` in its edge_shape line; a figure that cannot be measured is
said so."""
from __future__ import annotations

import math

import numpy as np

from bench_ctl.commands.options import fmt_value
from bench_ctl.diagnosis import features as F
from bench_ctl.identification.localize import pulse_edges


def Edges(k_on: int, k_off: int | None, amplitude: float, n: int = 3000):   # noqa: N802 - reads as a record
    """The setpoint edges the one finder finds in a setpoint stepping at k_on (and back at k_off)."""
    usetp = np.ones(n)
    usetp[k_on:(k_off if k_off is not None else n)] += amplitude
    return pulse_edges(usetp)


def _flat(n: int = 3000, seed: int = 0) -> np.ndarray:
    return 1.0 + np.random.default_rng(seed).normal(0.0, 0.01, n)


def test_edge_shape_says_what_it_cannot_measure():
    meas = _flat()
    model = np.full(meas.size, 1.0)              # a model trace that never rises: no first peak
    edges = Edges(k_on=1000, k_off=2000, amplitude=0.05)
    f = F.edge_shape(meas, model, 1e-3, edges, 0.01, 0.05)
    assert math.isnan(f.values["leading_model_rise_s"])
    assert "nan" not in f.evidence and "base model rise not measurable" in f.evidence
    falling = np.concatenate([np.ones(1000), np.linspace(1.0, 0.5, 2000)])   # goes the other way
    f = F.edge_shape(falling, falling, 1e-3, Edges(1000, None, 0.05), 0.01, 0.05)
    assert "nan" not in f.evidence and "rise not measurable (no rise to a first peak within 500 ms" in f.evidence
    assert f.entry().values["leading_rise_s"] is None        # and null in the JSON


def test_delay_and_asymmetry_say_what_they_cannot_measure():
    meas = _flat()
    edges = Edges(k_on=1000, k_off=2000, amplitude=0.05)
    d = F.delay(meas, np.full(meas.size, 1.0), 1e-3, edges, 0.01)
    assert math.isnan(d.values["delay_s"]) and "nan" not in d.evidence and "not measurable" in d.evidence
    late = Edges(k_on=1000, k_off=meas.size - 5, amplitude=0.05)   # too little after the return to fit a slope
    a = F.asymmetry(meas, meas, 1e-3, late, 0.01)
    assert math.isnan(a.values["slope_down"]) and "nan" not in a.evidence and "down not measurable" in a.evidence


def test_summary_tables_print_no_nan():
    assert fmt_value(float("nan")) == "n/a" and fmt_value(float("inf")) == "inf" and fmt_value(None) == "-"
    assert fmt_value(0.5, ".2f") == "0.50"
