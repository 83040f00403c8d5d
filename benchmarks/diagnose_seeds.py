"""One diagnosis whatever the seed (issue 49 item 5): a real unit's record imported once with the
tool's own `bench-ctl import` (as benchmarks/real_unit.py does), then `bench-ctl diagnose --model M`
on it at every seed, from the structure's typical values on the planning record's generator
(`--dyr`), exactly the `--diagnose M` step of real_unit.py without its `identify --model auto`.

Printed and saved (`--json`) per seed: the verdict, the effects of `explained_by` in order, what is
left over the noise floor (the record's pre-step disturbance) and the wall time; then the tally
against the targets: left within `--within` x at >= 9 of 10 seeds, the same first effect (the most
frequent one) at >= 8 of 10.

The Mostar exports (ALSETLab/Mostar) have no licence: give their paths, never copy them here.
Without a path it does nothing and exits 0 (`make bench`).

Usage: python benchmarks/diagnose_seeds.py PATH --dyr PLANT.dyr [--dyr-ignore PSS2B] [--model ESST5B]
           [--seeds 0-9] [--within 5] [--set NAME=VALUE ...] [--test step:amplitude=0.1] [--json OUT]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_ctl.cli import main  # noqa: E402
from bench_ctl.identification.threads import fit_threads  # noqa: E402
from bench_ctl.units.dyr_unit import unit_from_dyr  # noqa: E402
from bench_ctl.units.overrides import apply_overrides  # noqa: E402
from bench_ctl.units.unit import reference_unit  # noqa: E402
from import_real import add_import_options, import_one, label, parse_import_args  # noqa: E402


def _seeds(text: str) -> list[int]:
    if "-" in text:
        a, b = (int(v) for v in text.split("-"))
        return list(range(a, b + 1))
    return [int(v) for v in text.split(",")]


def main_bench(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("path", nargs="?", type=Path)
    ap.add_argument("--dyr", type=Path, default=None, help="planning record: the generator every fit runs on")
    ap.add_argument("--dyr-ignore", action="append", default=[], metavar="MODEL")
    ap.add_argument("--model", default="ESST5B", help="the structure diagnosed")
    ap.add_argument("--seeds", default="0-9", help="A-B or A,B,C")
    ap.add_argument("--within", type=float, default=5.0, help="target: left at most this x the noise floor")
    add_import_options(ap)
    args = parse_import_args(ap, argv)
    out: dict = {"model": args.model, "seeds": _seeds(args.seeds), "rows": [], "fit_threads": fit_threads()}
    if args.path is None:
        print("no export given: nothing run (python benchmarks/diagnose_seeds.py PATH --dyr PLANT.dyr)")
        _save(args.json_out, out)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        row = import_one(args.path, args, Path(tmp))
        if not row["ok"]:
            print(f"import refused: {row['error']}")
            return 1
        sets = [*args.sets, f"Vt0={row['vt0_pu']:.6g}"]
        if args.dyr:
            unit = unit_from_dyr(apply_overrides(reference_unit(), sets), args.dyr, ignore=args.dyr_ignore)
            v = unit.values()
            sets += [f"{k}={v[k]:.8g}" for k in ("Td0p", "Td0pp", "KPP", "KDA", "SATEQ", "S10", "S12")]
        out.update({"file": args.path.name, "set": sets})
        cap = Path(tmp) / f"{label(args.path)}.csv"
        print(f"{args.path.name}: diagnose --model {args.model}, " + ", ".join(sets))
        for seed in out["seeds"]:
            res = Path(tmp) / f"diag_{seed}.json"
            argv_d = ["diagnose", str(cap), "--model", args.model, "--json", str(res), "--seed", str(seed)]
            for s in sets:
                argv_d += ["--set", s]
            t0 = time.perf_counter()
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                rc = main(argv_d)
            wall = time.perf_counter() - t0
            d = json.loads(res.read_text())
            named = [s["name"] for s in d.get("explained_by") or []]
            left = d["left"]["mse_over_floor"]
            out["rows"].append({"seed": seed, "verdict": d["verdict"], "explained_by": named, "left": left,
                                "base_over_floor": d["base"]["mse"] / d["noise_floor"], "wall_s": wall,
                                "exit": rc})
            print(f"seed {seed}: verdict {d['verdict']}, explained by {named or 'nothing'}, left {left:.2f} x "
                  f"(base {d['base']['mse'] / d['noise_floor']:.2f} x), {wall:.1f} s", flush=True)
    rows = out["rows"]
    firsts = Counter(r["explained_by"][0] if r["explained_by"] else "none" for r in rows)
    first, n_first = firsts.most_common(1)[0]
    within = sum(r["left"] <= args.within for r in rows)
    out.update({"first_effect": first, "same_first": n_first, "within": within, "runs": len(rows),
                "within_x": args.within})
    print(f"left within {args.within:g}x at {within}/{len(rows)} seeds; first effect {first} at "
          f"{n_first}/{len(rows)} ({dict(firsts)}); {sum(r['wall_s'] for r in rows) / len(rows):.1f} s a run")
    _save(args.json_out, out)
    return 0


def _save(path: str | None, out: dict) -> None:
    if path:
        Path(path).write_text(json.dumps(out, indent=1))
        print(f"saved {path}")


if __name__ == "__main__":
    sys.exit(main_bench())
