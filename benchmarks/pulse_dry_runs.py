"""Pulse accuracy and download time over N dry runs of the no-load pulse test.

Each run is `bench-ctl run no_load_pulse --dry-run` as an engineer would start it (through
`run_procedure`, which starts a fresh embedded simulated bench): +0.05 pu for 1 s, recorded at
1 kHz. Reported against the commanded pulse:

- width_err_ms_*: recorded width (usetp samples away from the baseline x 1 ms) minus 1 s;
  the recorder's 1 kHz sampling quantises it to whole ms;
- host_late_ms_*: how much later than width_s after the pulse request the restore request
  left the host (monotonic clock, taken when the frame is sent);
- amplitude_err_*: recorded amplitude (mean usetp over the pulse minus the baseline) minus
  the commanded one, in pu;
- download_s_*: time to download the stored record (default 10 s: 30 000 words in 251 blocks)
  over the recorder's pseudo-terminal, integrity checks included.

Usage: python benchmarks/pulse_dry_runs.py [--runs 20] [--record-s 10] [--json OUT]
Prints a table; `--json` writes a flat object. Exits 0 when it ran (it reports, it does not
judge; the target is |width error| <= 5 ms).
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_ctl.runner.runner import run_procedure  # noqa: E402

BENCH = ROOT / "benches" / "example.toml"
WIDTH_S, AMPLITUDE_PU = 1.0, 0.05


def _stats(prefix: str, values: list[float]) -> dict[str, float]:
    absv = [abs(v) for v in values]
    return {f"{prefix}_max": max(absv), f"{prefix}_median": statistics.median(absv),
            f"{prefix}_mean_signed": statistics.fmean(values),
            f"{prefix}_min_signed": min(values), f"{prefix}_max_signed": max(values)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--record-s", type=float, default=10.0)
    ap.add_argument("--json", dest="json_out", default=None)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)

    width_ms, late_ms, amp, dl, run_s, codes = [], [], [], [], [], []
    blocks = None
    with tempfile.TemporaryDirectory(prefix="pulse-dry-runs-") as tmp:
        for i in range(args.runs):
            out = run_procedure("no_load_pulse", BENCH, Path(tmp) / f"run{i:02d}", dry_run=True,
                                params={"amplitude_pu": AMPLITUDE_PU, "width_s": WIDTH_S,
                                        "record_s": args.record_s})
            codes.append(out.exit_code)
            if "width_err_s" not in out.data:
                print(f"run {i}: exit {out.exit_code}: {out.message}", file=sys.stderr)
                continue
            d = out.data
            width_ms.append(d["width_err_s"] * 1e3)
            late_ms.append((d["commanded_width_s"] - WIDTH_S) * 1e3)
            amp.append(d["amplitude_err_pu"])
            dl.append(d["download_s"])
            run_s.append(out.duration_s)
            if blocks is None:
                blocks = json.loads(out.raw_path.with_name(out.raw_path.name + ".json")
                                    .read_text())["blocks"]
            print(f"run {i + 1:2d}/{args.runs}: exit {out.exit_code}  width err "
                  f"{width_ms[-1]:+5.1f} ms  host late {late_ms[-1]:6.3f} ms  amplitude err "
                  f"{amp[-1]:+.2e} pu  download {dl[-1]:.2f} s  run {run_s[-1]:.1f} s",
                  flush=True)
    if not width_ms:
        print("no run produced a capture", file=sys.stderr)
        return 0
    result: dict[str, float | int | str] = {
        "runs": args.runs, "runs_measured": len(width_ms), "record_s": args.record_s,
        "width_cmd_s": WIDTH_S, "amplitude_cmd_pu": AMPLITUDE_PU,
        "passed_runs": codes.count(0),
        "width_within_5ms": sum(abs(w) <= 5.0 for w in width_ms),
        **_stats("width_err_ms", width_ms), **_stats("host_late_ms", late_ms),
        **_stats("amplitude_err", amp),
        "download_s": statistics.median(dl), "download_s_max": max(dl),
        "download_blocks": blocks or 0, "run_s_median": statistics.median(run_s),
        "machine": f"{platform.machine()} {os.cpu_count()} cpu, Python {platform.python_version()}",
    }
    print()
    print(f"{'figure':28s} value")
    for key, value in result.items():
        text = f"{value:.4g}" if isinstance(value, float) else str(value)
        print(f"{key:28s} {text}")
    if args.json_out:
        Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json_out).write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.json_out}")
    return 0


if __name__ == "__main__":
    t0 = time.monotonic()
    code = main()
    print(f"total {time.monotonic() - t0:.0f} s")
    sys.exit(code)
