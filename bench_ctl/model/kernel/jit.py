"""How the kernel is compiled: the numba decorator of its functions, the LLVM options its RK4
loops need to be vectorised, and the guard that keeps numba's disk cache from running stale code.

numba keys a function's disk cache on the stamp of its own file only, while the kernel's loops
inline the blocks of sibling files (and the plant's code inlines the kernel's): `drop_stale_cache`
flushes a cache when any file it depends on changed. `SOURCES` is every file of this package;
the package guards its own dispatchers with it (`__init__`), the plant's modules theirs.
"""
from __future__ import annotations

import hashlib
import logging
import os
import threading
from collections.abc import Callable
from pathlib import Path

import llvmlite.binding as _llvm
import numba as nb

log = logging.getLogger(__name__)

# The RK4 loop over candidates reads ~40 rows of 2-D arrays; LLVM's loop vectoriser needs a
# runtime alias check per pair and gives up past its default of 8 checks ("too many memory
# checks needed"), leaving the loop scalar. Raising the limit makes it vectorise. Process-wide,
# it only raises a vectoriser limit. See docs/decisions/0003.
_llvm.set_option("", "-runtime-memory-check-threshold=256")
_llvm.set_option("", "-vectorize-memory-check-threshold=512")

#: the fast-math flags of the kernel's arithmetic (no "nnan"/"ninf": infinite limits are used)
FASTMATH = {"contract", "arcp", "reassoc", "afn"}

#: every file of the kernel package: what its compiled code (and code that inlines it) depends on
SOURCES: tuple[str, ...] = tuple(sorted(str(p) for p in Path(__file__).parent.glob("*.py")))

#: the package's compiled functions, registered by `njit` (guarded by `drop_stale_cache`)
DISPATCHERS: list = []

#: held by every call that enters a parallel loop (a kernel call of several chunks, the on-line
#: machine's): numba's workqueue threading layer, its fallback where neither OpenMP nor TBB is
#: installed, aborts when two threads enter one at once. Fits side by side
#: (`identification.threads`) make single-chunk calls, which run on their own thread and skip it.
PARALLEL_LOCK = threading.Lock()


def njit(*, inline: bool = True, fastmath: bool = True, parallel: bool = False, nogil: bool = False) -> Callable:
    """The kernel's numba decorator: cached, numpy's error model, FASTMATH; inlined into its
    caller (`inline`, numba IR level: the blocks and the RK4 step) or a function of its own (the
    loops LLVM vectorises, the chunk runner). `nogil`: the entry points Python calls release the
    GIL, so that independent fits on two threads run their kernel calls side by side. Registers
    the dispatcher in DISPATCHERS."""
    options: dict = {"cache": True, "error_model": "numpy"}
    if inline:
        options["inline"] = "always"
    if fastmath:
        options["fastmath"] = FASTMATH
    if parallel:
        options["parallel"] = True
    if nogil:
        options["nogil"] = True

    def wrap(fn: Callable) -> Callable:
        dispatcher = nb.njit(**options)(fn)
        DISPATCHERS.append(dispatcher)
        return dispatcher
    return wrap


def optimisation_note() -> str | None:
    """None when numba's code generator runs the "max" optimisation the kernel's RK4 loops need to
    be vectorised (bench_ctl sets NUMBA_OPT=max at import, see bench_ctl/__init__.py), else why
    not: numba was set up before bench_ctl was imported, or NUMBA_OPT was set otherwise."""
    try:
        from numba.core.registry import cpu_target
        codegen = cpu_target.target_context.codegen()
        ok = bool(getattr(codegen, "_loopvect", True)) and getattr(codegen, "_opt_level", 3) == 3
    except Exception:  # pragma: no cover - numba internals moved: do not guess
        return None
    if ok:
        return None
    return (f"numba runs without its 'max' optimisation (NUMBA_OPT={os.environ.get('NUMBA_OPT', '')!r}, or "
            "numba was set up before bench_ctl was imported): the kernel's RK4 loops stay scalar and the "
            "standard structures simulate ~2.5x slower")


def drop_stale_cache(dispatchers: tuple, sources: tuple[str, ...], name: str) -> bool:
    """Flush the disk cache of `dispatchers` when any file in `sources` (the code they inline
    from other files) changed since the cache was written.

    numba keys a function's disk cache on the stamp of its own file only, so after an edit of a
    file it inlines from, a function would keep running the old numerics from its cache. A hash
    of `sources` is kept beside the cache (`NAME.deps-sha256`); when it differs the cached code is
    flushed and recompiled. Returns True when it flushed."""
    caches = [c for c in (getattr(d, "_cache", None) for d in dispatchers) if c is not None]
    paths = {c.cache_path for c in caches if c.cache_path}
    if not paths:
        return False
    h = hashlib.sha256()
    for source in sources:
        h.update(Path(source).read_bytes())
    digest = h.hexdigest()
    stamp = Path(sorted(paths)[0]) / f"{name}.deps-sha256"
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
