"""A first run gives the answer of every later run: a variant compiled on first use is compiled in
a child process and run as loaded from numba's disk cache (bench_ctl/engine/variants.py). Before,
the process that compiled a variant ran code that rounded apart from the cached code (a batch of
on-line candidates, ~1e-13 pu in efd), and a fit on a real record then went elsewhere on a fresh
machine than on every run after it.

Slow tier: a variant is compiled with an empty cache (about 40 s)."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow

#: a batch of on-line ESST5B candidates (the vectorised path) and their digest
SCRIPT = """
import hashlib, logging, numpy as np
logging.basicConfig(level=logging.WARNING)
from bench_ctl import engine
from bench_ctl.engine.machines.grid import TYPICAL_MACHINE, machine_matrix
from bench_ctl.engine.simulate import param_matrix, pulse_usetp
from bench_ctl.units.overrides import with_model
from bench_ctl.units.unit import reference_unit
base = {**with_model(reference_unit(), "ESST5B").values(), "Vt0": 1.0}
names = ["KAVR", "TE", "TA1", "TA2", "TA3", "TA4"]
rng = np.random.default_rng(0)
X = np.array([[base[k] * rng.uniform(0.5, 2.0) for k in names] for _ in range(32)])
t, u = pulse_usetp(rate=200.0, duration=20.0)
out = engine.run(param_matrix(base, names, X), u, 1 / 200, 1.0,
                 machine=np.repeat(machine_matrix(dict(TYPICAL_MACHINE)), 32, axis=0))
print("digest", hashlib.sha256(out["efd"].tobytes()).hexdigest(), int((out["fail_step"] >= 0).sum()))
"""


def _run(cache: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "NUMBA_CACHE_DIR": cache}
    return subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, check=True)


def test_the_run_that_compiles_a_variant_gives_what_a_cached_run_gives(tmp_path):
    first = _run(str(tmp_path / "cache"))    # compiles the on-line standard-structure variant
    again = _run(str(tmp_path / "cache"))    # loads it
    assert "compiled in this process" not in first.stderr, first.stderr
    assert any(tmp_path.joinpath("cache").rglob("*.nbc"))
    digest = [line for line in first.stdout.splitlines() if line.startswith("digest")]
    assert digest and digest == [line for line in again.stdout.splitlines() if line.startswith("digest")]
