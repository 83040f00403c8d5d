"""Speed of the machine on the grid against the no-load kernel (issue 27: 1000 evaluations of an
on-line 10 s record at 1 ms <= 2x the no-load figure).

For each structure (default SEXS, ESST1A): one batched call of N candidates (default 1000, the
structure's identified parameters drawn uniformly within +-20 % of its typical values, seeded)
over a 10 s, 1 kHz record with a 2 % reference step held from 1 s: the no-load kernel
(`run_kernel`) and the machine on the grid (`online.run_online`, the typical GENROU through
XE = 0.2 at P = 0.8), both with a measured efd (the identification's fast path, no traces),
median of --repeat runs. Compile or cache load is measured first and excluded, and printed.

Usage: python benchmarks/online_speed.py [--models SEXS,ESST1A] [--candidates 1000] [--repeat 3] [--json OUT]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numba  # noqa: E402
import numpy as np  # noqa: E402

from bench_ctl.model import online  # noqa: E402
from bench_ctl.model.kernel import run_kernel  # noqa: E402
from bench_ctl.model.simulate import param_matrix  # noqa: E402
from bench_ctl.model.unit import reference_unit, with_model  # noqa: E402


def _population(model: str, n: int, seed: int) -> np.ndarray:
    unit = with_model(reference_unit(), model)
    names = list(unit.identify)
    x0 = np.array([unit.identify[k].value for k in names])
    rng = np.random.default_rng(seed)
    X = x0 * rng.uniform(0.8, 1.2, size=(n, len(names)))
    return param_matrix(unit.values(), names, X)


def _time(fn, repeat: int) -> float:
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t0)
    return statistics.median(runs)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="SEXS,ESST1A")
    ap.add_argument("--candidates", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", dest="json_out", default=None)
    args = ap.parse_args(argv)
    dt, n = 1e-3, 10001
    usetp = np.ones(n)
    usetp[1000:] += 0.02
    meas = np.ones(n)
    M = online.machine_matrix(online.TYPICAL_MACHINE)
    t0 = time.perf_counter()
    P1 = _population("SEXS", 1, args.seed)
    run_kernel(P1, usetp[:4], dt, 1.0, efd_meas=meas[:4], store=False)
    online.warm_up(P1)
    compile_s = time.perf_counter() - t0
    out: dict = {"candidates": args.candidates, "record_s": (n - 1) * dt, "threads": numba.get_num_threads(),
                 "compile_or_load_s": compile_s, "load_average": os.getloadavg()[0]}
    print(f"compile / cache load {compile_s:.1f} s (excluded); {args.candidates} candidates, 10 s at 1 kHz, "
          f"{numba.get_num_threads()} threads, load {os.getloadavg()[0]:.2f}")
    print(f"{'model':<10}{'no load s':>11}{'on line s':>11}{'ratio':>8}")
    for model in args.models.split(","):
        P = _population(model, args.candidates, args.seed)
        Mn = np.repeat(M, P.shape[0], axis=0)
        no_load = _time(lambda P=P: run_kernel(P, usetp, dt, 1.0, efd_meas=meas, store=False), args.repeat)
        on_line = _time(lambda P=P, Mn=Mn: online.run_online(P, Mn, usetp, dt, 1.0, measured={"efd": meas},
                                                             store=False), args.repeat)
        out[f"{model}_no_load_s"] = no_load
        out[f"{model}_on_line_s"] = on_line
        out[f"{model}_ratio"] = on_line / no_load
        print(f"{model:<10}{no_load:>11.3f}{on_line:>11.3f}{on_line / no_load:>7.1f}x")
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(out, indent=1) + "\n")
        print(f"wrote {args.json_out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
