"""Compiling the engine ahead of its first use: a unit's variants, or all of them (`bench-ctl
warm-up`, CI before the tests, a Dask worker before its first task), side by side in child
processes that write numba's disk cache; with a warm cache nothing is started.

(Child processes, not multiprocessing: a spawned worker re-imports the caller's main script, which
need not guard itself.)
"""
from __future__ import annotations

import logging
import os
from concurrent.futures import ThreadPoolExecutor

import numba as nb

from .layout import X_FULL, X_REF, X_ST4, X_ST4_ONLY
from .variants import EXCITERS, Key, cached, compile_in_child, compile_key, run_arguments, variant

log = logging.getLogger(__name__)

#: every variant: each machine under each class of blocks, on the grid with and without an IEEEST;
#: a PSS2A / PSS2B on the standard-structure blocks (`engine.grid_key`; with an ESST4B it compiles
#: its own variant on first use)
ALL: tuple[Key, ...] = tuple(
    [Key("noload", x) for x in (X_REF, X_FULL, X_ST4, X_ST4_ONLY)]
    + [Key("grid", x, s) for s in ("none", "ieeest") for x in (X_REF, X_FULL, X_ST4, X_ST4_ONLY)]
    + [Key("grid", X_FULL, "pss2")]
    + [Key("recorded", x) for x in (X_REF, X_FULL, X_ST4, X_ST4_ONLY)])
_BY_NAME = {k.name: k for k in ALL}


def key_named(name: str) -> Key:
    """The variant of a name (`Key.name`)."""
    try:
        return _BY_NAME[name]
    except KeyError:
        raise ValueError(f"unknown engine variant {name!r}; known: {', '.join(_BY_NAME)}") from None


def missing(keys: tuple[Key, ...]) -> list[Key]:
    """The variants among `keys` numba's disk cache lacks."""
    out = []
    for key in keys:
        Dt, drive, edges, out_, sw = run_arguments(key)
        v = variant(key)
        sig = tuple(nb.typeof(a) for a in (Dt, 0, 1, 1, 1, 0, drive.ext))
        if not cached(v.functions["new_work"], sig):
            out.append(key)
            continue
        w = v.functions["new_work"](Dt, 0, 1, 1, 1, 0, drive.ext)
        sig = tuple(nb.typeof(a) for a in (w, drive, edges, out_, 0, 4, 3, sw))
        if not cached(v.functions["advance"], sig):
            out.append(key)
    return out


def warm(keys: tuple[Key, ...], workers: int | None = None, report=None) -> dict[str, float]:
    """Compile the variants among `keys` the cache lacks, up to `workers` at once (default one a
    core), each in a child process that writes the cache (in this process when the child fails:
    `variants` says why not here); `report(name, seconds)` after each. Returns the seconds each
    took (empty when the cache held them all)."""
    todo = missing(tuple(keys))
    workers = max(1, min(len(todo), workers or os.cpu_count() or 1))
    seconds: dict[str, float] = {}

    def child(key: Key) -> None:
        took = compile_in_child(key)
        seconds[key.name] = took if took is not None else compile_key(key)
        if report:
            report(key, seconds[key.name])

    with ThreadPoolExecutor(workers) as pool:  # threads that wait on the children
        list(pool.map(child, todo))
    return seconds


__all__ = ["ALL", "EXCITERS", "Key", "compile_key", "key_named", "missing", "warm"]
