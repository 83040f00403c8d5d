"""The real-time plant: the reference unit (with its switchable effects) stepped at 1 kHz.

The plant is what the simulated devices share: the exciter writes its digital setpoint into it
and reads Vt, Efd and field current from it; the recorder samples it. It reuses the kernel's
numerics (`bench_ctl.model.kernel`: `_rhs`, `_rk4`, `_avr`, `_delayed`, `_hermite`, `derive`)
for one parameter set, with the state carried from call to call, so stepping the plant offline
with a setpoint series reproduces `bench_ctl.model.simulate.simulate()`.

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
reports lag statistics.
"""
from __future__ import annotations

import hashlib
import logging
import math
import os
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

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
def _rk4_step(D, u0, u1, v0, vm, v1, x0, x1, x2, x3, x4, x5, h):
    """The kernel's RK4 step (with the efd clamp) for candidate 0. Kept out of line: the
    kernel's stage functions are inlined, and three inlined copies would triple compile time."""
    return K._rk4(D, 0, u0, u1, v0, vm, v1, x0, x1, x2, x3, x4, x5, h)


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
        r = _rk4_step(D, ua, ub, v0, v1, v2, x0, x1, x2, x3, x4, x5, dt)
        if skew > 0.0:
            ef_h[0, k % Ls] = x3
            der_r[0, k % Ls] = r[6]
            der_l[0, (k + 1) % Ls] = r[7]
        X[0] = r[0]; X[1] = r[1]; X[2] = r[2]; X[3] = r[3]; X[4] = r[4]; X[5] = r[5]
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
                ra = _rk4_step(D, ua, uth, va, vam, vae, x0, x1, x2, x3, x4, x5, th * dt)
                rb = _rk4_step(D, uth, ub, vb, vbm, vbe, ra[0], ra[1], ra[2], ra[3], ra[4], ra[5],
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


# ---------------------------------------------------------------------------- real-time loop
# libc clock calls declared by symbol name (not ctypes pointers) so the loop can be cached.
CLOCK_MONOTONIC = 1
TIMER_ABSTIME = 1
(C_STOP, C_K, C_SPW, C_SPR, C_TS, C_TS1, C_NSTAT, C_BURSTS, C_MAXBURST, C_STALLS, C_LATESP,
 C_RESET) = range(12)
N_CTRL = 12
(F_USETP, F_LAGMAX, F_BEHINDMAX, F_FIRSTLAG, F_LASTLAG) = range(5)
N_F = 5
RING = 1 << 14          # samples kept for the listeners (16 s at 1 kHz)
SP_RING = 1 << 10       # pending setpoint changes
STAT_RING = 1 << 17     # lag samples kept for percentiles (131 s of 1 ms wake-ups)
MAX_BURST = 1000


@intrinsic
def _clock_gettime(typingctx, clk, addr):
    sig = types.int32(types.int32, types.uintp)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.IntType(32), [ir.IntType(32), ir.IntType(8).as_pointer()])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "clock_gettime")
        return builder.call(fn, [args[0], builder.inttoptr(args[1], ir.IntType(8).as_pointer())])
    return sig, codegen


@intrinsic
def _clock_nanosleep(typingctx, clk, flags, addr):
    sig = types.int32(types.int32, types.int32, types.uintp)

    def codegen(context, builder, signature, args):
        ptr = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.IntType(32), [ir.IntType(32), ir.IntType(32), ptr, ptr])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "clock_nanosleep")
        return builder.call(fn, [args[0], args[1], builder.inttoptr(args[2], ptr),
                                 ir.Constant(ptr, None)])
    return sig, codegen


@nb.njit(cache=True, nogil=True)
def _now_ns(ctrl):
    """CLOCK_MONOTONIC in ns, through ctrl's timespec slots (the call may write ctrl, so the
    compiler re-reads the shared control words after it)."""
    _clock_gettime(np.int32(CLOCK_MONOTONIC), ctrl.ctypes.data + 8 * C_TS)
    return ctrl[C_TS] * 1_000_000_000 + ctrl[C_TS1]


@nb.njit(cache=True, nogil=True, error_model="numpy", fastmath=_FM)
def _rt_loop(D, X, vr_r, vr_l, ef_h, der_r, der_l, ctrl, sp_step, sp_val, fst, ring, lag, behind,
             t0_ns, dt_ns, usetp_pre, dt, max_burst):
    R = ring.shape[0]
    RS = sp_step.shape[0]
    NS = lag.shape[0]
    u1 = np.empty(1)
    k = ctrl[C_K]
    usetp = fst[F_USETP]
    while ctrl[C_STOP] == 0:
        now = _now_ns(ctrl)
        n = (now - t0_ns) // dt_ns - k
        if n <= 0:
            deadline = t0_ns + (k + 1) * dt_ns
            ctrl[C_TS] = deadline // 1_000_000_000
            ctrl[C_TS1] = deadline % 1_000_000_000
            _clock_nanosleep(np.int32(CLOCK_MONOTONIC), np.int32(TIMER_ABSTIME),
                             ctrl.ctypes.data + 8 * C_TS)
            continue
        behind_ns = now - t0_ns - k * dt_ns
        if n > max_burst:
            n = max_burst
        spw = ctrl[C_SPW]
        spr = ctrl[C_SPR]
        for s in range(n):
            kk = k + s
            while spr < spw and sp_step[spr % RS] <= kk:
                if sp_step[spr % RS] < kk:
                    ctrl[C_LATESP] += 1
                usetp = sp_val[spr % RS]
                spr += 1
            u1[0] = usetp
            row = kk % R
            _advance(D, X, vr_r, vr_l, ef_h, der_r, der_l, kk, u1, usetp_pre, dt,
                     ring[row:row + 1])
        ctrl[C_SPR] = spr
        fst[F_USETP] = usetp
        k += n
        after = _now_ns(ctrl)          # an external call: the samples are stored before K
        ctrl[C_K] = k
        if ctrl[C_RESET] != 0:
            ctrl[C_NSTAT] = 0
            ctrl[C_BURSTS] = 0
            ctrl[C_MAXBURST] = 0
            ctrl[C_STALLS] = 0
            fst[F_LAGMAX] = 0.0
            fst[F_BEHINDMAX] = 0.0
            ctrl[C_RESET] = 0
        lag_s = (after - t0_ns - k * dt_ns) * 1e-9
        behind_s = behind_ns * 1e-9
        i = ctrl[C_NSTAT]
        if i == 0:
            fst[F_FIRSTLAG] = lag_s
        fst[F_LASTLAG] = lag_s
        lag[i % NS] = lag_s
        behind[i % NS] = behind_s
        ctrl[C_NSTAT] = i + 1
        fst[F_LAGMAX] = max(fst[F_LAGMAX], lag_s)
        fst[F_BEHINDMAX] = max(fst[F_BEHINDMAX], behind_s)
        if n > 1:
            ctrl[C_BURSTS] += 1
            ctrl[C_MAXBURST] = max(ctrl[C_MAXBURST], n)
        if behind_ns > dt_ns + 1_000_000:
            ctrl[C_STALLS] += 1


@nb.njit(cache=True, nogil=True)
def _sleep_probe(ctrl, t0_ns, dt_ns, n, late):
    """Sleep to n absolute deadlines dt_ns apart, as the plant loop does, and store how late each
    wake-up came (ns). Nothing else runs: what it measures is the machine's timer jitter."""
    for k in range(n):
        deadline = t0_ns + (k + 1) * dt_ns
        ctrl[C_TS] = deadline // 1_000_000_000
        ctrl[C_TS1] = deadline % 1_000_000_000
        _clock_nanosleep(np.int32(CLOCK_MONOTONIC), np.int32(TIMER_ABSTIME), ctrl.ctypes.data + 8 * C_TS)
        late[k] = _now_ns(ctrl) - deadline


def timer_jitter(seconds: float, *, dt: float = 1e-3, rt_priority: int | None = 10) -> dict[str, float]:
    """The machine's own wake-up lateness for a loop like the plant's (same clock calls, same
    priority, no model): the floor under the plant's timing figures on this host."""
    n = max(1, int(round(seconds / dt)))
    late = np.zeros(n, np.int64)
    ctrl = np.zeros(N_CTRL, np.int64)
    dt_ns = int(round(dt * 1e9))
    _sleep_probe(ctrl, _now_ns(ctrl), dt_ns, 1, late[:1])  # compile / load before timing
    rt = [False]

    def run() -> None:
        if rt_priority is not None and hasattr(os, "sched_setscheduler"):
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt_priority))
                rt[0] = True
            except (PermissionError, OSError):
                pass
        _sleep_probe(ctrl, _now_ns(ctrl), dt_ns, n, late)

    th = threading.Thread(target=run, name="timer-probe")
    th.start()
    th.join()
    ms = late * 1e-6
    return {"wakeups": n, "rt_priority": rt[0], "late_median_ms": float(np.median(ms)),
            "late_p99_ms": float(np.percentile(ms, 99)), "late_max_ms": float(ms.max()),
            "late_over_1ms": int(np.count_nonzero(ms > 1.0)), "late_over_5ms": int(np.count_nonzero(ms > 5.0))}


def drop_stale_cache(dispatchers: tuple, source: str) -> bool:
    """Flush the disk cache of `dispatchers` (this module's compiled functions) when `source`
    (kernel.py, whose numerics they inline) changed since the cache was written.

    numba keys a function's disk cache on the stamp of its own file only, so after an edit of
    kernel.py the plant would keep running the old numerics from its cache. A hash of kernel.py
    is kept beside the cache; when it differs the cached plant code is flushed and recompiled.
    Returns True when it flushed."""
    caches = [c for c in (getattr(d, "_cache", None) for d in dispatchers) if c is not None]
    paths = {c.cache_path for c in caches if c.cache_path}
    if not paths:
        return False
    digest = hashlib.sha256(Path(source).read_bytes()).hexdigest()
    stamp = Path(sorted(paths)[0]) / f"{Path(__file__).stem}.kernel-sha256"
    try:
        if stamp.read_text(encoding="ascii").strip() == digest:
            return False
    except OSError:
        pass
    for c in caches:
        c.flush()
    try:
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.write_text(digest + "\n", encoding="ascii")
    except OSError as exc:  # a read-only cache folder: the code still runs, compiled afresh
        log.debug("cannot write %s: %s", stamp, exc)
    return True


_COMPILED = (_rk4_step, _advance, _now_ns, _rt_loop, _sleep_probe)
drop_stale_cache(_COMPILED, K.__file__)


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
        self.dt = float(dt)
        self._dt_ns = int(round(self.dt * 1e9))
        if self._dt_ns * 1e-9 != self.dt and abs(self._dt_ns * 1e-9 - self.dt) > 1e-15:
            raise ValueError(f"plant step {dt!r} s is not a whole number of ns")
        #: SCHED_FIFO priority of the stepping thread (None: normal scheduling)
        self.rt_priority = rt_priority
        self.rt_active = False
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
        self._ctrl = np.zeros(N_CTRL, np.int64)          # shared with the compiled loop
        self._fst = np.zeros(N_F)
        self._fst[F_USETP] = self.usetp_pre
        self._sp_step = np.zeros(SP_RING, np.int64)
        self._sp_val = np.zeros(SP_RING)
        self._ring = np.zeros((RING, N_OUT))
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
        out = np.empty((u.shape[0], N_OUT))
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
            out = np.empty((n, N_OUT))
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
