"""Compiling the kernel before its first run, its large parts side by side.

A fresh compilation takes minutes, and most of it goes to seven functions LLVM optimises one
after the other: the four vectorised RK4 loops, the reference structure's two loops over time and
the split step (docs/decisions/0003); the derivation of the candidates' matrix adds most of a
minute of numba's typing. None calls another, so `compile_parts` compiles the ones numba's disk
cache lacks side by side, each in a child process that writes the cache; the chunk runners that
call them then load them from the cache instead of compiling them one by one. With a warm cache
it starts nothing. (Child processes, not multiprocessing: a spawned worker re-imports the
caller's main script, which need not guard itself.)
"""
from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numba as nb
import numpy as np

from ..params import KERNEL_PARAMS
from . import rk4
from .derive import _derive
from .layout import CHUNK, N_DERIVED, N_STATES

log = logging.getLogger(__name__)

#: the parts, the longest to compile first (so that the workers end about together)
PARTS: tuple[str, ...] = ("rk4_all_st4_only", "rk4_all_st4", "split_step", "rk4_all_ref", "rk4_all",
                          "run_span_ref", "run_span_unlimited", "_derive")


def dispatcher(name: str):
    """The compiled function of part `name` (`derive._derive`, else the RK4 loops')."""
    return _derive if name == "_derive" else getattr(rk4, name)


def _arguments(name: str) -> tuple:
    """Arguments of the types `chunk.run_chunk` calls part `name` with (their values unused)."""
    cols = np.zeros
    if name == "_derive":  # the transposed parameter matrix, field0, whether it is given
        return (cols((len(KERNEL_PARAMS), 1)), cols(1), False)
    loop = (cols((N_DERIVED, CHUNK)), cols((10, CHUNK)), cols((2, CHUNK)), cols((3, CHUNK)), 1e-3, 0)
    if name in ("run_span_ref", "run_span_unlimited"):
        # D, S, W, usetp, efd_meas, k0, k1, usetp_pre, dt, m, store, efd_out, vt_out, lo
        return (loop[0], loop[1], cols((4, CHUNK)), cols(2), cols(2), 0, 0, 0.0, 1e-3, 0, False, cols((1, 1)),
                cols((1, 1)), 0)
    if name != "split_step":
        return loop
    D, S = loop[0], loop[1]
    ring = cols((1, 1))
    # D, c, k, dt, S, S0, nbrk, bs, bj, target, uref, base, td_on, L, vr_r, vr_l, jf, vjl, vjr,
    # skew_on, Ls, kf, kef, kdl, kdr
    return (D, 0, 0, 1e-3, S, cols((N_STATES, 1)), 0, cols(3), cols(3), 0.0, 0.0, 0.0, False, 1,
            ring, ring, ring, ring, ring, False, 1, ring, ring, ring, ring)


def signature(name: str) -> tuple:
    """The numba signature `chunk.run_chunk` calls part `name` with."""
    return tuple(nb.typeof(a) for a in _arguments(name))


def cached(name: str) -> bool:
    """Whether numba's disk cache holds part `name` for this machine (reads the entry)."""
    function = dispatcher(name)
    sig = signature(name)
    if sig in function.overloads:
        return True
    cache = getattr(function, "_cache", None)  # numba's per-function disk cache (no public API)
    try:
        return cache is not None and cache.load_overload(sig, function.targetctx) is not None
    except Exception:  # pragma: no cover - an unreadable cache entry: compile it afresh
        return False


def compile_part(name: str) -> float:
    """Compile (or load) part `name` for its signature; seconds."""
    t0 = time.perf_counter()
    dispatcher(name).compile(signature(name))
    return time.perf_counter() - t0


def compile_parts(workers: int | None = None) -> dict[str, float]:
    """Compile the parts the disk cache lacks, up to `workers` at once (default: one a core), each
    in a child process (`child_main`) that writes the cache. Returns the seconds each compiled
    part took (empty when the cache held them all). With one worker, or for a part whose child
    failed, this process compiles it itself."""
    missing = [name for name in PARTS if not cached(name)]
    workers = max(1, min(len(missing), workers or os.cpu_count() or 1))
    seconds: dict[str, float] = {}
    if workers > 1:
        log.info("compiling the kernel's %s, %d at a time", ", ".join(missing), workers)

        def child(name: str) -> None:
            done = subprocess.run([sys.executable, "-c", CHILD, name], stdout=subprocess.PIPE, text=True)
            if done.returncode == 0:
                seconds.update(json.loads(done.stdout))
            else:
                log.warning("compiling %s in a child process failed (exit %s)", name, done.returncode)

        with ThreadPoolExecutor(workers) as pool:  # threads that wait on the children
            list(pool.map(child, missing))
    for name in missing:  # what no child compiled
        if name not in seconds:
            seconds[name] = compile_part(name)
    return seconds


def child_main(names: list[str]) -> None:
    """A child process of `compile_parts`: compile `names`, print their seconds as JSON."""
    print(json.dumps({name: compile_part(name) for name in names}))


#: what a child process runs (not `-m` on this module: the package imports it first)
CHILD = "import sys; from bench_ctl.model.kernel.precompile import child_main; child_main(sys.argv[1:])"
