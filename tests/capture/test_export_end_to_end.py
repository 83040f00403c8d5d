"""A real-shaped recorder export, end to end without hand editing (issue 12 item 4): Date and
Time columns, ~4.8 ms jittered steps (a 208 Hz recorder), vendor channel names, efd on the
rated-field base, no setpoint channel (the test described by the user, its edges found within
the stated tolerance). import -> diagnose -> report. The record comes from the independent plant."""
from __future__ import annotations

import datetime as dt
import json

import numpy as np
import pytest

import independent_plant as ip
from bench_ctl.cli import main
from truth import TRUTH

ON, WIDTH, BASE = 1.00213, 1.0, 2.5


def _export(path):
    fine = ip.Plant({**TRUTH, "S10": 0.08, "S12": 0.3}).run(
        ip.Test(on_s=ON, amplitude_pu=0.10, width_s=WIDTH),
        ip.Recorder(rate_hz=4000.0, duration_s=6.0, noise_pu=0.0, bits=0))
    rng = np.random.default_rng(7)
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.0046, 0.0050, 1200))])
    t = t[t < 5.9]
    efd = np.interp(t, fine.time, fine.truth["efd_clean"]) + rng.normal(0.0, 0.01, t.size)
    t0 = dt.datetime(2026, 3, 14, 9, 26, 53)
    lines = ["Date;Time;EFD_FLD_pu;IFD_FLD_pu"]
    for ti, e in zip(t, efd):
        ts = t0 + dt.timedelta(seconds=float(ti))
        lines.append(f"{ts:%Y-%m-%d};{ts:%H:%M:%S.%f};{e / BASE:.5f};0")
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.slow
def test_a_recorder_export_imports_diagnoses_and_reports(tmp_path):
    _export(tmp_path / "export.csv")
    assert main(["import", str(tmp_path / "export.csv"), "-o", str(tmp_path / "cap.csv"), "--delimiter", ";",
                 "--map", "efd=EFD_FLD_pu", "--date-column", "Date", "--clock-column", "Time",
                 "--efd-scale", str(BASE), "--resample", "1000",
                 "--test", "pulse:start=1.0,amplitude=0.1,width=1.0,tolerance=0.012"]) == 0
    side = json.loads((tmp_path / "cap.json").read_text())
    assert side["import"]["efd_base_scale"] == BASE and side["import"]["usetp_synthesised"] is True
    assert side["import"]["test"]["edge_tolerance_s"] == 0.012
    # 1: the base model's report fails its criteria (the saturation it lacks); the diagnosis says why
    assert main(["diagnose", str(tmp_path / "cap.csv"), "--json", str(tmp_path / "d.json"),
                 "--report", str(tmp_path / "r.html")]) in (0, 1)
    d = json.loads((tmp_path / "d.json").read_text())
    edges = [e for e in d["edges"] if e["capture"] == "capture"]
    assert [e["how"] for e in edges] == ["described", "described"]
    # the user said 1.000 s and 2.000 s; the unit stepped at 1.00213 s and 2.00213 s
    assert abs(edges[0]["fitted_s"] - ON) < 1.5e-3 and abs(edges[1]["fitted_s"] - (ON + WIDTH)) < 1.5e-3
    assert "saturation" in [s["name"] for s in d["explained_by"]]
    html = (tmp_path / "r.html").read_text(encoding="utf-8")
    assert 'id="diagnosis-explained-by"' in html and 'id="edge-timing"' in html
