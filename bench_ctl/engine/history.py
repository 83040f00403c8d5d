"""Reads of a candidate's history: the dead time's delayed regulator output and the recorder
skew's efd, both from rings of per-step values (a row a candidate).

Dead time: step j keeps VR's right limit at t_j (`vr_r`), its left limit at t_j+1 (`vr_l`) and,
when the setpoint jumped inside the step at fraction `jf` > 0, the left and right limits there
(`vjl`, `vjr`); VR is linear between, so a delayed jump stays a jump instead of being smeared over
a step. Skew: the efd at each sample and its one-sided slopes, read by cubic Hermite
interpolation, with the kink at a setpoint jump inside a step kept (`kf`, `kef`, `kdl`, `kdr`).
"""
from __future__ import annotations

import math

from .jit import njit
from .layout import EDGE_EPS

#: the dead time's rings in a chunk's `hist` array, and the skew's in its `skh` array
H_VR_R, H_VR_L, H_JF, H_VJL, H_VJR = range(5)
K_EF, K_DER_R, K_DER_L, K_KF, K_KEF, K_KDL, K_KDR = range(7)


@njit
def delayed_vr(hist, c, L, tau_steps, k, vr0, left):
    """VR at time tau_steps * dt from the rings of length L (`hist`, see the module docstring).
    `left` reads the left limit at a jump (the end of an RK (sub-)step sees the delayed signal
    just before a delayed jump, the start just after it)."""
    r = math.floor(tau_steps + 0.5)
    if abs(tau_steps - r) < EDGE_EPS:
        tau_steps = r
    if tau_steps < 0.0 or (left and tau_steps <= 0.0):
        return vr0
    j = int(math.ceil(tau_steps)) - 1 if left else int(math.floor(tau_steps))
    if j >= k:  # inside the current step (TD shorter than a step): hold the right limit
        return hist[H_VR_R, c, k % L]
    s = tau_steps - j
    q = j % L
    f = hist[H_JF, c, q]
    if f > 0.0:
        if s < f - EDGE_EPS or (left and s <= f + EDGE_EPS):
            return hist[H_VR_R, c, q] + (hist[H_VJL, c, q] - hist[H_VR_R, c, q]) * (s / f)
        return hist[H_VJR, c, q] + (hist[H_VR_L, c, (j + 1) % L] - hist[H_VJR, c, q]) * ((s - f) / (1.0 - f))
    return hist[H_VR_R, c, q] * (1.0 - s) + hist[H_VR_L, c, (j + 1) % L] * s


@njit
def hermite(y0, m0, y1, m1, s, h):
    s2 = s * s
    s3 = s2 * s
    return ((2 * s3 - 3 * s2 + 1) * y0 + (s3 - 2 * s2 + s) * h * m0
            + (-2 * s3 + 3 * s2) * y1 + (s3 - s2) * h * m1)


@njit
def skewed(skh, c, Ls, k, tau, dt, y0):
    """The efd recorded at sample k when the channel lags by tau = k - SKEW / dt steps: y0 before
    the record; else interpolated in the step that holds tau (across the kink of a jump in it)."""
    if tau <= 0.0:
        return y0
    j = int(math.floor(tau))
    if j >= k:
        return skh[K_EF, c, k % Ls]
    q = j % Ls
    q1 = (j + 1) % Ls
    s = tau - j
    f = skh[K_KF, c, q]
    if f <= 0.0:
        return hermite(skh[K_EF, c, q], skh[K_DER_R, c, q], skh[K_EF, c, q1], skh[K_DER_L, c, q1], s, dt)
    if s < f:  # a setpoint jump inside that step: the efd kink kept
        return hermite(skh[K_EF, c, q], skh[K_DER_R, c, q], skh[K_KEF, c, q], skh[K_KDL, c, q], s / f, f * dt)
    return hermite(skh[K_KEF, c, q], skh[K_KDR, c, q], skh[K_EF, c, q1], skh[K_DER_L, c, q1], (s - f) / (1.0 - f),
                   (1.0 - f) * dt)
