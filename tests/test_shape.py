"""The code's shape (docs/style.md, issue 47's "Shape" target), checked over the tree by reading it:

- no module over `MAX_MODULE_LINES` lines in bench_ctl/, drivers/, simulators/ (but `OVER_FOR_NOW`);
- no function over `MAX_FUNCTION_LINES` lines there;
- no function of bench_ctl/model/ or bench_ctl/engine/ with more than `MAX_PARAMS` parameters;
- the identification problem asks the engine for a simulation and owns no thread or vector-width
  policy: `PROBLEM_MODULES` import nothing of numba and name none of `POLICY_NAMES`.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOPS = ("bench_ctl", "drivers", "simulators")
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 150
MAX_PARAMS = 16
PARAM_ROOTS = ("bench_ctl/model/", "bench_ctl/engine/")
#: modules still over the line count that another branch splits (issue 47): allowed, not required,
#: so the merge of that branch does not fail here; delete an entry once its module is under
OVER_FOR_NOW: frozenset[str] = frozenset()
PROBLEM_MODULES = ("bench_ctl/identification/problem.py", "bench_ctl/identification/construction.py",
                   "bench_ctl/identification/fit_record.py")
POLICY_NAMES = {"LANES", "set_num_threads", "get_num_threads", "set_fit_threads", "numba", "nb", "prange"}


def _modules(root: Path) -> list[Path]:
    return [p for top in TOPS for p in sorted((root / top).rglob("*.py")) if "__pycache__" not in p.parts]


def shape_findings(root: Path, over_for_now: frozenset[str] = OVER_FOR_NOW) -> list[str]:
    out = []
    for path in _modules(root):
        rel = path.relative_to(root).as_posix()
        text = path.read_text(encoding="utf-8")
        n = len(text.splitlines())
        if n > MAX_MODULE_LINES and rel not in over_for_now:
            out.append(f"{rel}: {n} lines (at most {MAX_MODULE_LINES}: split it along a seam)")
        for node in ast.walk(ast.parse(text, filename=rel)):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            lines = node.end_lineno - node.lineno + 1
            if lines > MAX_FUNCTION_LINES:
                out.append(f"{rel}:{node.lineno} {node.name}: {lines} lines (at most {MAX_FUNCTION_LINES})")
            a = node.args
            k = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
            if k > MAX_PARAMS and rel.startswith(PARAM_ROOTS):
                out.append(f"{rel}:{node.lineno} {node.name}: {k} parameters (at most {MAX_PARAMS}: group them)")
    return out


def policy_findings(root: Path) -> list[str]:
    out = []
    for rel in PROBLEM_MODULES:
        tree = ast.parse((root / rel).read_text(encoding="utf-8"), filename=rel)
        for node in ast.walk(tree):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name.split(".")[0] for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [(node.module or "").split(".")[0]] + [a.name for a in node.names]
            elif isinstance(node, ast.Name):
                names = [node.id]
            elif isinstance(node, ast.Attribute):
                names = [node.attr]
            out += [f"{rel}:{node.lineno} names {n} (threads and vector width are the engine's)"
                    for n in names if n in POLICY_NAMES]
    return out


def test_no_module_function_or_parameter_list_over_its_limit():
    assert shape_findings(ROOT) == []


def test_the_problem_owns_no_thread_or_vector_width_policy():
    assert policy_findings(ROOT) == []


def test_the_shape_rules_catch_what_they_name(tmp_path):
    for top in TOPS:
        (tmp_path / top).mkdir()
    (tmp_path / "bench_ctl" / "model").mkdir()
    params = ", ".join(f"p{i}" for i in range(MAX_PARAMS + 1))
    (tmp_path / "bench_ctl" / "model" / "wide.py").write_text(f"def wide({params}):\n    pass\n")
    (tmp_path / "drivers" / "long.py").write_text("def long():\n" + "    x = 1\n" * MAX_FUNCTION_LINES)
    (tmp_path / "simulators" / "big.py").write_text("x = 1\n" * (MAX_MODULE_LINES + 1))
    found = shape_findings(tmp_path, frozenset())
    assert [f.split(":")[0] for f in found] == ["bench_ctl/model/wide.py", "drivers/long.py", "simulators/big.py"]
    assert shape_findings(tmp_path, frozenset({"simulators/big.py"}))[-1].startswith("drivers/long.py")
    ident = tmp_path / "bench_ctl" / "identification"
    ident.mkdir()
    (ident / "problem.py").write_text("from bench_ctl.engine.layout import LANES\nimport numba as nb\n")
    (ident / "construction.py").write_text("def f(e):\n    return e.set_num_threads(2)\n")
    (ident / "fit_record.py").write_text("x = 1\n")
    assert [f.split(" names ")[1].split(" ")[0] for f in policy_findings(tmp_path)] == \
        ["LANES", "numba", "set_num_threads"]
