"""Real recorder exports through the tool's own `bench-ctl import` (issue 26 item 1): the test's
edges found in the record (no setpoint channel), the efd base found (`--efd-base auto`), and the
record's own pre-step disturbance, per file.

Each PATH is imported as a user would (`bench_ctl.cli.main(["import", PATH, ...])`, into a
temporary folder), with the column names of a trending-recorder export (the defaults are the
Mostar commissioning exports' SFS_* columns: ALSETLab/Mostar, which has no licence: give the
files' paths, never copy them here) and the unit's saturation (default S10 = 0.1, S12 = 0.48: the
repository's GENSAL values S(1.0) = 0.1, S(1.2) = 0.4 relative, 1.2 x 0.4 absolute). Printed and
saved (`--json`) per file:

- the channel the edges were found in, each edge's instant and uncertainty (s), and the tolerance
  every fit then searches within; the amplitude vt shows against the stated one;
- the efd base factor (source units -> model pu), Vt0 and the no-load efd it aims at, the quarter
  spread of the pre-step efd; the ifd factor;
- the pre-step disturbance: the variance of the pre-step efd (model pu) about a straight line,
  the samples before the first setpoint change less 2 (the definition of the diagnosis' noise
  floor, bench_ctl/identification/localize.py), and its standard deviation.

Usage: python benchmarks/import_real.py PATH... [--test step:amplitude=0.1] [--resample 200] [--held interpolate]
           [--map NAME=COLUMN ...] [--set S10=0.1 --set S12=0.48] [--json OUT]
Exits 0 when every file imported (or none was given: `make bench` runs it without files), 1 when
one was refused (its reason printed), 2 on bad options.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from bench_ctl.capture import read_capture  # noqa: E402
from bench_ctl.capture.held import HELD_TREATMENTS  # noqa: E402
from bench_ctl.cli import main  # noqa: E402

MOSTAR_MAPS = ["efd=SFS_Meas_UfRel", "vt=SFS_Meas_UgRel", "vr=SFS_Reg_Uc", "ifd=SFS_Meas_IfRel"]
MOSTAR_CLOCK = ["--date-column", "date", "--clock-column", "time", "--date-format", "%d.%m.%Y"]
GUARD = 2


def label(path: Path) -> str:
    """A short name for the JSON keys: the export's name up to its channel suffix."""
    stem = re.split(r"_CH\s|\s_\s|@", path.stem)[0]
    return re.sub(r"[^A-Za-z0-9]+", "_", stem).strip("_") or "file"


def pre_step_disturbance(time_s: np.ndarray, usetp: np.ndarray, efd: np.ndarray) -> tuple[float, int]:
    """Variance of the efd before the first setpoint change (less GUARD samples) about a straight
    line (ddof 2), and the samples used."""
    moved = np.flatnonzero(np.abs(usetp - usetp[0]) > 1e-12)
    n = (int(moved[0]) if moved.size else usetp.size) - GUARD
    t, y = time_s[:n], efd[:n]
    res = y - np.polyval(np.polyfit(t, y, 1), t)
    return float(np.sum(res * res) / (n - 2)), n


def import_one(path: Path, args: argparse.Namespace, folder: Path) -> dict:
    out = folder / f"{label(path)}.csv"
    argv = ["import", str(path), "-o", str(out), *MOSTAR_CLOCK, "--resample", str(args.resample),
            "--test", args.test, "--efd-base", "auto", "--scale", "ifd=auto", "--held", args.held]
    for m in args.maps or MOSTAR_MAPS:
        argv += ["--map", m]
    for s in args.sets:
        argv += ["--set", s]
    buf_out, buf_err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buf_out), contextlib.redirect_stderr(buf_err):
        rc = main(argv)
    wall = time.perf_counter() - t0
    if rc != 0:
        return {"ok": False, "error": buf_err.getvalue().strip(), "wall_s": wall}
    cap = read_capture(out)
    imp = cap.meta["import"]
    found, base, ifd = imp["edges_found"], imp["efd_base"], imp.get("ifd_base") or {}
    var, n = pre_step_disturbance(cap.time, cap.usetp, cap.efd)
    row = {"ok": True, "wall_s": wall, "console": buf_out.getvalue().strip(),
           "channel": found["channel"], "imported_as": found["imported_as"],
           "tolerance_s": found["tolerance_s"], "noise_channel": found["noise"],
           "vt_ratio": found["amplitude_check"].get("ratio"),
           "efd_factor": base["factor"], "vt0_pu": base["vt0_pu"], "no_load_pu": base["no_load_pu"],
           "pre_quarter_spread_rel": base["pre_step"]["quarter_spread_rel"],
           "ifd_factor": ifd.get("factor"), "pre_step_var_pu2": var, "pre_step_std_pu": var ** 0.5,
           "pre_step_samples": n, "rate_hz": cap.rate_hz, "samples": cap.n}
    for e in found["edges"]:
        row[f"{e['edge']}_s"] = e["instant_s"]
        row[f"{e['edge']}_uncertainty_s"] = e["uncertainty_s"]
    return row


def add_import_options(ap: argparse.ArgumentParser) -> None:
    """The import's options (`import_one` reads them), shared with benchmarks/real_unit.py."""
    ap.add_argument("--test", default="step:amplitude=0.1")
    ap.add_argument("--resample", type=float, default=200.0, help="Hz (the exports are jittered)")
    ap.add_argument("--held", choices=HELD_TREATMENTS, default="keep",
                    help="the import's --held (a channel refreshed slower than the rows)")
    ap.add_argument("--map", dest="maps", action="append", default=None, metavar="NAME=COLUMN")
    ap.add_argument("--set", dest="sets", action="append", default=None, metavar="NAME=VALUE",
                    help="unit values (default: the Mostar unit's S10=0.1, S12=0.48)")
    ap.add_argument("--json", dest="json_out", default=None)


def parse_import_args(ap: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    args = ap.parse_args(argv)
    if args.sets is None:
        args.sets = ["S10=0.1", "S12=0.48"]
    return args


def main_bench(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("paths", nargs="*", type=Path)
    add_import_options(ap)
    args = parse_import_args(ap, argv)
    out: dict = {"test": args.test, "resample_hz": args.resample, "set": ";".join(args.sets)}
    if not args.paths:   # `make bench` runs every benchmark without arguments: nothing to import
        print("no export given: nothing imported (python benchmarks/import_real.py PATH...)")
    failed = 0
    with tempfile.TemporaryDirectory() as tmp:
        for path in args.paths:
            row = import_one(path, args, Path(tmp))
            name = label(path)
            print(f"== {name}  ({path.name})")
            if not row["ok"]:
                failed += 1
                print(f"   refused: {row['error']}")
                out[f"{name}_ok"] = False
                continue
            print("   " + row["console"].replace("\n", "\n   "))
            edges = ", ".join(f"{k[:-2]} {row[k]:.4f} +- {row[k[:-2] + '_uncertainty_s']:.4f} s"
                              for k in ("leading_s", "trailing_s") if k in row)
            print(f"   edges in {row['channel']}: {edges}; fits search +- {row['tolerance_s']:.4f} s; "
                  f"vt / stated amplitude {row['vt_ratio']:.3f}")
            print(f"   efd factor {row['efd_factor']:.4f} (Vt0 {row['vt0_pu']:.4f}, no-load efd "
                  f"{row['no_load_pu']:.4f} pu, pre-step quarter spread {100 * row['pre_quarter_spread_rel']:.2f} %); "
                  f"ifd factor {row['ifd_factor']:.4f}")
            print(f"   pre-step disturbance: variance {row['pre_step_var_pu2']:.4g} pu^2 "
                  f"(std {row['pre_step_std_pu']:.4g} pu) over {row['pre_step_samples']} samples at "
                  f"{row['rate_hz']:g} Hz; import {row['wall_s']:.2f} s")
            for k, v in row.items():
                if k != "console" and not isinstance(v, (dict, list)):
                    out[f"{name}_{k}"] = v
    out["files"] = len(args.paths)
    out["refused"] = failed
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(out, indent=1) + "\n")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main_bench())
