"""The state slots of a plug-in without states (no stabiliser, the recorded-input machine): an
empty tuple loaded, stored, stepped and combined."""
from __future__ import annotations

from .jit import njit


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
