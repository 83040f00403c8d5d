"""Every pointer resolves inside a clone: nothing in the repository points at a document outside
it, and every page it points at exists.

Over every text file of the tree (code, tests, docs, configs), a finding is:
- a path into the shared notes or the machine's work folder (`OUTSIDE`), or any absolute path
  to a document (`.md`, `.rst`, `.txt`, `.pdf`, ...);
- one of the four lost design notes by name (`LOST_NOTES`: they were never in the repository;
  their content is in docs/);
- a `docs/....md` path that does not exist, a `docs/decisions/NNNN` that is not exactly one
  record, a `#anchor` or a quoted section name ("Edge timing") that is not a heading of the page;
- in a Markdown file, a relative link that does not resolve.
And the paths the docs cite in backticks (`bench_ctl/...`, `tests/...`) must exist, so a moved
module cannot leave its documentation pointing at nothing.

And every code identifier a page names in backticks - `name`, `module.name`, `Class.method()`,
`bench_ctl.pkg.module.name` - exists in the code: the set of names is read from the code itself
(`code_names`: every module, class, function, argument, assigned name and attribute, import,
keyword and identifier-like string constant of the tree, the keys of its TOML files, Python's
builtins), so a renamed function leaves no page naming the old one. A name of another library is
written with its module (`scipy.integrate.solve_ivp`); key templates (`wall_s_C`) and file names
are not identifiers; the dated notes of `docs/lab/` record what was true on their date and are
not checked.

This file is not scanned: its fixtures are bad pointers on purpose. `PENDING` lists findings
another branch removes (none today); an entry that no longer matches anything fails, so it cannot
outlive its reason.
"""
from __future__ import annotations

import ast
import builtins
import collections
import glob
import importlib.util
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: this file is not scanned: its fixtures are bad pointers on purpose. Its patterns and fixtures
#: spell the lost names in parts all the same, so that a script that rewrites such pointers
#: leaves this file alone
SELF = Path(__file__).resolve()

SKIP_DIRS = {".git", ".venv", "venv", "__pycache__", ".pytest_cache", ".mypy_cache", ".ruff_cache",
             "bench-out", "demo-out", "build", "dist", "node_modules"}
TEXT_SUFFIXES = {".py", ".md", ".toml", ".txt", ".cfg", ".ini", ".sh", ".yml", ".yaml", ".rst", ".json"}
TEXT_NAMES = {"Makefile", "run", ".gitignore"}

_NOTES = ("DES" "IGN", "SCH" "EMA", "PROF" "ILES", "STY" "LE")
LOST_NOTES = re.compile(r"\b(?:" + "|".join(_NOTES) + r")\.md\b")
OUTSIDE = re.compile(re.escape("/" + "work" + "/") + "|" + re.escape(".." + "/shared"))
ABSOLUTE_DOC = re.compile(r"(?<![\w.:/~-])(?:/|~/)[\w.@+-]+(?:/[\w.@+-]+)*\.(?:md|rst|txt|pdf|adoc|docx?|odt)\b")
DOCS_PATH = re.compile(r"(?<![\w/.-])(docs/[\w./-]*?\.md)(#[\w-]+)?")
DECISION_NUMBER = re.compile(r"(?<![\w/.-])docs/decisions/(\d{4})(?![\w-]*\.md)")
QUOTED_SECTION = re.compile(r'(docs/[\w./-]+\.md)(?:,\s*|\s*\(|\s+)"([^"\n]+(?:\n[ \t#:]*[^"\n]+)?)"')
MD_LINK = re.compile(r"\]\(([^)\s]+)\)")
CITED_PATH = re.compile(r"`((?:bench_ctl|drivers|simulators|procedures|tests|benchmarks|docs)/[^`\s]*)`")

#: (path, text of the finding): pointers another branch of issue 25 removes (re-run the repoint
#: script after merging it, then delete the entry)
PENDING: tuple[tuple[str, str], ...] = ()


def text_files(root: Path) -> list[Path]:
    out = []
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root)
        if any(part in SKIP_DIRS or part.endswith(".egg-info") for part in rel.parts[:-1]):
            continue
        if path.is_file() and (path.suffix in TEXT_SUFFIXES or path.name in TEXT_NAMES) \
                and path.resolve() != SELF:
            out.append(path)
    return out


def slug(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading."""
    s = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return s.replace(" ", "-")


def headings(page: Path) -> list[str]:
    out, fenced = [], False
    for line in page.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and (m := re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line)):
            out.append(m.group(1))
    return out


def _line(text: str, pos: int) -> int:
    return text.count("\n", 0, pos) + 1


def _page_findings(root: Path, page_rel: str, anchor: str | None, section: str | None) -> str | None:
    page = root / page_rel
    if not page.is_file():
        return f"{page_rel} does not exist"
    heads = headings(page)
    if anchor and anchor not in {slug(h) for h in heads}:
        return f"{page_rel} has no heading for #{anchor}"
    if section:
        want = re.sub(r"\s*\n[ \t#:]*", " ", section).strip().lower()
        if not any(h.lower().startswith(want) for h in heads):   # "The eight effects (...)"
            return f'{page_rel} has no section "{want}"'
    return None


def findings(root: Path) -> list[str]:
    found = []
    for path in text_files(root):
        rel = path.relative_to(root).as_posix()
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue

        def add(pos: int, what: str, rel: str = rel, text: str = text) -> None:
            found.append(f"{rel}:{_line(text, pos)}: {what}")

        for rx, why in ((OUTSIDE, "points outside the repository"),
                        (ABSOLUTE_DOC, "an absolute path to a document"),
                        (LOST_NOTES, "a design note the repository does not have (see docs/README.md)")):
            for m in rx.finditer(text):
                add(m.start(), f"{m.group(0)!r}: {why}")
        for m in DOCS_PATH.finditer(text):
            problem = _page_findings(root, m.group(1), m.group(2)[1:] if m.group(2) else None, None)
            if problem:
                add(m.start(), problem)
        for m in QUOTED_SECTION.finditer(text):
            if (root / m.group(1)).is_file():
                problem = _page_findings(root, m.group(1), None, m.group(2))
                if problem:
                    add(m.start(), problem)
        for m in DECISION_NUMBER.finditer(text):
            hits = list((root / "docs" / "decisions").glob(f"{m.group(1)}-*.md"))
            if len(hits) != 1:
                add(m.start(), f"docs/decisions/{m.group(1)}: {len(hits)} records with that number")
        if path.suffix == ".md":
            for m in MD_LINK.finditer(text):
                target = m.group(1)
                if re.match(r"[a-z][a-z0-9+.-]*:", target):   # http:, mailto: ...
                    continue
                file_part, _, anchor = target.partition("#")
                dest = (path.parent / file_part).resolve() if file_part else path
                if not dest.exists():
                    add(m.start(), f"link {target!r} does not resolve")
                elif anchor and dest.suffix == ".md":
                    problem = _page_findings(root, dest.relative_to(root.resolve()).as_posix(), anchor, None)
                    if problem:
                        add(m.start(), f"link {target!r}: {problem}")
    return [f for f in found if not _pending(f)]


def _pending(finding: str) -> bool:
    return any(finding.startswith(path + ":") and text in finding for path, text in PENDING)


def cited_path_findings(root: Path) -> list[str]:
    """Paths the docs (and the READMEs) cite in backticks that do not exist. A path component
    that is an upper-case placeholder (NAME.py) matches any file; `::test` is dropped."""
    found = []
    pages = sorted((root / "docs").rglob("*.md")) + [root / "README.md"]
    for page in pages:
        text = page.read_text(encoding="utf-8")
        for m in CITED_PATH.finditer(text):
            cited = m.group(1).split("::")[0].rstrip("/.,;:")
            pattern = "/".join(re.sub(r"^[A-Z]{1,5}(?=\.|$)", "*", part) for part in cited.split("/"))
            candidates = [pattern, pattern + ".py"]
            if not any(glob.glob(str(root / c)) for c in candidates):
                found.append(f"{page.relative_to(root).as_posix()}:{_line(text, m.start())}: "
                             f"{cited} does not exist")
    return found


def test_nothing_points_outside_the_repository():
    assert findings(ROOT) == []


def test_paths_the_docs_cite_exist():
    assert cited_path_findings(ROOT) == []


def test_pending_exceptions_are_still_needed():
    """A PENDING entry whose pointer is gone (the other branch merged, the script re-run) must be
    deleted; so must one whose file no longer exists."""
    stale = [f"{path}: no {text!r} left (delete this PENDING entry)" for path, text in PENDING
             if not (ROOT / path).is_file() or text not in (ROOT / path).read_text(encoding="utf-8")]
    assert stale == []


def test_the_checker_catches_each_kind_of_pointer(tmp_path):
    note = "STY" "LE.md"
    files = {
        "docs/real.md": "# Real page\n\n## Edge timing\n\nsee [model](model.md) and [here](#edge-timing)\n",
        "docs/decisions/0001-one.md": "# 0001. One\n",
        "a.py": f'"""Exit codes ({note})."""\n',
        "b.py": "# see " + "/" + "work" + "/notes/x.txt\n",
        "c.toml": "# notes in " + ".." + "/shared/design\n",
        "d.py": '"""As in ~/notes/design' + '.md and /srv/docs/profiles' + '.rst."""\n',
        "e.py": '"""Formats: docs/formats.md; timing: docs/real.md#no-such-heading."""\n',
        "f.md": 'See docs/real.md, "No such section" and docs/decisions/0002 and [x](docs/gone.md).\n',
        "ok.py": '"""docs/real.md, "Edge timing"; docs/real.md#edge-timing; docs/decisions/0001;'
                 ' https://example.org/x/README.md"""\n',
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text, encoding="utf-8")
    found = findings(tmp_path)
    expect = {
        "a.py:1": "design note", "b.py:1": "points outside", "c.toml:1": "points outside",
        "e.py:1": "docs/formats.md does not exist", "docs/real.md:5": "link 'model.md'",
    }
    for where, what in expect.items():
        assert any(f.startswith(where) and what in f for f in found), (where, what, found)
    assert sum(f.startswith("d.py:1") and "absolute path" in f for f in found) == 2, found
    assert any("no heading for #no-such-heading" in f for f in found), found
    assert any('no section "no such section"' in f for f in found), found
    assert any("docs/decisions/0002: 0 records" in f for f in found), found
    assert any("link 'docs/gone.md' does not resolve" in f for f in found), found
    assert not any(f.startswith("ok.py") for f in found), found
    assert not any("#edge-timing" in f for f in found), found


# --- every code identifier a page names exists -------------------------------------------------

CODE_DIRS = ("bench_ctl", "drivers", "simulators", "procedures", "benchmarks", "tests")
#: configuration files whose words count as names (a pytest marker's environment variable)
CONFIG_FILES = ("pyproject.toml", "Makefile", ".ci/run")
IDENTIFIER = re.compile(r"[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*")
WORD = re.compile(r"[A-Za-z_]\w*")
CODE_SPAN = re.compile(r"`([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*)(\(\))?`")
#: the last part of a file name, not an identifier (`result.json`, `kernel.py`)
FILE_SUFFIXES = {"py", "json", "jsonl", "csv", "html", "toml", "bin", "log", "md", "png", "pdf", "dat", "cfg",
                 "cff", "txt", "dyr", "yml", "yaml", "lock"}


@dataclass
class CodeNames:
    """What the code defines: `defined` (any name bound anywhere), `keys` (strings the code uses as
    keys, and the TOML files' keys), `members` (module dotted path or class name -> the names it
    defines at its top level), `modules` (the dotted paths)."""
    defined: set[str] = field(default_factory=set)
    keys: set[str] = field(default_factory=set)
    members: dict[str, set[str]] = field(default_factory=lambda: collections.defaultdict(set))
    modules: set[str] = field(default_factory=set)

    def drop(self, name: str) -> CodeNames:
        """These names without `name` (what a page would be checked against had `name` been
        renamed)."""
        members = collections.defaultdict(set, {k: v - {name} for k, v in self.members.items()})
        return CodeNames(self.defined - {name}, self.keys - {name}, members, set(self.modules))


def _docstrings(tree: ast.AST) -> set[int]:
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                out.add(id(first.value))
    return out


def _top_level(body: list[ast.stmt]) -> set[str]:
    out = set()
    for node in body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            for target in node.targets if isinstance(node, ast.Assign) else [node.target]:
                out.update(n.id for n in ast.walk(target) if isinstance(n, ast.Name))
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            out.update((a.asname or a.name).split(".")[0] for a in node.names)
    return out


def code_names(root: Path) -> CodeNames:
    """Every name the code of `root` defines (see `CodeNames`); derived from the code, never a list."""
    names = CodeNames()
    names.defined |= set(dir(builtins))
    for top in CODE_DIRS:
        for path in sorted((root / top).rglob("*.py")):
            rel = path.relative_to(root)
            if any(part in SKIP_DIRS for part in rel.parts) or path.resolve() == SELF:
                continue
            parts = rel.with_suffix("").parts
            dotted = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            names.modules.add(dotted)
            names.defined.update(dotted.split("."))
            tree = ast.parse(path.read_text(encoding="utf-8"))
            docs = _docstrings(tree)
            names.members[dotted] |= _top_level(tree.body)
            for node in ast.walk(tree):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                    names.defined.add(node.name)
                    if isinstance(node, ast.ClassDef):
                        names.members[node.name] |= _top_level(node.body)
                elif isinstance(node, ast.arg):
                    names.defined.add(node.arg)
                elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                    names.defined.add(node.id)
                elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                    names.defined.add(node.attr)
                elif isinstance(node, ast.alias):
                    names.defined.update((node.asname or node.name).split("."))
                elif isinstance(node, ast.keyword) and node.arg:
                    names.keys.add(node.arg)
                elif isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs \
                        and IDENTIFIER.fullmatch(node.value):
                    names.keys.update(node.value.split("."))
    for path in root.rglob("*.toml"):
        if any(part in SKIP_DIRS for part in path.relative_to(root).parts):
            continue
        stack: list = [tomllib.loads(path.read_text(encoding="utf-8"))]
        while stack:
            x = stack.pop()
            if isinstance(x, dict):
                names.keys.update(x)
                stack += list(x.values())
            elif isinstance(x, list):
                stack += x
    for rel in CONFIG_FILES:
        if (root / rel).is_file():
            names.keys.update(WORD.findall((root / rel).read_text(encoding="utf-8")))
    return names


def _template(token: str) -> bool:
    """A key template (`wall_s_C`, `SEXS_ratio`): upper-case placeholders among lower-case parts."""
    parts = [p for p in re.split(r"[_.]", token) if p]
    return any(p.isupper() for p in parts) and any(re.search(r"[a-z]", p) for p in parts)


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def _exists(token: str, names: CodeNames) -> bool:
    parts = token.split(".")
    known = names.defined | names.keys
    if len(parts) == 1:
        return token in known
    if any(m == token or m.endswith("." + token) for m in names.modules):   # a module (`bench_ctl.runner`)
        return True
    # a module of the tree, by its dotted path or by the end of it (`dialect.Dialect`,
    # `fleet.tasks.warm_worker`): the name after it is one the module defines
    for i in range(len(parts) - 1, 0, -1):
        prefix = ".".join(parts[:i])
        mods = [m for m in names.modules if m == prefix or m.endswith("." + prefix)]
        if mods and (parts[0] in CODE_DIRS or i > 0):
            rest = parts[i:]
            if any(rest[0] in names.members[m] for m in mods) and all(r in known for r in rest[1:]):
                return True
            if parts[0] in CODE_DIRS:
                return False
    if parts[0] in names.members:    # a class and one of its own names (`EdgeSearch.pulse`)
        if parts[1] in names.members[parts[0]] and all(r in known for r in parts[2:]):
            return True
    if all(p in names.keys for p in parts):    # a key path of a file (`model.name`, `limits.q_min_mvar`)
        return True
    head = parts[0]
    if head not in known or _installed(head):   # another library's (`scipy.integrate.solve_ivp`)
        return head not in {m.split(".")[-1] for m in names.modules} and head not in names.members
    return False


def identifier_findings(root: Path, names: CodeNames | None = None,
                        pages: list[Path] | None = None) -> list[str]:
    """Code identifiers the docs (and the README) name in backticks that the code does not have."""
    names = names if names is not None else code_names(root)
    if pages is None:
        pages = [p for p in sorted((root / "docs").rglob("*.md")) if "lab" not in p.relative_to(root).parts]
        pages.append(root / "README.md")
    found = []
    for page in pages:
        text = page.read_text(encoding="utf-8")
        for m in CODE_SPAN.finditer(text):
            token, call = m.group(1), m.group(2)
            if token.rsplit(".", 1)[-1] in FILE_SUFFIXES or _template(token):
                continue
            if not (call or "_" in token or "." in token or re.search(r"[a-z][A-Z]", token)):
                continue    # a plain word or a parameter name (`auto`, `KAVR`)
            if not _exists(token, names):
                found.append(f"{page.relative_to(root).as_posix()}:{_line(text, m.start())}: "
                             f"`{token}{call or ''}` is not a name of the code")
    return found


@pytest.fixture(scope="module")
def names() -> CodeNames:
    """The tree's code names, read once (3 s) for the two tests below."""
    return code_names(ROOT)


def test_every_identifier_the_docs_name_exists(names):
    assert identifier_findings(ROOT, names) == []


def test_a_stale_identifier_fails_the_check(tmp_path, names):
    """Mutations: a page naming a function that is not in the code, and the code losing a name a
    page names (as a rename would), each make the check fail; a qualified name of another
    library, a key template and a file name do not."""
    page = tmp_path / "docs" / "page.md"
    page.parent.mkdir()
    page.write_text("The report's `bench_ctl.model.dialect.kernel_sections` and `Dialect.kernel_text`;\n"
                    "`diagnosis.significance.SIGNIFICANT`, `scipy.integrate.solve_ivp`, `wall_s_C`, `result.json`.\n",
                    encoding="utf-8")
    assert identifier_findings(tmp_path, names, [page]) == []
    # a page names what no longer exists (decision 0009 named `_rhs_ref`, 0010 `_st4`)
    page.write_text("the reference right-hand side (`_rhs_ref`) and `online.step_online`\n", encoding="utf-8")
    found = identifier_findings(tmp_path, names, [page])
    assert len(found) == 2 and "`_rhs_ref`" in found[0] and "`online.step_online`" in found[1], found
    # the code renames a function a real page names: that page fails
    real = ROOT / "docs" / "model.md"
    assert identifier_findings(ROOT, names, [real]) == []
    gone = identifier_findings(ROOT, names.drop("CHECK_GAIN"), [real]) + \
        identifier_findings(ROOT, names.drop("kernel_view"), [real])
    assert any("CHECK_GAIN" in f for f in gone) and any("kernel_view" in f for f in gone), gone


def test_the_benchmarks_page_is_reference_not_a_lab_log():
    """docs/benchmarks.md states the current figures, each with its command; dated measurements
    ("Measured again 2026-11-27 ...") belong to docs/lab/ or a decision record's appendix."""
    text = (ROOT / "docs" / "benchmarks.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 300
    dated = re.findall(r"(?im)^.*\b(?:measured|recorded)(?: again)?(?: on)? \(?20\d\d-\d\d-\d\d.*$", text)
    assert dated == []
    assert list((ROOT / "docs" / "lab").glob("*.md")), "the dated notes have a home"


MODULE_ROOTS = ("bench_ctl", "drivers", "simulators", "procedures")


def module_list_findings(root: Path) -> list[str]:
    """Modules of the four packages that docs/architecture.md's "Every module" list lacks, and
    entries of that list that are no module."""
    text = (root / "docs" / "architecture.md").read_text(encoding="utf-8")
    section = text.split("## Every module", 1)[1].split("\n## ", 1)[0]
    listed = set(re.findall(r"^\| `([\w/]+\.py)` \|", section, flags=re.M))
    present = {p.relative_to(root).as_posix() for r in MODULE_ROOTS for p in (root / r).rglob("*.py")
               if "__pycache__" not in p.parts}
    return ([f"{m}: not in docs/architecture.md's module list" for m in sorted(present - listed)]
            + [f"{m}: listed in docs/architecture.md, no such module" for m in sorted(listed - present)])


def test_the_architecture_lists_every_module():
    assert module_list_findings(ROOT) == []


def test_a_module_missing_from_the_list_fails(tmp_path):
    for r in MODULE_ROOTS:
        (tmp_path / r).mkdir()
        (tmp_path / r / "__init__.py").write_text("")
    (tmp_path / "docs").mkdir()
    listed = "".join(f"| `{r}/__init__.py` | x |\n" for r in MODULE_ROOTS)
    (tmp_path / "docs" / "architecture.md").write_text(f"# A\n\n## Every module\n\n{listed}| `gone.py` | x |\n")
    (tmp_path / "bench_ctl" / "new.py").write_text("")
    assert module_list_findings(tmp_path) == ["bench_ctl/new.py: not in docs/architecture.md's module list",
                                             "gone.py: listed in docs/architecture.md, no such module"]
