"""No stabiliser: no states, output 0 (a unit at no load, or on line without one)."""
from __future__ import annotations

from ..jit import njit
from ..stateless import axpy, combine, load, store

__all__ = ["N_STATES", "axpy", "combine", "load", "output", "park", "rhs", "store"]

N_STATES = 0






@njit
def rhs(D, c, x, w, pe):
    return 0.0, ()


@njit
def output(D, c, x, w, pe):
    return 0.0


@njit
def park(D, c):
    return ()
