"""Structure selection (`identify --model auto`) on records another simulator made: the ANDES
captures (tests/fixtures/andes) of a no-load GENROU (S(1.0) 0.05, S(1.2) 0.2) with a standard
exciter (issue 26, item 3).

Each capture gets recorder noise (0.01 pu on efd, 0.002 pu on Vt, seeded) and is given to the
selection as a commissioning engineer would hold it without knowing the exciter: the generator's
data sheet (T'd0, T''d0, the GENROU flux shares, its saturation) and nothing of the exciter. Every
candidate structure starts from its typical values (its limits, TR, KC, ... at the library's
typical values; only its default identified parameters are fitted). Reported per capture: the
ranking (score difference to the best, fit and check over the noise floor), whether the true
structure is first or named equivalent to the first (or its pulse twin, `Structure.pulse_twin`,
the same equations on a pulse test, is), and the time.

Usage: python benchmarks/select_structure.py [--captures sexs_05pct,...] [--models SEXS,...]
       [--evals 1000] [--seed 0] [--json OUT]
Prints a table; `--json` writes the per-capture rankings. Exits 0 when it ran (it reports).
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

import numpy as np  # noqa: E402

from andes_units import fixture_column, generator_values, manifest, read_fixture  # noqa: E402
from bench_ctl.capture import Capture  # noqa: E402
from bench_ctl.identification.candidates import auto_models, free_limits  # noqa: E402
from bench_ctl.identification.identify import warm_up  # noqa: E402
from bench_ctl.identification.selection import select_structure  # noqa: E402
from bench_ctl.identification.threads import fit_threads  # noqa: E402
from bench_ctl.model.structures import STRUCTURES  # noqa: E402
from bench_ctl.units.overrides import apply_overrides, with_model  # noqa: E402
from bench_ctl.units.unit import reference_unit  # noqa: E402


def candidate_units(models: list[str], limits: str) -> dict:
    """Every candidate in its structure at typical values, on the fixtures' generator; its
    limits identified too with `limits` "free" (`candidates.free_limits`)."""
    g = generator_values(manifest()["generator_params"])
    base = apply_overrides(reference_unit(), [f"{k}={g[k]}" for k in ("Td0p", "Td0pp", "KPP", "KDA")])
    base = base.with_effects({"saturation": {"S10": g["S10"], "S12": g["S12"]}})
    units = {m: with_model(base, m) for m in models}
    return {m: free_limits(u) for m, u in units.items()} if limits == "free" else units


def noisy(name: str, seed: int) -> Capture:
    base = read_fixture(name)
    rng = np.random.default_rng([seed, 0x5E1E])
    return Capture(base.time, base.usetp, base.efd + rng.normal(0.0, 0.01, base.n),
                   base.vt + rng.normal(0.0, 0.002, base.n), extra={"ifd": fixture_column(name, "ifd")},
                   source=f"andes-{name}", meta={"source": f"ANDES fixture {name} (tests/fixtures/andes)"})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--captures", default=",".join(sorted(manifest()["captures"])))
    ap.add_argument("--models", default=",".join(auto_models()),
                    help="candidates (default: those of --model auto, one of each pair of pulse twins)")
    ap.add_argument("--evals", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--limits", choices=("free", "typical"), default="free",
                    help="the candidates' limits identified (free) or held at their typical values")
    ap.add_argument("--json", dest="json_out", default=None)
    args = ap.parse_args(argv)
    names = [c for c in args.captures.split(",") if c]
    models = [m for m in args.models.split(",") if m]
    units = candidate_units(models, args.limits)
    t0 = time.perf_counter()
    warm_up(next(iter(units.values())))
    compile_s = time.perf_counter() - t0
    rows, hits = [], 0
    for name in names:
        truth = manifest()["captures"][name]["exciter"]
        cap = noisy(name, args.seed)
        t = time.perf_counter()
        sel = select_structure([cap], units, max_evals=args.evals, seed=args.seed)
        wall = time.perf_counter() - t
        j = sel.entry().to_json()
        first = sel.best.model
        named = {first, *sel.equivalent}
        # the truth, or its pulse twin (the same equations on a pulse test) standing for it
        hit = truth in named or any(STRUCTURES[m].pulse_twin == truth or STRUCTURES[truth].pulse_twin == m
                                    for m in named)
        hits += hit
        order = " > ".join(f"{c['model']}({c['score_difference']:+.0f}, fit {c['x_floor']:.3g}x, "
                           f"check {c['check_x_floor'] or float('nan'):.3g}x)"
                           for c in j["candidates"] if c["x_floor"] is not None)
        print(f"{name:<14} truth {truth:<7} first {first:<9} {'OK ' if hit else 'MISS'} {wall:6.1f} s  "
              f"equivalent {','.join(sel.equivalent) or '-'}\n    {order}", flush=True)
        rows.append({"capture": name, "truth": truth, "first": first, "hit": bool(hit),
                     "equivalent": list(sel.equivalent), "wall_s": wall, "selection": j})
    out = {"benchmark": "select_structure", "source": "andes", "evals": args.evals, "seed": args.seed,
           "limits": args.limits, "fit_threads": fit_threads(),
           "models": models, "captures": len(rows), "hits": hits,
           "hit_rate": hits / len(rows) if rows else None, "compile_s": compile_s,
           "mean_wall_s": float(np.mean([r["wall_s"] for r in rows])) if rows else None,
           "command": "python benchmarks/select_structure.py " + " ".join(argv or sys.argv[1:]), "rows": rows}
    print(f"true structure first (or named equivalent): {hits}/{len(rows)}; "
          f"{out['mean_wall_s']:.1f} s per capture (compile {compile_s:.1f} s)")
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(out, indent=1, default=float), "utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
