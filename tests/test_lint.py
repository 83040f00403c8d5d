"""`ruff check` over the tree with the project's configuration (`[tool.ruff]` in pyproject.toml):
pycodestyle, pyflakes, isort, bugbear, pyupgrade. ruff is in the `test` extra (CI installs it);
where it is not installed the test is skipped, saying so."""
from __future__ import annotations

import ast
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
    assert ruff("--stdin-filename", "bench_ctl/engine/machines/probe.py", "-", stdin=text).returncode == 1


def private_imports(root: Path) -> list[str]:
    """Names a module takes from another module of the tree although they are private there: `from
    M import _name`, or `M._name` of a module it imported (a module's own and dunder names are
    free). What a module offers another is public; a private helper used elsewhere is made public
    where it lives, or moved to where both can reach it."""
    found = []
    tops = ("bench_ctl", "drivers", "simulators", "procedures")
    for top in tops:
        for path in sorted((root / top).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            modules = set()
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom):
                    absolute = node.level == 0 and (node.module or "").split(".")[0] in tops
                    if node.level or absolute:
                        for a in node.names:
                            if a.name.startswith("_") and not a.name.startswith("__"):
                                found.append(f"{path.relative_to(root)}:{node.lineno}: from {'.' * node.level}"
                                             f"{node.module or ''} import {a.name}")
                            elif a.name[:1].islower():
                                modules.add(a.asname or a.name)
                elif isinstance(node, ast.Import):
                    modules |= {(a.asname or a.name).split(".")[0] for a in node.names
                                if a.name.split(".")[0] in tops}
            for node in ast.walk(tree):
                if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in modules
                        and node.attr.startswith("_") and not node.attr.startswith("__")):
                    found.append(f"{path.relative_to(root)}:{node.lineno}: {node.value.id}.{node.attr}")
    return found


def test_no_module_takes_a_private_name_of_another():
    assert private_imports(ROOT) == []


def test_the_private_name_rule_catches_both_forms(tmp_path):
    (tmp_path / "bench_ctl" / "engine").mkdir(parents=True)
    (tmp_path / "bench_ctl" / "engine" / "a.py").write_text(
        "from .step import _fixed_view, rk4\nfrom bench_ctl.engine import step\n"
        "x = step._view_d\ny = step.rk4\n", encoding="utf-8")
    (tmp_path / "bench_ctl" / "engine" / "b.py").write_text("def _own():\n    return _own.__name__\n",
                                                            encoding="utf-8")
    found = private_imports(tmp_path)
    assert [f.split(": ", 1)[1] for f in found] == ["from .step import _fixed_view", "step._view_d"]
