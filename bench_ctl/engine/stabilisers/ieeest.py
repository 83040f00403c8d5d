"""IEEEST on the rotor speed, without its notch filters (ANDES' and PSS/E's IEEEST with A1..A6 =
0): the speed deviation through two lead-lags, the gain KS and the washout, limited to +-LSMAX,

    vs = clamp(KS (1 + s T1)/(1 + s T2) (1 + s T3)/(1 + s T4) s TW/(1 + s TW) (omega - 1), +-LSMAX)

added to the exciter's reference. Three states, 0 at the operating point (the speed nominal);
KS = 0 gives 0. Its parameters are the unit's [grid] PSS_* values (`params.MACHINE_CATALOGUE`),
read when its PSS_MODEL is IEEEST (the default).
"""
from __future__ import annotations

import numpy as np

from bench_ctl.model.params import MCOL
from bench_ctl.model.stabilisers import IEEEST

from ..jit import njit
from ..layout import D_PSS_IT2, D_PSS_IT4, D_PSS_ITW, D_PSS_KS, D_PSS_LIM, D_PSS_R1, D_PSS_R3

#: the stabiliser's states in a chunk's state array: after the exciter's six and the machine's seven
N_STATES = 3
FIRST = 13


def derive_columns(D: np.ndarray, M: np.ndarray) -> None:
    """The stabiliser's derived columns of D from the machine matrix M (its PSS_* values); KS 0
    for a candidate whose PSS_MODEL is another."""
    m = {name: M[:, j] for name, j in MCOL.items()}
    D[:, D_PSS_KS], D[:, D_PSS_LIM] = np.where(m["PSS_MODEL"] == IEEEST, m["PSS_KS"], 0.0), m["PSS_LSMAX"]
    D[:, D_PSS_IT2], D[:, D_PSS_R1] = 1.0 / m["PSS_T2"], m["PSS_T1"] / m["PSS_T2"]
    D[:, D_PSS_IT4], D[:, D_PSS_R3] = 1.0 / m["PSS_T4"], m["PSS_T3"] / m["PSS_T4"]
    D[:, D_PSS_ITW] = 1.0 / m["PSS_TW"]


def present(D: np.ndarray) -> bool:
    """Whether some candidate of the derived matrix D has a stabiliser (KS > 0)."""
    return bool(np.any(D[:, D_PSS_KS] != 0.0))


@njit
def load(S, c):
    return S[13, c], S[14, c], S[15, c]


@njit
def store(S, c, x):
    S[13, c] = x[0]
    S[14, c] = x[1]
    S[15, c] = x[2]


@njit
def axpy(x, k, h):
    return x[0] + h * k[0], x[1] + h * k[1], x[2] + h * k[2]


@njit
def combine(x, a, b, c, d, h6):
    return (x[0] + h6 * (a[0] + 2.0 * b[0] + 2.0 * c[0] + d[0]), x[1] + h6 * (a[1] + 2.0 * b[1] + 2.0 * c[1] + d[1]),
            x[2] + h6 * (a[2] + 2.0 * b[2] + 2.0 * c[2] + d[2]))


@njit
def rhs(D, c, x, w, pe):
    """(vs, its states' derivatives) at rotor speed w."""
    x13, x14, x15 = x
    dw = w - 1.0
    y1 = x13 + D[D_PSS_R1, c] * (dw - x13)
    y2 = x14 + D[D_PSS_R3, c] * (y1 - x14)
    v = D[D_PSS_KS, c] * y2
    lim = D[D_PSS_LIM, c]
    vs = v - x15
    vs = vs if vs < lim else lim
    vs = vs if vs > -lim else -lim
    return vs, ((dw - x13) * D[D_PSS_IT2, c], (y1 - x14) * D[D_PSS_IT4, c], (v - x15) * D[D_PSS_ITW, c])


@njit
def output(D, c, x, w, pe):
    return rhs(D, c, x, w, pe)[0]


@njit
def park(D, c):
    return 0.0, 0.0, 0.0
