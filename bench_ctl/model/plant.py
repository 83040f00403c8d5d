"""The real-time plant: the reference unit (with its switchable effects) stepped at 1 kHz.

The plant is what the simulated devices share: the exciter writes its digital setpoint into it
and reads Vt, Efd and field current from it; the recorder samples it. It reuses the kernel's
numerics (`bench_ctl.model.kernel`: `_rhs`, `_rk4`, `_avr`, `_delayed`, `_hermite`, `derive`)
for one parameter set, with the state carried from call to call, so stepping the plant offline
with a setpoint series reproduces `bench_ctl.model.simulate.simulate()`.

Conventions (the kernel's): sample k is the state at t_k = k * dt; the setpoint of step k acts
on [t_k, t_k+1) (zero-order hold); the recorded efd (`efd_rec`) includes the recorder-side
effects (recorder_gain, time_skew), `efd` is the exciter's true output.

Real time (`start()`): a thread steps the plant against `time.monotonic()`; step k is computed
once the wall clock has passed t_k+1, in a burst when the thread was late, so plant time never
runs ahead of wall time and catches up after a stall. A setpoint written at wall time t
(`write_setpoint`) acts from step ceil((t - t0) / dt), i.e. from the next plant step, whatever
the thread's lag. `timing()` reports the lag statistics.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable

import numba as nb
import numpy as np

from . import kernel as K
from .simulate import param_matrix
from .unit import Unit, load_unit

log = logging.getLogger(__name__)

#: columns of the per-sample output block
(O_USETP, O_EFD_REC, O_VT, O_EFD, O_EQP, O_UREF, O_FLAGS) = range(7)
N_OUT = 7
#: flag bits in O_FLAGS
FLAG_CEILING, FLAG_RATE, FLAG_RAMP, FLAG_FAILED = 1, 2, 4, 8

_FM = {"contract", "arcp", "reassoc", "afn"}


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
    h2 = 0.5 * dt
    h6 = dt / 6.0
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
                    y = K._hermite(ef_h[0, j % Ls], der_r[0, j % Ls], ef_h[0, (j + 1) % Ls],
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
            vr_r[0, k % L] = K._avr(D, 0, ua, vm0, X[1], X[2])[0]
            base = k - td / dt
            v0 = K._delayed(vr_r, vr_l, 0, L, base, k, e0, False)
            v1 = K._delayed(vr_r, vr_l, 0, L, base + 0.5, k, e0, False)
            v2 = K._delayed(vr_r, vr_l, 0, L, base + 1.0, k, e0, True)
        x0, x1, x2, x3, x4, x5 = X[0], X[1], X[2], X[3], X[4], X[5]
        um = 0.5 * (ua + ub)
        a = K._rhs(D, 0, ua, v0, x0, x1, x2, x3, x4, x5)
        b = K._rhs(D, 0, um, v1, x0 + h2 * a[0], x1 + h2 * a[1], x2 + h2 * a[2], x3 + h2 * a[3],
                   x4 + h2 * a[4], x5 + h2 * a[5])
        c = K._rhs(D, 0, um, v1, x0 + h2 * b[0], x1 + h2 * b[1], x2 + h2 * b[2], x3 + h2 * b[3],
                   x4 + h2 * b[4], x5 + h2 * b[5])
        d = K._rhs(D, 0, ub, v2, x0 + dt * c[0], x1 + dt * c[1], x2 + dt * c[2], x3 + dt * c[3],
                   x4 + dt * c[4], x5 + dt * c[5])
        if skew > 0.0:
            ef_h[0, k % Ls] = x3
            der_r[0, k % Ls] = a[3]
            der_l[0, (k + 1) % Ls] = d[3]
        X[0] = x0 + h6 * (a[0] + 2.0 * b[0] + 2.0 * c[0] + d[0])
        X[1] = x1 + h6 * (a[1] + 2.0 * b[1] + 2.0 * c[1] + d[1])
        X[2] = x2 + h6 * (a[2] + 2.0 * b[2] + 2.0 * c[2] + d[2])
        X[3] = x3 + h6 * (a[3] + 2.0 * b[3] + 2.0 * c[3] + d[3])
        X[4] = x4 + h6 * (a[4] + 2.0 * b[4] + 2.0 * c[4] + d[4])
        X[5] = x5 + h6 * (a[5] + 2.0 * b[5] + 2.0 * c[5] + d[5])
        X[3] = min(max(X[3], D[K.D_VRMIN, 0]), D[K.D_VRMAX, 0])
        X[6] = ub
        mag = abs(X[0]) + abs(X[1]) + abs(X[2]) + abs(X[3]) + abs(X[4]) + abs(X[5])
        if not (mag < K.BLOWUP):
            X[8] = 1.0
            X[0] = D[K.D_VT0, 0]; X[4] = D[K.D_VT0, 0]; X[5] = D[K.D_VT0, 0]
            X[3] = e0; X[1] = D[K.D_E0, 0]; X[2] = D[K.D_E0, 0]
        # ---- a dead time that is not a whole number of steps: split the step (as the kernel) ----
        if td > 0.0 and X[8] == 0.0:
            base = k - td / dt
            j0 = math.floor(base)
            frac = base - j0
            if frac >= 1e-9 and j0 + 1 < k:
                th = 1.0 - frac
                uth = ua + th * (ub - ua)
                va = K._delayed(vr_r, vr_l, 0, L, base, k, e0, False)
                vam = K._delayed(vr_r, vr_l, 0, L, base + 0.5 * th, k, e0, False)
                vae = K._delayed(vr_r, vr_l, 0, L, j0 + 1.0, k, e0, True)
                vb = K._delayed(vr_r, vr_l, 0, L, j0 + 1.0, k, e0, False)
                vbm = K._delayed(vr_r, vr_l, 0, L, j0 + 1.0 + 0.5 * frac, k, e0, False)
                vbe = K._delayed(vr_r, vr_l, 0, L, base + 1.0, k, e0, True)
                ra = K._rk4(D, 0, ua, uth, va, vam, vae, x0, x1, x2, x3, x4, x5, th * dt)
                rb = K._rk4(D, 0, uth, ub, vb, vbm, vbe, ra[0], ra[1], ra[2], ra[3], ra[4], ra[5],
                            frac * dt)
                X[0] = rb[0]; X[1] = rb[1]; X[2] = rb[2]; X[3] = rb[3]; X[4] = rb[4]; X[5] = rb[5]
                if skew > 0.0:
                    der_r[0, k % Ls] = ra[6]
                    der_l[0, (k + 1) % Ls] = rb[7]
        if skew > 0.0:
            ef_h[0, (k + 1) % Ls] = X[3]
        vm = X[0] if D[K.D_ITR, 0] > 0.0 else X[5]
        vr = K._avr(D, 0, ub, vm, X[1], X[2])[0]
        if td > 0.0:
            vr_l[0, (k + 1) % L] = vr
        # ---- limiter flags after the step ----
        flags = 0.0
        if X[3] >= D[K.D_VRMAX, 0] or X[3] <= D[K.D_VRMIN, 0]:
            flags += 1.0
        if abs((vr - X[3]) * D[K.D_ITE, 0]) > D[K.D_RATE, 0]:
            flags += 2.0
        if ub != target:
            flags += 4.0
        if X[8] != 0.0:
            flags += 8.0
        out[s, 6] = flags


@dataclass(frozen=True)
class PlantState:
    """A snapshot of the plant after its last step (exciter readings)."""
    step: int                 # number of steps taken; plant time = step * dt
    time_s: float
    usetp: float              # digital setpoint acting now
    active_setpoint: float    # setpoint after the device's ramp (pu)
    vt: float
    efd: float
    ifd: float                # field current, pu: E'q + Sat(E'q)
    flags: int                # FLAG_* bits


@dataclass(frozen=True)
class PlantTiming:
    """Real-time statistics: lag = wall time - plant time, sampled after every burst."""
    steps: int
    elapsed_s: float
    lag_mean_s: float
    lag_max_s: float
    lag_p99_s: float
    late_bursts: int          # bursts of more than one step (the thread woke late)
    max_burst: int
    drift_s: float            # (wall - plant) at the end minus at the start
    behind_max_s: float       # wall - plant time when the thread woke, before catching up
    behind_p99_s: float       # (>= one step by construction: a step is computed after its end)
    stalls_over_1ms: int      # wake-ups that found the plant more than one step + 1 ms behind


Listener = Callable[[int, np.ndarray], None]


class Plant:
    """The reference unit stepping with carried state; offline (`advance`) or real time (`start`)."""

    def __init__(self, unit: Unit | None = None, *, dt: float = 1e-3,
                 usetp0: float | None = None) -> None:
        self.unit = unit if unit is not None else load_unit(None)
        self.dt = float(dt)
        values = self.unit.values()
        self._D = np.ascontiguousarray(K.derive(param_matrix(values)).T)
        if self._D[K.D_VALID, 0] == 0.0:
            raise ValueError(f"unit {self.unit.name!r}: parameters are not valid for the kernel")
        self.vt0 = float(self._D[K.D_VT0, 0])
        #: the setpoint at which the plant starts in steady state (uref = uref0)
        self.usetp_pre = float(values["Vt0"] if usetp0 is None else usetp0)
        D = self._D
        sat_a, sat_b = float(D[K.D_SATA, 0]), float(D[K.D_SATB, 0])
        self._sat = (sat_a, sat_b)
        L = int(math.ceil(D[K.D_TD, 0] / self.dt)) + 3 if D[K.D_TD, 0] > 0 else 1
        Ls = int(math.ceil(D[K.D_SKEW, 0] / self.dt)) + 3 if D[K.D_SKEW, 0] > 0 else 1
        e0 = D[K.D_EFD0, 0]
        self._X = np.array([self.vt0, D[K.D_E0, 0], D[K.D_E0, 0], e0, self.vt0, self.vt0,
                            D[K.D_UREF0, 0], D[K.D_GAIN, 0] * e0, 0.0])
        self._vr_r = np.full((1, L), e0)
        self._vr_l = np.full((1, L), e0)
        self._ef_h = np.full((1, Ls), e0)
        self._der_r = np.zeros((1, Ls))
        self._der_l = np.zeros((1, Ls))
        self._k = 0
        self._usetp = self.usetp_pre
        self._flags = 0
        self._lock = threading.Lock()              # state + setpoint queue
        self._pending: deque[tuple[int, float]] = deque()   # (step, value) for real time
        self._listeners: list[Listener] = []
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._running = threading.Event()
        self.t0: float | None = None               # monotonic time of plant time 0 (real time)
        self._lags: list[float] = []
        self._behind: list[float] = []
        self._bursts = 0
        self._max_burst = 0
        self._first_lag: float | None = None
        self._last_lag = 0.0

    # ------------------------------------------------------------------ offline stepping
    def advance(self, usetp: np.ndarray | float, n: int | None = None) -> np.ndarray:
        """Take len(usetp) steps (or n steps at a constant setpoint); returns the samples (n, N_OUT)."""
        u = np.full(int(n), float(usetp)) if n is not None else np.ascontiguousarray(usetp, float)
        out = np.empty((u.shape[0], N_OUT))
        with self._lock:
            self._step_locked(u, out)
        return out

    def _step_locked(self, u: np.ndarray, out: np.ndarray) -> None:
        if u.shape[0] == 0:
            return
        _advance(self._D, self._X, self._vr_r, self._vr_l, self._ef_h, self._der_r, self._der_l,
                 self._k, u, self.usetp_pre, self.dt, out)
        self._k += u.shape[0]
        self._usetp = float(u[-1])
        self._flags = int(out[-1, O_FLAGS])
        if self._flags & FLAG_FAILED:
            log.error("plant state left its sane range at step %d; parked at steady state", self._k)

    def add_listener(self, fn: Listener) -> None:
        """fn(first_step, samples) is called (plant thread) after every burst of steps."""
        self._listeners.append(fn)

    def remove_listener(self, fn: Listener) -> None:
        if fn in self._listeners:
            self._listeners.remove(fn)

    @property
    def step(self) -> int:
        return self._k

    def state(self) -> PlantState:
        with self._lock:
            X = self._X
            a, b = self._sat
            eqp = float(X[4])
            ifd = eqp + (b * (eqp - a) ** 2 if eqp > a else 0.0)
            ref = self.usetp_pre + float(X[6]) - float(self._D[K.D_UREF0, 0])
            return PlantState(self._k, self._k * self.dt, self._usetp, ref, float(X[5]),
                              float(X[3]), ifd, self._flags)

    # ------------------------------------------------------------------ real time
    def write_setpoint(self, value: float, at: float | None = None) -> int:
        """Set the digital setpoint; acts from the next plant step after wall time `at`.

        Returns the plant step index from which the new value acts."""
        if not math.isfinite(value):
            raise ValueError(f"plant setpoint {value!r} is not finite")
        with self._lock:
            now = time.monotonic() if at is None else at
            if self.t0 is None:        # offline: from the next step taken
                self._pending.append((self._k, float(value)))
                return self._k
            k = max(self._k, math.ceil((now - self.t0) / self.dt - 1e-9))
            self._pending.append((k, float(value)))
            return k

    def _inputs(self, k0: int, n: int) -> np.ndarray:
        """Setpoint per step k0..k0+n-1 from the pending changes (lock held)."""
        u = np.empty(n)
        cur = self._usetp
        pos = 0
        while self._pending and self._pending[0][0] < k0 + n:
            k, v = self._pending.popleft()
            idx = max(k - k0, 0)
            u[pos:idx] = cur
            pos = max(pos, idx)
            cur = v
        u[pos:] = cur
        return u

    def run_offline(self, n: int) -> np.ndarray:
        """Take n steps using the setpoint changes written so far (no clock)."""
        with self._lock:
            u = self._inputs(self._k, n)
            out = np.empty((n, N_OUT))
            self._step_locked(u, out)
        for fn in list(self._listeners):
            fn(self._k - n, out)
        return out

    def start(self) -> float:
        """Start real-time stepping in a daemon thread; returns t0 (monotonic)."""
        if self._thread is not None:
            raise RuntimeError("plant already started")
        # warm the compiled stepper so the first real step is not late by the compile time
        self._warm()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="plant", daemon=True)
        self._thread.start()
        self._running.wait()
        assert self.t0 is not None
        return self.t0

    def _warm(self) -> None:
        X = self._X.copy()
        scratch = [a.copy() for a in (self._vr_r, self._vr_l, self._ef_h, self._der_r, self._der_l)]
        _advance(self._D, X, *scratch, 0, np.full(2, self.usetp_pre), self.usetp_pre, self.dt,
                 np.empty((2, N_OUT)))

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def _run(self) -> None:
        dt = self.dt
        with self._lock:
            self.t0 = time.monotonic() - self._k * dt
        self._running.set()
        out_buf = np.empty((1024, N_OUT))
        while not self._stop.is_set():
            now = time.monotonic()
            due = int((now - self.t0) / dt)
            n = due - self._k
            if n > 0:
                behind = now - self.t0 - self._k * dt
                n = min(n, out_buf.shape[0])
                with self._lock:
                    k0 = self._k
                    u = self._inputs(k0, n)
                    out = out_buf[:n]
                    self._step_locked(u, out)
                for fn in list(self._listeners):
                    try:
                        fn(k0, out)
                    except Exception:  # a listener must never stop the plant
                        log.exception("plant listener %r failed", fn)
                lag = time.monotonic() - self.t0 - self._k * dt
                self._note_lag(lag, n, behind)
                continue
            wait = self.t0 + (self._k + 1) * dt - time.monotonic()
            if wait > 0:
                time.sleep(wait)

    def _note_lag(self, lag: float, n: int, behind: float) -> None:
        if self._first_lag is None:
            self._first_lag = lag
        self._last_lag = lag
        if len(self._lags) < 2_000_000:
            self._lags.append(lag)
            self._behind.append(behind)
        if n > 1:
            self._bursts += 1
            self._max_burst = max(self._max_burst, n)

    def reset_timing(self) -> None:
        """Forget the lag statistics (e.g. after warm-up)."""
        self._lags = []
        self._behind = []
        self._bursts = 0
        self._max_burst = 0
        self._first_lag = None

    def timing(self) -> PlantTiming:
        n = min(len(self._lags), len(self._behind))
        lags = np.asarray(self._lags[:n]) if n else np.zeros(1)
        behind = np.asarray(self._behind[:n]) if n else np.zeros(1)
        elapsed = (time.monotonic() - self.t0) if self.t0 is not None else 0.0
        return PlantTiming(self._k, elapsed, float(lags.mean()), float(lags.max()),
                           float(np.percentile(lags, 99)), self._bursts, self._max_burst,
                           float(self._last_lag - (self._first_lag or 0.0)),
                           float(behind.max()), float(np.percentile(behind, 99)),
                           int(np.count_nonzero(behind > self.dt + 1e-3)))

    def wall_to_step(self, t_wall: float) -> float:
        """Plant step (fractional) at monotonic wall time t_wall (real time only)."""
        if self.t0 is None:
            raise RuntimeError("plant not started in real time")
        return (t_wall - self.t0) / self.dt
