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

This file is not scanned: its fixtures are bad pointers on purpose. `PENDING` lists findings
another branch removes (none today); an entry that no longer matches anything fails, so it cannot
outlive its reason.
"""
from __future__ import annotations

import glob
import re
from pathlib import Path

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
