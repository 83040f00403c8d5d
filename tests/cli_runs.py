"""`bench-ctl run` as a separate process against a simulated bench in the test's process.

A run in its own process is what an operator starts: real signals (SIGKILL included) reach it,
and its output folder can sit on a full or read-only file system, while the test watches the
simulated devices directly. `bench_toml` writes the bench config pointing at a `SimBench`;
`start_run` starts the run; `audit_rows` reads an audit that may still be growing.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
# a short real pulse test: 0.3 s pulse inside a 1.5 s record
FAST_PARAMS = {"pre_trigger_s": 0.2, "record_s": 1.5, "width_s": 0.3, "recovery_timeout_s": 3.0,
               "width_tolerance_s": 0.02}


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    return json.dumps(str(value))


def write_toml(path: Path, doc: dict[str, Any]) -> Path:
    """A bench config document (tables of scalars, one level of sub-tables) as TOML."""
    lines: list[str] = []

    def table(name: str, values: dict[str, Any]) -> None:
        lines.append(f"[{name}]")
        subs = {}
        for key, value in values.items():
            if isinstance(value, dict):
                subs[key] = value
            else:
                lines.append(f"{key} = {_toml_value(value)}")
        lines.append("")
        for key, value in subs.items():
            table(f"{name}.{key}", value)

    for name, values in doc.items():
        table(name, values)
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def bench_doc(sim: Any, *, exciter_url: str | None = None, exciter: dict | None = None,
              limits: dict | None = None) -> dict[str, Any]:
    """benches/example.toml pointed at `sim` (its TCP exciter, or `exciter_url`; the recorder on
    its pseudo-terminal), with short timeouts."""
    doc = tomllib.loads((ROOT / "benches" / "example.toml").read_text())
    ep = sim.endpoints
    doc["exciter"].update({"url": exciter_url or f"tcp://{ep.exciter_host}:{ep.exciter_port}",
                           "timeout_s": 0.3, "heartbeat_period_s": 0.1, **(exciter or {})})
    doc["recorder"].update(url=ep.recorder_serial, timeout_s=0.2)
    doc["limits"].update({"restore_deadline_s": 3.0, **(limits or {})})
    return doc


def bench_toml(path: Path, sim: Any, **kw: Any) -> Path:
    return write_toml(path, bench_doc(sim, **kw))


def run_argv(bench: Path, out: Path, *, params: dict[str, Any] | None = None,
             procedure: str = "no_load_pulse", extra: tuple[str, ...] = ("--yes",)) -> list[str]:
    argv = [sys.executable, "-m", "bench_ctl.cli", "run", procedure, "--bench", str(bench),
            "--out", str(out), *extra]
    for key, value in (FAST_PARAMS if params is None else params).items():
        argv += ["--param", f"{key}={value}"]
    return argv


def run_env(**extra: str) -> dict[str, str]:
    """The environment of a run: this worktree importable (bench locks are host-wide whatever the
    environment: bench_ctl/runner/lock.py), plus `extra`."""
    return {**os.environ, "PYTHONPATH": str(ROOT), **extra}


def start_run(argv: list[str], *, env: dict[str, str] | None = None, **popen: Any) -> subprocess.Popen:
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=run_env() if env is None else env, cwd=ROOT, **popen)


def wait_for(cond: Any, timeout_s: float, what: str, every_s: float = 0.002) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(every_s)


def audit_rows(path: Path) -> list[dict[str, Any]]:
    """The complete lines of an audit that may still be written (or cut short)."""
    rows = []
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return rows
    for line in text.splitlines():
        try:
            rows.append(json.loads(line))
        except ValueError:
            break
    return rows
