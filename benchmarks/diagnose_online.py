"""The gap diagnosis on line, on records another simulator made: ANDES' on-line captures
(tests/fixtures/andes_online, benchmarks/andes_online.py: a GENROU through XE to an infinite bus,
SEXS or ESST1A, a +2 % reference step held 5 s) -- issue 27, item 5.

Each capture gets recorder noise (0.01 pu on efd, 0.002 pu on Q, 0.0005 pu on Vt; seeded) and is
diagnosed against the unit as ANDES ran it (generator, exciter at its true values as the start of
the identified ones), in three cases:
- `true`: the unit's XE is the grid's. Expected: `none`.
- `xe_half`, `xe_double`: the unit file's XE is half or twice the grid's. Expected:
  `grid_reactance`, with the grid's XE found.
- a capture with `_pss` in its name holds an active stabiliser (ANDES' IEEEST) the unit file does
  not have. Expected: `pss` (its fitted gain and lead-lags printed; the manifest has ANDES'); with
  the unit's XE wrong as well, `explained_by` must hold exactly `grid_reactance` and `pss`.

Printed per case: the verdict, the expected one, the effects explained_by adds with their
parameters, the error left over the noise floor (the diagnosis' `left`), the base model's error
over it, and the time.
`--json` writes the rows and the tally.

Usage: python benchmarks/diagnose_online.py [--only sexs_xe02,...] [--cases true,xe_half,xe_double]
           [--seeds 1] [--json OUT]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from andes_units import online_capture, online_entry, online_manifest, online_unit  # noqa: E402
from bench_ctl.diagnosis import diagnose  # noqa: E402
from bench_ctl.units.overrides import apply_overrides  # noqa: E402

NOISE = {"noise": 0.01, "q_noise": 0.002, "vt_noise": 0.0005}
XE_FACTOR = {"true": 1.0, "xe_half": 0.5, "xe_double": 2.0}


def run_case(name: str, case: str, seed: int) -> dict:
    entry = online_entry(name)
    xe = float(entry["xe_pu"])
    cap = online_capture(name, seed=seed, **NOISE)
    unit = online_unit(name)
    if case != "true":
        unit = apply_overrides(unit, [f"XE={xe * XE_FACTOR[case]:.6g}"])
    pss = "_pss" in name
    expected = ("pss" if case == "true" else "grid_reactance+pss") if pss else \
        ("none" if case == "true" else "grid_reactance")
    t0 = time.perf_counter()
    d = diagnose(cap, unit, seed=seed).to_json()
    wall = time.perf_counter() - t0
    final = d["explained_by"][-1] if d["explained_by"] else None
    xe_found = (final or {}).get("params", {}).get("XE")
    return {"capture": name, "case": case, "seed": seed, "xe_true": xe, "xe_unit": float(unit.grid["XE"]),
            "expected": expected, "verdict": d["verdict"],
            "named": (d["verdict"] == expected if "+" not in expected else
                      sorted(s["name"] for s in d["explained_by"]) == expected.split("+")),
            "explained_by": [{"effect": s["name"], "params": s["params"], "mse_over_floor": s["mse_over_floor"]}
                             for s in d["explained_by"]],
            "xe_found": xe_found, "xe_rel_err": None if xe_found is None else abs(xe_found / xe - 1.0),
            "base_over_floor": d["base"]["mse"] / d["noise_floor"],
            "left_over_floor": d["left"]["mse_over_floor"],   # the last model, polished once more
            "noise_floor": d["noise_floor"], "wall_s": wall}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=None, help="captures (default: all in the manifest)")
    ap.add_argument("--cases", default="true,xe_half,xe_double")
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--json", dest="json_out", default=None)
    args = ap.parse_args(argv)
    m = online_manifest()
    names = args.only.split(",") if args.only else sorted(m["captures"]) + sorted(m["pss_captures"])
    cases = args.cases.split(",")
    bad = set(cases) - set(XE_FACTOR)
    if bad:
        ap.error(f"unknown case(s) {sorted(bad)}; known: {', '.join(XE_FACTOR)}")
    rows = []
    print(f"{'capture':<18}{'case':<10}{'seed':>4}  {'expected':<19}{'verdict':<15}{'base/floor':>11}"
          f"{'left/floor':>11}{'XE unit':>8}{'XE found':>9}{'wall s':>8}")
    for name in names:
        for case in cases:
            for seed in range(args.seeds):
                r = run_case(name, case, seed)
                rows.append(r)
                xf = "-" if r["xe_found"] is None else f"{r['xe_found']:.4f}"
                print(f"{name:<18}{case:<10}{seed:>4}  {str(r['expected']):<19}{r['verdict']:<15}"
                      f"{r['base_over_floor']:>11.3f}{r['left_over_floor']:>11.3f}{r['xe_unit']:>8.3g}{xf:>9}"
                      f"{r['wall_s']:>8.1f}")
                for s in r["explained_by"]:
                    print(f"{'':<36}+ {s['effect']}: " + ", ".join(f"{k}={v:.4g}" for k, v in s["params"].items()
                                                                 if v is not None))
    tally = {"named": sum(r["named"] for r in rows), "judged": len(rows),
             "wall_s_max": max((r["wall_s"] for r in rows), default=None),
             "wall_s_mean": sum(r["wall_s"] for r in rows) / len(rows) if rows else None}
    print(f"\nnamed as expected: {tally['named']}/{tally['judged']}; wall mean {tally['wall_s_mean']:.1f} s, "
          f"max {tally['wall_s_max']:.1f} s")
    if args.json_out:
        Path(args.json_out).write_text(json.dumps({"noise": NOISE, "rows": rows, "tally": tally}, indent=1) + "\n")
        print(f"wrote {args.json_out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
