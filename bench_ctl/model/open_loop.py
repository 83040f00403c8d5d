"""The excitation system alone, driven by a recorded terminal voltage and field current (open loop).

The check issue 13 asks of every structure: the AVR / exciter of the kernel, with the generator
cut away, fed the Vt and Ifd another simulator (or a unit) recorded, must give the efd it
recorded. It runs the kernel's own blocks (`kernel.rhs`, `ceilings`, `field_voltage`) so that what is
checked is what identification simulates; only the generator's states are replaced by the record:
with KPP = KDA = 0 and no generator saturation the kernel reads Vt = E''q and Ifd = E'q, so the
recorded Vt and Ifd are fed in as those two states, linearly interpolated to each RK4 stage, and
their derivatives are zero (a moving ceiling is re-applied at every step end instead).

The setpoint jumps at given instants (inside a sample where the record puts them there); a step
holding one is split there, as the closed-loop kernel does. The exciter starts in the steady
state of the unit's values (as the closed loop does); a record that does not start there shows
the difference as error, which is part of what the check measures.

Effects inside the loop that have no open-loop meaning here (dead time, setpoint ramp, recorder
skew) are refused.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numba as nb
import numpy as np

from . import kernel as K
from .params import KERNEL_PARAMS


@nb.njit(cache=True, inline="always", error_model="numpy")
def _interp(t0, dt, y, tt):
    """y (sampled from t0 every dt) at tt, linear, held beyond the ends."""
    s = (tt - t0) / dt
    n = y.shape[0]
    if s <= 0.0:
        return y[0]
    if s >= n - 1:
        return y[n - 1]
    j = int(s)
    f = s - j
    return y[j] + f * (y[j + 1] - y[j])


@nb.njit(cache=True, error_model="numpy")
def _open_loop(D, t0, dt, T, uref0, etimes, ejumps, vt, ifd, out):
    xm = D[K.D_VT0, 0]
    x1 = D[K.D_E0, 0]
    x2 = D[K.D_X20, 0]
    ef = D[K.D_EFD0, 0]
    xf = D[K.D_XF0, 0]
    xe = D[K.D_XE0, 0]
    ne = etimes.shape[0]
    cuts = np.empty(ne + 2)
    for k in range(T):
        tk = t0 + k * dt
        out[k] = D[K.D_GAIN, 0] * K.field_voltage(D, 0, ef, ifd[k], vt[k], xf, xe)
        if k == T - 1:
            break
        # the step [t_k, t_k+1], split at every setpoint edge inside it
        nc = 0
        cuts[nc] = tk
        nc += 1
        for j in range(ne):
            if tk < etimes[j] < tk + dt:
                cuts[nc] = etimes[j]
                nc += 1
        cuts[nc] = tk + dt
        nc += 1
        for q in range(nc - 1):
            a = cuts[q]
            b = cuts[q + 1]
            h = b - a
            if h <= 0.0:
                continue
            mid = 0.5 * (a + b)
            u = uref0
            for j in range(ne):
                if etimes[j] <= mid:
                    u += ejumps[j]
            ga = _interp(t0, dt, ifd, a)
            va = _interp(t0, dt, vt, a)
            gm = _interp(t0, dt, ifd, mid)
            vmid = _interp(t0, dt, vt, mid)
            gb = _interp(t0, dt, ifd, b)
            vb = _interp(t0, dt, vt, b)
            h2 = 0.5 * h
            r1 = K.rhs(D, 0, u, 0.0, xm, x1, x2, ef, ga, va, xf, xe)
            r2 = K.rhs(D, 0, u, 0.0, xm + h2 * r1[0], x1 + h2 * r1[1], x2 + h2 * r1[2], ef + h2 * r1[3],
                        gm, vmid, xf + h2 * r1[6], xe + h2 * r1[7])
            r3 = K.rhs(D, 0, u, 0.0, xm + h2 * r2[0], x1 + h2 * r2[1], x2 + h2 * r2[2], ef + h2 * r2[3],
                        gm, vmid, xf + h2 * r2[6], xe + h2 * r2[7])
            r4 = K.rhs(D, 0, u, 0.0, xm + h * r3[0], x1 + h * r3[1], x2 + h * r3[2], ef + h * r3[3],
                        gb, vb, xf + h * r3[6], xe + h * r3[7])
            h6 = h / 6.0
            xm += h6 * (r1[0] + 2 * r2[0] + 2 * r3[0] + r4[0])
            x1 += h6 * (r1[1] + 2 * r2[1] + 2 * r3[1] + r4[1])
            x2 += h6 * (r1[2] + 2 * r2[2] + 2 * r3[2] + r4[2])
            y3 = ef + h6 * (r1[3] + 2 * r2[3] + 2 * r3[3] + r4[3])
            xf += h6 * (r1[6] + 2 * r2[6] + 2 * r3[6] + r4[6])
            xe += h6 * (r1[7] + 2 * r2[7] + 2 * r3[7] + r4[7])
            hi, lo = K.ceilings(D, 0, gb, vb)
            z3 = y3 if y3 > lo else lo
            z3 = z3 if z3 < hi else hi
            ef = z3 + D[K.D_LIMOUT, 0] * (y3 - z3)


# numba keys the cache on this file alone: flush it when a file of the kernel package changes
K.drop_stale_cache((_open_loop,), K.SOURCES, "open_loop")


def run_open_loop(values: Mapping[str, float], time: np.ndarray, vt: np.ndarray, ifd: np.ndarray,
                  edge_times: Sequence[float] = (), edge_jumps: Sequence[float] = ()) -> np.ndarray:
    """efd of the excitation system of `values` (every kernel parameter) fed the recorded `vt` and
    `ifd` (pu, on a uniform `time` grid), its setpoint starting where the steady state of `values`
    puts it and jumping by `edge_jumps[j]` (pu) at `edge_times[j]` (s, on the record's clock)."""
    missing = [n for n in KERNEL_PARAMS if n not in values]
    if missing:
        raise ValueError(f"open loop: no value for {missing}")
    for name, neutral in (("TD", 0.0), ("SKEW", 0.0)):
        if float(values[name]) != neutral:
            raise ValueError(f"open loop: {name} = {values[name]!r}; the exciter alone has no {name}")
    if np.isfinite(float(values["RAMP"])):
        raise ValueError(f"open loop: RAMP = {values['RAMP']!r}; a setpoint ramp needs the closed loop")
    t = np.asarray(time, float)
    vt = np.ascontiguousarray(vt, dtype=np.float64)
    ifd = np.ascontiguousarray(ifd, dtype=np.float64)
    if not (t.size == vt.size == ifd.size) or t.size < 2:
        raise ValueError(f"open loop: time, vt, ifd must have one equal length >= 2 "
                         f"(got {t.size}, {vt.size}, {ifd.size})")
    dt = float(t[1] - t[0])
    if not dt > 0 or not np.allclose(np.diff(t), dt, rtol=1e-6, atol=1e-12):
        raise ValueError("open loop: the time grid must be uniform and increasing")
    if len(edge_times) != len(edge_jumps):
        raise ValueError("open loop: one jump per edge time")
    P = np.array([[float(values[n]) for n in KERNEL_PARAMS]])
    D = K.derive(P)
    if D[0, K.D_VALID] == 0.0:
        raise ValueError("open loop: the values are not a valid unit (see `bench-ctl models`)")
    # the generator cut away: Vt = E''q and Ifd = E'q, fed from the record, with no dynamics
    for col in (K.D_KPP, K.D_SATVT, K.D_KDA, K.D_SATB, K.D_ITD0P, K.D_ITD0PP):
        D[0, col] = 0.0
    out = np.empty(t.size)
    uref0 = float(D[0, K.D_UREF0])
    _open_loop(np.ascontiguousarray(D.T), float(t[0]), dt, t.size, uref0,
               np.asarray(edge_times, float), np.asarray(edge_jumps, float), vt, ifd, out)
    return out
