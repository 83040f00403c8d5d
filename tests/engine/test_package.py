"""The engine package's own bookkeeping: the derived-column layout generated from the plug-ins'
tuples, every compiled function through one decorator with cache names that carry the sources'
digest (a source edited names new cache files, the old ones are removed), the variants bound from
the plug-ins, the loops still vectorised, and a read-only record on the same compiled code."""
from __future__ import annotations

import importlib
import pkgutil
import re
import shutil
import subprocess
from pathlib import Path

import numba as nb
import numpy as np
import pytest

import bench_ctl
from bench_ctl import engine
from bench_ctl.engine import exciter, jit, layout, variants
from bench_ctl.engine.machines import grid, noload
from bench_ctl.engine.simulate import param_matrix
from bench_ctl.engine.stabilisers import ieeest, none
from bench_ctl.model.params import KERNEL_PARAMS, RECORD_PARAMS
from bench_ctl.units.unit import reference_unit

ROOT = Path(bench_ctl.__file__).parent


def test_the_columns_follow_the_plugins_tuples():
    """Every D_* constant is its entry's offset in COLUMNS (the exciter's, the machine's, the
    stabiliser's); the entries tile 0..N_DERIVED-1; P_* are the parameter matrix's columns."""
    at = 0
    for name, width, meaning in layout.COLUMNS:
        assert getattr(layout, f"D_{name}") == at, name
        assert meaning
        at += width
    assert at == layout.N_DERIVED
    assert layout.COLUMNS == layout.EXCITER + layout.GRID + layout.STABILISER
    assert sorted(n for n in vars(layout) if n.startswith("D_")) == sorted(f"D_{n}" for n, _, _ in layout.COLUMNS)
    assert layout.COLUMNS[[n for n, _, _ in layout.COLUMNS].index("EDGE0")][1] == len(RECORD_PARAMS)
    assert [getattr(layout, f"P_{n}") for n in KERNEL_PARAMS] == list(range(len(KERNEL_PARAMS)))
    assert engine.derive(np.zeros((1, len(KERNEL_PARAMS)))).shape == (1, layout.N_DERIVED)


def test_every_compiled_function_goes_through_the_one_decorator():
    """No numba decorator in the tree but `jit.njit` (one set of options, one cache name scheme),
    and every compiled function of the engine and the plants is registered, cached, with numpy's
    error model and a name carrying the sources' digest."""
    raw = [f"{p.relative_to(ROOT.parent)}:{i + 1}" for p in ROOT.rglob("*.py") if p.name != "jit.py"
           for i, line in enumerate(p.read_text(encoding="utf-8").splitlines())
           if re.search(r"\b(nb|numba)\.(njit|jit|vectorize|guvectorize|cfunc)\b", line)]
    assert raw == []
    found = {}
    for info in pkgutil.walk_packages([str(ROOT)], prefix="bench_ctl."):
        if info.name.startswith(("bench_ctl.engine", "bench_ctl.plants")):
            m = importlib.import_module(info.name)
            found.update({f"{info.name}.{k}": v for k, v in vars(m).items()
                          if isinstance(v, nb.core.registry.CPUDispatcher) and v.py_func.__module__ == info.name})
    assert len(found) > 50
    registered = {id(d) for d in jit.DISPATCHERS.values()}
    assert [n for n, d in found.items() if id(d) not in registered] == []
    for d in found.values():
        assert d._cache.cache_path and d.targetoptions["error_model"] == "numpy"
        assert re.search(rf"__(\w+_)?{jit.DIGEST}$", d.py_func.__qualname__), d.py_func.__qualname__


def test_the_digest_covers_every_source_and_moves_with_any_edit(tmp_path):
    """DIGEST hashes the code of every file of the engine and the plants (a new file cannot be left
    out); an edit of any one's code, even a plug-in's, gives another digest, so the cache files
    compiled before are never loaded; a comment or a docstring does not."""
    on_disk = sorted(str(p) for r in ("engine", "plants") for p in (ROOT / r).rglob("*.py"))
    assert list(jit.SOURCES) == on_disk
    copies = []
    for p in jit.SOURCES:
        q = tmp_path / Path(p).relative_to(ROOT)
        q.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(p, q)
        copies.append(str(q))
    assert jit._digest(tuple(copies)) == jit.DIGEST
    plugin = tmp_path / "engine" / "machines" / "noload.py"
    text = plugin.read_text()
    plugin.write_text(text.replace('"""', '"""A docstring edited: ', 1) + "\n# a comment\n")
    assert jit._digest(tuple(copies)) == jit.DIGEST      # the code is the same: the cache holds
    plugin.write_text(text.replace("N_STATES = 2", "N_STATES = 3"))
    assert jit._digest(tuple(copies)) != jit.DIGEST


def test_stale_cache_files_are_removed_and_current_ones_kept(tmp_path, monkeypatch):
    """`prune_stale` removes the cache files of another digest from the folders the engine's
    functions cache into, and keeps this digest's and any other file."""
    stale, current, other = (tmp_path / f"step.rk4__noload_ref_none_{'0' * 10}-77.py311.nbi",
                             tmp_path / f"step.rk4__noload_ref_none_{jit.DIGEST}-77.py311.nbi",
                             tmp_path / "unrelated-12.py311.nbi")
    for f in (stale, current, other):
        f.write_text("x")

    class Cache:
        _cache_path = str(tmp_path)

    class Dispatcher:
        _cache = Cache()

    monkeypatch.setattr(jit, "DISPATCHERS", {"d": Dispatcher()})
    assert jit.prune_stale() == 1
    assert not stale.exists() and current.exists() and other.exists()


def test_a_variant_binds_its_plugins_into_the_seam():
    """A variant's copies of the generic step and runner read its plug-ins: the machine, the
    exciter's class of blocks and the stabiliser; every copy calls the variant's copies of the
    others, never the generic ones."""
    v = variants.variant(variants.Key("grid", layout.X_REF, "ieeest"))
    g = v.functions["step_all"].py_func.__globals__
    assert g["gen_algebra"] is grid.algebra and g["pss_rhs"] is ieeest.rhs and g["exc_rhs"] is exciter.ref_rhs
    assert g["ST4"] == exciter.ST4_NONE and g["SPAN"] is False
    for name, copy in v.functions.items():
        for callee, target in copy.py_func.__globals__.items():
            if callee in v.functions:
                assert target is v.functions[callee], (name, callee)
    w = variants.variant(variants.Key("noload", layout.X_ST4_ONLY))
    g = w.functions["advance"].py_func.__globals__
    assert g["gen_rhs"] is noload.rhs and g["pss_load"] is none.load and g["exc_rhs"] is exciter.full_rhs
    assert g["ST4"] == exciter.ST4_ALL
    assert {"new_work", "advance", "step_all", "substep", "rk4"} <= set(v.functions)


def test_a_read_only_record_runs_on_the_same_compiled_code():
    """A capture's arrays are read-only, and numba types those apart from writable ones: the
    engine copies them, so any mix of read-only series runs on the code it compiled, with the
    same results."""
    P = np.repeat(param_matrix(reference_unit().values()), 40, axis=0)  # one chunk and several
    u = np.r_[np.ones(50), np.full(50, 1.05)]
    meas = np.linspace(1.0, 1.2, 100)
    kw = dict(weights={"vt": 0.5})
    first = engine.run(P[:1], u, 1e-3, 1.0, measured={"efd": meas, "vt": meas}, **kw)
    v = variants.variant(variants.Key("noload", layout.X_REF))
    for frozen in ("u", "efd", "vt", "all"):
        uu, ee, vv = u.copy(), meas.copy(), meas.copy()
        for name, a in (("u", uu), ("efd", ee), ("vt", vv)):
            if frozen in (name, "all"):
                a.setflags(write=False)
        for rows in (P[:1], P):
            out = engine.run(rows, uu, 1e-3, 1.0, measured={"efd": ee, "vt": vv}, **kw)
            assert np.array_equal(out["efd"][0], first["efd"][0]) and out["obj"][0] == first["obj"][0]
    assert {n: len(v.functions[n].signatures) for n in ("new_work", "advance")} == {"new_work": 1, "advance": 1}


def _object_code(dispatcher) -> bytes:
    """The machine code numba made for the dispatcher's one overload: kept by the library when
    compiled in this process; when loaded from the on-disk cache the JIT consumes it, so it is read
    back from the cache's data file (numba's own index key and payload layout)."""
    (cres,) = dispatcher.overloads.values()
    try:
        return cres.library._get_compiled_object()
    except RuntimeError:
        cache = dispatcher._cache
        key = cache._index_key(tuple(cres.signature.args), dispatcher.targetctx.codegen())
        libdata = cache._cache_file.load(key)[0]     # (name, "object", (object code, bitcode))
        return libdata[2][0]


@pytest.mark.skipif(shutil.which("objdump") is None, reason="no objdump")
@pytest.mark.parametrize("key", [variants.Key("noload", layout.X_REF), variants.Key("noload", layout.X_FULL),
                                 variants.Key("grid", layout.X_FULL, "ieeest"),
                                 variants.Key("grid", layout.X_FULL, "pss2")], ids=lambda k: k.name)
def test_the_rk4_loops_are_vectorised(key, tmp_path):
    """The loop over candidates (`step.step_all`) runs in packed vector instructions (registers
    holding several doubles): a change that leaves it scalar (a call in the loop, a branch, an
    alias LLVM cannot rule out) runs several times slower and fails here."""
    from bench_ctl.engine import warm
    from bench_ctl.engine.warm import compile_key

    compile_key(key)
    v = variants.variant(key)
    w = v.call("new_work", *warm.run_arguments(key)[:1], 0, 1, 1, 1, 0, np.zeros((2, 1)))
    v.call("step_all", w.D, w.S, w.R, w.U, w.M, 0, 1e-3, 1, np.zeros((2, 1)))   # (loaded from the cache)
    obj = tmp_path / "step_all.o"
    obj.write_bytes(_object_code(v.functions["step_all"]))
    asm = subprocess.run(["objdump", "-d", "--no-show-raw-insn", str(obj)], capture_output=True, text=True,
                         check=True).stdout
    packed = re.findall(r"\bv?(?:mul|add|sub|div|fmadd\w*|fmsub\w*|fnmadd\w*)pd\s+.*%[xyz]mm", asm)
    assert len(packed) > 100, f"{key.name}: {len(packed)} packed double operations"
