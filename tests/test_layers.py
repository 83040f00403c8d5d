"""The layer rules of docs/architecture.md, checked over the whole tree by reading the imports
(contracts in the spirit of import-linter's, as ophyd-async keeps them).

- Every module of bench_ctl/, drivers/, simulators/ and procedures/ belongs to one layer of
  `LAYERS` (the longest matching name), and imports only its own layer, `SHARED` and the layers
  its entry lists (third-party packages are free). A module in no layer fails: a new package
  states its place here and in docs/architecture.md.
- Identification never imports diagnosis.
- A procedure never reaches a device's insides: no `.link`, `.profile`, `.heartbeat` and no
  private name of anything it was given (it is typed against `bench_ctl.runner.protocols`).
- No import cycles between modules.

`from P import name` counts as importing P.name when that is a module of the tree (`from
bench_ctl.engine import runner` imports the runner); imports inside functions count. tests/ and
benchmarks/ are outside the rules (they build simulators and call everything).
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOPS = ("bench_ctl", "drivers", "simulators", "procedures")

#: what every layer may import: the package itself (its version) and the leaf helpers, which
#: import nothing of the tree but the exit codes (checked below): exit codes, input files, output
#: files, typed JSON records, timestamps
SHARED = ("bench_ctl", "bench_ctl.exitcodes", "bench_ctl.limits", "bench_ctl.outputs", "bench_ctl.records",
          "bench_ctl.timestamps", "bench_ctl.compile_notice")
#: the model's rooms, bottom up: the catalogue, the analysis of recorded signals, unit files and
#: .dyr, the simulation engine
MODELLING = ("bench_ctl.model", "bench_ctl.signals", "bench_ctl.units", "bench_ctl.engine")
ANALYSIS = (*MODELLING, "bench_ctl.capture", "bench_ctl.identification", "bench_ctl.diagnosis", "bench_ctl.report")
#: the pure analysis helpers a procedure may use on what it recorded: numpy on arrays, no engine,
#: no plant, no files, no device (the shared edge finder)
PURE_ANALYSIS = ("bench_ctl.signals.edges", "bench_ctl.signals.mode")

#: layer -> what it may import besides itself and SHARED (a name stands for its sub-modules)
LAYERS: dict[str, tuple[str, ...]] = {
    "bench_ctl": (),                       # the package __init__ (its version, NUMBA_OPT) only
    "bench_ctl.exitcodes": (),
    "bench_ctl.limits": (),
    "bench_ctl.timestamps": (),
    "bench_ctl.outputs": (),
    "bench_ctl.records": (),
    "bench_ctl.compile_notice": (),
    "drivers": (),
    "simulators": ("drivers", "bench_ctl.plants", "bench_ctl.model", "bench_ctl.units"),
    "procedures": ("bench_ctl.runner", *PURE_ANALYSIS),
    "bench_ctl.runner": ("drivers", "bench_ctl.capture"),
    "bench_ctl.model": (),
    "bench_ctl.signals": ("bench_ctl.model",),
    "bench_ctl.units": ("bench_ctl.model", "bench_ctl.signals"),
    "bench_ctl.engine": ("bench_ctl.model", "bench_ctl.signals", "bench_ctl.units"),
    "bench_ctl.plants": MODELLING,
    "bench_ctl.capture": MODELLING,
    "bench_ctl.identification": (*MODELLING, "bench_ctl.capture"),
    "bench_ctl.diagnosis": (*MODELLING, "bench_ctl.capture", "bench_ctl.identification"),
    "bench_ctl.report": (*MODELLING, "bench_ctl.capture", "bench_ctl.identification", "bench_ctl.diagnosis"),
    "bench_ctl.fleet": ("bench_ctl.cli", *ANALYSIS),
    "bench_ctl.cli": (),                   # sub-commands are imported by name, when used
    "bench_ctl.commands": ("bench_ctl.cli", *ANALYSIS, "bench_ctl.plants", "bench_ctl.runner", "bench_ctl.fleet",
                           "drivers", "simulators"),
}
#: module -> what it may import beyond its layer
MODULE_EXTRA: dict[str, tuple[str, ...]] = {
    # a dry run starts the simulated bench in a child process (docs/decisions/0005)
    "bench_ctl.runner.dryrun": ("simulators",),
}

#: (importer, imported, why): imports the rules refuse that are allowed for now; each must still
#: occur (the test says when one can go)
TEMPORARY: tuple[tuple[str, str, str], ...] = ()

#: what a procedure must not reach on a device (bench_ctl.runner.protocols gives what it needs)
DEVICE_INSIDES = ("link", "profile", "heartbeat")


def module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _is_module(root: Path, name: str) -> bool:
    p = root.joinpath(*name.split("."))
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


def imports(root: Path, path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in `path`, relative ones resolved; `from P
    import name` is P.name when that is a module of the tree, else P."""
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
            subs = [f"{name}.{a.name}" for a in node.names if _is_module(root, f"{name}.{a.name}")]
            if len(subs) < len(node.names):
                out.append((node.lineno, name))
            out += [(node.lineno, s) for s in subs]
    return out


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def layer_of(mod: str) -> str | None:
    """The longest LAYERS name `mod` falls under ("bench_ctl" itself only for the package)."""
    best = None
    for layer in LAYERS:
        if (mod == layer if layer == "bench_ctl" else _under(mod, layer)) and len(layer) > len(best or ""):
            best = layer
    return best


def tree_modules(root: Path) -> dict[str, Path]:
    return {module_name(root, p): p for top in TOPS if (root / top).is_dir()
            for p in sorted((root / top).rglob("*.py"))
            if not any(part.startswith(".") for part in p.relative_to(root).parts)}


def _refusal(mod: str, name: str) -> str | None:
    """Why `mod` may not import `name` (a module of the tree), or None."""
    layer = layer_of(mod)
    if layer is None:
        return f"{mod} is in no layer (place it in tests/test_layers.py LAYERS and docs/architecture.md)"
    if _under(mod, "bench_ctl.identification") and _under(name, "bench_ctl.diagnosis"):
        return "identification never imports diagnosis"
    if name in SHARED or _under(name, layer) or layer_of(name) == layer:
        return None
    allowed = LAYERS[layer] + MODULE_EXTRA.get(mod, ())
    if any(_under(name, a) for a in allowed):
        return None
    return f"{layer} imports only {', '.join(allowed) or 'nothing of the tree'} (and {', '.join(SHARED)})"


def violations(root: Path, temporary=TEMPORARY) -> list[str]:
    found, used = [], set()
    for mod, path in tree_modules(root).items():
        if layer_of(mod) is None:
            found.append(f"{path.relative_to(root)}: {_refusal(mod, mod)}")
            continue
        for line, name in imports(root, path):
            if name.split(".")[0] not in TOPS:
                continue
            why = _refusal(mod, name)
            if why is None:
                continue
            allowed = [t for t in temporary if t[0] == mod and _under(name, t[1])]
            if allowed:
                used.add(allowed[0])
                continue
            found.append(f"{path.relative_to(root)}:{line}: {mod} imports {name} ({why})")
    found += [f"temporary exception {t[0]} -> {t[1]} ({t[2]}) no longer needed: remove it from TEMPORARY"
              for t in temporary if t not in used]
    return found


def reaches(root: Path) -> list[str]:
    """Attributes a procedure must not touch: a device's link, profile or heartbeat, and private
    names of anything but itself."""
    found = []
    for path in sorted((root / "procedures").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if not isinstance(node, ast.Attribute):
                continue
            private = node.attr.startswith("_") and not node.attr.startswith("__")
            if isinstance(node.value, ast.Name) and node.value.id == "self":
                continue
            if node.attr in DEVICE_INSIDES or private:
                found.append(f"{path.relative_to(root)}:{node.lineno}: .{node.attr} (a procedure uses "
                             "bench_ctl.runner.protocols, never a driver's insides)")
    return found


def test_the_tree_keeps_its_layers():
    assert violations(ROOT) == []


def test_procedures_never_reach_a_drivers_insides():
    assert reaches(ROOT) == []


def test_the_leaf_helpers_import_nothing_of_the_tree():
    """...but the exit codes, which import nothing at all: each helper's input error derives from
    their `BadInput`."""
    for mod in SHARED:
        path = tree_modules(ROOT)[mod]
        if mod == "bench_ctl":
            continue
        allowed = () if mod == "bench_ctl.exitcodes" else ("bench_ctl.exitcodes",)
        assert [n for _, n in imports(ROOT, path) if n.split(".")[0] in TOPS and n not in allowed] == [], mod


def test_the_checker_catches_each_rule(tmp_path):
    files = {
        "bench_ctl/__init__.py": "",
        "bench_ctl/limits.py": "",
        "bench_ctl/model/__init__.py": "",
        "bench_ctl/model/params.py": "from bench_ctl.units import unit\n",          # refused
        "bench_ctl/engine/__init__.py": "from .step import rk4\n",               # fine: inside
        "bench_ctl/engine/layout.py": "",
        "bench_ctl/engine/step.py": "from .layout import CHUNK\nfrom ..units.unit import U\n",  # fine
        "bench_ctl/signals/edges.py": "from ..engine import step\n",               # refused
        "bench_ctl/units/unit.py": "from bench_ctl.limits import read_text\n",     # fine: shared
        "bench_ctl/identification/__init__.py": "",
        "bench_ctl/identification/i.py": "from bench_ctl.engine import step\n"     # fine
                                         "from bench_ctl.diagnosis import d\n",     # refused
        "bench_ctl/diagnosis/__init__.py": "",
        "bench_ctl/diagnosis/d.py": "from bench_ctl.plants import Plant\n"       # refused
                                    "from bench_ctl.plants.realtime import f\n",   # refused: a submodule
        "bench_ctl/commands/__init__.py": "",
        "bench_ctl/commands/c.py": "from bench_ctl.plants import plant\n",       # fine
        "bench_ctl/report/__init__.py": "",
        "bench_ctl/report/r.py": "from ..runner import bench\n",                  # refused
        "bench_ctl/runner/__init__.py": "",
        "bench_ctl/runner/bench.py": "import simulators.bench\n",                 # refused
        "bench_ctl/runner/dryrun.py": "import simulators.bench\n",                # fine
        "bench_ctl/fleet/__init__.py": "",
        "bench_ctl/fleet/f.py": "from drivers.link import ModbusLink\n",          # refused
        "bench_ctl/newpkg/__init__.py": "",                                       # in no layer
        "procedures/p.py": "from drivers.errors import DeviceError\n"             # refused
                           "from bench_ctl.signals.edges import find_edges\n"       # fine
                           "from bench_ctl.units.unit import load_unit\n"         # refused
                           "def f(bench):\n    return bench.exciter.link, bench.recorder._x\n",
        "drivers/d.py": "import simulators.bench\n",                              # refused
        "drivers/ok.py": "from bench_ctl.limits import read_text\n",              # fine
        "drivers/r.py": "from bench_ctl.runner import run_procedure\n"            # refused
                        "from bench_ctl.capture import read_capture\n",           # refused
        "simulators/__init__.py": "",
        "simulators/s.py": "from drivers.profile import load_profile\n",         # fine
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text, encoding="utf-8")
    found = violations(tmp_path, temporary=(("bench_ctl.report.r", "drivers", "a stale one"),))
    expected = [
        "bench_ctl.identification.i imports bench_ctl.diagnosis.d (identification never imports diagnosis)",
        "bench_ctl.model.params imports bench_ctl.units.unit (bench_ctl.model imports only",
        "bench_ctl.signals.edges imports bench_ctl.engine.step (bench_ctl.signals imports only",
        "bench_ctl.diagnosis.d imports bench_ctl.plants (bench_ctl.diagnosis imports only",
        "bench_ctl.diagnosis.d imports bench_ctl.plants.realtime (bench_ctl.diagnosis imports only",
        "bench_ctl.report.r imports bench_ctl.runner.bench (bench_ctl.report imports only",
        "bench_ctl.runner.bench imports simulators.bench",
        "bench_ctl.fleet.f imports drivers.link",
        "bench_ctl.newpkg is in no layer",
        "procedures.p imports drivers.errors",
        "procedures.p imports bench_ctl.units.unit",
        "drivers.d imports simulators.bench",
        "drivers.r imports bench_ctl.runner",
        "drivers.r imports bench_ctl.capture",
        "temporary exception bench_ctl.report.r -> drivers (a stale one) no longer needed",
    ]
    for e in expected:
        assert sum(e in f for f in found) == 1, (e, found)
    assert len(found) == len(expected), found
    assert [f.split(": ")[1] for f in reaches(tmp_path)] == [".link (a procedure uses bench_ctl.runner.protocols, "
                                                            "never a driver's insides)", "._x (a procedure uses "
                                                            "bench_ctl.runner.protocols, never a driver's insides)"]


def import_cycles(root: Path) -> list[list[str]]:
    """Cycles among the tree's modules (a package's __init__ importing its own modules is not one)."""
    mods = tree_modules(root)
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
