"""`run_batch`: the steps of every capture of a manifest on a Dask cluster, then the summary.

Cluster: a LocalCluster sized to the machine, listening on loopback only unless another host is
named (one single-threaded worker process per core; the
kernel's own threads are kept to one per worker, `NUMBA_NUM_THREADS=1`, so workers do not fight
over the cores), started and closed here; or an existing cluster by scheduler address. Every
worker loads the compiled kernel once (a worker plugin, numba's disk cache) before its first
task. One task per capture step; report waits for identify and diagnose of its capture.
Resumable: a capture whose `done.json` fingerprint (input SHA-256s and settings) matches is
skipped. A failing step (bad file, fit failure, worker lost) becomes a row with its error; the
others go on. Ctrl-C cancels what has not finished; what has finished stays, and the summary is
written for it.
"""
from __future__ import annotations

import csv
import html
import logging
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from distributed.diagnostics.plugin import WorkerPlugin

from bench_ctl.diagnosis.diagnosis_file import read_diagnosis
from bench_ctl.exitcodes import ExitCode
from bench_ctl.identification.result_file import read_result
from bench_ctl.limits import InputError
from bench_ctl.outputs import OutputRefused, Outputs, why_not_written
from bench_ctl.records import FormatError

from . import tasks
from .manifest import Entry, read_manifest

if TYPE_CHECKING:
    from distributed import LocalCluster

R = TypeVar("R")

log = logging.getLogger(__name__)

#: a step that ran to its end (its output exists): passed, or its criteria failed
DONE_CODES = (ExitCode.OK, ExitCode.FAILED)

#: the environment of our LocalCluster's workers: the kernel on one thread (one worker per core)
WORKER_ENV = {"NUMBA_NUM_THREADS": "1"}
#: Dask settings of our LocalCluster's workers. They go through dask.config in the process that
#: starts the cluster: each nanny hands its worker the parent's config, which overrides what a
#: DASK_* variable in the worker's environment says (seen: profile.enabled True in a worker
#: started with DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False). No statistical profiler (a
#: callback that samples the running task's stack every 10 ms, taking the GIL from the fits);
#: glibc's own trim threshold instead of Dask's MALLOC_TRIM_THRESHOLD_=65536, which fixes the mmap
#: threshold too, so every array above 64 kB is mapped and faulted in anew (figures:
#: docs/decisions/0008, appendix). The event-loop watchdog (tick)
#: and the dashboard's CPU / memory sampler run at 1 s and 2 s instead of 20 ms and 0.5 s: on a
#: 2-core machine every core is a worker, and their wake-ups came out of the fits' time.
WORKER_CONFIG = {"distributed.worker.profile.enabled": False,
                 "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                 "distributed.admin.tick.interval": "1s",
                 "distributed.admin.system-monitor.interval": "2s"}


#: where our LocalCluster listens unless the user names another address: this machine only
LOOPBACK = "127.0.0.1"


def _with_port(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host and not host.startswith("[") else f"{host}:{port}"


def local_cluster(n_workers: int, host: str = LOOPBACK) -> LocalCluster:
    """A LocalCluster of `n_workers` single-threaded worker processes set up for the fits. Its
    scheduler, workers, nannies and dashboard all listen on `host` (default: loopback only; the
    dashboard on ':0' alone would listen on every interface)."""
    import dask
    from distributed import LocalCluster

    with dask.config.set(WORKER_CONFIG):   # read by each nanny when it is made, here
        return LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, host=host,
                            dashboard_address=_with_port(host, 0), env=WORKER_ENV,
                            silence_logs=logging.WARNING)

SUMMARY_COLUMNS = ("capture", "status", "mse", "noise_floor", "mse_over_floor", "verdict", "explained_by",
                   "warnings", "result", "diagnosis", "report", "error", "wall_s")


@dataclass
class BatchOutcome:
    rows: list[dict[str, Any]]
    summary_csv: Path
    index_html: Path
    wall_s: float
    warm_s: dict[str, float] = field(default_factory=dict)
    interrupted: bool = False
    #: every step's row as the task returned it (timestamps, pid, wall time), for benchmarks
    step_rows: list[dict[str, Any]] = field(default_factory=list)
    #: time.time() when run_batch began
    start_unix: float = 0.0

    @property
    def exit_code(self) -> ExitCode:
        if self.interrupted:
            return ExitCode.ABORTED
        if any(r["status"] in ("error", "criteria failed") for r in self.rows):
            return ExitCode.FAILED
        return ExitCode.OK


def _report_step(id_row: dict | None, dg_row: dict | None, entry: Entry, folder: str, evals: int,
                 seed: int) -> dict:
    """The report of a capture, once its identification (and diagnosis) ended; a row whose steps
    leave identify out reports from the result an earlier batch left in its folder."""
    def refused(why: str) -> dict:
        return {"step": "report", "capture": entry.name, "rc": int(ExitCode.ABORTED), "wall_s": 0.0,
                "error": why, "output": ""}

    if "identify" in entry.steps:
        if id_row is None or id_row.get("rc") not in DONE_CODES:
            return refused("not made: the identification failed")
    else:
        why = tasks.earlier_result_problem(entry, Path(folder))
        if why:
            return refused(f"not made: {why}")
    return tasks.run_step("report", entry, folder, evals, seed)


def _read(path: Path, read: Callable[[Path], R], errors: list[str]) -> R | None:
    """A result or diagnosis the batch wrote (None when absent or unreadable, read bounded); one
    that is not what its name says is an error of the row."""
    if not path.exists():
        return None
    try:
        return read(path)
    except InputError:
        return None
    except FormatError as exc:
        errors.append(str(exc))
        return None


def summary_row(entry: Entry, folder: Path, steps: dict[str, dict], *, skipped: bool = False) -> dict[str, Any]:
    errors = [f"{s}: {r['error']}" for s, r in steps.items() if r.get("error")]
    res = _read(folder / tasks.RESULT, read_result, errors)
    dia = _read(folder / tasks.DIAGNOSIS, read_diagnosis, errors)
    rcs = [r.get("rc") for r in steps.values()]
    status = ("skipped (up to date)" if skipped else "error" if errors or any(rc not in DONE_CODES for rc in rcs)
              else "criteria failed" if ExitCode.FAILED in rcs else "ok")
    rep_out = steps.get("report", {}).get("output", "")
    warnings = [ln.strip() for ln in rep_out.splitlines() if ln.startswith(("WARN:", "FAIL:"))]
    mse = res.mse if res is not None else None
    floor = dia.noise_floor if dia is not None else None
    rel = lambda n: str((folder / n).relative_to(folder.parent)) if (folder / n).exists() else ""  # noqa: E731
    return {"capture": str(entry.capture), "status": status, "mse": mse, "noise_floor": floor,
            "mse_over_floor": (mse / floor) if mse is not None and floor is not None and floor > 0 else None,
            "verdict": dia.verdict if dia is not None else "",
            "explained_by": "+".join(s.name for s in dia.explained_by) if dia is not None else "",
            "warnings": " | ".join(warnings), "result": rel(tasks.RESULT), "diagnosis": rel(tasks.DIAGNOSIS),
            "report": rel(tasks.REPORT), "error": " | ".join(errors),
            "wall_s": round(sum(r.get("wall_s", 0.0) for r in steps.values()), 3),
            "unit": str(entry.unit or "reference unit"), "model": entry.model or "reference"}


def problem_row(entry: Entry, problem: str) -> dict[str, Any]:
    """The summary row of a capture that could not run (a file missing, outside the manifest's
    folder, unreadable): an error, its steps not run, nothing of its files shown."""
    return {"capture": str(entry.capture), "status": "error", "mse": None, "noise_floor": None,
            "mse_over_floor": None, "verdict": "", "explained_by": "", "warnings": "", "result": "",
            "diagnosis": "", "report": "", "error": problem, "wall_s": 0.0,
            "unit": str(entry.unit or "reference unit"), "model": entry.model or "reference"}


def summary_outputs(out: Path, inputs: list[Path | None]) -> Outputs:
    """The guard of the batch's own summary files: never an input (the manifest, a capture), never
    through a link, a folder that can be written. They are the batch's to replace: each run (a
    resumed one too) writes them anew."""
    guard = Outputs(inputs, force=True)
    guard.claim("summary", out / "summary.csv")
    guard.claim("index", out / "index.html")
    return guard


def write_summary(out: Path, rows: list[dict[str, Any]], guard: Outputs | None = None) -> tuple[Path, Path]:
    """summary.csv and index.html (sortable by clicking a column head), each written atomically."""
    import io

    guard = guard or summary_outputs(out, [])
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(SUMMARY_COLUMNS), extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    guard.write_text(out / "summary.csv", buf.getvalue())
    guard.write_text(out / "index.html", _index_html(rows))
    return out / "summary.csv", out / "index.html"


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else ("" if v is None else str(v))


def _index_html(rows: list[dict[str, Any]]) -> str:
    heads = ("capture", "unit", "model", "status", "mse / floor", "verdict", "explained by", "warnings", "report")
    body = []
    for r in rows:
        link = f'<a href="{html.escape(r["report"])}">report</a>' if r.get("report") else ""
        cells = [r["capture"], r.get("unit", ""), r.get("model", ""), r["status"], _fmt(r.get("mse_over_floor")),
                 r.get("verdict", ""), r.get("explained_by", ""), r.get("warnings") or r.get("error", "")]
        body.append("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in cells) + f"<td>{link}</td></tr>")
    return ("<!doctype html><html><head><meta charset='utf-8'><title>bench-ctl batch</title><style>"
            "body{font-family:sans-serif}table{border-collapse:collapse}td,th{border:1px solid #ccc;"
            "padding:3px 6px}th{cursor:pointer;background:#eee}</style></head><body>"
            f"<h1>bench-ctl batch: {len(rows)} captures</h1><table id='runs'><thead><tr>"
            + "".join(f"<th>{h}</th>" for h in heads) + "</tr></thead><tbody>" + "".join(body)
            + "</tbody></table><script>"
            "document.querySelectorAll('#runs th').forEach(function(th,i){th.onclick=function(){"
            "var tb=th.closest('table').tBodies[0],rs=Array.from(tb.rows),up=th.dataset.up!=='1';"
            "th.dataset.up=up?'1':'0';rs.sort(function(a,b){var x=a.cells[i].innerText,y=b.cells[i].innerText,"
            "p=parseFloat(x),q=parseFloat(y);var c=(!isNaN(p)&&!isNaN(q))?p-q:x.localeCompare(y);"
            "return up?c:-c;});rs.forEach(function(r){tb.appendChild(r);});};});"
            "</script></body></html>\n")


class _WarmUp(WorkerPlugin):
    """Dask worker plugin: load the kernel once per worker, before its first task."""

    name = "bench-ctl-kernel"

    def setup(self, worker: Any) -> None:
        worker.bench_ctl_warm_s = tasks.warm_worker()


def _kernel_ready(dask_worker: Any = None) -> float:
    """Seconds the worker spent loading the kernel (runs the warm-up if the plugin has not)."""
    s = getattr(dask_worker, "bench_ctl_warm_s", None)
    if s is None:
        s = tasks.warm_worker()
        if dask_worker is not None:
            dask_worker.bench_ctl_warm_s = s
    return float(s)


def run_batch(manifest: str | Path, out_dir: str | Path, *, scheduler: str | None = None,
              workers: int | None = None, evals: int = 1000, seed: int = 0, progress: bool = True,
              echo: Callable[[str], None] = print, allow_outside: bool = False,
              host: str = LOOPBACK) -> BatchOutcome:
    """Run the manifest (see the module docstring). A row that cannot run (`Entry.problem`, or a
    file gone before it is hashed) is an error row; the others run. Raises ManifestError for a
    manifest that cannot be read, OutputRefused for an output folder that cannot be written
    (both before the cluster starts)."""
    from distributed import Client, as_completed

    t0, t0_unix = time.perf_counter(), time.time()
    notes: list[str] = []
    entries = read_manifest(manifest, allow_outside=allow_outside, notes=notes)
    for note in notes:
        echo(f"note: {note}")
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputRefused(f"--out {out}: {why_not_written(exc, out)}") from None
    guard = summary_outputs(out, [Path(manifest)] + [p for e in entries for p in (e.capture, e.holdout, e.unit)
                                                      if not e.problem])
    cluster = None
    if scheduler:
        client = Client(scheduler)
    else:
        n = workers or os.cpu_count() or 1
        cluster = local_cluster(n, host)
        client = Client(cluster)
    rows: dict[str, dict[str, Any]] = {}
    steps: dict[str, dict[str, dict]] = {e.name: {} for e in entries}
    interrupted = False
    warm: dict[str, float] = {}
    try:
        echo(f"Dask dashboard: {client.dashboard_link}")
        client.register_plugin(_WarmUp())
        warm = client.run(_kernel_ready)
        echo(f"kernel ready on {len(warm)} worker(s): " + ", ".join(f"{v:.1f} s" for v in warm.values()))
        futures = {}
        fps = {}
        for e in entries:
            folder = out / e.name
            if e.problem:
                rows[e.name] = problem_row(e, e.problem)
                continue
            try:
                fp = tasks.fingerprint(e, evals, seed)
            except InputError as exc:   # gone or unreadable since the manifest was read
                rows[e.name] = problem_row(e, f"{Path(exc.file).name}: {exc.reason}")
                continue
            fps[e.name] = fp
            if tasks.is_done(folder, fp):
                rows[e.name] = summary_row(e, folder, {}, skipped=True)
                continue
            f_id = f_dg = None
            if "identify" in e.steps:
                f_id = client.submit(tasks.run_step, "identify", e, str(folder), evals, seed,
                                     key=f"identify-{e.name}-{seed}", pure=False)
                futures[f_id] = e
            if "diagnose" in e.steps:
                f_dg = client.submit(tasks.run_step, "diagnose", e, str(folder), evals, seed,
                                     key=f"diagnose-{e.name}-{seed}", pure=False)
                futures[f_dg] = e
            if "report" in e.steps:
                f_rp = client.submit(_report_step, f_id, f_dg, e, str(folder), evals, seed,
                                     key=f"report-{e.name}-{seed}", pure=False)
                futures[f_rp] = e
        bar = None
        if progress:
            from tqdm import tqdm
            bar = tqdm(total=len(futures), desc="steps", unit="step", file=sys.stderr, disable=None)
        try:
            for fut in as_completed(list(futures)):
                e = futures[fut]
                try:
                    row = fut.result()
                except Exception as exc:  # noqa: BLE001 - a lost worker is a row, not the end
                    step = str(fut.key).split("-")[0]
                    row = {"step": step, "capture": e.name, "rc": int(ExitCode.ABORTED), "wall_s": 0.0, "output": "",
                           "error": f"{type(exc).__name__}: {exc}"}
                steps[e.name][row["step"]] = row
                if bar is not None:
                    bar.update(1)
                if len(steps[e.name]) == len(e.steps):
                    folder = out / e.name
                    rows[e.name] = summary_row(e, folder, steps[e.name])
                    if rows[e.name]["status"] in ("ok", "criteria failed"):
                        tasks.write_done(folder, fps[e.name], list(steps[e.name].values()))
        finally:
            if bar is not None:
                bar.close()
    except KeyboardInterrupt:
        interrupted = True
        echo("interrupted: cancelling the steps not finished; finished results are kept")
        for f in list(locals().get("futures", {})):
            f.cancel()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    ordered = [rows.get(e.name) or summary_row(e, out / e.name, steps[e.name]) | {"status": "not run"}
               for e in entries]
    try:
        csv_path, index = write_summary(out, ordered, guard)
    except OSError as exc:   # the outputs stay where they are; the summary is what failed
        raise OutputRefused(f"the batch's summary was not written ({why_not_written(exc, out / 'summary.csv')}); "
                            f"every capture's own files are in {out}") from None
    return BatchOutcome(ordered, csv_path, index, time.perf_counter() - t0, warm, interrupted,
                        [r for s in steps.values() for r in s.values()], t0_unix)
