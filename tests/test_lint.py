"""`ruff check` over the tree with the project's configuration (`[tool.ruff]` in pyproject.toml):
pycodestyle, pyflakes, isort, bugbear, pyupgrade. ruff is in the `test` extra (CI installs it);
where it is not installed the test is skipped, saying so."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINTED = ("bench_ctl", "drivers", "simulators", "procedures", "tests", "benchmarks")


def ruff_binary() -> str | None:
    """The ruff of this environment: the `ruff` package's binary, else one on PATH."""
    try:
        from ruff.__main__ import find_ruff_bin
    except ImportError:
        return shutil.which("ruff")
    try:
        return os.fspath(find_ruff_bin())
    except FileNotFoundError:
        return shutil.which("ruff")


RUFF = ruff_binary()
needs_ruff = pytest.mark.skipif(RUFF is None, reason="ruff is not installed (pip install -e '.[test]' brings it)")


def ruff(*args: str, stdin: str | None = None) -> subprocess.CompletedProcess:
    assert RUFF is not None
    return subprocess.run([RUFF, "check", "--no-cache", "--output-format", "concise", *args], cwd=ROOT,
                          input=stdin, capture_output=True, text=True, timeout=120)


@needs_ruff
def test_the_tree_passes_ruff():
    out = ruff(*LINTED)
    assert out.returncode == 0, out.stdout + out.stderr


@needs_ruff
def test_ruff_runs_with_the_projects_rules():
    """The configuration is the one read (an unused import, an unsorted block and a mutable
    default are findings), in every folder of the package (nothing is excluded)."""
    text = "import sys\nimport os\n\n\ndef f(x=[]):\n    return x\n"
    out = ruff("--stdin-filename", "bench_ctl/probe.py", "-", stdin=text)
    assert out.returncode == 1
    for code in ("F401", "I001", "B006"):
        assert code in out.stdout, out.stdout
    assert ruff("--stdin-filename", "bench_ctl/model/kernel/probe.py", "-", stdin=text).returncode == 1
