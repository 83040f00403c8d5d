"""The independent plant (tests/independent_plant.py) against solve_ivp, and what it records.

The reference is `reference_efd` of test_kernel_reference.py: the continuous-time equations
integrated by Radau at rtol 1e-10 with the integration split at every input discontinuity, a
third implementation beside the kernel and the independent plant.
"""
from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from test_reference import AMP, CASES, DURATION, REF, reference_efd, tiered

from independent_plant import NO_EFFECT, Plant, Recorder, Test, draw_avr, draw_effect, random_edges

ON, OFF = 0.99963, 1.99918  # between the 1 kHz samples


@pytest.mark.parametrize("case", tiered(list(CASES) + ["saturation+ceiling_limit+dead_time"]))
def test_plant_matches_solve_ivp_with_edges_between_samples(case):
    effects = {}
    for name in case.split("+"):
        effects.update(CASES[name])
    p = {**REF, **NO_EFFECT, **effects}
    rec = Plant(p).run(Test(on_s=ON, amplitude_pu=AMP, width_s=OFF - ON),
                       Recorder(rate_hz=1000.0, duration_s=DURATION, noise_pu=0.0, bits=0))
    ref = reference_efd(p, rec.time, on=ON, off=OFF)
    err = float(np.max(np.abs(rec.efd - ref)))
    assert err < 1e-3, f"{case}: max |efd error| {err:.2e} pu"


def test_recorder_samples_the_setpoint_and_adds_seeded_noise_and_quantisation():
    rate = 1000.0
    test = Test(on_s=ON, width_s=OFF - ON)
    clean = Plant(REF).run(test, Recorder(rate_hz=rate, duration_s=2.5, noise_pu=0.0, bits=0))
    noisy = Plant(REF).run(test, Recorder(rate_hz=rate, duration_s=2.5, noise_pu=0.01, bits=12), seed=3)
    again = Plant(REF).run(test, Recorder(rate_hz=rate, duration_s=2.5, noise_pu=0.01, bits=12), seed=3)
    # a change first seen at sample k happened in (t[k-1], t[k]]
    k_on = int(np.flatnonzero(np.diff(noisy.usetp) > 0)[0]) + 1
    assert noisy.time[k_on - 1] < ON <= noisy.time[k_on]
    assert np.array_equal(noisy.efd, again.efd)
    lsb = 20.0 / 2 ** 12
    assert np.allclose(noisy.efd / lsb, np.round(noisy.efd / lsb))
    resid = noisy.efd - clean.efd
    assert 0.009 < float(np.std(resid)) < 0.011


@pytest.mark.slow
def test_random_units_are_stable_and_effects_visible():
    rng = np.random.default_rng(11)
    avr = draw_avr(rng)
    assert avr["TA2"] <= avr["TA1"] and avr["TA4"] >= avr["TA2"]
    rec = Plant(avr).run(Test(on_s=1.0), Recorder(rate_hz=500.0, duration_s=4.0, noise_pu=0.0, bits=0))
    free = rec.truth["efd_clean"]
    for name in ("ceiling_limit", "dead_time", "rate_limit", "saturation"):
        eff = draw_effect(name, rng, free, 1.0 / 500.0)
        with_eff = Plant({**avr, **eff}).run(Test(on_s=1.0), Recorder(rate_hz=500.0, duration_s=4.0,
                                                                      noise_pu=0.0, bits=0))
        assert np.max(np.abs(with_eff.truth["efd_clean"] - free)) > 0.05, name
    moved = random_edges(rng, Test(on_s=1.0, width_s=1.0), 1e-3, "inside")
    assert 1.0 - 1e-3 < moved.on_s < 1.0 and 2.0 - 1e-3 < moved.on_s + moved.width_s < 2.0
    early = random_edges(rng, Test(on_s=1.0, width_s=1.0), 1e-3, "early")
    assert early.on_s == pytest.approx(0.999)


def test_plant_does_not_import_the_kernel():
    tree = ast.parse(Path(__file__).resolve().parents[1].joinpath("independent_plant.py").read_text(encoding="utf-8"))
    mods = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    mods += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert not [m for m in mods if m.startswith("bench_ctl")], mods
