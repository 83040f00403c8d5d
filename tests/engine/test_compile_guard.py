"""The compile guard (tests/compile_guard.py) and the list of variants CI compiles ahead
(tests/engine_variants.txt): the list names variants the warm-up knows, a cache file's name gives
its variant, and the guard fails a session exactly when a test compiled a variant the list leaves
out, or compiled anything after the warm-up."""
from __future__ import annotations

import os

import pytest

from bench_ctl.commands.warm_up import read_variants
from bench_ctl.engine import jit
from bench_ctl.engine.warm import ALL
from compile_guard import INDEX, LIST, Guard, listed

D = jit.DIGEST


def test_the_list_names_variants_the_warm_up_compiles(tmp_path):
    assert {k.name for k in read_variants(LIST)} == listed() and listed() <= {k.name for k in ALL}
    bad = tmp_path / "v.txt"
    bad.write_text("noload_ref_none  # a comment\ngrid_full_pss3\n")
    with pytest.raises(ValueError, match="unknown engine variant 'grid_full_pss3'"):
        read_variants(bad)


@pytest.mark.parametrize("name, function, variant", [
    (f"runner.advance__grid_full_pss2_{D}-401.py311.nbi", "advance", "grid_full_pss2"),
    (f"realtime.rt_loop__noload_ref_none_{D}-76.py311.nbi", "rt_loop", "noload_ref_none"),
    (f"span._rk4__{D}-20.py311.nbi", "_rk4", None),
    (f"span.span__limited_{D}-120.py311.nbi", "span", "limited")])
def test_a_cache_index_names_its_function_and_variant(name, function, variant):
    m = INDEX.match(name)
    assert (m["function"], m["variant"], m["digest"]) == (function, variant, D)
    assert INDEX.match(name.replace(".nbi", ".1.nbc")) is None


def _guard(folder, cached: set[str]) -> Guard:
    for name in cached:
        (folder / f"runner.advance__{name}_{D}-401.py311.nbi").write_text("")
    return Guard([folder], {p: p.stat().st_mtime_ns for p in folder.iterdir()}, D,
                 expected={"noload_ref_none", "grid_full_pss2"})


def _compile(folder, variant: str, line: int = 163) -> None:
    path = folder / f"runner.new_work__{variant}_{D}-{line}.py311.nbi"
    path.write_text("")
    os.utime(path, ns=(0, 10**18))


@pytest.mark.parametrize("cached, compiled, fails", [
    ({"noload_ref_none", "grid_full_pss2"}, None, None),                 # nothing compiled
    ({"noload_ref_none", "grid_full_pss2"}, "noload_ref_none", True),     # after the warm-up: anything
    ({"noload_ref_none"}, "grid_full_pss2", False),                       # a cold cache, a listed variant
    ({"noload_ref_none"}, "grid_st4_none", True),                         # a variant the list leaves out
    ({"noload_ref_none", "grid_full_pss2", "grid_st4_none"}, "grid_st4_none", True)])
def test_the_guard_fails_a_variant_left_out_and_any_compilation_after_the_warm_up(tmp_path, cached, compiled,
                                                                                  fails):
    guard = _guard(tmp_path, cached)
    guard.runs.append(("tests/x.py::test_y", 10**9 - 1.0, 10**9 + 1.0))
    if compiled:
        _compile(tmp_path, compiled)
    failed, lines = guard.finish()
    if compiled is None:
        assert (failed, lines) == (False, [])
        return
    assert failed is fails, lines
    assert f"  {compiled}: runner.new_work" in lines and "    compiled by tests/x.py::test_y" in lines
    assert any("not in engine_variants.txt" in line for line in lines) is (compiled == "grid_st4_none")
