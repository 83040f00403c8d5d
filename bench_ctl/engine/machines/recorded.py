"""No machine: a record's terminal voltage and field current played back to the excitation system
(the open loop, `open_loop`). The excitation system alone, fed the Vt and Ifd another simulator
(or a unit) recorded, must give the efd it recorded; what is checked is then what identification
simulates, without the generator. The recorded series (`ext`: row 0 Vt, row 1 Ifd, on the
record's samples) are interpolated linearly to each RK4 stage's instant `t` (in steps from the
record's first sample) and held beyond its ends; the ceilings move with them only from step to
step (re-applied at every step's end). No states.
"""
from __future__ import annotations

from ..jit import njit
from ..stateless import axpy, combine, load, store
from .noload import alg_load, alg_store, power, signals, speed  # the same algebra slots (Vt, Ifd)

__all__ = ["N_ALG", "N_STATES", "algebra", "alg_load", "alg_store", "axpy", "combine", "end", "flux", "load",
           "park", "power", "rhs", "signals", "speed", "store", "valid"]

N_STATES = 0
N_ALG = 2


@njit
def _at(y, t):
    n = y.shape[0]
    if t <= 0.0:
        return y[0]
    if t >= n - 1:
        return y[n - 1]
    j = int(t)
    f = t - j
    return y[j] + f * (y[j + 1] - y[j])






@njit
def algebra(D, c, t, x, ext):
    return _at(ext[0], t), _at(ext[1], t)







@njit
def rhs(D, c, t, x, a, fld, ext):
    return (), 0.0, 0.0


@njit
def end(D, c, x):
    return x


@njit
def park(D, c):
    return ()


@njit
def valid(D, c):
    return True


@njit
def flux(x):
    """E'q (a plant reports it)."""
    return 0.0
