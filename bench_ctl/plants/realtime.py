"""The plants' real-time loop: libc clocks from compiled code, stepping the engine against
CLOCK_MONOTONIC.

`rt_loop` runs without the GIL: step k is computed once the clock has passed t_k+1 (a burst after a
late wake-up), setpoint changes come through a ring (`sp_step`, `sp_val`), samples go to `ring`,
timing statistics to `lag` / `behind` and the control words `C_*` / `F_*` shared with
`plants.plant.Plant`. Each sample is one call of the engine's `advance` (slot `advance`, bound to
the plant's variant by `loop_for`), so every machine the engine runs steps in real time the same
way. `timer_jitter` measures the host's own wake-up lateness for such a loop, without a model: the
floor under the plant's timing figures.
"""
from __future__ import annotations

import os
import threading

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from bench_ctl.engine.jit import njit, specialise

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


@njit(nogil=True)
def now_ns(ctrl):
    """CLOCK_MONOTONIC in ns, through ctrl's timespec slots (the call may write ctrl, so the
    compiler re-reads the shared control words after it)."""
    _clock_gettime(np.int32(CLOCK_MONOTONIC), ctrl.ctypes.data + 8 * C_TS)
    return ctrl[C_TS] * 1_000_000_000 + ctrl[C_TS1]


#: the slot `loop_for` binds to a variant's `advance` (the engine's runner)
advance = None


@njit(nogil=True)
def rt_loop(w, run, clock, t0_ns, dt_ns, usetp_pre, dt, max_burst):
    """Step the plant's Work `w` in real time until ctrl[C_STOP]: `run` = (Drive, Edges, Out,
    Switches, (1, -1)) of one sample (the Drive's setpoint array of length 1 is rewritten each
    sample, the Out's traces hold that sample's columns 1..; the pair is `advance`'s sample count
    and last sample, passed in: a literal here would compile `advance` again for literal types),
    `clock` = (ctrl, sp_step, sp_val, fst, ring, lag, behind)."""
    drive, edges, out, sw, (one, last) = run
    ctrl, sp_step, sp_val, fst, ring, lag, behind = clock
    R = ring.shape[0]
    RS = sp_step.shape[0]
    NS = lag.shape[0]
    u1 = drive.usetp
    k = ctrl[C_K]
    usetp = fst[F_USETP]
    while ctrl[C_STOP] == 0:
        now = now_ns(ctrl)
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
            advance(w, drive, edges, out, kk, one, last, sw)
            row = kk % R
            ring[row, 0] = usetp
            for q in range(1, ring.shape[1]):
                ring[row, q] = out.traces[q, 0, 0]
        ctrl[C_SPR] = spr
        fst[F_USETP] = usetp
        k += n
        after = now_ns(ctrl)          # an external call: the samples are stored before K
        ctrl[C_K] = k
        _statistics(ctrl, fst, lag, behind, NS, (after - t0_ns - k * dt_ns) * 1e-9, behind_ns, dt_ns, n)


@njit(nogil=True)
def _statistics(ctrl, fst, lag, behind, NS, lag_s, behind_ns, dt_ns, n):
    """The timing statistics of one burst."""
    if ctrl[C_RESET] != 0:
        ctrl[C_NSTAT] = 0
        ctrl[C_BURSTS] = 0
        ctrl[C_MAXBURST] = 0
        ctrl[C_STALLS] = 0
        fst[F_LAGMAX] = 0.0
        fst[F_BEHINDMAX] = 0.0
        ctrl[C_RESET] = 0
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


def loop_for(variant):
    """`rt_loop` bound to `variant`'s `advance` (compiled, and cached, per variant)."""
    return specialise(rt_loop, variant.key.name, {"advance": variant.functions["advance"]})


@njit(nogil=True)
def _sleep_probe(ctrl, t0_ns, dt_ns, n, late):
    """Sleep to n absolute deadlines dt_ns apart, as the plant loop does, and store how late each
    wake-up came (ns). Nothing else runs: what it measures is the machine's timer jitter."""
    for k in range(n):
        deadline = t0_ns + (k + 1) * dt_ns
        ctrl[C_TS] = deadline // 1_000_000_000
        ctrl[C_TS1] = deadline % 1_000_000_000
        _clock_nanosleep(np.int32(CLOCK_MONOTONIC), np.int32(TIMER_ABSTIME), ctrl.ctypes.data + 8 * C_TS)
        late[k] = now_ns(ctrl) - deadline


def timer_jitter(seconds: float, *, dt: float = 1e-3, rt_priority: int | None = 10) -> dict[str, float]:
    """The machine's own wake-up lateness for a loop like the plant's (same clock calls, same
    priority, no model): the floor under the plant's timing figures on this host."""
    n = max(1, int(round(seconds / dt)))
    late = np.zeros(n, np.int64)
    ctrl = np.zeros(N_CTRL, np.int64)
    dt_ns = int(round(dt * 1e9))
    _sleep_probe(ctrl, now_ns(ctrl), dt_ns, 1, late[:1])  # compile / load before timing
    rt = [False]

    def run() -> None:
        if rt_priority is not None and hasattr(os, "sched_setscheduler"):
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt_priority))
                rt[0] = True
            except (PermissionError, OSError):
                pass
        _sleep_probe(ctrl, now_ns(ctrl), dt_ns, n, late)

    th = threading.Thread(target=run, name="timer-probe")
    th.start()
    th.join()
    ms = late * 1e-6
    return {"wakeups": n, "rt_priority": rt[0], "late_median_ms": float(np.median(ms)),
            "late_p99_ms": float(np.percentile(ms, 99)), "late_max_ms": float(ms.max()),
            "late_over_1ms": int(np.count_nonzero(ms > 1.0)), "late_over_5ms": int(np.count_nonzero(ms > 5.0))}
