"""The layer rules of docs/architecture.md, checked over the whole tree by reading the imports.

- procedures/ reach devices only through the runner: they import neither drivers nor simulators;
- drivers/ never imports simulators/ (a simulated device is another address, not a branch);
- the analysis packages (bench_ctl.model, capture, identification, diagnosis, report) import
  none of drivers, simulators and bench_ctl.runner: they read captures and results only.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

RULES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("procedures", ("drivers", "simulators")),
    ("drivers", ("simulators",)),
    *((f"bench_ctl.{pkg}", ("drivers", "simulators", "bench_ctl.runner"))
      for pkg in ("model", "capture", "identification", "diagnosis", "report")),
)


def module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports(root: Path, path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in `path`, relative ones resolved."""
    mod = module_name(root, path)
    package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            out.append((node.lineno, name))
    return out


def violations(root: Path, rules=RULES) -> list[str]:
    found = []
    for path in sorted(root.rglob("*.py")):
        if any(part.startswith(".") or part in ("tests", "benchmarks") for part in path.relative_to(root).parts):
            continue
        mod = module_name(root, path)
        for layer, banned in rules:
            if mod != layer and not mod.startswith(layer + "."):
                continue
            for line, name in imports(root, path):
                for b in banned:
                    if name == b or name.startswith(b + "."):
                        found.append(f"{path.relative_to(root)}:{line}: {mod} imports {name} "
                                     f"({layer} must not import {b})")
    return found


def test_the_tree_keeps_its_layers():
    assert violations(ROOT) == []


def test_the_checker_catches_each_rule(tmp_path):
    files = {
        "procedures/p.py": "from drivers.errors import DeviceError\n",
        "drivers/d.py": "import simulators.bench\n",
        "drivers/ok.py": "from bench_ctl.runner import run_procedure\n",
        "bench_ctl/__init__.py": "",
        "bench_ctl/report/__init__.py": "",
        "bench_ctl/report/r.py": "from ..runner import bench\n",
        "bench_ctl/model/m.py": "from bench_ctl.model import kernel\n",
        "simulators/s.py": "from drivers.profile import load_profile\n",
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text, encoding="utf-8")
    found = violations(tmp_path)
    assert len(found) == 3, found
    assert any("procedures.p imports drivers.errors" in f for f in found)
    assert any("drivers.d imports simulators.bench" in f for f in found)
    assert any("bench_ctl.report.r imports bench_ctl.runner" in f for f in found)


def import_cycles(root: Path) -> list[list[str]]:
    """Cycles among the tree's modules (a package's __init__ importing its own modules is not one)."""
    mods = {module_name(root, p): p for p in root.rglob("*.py")
            if not any(part.startswith(".") or part in ("tests", "benchmarks") for part in p.relative_to(root).parts)}
    graph: dict[str, set[str]] = {}
    for mod, path in mods.items():
        deps = set()
        for _line, name in imports(root, path):
            while name and name not in mods:
                name = name.rpartition(".")[0]
            if name and name != mod and not mod.startswith(name + ".") and not name.startswith(mod + "."):
                deps.add(name)
        graph[mod] = deps
    cycles, state = [], {}

    def visit(m: str, stack: list[str]) -> None:
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d, stack)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])
    return cycles


def test_no_module_imports_itself_round_a_circle():
    assert import_cycles(ROOT) == []
