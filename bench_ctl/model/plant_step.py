"""One parameter set of the reference unit stepped with carried state: the plant's numerics.

`_advance` reuses the kernel's blocks (`bench_ctl.model.kernel`: `rk4_step_ref`, `avr`,
`delayed_vr`, `hermite`, `ceilings`) for candidate 0 of a transposed derived-parameter block,
writing one row of `N_OUT` columns per step, so stepping it with a setpoint series reproduces
`bench_ctl.model.simulate.simulate()`. numba's disk cache of this module is flushed when a file
of the kernel package changes (`kernel.drop_stale_cache`).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from . import kernel as K

#: columns of the per-sample output block
(O_USETP, O_EFD_REC, O_VT, O_EFD, O_EQP, O_UREF, O_FLAGS) = range(7)
N_OUT = 7
#: flag bits in O_FLAGS
FLAG_CEILING, FLAG_RATE, FLAG_RAMP, FLAG_FAILED = 1, 2, 4, 8

_FM = {"contract", "arcp", "reassoc", "afn"}


@nb.njit(cache=True, error_model="numpy", fastmath=_FM)
def _rk4_step(D, u0, u1, v0, vm, v1, x0, x1, x2, x3, x4, x5, h):
    """The kernel's RK4 step (with the efd clamp) for candidate 0. Kept out of line: the
    kernel's stage functions are inlined, and three inlined copies would triple compile time.
    The plant is the reference structure (`rk4_step_ref`: no block of the standard structures)."""
    return K.rk4_step_ref(D, 0, u0, u1, v0, vm, v1, x0, x1, x2, x3, x4, x5, h, True)


@nb.njit(cache=True, error_model="numpy", fastmath=_FM)
def _advance(D, X, vr_r, vr_l, ef_h, der_r, der_l, k0, u, usetp_pre, dt, out):
    """Advance one candidate (D transposed, column 0) over len(u) steps from step k0.

    X = [xm, x1, x2, efd, E'q, E''q, uref, out_e, failed]. Writes per step k the sample at t_k
    into out[s] (see O_* columns) and leaves X at t_{k0+len(u)}."""
    L = vr_r.shape[1]
    Ls = ef_h.shape[1]
    td = D[K.D_TD, 0]
    skew = D[K.D_SKEW, 0]
    ramp = D[K.D_RAMP, 0]
    e0 = D[K.D_EFD0, 0]
    jz = np.zeros((1, L))  # the plant's setpoint changes on its own steps: no jump inside a step
    for s in range(u.shape[0]):
        k = k0 + s
        # ---- sample k (states at t_k) ----
        y = X[3]
        if skew > 0.0:
            tau = k - skew / dt
            if tau <= 0.0:
                y = e0
            else:
                j = int(math.floor(tau))
                if j < k:
                    y = K.hermite(ef_h[0, j % Ls], der_r[0, j % Ls], ef_h[0, (j + 1) % Ls],
                                   der_l[0, (j + 1) % Ls], tau - j, dt)
        if X[8] == 0.0:
            X[7] = D[K.D_GAIN, 0] * y
        out[s, 0] = u[s]
        out[s, 1] = X[7]
        out[s, 2] = X[5]
        out[s, 3] = X[3]
        out[s, 4] = X[4]
        # ---- setpoint over [t_k, t_k+1) ----
        target = D[K.D_UREF0, 0] + (u[s] - usetp_pre)
        ua = target
        ub = target
        if ramp < 1.0e300:
            step = min(max(ub - X[6], -ramp * dt), ramp * dt)
            ua = X[6]
            ub = X[6] + step
        out[s, 5] = ub
        # ---- dead time ----
        v0 = 0.0
        v1 = 0.0
        v2 = 0.0
        if td > 0.0:
            vm0 = X[0] if D[K.D_ITR, 0] > 0.0 else X[5]
            vr_r[0, k % L] = K.avr(D, 0, ua, vm0, X[1], X[2], 0.0)[0]
            base = k - td / dt
            v0 = K.delayed_vr(vr_r, vr_l, jz, jz, jz, 0, L, base, k, e0, False)
            v1 = K.delayed_vr(vr_r, vr_l, jz, jz, jz, 0, L, base + 0.5, k, e0, False)
            v2 = K.delayed_vr(vr_r, vr_l, jz, jz, jz, 0, L, base + 1.0, k, e0, True)
        x0, x1, x2, x3, x4, x5 = X[0], X[1], X[2], X[3], X[4], X[5]
        r = _rk4_step(D, ua, ub, v0, v1, v2, x0, x1, x2, x3, x4, x5, dt)
        if skew > 0.0:
            ef_h[0, k % Ls] = x3
            der_r[0, k % Ls] = r[6]
            der_l[0, (k + 1) % Ls] = r[7]
        X[0] = r[0]
        X[1] = r[1]
        X[2] = r[2]
        X[3] = r[3]
        X[4] = r[4]
        X[5] = r[5]
        X[6] = ub
        mag = abs(X[0]) + abs(X[1]) + abs(X[2]) + abs(X[3]) + abs(X[4]) + abs(X[5])
        if not (mag < K.BLOWUP):
            X[8] = 1.0
            X[0] = D[K.D_VT0, 0]
            X[4] = D[K.D_VT0, 0]
            X[5] = D[K.D_VT0, 0]
            X[3] = e0
            X[1] = D[K.D_E0, 0]
            X[2] = D[K.D_E0, 0]
        # ---- a delayed VR that jumps inside the step (a setpoint change seen through a dead time
        # that is not a whole number of steps): split the step there, as the kernel does ----
        if td > 0.0 and X[8] == 0.0:
            base = k - td / dt
            j0 = math.floor(base)
            frac = base - j0
            if frac >= 1e-9 and j0 + 1 < k and vr_r[0, (j0 + 1) % L] != vr_l[0, (j0 + 1) % L]:
                th = 1.0 - frac
                uth = ua + th * (ub - ua)
                va = K.delayed_vr(vr_r, vr_l, jz, jz, jz, 0, L, base, k, e0, False)
                vam = K.delayed_vr(vr_r, vr_l, jz, jz, jz, 0, L, base + 0.5 * th, k, e0, False)
                vae = K.delayed_vr(vr_r, vr_l, jz, jz, jz, 0, L, j0 + 1.0, k, e0, True)
                vb = K.delayed_vr(vr_r, vr_l, jz, jz, jz, 0, L, j0 + 1.0, k, e0, False)
                vbm = K.delayed_vr(vr_r, vr_l, jz, jz, jz, 0, L, j0 + 1.0 + 0.5 * frac, k, e0, False)
                vbe = K.delayed_vr(vr_r, vr_l, jz, jz, jz, 0, L, base + 1.0, k, e0, True)
                ra = _rk4_step(D, ua, uth, va, vam, vae, x0, x1, x2, x3, x4, x5, th * dt)
                rb = _rk4_step(D, uth, ub, vb, vbm, vbe, ra[0], ra[1], ra[2], ra[3], ra[4], ra[5],
                               frac * dt)
                X[0] = rb[0]
                X[1] = rb[1]
                X[2] = rb[2]
                X[3] = rb[3]
                X[4] = rb[4]
                X[5] = rb[5]
                if skew > 0.0:
                    der_r[0, k % Ls] = ra[6]
                    der_l[0, (k + 1) % Ls] = rb[7]
        if skew > 0.0:
            ef_h[0, (k + 1) % Ls] = X[3]
        vm = X[0] if D[K.D_ITR, 0] > 0.0 else X[5]
        vr = K.avr(D, 0, ub, vm, X[1], X[2], 0.0)[0]
        if td > 0.0:
            vr_l[0, (k + 1) % L] = vr
        # ---- limiter flags after the step ----
        flags = 0.0
        hi, lo = K.ceilings(D, 0, X[4], X[5])
        if X[3] >= hi or X[3] <= lo:
            flags += 1.0
        if abs((vr - X[3]) * D[K.D_ITE, 0]) > D[K.D_RATE, 0]:
            flags += 2.0
        if ub != target:
            flags += 4.0
        if X[8] != 0.0:
            flags += 8.0
        out[s, 6] = flags


# numba keys the cache on this file alone: flush it when a file of the kernel package changes
K.drop_stale_cache((_rk4_step, _advance), K.SOURCES, "plant_step")
