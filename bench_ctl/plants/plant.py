"""The real-time plants: the unit (with its switchable effects) stepped at 1 kHz, at no load
(`Plant`) or on the grid (`OnlinePlant`).

A plant is what the simulated devices share: the exciter writes its digital setpoint into it and
reads Vt, Efd, the field current (and on line P and Q) from it; the recorder samples it. It is one
candidate of the engine (`bench_ctl.engine`) with its state carried from call to call, so stepping
a plant offline with a setpoint series reproduces `engine.run` sample for sample.

Conventions (the engine's): sample k is the state at t_k = k * dt; the setpoint of step k acts on
[t_k, t_k+1) (zero-order hold); the recorded efd (`efd_rec`) includes the recorder-side effects
(recorder_gain, time_skew), `efd` is the exciter's true output. A sample's flags say what acted in
the step after it (a ceiling reached, the slew limit, the setpoint ramp, a failure).

Real time (`start()`): a thread runs a compiled loop that does not hold the GIL (so the Python
threads serving Modbus cannot delay it) against CLOCK_MONOTONIC (= `time.monotonic`): step k is
computed once the clock has passed t_k+1, in a burst when the loop woke late, so plant time never
runs ahead of wall time and catches up after a stall; between steps it sleeps to an absolute
deadline. The thread asks for SCHED_FIFO priority (`rt_priority`, best effort). A setpoint written
at wall time t (`write_setpoint`) acts from step ceil((t - t0) / dt), i.e. from the next plant
step, whatever the loop's lag. Samples go to a ring buffer; a second (Python) thread hands them to
the listeners (recorder, watchdog) a few ms later, in order and without gaps. `timing()` reports
lag statistics. The compiled loop is `plants.realtime`.
"""
from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque

import numba as nb
import numpy as np

from bench_ctl import engine
from bench_ctl.engine import classify, grid_key, variant
from bench_ctl.engine.derived import derive
from bench_ctl.engine.layout import D_GVALID, D_SKEW, D_TD, D_TM, D_UREF0, D_VALID, R_FLD
from bench_ctl.engine.machines import grid
from bench_ctl.engine.runner import C_UREF, FLAG_CEILING, FLAG_FAILED, FLAG_RAMP, FLAG_RATE, Drive, Edges, Out, Switches
from bench_ctl.engine.simulate import param_matrix
from bench_ctl.engine.stabilisers import OUTPUT_LIMIT_ROWS
from bench_ctl.engine.variants import Key, cached
from bench_ctl.units.unit import Unit, load_unit

from . import realtime as RT
from .realtime import (
    C_BURSTS,
    C_K,
    C_LATESP,
    C_MAXBURST,
    C_NSTAT,
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
)
from .samples import (
    KEEP_COLUMNS,
    N_OUT,
    O_EFD_REC,
    O_FLAGS,
    O_IFD,
    O_P,
    O_Q,
    O_USETP,
    O_VT,
    Listener,
    PlantState,
    PlantTiming,
)

#: the real-time loop's compile time (s of one core, measured: `bench-ctl warm-up` with an empty cache)
RT_LOOP_ESTIMATE_S = 10.0

log = logging.getLogger(__name__)

#: the turbine's mechanical power an on-line plant accepts, pu on the machine base
TURBINE_PU = (-0.2, 1.2)

__all__ = ["FLAG_CEILING", "FLAG_FAILED", "FLAG_RAMP", "FLAG_RATE", "Plant", "OnlinePlant", "TURBINE_PU", "warm_up"]

_RT_LOOPS: dict[Key, object] = {}


class Plant:
    """The unit at no load stepping with carried state; offline (`advance`) or real time
    (`start`)."""

    #: the unit is synchronised (P and Q are the machine's, not a set load)
    on_line = False
    #: recorded channel -> column of the per-sample block the listeners get
    channels: dict[str, int] = {"usetp": O_USETP, "efd": O_EFD_REC, "vt": O_VT}

    def __init__(self, unit: Unit | None = None, *, dt: float = 1e-3, usetp0: float | None = None,
                 rt_priority: int | None = 10) -> None:
        self.unit = unit if unit is not None else load_unit(None)
        self._clock(dt, rt_priority)
        values = self.unit.values()
        self.usetp_pre = float(values["Vt0"] if usetp0 is None else usetp0)
        self._setup(*self._derived(param_matrix(values)))

    def _derived(self, P: np.ndarray) -> tuple[np.ndarray, Key]:
        """The plant's derived row and its variant: the unit at no load."""
        D = derive(P)
        if D[0, D_VALID] == 0.0:
            raise ValueError(f"unit {self.unit.name!r}: parameters are not valid for the engine")
        return D, Key("noload", classify(D))

    def _setup(self, D: np.ndarray, key: Key) -> None:
        """The plant's candidate: its variant, its Work at the initial state, a sample's run."""
        self._variant = variant(key)
        self.vt0 = float(D[0, engine.layout.D_VT0])
        td, skew = float(D[0, D_TD]), float(D[0, D_SKEW])
        self._sw = Switches(td > 0, skew > 0, float(D[0, engine.layout.D_RAMP]) < 1.0e300, False, True,
                            int(math.ceil(td / self.dt)) + 3 if td > 0 else 1,
                            int(math.ceil(skew / self.dt)) + 3 if skew > 0 else 1)
        self._edges = Edges(np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0, np.int64),
                            np.zeros(1, np.uint8))
        self._ext = np.zeros((2, 1))
        self._work = self._variant.call("new_work", np.ascontiguousarray(D.T), 0, 1, self._sw.ring, self._sw.ring_skew,
                                        0, self._ext)
        self._uref0 = float(D[0, D_UREF0])
        self._runtime(N_OUT)

    def _run(self, u: np.ndarray) -> tuple[Drive, Out]:
        """A call's Drive and Out for the setpoints u."""
        n = u.shape[0]
        drive = Drive(u, self.usetp_pre, self.dt, np.zeros((4, 1)), np.zeros(4), self._ext)
        return drive, Out(np.zeros((N_OUT, 1, n)), KEEP_COLUMNS, np.zeros((4, 1)), np.zeros((4, 1)), np.full(1, -1))

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
        with self._lock:
            return self._step_locked(u)

    def _step_locked(self, u: np.ndarray) -> np.ndarray:
        if self.realtime:
            raise RuntimeError("the plant runs in real time; offline stepping is not possible")
        if u.shape[0] == 0:
            return np.empty((0, self._n_out))
        u = np.require(u, np.float64, ("C", "W"))
        drive, out = self._run(u)
        self._variant.call("advance", self._work, drive, self._edges, out, self.step, u.shape[0], -1, self._sw)
        rows = np.ascontiguousarray(out.traces[:, 0, :].T)
        rows[:, O_USETP] = u
        self._ctrl[C_K] += u.shape[0]
        self._fst[F_USETP] = float(u[-1])
        self._flags = int(rows[-1, O_FLAGS])
        if self._flags & FLAG_FAILED:
            log.error("plant state left its sane range at step %d; parked at its initial state", self.step)
        return rows

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
            out = self._step_locked(u)
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
        w = self._work
        k = self.step
        flags = int(self._ring[(k - 1) % RING, O_FLAGS]) if self.realtime and k else self._flags
        vt, ifd, p, q = (float(w.R[row, 0]) if row is not None else 0.0 for row in self._signal_rows())
        usetp = float(self._fst[F_USETP])
        active = self.usetp_pre + float(w.cand[C_UREF, 0]) - self._uref0
        return PlantState(k, k * self.dt, usetp, active, vt, float(w.R[R_FLD, 0]), ifd, flags, p=p, q=q)

    def _signal_rows(self) -> tuple[int | None, ...]:
        """The readout rows of Vt, Ifd, P, Q (`engine.step`: the machine's algebra from row 2)."""
        return 2, 3, None, None

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
        self.warm()
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

    def _rt_args(self, work, clock) -> tuple:
        drive, out = self._run(np.full(1, self.usetp_pre))
        return (work, (drive, self._edges, out, self._sw, (1, -1)), clock, self._t0_ns, self._dt_ns, self.usetp_pre,
                self.dt, MAX_BURST)

    def _loop(self):
        loop = _RT_LOOPS.get(self._variant.key)
        if loop is None:
            loop = _RT_LOOPS[self._variant.key] = RT.loop_for(self._variant)
        return loop

    def warm(self) -> None:
        """Compile (or load from cache) the real-time loop before the clock starts (on copies)."""
        work = type(self._work)(*(a.copy() for a in self._work))
        ctrl = np.zeros(N_CTRL, np.int64)
        ctrl[C_STOP] = 1
        clock = (ctrl, self._sp_step.copy(), self._sp_val.copy(), self._fst.copy(), np.zeros((4, self._n_out)),
                 np.zeros(4), np.zeros(4))
        loop, args = self._loop(), self._rt_args(work, clock)
        drive, edges, out, sw, (one, last) = args[1]
        # the variant's step first (said while it compiles), which the loop then calls as compiled
        self._variant.call("advance", work, drive, edges, out, self.step, one, last, sw)
        sig = tuple(nb.typeof(a) for a in args)
        if sig in loop.overloads or cached(loop, sig):   # in memory, or loaded from numba's disk cache
            loop(*args)
            return
        with engine.compiling(f"real-time loop of the {self._variant.key.words()}", RT_LOOP_ESTIMATE_S):
            loop(*args)

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
        clock = (self._ctrl, self._sp_step, self._sp_val, self._fst, self._ring, self._lag, self._behind)
        self._loop()(*self._rt_args(self._work, clock))

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
        from .realtime import C_RESET
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


class OnlinePlant(Plant):
    """The unit synchronised to an infinite bus (`engine.machines.grid`), stepping with carried
    state; `unit` needs the machine's data, XE and the operating point P0, Q0 in its [grid]. The
    turbine is a mechanical power (`set_mech_power`, pu on the machine base): the electrical P
    follows it through the swing equation; Q follows the excitation. Powers read in MW and Mvar on
    the device through `mva`, the machine base. The unit's stabiliser ([grid] PSS_MODEL) has an
    output switch (`set_pss`, on at the start): off, its output is held at 0 while its states keep
    running on the speed and power, as a real PSS whose output is switched."""

    on_line = True
    channels = {"usetp": O_USETP, "efd": O_EFD_REC, "vt": O_VT, "p": O_P, "q": O_Q, "ifd": O_IFD}

    def __init__(self, unit: Unit | None = None, *, dt: float = 1e-3, usetp0: float | None = None,
                 rt_priority: int | None = 10, mva: float = 100.0) -> None:
        if not (mva > 0 and math.isfinite(mva)):
            raise ValueError(f"machine base {mva!r} MVA must be positive")
        #: the machine base (MVA): P and Q in MW and Mvar on the device
        self.mva = float(mva)
        super().__init__(unit, dt=dt, usetp0=usetp0, rt_priority=rt_priority)
        self._pss_limits = self._work.D[list(OUTPUT_LIMIT_ROWS), 0].copy()
        #: the stabiliser's output switch (True: its output reaches the exciter's reference)
        self.pss_on = True

    def _derived(self, P: np.ndarray) -> tuple[np.ndarray, Key]:
        D = grid.derive_grid(P, grid.machine_matrix(grid.unit_machine(self.unit)))
        if D[0, D_VALID] == 0.0:
            raise ValueError(f"unit {self.unit.name!r}: parameters are not valid for the engine")
        if D[0, D_GVALID] == 0.0:
            raise ValueError(f"unit {self.unit.name!r}: the machine's reactances are out of order "
                             "(Xd > X'd > X''d > Xl, Xq >= X'q >= X''d) or H, T''q0 not positive")
        return D, grid_key(D)

    def _signal_rows(self) -> tuple[int | None, ...]:
        return 2, 3, 6, 7

    @property
    def mech_power(self) -> float:
        """The turbine's mechanical power, pu on the machine base."""
        return float(self._work.D[D_TM, 0])

    def set_mech_power(self, pu: float) -> None:
        """Set the turbine's mechanical power (pu on the machine base); acts from the next step."""
        if not math.isfinite(pu) or not TURBINE_PU[0] <= pu <= TURBINE_PU[1]:
            raise ValueError(f"mechanical power {pu!r} pu outside {TURBINE_PU[0]:g}..{TURBINE_PU[1]:g} pu")
        self._work.D[D_TM, 0] = float(pu)

    def set_pss(self, on: bool) -> None:
        """Switch the stabiliser's output on or off, from the next step: off holds its output
        limits at 0 (`OUTPUT_LIMIT_ROWS`), so it adds nothing to the reference while its states
        keep running; on puts the unit's limits back. A unit without a stabiliser is unchanged."""
        self._work.D[list(OUTPUT_LIMIT_ROWS), 0] = self._pss_limits if on else 0.0
        self.pss_on = bool(on)


def warm_up(unit: Unit | None = None, *, online: bool = False) -> float:
    """Compile (or load from the cache) a plant's stepping and real-time loop; seconds."""
    t0 = time.perf_counter()
    plant = OnlinePlant(unit, rt_priority=None) if online else Plant(unit, rt_priority=None)
    plant.warm()
    plant.advance(plant.usetp_pre, 2)
    return time.perf_counter() - t0
