"""Simulations per second of a 10 s, 1 kHz record of the reference unit (issue 2, section 6).

Batch sizes 1, 16, 64, 256, on one core and on all cores; the kernel's compile (or cache load)
time is measured apart, in a fresh process state, before any timing. Prints a table; `--json OUT`
writes a flat JSON object whose key `sims_per_s` is the best figure.

    python benchmarks/simulate.py --json bench-out/simulate.json
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numba
import numpy as np

from bench_ctl.engine import run
from bench_ctl.engine.simulate import param_matrix, pulse_usetp
from bench_ctl.units.unit import reference_unit


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--min-seconds", type=float, default=1.0, help="time each configuration at least this long")
    args = ap.parse_args()

    unit = reference_unit()
    t, usetp = pulse_usetp(duration=10.0, rate=1000.0)
    dt = 1e-3
    names = list(unit.identify)
    lo = np.array([b.min for b in unit.identify.values()])
    hi = np.array([b.max for b in unit.identify.values()])
    rng = np.random.default_rng(0)
    base = param_matrix(unit.values())

    t0 = time.perf_counter()
    meas = run(base, usetp, dt, 1.0)["efd"][0]  # first call: compile or load the cache
    compile_s = time.perf_counter() - t0

    all_threads = numba.config.NUMBA_NUM_THREADS
    rows = []
    out: dict[str, float] = {"compile_s": round(compile_s, 3), "cores": os.cpu_count() or 1,
                             "record_samples": int(usetp.size)}
    best = 0.0
    for threads in sorted({1, all_threads}):
        numba.set_num_threads(threads)
        for n in (1, 16, 64, 256):
            # candidates around the reference values (all stable), as an optimizer's population
            X = np.array([200, 1, 0.2, 0.5, 10, 0.02]) * (1 + 0.2 * (rng.random((n, 6)) - 0.5))
            X = np.clip(X, lo, hi)
            P = param_matrix(unit.values(), names, X)
            run(P, usetp, dt, 1.0, measured={"efd": meas}, store=False)  # warm
            calls, start = 0, time.perf_counter()
            while True:
                run(P, usetp, dt, 1.0, measured={"efd": meas}, store=False)
                calls += 1
                elapsed = time.perf_counter() - start
                if elapsed >= args.min_seconds:
                    break
            rate = n * calls / elapsed
            best = max(best, rate)
            rows.append((threads, n, rate, elapsed / calls * 1e3))
            out[f"sims_per_s_threads{threads}_batch{n}"] = round(rate, 1)
    out["sims_per_s"] = round(best, 1)
    out["load_avg_1min"] = round(os.getloadavg()[0], 2)  # other work on the machine skews wall time

    print(f"kernel compile / cache load: {compile_s:.2f} s (excluded below)")
    print(f"{'threads':>7} {'batch':>6} {'sims/s':>10} {'ms/call':>9}")
    for threads, n, rate, ms in rows:
        print(f"{threads:>7} {n:>6} {rate:>10.0f} {ms:>9.2f}")
    print(f"best: {best:.0f} simulations/s of a 10 s, 1 kHz record (target >= 5000); "
          f"load average {out['load_avg_1min']} on {out['cores']} cores")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
