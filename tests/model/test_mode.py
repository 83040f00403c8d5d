"""The electromechanical mode estimator (`bench_ctl.signals.mode`): a damped sinusoid beside a slow
exponential after an edge, with noise, recovered; noise alone is no mode."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bench_ctl.signals.mode import electromechanical_mode


@pytest.mark.parametrize("f,zeta", [(1.2, 0.08), (0.7, 0.2), (2.0, 0.03)])
def test_a_damped_swing_after_an_edge_is_recovered(f, zeta):
    t = np.arange(0.0, 10.0, 1e-3)
    w = 2 * math.pi * f
    s = zeta * w / math.sqrt(1 - zeta * zeta)
    after = t >= 1.0
    p = (0.8 + after * 0.02 * (1 - np.exp(-(t - 1) / 0.8))
         + after * 0.05 * np.exp(-s * (t - 1)) * np.sin(w * (t - 1) + 0.3)
         + np.random.default_rng(0).normal(0.0, 0.003, t.size))
    m = electromechanical_mode(t, p, 1.0)
    assert m is not None
    assert m.frequency_hz == pytest.approx(f, rel=0.01)
    assert m.damping == pytest.approx(zeta, rel=0.05)
    assert m.rms_residual == pytest.approx(0.003, rel=0.05)


def test_noise_alone_is_no_mode():
    t = np.arange(0.0, 10.0, 1e-3)
    assert electromechanical_mode(t, 0.8 + np.random.default_rng(1).normal(0.0, 0.003, t.size), 1.0) is None
    assert electromechanical_mode(t[:40], np.ones(40), 0.0) is None   # too short
