"""Independent fits side by side, on threads.

The kernel's entry points release the GIL (`kernel.jit.njit(nogil=True)`, and the on-line
machine's, and the derivation of the candidates' matrix), so fits that share nothing run their
kernel calls at once, one a core. Their numpy and SciPy steps (MVMO's bookkeeping, SLSQP, the
least squares) mostly hold the GIL and take turns. The structure selection fits its candidate
structures this way and the diagnosis its effects.

Each fit keeps its own seed and its result keeps its place in the list, and the kernel splits a
call into chunks that keep every candidate in the same kind of loop whatever runs beside it, so
the answer is the same bit for bit on one thread or two (docs/decisions/0022-fits-side-by-side.md).

How many at once: `BENCH_CTL_FIT_THREADS` when set, else what `set_fit_threads` set (a Dask
worker of a fleet run sets 1: its cluster already runs one worker a core), else the cores this
process may use, at most `MAX_THREADS`.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

__all__ = ["MAX_THREADS", "fit_threads", "set_fit_threads", "map_fits"]

T = TypeVar("T")
R = TypeVar("R")

#: the default's ceiling: the share of a fit that holds the GIL is about half of it (the selection
#: on the Mostar record: 2.3 s of 5 s in the kernel), so a third thread would mostly wait on it;
#: two is what was measured (docs/benchmarks.md, "Fits side by side")
MAX_THREADS = 2
ENV = "BENCH_CTL_FIT_THREADS"

_threads: int | None = None


def set_fit_threads(n: int | None) -> None:
    """Run at most n fits at once in this process (None: the default again)."""
    global _threads
    if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
        raise ValueError(f"fit threads {n!r}: need an integer >= 1")
    _threads = n


def fit_threads() -> int:
    """How many fits run at once (module docstring)."""
    raw = os.environ.get(ENV, "").strip()
    if raw:
        try:
            n = int(raw)
        except ValueError:
            n = 0
        if n < 1:
            raise ValueError(f"{ENV}={raw!r}: need an integer >= 1")
        return n
    if _threads is not None:
        return _threads
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_THREADS))


def map_fits(fn: Callable[[T], R], items: Iterable[T], each: Callable[[T, R], object] | None = None) -> list[R]:
    """[fn(item) for item in items], up to `fit_threads()` at once. `each(item, result)` runs on
    the calling thread, in the items' order, as soon as that result and those before it are in
    (a progress line). The first exception raised is raised here, once the fits already running
    have ended (those not started are dropped)."""
    todo = list(items)
    n = min(fit_threads(), len(todo))
    if n <= 1:
        return _in_order(todo, map(fn, todo), each)
    # BLAS on one thread around the pool: each fit's own limit (run_identification, diagnose)
    # restores what it found when it ends, and it must find 1 there, not the machine's count
    # left behind by a fit that ended on the other thread
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        pool = ThreadPoolExecutor(n, thread_name_prefix="bench-ctl-fit")
        try:
            return _in_order(todo, pool.map(fn, todo), each)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _in_order(todo: list[T], results: Iterable[R], each: Callable[[T, R], object] | None) -> list[R]:
    """The results as a list, `each` called on every one as it comes, in order."""
    out: list[R] = []
    for x, r in zip(todo, results):
        out.append(r)
        if each is not None:
            each(x, r)
    return out
