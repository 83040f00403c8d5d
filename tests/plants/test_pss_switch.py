"""The on-line plant's PSS switch (issue 49 item 3): off holds the stabiliser's output at 0 while its
states run (sample for sample the unit with its output limit 0), on puts the unit's limit back, and
the swing after a step is damped more with it on."""
from __future__ import annotations

import numpy as np

from bench_ctl.plants import O_P, OnlinePlant
from bench_ctl.signals.mode import electromechanical_mode
from bench_ctl.units.overrides import apply_overrides
from bench_ctl.units.unit import load_unit

#: the reference unit's IEEEST of the dry run of pss_step (procedures/pss_step.py SIMULATED_BENCH)
IEEEST = ("PSS_MODEL=IEEEST", "PSS_KS=5", "PSS_T1=0.2", "PSS_T2=0.05", "PSS_T3=0.2", "PSS_T4=0.05", "PSS_TW=5",
          "PSS_LSMAX=0.1")


def _step(plant: OnlinePlant) -> np.ndarray:
    return np.vstack([plant.advance(plant.usetp_pre, 1000), plant.advance(plant.usetp_pre + 0.02, 6000)])


def test_the_switch_holds_the_output_at_zero_and_the_pss_damps_the_swing():
    unit = apply_overrides(load_unit(None), IEEEST)
    off = OnlinePlant(unit, rt_priority=None)
    off.set_pss(False)
    limited = OnlinePlant(apply_overrides(unit, ["PSS_LSMAX=0"]), rt_priority=None)
    rows_off, rows_limited = _step(off), _step(limited)
    assert np.array_equal(rows_off, rows_limited)
    on = OnlinePlant(unit, rt_priority=None)
    rows_on = _step(on)
    t = np.arange(rows_on.shape[0]) * on.dt
    m_off, m_on = (electromechanical_mode(t, r[:, O_P], 1.0) for r in (rows_off, rows_on))
    assert m_off is not None and m_on is not None
    assert m_on.damping > m_off.damping + 0.1, (m_off, m_on)
    off.set_pss(True)          # back on: the unit's own limit again, the output no longer 0
    after = off.advance(off.usetp_pre, 500)
    assert off.pss_on and not np.array_equal(after, limited.advance(limited.usetp_pre, 500))
