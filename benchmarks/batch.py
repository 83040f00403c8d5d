"""Fleet throughput: N captures identified and diagnosed on a 2-worker Dask LocalCluster against
the same captures serially in one process (issue 14).

Captures: the independent plant (tests/independent_plant.py) with random AVR parameters, 5 %/1 s
pulses, edges inside their sample intervals, 0.01 pu noise. Reported: wall time serial and on
the cluster, speedup end to end and over the window in which tasks ran, where the cluster's wall
time went (before the first task: client and the kernel loaded on each worker; the task window;
after the last task), how busy each worker was in the window, how much slower a task runs beside
another than alone (cache and memory contention of this VM), overhead per task ((window x workers
- sum of task times) / sum of task times), the first task's wait for the kernel on each worker,
peak RSS per worker, and captures per hour. Kernel compilation is excluded from both timings
(warm caches, stated apart).

Usage: python benchmarks/batch.py [--captures 40] [--workers 2] [--duration 10] [--evals 1000]
       [--json OUT]
Prints a table; `--json` writes a flat object. Exits 0 when it ran (it reports, it does not judge).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import numpy as np  # noqa: E402


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def make_captures(folder: Path, n: int, duration: float, seed: int) -> Path:
    import independent_plant as ip

    lines = ["capture,steps"]
    for i in range(n):
        rng = np.random.default_rng([seed, i])
        test = ip.random_edges(rng, ip.Test(on_s=1.0, width_s=1.0), 1e-3, "inside")
        rec = ip.Plant(ip.draw_avr(rng)).run(test, ip.Recorder(duration_s=duration), seed=i)
        rec.write_csv(folder / f"cap{i:03d}.csv")
        lines.append(f"cap{i:03d}.csv,identify+diagnose")
    (folder / "manifest.csv").write_text("\n".join(lines) + "\n")
    return folder / "manifest.csv"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--captures", type=int, default=40)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--evals", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", dest="json_out", default=None)
    args = ap.parse_args(argv)

    from distributed import Client

    from bench_ctl.fleet import tasks
    from bench_ctl.fleet.batch import local_cluster, run_batch
    from bench_ctl.fleet.manifest import read_manifest

    work = Path(tempfile.mkdtemp(prefix="bench-ctl-batch-"))
    t0 = time.perf_counter()
    manifest = make_captures(work, args.captures, args.duration, args.seed)
    gen_s = time.perf_counter() - t0
    entries = read_manifest(manifest)
    compile_s = tasks.warm_worker()

    # serial, in this process (numba on one thread, as each cluster worker)
    os.environ["NUMBA_NUM_THREADS"] = "1"
    import numba
    numba.set_num_threads(1)
    t0 = time.perf_counter()
    serial_tasks = []
    for e in entries:
        for step in e.steps:
            serial_tasks.append(tasks.run_step(step, e, str(work / "serial" / e.name), args.evals, args.seed))
    serial_s = time.perf_counter() - t0
    serial_rss = _peak_rss_mb()

    with local_cluster(args.workers) as cluster:
        outcome = run_batch(manifest, work / "cluster", scheduler=cluster.scheduler_address, evals=args.evals,
                            seed=args.seed, progress=False, echo=lambda s: None)
        with Client(cluster.scheduler_address) as client:
            rss = client.run(_peak_rss_mb)
    cluster_s = outcome.wall_s
    task_s = sum(r.get("wall_s", 0.0) for r in serial_tasks)
    steps = outcome.step_rows
    task_cluster_s = sum(float(r["wall_s"]) for r in steps)
    n_tasks = len(serial_tasks)
    # where the cluster's wall time went: before the first task (client, kernel load on each
    # worker), the window in which tasks ran, after the last one (summary, client close)
    first = min(r["start_unix"] for r in steps)
    last = max(r["end_unix"] for r in steps)
    window_s = last - first
    busy = {}
    for r in steps:
        busy[r["pid"]] = busy.get(r["pid"], 0.0) + float(r["wall_s"])
    same = 0
    for e in entries:
        a = json.loads((work / "serial" / e.name / tasks.RESULT).read_text())
        b = json.loads((work / "cluster" / e.name / tasks.RESULT).read_text())
        strip = lambda d: {k: v for k, v in d.items() if k not in tasks.VOLATILE_KEYS}  # noqa: E731
        same += strip(a)["params"] == strip(b)["params"] and a["mse"] == b["mse"]
    out = {
        "captures": args.captures, "workers": args.workers, "duration_s": args.duration, "evals": args.evals,
        "tasks": n_tasks, "generate_s": gen_s, "compile_s": compile_s,
        "serial_s": serial_s, "cluster_s": cluster_s, "speedup": serial_s / cluster_s,
        "speedup_with_kernel_load": (serial_s + compile_s) / cluster_s,
        "before_first_task_s": first - outcome.start_unix, "task_window_s": window_s,
        "after_last_task_s": cluster_s - (last - outcome.start_unix),
        "speedup_task_window": serial_s / window_s,
        "worker_busy_pct_min": 100.0 * min(busy.values()) / window_s,
        "task_slowdown_cluster_vs_serial": task_cluster_s / task_s,
        "overhead_per_task_pct": 100.0 * (window_s * args.workers - task_cluster_s) / task_cluster_s,
        "mean_task_s": task_s / n_tasks, "first_task_wait_s_max": max(outcome.warm_s.values()),
        "peak_rss_mb_worker_max": max(rss.values()), "peak_rss_mb_serial": serial_rss,
        "results_identical": same, "captures_per_hour_cluster": 3600.0 * args.captures / cluster_s,
        "statuses": ",".join(sorted({r["status"] for r in outcome.rows})),
        "load_avg_1min": os.getloadavg()[0],
    }
    print(f"{args.captures} captures (identify + diagnose), {args.duration:g} s records, {args.evals} evaluations")
    for k in ("serial_s", "cluster_s", "speedup", "speedup_with_kernel_load", "before_first_task_s",
              "task_window_s", "after_last_task_s", "speedup_task_window", "worker_busy_pct_min",
              "task_slowdown_cluster_vs_serial", "overhead_per_task_pct", "mean_task_s", "first_task_wait_s_max",
              "peak_rss_mb_worker_max", "peak_rss_mb_serial", "results_identical", "captures_per_hour_cluster",
              "compile_s", "load_avg_1min"):
        v = out[k]
        print(f"  {k:<28}{v:>12.3f}" if isinstance(v, float) else f"  {k:<28}{v:>12}")
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
