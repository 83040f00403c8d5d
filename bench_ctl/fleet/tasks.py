"""One step of one capture, run exactly as the single command runs it (same argv, same files):
`bench-ctl identify CAP --json result.json`, `bench-ctl diagnose CAP [--holdout H] --json
diagnosis.json`, `bench-ctl report result.json --diagnosis diagnosis.json -o report.html`.

A step returns a plain dict (picklable, for Dask): the exit code, what the command printed, the
wall time, and the error when it raised. A step never raises for a bad capture; it raises only
when the worker itself fails. Outputs go to temporary names in the capture's folder and are
renamed when the command has ended, so an interrupted batch leaves no half-written file.
"""
from __future__ import annotations

import contextlib
import io
import os
import time
import traceback
from pathlib import Path
from typing import Any

from bench_ctl.exitcodes import ExitCode
from bench_ctl.limits import InputError, read_json, sha256_file

from .manifest import Entry

RESULT, DIAGNOSIS, REPORT, DONE = "result.json", "diagnosis.json", "report.html", "done.json"
#: result / diagnosis keys that differ between two runs of the same capture by design
VOLATILE_KEYS = ("wall_s", "compile_s", "created_utc", "command_line", "seconds")


def _sha256(path: Path | None) -> str | None:
    return None if path is None else sha256_file(path)


def fingerprint(entry: Entry, evals: int, seed: int) -> dict[str, Any]:
    """What a capture's outputs depend on: input hashes and the settings (for resuming). An
    input gone, unreadable or no longer a regular file is an `InputError` naming it."""
    return {"capture": _sha256(entry.capture), "holdout": _sha256(entry.holdout),
            "unit": _sha256(entry.unit), "overrides": list(entry.overrides), "model": entry.model,
            "steps": list(entry.steps), "evals": evals, "seed": seed}


def _unit_args(entry: Entry) -> list[str]:
    args = ["--unit", str(entry.unit)] if entry.unit else []
    if entry.model:
        args += ["--model", entry.model]
    for s in entry.overrides:
        args += ["--set", s]
    return args


def argv_for(step: str, entry: Entry, folder: Path, *, evals: int, seed: int) -> list[str]:
    """The single command's argv for `step` of `entry`, writing into `folder`."""
    if step == "identify":
        return ["identify", str(entry.capture), *_unit_args(entry), "--evals", str(evals), "--seed", str(seed),
                "--no-progress", "--force", "--json", str(folder / RESULT)]
    if step == "diagnose":
        hold = ["--holdout", str(entry.holdout)] if entry.holdout else []
        return ["diagnose", str(entry.capture), *hold, *_unit_args(entry), "--seed", str(seed), "--force",
                "--json", str(folder / DIAGNOSIS)]
    if step == "report":
        # the result is the batch's own (its identify step, or an earlier batch's of this row, whose
        # capture `earlier_result_problem` checked): its capture lies outside the row's folder
        diag = ["--diagnosis", str(folder / DIAGNOSIS)] if (folder / DIAGNOSIS).exists() else []
        return ["report", str(folder / RESULT), *diag, "--force", "--allow-outside", "-o", str(folder / REPORT)]
    raise ValueError(f"unknown step {step!r}")


def earlier_result_problem(entry: Entry, folder: Path) -> str:
    """Why a row whose steps leave identify out cannot be reported from the result in its folder
    ("" when it can): none there, unreadable, or made from another capture than the row's."""
    from bench_ctl.identification.result_file import read_result
    from bench_ctl.records import FormatError

    path = folder / RESULT
    if not path.exists():
        return (f"the row's steps leave identify out and {path} does not exist (an earlier batch's "
                "identification of this capture is reported; run identify first)")
    try:
        result = read_result(path)
    except (InputError, FormatError) as exc:
        return f"{path}: {exc}"
    want = Path(entry.capture).resolve()
    for i, c in enumerate(result.captures):
        got = (folder / c.path).resolve() if c.path and not Path(c.path).is_absolute() else Path(c.path or "")
        if got.resolve() != want:
            return f"{path} was made from another capture (captures[{i}]: {c.path}), not {entry.capture}"
    return ""


def run_step(step: str, entry: Entry, folder: str, evals: int, seed: int) -> dict[str, Any]:
    """Run one step in this process; see the module docstring."""
    from bench_ctl.cli import main

    out_dir = Path(folder)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    buf = io.StringIO()
    row: dict[str, Any] = {"step": step, "capture": entry.name, "pid": os.getpid(), "start_unix": time.time()}
    try:
        argv = argv_for(step, entry, out_dir, evals=evals, seed=seed)
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            rc = main(argv)
        row.update(rc=int(rc), argv=argv)
    except Exception as exc:  # noqa: BLE001 - a bad capture is a row of the summary, not a crash
        row.update(rc=int(ExitCode.ABORTED), error=f"{type(exc).__name__}: {exc}",
                   trace=traceback.format_exc(limit=4))
    row["output"] = buf.getvalue()[-4000:]
    row["wall_s"] = time.perf_counter() - t0
    row["end_unix"] = time.time()
    if row["rc"] not in (ExitCode.OK, ExitCode.FAILED) and "error" not in row:
        lines = [ln for ln in row["output"].splitlines() if ln.strip()]
        row["error"] = lines[-1] if lines else f"exit {row['rc']}"
    return row


def warm_worker() -> float:
    """Load (or compile) the kernel in this worker once, before its first task; seconds. The
    worker's fits run one at a time: the cluster already runs one worker a core."""
    from bench_ctl.identification.identify import warm_up
    from bench_ctl.identification.threads import set_fit_threads
    from bench_ctl.units.unit import reference_unit

    set_fit_threads(1)
    return warm_up(reference_unit())


def write_done(folder: Path, fp: dict[str, Any], rows: list[dict[str, Any]]) -> None:
    """Mark a capture complete (last, atomically): its fingerprint and step exit codes."""
    from bench_ctl.outputs import write_json

    # the batch's own marker, replaced when the capture is done again (never through a link)
    write_json(folder / DONE, {"fingerprint": fp, "steps": {r["step"]: r["rc"] for r in rows}}, force=True)


OUTPUT_OF = {"identify": RESULT, "diagnose": DIAGNOSIS, "report": REPORT}


def is_done(folder: Path, fp: dict[str, Any]) -> bool:
    """The capture's outputs exist and were made from the same inputs and settings."""
    try:
        done = read_json(folder / DONE, "a result JSON")
    except InputError:
        return False
    if not isinstance(done, dict):
        return False
    return done.get("fingerprint") == fp and all((folder / OUTPUT_OF[s]).exists() for s in fp["steps"])
