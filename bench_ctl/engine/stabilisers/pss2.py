"""PSS2A and PSS2B, one plug-in (IEEE 421.5-2016's PSS2B, PSS/E's PSS2A and PSS2B records;
`bench_ctl.model.stabilisers` for the user's side and the sources, docs/decisions/0024):

    u1 = clamp(omega - 1, VS1MIN, VS1MAX) - U10       u2 = clamp(Pe, VS2MIN, VS2MAX) - U20
    V1 = 1/(1 + s T6) s TW2/(1 + s TW2) s TW1/(1 + s TW1) u1
    V2 = KS2/(1 + s T7) s TW4/(1 + s TW4) s TW3/(1 + s TW3) u2
    vs = clamp(KS1 LL(T1, T2) LL(T3, T4) LL(T10, T11) ([(1 + s T8)/(1 + s T9)^M]^N (V1 + KS3 V2) - V2),
               VSTMIN, VSTMAX)

added to the exciter's reference, from the rotor speed w and the electrical power Pe the machine
gives. PSS2A is PSS2B with LL(T10, T11) = 1 and no input limits (its derived columns say so).
U10, U20 are the limited inputs at the operating point: every state is 0 there (each washout's
state is its input's deviation from it), and so is the output.

Seventeen states: the washouts TW1, TW2 (input 1), TW3, TW4 (input 2), the lags T6, T7, the
ramp-tracking filter's eight, the lead-lags T1/T2, T3/T4, T10/T11. The filter is a chain of the
M N lags its largest case (M N = 8) needs, N sections of M lags each, the last of a section the
lead-lag (1 + s T8)/(1 + s T9): state k's output is `in + RC_k (x_k - in)`, its derivative
`RA_k (in - x_k)`, with RC_k = 1 - T8/T9 (a section's last) or 1, RA_k = 1/T9; a state beyond
M N has RC_k = RA_k = 0: its input passes and it stays at 0. M and N are thus the candidate's
(the derived columns), not the variant's: one compiled variant runs every M, N, branch-free. A
bypassed washout (TW = 0) has 1/TW = 0 (its state stays 0, its output is its input), a bypassed
lag (T6 = 0) outputs its input, a bypassed lead-lag has ratio 1 and 1/T = 0.
"""
from __future__ import annotations

import math

import numpy as np

from bench_ctl.model.params import MCOL
from bench_ctl.model.stabilisers import PSS2A, PSS2B

from ..jit import njit
from ..layout import (
    D_P2_I6,
    D_P2_I7,
    D_P2_IT,
    D_P2_IW,
    D_P2_KS1,
    D_P2_KS2,
    D_P2_KS3,
    D_P2_ON6,
    D_P2_ON7,
    D_P2_R,
    D_P2_RA,
    D_P2_RC,
    D_P2_U10,
    D_P2_U20,
    D_P2_V1MAX,
    D_P2_V1MIN,
    D_P2_V2MAX,
    D_P2_V2MIN,
    D_P2_VSTMAX,
    D_P2_VSTMIN,
    D_TM,
)

#: the stabiliser's states in a chunk's state array: after the exciter's six and the machine's seven
N_STATES = 17
FIRST = 13
#: the ramp-tracking filter's states (PSS/E: M N <= 8)
N_RTF = 8


def _lead_lag(lead: np.ndarray, lag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ratio, 1 / lag) of lead-lags, (1, 0) where the lag is 0 (bypassed: the lead is 0 too,
    `check_stabiliser`)."""
    on = lag > 0
    safe = np.where(on, lag, 1.0)
    return np.where(on, lead / safe, 1.0), np.where(on, 1.0 / safe, 0.0)


def derive_columns(D: np.ndarray, M: np.ndarray) -> None:
    """The PSS2A / PSS2B columns of D from the machine matrix M (its PSS2_* values, checked by
    `machines.grid.machine_matrix`) and the machine's columns already in D (D_TM, the electrical
    power at the operating point); KS1 0 for a candidate whose PSS_MODEL is another."""
    m = {name: M[:, j] for name, j in MCOL.items()}
    model = m["PSS_MODEL"]
    on = (model == PSS2A) | (model == PSS2B)
    b = model == PSS2B
    D[:, D_P2_KS1] = np.where(on, m["PSS2_KS1"], 0.0)
    D[:, D_P2_KS2], D[:, D_P2_KS3] = m["PSS2_KS2"], m["PSS2_KS3"]
    for i in range(4):
        tw = m[f"PSS2_TW{i + 1}"]
        D[:, D_P2_IW + i] = np.where(tw > 0, 1.0 / np.where(tw > 0, tw, 1.0), 0.0)
    for col_i, col_on, name in ((D_P2_I6, D_P2_ON6, "PSS2_T6"), (D_P2_I7, D_P2_ON7, "PSS2_T7")):
        t = m[name]
        D[:, col_i] = np.where(t > 0, 1.0 / np.where(t > 0, t, 1.0), 0.0)
        D[:, col_on] = (t > 0).astype(float)
    stages = (m["PSS2_M"] * m["PSS2_N"]).astype(int)
    lags = np.maximum(m["PSS2_M"].astype(int), 1)
    t9 = np.where(m["PSS2_T9"] > 0, m["PSS2_T9"], 1.0)
    for k in range(N_RTF):
        used = k < stages
        last = (k % lags) == lags - 1     # the section's lead-lag (1 + s T8)/(1 + s T9)
        D[:, D_P2_RA + k] = np.where(used, 1.0 / t9, 0.0)
        D[:, D_P2_RC + k] = np.where(used, np.where(last, 1.0 - m["PSS2_T8"] / t9, 1.0), 0.0)
    for i, (lead, lag) in enumerate((("PSS2_T1", "PSS2_T2"), ("PSS2_T3", "PSS2_T4"), ("PSS2_T10", "PSS2_T11"))):
        r, it = _lead_lag(m[lead], m[lag])
        if i == 2:   # PSS2A has no third lead-lag
            r, it = np.where(b, r, 1.0), np.where(b, it, 0.0)
        D[:, D_P2_R + i], D[:, D_P2_IT + i] = r, it
    inf = math.inf
    D[:, D_P2_V1MAX] = np.where(b, m["PSS2_VS1MAX"], inf)
    D[:, D_P2_V1MIN] = np.where(b, m["PSS2_VS1MIN"], -inf)
    D[:, D_P2_V2MAX] = np.where(b, m["PSS2_VS2MAX"], inf)
    D[:, D_P2_V2MIN] = np.where(b, m["PSS2_VS2MIN"], -inf)
    D[:, D_P2_U10] = np.minimum(np.maximum(0.0, D[:, D_P2_V1MIN]), D[:, D_P2_V1MAX])
    D[:, D_P2_U20] = np.minimum(np.maximum(D[:, D_TM], D[:, D_P2_V2MIN]), D[:, D_P2_V2MAX])
    D[:, D_P2_VSTMAX], D[:, D_P2_VSTMIN] = m["PSS2_VSTMAX"], m["PSS2_VSTMIN"]


def present(D: np.ndarray) -> bool:
    """Whether some candidate of the derived matrix D has a PSS2A or PSS2B (KS1 > 0)."""
    return bool(np.any(D[:, D_P2_KS1] != 0.0))


@njit
def load(S, c):
    return (S[13, c], S[14, c], S[15, c], S[16, c], S[17, c], S[18, c], S[19, c], S[20, c], S[21, c], S[22, c],
            S[23, c], S[24, c], S[25, c], S[26, c], S[27, c], S[28, c], S[29, c])


@njit
def store(S, c, x):
    S[13, c] = x[0]
    S[14, c] = x[1]
    S[15, c] = x[2]
    S[16, c] = x[3]
    S[17, c] = x[4]
    S[18, c] = x[5]
    S[19, c] = x[6]
    S[20, c] = x[7]
    S[21, c] = x[8]
    S[22, c] = x[9]
    S[23, c] = x[10]
    S[24, c] = x[11]
    S[25, c] = x[12]
    S[26, c] = x[13]
    S[27, c] = x[14]
    S[28, c] = x[15]
    S[29, c] = x[16]


@njit
def axpy(x, k, h):
    return (x[0] + h * k[0], x[1] + h * k[1], x[2] + h * k[2], x[3] + h * k[3], x[4] + h * k[4], x[5] + h * k[5],
            x[6] + h * k[6], x[7] + h * k[7], x[8] + h * k[8], x[9] + h * k[9], x[10] + h * k[10],
            x[11] + h * k[11], x[12] + h * k[12], x[13] + h * k[13], x[14] + h * k[14], x[15] + h * k[15],
            x[16] + h * k[16])


@njit
def rk(x, a, b, c, d, h6):
    """One state's RK4 combination."""
    return x + h6 * (a + 2.0 * b + 2.0 * c + d)


@njit
def combine(x, a, b, c, d, h6):
    return (rk(x[0], a[0], b[0], c[0], d[0], h6), rk(x[1], a[1], b[1], c[1], d[1], h6),
            rk(x[2], a[2], b[2], c[2], d[2], h6), rk(x[3], a[3], b[3], c[3], d[3], h6),
            rk(x[4], a[4], b[4], c[4], d[4], h6), rk(x[5], a[5], b[5], c[5], d[5], h6),
            rk(x[6], a[6], b[6], c[6], d[6], h6), rk(x[7], a[7], b[7], c[7], d[7], h6),
            rk(x[8], a[8], b[8], c[8], d[8], h6), rk(x[9], a[9], b[9], c[9], d[9], h6),
            rk(x[10], a[10], b[10], c[10], d[10], h6), rk(x[11], a[11], b[11], c[11], d[11], h6),
            rk(x[12], a[12], b[12], c[12], d[12], h6), rk(x[13], a[13], b[13], c[13], d[13], h6),
            rk(x[14], a[14], b[14], c[14], d[14], h6), rk(x[15], a[15], b[15], c[15], d[15], h6),
            rk(x[16], a[16], b[16], c[16], d[16], h6))


@njit
def clamp(v, lo, hi):
    v = v if v < hi else hi
    return v if v > lo else lo


@njit
def washout(D, c, i, u, x):
    """(output, derivative) of washout i (0..3) with state x: u - x, (u - x) / TW (0 bypassed)."""
    y = u - x
    return y, y * D[D_P2_IW + i, c]


@njit
def stage(D, c, k, u, x):
    """(output, derivative) of the ramp-tracking filter's state k at input u."""
    return u + D[D_P2_RC + k, c] * (x - u), (u - x) * D[D_P2_RA + k, c]


@njit
def lead_lag(D, c, i, u, x):
    """(output, derivative) of lead-lag i (0: T1/T2, 1: T3/T4, 2: T10/T11)."""
    e = u - x
    return x + D[D_P2_R + i, c] * e, e * D[D_P2_IT + i, c]


@njit
def rhs(D, c, x, w, pe):
    """(vs, its states' derivatives) at rotor speed w and electrical power pe."""
    u1 = clamp(w - 1.0, D[D_P2_V1MIN, c], D[D_P2_V1MAX, c]) - D[D_P2_U10, c]
    u2 = clamp(pe, D[D_P2_V2MIN, c], D[D_P2_V2MAX, c]) - D[D_P2_U20, c]
    a1, d0 = washout(D, c, 0, u1, x[0])
    a2, d1 = washout(D, c, 1, a1, x[1])
    on6 = D[D_P2_ON6, c]
    v1 = a2 + on6 * (x[4] - a2)
    d4 = (a2 - x[4]) * D[D_P2_I6, c]
    b1, d2 = washout(D, c, 2, u2, x[2])
    b2, d3 = washout(D, c, 3, b1, x[3])
    g2 = D[D_P2_KS2, c] * b2
    on7 = D[D_P2_ON7, c]
    v2 = g2 + on7 * (x[5] - g2)
    d5 = (g2 - x[5]) * D[D_P2_I7, c]
    r0, e0 = stage(D, c, 0, v1 + D[D_P2_KS3, c] * v2, x[6])
    r1, e1 = stage(D, c, 1, r0, x[7])
    r2, e2 = stage(D, c, 2, r1, x[8])
    r3, e3 = stage(D, c, 3, r2, x[9])
    r4, e4 = stage(D, c, 4, r3, x[10])
    r5, e5 = stage(D, c, 5, r4, x[11])
    r6, e6 = stage(D, c, 6, r5, x[12])
    r7, e7 = stage(D, c, 7, r6, x[13])
    y1, f1 = lead_lag(D, c, 0, D[D_P2_KS1, c] * (r7 - v2), x[14])
    y2, f2 = lead_lag(D, c, 1, y1, x[15])
    y3, f3 = lead_lag(D, c, 2, y2, x[16])
    vs = clamp(y3, D[D_P2_VSTMIN, c], D[D_P2_VSTMAX, c])
    return vs, (d0, d1, d2, d3, d4, d5, e0, e1, e2, e3, e4, e5, e6, e7, f1, f2, f3)


@njit
def output(D, c, x, w, pe):
    return rhs(D, c, x, w, pe)[0]


@njit
def park(D, c):
    """The states at the operating point: all 0."""
    return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
