"""The engine's variants: one machine, one class of the excitation system's blocks and one
stabiliser, bound into the seam's slots of the generic step and runner (`step`, `substep`,
`runner`), each compiled on first use into numba's disk cache (docs/decisions/0023).

A variant's functions are copies of the generic ones whose slot globals (ST4, SPAN, ROWS, exc_*,
gen_*, pss_*) name its plug-ins; numba prunes what those constants rule out before typing, so a variant
compiles its own blocks only. A command compiles the variants its records need, and says so while
it does (`compiling`): a fresh machine pays that once.

A variant is compiled in a child process that writes the disk cache, and every process runs it as
loaded from there: the code numba runs in the process that compiled it rounds apart from the same
code loaded from the cache (a batch of candidates on line, ~1e-13 pu in efd; on one real record that
moved an identification from 9.9x to 10.3x the disturbance), so a first run gave another answer
than every later one, and a Dask worker that compiled a variant another answer than the workers
that loaded it (docs/decisions/0023).
"""
from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from types import FunctionType

import numba as nb
import numpy as np
from numba.core.registry import CPUDispatcher

from bench_ctl.compile_notice import compiling
from bench_ctl.model.params import KERNEL_PARAMS, REFERENCE_VALUES, neutral_values

from . import exciter, runner, step, substep
from .derived import derive
from .exciter import ST4_ALL, ST4_NONE, ST4_SOME
from .jit import prune_stale, specialise
from .layout import N_SCORED, X_FULL, X_REF, X_ST4, X_ST4_ONLY
from .machines import grid, noload, recorded
from .runner import N_KEEP, Drive, Edges, Out, Switches
from .stabilisers import ieeest, none, pss2

log = logging.getLogger(__name__)

MACHINES = {"noload": noload, "grid": grid, "recorded": recorded}
STABILISERS = {"none": none, "ieeest": ieeest, "pss2": pss2}
EXCITERS = {X_REF: "ref", X_FULL: "full", X_ST4: "st4", X_ST4_ONLY: "st4only"}
#: in words, for what a command says while it compiles
_WORDS = {"noload": "no-load", "grid": "on-line", "recorded": "open-loop",
          "ref": "reference blocks", "full": "standard-structure blocks", "st4": "standard-structure blocks with "
          "ESST4B's stage", "st4only": "ESST4B", "none": "", "ieeest": "with an IEEEST stabiliser",
          "pss2": "with a PSS2A/PSS2B stabiliser"}
#: seconds a variant's first compilation took on a 2-core machine of this project's CI (measured:
#: docs/benchmarks.md, "The engine"), what a command says before it waits
ESTIMATE_S = {"ref": 30.0, "full": 30.0, "st4": 35.0, "st4only": 30.0}

_SLOT = ("ST4", "SPAN", "ROWS")
_SLOT_PREFIX = ("exc_", "gen_", "pss_")


@dataclass(frozen=True)
class Key:
    """A variant: the machine, the excitation system's class (`layout.X_*`), the stabiliser."""
    machine: str
    exciter: int
    stabiliser: str = "none"

    @property
    def name(self) -> str:
        return f"{self.machine}_{EXCITERS[self.exciter]}_{self.stabiliser}"

    def words(self) -> str:
        parts = [_WORDS[self.machine], "engine,", _WORDS[EXCITERS[self.exciter]], _WORDS[self.stabiliser]]
        return " ".join(p for p in parts if p)


def _bindings(key: Key) -> dict[str, object]:
    """The slot globals of variant `key`."""
    machine = MACHINES[key.machine]
    pss = STABILISERS[key.stabiliser]
    ref = key.exciter == X_REF
    st4 = {X_REF: ST4_NONE, X_FULL: ST4_NONE, X_ST4: ST4_SOME, X_ST4_ONLY: ST4_ALL}[key.exciter]
    out: dict[str, object] = {"ST4": st4, "SPAN": key.machine == "noload" and ref and key.stabiliser == "none",
                              # the state rows in use: the exciter's six, the machine's, the stabiliser's
                              # (after the largest machine's seven)
                              "ROWS": max(6 + machine.N_STATES, pss.FIRST + pss.N_STATES if pss.N_STATES else 0)}
    for slot in ("load", "store", "axpy", "combine", "rhs", "limit", "output", "clamp", "slope", "vr", "park"):
        out[f"exc_{slot}"] = getattr(exciter, f"{'ref' if ref else 'full'}_{slot}")
    for slot in ("load", "store", "axpy", "combine", "algebra", "alg_load", "alg_store", "signals", "speed", "power",
                 "rhs", "end", "park", "valid", "flux"):
        out[f"gen_{slot}"] = getattr(machine, slot)
    for slot in ("load", "store", "axpy", "combine", "rhs", "output", "park"):
        out[f"pss_{slot}"] = getattr(pss, slot)
    return out


def _generic() -> list[tuple[str, CPUDispatcher]]:
    """The generic functions a variant copies: those of `step`, `substep` and `runner` that read a
    slot, directly or through another such function (found from their code's names)."""
    fns = [(name, obj) for mod in (step, substep, runner) for name, obj in vars(mod).items()
           if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == mod.__name__]
    code = {name: set(_names(obj.py_func.__wrapped__)) for name, obj in fns}
    slotted = {name for name, names in code.items()
               if any(n in _SLOT or n.startswith(_SLOT_PREFIX) for n in names)}
    grew = True
    while grew:
        grew = False
        for name, names in code.items():
            if name not in slotted and names & slotted:
                slotted.add(name)
                grew = True
    return [(name, obj) for name, obj in fns if name in slotted]


def _names(fn: FunctionType) -> Iterator[str]:
    """The global names `fn`'s code reads (nested code objects included)."""
    stack = [fn.__code__]
    while stack:
        code = stack.pop()
        yield from code.co_names
        stack.extend(c for c in code.co_consts if hasattr(c, "co_names"))


class Variant:
    """The compiled functions of one variant (`Key`), by the generic function's name; `call` runs
    one (`new_work`, `advance`: a chunk's start and its samples)."""

    def __init__(self, key: Key) -> None:
        self.key = key
        constants = _bindings(key)
        copies = {name: specialise(dispatcher, key.name, constants) for name, dispatcher in _generic()}
        for copy in copies.values():   # each copy calls the variant's copies of the others
            copy.py_func.__globals__.update(copies)
        self.functions = copies
        self._ready: set[str] = set()
        self._whole = False   # compile_key called: every function compiled for a run's types

    def call(self, name: str, *args):
        """Function `name` of the variant called with `args`, compiled first (and said) when numba's
        disk cache does not hold it for these argument types; `new_work`, a run's first call,
        compiles the variant's run with it (`compile_key`: a run's argument types), so that a
        first run says one notice for the variant, not one per function."""
        dispatcher = self.functions[name]
        if name not in self._ready:
            sig = tuple(nb.typeof(a) for a in args)
            if sig not in dispatcher.overloads and not cached(dispatcher, sig):
                with compiling(self.key.words(), ESTIMATE_S[EXCITERS[self.key.exciter]]):
                    if not self._from_child(dispatcher, sig):
                        dispatcher.compile(sig)
                        if name == "new_work" and not self._whole:   # a run's first step: the rest
                            self._whole = True                       # under the same notice, one line
                            compile_key(self.key)
                prune_stale()
            self._ready.add(name)
        return dispatcher(*args)

    def _from_child(self, dispatcher: CPUDispatcher, sig: tuple) -> bool:
        """Whether a child process compiled the variant into the cache and `sig` loads from there
        (module docstring); False in such a child, and (warned) when the cache cannot be written or
        the child failed: the caller compiles it here."""
        if _COMPILING_CHILD or self.key in _CHILD_FAILED:   # (said when it failed)
            return False
        if writable(dispatcher) and compile_in_child(self.key) is not None and cached(dispatcher, sig):
            return True
        log.warning("the %s is compiled in this process: its results may differ in the last digits from a "
                    "run that loads it from numba's cache", self.key.words())
        return False


def cached(dispatcher: CPUDispatcher, sig: tuple) -> bool:
    """Whether numba's disk cache holds `dispatcher` for `sig` on this machine (loads it)."""
    cache = getattr(dispatcher, "_cache", None)  # numba's per-function disk cache (no public API)
    try:
        return cache is not None and cache.load_overload(sig, dispatcher.targetctx) is not None
    except Exception:  # pragma: no cover - an unreadable cache entry: compile it afresh
        return False


def writable(dispatcher: CPUDispatcher) -> bool:
    """Whether numba's disk cache of `dispatcher` can be written (a child's compilation kept)."""
    path = getattr(getattr(dispatcher, "_cache", None), "_cache_path", None)  # no public API
    while path and not os.path.isdir(path):   # numba makes the folder when it first writes
        parent = os.path.dirname(path)
        path = parent if parent != path else None
    return bool(path) and os.access(path, os.W_OK)


#: this process is a child of `compile_in_child`: it compiles what it is asked here
_COMPILING_CHILD = False
#: the variants a child failed to compile in this process: compiled here, not asked of a child again
_CHILD_FAILED: set[Key] = set()
#: what a child process runs to compile variants (not `-m`: the package imports this module first)
CHILD = "import sys; from bench_ctl.engine.variants import child_main; child_main(sys.argv[1:])"


def compile_in_child(key: Key) -> float | None:
    """Compile variant `key` in a child process that writes numba's disk cache; the seconds it
    took, None when the child failed (logged)."""
    spec = f"{key.machine}:{key.exciter}:{key.stabiliser}"
    done = subprocess.run([sys.executable, "-c", CHILD, spec], capture_output=True, text=True)
    if done.returncode != 0:
        log.warning("compiling the %s in a child process failed (exit %s): %s", key.words(), done.returncode,
                    done.stderr.strip()[-2000:])
        _CHILD_FAILED.add(key)
        return None
    return float(json.loads(done.stdout.strip().splitlines()[-1])[spec])


def child_main(specs: list[str]) -> None:
    """A child process of `compile_in_child`: compile the variants MACHINE:EXCITER:STABILISER in
    this process (the disk cache keeps them), print the seconds of each as JSON."""
    global _COMPILING_CHILD
    _COMPILING_CHILD = True
    seconds = {}
    for spec in specs:
        machine, exciter, stabiliser = spec.split(":")
        seconds[spec] = compile_key(Key(machine, int(exciter), stabiliser))
    print(json.dumps(seconds))


_VARIANTS: dict[Key, Variant] = {}


def variant(key: Key) -> Variant:
    """The variant `key` (its functions made on first use; compiled when first called)."""
    v = _VARIANTS.get(key)
    if v is None:
        v = _VARIANTS[key] = Variant(key)
    return v


def run_arguments(key: Key):
    """Arguments of the types a run passes `new_work` and `advance` (a 4-sample record)."""
    values = {**{n: 0.0 for n in KERNEL_PARAMS}, **neutral_values(), **REFERENCE_VALUES}
    P = np.array([[values[n] for n in KERNEL_PARAMS]])
    D = grid.derive_grid(P, grid.machine_matrix(grid.TYPICAL_MACHINE)) if key.machine == "grid" else derive(P)
    T = 4
    ext = np.ones((2, T)) if key.machine == "recorded" else np.zeros((2, 1))
    drive = Drive(np.array([1.0, 1.0, 1.05, 1.05]), 1.0, 1e-3, np.zeros((N_SCORED, T)), np.ones(N_SCORED), ext)
    edges = Edges(np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0, np.int64), np.zeros(T, np.uint8))
    out = Out(np.zeros((2, 1, T)), np.full(N_KEEP, -1, np.int64), np.zeros((N_SCORED, 1)), np.zeros((N_SCORED, 1)),
              np.full(1, -1, np.int64))
    return np.ascontiguousarray(D.T), drive, edges, out, Switches(False, False, False, False, True, 1, 1)


def compile_key(key: Key) -> float:
    """Compile (or load) variant `key` in this process; seconds."""
    t0 = time.perf_counter()
    Dt, drive, edges, out, sw = run_arguments(key)
    v = variant(key)
    w = v.call("new_work", Dt, 0, 1, 1, 1, 0, drive.ext)
    v.call("advance", w, drive, edges, out, 0, 4, 3, sw)
    return time.perf_counter() - t0
