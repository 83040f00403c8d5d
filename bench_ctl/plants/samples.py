"""What a plant hands out: the columns of its per-sample block, a snapshot of its state and its
real-time statistics.

The simulated devices and the listeners (recorder, watchdog) read a plant through these: a block
of samples `(n, N_OUT)` whose columns are `O_*`, mapped from the engine's kept quantities by
`KEEP_COLUMNS`; `PlantState` after the last step; `PlantTiming` of the real-time loop.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bench_ctl.engine.layout import SIGNALS
from bench_ctl.engine.runner import K_EQP, K_FLAGS, K_FLD, K_UREF, N_KEEP

#: the columns of the per-sample block `advance` returns and the listeners get
(O_USETP, O_EFD_REC, O_VT, O_EFD, O_EQP, O_UREF, O_FLAGS, O_P, O_Q, O_IFD) = range(10)
N_OUT = 10


def _keep() -> np.ndarray:
    """The engine's kept quantities -> the plant's columns."""
    keep = np.full(N_KEEP, -1, dtype=np.int64)
    for name, col in (("efd", O_EFD_REC), ("vt", O_VT), ("p", O_P), ("q", O_Q), ("ifd", O_IFD)):
        keep[SIGNALS.index(name)] = col
    keep[K_FLD], keep[K_EQP], keep[K_UREF], keep[K_FLAGS] = O_EFD, O_EQP, O_UREF, O_FLAGS
    return keep


#: the engine's kept quantity -> the plant's column (-1: not kept), the `keep` of its Out
KEEP_COLUMNS = _keep()


@dataclass(frozen=True)
class PlantState:
    """A snapshot of the plant after its last step (exciter readings)."""
    step: int                 # number of steps taken; plant time = step * dt
    time_s: float
    usetp: float              # digital setpoint acting now
    active_setpoint: float    # setpoint after the device's ramp (pu)
    vt: float
    efd: float
    ifd: float                # field current, pu: E'q + Sat(E'q) (on line: XadIfd)
    flags: int                # FLAG_* bits
    p: float = 0.0            # active and reactive power, pu on the machine base (on line)
    q: float = 0.0


@dataclass(frozen=True)
class PlantTiming:
    """Real-time statistics: lag = wall time - plant time after each burst of steps."""
    steps: int
    elapsed_s: float
    lag_mean_s: float
    lag_max_s: float
    lag_p99_s: float
    late_bursts: int          # bursts of more than one step (the loop woke late)
    max_burst: int
    drift_s: float            # lag at the last burst minus lag at the first
    behind_max_s: float       # wall - plant time when the loop woke, before catching up
    behind_p99_s: float       # (>= one step by construction: a step is computed after its end)
    stalls_over_1ms: int      # wake-ups that found the plant more than one step + 1 ms behind
    late_setpoints: int       # setpoint changes published after their step had been computed


Listener = Callable[[int, np.ndarray], None]
