"""No stabiliser: no states, output 0 (a unit at no load, or on line without one)."""
from __future__ import annotations

from ..jit import njit

N_STATES = 0


@njit
def load(S, c):
    return ()


@njit
def store(S, c, x):
    pass


@njit
def axpy(x, k, h):
    return ()


@njit
def combine(x, a, b, c, d, h6):
    return ()


@njit
def rhs(D, c, x, w, pe):
    return 0.0, ()


@njit
def output(D, c, x, w, pe):
    return 0.0


@njit
def park(D, c):
    return ()
