"""A real unit on line, end to end as a user does it (issue 27): a recorder export of a
voltage-reference step with the unit synchronised, imported with the tool's own `import` (edges
found, P and Q mapped), identified on the grid with the planning record's generator and exciter
(`--from-dyr`) and the grid reactance XE fitted within bounds, then reported.

Made for the public Mostar records (repository ALSETLab/Mostar, no licence: fetch it yourself,
never commit it): the on-line 5 % step `AVR_MR_Step5_CH 1 _ TrendingRecorder @ 9-20-2015
12-55-05 PM.csv` (channels Ug, Uf, If, Ig, P, Q; ~208 Hz, resampled to 200 Hz). The efd channel
records rated-field units; its base is the one `import --efd-base auto` found on the same unit's
no-load step (AVR_PH_Step10: factor 2.9526, i.e. 0.33869 rf = 1 pu), given with --efd-base.

Printed and saved (--json): the efd MSE against the record's own pre-step disturbance (variance
of the pre-step efd about a straight line, as benchmarks/import_real.py), the fitted XE and
exciter values, the RMS error of Vt and Q over the test, and the electromechanical mode in P after
the step, measured and simulated (the report's estimate, `bench_ctl.signals.mode`).

`--diagnose`: then `bench-ctl diagnose` on the same capture and unit, from the identification's
values (`--result`): the verdict, the effects that explain the record together and what is left
(the diagnosis' `left`) over its noise floor; and the last explained_by step's model re-simulated
on the whole record (`diagnosis.last_step_efd`): its efd MSE over the pre-step disturbance, over
the part the diagnosis fitted (on line: from 5 s before the step, `bench_ctl.diagnosis.span`) and
over the whole record (where the operation before the step, which every model holds at its
operating point, dilutes it). XE is fitted in the base model here, so the grid's reactance is no
effect of its.

Without a record it runs nothing and exits 0 (`make bench`).

Usage: python benchmarks/real_online.py RECORD.csv --dyr unit.dyr [--dyr-ignore PSS2B] [--efd-base 0.33869rf]
           [--xe-bounds 0.02,0.8] [--weights vt=100,q=10] [--evals 1000] [--seed 1] [--diagnose] [--held interpolate]
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

import numpy as np  # noqa: E402

from bench_ctl.capture import read_capture  # noqa: E402
from bench_ctl.capture.held import HELD_TREATMENTS  # noqa: E402
from bench_ctl.cli import main  # noqa: E402
from bench_ctl.identification.timing import fitted_edge_plan  # noqa: E402
from bench_ctl.model.dialect import kernel_sections  # noqa: E402
from bench_ctl.report.analysis import simulate_record  # noqa: E402
from bench_ctl.report.inputs import model_values  # noqa: E402
from bench_ctl.signals.edges import Edge  # noqa: E402
from bench_ctl.signals.mode import electromechanical_mode  # noqa: E402
from import_real import MOSTAR_CLOCK, pre_step_disturbance  # noqa: E402

MAPS = ["efd=SFS_Meas_UfRel", "vt=SFS_Meas_UgRel", "p=SFS_Meas_PRel", "q=SFS_Meas_QRel", "ifd=SFS_Meas_IfRel",
        "vr=SFS_Reg_Uc"]


def _run(argv: list[str]) -> tuple[int, str, str, float]:
    out, err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue(), time.perf_counter() - t0


def _last_step_efd(diag: dict, values: dict, result: dict, cap, var: float) -> dict:  # noqa: ANN001
    """The last explained_by step's model re-simulated on the whole record (the report's
    `simulate_record`, on the grid from the record's operating point): its efd MSE over the part
    the diagnosis fitted (`validation.fit`) and over the whole record, each over the pre-step
    disturbance `var`."""
    step = diag["explained_by"][-1]
    kernel = (diag.get("kernel") or {}).get("explained_by_avr_params") or [step.get("avr_params") or {}]
    model = {k: v for k, v in (kernel[-1] or {}).items() if v is not None}
    grid = dict(result["unit"]["grid"])
    grid.update({k: model.pop(k) for k in list(model) if k in grid})
    effect = {k: v for k, v in step["params"].items() if v is not None}
    grid.update({k: effect.pop(k) for k in list(effect) if k in grid})
    edges = [Edge.from_json({k: v for k, v in e.items() if k != "capture"}) for e in diag["edges"]
             if e.get("capture") in (None, "capture")]
    spec, _ = fitted_edge_plan(edges, cap.n)
    offsets = {k: v for k, v in step["edges"].items() if v is not None}
    sim = simulate_record({**values, **model, **effect, **offsets}, cap, grid, spec, "diagnosis")
    t = cap.time - cap.time[0]
    t0, t1 = diag["validation"]["fit"]["t0"], diag["validation"]["fit"]["t1"]
    span = (t >= t0 - 1e-9) & (t <= t1 + 1e-9)
    err2 = (sim["efd"] - cap.efd) ** 2
    mse_span, mse_whole = float(np.mean(err2[span])), float(np.mean(err2))
    return {"effects": step["effects"], "span_s": [t0, t1], "mse_span": mse_span, "mse_whole": mse_whole,
            "over_disturbance_span": mse_span / var, "over_disturbance_whole": mse_whole / var,
            "objective_mse": step["mse"], "objective_over_disturbance": step["mse"] / var}


def main_(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("record", nargs="?", help="the export (none: nothing runs; the data is not in the repository)")
    ap.add_argument("--dyr", help="the unit's planning record (GENSAL/GENROU and its exciter)")
    ap.add_argument("--dyr-ignore", action="append", default=[], metavar="MODEL",
                    help="leave this record of the unit out (--from-dyr stops at a stabiliser or limiter it cannot "
                         "model, e.g. PSS3B or OEL1B, unless left out; PSS2A / PSS2B are read)")
    ap.add_argument("--efd-base", default="0.33869rf")
    ap.add_argument("--test", default="step:amplitude=0.05")
    ap.add_argument("--resample", type=float, default=200.0)
    ap.add_argument("--held", choices=HELD_TREATMENTS, default="keep",
                    help="the import's --held: a channel refreshed slower than the rows kept or interpolated")
    ap.add_argument("--xe-bounds", default="0.02,0.8")
    ap.add_argument("--weights", default="vt=100,q=10", help="signal weights beside efd's 1 (the unit's [weights])")
    ap.add_argument("--evals", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--diagnose", action="store_true", help="then diagnose the record (from the identification)")
    ap.add_argument("--json", dest="json_out", default=None)
    args = ap.parse_args(argv)
    if args.record is None:
        print("no record given: nothing to run (python benchmarks/real_online.py RECORD.csv --dyr unit.dyr)")
        return 0
    if args.dyr is None:
        ap.error("--dyr: the unit's planning record is needed with a record")
    lo, hi = (float(v) for v in args.xe_bounds.split(","))
    sets = [f"XE.min={lo}", f"XE.max={hi}"] + [f"weights.{w}" for w in args.weights.split(",") if w]
    with tempfile.TemporaryDirectory(prefix="real-online-") as tmp:
        cap_path, res_path = Path(tmp) / "cap.csv", Path(tmp) / "result.json"
        imp = ["import", args.record, "-o", str(cap_path), *MOSTAR_CLOCK, "--resample", str(args.resample),
               "--test", args.test, "--efd-base", args.efd_base, "--held", args.held]
        imp += [a for m in MAPS for a in ("--map", m)]
        rc, out, err, imp_s = _run(imp)
        if rc != 0:
            print(f"import refused: {err.strip()}")
            return 1
        print(out.strip())
        ignore = [a for m in args.dyr_ignore for a in ("--dyr-ignore", m)]
        ident = ["identify", str(cap_path), "--from-dyr", args.dyr, *ignore, "--evals", str(args.evals), "--seed",
                 str(args.seed), "--json", str(res_path)] + [a for s in sets for a in ("--set", s)]
        rc, out, err, id_s = _run(ident)
        print(out.strip())
        if not res_path.is_file():
            print(f"identify wrote no result (exit {rc}): {err.strip()}")
            return 1
        cap = read_capture(cap_path)
        result = json.loads(res_path.read_text())
        diag = None
        if args.diagnose:
            diag_path = Path(tmp) / "diagnosis.json"
            rc, out, err, diag_s = _run(["diagnose", str(cap_path), "--from-dyr", args.dyr, *ignore, "--result",
                                         str(res_path),
                                         "--seed", str(args.seed), "--json", str(diag_path)]
                                        + [a for s in sets for a in ("--set", s)])
            print(out.strip())
            if not diag_path.is_file():
                print(f"diagnose wrote no diagnosis (exit {rc}): {err.strip()}")
                return 1
            diag = json.loads(diag_path.read_text())
    var, n_pre = pre_step_disturbance(cap.time, cap.usetp, cap.efd)
    sections = kernel_sections(result)
    values = model_values(sections["params"], sections["fixed"], "result")
    edges = [Edge.from_json(e) for e in result["captures"][0]["edges"]]
    spec, offsets = fitted_edge_plan(edges, cap.n)   # the fitted edge instants
    sim = simulate_record({**values, **offsets}, cap, result["unit"]["grid"], spec, "result")
    lead = float(cap.time[np.flatnonzero(np.abs(cap.usetp - cap.usetp[0]) > 1e-9)[0]])
    test = cap.time >= lead - 1.0
    rms = {s: float(np.sqrt(np.mean((sim[s][test] - cap.columns()[s][test]) ** 2))) for s in ("vt", "q")}
    modes = {name: electromechanical_mode(cap.time, x, lead) for name, x in
             (("measured", cap.channel("p")), ("simulated", sim["p"]))}
    row = {"record": Path(args.record).name, "samples": cap.n, "rate_hz": cap.rate_hz, "import_s": imp_s,
           "identify_s": id_s, "evaluations": result["evaluations"], "mse": result["mse"],
           "pre_step_var_pu2": var, "pre_step_samples": n_pre, "mse_over_disturbance": result["mse"] / var,
           "XE": result["unit"]["grid"].get("XE"), "params": result["params"],
           "rms_vt_pu": rms["vt"], "rms_q_pu": rms["q"], "weights": args.weights, "seed": args.seed}
    for name, m in modes.items():
        row[f"mode_{name}_hz"] = None if m is None else m.frequency_hz
        row[f"mode_{name}_zeta"] = None if m is None else m.damping
    print(f"\nefd MSE {row['mse']:.4g} = {row['mse_over_disturbance']:.2f} x the pre-step disturbance "
          f"({var:.3g} pu^2); XE {row['XE']:.4g} pu; RMS over the test: Vt {rms['vt']:.4g} pu, Q {rms['q']:.4g} pu")
    for name, m in modes.items():
        print(f"mode in P, {name}: " + ("none found" if m is None else
                                       f"{m.frequency_hz:.3f} Hz, damping ratio {m.damping:.3f}"))
    print(f"import {imp_s:.1f} s, identify {id_s:.1f} s ({row['evaluations']} evaluations)")
    if diag is not None:
        left = diag["left"]["mse"]   # after the last step's model was polished once more
        efd_w = float(result["unit"]["weights"].get("efd", 1.0))
        row["diagnosis"] = {"verdict": diag["verdict"], "wall_s": diag_s, "noise_floor": diag["noise_floor"],
                            "base_mse": diag["base"]["mse"], "left_mse": left,
                            "left_over_floor": left / diag["noise_floor"],
                            "explained_by": [{"effect": s["name"], "params": s["params"],
                                              "mse_over_floor": s["mse_over_floor"]} for s in diag["explained_by"]],
                            "not_tried": (diag.get("vocabulary") or {}).get("not_tried"),
                            "weights_efd": efd_w}
        print(f"diagnosis: verdict {diag['verdict']}; base {diag['base']['mse']:.4g}, left {left:.4g} = "
              f"{left / diag['noise_floor']:.2f} x its noise floor ({diag['noise_floor']:.3g}, weighted "
              f"efd + Q); {diag_s:.1f} s")
        if diag["explained_by"]:
            row["diagnosis"]["last_step_efd"] = last = _last_step_efd(diag, values, result, cap, var)
            print(f"the last explained_by step ({'+'.join(last['effects'])}), re-simulated: efd MSE "
                  f"{last['mse_span']:.4g} = {last['over_disturbance_span']:.2f} x the pre-step disturbance over "
                  f"the part diagnosed ({last['span_s'][0]:.2f}-{last['span_s'][1]:.2f} s); over the whole "
                  f"record {last['over_disturbance_whole']:.2f} x (the operation before the step, held at its "
                  f"operating point, counted)")
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(row, indent=1) + "\n")
        print(f"wrote {args.json_out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main_())
