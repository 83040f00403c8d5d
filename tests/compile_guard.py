"""The check that nothing compiles inside the tests: `make test` and `make test-slow` compile the
engine's variants the suite runs ahead (`bench-ctl warm-up --variants tests/engine_variants.txt`),
as a compilation inside a test counts against that test's time limit and two workers would compile
the same variant twice.

The evidence is numba's disk cache, whichever process compiled (a pytest worker, a dry run's
child, a `bench-ctl` the test started): an index file of the engine or the plants (`.nbi`) written
during the session is a compilation. The session (the controller under pytest-xdist) lists them
at its start and again at its end, and names each compiled function's variant (the `__VARIANT_`
of its cache name, bench_ctl/engine/jit.py) and the tests that were running when it was written.

It fails the session
- when a test compiled a variant the list leaves out (CI would compile it inside a test), and
- when anything compiled although every listed variant was in the cache at the start: after the
  warm-up, a compilation is a call the warm-up does not make (another variant, other argument
  types).
A session on a cache that lacked listed variants (a first run, an edit of the engine: the tests
compile what they use, as decision 0023 allows) is told what compiled, and passes.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

LIST = Path(__file__).with_name("engine_variants.txt")
#: a cache index file's name: MODULE.FUNCTION__[VARIANT_]DIGEST-LINE.pyXY.nbi (jit._compiled)
INDEX = re.compile(r"^(?P<module>\w+)\.(?P<function>\w+?)__(?:(?P<variant>\w+)_)?(?P<digest>[0-9a-f]{10})"
                   r"-\d+\.py\d+\.nbi$")


def listed() -> set[str]:
    """The variant names tests/engine_variants.txt lists."""
    lines = LIST.read_text(encoding="utf-8").splitlines()
    return {name for name in (line.split("#", 1)[0].strip() for line in lines) if name}


def cache_folders() -> list[Path]:
    """The folders numba caches the engine's and the plants' functions in."""
    import bench_ctl.plants  # noqa: F401 - registers the real-time loop's functions
    from bench_ctl.engine import jit

    paths = {getattr(getattr(d, "_cache", None), "_cache_path", None) for d in jit.DISPATCHERS.values()}
    return sorted(Path(p) for p in paths if p)


def snapshot(folders: list[Path]) -> dict[Path, int]:
    """Every cache index file in `folders`, with its modification time (ns)."""
    out = {}
    for folder in folders:
        try:
            entries = list(folder.iterdir())
        except OSError:
            continue
        for path in entries:
            if path.suffix == ".nbi":
                try:
                    out[path] = path.stat().st_mtime_ns
                except OSError:   # removed meanwhile (prune_stale)
                    pass
    return out


@dataclass
class Guard:
    """The session's record: the cache at its start, the tests' times, and the verdict."""
    folders: list[Path]
    before: dict[Path, int]
    digest: str
    expected: set[str] = field(default_factory=listed)
    #: (nodeid, start, stop) of each test phase, epoch seconds
    runs: list[tuple[str, float, float]] = field(default_factory=list)

    @classmethod
    def start(cls) -> Guard:
        from bench_ctl.engine import jit

        folders = cache_folders()
        return cls(folders, snapshot(folders), jit.DIGEST)

    def warm(self) -> bool:
        """Whether every listed variant was in the cache at the start (the warm-up ran)."""
        have = {m["variant"] for m in (INDEX.match(p.name) for p in self.before)
                if m and m["digest"] == self.digest}
        return self.expected <= have

    def finish(self) -> tuple[bool, list[str]]:
        """(whether the session fails, the lines that say what compiled); no lines: nothing did."""
        from bench_ctl.engine.warm import ALL

        after = snapshot(self.folders)
        written = sorted((t, p) for p, t in after.items() if self.before.get(p) != t)
        if not written:
            return False, []
        by_variant: dict[str, list[tuple[int, str]]] = {}
        for t, path in written:
            m = INDEX.match(path.name)
            variant = (m["variant"] or "") if m else "?"
            by_variant.setdefault(variant, []).append((t, f"{m['module']}.{m['function']}" if m else path.name))
        known = {k.name for k in ALL}
        outside = sorted(v for v in by_variant if v in known and v not in self.expected)
        warm = self.warm()
        lines = []
        for variant, items in sorted(by_variant.items()):
            functions = ", ".join(sorted({f for _, f in items}))
            lines.append(f"  {variant or '(no variant)'}: {functions}")
            lines.append(f"    compiled by {' or '.join(self.running([t for t, _ in items])) or 'no test'}")
        if outside:
            lines.append(f"  not in {LIST.name}, so CI compiles it inside a test: {', '.join(outside)}; add it "
                         "there (`make test` compiles what it lists ahead)")
        failed = bool(outside) or warm
        if warm:
            lines.insert(0, "FAILED: the engine compiled inside the tests after the warm-up (every variant of "
                            f"{LIST.name} was in numba's cache at the start): a call the warm-up does not make")
        else:
            lines.insert(0, f"{'FAILED: ' if failed else ''}the engine compiled inside the tests: numba's cache "
                            f"lacked variants of {LIST.name} at the start (`bench-ctl warm-up --variants "
                            "tests/engine_variants.txt` compiles them ahead)")
        return failed, lines

    def running(self, times_ns: list[int]) -> list[str]:
        """The tests that ran while every one of these files was written (the one that compiled
        them), else those that ran while any was."""
        sets = [{n for n, a, b in self.runs if a - 0.1 <= t / 1e9 <= b + 0.1} for t in times_ns]
        return sorted(set.intersection(*sets) or set.union(*sets))
