"""Blind suite of the gap diagnosis: captures with a withheld effect, diagnosed and scored (issue 7).

Each case: the reference unit with random AVR parameters (log-uniform in the unit's bounds,
satisfying its constraints, realistic pulse response) and one effect at a random, visible but
plausible magnitude (`bench_ctl.diagnosis.blind.draw_effect`), or no effect; a main capture of
the 5 %/1 s pulse and a holdout capture of a 0.5 s or 1.5 s pulse, 10 s at 1 kHz by default,
recorder noise 0.01 pu + 12-bit quantisation. The diagnosis sees the two captures and the
reference unit file only.

Reported: the confusion matrix (rows: withheld effect, columns: verdict), `top1` (share of the
effect cases whose verdict is the withheld effect), `none_correct` (effect-free cases with
verdict none, out of `none_cases`), `none_with_explained_by` (effect-free cases with a non-empty
explained_by), `median_gap_closed` (median over the effect cases of the withheld effect's holdout
gap_closed), for two-effect cases (`--effects a+b,...`) `pair_both_explained` (both withheld
effects in explained_by), `seconds_per_capture` (mean wall time of one diagnosis, kernel
compilation excluded). Targets (issues 11, 12): top1 >= 0.95, none >= 90 %, median gap >= 0.8,
with and without the holdout; two effects both explained in >= 80 %, effect-free records with
an explained_by in <= 10 %; <= 10 s per capture.

Sources (issue 11): `--source independent` (default) draws the cases from the plant in
tests/independent_plant.py, written apart from the kernel, each setpoint edge at a random instant
inside its sample interval (`--edges early`: a whole sample early); `--source andes` from the
captures another simulator made (tests/andes_cases.py: the ANDES fixtures diagnosed with their
own structure; the effects ANDES' records can carry: saturation, ceiling_limit, recorder_gain,
time_skew, none; no holdout, the check is the record's windows); `--source kernel` from
bench_ctl's own model (edges on the samples).

Usage: python benchmarks/diagnose_blind.py [--cases-per-effect 10] [--none-cases 10] [--seed 0]
       [--source independent|andes|kernel] [--edges inside|early|on] [--effects a,b,c+d]
       [--rate 1000] [--duration 10] [--no-holdout] [--json OUT] [--csv CASES.csv]
Prints per-case lines and the table; exits 0 when it ran (it reports, it does not judge).
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # the independent plant lives with the tests

from bench_ctl.diagnosis import diagnose  # noqa: E402
from bench_ctl.diagnosis.blind import NONE, SuiteConfig, make_case, make_suite, run_suite, score  # noqa: E402
from bench_ctl.identification.threads import fit_threads  # noqa: E402
from bench_ctl.model.effects import EFFECT_NAMES  # noqa: E402
from bench_ctl.units.unit import load_unit  # noqa: E402


def confusion_table(conf: dict[str, dict[str, int]]) -> str:
    labels = list(EFFECT_NAMES) + [NONE]
    short = {n: n[:8] for n in labels}
    corner = "truth \\ verdict"
    head = f"{corner:<16}" + "".join(f"{short[n]:>9}" for n in labels)
    lines = [head, "-" * len(head)]
    for t in labels:
        row = conf[t]
        if not sum(row.values()):
            continue
        lines.append(f"{t:<16}" + "".join(f"{row[p] if row[p] else '.':>9}" for p in labels))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases-per-effect", type=int, default=10)
    ap.add_argument("--none-cases", type=int, default=None, help="effect-free cases (default: as many as per effect)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rate", type=float, default=1000.0, help="sample rate of the captures (Hz)")
    ap.add_argument("--duration", type=float, default=10.0, help="record length (s)")
    ap.add_argument("--no-holdout", action="store_true", help="diagnose without the holdout capture "
                    "(fit / check split inside the record)")
    ap.add_argument("--source", default="independent", choices=("independent", "andes", "kernel"),
                    help="independent: cases from tests/independent_plant.py (not the kernel); andes: the "
                         "ANDES fixtures (tests/andes_cases.py: saturation, ceiling_limit, recorder_gain, "
                         "time_skew, none; no holdout); kernel: bench_ctl's own synthetic captures")
    ap.add_argument("--edges", default="inside", choices=("inside", "early", "on"),
                    help="independent source: each setpoint edge inside its sample interval, a whole sample "
                         "early, or on the sample")
    ap.add_argument("--effects", default=None, help="comma-separated effects (default all eight); "
                    "a+b withholds two at once")
    ap.add_argument("--one-regime", action="store_true",
                    help="independent source: each effect's evidence in one regime of the record (saturation "
                         "seen on the plateau, a ceiling reached on the leading edge only; tests/independent_plant.py "
                         "draw_one_regime); effects default to those two")
    ap.add_argument("--json", dest="json_out", default=None)
    ap.add_argument("--csv", dest="csv_out", default=None, help="one row per case")
    args = ap.parse_args(argv)
    cfg = SuiteConfig(rate_hz=args.rate, duration_s=args.duration)
    none_cases = args.cases_per_effect if args.none_cases is None else args.none_cases

    t0 = time.perf_counter()
    if args.one_regime and args.source != "independent":
        ap.error("--one-regime draws from the independent plant (--source independent)")
    default_effects = ["saturation", "ceiling_limit"] if args.one_regime else list(EFFECT_NAMES)
    effects = [e.strip() for e in args.effects.split(",")] if args.effects else default_effects
    if args.source == "andes":
        from andes_cases import EFFECTS, andes_suite
        cases = andes_suite(args.cases_per_effect, none_cases, seed=args.seed,
                            effects=effects if args.effects else list(EFFECTS))
    elif args.source == "independent":
        from independent_cases import independent_suite
        cases = independent_suite(args.cases_per_effect, none_cases, seed=args.seed, effects=effects, cfg=cfg,
                                  edges=args.edges, one_regime=args.one_regime)
    else:
        cases = make_suite(args.cases_per_effect, none_cases, seed=args.seed, effects=effects, cfg=cfg)
    t_gen = time.perf_counter() - t0
    warm = make_case(NONE, 10**6 + args.seed, cfg)  # compile the kernel outside the timing
    t0 = time.perf_counter()
    diagnose(warm.capture, load_unit(None), holdout=warm.holdout)
    t_warm = time.perf_counter() - t0
    print(f"{len(cases)} cases generated in {t_gen:.1f} s; warm-up diagnosis {t_warm:.1f} s "
          f"(includes kernel compilation when not cached)", flush=True)

    def progress(r) -> None:
        mark = "ok " if r.verdict == r.truth else "BAD"
        gap = "-" if r.gap_closed_holdout is None else f"{r.gap_closed_holdout:.3f}"
        print(f"{mark} {r.case_id:<22} verdict {r.verdict:<15} gap {gap:>7}  {r.seconds:5.1f} s  "
              f"cpu {r.cpu_seconds:5.1f} s  ranking {','.join(r.ranking[:3])}  "
              f"explained_by {'>'.join(r.explained) or '-'}  "
              f"ambiguous {r.ambiguous or '-'}", flush=True)

    def diag(capture, unit, holdout=None, seed=0):
        return diagnose(capture, unit, holdout=None if args.no_holdout else holdout, seed=seed)

    results = run_suite(cases, diag, seed=args.seed, progress=progress)
    s = score(results)
    print()
    print(confusion_table(s["confusion"]))
    print()
    if s["effect_cases"]:
        print(f"top1                 {s['top1']:.3f}  ({s['top1_correct']}/{s['effect_cases']}; target >= 0.95)")
    if s["none_cases"]:
        print(f"none_correct         {s['none_correct']}/{s['none_cases']}  (target >= 90 %); with a non-empty "
              f"explained_by: {s['none_with_explained_by']} (target <= 10 %)")
    if s["median_gap_closed"] is not None:
        print(f"median_gap_closed    {s['median_gap_closed']:.3f}  (holdout; target >= 0.8)")
    if s["pair_cases"]:
        print(f"two-effect cases     both effects in explained_by: {s['pair_both_explained']}/{s['pair_cases']} "
              f"(target >= 80 %); by pair: {s['pair_by_kind']}")
    print(f"seconds_per_capture  {s['seconds_per_capture']:.1f}  (max {max(r.seconds for r in results):.1f}; "
          f"CPU {s['cpu_seconds_per_capture']:.1f} s, both threads counted)")
    if args.json_out:
        flat = {k: v for k, v in s.items() if k != "confusion"}
        flat.update({"confusion": s["confusion"], "seed": args.seed, "cases_per_effect": args.cases_per_effect,
                     "source": args.source, "edges": args.edges if args.source == "independent" else "on",
                     "rate_hz": args.rate, "duration_s": args.duration,
                     "holdout": not args.no_holdout and args.source != "andes", "one_regime": args.one_regime,
                     "seconds_max": max(r.seconds for r in results), "fit_threads": fit_threads()})
        Path(args.json_out).write_text(json.dumps(flat, indent=1) + "\n", encoding="utf-8")
    if args.csv_out:
        with open(args.csv_out, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(["case", "truth", "verdict", "gap_closed_holdout", "seconds", "cpu_seconds", "ranking",
                        "sequence", "ambiguous", "explained_by"])
            for r in results:
                w.writerow([r.case_id, r.truth, r.verdict, r.gap_closed_holdout, f"{r.seconds:.2f}",
                            f"{r.cpu_seconds:.2f}", " ".join(r.ranking), " ".join(r.sequence),
                            " ".join("/".join(a) for a in r.ambiguous), " ".join(r.explained)])
    return 0


if __name__ == "__main__":
    sys.exit(main())
