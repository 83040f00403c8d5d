"""How the engine is compiled: the one numba decorator, the LLVM options, variants specialised by
compile-time constants, and cache files that can never hold stale code.

Every compiled function of bench_ctl goes through `njit`. numba compiles each one on its own and
LLVM inlines the small ones into their callers (`-inline-threshold` below): the loops over
candidates become one straight-line body LLVM vectorises, as numba's own IR inliner made them,
at a twentieth of the compile time (docs/decisions/0023).

A variant (the no-load machine with the reference blocks, a GENROU on the grid with a stabiliser,
...) is the engine's generic code with some module globals replaced by constants (`specialise`):
numba prunes the branches those constants rule out before typing them, so a variant compiles only
the blocks it runs, and each variant has cache files of its own.

numba keys a cache on the stamp of the function's own file, while the engine's functions inline
code of other files. Every compiled function's name (and so its cache file's) therefore carries a
digest of the code of every source file of the engine and the plants (`DIGEST`, comments and
docstrings left out): a change to any of them names new cache files, and `prune_stale` removes
the old ones.
"""
from __future__ import annotations

import ast
import hashlib
import logging
import os
import re
import sys
import threading
import types
from collections.abc import Callable, Mapping
from pathlib import Path

import llvmlite.binding as _llvm
import numba as nb
import numba.core.event

log = logging.getLogger(__name__)

#: numba's SSA pass recurses over the control-flow graph of the function it compiles; a runner with
#: its plumbing inlined is large enough that a cold compilation nested in a caller's type inference
#: passes Python's default limit of 1000 frames and fails with RecursionError. Python 3.11 calls
#: Python functions without C recursion, so a higher limit costs nothing until it is used.
RECURSION_LIMIT = 20000
if sys.getrecursionlimit() < RECURSION_LIMIT:
    sys.setrecursionlimit(RECURSION_LIMIT)

#: LLVM's options while a loop over candidates (`njit(vector=True)`) is compiled. The loop inlines
#: the blocks, functions of their own (a loop with a call in it stays scalar): the inline threshold
#: lets LLVM inline a whole right-hand side (measured: 10000 inlines the full structures' RK4 step,
#: 2000 does not). The loop reads ~40 rows of 2-D arrays; LLVM's vectoriser needs a runtime alias
#: check per pair and gives up past its default of 8 ("too many memory checks needed"): raised.
#: Everything else compiles with LLVM's defaults, which keep the runner's plumbing small and quick
#: to compile (docs/decisions/0023).
VECTOR_OPTIONS = {"inline-threshold": ("10000", "225"), "runtime-memory-check-threshold": ("256", "8"),
                  "vectorize-memory-check-threshold": ("512", "128")}

#: the fast-math flags of the engine's arithmetic (no "nnan"/"ninf": infinite limits are used)
FASTMATH = frozenset({"contract", "arcp", "reassoc", "afn"})

#: the files whose code compiled functions may inline: the engine's and the plants'
_ROOTS = (Path(__file__).resolve().parent, Path(__file__).resolve().parent.parent / "plants")
SOURCES: tuple[str, ...] = tuple(sorted(str(p) for root in _ROOTS for p in root.rglob("*.py")))


def _code(source: str) -> str:
    """The code of a source file without its comments and docstrings: what compiled code depends
    on (an edit of a comment or a docstring names no new cache files)."""
    tree = ast.parse(Path(source).read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(body, list) and body and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str)):
            body[0] = ast.Pass()
    return ast.dump(tree)


def _digest(sources: tuple[str, ...]) -> str:
    h = hashlib.sha256()
    for source in sources:
        h.update(Path(source).name.encode())
        h.update(_code(source).encode())
    return h.hexdigest()[:10]


#: part of every compiled function's cache name: a change to any source names new cache files
DIGEST = _digest(SOURCES)

#: every compiled function of the process, by its cache name (the registry `prune_stale` reads)
DISPATCHERS: dict[str, object] = {}

#: the Python functions whose compilation runs with VECTOR_OPTIONS (and their variants')
VECTOR_LOOPS: set = set()
#: the LLVM optimisation level of everything else
PLUMBING_OPT = 2


class _VectorScope(nb.core.event.Listener):
    """Sets VECTOR_OPTIONS and numba's "max" optimisation (an extra O3 round with the loop
    vectoriser before the full one: what vectorises the RK4 loops, bench_ctl/__init__.py) while a
    loop over candidates compiles; LLVM's defaults and numba's plain O3 without the vectorisers
    otherwise: the runner's plumbing, about half of a variant's code, then compiles in about half
    the time (docs/decisions/0023). numba compiles a callee inside its caller's compilation: a
    stack, under numba's compiler lock; LLVM and numba read the settings when they build the pass
    pipelines of a library's final module."""

    def __init__(self) -> None:
        self.stack: list[bool] = []
        from numba.core import config
        self.config = config
        self.vectorise = (config.LOOP_VECTORIZE, config.SLP_VECTORIZE)
        self.opt = config.OPT
        self.max = getattr(config.OPT, "is_opt_max", False)
        self.apply(False)

    def apply(self, vector: bool) -> None:
        for name, (on, off) in VECTOR_OPTIONS.items():
            _llvm.set_option("", f"-{name}={on if vector else off}")
        try:
            from numba.core.registry import cpu_target
            codegen = cpu_target.target_context.codegen()
        except Exception:  # pragma: no cover - numba internals moved: keep its own settings
            return
        if not self.max:   # the user chose numba's level: keep it
            return
        codegen._opt_level, codegen._loopvect = (3, True) if vector else (0, False)
        self.config.LOOP_VECTORIZE, self.config.SLP_VECTORIZE = self.vectorise if vector else (0, 0)
        self.config.OPT = self.opt if vector else type(self.opt)(PLUMBING_OPT)

    def on_start(self, event) -> None:
        fn = getattr(event.data["dispatcher"].py_func, "__wrapped__", None)
        self.stack.append(fn in VECTOR_LOOPS)
        self.apply(self.stack[-1])

    def on_end(self, event) -> None:
        self.stack.pop()
        self.apply(bool(self.stack) and self.stack[-1])


_SCOPE = _VectorScope()
nb.core.event.register("numba:compile", _SCOPE)

#: held by every call that enters a parallel loop: numba's workqueue threading layer, its
#: fallback where neither OpenMP nor TBB is installed, aborts when two threads enter one at once.
#: Fits side by side (`identification.threads`) make single-chunk calls, which skip it.
PARALLEL_LOCK = threading.Lock()


def _options(fastmath: bool, parallel: bool, nogil: bool, inline: bool = False) -> dict:
    options: dict = {"cache": True, "error_model": "numpy"}
    if inline:
        options["inline"] = "always"
    if fastmath:
        options["fastmath"] = set(FASTMATH)
    if parallel:
        options["parallel"] = True
    if nogil:
        options["nogil"] = True
    return options


def _compiled(fn: Callable, suffix: str, constants: Mapping[str, object], options: dict):
    """numba's dispatcher of a copy of `fn` named `fn__SUFFIX_DIGEST`, its module globals overlaid
    with `constants` (compile-time constants to numba, as every global it reads)."""
    glob = fn.__globals__
    if constants:
        glob = dict(glob)
        glob.update(constants)
    copy = types.FunctionType(fn.__code__, glob, fn.__name__, fn.__defaults__, fn.__closure__)
    copy.__qualname__ = f"{fn.__qualname__}__{suffix + '_' if suffix else ''}{DIGEST}"
    copy.__module__ = fn.__module__
    copy.__doc__ = fn.__doc__
    copy.__wrapped__ = fn
    dispatcher = nb.njit(**options)(copy)
    DISPATCHERS[f"{fn.__module__}.{copy.__qualname__}"] = dispatcher
    return dispatcher


def njit(fn: Callable | None = None, *, fastmath: bool = True, parallel: bool = False, nogil: bool = False,
         inline: bool = False, vector: bool = False):
    """The engine's numba decorator: cached, numpy's error model, FASTMATH. A block is a function of
    its own that LLVM inlines into its callers; `inline`: a piece of a loop's plumbing numba
    inlines into its caller instead (numba compiles a function into a library of its own, and
    every caller's library optimises and generates again the code of everything it calls: a
    caller's plumbing inlined keeps the heavy steps in fewer libraries). `nogil`: an entry point
    Python calls releases the GIL (chunks and fits side by side on threads). `vector`: a loop
    over candidates LLVM must vectorise (compiled with VECTOR_OPTIONS). The function keeps its
    Python self as `py_func` (`specialise` copies it)."""
    def wrap(f: Callable):
        if vector:
            VECTOR_LOOPS.add(f)
        return _compiled(f, "", {}, _options(fastmath, parallel, nogil, inline))
    return wrap(fn) if fn is not None else wrap


def specialise(dispatcher, variant: str, constants: Mapping[str, object]):
    """The compiled function `dispatcher` (made by `njit`) with the module globals in `constants`
    replaced: a variant of it, compiled (and cached) on its own. `variant` names it (a word of
    letters, digits and underscores)."""
    if not re.fullmatch(r"\w+", variant):
        raise ValueError(f"variant name {variant!r}: letters, digits and _ only")
    fn = dispatcher.py_func.__wrapped__
    # (numba keeps `cache` apart from the target options a dispatcher holds)
    options = {**{k: v for k, v in dispatcher.targetoptions.items() if k != "nopython"}, "cache": True}
    return _compiled(fn, variant, constants, options)


def prune_stale() -> int:
    """Remove the cache files of the engine's functions compiled from other sources than these
    (another DIGEST) from the cache folders this process uses; returns how many. Run when
    something was compiled: stale files are never loaded (their names differ), only kept."""
    folders = set()
    for dispatcher in list(DISPATCHERS.values()):
        cache = getattr(dispatcher, "_cache", None)
        path = getattr(cache, "_cache_path", None)
        if path:
            folders.add(path)
    stale = re.compile(r"__(?:\w+_)?([0-9a-f]{10})-\d+\.py\d+\.(?:nbi|nbc)$")
    removed = 0
    for folder in folders:
        try:
            names = os.listdir(folder)
        except OSError:
            continue
        for name in names:
            m = stale.search(name)
            if m and m.group(1) != DIGEST:
                try:
                    os.remove(os.path.join(folder, name))
                    removed += 1
                except OSError as exc:  # another process removed it, or a read-only cache
                    log.debug("cannot remove %s: %s", name, exc)
    return removed


def optimisation_note() -> str | None:
    """None when numba's code generator runs the "max" optimisation the engine's RK4 loops need to
    be vectorised (bench_ctl sets NUMBA_OPT=max at import, see bench_ctl/__init__.py), else why
    not: numba was set up before bench_ctl was imported, or NUMBA_OPT was set otherwise."""
    if _SCOPE.max:
        return None
    return (f"numba runs without its 'max' optimisation (NUMBA_OPT={os.environ.get('NUMBA_OPT', '')!r}, or "
            "numba was set up before bench_ctl was imported): the engine's RK4 loops stay scalar and the "
            "standard structures simulate ~2.5x slower")
