"""Accuracy of MVMO against its peers on synthetic captures with random AVR parameters.

For each seed: AVR parameters drawn log-uniformly inside the reference unit's bounds, satisfying
its constraints (TA2 <= TA1, TA4 >= TA2) and physically plausible (closed-loop damping ratio
>= 0.05, |efd| <= 10 pu over the pulse; `synthetic.random_parameters`); a 10 s, 1 kHz capture of the
5 %/1 s pulse recorded with noise 0.01 pu (+ 12-bit quantisation); then each method fits the
reference unit's model at the same budget (default 1000 evaluations), starting where it starts
(local and open-loop: the unit's typical values, which the open-loop method also uses for its
pseudo-measured Vt). Reported per method: MSE / noise variance (noise variance = 0.01^2 +
lsb^2/12), median and worst over the seeds, the count within 5 % of the noise variance, and the
number of fits that break a constraint. Targets (issue 3): MVMO within 5 % in >= 19 of 20
runs, the best median, no violation; the paper's order MVMO <= PowerFactory-like (local) <
Simulink-like (open-loop).

With --near-boundary the truths have TA2 just below TA1 (within 10 %): the constraint is nearly
active and the lead-lag (TA1, TA2) nearly cancels, which is where a positivity-only method
crosses TA2 <= TA1 at no cost in MSE.

Sources (issue 11: never only the model being tested): `independent`, records of the plant in
tests/independent_plant.py (its own integrator and effect code; AVR parameters drawn there; each
setpoint edge at a random instant inside its sample interval, `--edges early` a whole sample early),
and `kernel`, bench_ctl's own synthetic captures (edges on the grid). The ratio is to the noise
actually in each record. `--nominal` adds MVMO with the edge instants assumed on their samples.

Usage: python benchmarks/identify_accuracy.py [--seeds 20] [--evals 1000] [--methods mvmo,de,local,open-loop]
       [--source independent,kernel] [--edges inside|early|on] [--nominal]
       [--mvmo-options '{"particles": 16}'] [--near-boundary] [--duration 10] [--rate 1000]
       [--json OUT] [--csv RUNS.csv]
Prints a table; `--json` writes a flat object. Exits 0 when it ran (it reports, it does not judge).
"""
from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # the independent plant lives with the tests

import numpy as np  # noqa: E402

from bench_ctl.capture import Capture, read_capture  # noqa: E402
from bench_ctl.engine.simulate import RecorderModel  # noqa: E402
from bench_ctl.identification.construction import make_problem  # noqa: E402
from bench_ctl.identification.identify import warm_up  # noqa: E402
from bench_ctl.identification.options import IDENTIFY  # noqa: E402
from bench_ctl.identification.peers import OPTIMIZERS, run_optimizer  # noqa: E402
from bench_ctl.identification.synthetic import noise_variance, random_parameters, synthetic_capture, with_values  # noqa: E402
from bench_ctl.units.overrides import apply_overrides  # noqa: E402
from bench_ctl.units.unit import reference_unit  # noqa: E402


def _key(method: str) -> str:
    return method.replace("-", "_")


def draw_truth(unit, seed: int, args: argparse.Namespace) -> dict[str, float]:
    """Random plausible AVR parameters; with --near-boundary TA2 = TA1 (1 - 0.1 u), so the
    constraint TA2 <= TA1 is nearly active (the situation where the paper's PowerFactory fit
    broke it)."""
    rng = np.random.default_rng([seed, 0xACC])
    while True:
        truth = random_parameters(unit, rng, duration=args.duration, rate=args.rate)
        if not args.near_boundary:
            return truth
        lo, hi = unit.identify["TA2"].min, unit.identify["TA2"].max
        ta2 = truth["TA1"] * (1.0 - 0.1 * rng.random())
        if lo <= ta2 <= hi and ta2 <= truth["TA4"]:
            return {**truth, "TA2": ta2}


def make_case(source: str, unit, seed: int, args: argparse.Namespace):
    """(capture, true AVR parameters, noise variance actually in the record, x_true for the
    kernel's own problem or None) for one seed of `source`."""
    if source == "kernel":
        truth = draw_truth(unit, seed, args)
        cap = synthetic_capture(with_values(unit, truth), duration=args.duration, rate=args.rate,
                                seed=10_000 + seed)
        return cap, truth, noise_variance(RecorderModel()), truth
    if source == "independent":
        import independent_plant as ip  # tests/independent_plant.py: not the kernel
        rng = np.random.default_rng([seed, 0x1D])
        truth = ip.draw_avr(rng)
        dt = 1.0 / args.rate
        test = ip.random_edges(rng, ip.Test(on_s=1.0, width_s=1.0), dt, args.edges)
        rec = ip.Plant(truth).run(test, ip.Recorder(rate_hz=args.rate, duration_s=args.duration,
                                                    noise_pu=0.01, bits=16), seed=20_000 + seed)
        cap = Capture(time=rec.time, usetp=rec.usetp, efd=rec.efd, source=f"independent seed {seed}")
        noise = float(np.mean((rec.efd - rec.truth["efd_clean"]) ** 2))
        return cap, truth, noise, None
    if source == "andes":
        # tests/fixtures/andes (benchmarks/andes_captures.py): the 5 % pulses, each exciter model in turn,
        # 0.01 pu noise added here (seeded); the reference structure is fitted, so a model mismatch shows
        folder = ROOT / "tests" / "fixtures" / "andes"
        manifest = json.loads((folder / "manifest.json").read_text())
        names = sorted(n for n, c in manifest["captures"].items() if c["amplitude_of_vt0"] == 0.05)
        name = names[seed % len(names)]
        cap = read_capture(folder / manifest["captures"][name]["file"])
        noise = np.random.default_rng([seed, 0xA7D]).normal(0.0, 0.01, cap.n)
        return (Capture(time=cap.time, usetp=cap.usetp, efd=cap.efd + noise, source=f"andes {name}"),
                {"exciter": name}, float(np.mean(noise ** 2)), None)
    raise ValueError(f"unknown source {source!r}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--evals", type=int, default=1000)
    ap.add_argument("--methods", default=",".join(OPTIMIZERS))
    ap.add_argument("--source", default="independent,kernel",
                    help="where the captures come from, comma-separated: independent (the plant in "
                         "tests/independent_plant.py, edges off the sample grid), kernel (bench_ctl's own "
                         "model, edges on the grid), andes (tests/fixtures/andes, other exciter structures)")
    ap.add_argument("--edges", default="inside", choices=("inside", "early", "on"),
                    help="independent source: each edge at a random instant inside its sample interval, "
                         "a whole sample early, or on the sample")
    ap.add_argument("--nominal", action="store_true",
                    help="also run MVMO with the edges assumed on their samples (the zero-order hold)")
    ap.add_argument("--mvmo-options", default="{}", help="JSON dict of MVMO options")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--near-boundary", action="store_true",
                    help="truths with TA2 within 10 %% below TA1 (near the constraint, as in the paper)")
    ap.add_argument("--json", dest="json_out", default=None)
    ap.add_argument("--csv", dest="csv_out", default=None, help="per-run rows")
    args = ap.parse_args(argv)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    for m in methods:
        if m not in OPTIMIZERS:
            ap.error(f"unknown method {m!r}; known: {', '.join(OPTIMIZERS)}")
    sources = [x.strip() for x in args.source.split(",") if x.strip()]
    mvmo_options = json.loads(args.mvmo_options)

    unit = reference_unit()
    compile_s = warm_up(unit)
    rows = []
    out: dict[str, float | int | str] = {"seeds": args.seeds, "evaluations": args.evals,
                                         "near_boundary": int(args.near_boundary), "edges": args.edges,
                                         "sources": ",".join(sources), "compile_s": compile_s,
                                         "mvmo_options": json.dumps({**IDENTIFY, **mvmo_options})}
    t_start = time.perf_counter()
    run_methods = methods + (["mvmo-nominal"] if args.nominal else [])
    for source in sources:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            # the truth's stream is kept apart from the optimizers' (which use `seed` itself: MVMO's
            # first generation would otherwise draw the truth exactly)
            cap, truth, var, x_true_values = make_case(source, unit, seed, args)
            # ANDES' generator has S(1.0) 0.05, S(1.2) 0.2: known generator data, given to the unit
            case_unit = apply_overrides(unit, ["S10=0.05", "S12=0.2"]) if source == "andes" else unit
            prob = make_problem([cap], case_unit)
            mse_true = None
            if x_true_values is not None:
                x_true = np.array([x_true_values.get(n, 0.0) for n in prob.names])
                mse_true = float(np.mean(prob.mse(x_true)))
            line = [f"{source:<11} seed {seed:2d}"]
            for m in run_methods:
                p = make_problem([cap], case_unit, fit_edges=False) if m == "mvmo-nominal" else prob
                r = run_optimizer("mvmo" if m == "mvmo-nominal" else m, p, max_evals=args.evals, seed=seed,
                                  options=mvmo_options if m.startswith("mvmo") else None)
                mse = float(np.mean(p.mse(r.x)))
                rows.append({"source": source, "seed": seed, "method": m, "mse": mse, "ratio": mse / var,
                             "ratio_truth": (mse / mse_true) if mse_true else float("nan"),
                             "objective": r.fun, "evaluations": r.nfev, "wall_s": r.wall_s,
                             "violated": ";".join(r.violated),
                             **{f"true_{k}": v for k, v in truth.items()},
                             **{f"fit_{k}": float(v) for k, v in zip(p.names, r.x)}})
                line.append(f"{m} {mse / var:8.4f}{'!' if r.violated else ''}")
            print("  ".join(line), flush=True)
    total_s = time.perf_counter() - t_start
    out["total_s"] = total_s
    print()
    print(f"MSE / noise variance actually in the record, {args.seeds} random AVR parameter sets per source, "
          f"{args.evals} evaluations each, {args.duration:g} s at {args.rate:g} Hz, edges {args.edges} "
          "(independent source)")
    head = (f"{'source':<12}{'method':<13}{'median':>9}{'worst':>10}{'best':>9}{'<=1.05':>8}{'violations':>11}"
            f"{'wall s med':>11}")
    print(head)
    print("-" * len(head))
    for source in sources:
        for m in run_methods:
            rs = [r for r in rows if r["method"] == m and r["source"] == source]
            ratios = [r["ratio"] for r in rs]
            k = f"{source}_{_key(m)}"
            out[f"median_ratio_{k}"] = statistics.median(ratios)
            out[f"worst_ratio_{k}"] = max(ratios)
            out[f"best_ratio_{k}"] = min(ratios)
            out[f"within_5pct_{k}"] = sum(v <= 1.05 for v in ratios)
            out[f"share_within_5pct_{k}"] = sum(v <= 1.05 for v in ratios) / len(ratios)
            out[f"violations_{k}"] = sum(bool(r["violated"]) for r in rs)
            out[f"median_wall_s_{k}"] = statistics.median(r["wall_s"] for r in rs)
            worst_seeds = [r["seed"] for r in sorted(rs, key=lambda r: -r["ratio"]) if r["ratio"] > 1.05]
            out[f"over_5pct_seeds_{k}"] = ",".join(map(str, worst_seeds))
            print(f"{source:<12}{m:<13}{out[f'median_ratio_{k}']:>9.5f}{out[f'worst_ratio_{k}']:>10.4g}"
                  f"{out[f'best_ratio_{k}']:>9.4f}{out[f'within_5pct_{k}']:>5}/{len(rs):<2}"
                  f"{out[f'violations_{k}']:>11}{out[f'median_wall_s_{k}']:>11.2f}")
    print(f"total {total_s:.0f} s")
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(out, indent=1) + "\n")
    if args.csv_out:
        with open(args.csv_out, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
