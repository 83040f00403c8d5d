"""One UTC timestamp format for every file bench-ctl writes (`bench_ctl.timestamps`), and no
module that makes its own."""
from __future__ import annotations

import datetime as dt
import re
import time
from pathlib import Path

import pytest

from bench_ctl.timestamps import utc_at_monotonic, utc_now_text, utc_text

ROOT = Path(__file__).resolve().parents[1]
FORMAT = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d{6})?\+00:00")

#: where "now" is still formatted by hand, and why (each a module another change owns)
ELSEWHERE: set[str] = set()


def test_the_format_reads_back_and_is_always_utc():
    now = utc_now_text()
    assert FORMAT.fullmatch(now), now
    assert dt.datetime.fromisoformat(now).utcoffset() == dt.timedelta(0)
    assert FORMAT.fullmatch(utc_now_text("microseconds"))
    cest = dt.datetime(2026, 3, 14, 11, 26, 53, tzinfo=dt.timezone(dt.timedelta(hours=2)))
    assert utc_text(cest) == "2026-03-14T09:26:53+00:00"
    with pytest.raises(ValueError, match="no time zone"):
        utc_text(dt.datetime(2026, 3, 14, 9, 26, 53))


def test_a_monotonic_instant_is_placed_on_the_wall_clock():
    t = time.monotonic()
    there = dt.datetime.fromisoformat(utc_at_monotonic(t - 2.0))
    assert abs((dt.datetime.now(dt.UTC) - there).total_seconds() - 2.0) < 0.5


def test_no_module_formats_now_by_hand():
    """A timestamp of 'now' is made by bench_ctl.timestamps only (datetime.now / utcnow /
    gmtime followed by isoformat or strftime); the time of a record's own samples (COMTRADE,
    a vendor export) and a folder's local-time name are not timestamps of a written file."""
    now = re.compile(r"(datetime\.now\(|\.utcnow\(|gmtime\()[^\n]*(isoformat|strftime)")
    found, exempt = [], set()
    for top in ("bench_ctl", "drivers", "simulators", "procedures"):
        for path in sorted((ROOT / top).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel == "bench_ctl/timestamps.py":
                continue
            for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if not now.search(line) or "strftime(\"%Y%m%dT%H%M%S\")" in line:
                    continue
                if rel in ELSEWHERE:
                    exempt.add(rel)
                else:
                    found.append(f"{rel}:{i}: {line.strip()}")
    assert found == []
    assert exempt == ELSEWHERE, f"no longer formats now by hand: remove {ELSEWHERE - exempt} from ELSEWHERE"
