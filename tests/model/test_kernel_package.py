"""The kernel package's own bookkeeping: the derived-column layout generated from one tuple, the
numba options in one decorator, and the stale-cache guard covering every file of the package
(numba keys a function's disk cache on its own file, while the loops inline sibling files)."""
from __future__ import annotations

import hashlib
import importlib
import pkgutil
import re
from pathlib import Path

import numba as nb
import numpy as np

import bench_ctl.model.kernel as K
from bench_ctl.model.kernel import jit, layout
from bench_ctl.model.params import KERNEL_PARAMS, RECORD_PARAMS

PACKAGE = Path(K.__file__).parent


def _modules():
    return [importlib.import_module(f"{K.__name__}.{m.name}") for m in pkgutil.iter_modules([str(PACKAGE)])]


def test_the_columns_follow_the_layout_tuple():
    """Every D_* constant is its entry's offset in COLUMNS; the entries tile 0..N_DERIVED-1."""
    at = 0
    for name, width, meaning in layout.COLUMNS:
        assert getattr(layout, f"D_{name}") == at, name
        assert meaning
        at += width
    assert at == layout.N_DERIVED == K.N_DERIVED
    assert sorted(n for n in vars(layout) if n.startswith("D_")) == sorted(f"D_{n}" for n, _, _ in layout.COLUMNS)
    assert layout.COLUMNS[[n for n, _, _ in layout.COLUMNS].index("EDGE0")][1] == len(RECORD_PARAMS)
    assert K.derive(np.zeros((1, len(KERNEL_PARAMS)))).shape == (1, layout.N_DERIVED)


def test_the_stale_cache_guard_hashes_every_file_of_the_package():
    """SOURCES lists every module file of the package (a new file cannot be left out), and the
    stamp the kernel's own guard wrote at import is the hash of exactly those files."""
    on_disk = sorted(str(p) for p in PACKAGE.glob("*.py"))
    assert list(K.SOURCES) == on_disk
    assert {Path(m.__file__).name for m in _modules()} | {"__init__.py"} == {Path(p).name for p in on_disk}
    digest = hashlib.sha256(b"".join(Path(p).read_bytes() for p in K.SOURCES)).hexdigest()
    caches = [d._cache for d in jit.DISPATCHERS if d._cache.cache_path]
    stamp = Path(sorted(c.cache_path for c in caches)[0]) / "kernel.deps-sha256"
    assert stamp.read_text(encoding="ascii").strip() == digest


def test_every_compiled_function_of_the_package_is_guarded():
    """Every numba function of the package goes through `jit.njit` (one set of options) and is
    therefore in the list the stale-cache guard flushes."""
    found = {id(v): f"{m.__name__}.{n}" for m in _modules() for n, v in vars(m).items()
             if isinstance(v, nb.core.registry.CPUDispatcher) and v.py_func.__module__ == m.__name__}
    assert found, "no compiled function found"
    missing = [name for key, name in found.items() if key not in {id(d) for d in jit.DISPATCHERS}]
    assert missing == []
    for d in jit.DISPATCHERS:
        assert d._cache.cache_path and d.targetoptions["error_model"] == "numpy"   # cached (not a NullCache)


def test_the_guard_flushes_the_kernel_when_a_sibling_file_changes(tmp_path):
    """What the guard does with the package's files: a copy of SOURCES, one file edited, flushes."""
    copies = []
    for p in K.SOURCES:
        q = tmp_path / Path(p).name
        q.write_bytes(Path(p).read_bytes())
        copies.append(str(q))

    class FakeCache:
        cache_path = str(tmp_path / "cache")
        flushes = 0

        def flush(self):
            FakeCache.flushes += 1

    class FakeDispatcher:
        _cache = FakeCache()

    assert K.drop_stale_cache((FakeDispatcher(),), tuple(copies), "kernel") is True
    assert K.drop_stale_cache((FakeDispatcher(),), tuple(copies), "kernel") is False
    blocks = tmp_path / "blocks.py"
    blocks.write_text(blocks.read_text() + "\n# an edit\n")
    assert K.drop_stale_cache((FakeDispatcher(),), tuple(copies), "kernel") is True
    assert FakeCache.flushes == 2


def test_what_the_model_modules_use_of_the_kernel_is_public():
    """The plant, the open loop and the rest of bench_ctl.model reach the kernel through `K.name`:
    every such name exists and is public (in `__all__`)."""
    used = set()
    for path in (PACKAGE.parent).glob("*.py"):
        used |= set(re.findall(r"\bK\.(\w+)", path.read_text(encoding="utf-8")))
    assert used, "no K.name found: the pattern no longer matches how bench_ctl.model imports the kernel"
    assert sorted(n for n in used if n not in K.__all__) == []
    assert all(hasattr(K, n) for n in K.__all__)


def test_the_parts_compiled_ahead_have_the_types_the_chunk_runner_calls_them_with():
    """`precompile` compiles the RK4 loops, the split step and the derivation ahead, from example
    arguments. After
    a run through every part (dead time and a fitted edge: split steps), numba's disk cache holds
    exactly that one signature of each part: the chunk runner asked for no other."""
    from bench_ctl.model.edges import EdgeSpec
    from bench_ctl.model.kernel import precompile
    from bench_ctl.model.params import COL
    from bench_ctl.model.simulate import param_matrix
    from bench_ctl.model.unit import reference_unit

    P = np.repeat(param_matrix(reference_unit().values()), 3, axis=0)
    P[1, COL["TD"]] = 0.0123
    u = np.r_[np.ones(50), np.full(50, 1.05)]
    edges = EdgeSpec(np.array([50]), np.array([0.05]), np.array([0.0493]), np.array([0]))
    K.run_kernel(P, u, 1e-3, 1.0, edges=edges)
    for name in precompile.PARTS:
        index = precompile.dispatcher(name)._cache._cache_file._load_index()  # numba's cache index (private)
        assert [key[0] for key in index] == [precompile.signature(name)], name
    assert precompile.compile_parts() == {}  # all in the cache: nothing compiled, no child started


def test_a_read_only_record_runs_on_the_same_compiled_code():
    """A capture's arrays are read-only, and numba types those apart from writable ones: the
    kernel copies them, so any mix of read-only series runs on the one chunk runner it compiled,
    with the same results."""
    from bench_ctl.model.kernel import chunk
    from bench_ctl.model.simulate import param_matrix
    from bench_ctl.model.unit import reference_unit

    P = np.repeat(param_matrix(reference_unit().values()), 40, axis=0)  # serial and parallel paths
    u = np.r_[np.ones(50), np.full(50, 1.05)]
    meas = np.linspace(1.0, 1.2, 100)
    first = K.run_kernel(P[:1], u, 1e-3, 1.0, efd_meas=meas, vt_meas=meas, w_vt=0.5)
    for frozen in ("u", "efd", "vt", "all"):
        uu, ee, vv = u.copy(), meas.copy(), meas.copy()
        for name, a in (("u", uu), ("efd", ee), ("vt", vv)):
            if frozen in (name, "all"):
                a.setflags(write=False)
        for rows in (P[:1], P):
            out = K.run_kernel(rows, uu, 1e-3, 1.0, efd_meas=ee, vt_meas=vv, w_vt=0.5)
            assert np.array_equal(out["efd"][0], first["efd"][0]) and out["obj"][0] == first["obj"][0]
    assert len(chunk.run_chunk.signatures) == 1 and len(chunk.run_chunks.signatures) == 1
