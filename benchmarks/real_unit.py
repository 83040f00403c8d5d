"""A real unit's record against every structure of the library (issue 26 items 3-4): imported with
the tool's own `bench-ctl import` (edges and efd base found, as benchmarks/import_real.py does), then

- the planning record's values run in the kernel on it, when `--dyr` gives one (e.g. the
  repository's own GENSAL + ST5B fit of the unit);
- `bench-ctl identify --model auto` on it (`--evals`, `--seed`): every structure identified from
  its typical values (limits fitted too), on the `.dyr`'s generator (T'd0, T''d0, KPP, KDA,
  saturation) when one is given, checked on the windows it was not fitted on and ranked;
- `--diagnose`: the named structures diagnosed (`bench-ctl diagnose`), what the explanation
  leaves.

Every figure is over the record's own pre-step disturbance (the variance of the pre-step efd
about a straight line: the diagnosis' noise floor). The ranking is the selection's: BIC on the
record plus the check's deviance (a structure with more freedom must earn it on the check).

The Mostar exports (ALSETLab/Mostar) have no licence: give their paths, never copy them here.
Without a path it does nothing and exits 0 (`make bench`).

Usage: python benchmarks/real_unit.py PATH [--dyr PLANT.dyr] [--dyr-ignore PSS2B] [--models all|A,B] [--evals 1000]
           [--seed 1] [--diagnose ESST5B,REFERENCE] [--set NAME=VALUE ...] [--test step:amplitude=0.1]
           [--json OUT]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_ctl.capture import read_capture  # noqa: E402
from bench_ctl.cli import main  # noqa: E402
from bench_ctl.identification.construction import make_problem  # noqa: E402
from bench_ctl.identification.threads import fit_threads  # noqa: E402
from bench_ctl.model.structures import STRUCTURES  # noqa: E402
from bench_ctl.units.dyr_unit import unit_from_dyr  # noqa: E402
from bench_ctl.units.overrides import apply_overrides  # noqa: E402
from bench_ctl.units.unit import reference_unit  # noqa: E402
from import_real import add_import_options, import_one, label, parse_import_args, pre_step_disturbance  # noqa: E402


def main_bench(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("path", nargs="?", type=Path)
    ap.add_argument("--dyr", type=Path, default=None, help="planning record whose values are run as they are")
    ap.add_argument("--dyr-ignore", action="append", default=[], metavar="MODEL",
                    help="leave this record of the unit out (a stabiliser or limiter bench-ctl cannot model, e.g. "
                         "PSS3B or OEL1B, stops the reading unless left out; PSS2A / PSS2B are read)")
    ap.add_argument("--models", default="all",
                    help="structures whose rows are reported (identify --model auto fits every one)")
    ap.add_argument("--evals", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--diagnose", default="", help="comma-separated structures to diagnose as well")
    add_import_options(ap)
    args = parse_import_args(ap, argv)
    out: dict = {"evals": args.evals, "seed": args.seed, "set": ";".join(args.sets)}
    if args.path is None:
        print("no export given: nothing run (python benchmarks/real_unit.py PATH)")
        _save(args, out)
        return 0
    models = list(STRUCTURES) if args.models == "all" else [m.strip().upper() for m in args.models.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        row = import_one(args.path, args, Path(tmp))
        if not row["ok"]:
            print(f"import refused: {row['error']}")
            return 1
        cap = read_capture(Path(tmp) / f"{label(args.path)}.csv")
        var, n = pre_step_disturbance(cap.time, cap.usetp, cap.efd)
        # the model starts where the record does: Vt0 from the record's pre-step vt
        base = apply_overrides(reference_unit(), [*args.sets, f"Vt0={row['vt0_pu']:.6g}"])
        print(f"{args.path.name}: {cap.n} samples at {cap.rate_hz:g} Hz; pre-step disturbance "
              f"{var:.4g} pu^2 over {n} samples; Vt0 {row['vt0_pu']:.4f}, efd factor {row['efd_factor']:.4f}")
        out.update({"file": args.path.name, "disturbance_pu2": var, "vt0_pu": row["vt0_pu"],
                    "efd_factor": row["efd_factor"]})
        generator: list[str] = []
        if args.dyr:
            unit = unit_from_dyr(base, args.dyr, ignore=args.dyr_ignore)
            p = make_problem([cap], unit)
            m = p.mse(p.x_start())[0]
            print(f"{args.dyr.name} ({unit.model}) as it is: mse {m:.4g} pu^2 = {m / var:.1f} x the disturbance")
            out.update({"dyr_model": unit.model, "dyr_mse": m, "dyr_ratio": m / var})
            # every structure then runs on the record's generator (with_model keeps it)
            v = unit.values()
            generator = [f"{k}={v[k]:.8g}" for k in ("Td0p", "Td0pp", "KPP", "KDA", "SATEQ", "S10", "S12")]
            base = apply_overrides(base, generator)
            print("generator from the record: " + ", ".join(generator))
        # `bench-ctl identify --model auto`, as a user runs it: every structure identified, checked
        # and ranked (bench_ctl.identification.selection)
        res = Path(tmp) / "auto.json"
        argv_i = ["identify", str(Path(tmp) / f"{label(args.path)}.csv"), "--model", "auto", "--json", str(res),
                  "--seed", str(args.seed), "--evals", str(args.evals), "--no-progress"]
        for s_ in [*args.sets, f"Vt0={row['vt0_pu']:.6g}", *generator]:
            argv_i += ["--set", s_]
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()) as said, contextlib.redirect_stderr(io.StringIO()):
            rc = main(argv_i)
        wall = time.perf_counter() - t0
        text = said.getvalue()
        print(text[text.find("structure selection"):].rstrip() if "structure selection" in text else text)
        sel = json.loads(res.read_text())["selection"] if res.exists() else {}
        cands = [c for c in sel.get("candidates", []) if models == list(STRUCTURES) or c["model"] in models]
        for c in cands:
            out[f"{c['model']}_mse"] = c["mse"]
            out[f"{c['model']}_ratio"] = c["mse"] / var if c["mse"] is not None else None
            out[f"{c['model']}_check_ratio"] = c["check_mse"] / var if c["check_mse"] is not None else None
            out[f"{c['model']}_fitted"] = c["k"]
            out[f"{c['model']}_score_difference"] = c["score_difference"]
            out[f"{c['model']}_params"] = c.get("params")
        out["ranking"] = [c["model"] for c in cands]
        out["auto_verdict"] = sel.get("verdict")
        out["auto_wall_s"] = wall
        out["auto_exit"] = rc
        print(f"identify --model auto: {wall:.1f} s, exit {rc}; over the pre-step disturbance: " + ", ".join(
            f"{c['model']} fit {c['mse'] / var:.1f}x" for c in cands if c["mse"] is not None))
        for name in [m.strip().upper() for m in args.diagnose.split(",") if m.strip()]:
            res = Path(tmp) / f"diag_{name}.json"
            argv_d = ["diagnose", str(Path(tmp) / f"{label(args.path)}.csv"), "--model", name,
                      "--json", str(res), "--seed", str(args.seed)]
            for s in [*args.sets, f"Vt0={row['vt0_pu']:.6g}", *generator]:
                argv_d += ["--set", s]
            t0 = time.perf_counter()
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                rc = main(argv_d)
            wall = time.perf_counter() - t0
            d = json.loads(res.read_text())
            named = [s["name"] for s in d.get("explained_by") or []]
            left = d["left"]["mse_over_floor"]
            print(f"diagnose --model {name}: verdict {d['verdict']}, explained by {named or 'nothing'}, "
                  f"left {left:.2f} x the noise floor ({wall:.1f} s, exit {rc})")
            out[f"diagnose_{name}_verdict"] = d["verdict"]
            out[f"diagnose_{name}_explained_by"] = named
            out[f"diagnose_{name}_left"] = left
            out[f"diagnose_{name}_wall_s"] = wall
    _save(args, out)
    return 0


def _save(args: argparse.Namespace, out: dict) -> None:
    out["fit_threads"] = fit_threads()
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(out, indent=1, default=str))
        print(f"saved {args.json_out}")


if __name__ == "__main__":
    sys.exit(main_bench())
