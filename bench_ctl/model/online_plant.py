"""The unit on the grid as the simulated bench's plant (issue 27, item 4): `sim --online`.

The machine of `bench_ctl.model.online` (a GENROU or GENSAL through XE to an infinite bus, under the
unit's excitation system) stepped with carried state, offline or in real time, behind the same
interface as the no-load `Plant`: the exciter writes its setpoint and reads Vt, Efd, Ifd, P and Q,
the recorder samples the columns `channels` names (usetp, efd, vt, p, q, ifd). Stepping it with a
setpoint series reproduces `online.run_online` sample for sample (tests/model/test_online_plant.py).

The turbine is a mechanical power, `set_mech_power` (pu on the machine base): the electrical P
follows it through the swing equation; Q follows the excitation. Powers read in MW and Mvar on the
device through `mva`, the machine base.

Real time: a Python thread sleeps to each step's deadline on CLOCK_MONOTONIC and computes every
step the clock has passed in one compiled call that releases the GIL (`online.advance`); the
setpoint ring, the sample ring, the listeners and the timing statistics are the no-load plant's.
The compiled no-load loop (`realtime._rt_loop`) inlines the no-load step, so it cannot run this
machine; a Python-timed loop wakes up later than a compiled one (its figures are in `timing()`),
but the plant's time never runs ahead of the wall clock and a setpoint still acts from the first
step after it was written, so the record is the same (docs/decisions/0018).
"""
from __future__ import annotations

import math
import time

import numpy as np

from .kernel.layout import CHUNK, D_VALID
from .online import (
    A_EFD_REC,
    A_IFD,
    A_P,
    A_Q,
    A_USETP,
    A_VT,
    G_TM,
    G_VALID,
    N_ADVANCE,
    N_ONLINE,
    advance,
    derive_on_line,
    initial_state,
    machine_matrix,
    unit_machine,
)
from .plant import Plant, PlantState
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
    RING,
    SP_RING,
)
from .simulate import param_matrix
from .unit import Unit, load_unit

#: the turbine's mechanical power the plant accepts, pu on the machine base
TURBINE_PU = (-0.2, 1.2)


class OnlinePlant(Plant):
    """The unit synchronised to an infinite bus, stepping with carried state (see the module
    docstring); `unit` needs the machine's data, XE and the operating point P0, Q0 in its [grid]."""

    on_line = True
    channels = {"usetp": A_USETP, "efd": A_EFD_REC, "vt": A_VT, "p": A_P, "q": A_Q, "ifd": A_IFD}

    def __init__(self, unit: Unit | None = None, *, dt: float = 1e-3, usetp0: float | None = None,
                 rt_priority: int | None = 10, mva: float = 100.0) -> None:
        self.unit = unit if unit is not None else load_unit(None)
        self._clock(dt, rt_priority)
        if not (mva > 0 and math.isfinite(mva)):
            raise ValueError(f"machine base {mva!r} MVA must be positive")
        #: the machine base (MVA): P and Q in MW and Mvar on the device
        self.mva = float(mva)
        values = self.unit.values()
        # the compiled step runs chunks of CHUNK candidates: candidate 0 is the plant, the others copies
        P, M = param_matrix(values), machine_matrix(unit_machine(self.unit))
        self._D, self._G = derive_on_line(np.repeat(P, CHUNK, axis=0), np.repeat(M, CHUNK, axis=0))
        if self._D[D_VALID, 0] == 0.0:
            raise ValueError(f"unit {self.unit.name!r}: parameters are not valid for the kernel")
        if self._G[G_VALID, 0] == 0.0:
            raise ValueError(f"unit {self.unit.name!r}: the machine's reactances are out of order "
                             "(Xd > X'd > X''d > Xl, Xq >= X'q >= X''d) or H, T''q0 not positive")
        self.vt0 = float(values["Vt0"])
        self.usetp_pre = float(values["Vt0"] if usetp0 is None else usetp0)
        self._X = np.zeros((N_ONLINE, CHUNK))
        initial_state(self._D, self._G, 0, self._X, 0)
        self._X0 = self._X[:, 0].copy()    # the operating point, where a blown-up state is parked
        self._last = np.zeros(6)         # (efd, Vt, P, Q, Ifd, flags) after the last step
        self._runtime(N_ADVANCE)
        advance(self._D, self._G, self._X, self._X0, np.empty(0), self.usetp_pre, self.dt,
                np.empty((0, N_ADVANCE)), self._last)

    # ------------------------------------------------------------------ the turbine
    @property
    def mech_power(self) -> float:
        """The turbine's mechanical power, pu on the machine base."""
        return float(self._G[G_TM, 0])

    def set_mech_power(self, pu: float) -> None:
        """Set the turbine's mechanical power (pu on the machine base); acts from the next step."""
        if not math.isfinite(pu) or not TURBINE_PU[0] <= pu <= TURBINE_PU[1]:
            raise ValueError(f"mechanical power {pu!r} pu outside {TURBINE_PU[0]:g}..{TURBINE_PU[1]:g} pu")
        self._G[G_TM, 0] = float(pu)

    # ------------------------------------------------------------------ stepping
    def _step_locked(self, u: np.ndarray, out: np.ndarray) -> None:
        if self.realtime:
            raise RuntimeError("the plant runs in real time; offline stepping is not possible")
        if u.shape[0] == 0:
            return
        advance(self._D, self._G, self._X, self._X0, u, self.usetp_pre, self.dt, out, self._last)
        self._ctrl[C_K] += u.shape[0]
        self._fst[F_USETP] = float(u[-1])
        self._flags = int(self._last[5])

    def state(self) -> PlantState:
        last = self._last.copy()
        k = self.step
        usetp = float(self._fst[F_USETP])
        return PlantState(k, k * self.dt, usetp, usetp, float(last[1]), float(last[0]), float(last[4]),
                          int(last[5]), p=float(last[2]), q=float(last[3]))

    def _warm(self) -> None:
        """Compile (or load from cache) before the clock starts."""
        u = np.full(2, self.usetp_pre)
        advance(self._D, self._G.copy(), self._X.copy(), self._X0, u, self.usetp_pre, self.dt,
                np.empty((2, self._n_out)), np.zeros(6))

    def _loop_thread(self) -> None:
        """Sleep to each step's deadline; compute every step the clock has passed in one call."""
        self._raise_priority()
        ctrl, fst = self._ctrl, self._fst
        t0, dt_ns = self._t0_ns, self._dt_ns
        buf = np.empty((MAX_BURST, self._n_out))
        k = int(ctrl[C_K])
        usetp = float(fst[F_USETP])
        while ctrl[C_STOP] == 0:
            now = time.monotonic_ns()
            n = (now - t0) // dt_ns - k
            if n <= 0:
                time.sleep((t0 + (k + 1) * dt_ns - now) * 1e-9)
                continue
            behind_ns = now - t0 - k * dt_ns
            n = min(n, MAX_BURST)
            u = np.full(n, usetp)
            spr, spw = int(ctrl[C_SPR]), int(ctrl[C_SPW])
            while spr < spw and self._sp_step[spr % SP_RING] < k + n:
                at = int(self._sp_step[spr % SP_RING])
                if at < k:
                    ctrl[C_LATESP] += 1
                usetp = float(self._sp_val[spr % SP_RING])
                u[max(at - k, 0):] = usetp
                spr += 1
            ctrl[C_SPR] = spr
            rows = buf[:n]
            advance(self._D, self._G, self._X, self._X0, u, self.usetp_pre, self.dt, rows, self._last)
            self._ring[(k + np.arange(n)) % RING] = rows
            fst[F_USETP] = usetp
            k += n
            ctrl[C_K] = k
            self._count(behind_ns, time.monotonic_ns() - t0 - k * dt_ns, n)

    def _count(self, behind_ns: int, lag_ns: int, n: int) -> None:
        """The timing statistics of one burst, as the compiled no-load loop keeps them."""
        ctrl, fst = self._ctrl, self._fst
        if ctrl[C_RESET] != 0:
            ctrl[C_NSTAT] = ctrl[C_BURSTS] = ctrl[C_MAXBURST] = ctrl[C_STALLS] = 0
            fst[F_LAGMAX] = fst[F_BEHINDMAX] = 0.0
            ctrl[C_RESET] = 0
        lag_s, behind_s = lag_ns * 1e-9, behind_ns * 1e-9
        i = int(ctrl[C_NSTAT])
        if i == 0:
            fst[F_FIRSTLAG] = lag_s
        fst[F_LASTLAG] = lag_s
        self._lag[i % self._lag.shape[0]] = lag_s
        self._behind[i % self._behind.shape[0]] = behind_s
        ctrl[C_NSTAT] = i + 1
        fst[F_LAGMAX] = max(fst[F_LAGMAX], lag_s)
        fst[F_BEHINDMAX] = max(fst[F_BEHINDMAX], behind_s)
        if n > 1:
            ctrl[C_BURSTS] += 1
            ctrl[C_MAXBURST] = max(int(ctrl[C_MAXBURST]), n)
        if behind_ns > self._dt_ns + 1_000_000:
            ctrl[C_STALLS] += 1


def warm_up(unit: Unit | None = None) -> float:
    """Compile (or load from the cache) the on-line plant's step (`online.advance`, which links the
    vectorised step in: minutes on a fresh machine); seconds. `make test` runs it before the tests, so
    a dry run's simulated bench starts within its timeout."""
    t0 = time.perf_counter()
    plant = OnlinePlant(unit, rt_priority=None)
    plant._warm()
    plant.advance(plant.usetp_pre, 2)
    return time.perf_counter() - t0
