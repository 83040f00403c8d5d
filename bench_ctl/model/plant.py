"""The real-time plant: the reference unit (with its switchable effects) stepped at 1 kHz.

The plant is what the simulated devices share: the exciter writes its digital setpoint into it
and reads Vt, Efd and field current from it; the recorder samples it. It reuses the kernel's
numerics for one parameter set (`bench_ctl.model.plant_step`), with the state carried from call
to call, so stepping the plant offline with a setpoint series reproduces
`bench_ctl.model.simulate.simulate()`.

Conventions (the kernel's): sample k is the state at t_k = k * dt; the setpoint of step k acts
on [t_k, t_k+1) (zero-order hold); the recorded efd (`efd_rec`) includes the recorder-side
effects (recorder_gain, time_skew), `efd` is the exciter's true output.

Real time (`start()`): a thread runs a compiled loop that does not hold the GIL (so the
Python threads serving Modbus cannot delay it) against CLOCK_MONOTONIC (= `time.monotonic`):
step k is computed once the clock has passed t_k+1, in a burst when the loop woke late, so plant
time never runs ahead of wall time and catches up after a stall; between steps it sleeps to an
absolute deadline (no accumulated drift). The thread asks for SCHED_FIFO priority (`rt_priority`,
best effort) so that other processes on a loaded machine do not delay it. A setpoint written at
wall time t (`write_setpoint`) acts from step ceil((t - t0) / dt), i.e. from the next plant
step, whatever the loop's lag. Samples go to a ring buffer; a second (Python) thread hands them
to the listeners (recorder, watchdog) a few ms later, in order and without gaps. `timing()`
reports lag statistics. The compiled loop is `bench_ctl.model.realtime`.
"""
from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import kernel as K
from .plant_step import (
    FLAG_CEILING,
    FLAG_FAILED,
    FLAG_RAMP,
    FLAG_RATE,
    N_OUT,
    O_EFD,
    O_EFD_REC,
    O_EQP,
    O_FLAGS,
    O_UREF,
    O_USETP,
    O_VT,
    _advance,
)
from .realtime import (
    C_BURSTS,
    C_K,
    C_LATESP,
    C_MAXBURST,
    C_NSTAT,
    C_RESET,
    C_SPR,
    C_SPW,
    C_STALLS,
    C_STOP,
    F_BEHINDMAX,
    F_FIRSTLAG,
    F_LAGMAX,
    F_LASTLAG,
    F_USETP,
    MAX_BURST,
    N_CTRL,
    N_F,
    RING,
    SP_RING,
    STAT_RING,
    _rt_loop,
)
from .simulate import param_matrix
from .unit import Unit, load_unit

log = logging.getLogger(__name__)

# the per-sample output block of `Plant.advance` and the listeners: columns and flag bits
__all__ = ["FLAG_CEILING", "FLAG_FAILED", "FLAG_RAMP", "FLAG_RATE", "N_OUT", "O_EFD", "O_EFD_REC", "O_EQP",
           "O_FLAGS", "O_UREF", "O_USETP", "O_VT", "Listener", "Plant", "PlantState", "PlantTiming"]


@dataclass(frozen=True)
class PlantState:
    """A snapshot of the plant after its last step (exciter readings)."""
    step: int                 # number of steps taken; plant time = step * dt
    time_s: float
    usetp: float              # digital setpoint acting now
    active_setpoint: float    # setpoint after the device's ramp (pu)
    vt: float
    efd: float
    ifd: float                # field current, pu: E'q + Sat(E'q) (on line: XadIfd)
    flags: int                # FLAG_* bits
    p: float = 0.0            # active and reactive power, pu on the machine base (on line)
    q: float = 0.0


@dataclass(frozen=True)
class PlantTiming:
    """Real-time statistics: lag = wall time - plant time after each burst of steps."""
    steps: int
    elapsed_s: float
    lag_mean_s: float
    lag_max_s: float
    lag_p99_s: float
    late_bursts: int          # bursts of more than one step (the loop woke late)
    max_burst: int
    drift_s: float            # lag at the last burst minus lag at the first
    behind_max_s: float       # wall - plant time when the loop woke, before catching up
    behind_p99_s: float       # (>= one step by construction: a step is computed after its end)
    stalls_over_1ms: int      # wake-ups that found the plant more than one step + 1 ms behind
    late_setpoints: int       # setpoint changes published after their step had been computed


Listener = Callable[[int, np.ndarray], None]


class Plant:
    """The reference unit stepping with carried state; offline (`advance`) or real time (`start`)."""

    def __init__(self, unit: Unit | None = None, *, dt: float = 1e-3,
                 usetp0: float | None = None, rt_priority: int | None = 10) -> None:
        self.unit = unit if unit is not None else load_unit(None)
        self._clock(dt, rt_priority)
        values = self.unit.values()
        self._D = np.ascontiguousarray(K.derive(param_matrix(values)).T)
        if self._D[K.D_VALID, 0] == 0.0:
            raise ValueError(f"unit {self.unit.name!r}: parameters are not valid for the kernel")
        D = self._D
        self.vt0 = float(D[K.D_VT0, 0])
        #: the setpoint at which the plant starts in steady state (uref = uref0)
        self.usetp_pre = float(values["Vt0"] if usetp0 is None else usetp0)
        self._sat = (float(D[K.D_SATA, 0]), float(D[K.D_SATB, 0]))
        L = int(math.ceil(D[K.D_TD, 0] / self.dt)) + 3 if D[K.D_TD, 0] > 0 else 1
        Ls = int(math.ceil(D[K.D_SKEW, 0] / self.dt)) + 3 if D[K.D_SKEW, 0] > 0 else 1
        e0 = D[K.D_EFD0, 0]
        self._X = np.array([self.vt0, D[K.D_E0, 0], D[K.D_E0, 0], e0, self.vt0, self.vt0,
                            D[K.D_UREF0, 0], D[K.D_GAIN, 0] * e0, 0.0])
        self._hist = (np.full((1, L), e0), np.full((1, L), e0), np.full((1, Ls), e0),
                      np.zeros((1, Ls)), np.zeros((1, Ls)))
        self._runtime(N_OUT)

    #: the unit is synchronised (P and Q are the machine's, not a set load)
    on_line = False
    #: recorded channel -> column of the per-sample block the listeners get
    channels: dict[str, int] = {"usetp": O_USETP, "efd": O_EFD_REC, "vt": O_VT}

    def _clock(self, dt: float, rt_priority: int | None) -> None:
        self.dt = float(dt)
        self._dt_ns = int(round(self.dt * 1e9))
        if self._dt_ns * 1e-9 != self.dt and abs(self._dt_ns * 1e-9 - self.dt) > 1e-15:
            raise ValueError(f"plant step {dt!r} s is not a whole number of ns")
        #: SCHED_FIFO priority of the stepping thread (None: normal scheduling)
        self.rt_priority = rt_priority
        self.rt_active = False

    def _runtime(self, n_out: int) -> None:
        """What stepping needs whatever the model: control words, rings, locks, listeners."""
        self._n_out = n_out
        self._ctrl = np.zeros(N_CTRL, np.int64)          # shared with the compiled loop
        self._fst = np.zeros(N_F)
        self._fst[F_USETP] = self.usetp_pre
        self._sp_step = np.zeros(SP_RING, np.int64)
        self._sp_val = np.zeros(SP_RING)
        self._ring = np.zeros((RING, n_out))
        self._lag = np.zeros(STAT_RING)
        self._behind = np.zeros(STAT_RING)
        self._flags = 0
        self._lock = threading.Lock()                    # offline stepping, setpoint writers
        self._pending: deque[tuple[int, float]] = deque()   # offline setpoint changes
        self._last_sp_step = 0
        self._listeners: list[Listener] = []
        self._threads: list[threading.Thread] = []
        self._stopping = threading.Event()
        self.t0: float | None = None     # monotonic time of plant time 0 (real time)
        self._t0_ns = 0

    # ------------------------------------------------------------------ offline stepping
    @property
    def realtime(self) -> bool:
        return self.t0 is not None

    @property
    def step(self) -> int:
        """Steps taken so far; plant time = step * dt."""
        return int(self._ctrl[C_K])

    def advance(self, usetp: np.ndarray | float, n: int | None = None) -> np.ndarray:
        """Take len(usetp) steps (or n steps at a constant setpoint); returns the samples (n, N_OUT)."""
        u = np.full(int(n), float(usetp)) if n is not None else np.ascontiguousarray(usetp, float)
        out = np.empty((u.shape[0], self._n_out))
        with self._lock:
            self._step_locked(u, out)
        return out

    def _step_locked(self, u: np.ndarray, out: np.ndarray) -> None:
        if self.realtime:
            raise RuntimeError("the plant runs in real time; offline stepping is not possible")
        if u.shape[0] == 0:
            return
        _advance(self._D, self._X, *self._hist, self.step, u, self.usetp_pre, self.dt, out)
        self._ctrl[C_K] += u.shape[0]
        self._fst[F_USETP] = float(u[-1])
        self._flags = int(out[-1, O_FLAGS])
        if self._flags & FLAG_FAILED:
            log.error("plant state left its sane range at step %d; parked at steady state", self.step)

    def run_offline(self, n: int) -> np.ndarray:
        """Take n steps using the setpoint changes written so far (no clock); feeds listeners."""
        with self._lock:
            k0 = self.step
            u = np.empty(n)
            cur = float(self._fst[F_USETP])
            pos = 0
            while self._pending and self._pending[0][0] < k0 + n:
                k, v = self._pending.popleft()
                idx = max(k - k0, 0)
                u[pos:idx] = cur
                pos = max(pos, idx)
                cur = v
            u[pos:] = cur
            out = np.empty((n, self._n_out))
            self._step_locked(u, out)
        for fn in list(self._listeners):
            fn(k0, out)
        return out

    def add_listener(self, fn: Listener) -> None:
        """fn(first_step, samples) is called (listener thread) for every new block of samples."""
        self._listeners.append(fn)

    def remove_listener(self, fn: Listener) -> None:
        if fn in self._listeners:
            self._listeners.remove(fn)

    def state(self) -> PlantState:
        """The latest state (read without stopping the loop: values may straddle one step)."""
        X = self._X.copy()
        k = self.step
        flags = int(self._ring[(k - 1) % RING, O_FLAGS]) if self.realtime and k else self._flags
        a, b = self._sat
        eqp = float(X[4])
        ifd = eqp + (b * (eqp - a) ** 2 if eqp > a else 0.0)
        ref = self.usetp_pre + float(X[6]) - float(self._D[K.D_UREF0, 0])
        return PlantState(k, k * self.dt, float(self._fst[F_USETP]), ref, float(X[5]),
                          float(X[3]), ifd, flags)

    # ------------------------------------------------------------------ real time
    def write_setpoint(self, value: float, at: float | None = None) -> int:
        """Set the digital setpoint; acts from the first plant step after wall time `at`
        (default now; offline: from the next step taken). Returns that step."""
        if not math.isfinite(value):
            raise ValueError(f"plant setpoint {value!r} is not finite")
        with self._lock:
            if not self.realtime:
                self._pending.append((self.step, float(value)))
                return self.step
            now = time.monotonic() if at is None else at
            k = max(self.step, self._last_sp_step,
                    math.ceil((now - self.t0) / self.dt - 1e-9))
            i = int(self._ctrl[C_SPW])
            if i - int(self._ctrl[C_SPR]) >= SP_RING:
                raise RuntimeError("plant setpoint queue full (the plant loop is not running)")
            self._sp_step[i % SP_RING] = k
            self._sp_val[i % SP_RING] = float(value)
            self._ctrl[C_SPW] = i + 1
            self._last_sp_step = k
            return k

    def start(self) -> float:
        """Start real-time stepping; returns t0 (monotonic time of plant time 0)."""
        if self._threads:
            raise RuntimeError("plant already started")
        self._warm()
        with self._lock:
            self._t0_ns = time.monotonic_ns() - self.step * self._dt_ns
            self.t0 = self._t0_ns * 1e-9
            self._ctrl[C_STOP] = 0
            for k, v in self._pending:          # offline changes not yet stepped
                i = int(self._ctrl[C_SPW])
                self._sp_step[i % SP_RING], self._sp_val[i % SP_RING] = k, v
                self._ctrl[C_SPW] = i + 1
            self._pending.clear()
        self._stopping.clear()
        first = self.step
        self._threads = [threading.Thread(target=self._loop_thread, name="plant", daemon=True),
                         threading.Thread(target=self._dispatch, args=(first,),
                                          name="plant-listeners", daemon=True)]
        for t in self._threads:
            t.start()
        return self.t0

    def _warm(self) -> None:
        """Compile (or load from cache) before the clock starts."""
        X = self._X.copy()
        scratch = [a.copy() for a in self._hist]
        _advance(self._D, X, *scratch, 0, np.full(2, self.usetp_pre), self.usetp_pre, self.dt,
                 np.empty((2, N_OUT)))
        ctrl = np.zeros(N_CTRL, np.int64)
        ctrl[C_STOP] = 1
        _rt_loop(self._D, X, *scratch, ctrl, self._sp_step.copy(), self._sp_val.copy(),
                 self._fst.copy(), np.zeros((4, N_OUT)), np.zeros(4), np.zeros(4), 0,
                 self._dt_ns, self.usetp_pre, self.dt, MAX_BURST)

    def _raise_priority(self) -> None:
        """Best effort: SCHED_FIFO for this thread (Linux; needs CAP_SYS_NICE, e.g. root).

        On a loaded 2-core machine a normally scheduled thread wakes up to ~10 ms late; with
        SCHED_FIFO the plant stays within a step. The loop sleeps between steps, so the
        priority cannot starve the machine."""
        if self.rt_priority is None or not hasattr(os, "sched_setscheduler"):
            return
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.rt_priority))
            self.rt_active = True
        except (PermissionError, OSError) as exc:
            log.warning("plant: no real-time priority (%s); timing may suffer under load", exc)

    def _loop_thread(self) -> None:
        self._raise_priority()
        _rt_loop(self._D, self._X, *self._hist, self._ctrl, self._sp_step, self._sp_val,
                 self._fst, self._ring, self._lag, self._behind, self._t0_ns, self._dt_ns,
                 self.usetp_pre, self.dt, MAX_BURST)

    def _dispatch(self, done: int) -> None:
        """Hand new samples to the listeners, in order (runs until the loop has stopped)."""
        while True:
            k = self.step
            if k > done:
                if k - done > RING:
                    log.error("plant listeners fell %d steps behind; samples %d..%d lost",
                              k - done, done, k - RING - 1)
                    done = k - RING
                a, b = done % RING, k % RING
                rows = self._ring[a:b].copy() if a < b else \
                    np.vstack([self._ring[a:], self._ring[:b]])
                for fn in list(self._listeners):
                    try:
                        fn(done, rows)
                    except Exception:  # a listener must never stop the others
                        log.exception("plant listener %r failed", fn)
                done = k
            elif self._stopping.is_set() and not self._threads[0].is_alive():
                return
            else:
                time.sleep(0.001)

    def stop(self) -> None:
        """Stop real-time stepping (the state is kept; idempotent)."""
        if not self._threads:
            return
        self._ctrl[C_STOP] = 1
        self._stopping.set()
        for t in self._threads:
            t.join(timeout=5.0)
        self._threads = []

    def reset_timing(self) -> None:
        """Forget the lag statistics (e.g. after warm-up); applied by the loop at its next burst."""
        self._ctrl[C_RESET] = 1

    def timing(self) -> PlantTiming:
        n = int(min(self._ctrl[C_NSTAT], STAT_RING))
        lags = self._lag[:n].copy() if n else np.zeros(1)
        behind = self._behind[:n].copy() if n else np.zeros(1)
        elapsed = (time.monotonic() - self.t0) if self.t0 is not None else 0.0
        c, f = self._ctrl, self._fst
        return PlantTiming(self.step, elapsed, float(lags.mean()), float(f[F_LAGMAX]),
                           float(np.percentile(lags, 99)), int(c[C_BURSTS]), int(c[C_MAXBURST]),
                           float(f[F_LASTLAG] - f[F_FIRSTLAG]), float(f[F_BEHINDMAX]),
                           float(np.percentile(behind, 99)), int(c[C_STALLS]), int(c[C_LATESP]))

    def wall_to_step(self, t_wall: float) -> float:
        """Plant step (fractional) at monotonic wall time t_wall (real time only)."""
        if self.t0 is None:
            raise RuntimeError("plant not started in real time")
        return (t_wall - self.t0) / self.dt
