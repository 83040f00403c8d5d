"""The model library against another simulator: ANDES captures (tests/fixtures/andes) of a no-load
GENROU with SEXS, EXST1, ESST1A, IEEEX1, ESST4B, EXAC1, ESAC1A and AC8B exciters (issues 13, 26).

1. Reproduction at the true values: each structure, with the values ANDES used, the setpoint
   edges at their true instants: open loop (the excitation system alone fed ANDES' Vt and Ifd,
   bench_ctl.engine.open_loop) and closed loop (with the kernel's generator from the GENROU data,
   tests/andes_units.py): max and RMS |efd error| over every capture (5, 10, 20 %).
2. Identification: each structure's default identified parameters (gain, time constants) fitted
   by MVMO (1000 evaluations, edge instants fitted) to the 5 % captures with 0.01 pu noise added
   (seeded), the rest of the unit known (data sheet); reported: MSE / noise variance actually in
   the record, and the relative error of every parameter the identifiability analysis calls
   determined (and of the others, marked).
3. Speed: 1000 evaluations of each structure on a 5 s, 1 kHz record (one batched kernel call of
   1000 candidates, median of 5, compile excluded) against the reference structure.

Usage: python benchmarks/model_library.py [--seeds 5] [--evals 1000] [--json OUT]
Prints tables; `--json` writes a flat object. Exits 0 when it ran (it reports, it does not judge).
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import numpy as np  # noqa: E402

from andes_units import fixture_unit, manifest, open_loop_efd, read_fixture, standard_params, true_edges  # noqa: E402
from bench_ctl.capture import Capture  # noqa: E402
from bench_ctl.engine import run  # noqa: E402
from bench_ctl.engine.simulate import param_matrix, pre_trigger_mean, simulate  # noqa: E402
from bench_ctl.identification.identify import run_identification, warm_up  # noqa: E402
from bench_ctl.units.overrides import apply_overrides  # noqa: E402
from bench_ctl.units.unit import reference_unit  # noqa: E402

#: ANDES 2.0's EXST1 limits its washout output (HardLimiter(u=WF_y)), not VA: with KF = 0 its
#: ceilings never act (its 20 % capture reaches 5.1 pu, VRMAX 4.0). Compared with limits wide.
ANDES_QUIRKS = {"EXST1": ["VRMAX=20", "VRMIN=-20"]}


def reproduction(out: dict) -> None:
    print("1. Reproduction of the ANDES captures at the true values (no noise, edges at their true instants)")
    print(f"{'capture':<15}{'open max':>10}{'rms':>9}{'closed max':>12}{'rms':>9}  note")
    worst = {}
    for name in sorted(manifest()["captures"]):
        exc = manifest()["captures"][name]["exciter"]
        unit = fixture_unit(name)
        note = ""
        if exc in ANDES_QUIRKS:
            unit = apply_overrides(unit, ANDES_QUIRKS[exc])
            note = "ANDES' EXST1 ceilings never act: compared with limits wide"
        cap = read_fixture(name)
        spec, off = true_edges(name, cap)
        closed, _, fail = simulate({**unit.values(), **off}, cap.usetp, cap.dt, edges=spec)
        row = []
        for efd in (open_loop_efd(name, unit, cap), closed):
            err = efd - cap.efd
            row += [float(np.max(np.abs(err))), float(np.sqrt(np.mean(err ** 2)))]
        out[f"open_loop_max_{name}"], out[f"open_loop_rms_{name}"] = row[0], row[1]
        out[f"closed_loop_max_{name}"], out[f"closed_loop_rms_{name}"] = row[2], row[3]
        worst[exc] = max(worst.get(exc, 0.0), row[0], row[2])
        print(f"{name:<15}{row[0]:>10.4f}{row[1]:>9.5f}{row[2]:>12.4f}{row[3]:>9.5f}  {note}")
    for exc, w in worst.items():
        out[f"reproduce_worst_max_{exc}"] = w
    print("worst max |efd error| per structure (target <= 0.01 pu): "
          + ", ".join(f"{e} {w:.4f}" for e, w in worst.items()))
    print()


def identification(args: argparse.Namespace, out: dict) -> None:
    print(f"2. Identification on the 5 % captures, 0.01 pu noise, {args.seeds} noise seeds, "
          f"{args.evals} evaluations (MVMO, edges fitted)")
    names = sorted(n for n, c in manifest()["captures"].items() if c["amplitude_of_vt0"] == 0.05)
    by_model: dict[str, list[dict]] = {}
    for name in names:
        entry = manifest()["captures"][name]
        exc = entry["exciter"]
        truth = standard_params(entry)
        unit = fixture_unit(name, true_values=False)
        base = read_fixture(name)
        for seed in range(args.seeds):
            noise = np.random.default_rng([seed, 0xA7D]).normal(0.0, 0.01, base.n)
            cap = Capture(time=base.time, usetp=base.usetp, efd=base.efd + noise, source=f"andes {name}")
            ident = run_identification([cap], unit, max_evals=args.evals, seed=seed)
            r = ident.result
            var = float(np.mean(noise ** 2))
            ratio = float(r.mse) / var
            model = r.model
            errs = {}
            absolute = set()   # a true 0 (ESAC1A's KF: ANDES never feeds it back): the error itself
            for p in model["identified"]:
                v, t = float(model["params"][p]), float(truth[p])
                errs[p] = (v / t - 1.0 if t != 0.0 else v, bool(model["determined"].get(p)))
                if t == 0.0:
                    absolute.add(p)
            det = [abs(e) for p, (e, d) in errs.items() if d and p not in absolute]
            row = {"capture": name, "seed": seed, "ratio": ratio, "wall_s": float(r.wall_s),
                   "worst_determined": max(det) if det else float("nan"), "errors": errs}
            by_model.setdefault(exc, []).append(row)
            cells = "  ".join((f"{p} {e:+.3g} (true 0)" if p in absolute else f"{p} {100 * e:+.1f}%")
                              + ("" if d else "(u)") for p, (e, d) in errs.items())
            print(f"  {name:<14} seed {seed}  mse/noise {ratio:.4f}  {r.wall_s:.2f} s  {cells}", flush=True)
    print()
    print(f"{'model':<8}{'median ratio':>13}{'worst':>8}{'<=1.05':>8}{'worst det. err':>15}{'<=10 %':>8}{'wall s':>8}")
    for exc, rows in by_model.items():
        ratios = [r["ratio"] for r in rows]
        det = [r["worst_determined"] for r in rows if r["worst_determined"] == r["worst_determined"]]
        out[f"median_ratio_{exc}"] = statistics.median(ratios)
        out[f"worst_ratio_{exc}"] = max(ratios)
        out[f"within_5pct_{exc}"] = sum(x <= 1.05 for x in ratios)
        out[f"worst_determined_rel_err_{exc}"] = max(det) if det else None
        out[f"determined_within_10pct_{exc}"] = sum(x <= 0.10 for x in det)
        out[f"cases_{exc}"] = len(rows)
        out[f"median_wall_s_{exc}"] = statistics.median(r["wall_s"] for r in rows)
        print(f"{exc:<8}{statistics.median(ratios):>13.4f}{max(ratios):>8.4f}"
              f"{sum(x <= 1.05 for x in ratios):>5}/{len(rows):<2}"
              f"{(max(det) if det else float('nan')) * 100:>14.1f}%{sum(x <= 0.10 for x in det):>5}/{len(det):<2}"
              f"{statistics.median(r['wall_s'] for r in rows):>8.2f}")
    print("(u): not determined by the capture (identifiability analysis); its error is not judged")
    print()


def speed(out: dict) -> None:
    """1000 evaluations of each structure in one batched kernel call, two populations: drawn in the
    structure's default bounds (log-uniform; an MVMO first generation: many candidates ride a
    limit or need split steps) and within +-20 % of its typical values (a late generation: the
    whole record linear-ish, the kernel's block cost itself). The issue's "within 2x of today's
    structure" is judged on the second: the first also measures how wide each structure's
    default bounds are."""
    print("3. 1000 evaluations (one batched kernel call, 5 s at 1 kHz, median of 5, compile excluded)")
    t = np.arange(5001) * 1e-3
    usetp = 1.0 + 0.05 * ((t >= 1.0) & (t < 2.0))
    efd = np.ones_like(t)
    from bench_ctl.units.overrides import with_model
    ref: dict[str, float] = {}
    print(f"  {'model':<10} {'in bounds':>10} {'ratio':>7} {'failed':>7}   {'near typical':>12} {'ratio':>7}")
    for model in ("REFERENCE", "SEXS", "EXST1", "ESST1A", "IEEEX1", "ESST4B", "ESST5B", "EXAC1", "AC8B"):
        rng = np.random.default_rng(7)
        unit = with_model(reference_unit(), model)
        names = list(unit.identify)
        lo = np.array([b.min for b in unit.identify.values()])
        hi = np.array([b.max for b in unit.identify.values()])
        pos = lo > 0   # log-uniform inside positive bounds, uniform where a bound is 0 (ESST4B's KIR)
        llo, lhi = np.log(np.where(pos, lo, 1.0)), np.log(np.where(pos, hi, np.e))
        X = np.where(pos, np.exp(rng.uniform(llo, lhi, (1000, len(names)))),
                     rng.uniform(lo, hi, (1000, len(names))))
        x0 = np.array([unit.values()[n] for n in names])
        pops = {"bounds": X, "typical": x0 * np.exp(rng.uniform(-0.2, 0.2, (1000, len(names))))}
        row = {}
        for kind, pop in pops.items():
            P = param_matrix(unit.values(), names, pop)
            run(P[:8], usetp, 1e-3, 1.0, measured={"efd": efd}, store=False)  # compile / load the cache
            run(P, usetp, 1e-3, 1.0, measured={"efd": efd}, store=False)      # ... both the serial and parallel paths
            times = []
            for _ in range(5):
                t0 = time.perf_counter()
                res = run(P, usetp, 1e-3, pre_trigger_mean(usetp, 1e-3), measured={"efd": efd}, store=False)
                times.append(time.perf_counter() - t0)
            med = statistics.median(times)
            ref.setdefault(kind, med)
            row[kind] = (med, med / ref[kind], int(np.sum(res["fail_step"] >= 0)))
            out[f"kernel_1000_s_{model}" + ("" if kind == "bounds" else "_typical")] = med
            out[f"kernel_vs_reference_{model}" + ("" if kind == "bounds" else "_typical")] = med / ref[kind]
        (mb, rb, fb), (mt, rt, _) = row["bounds"], row["typical"]
        print(f"  {model:<10} {mb:>8.3f} s {rb:>6.2f}x {fb:>7}   {mt:>10.3f} s {rt:>6.2f}x")
    print("  ratio: of the reference structure on the same kind of population; failed: candidates the kernel "
          "stopped (unstable), cheaper")
    print()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--evals", type=int, default=1000)
    ap.add_argument("--skip", default="", help="comma-separated parts to skip: reproduce,identify,speed")
    ap.add_argument("--json", dest="json_out", default=None)
    args = ap.parse_args(argv)
    skip = set(filter(None, args.skip.split(",")))
    out: dict = {"seeds": args.seeds, "evaluations": args.evals,
                 "andes_version": manifest().get("andes_version")}
    t0 = time.perf_counter()
    out["compile_s"] = warm_up(reference_unit())
    if "reproduce" not in skip:
        reproduction(out)
    if "speed" not in skip:
        speed(out)
    if "identify" not in skip:
        identification(args, out)
    out["total_s"] = time.perf_counter() - t0
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(out, indent=1, sort_keys=True) + "\n", "utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
