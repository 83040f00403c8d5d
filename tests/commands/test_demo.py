"""`bench-ctl demo`: the whole job on the embedded simulated bench, end to end (the main job)."""
from __future__ import annotations

import json

import pytest

from bench_ctl.capture import read_capture
from bench_ctl.cli import main


@pytest.mark.slow
def test_demo_writes_every_artifact_and_fits(tmp_path, capsys):
    out = tmp_path / "demo"
    rc = main(["demo", "--out", str(out), "--evals", "400"])
    printed = capsys.readouterr().out
    if rc == 1 and "this host sent the restore write" in printed:
        # the pulse procedure measured its own restore write leaving more than the width tolerance
        # (5 ms) late: the machine stalled (a VM does, for up to ~30 ms, see benchmarks/sim_latency.py)
        # and the test failed as a real one should; nothing about the product is shown either way
        pytest.skip("host stalled at the restore deadline: "
                    + next(line for line in printed.splitlines() if "this host sent" in line)[:300])
    assert rc == 0, printed
    for name in ("capture.csv", "capture.json", "audit.jsonl", "result.json", "diagnosis.json", "report.html"):
        assert (out / name).is_file(), name
        assert str(out / name) in printed          # the paths are printed
    cap = read_capture(out / "capture.csv")
    assert cap.n == 10000 and abs(cap.dt - 1e-3) < 1e-12   # 10 s at 1 kHz
    result = json.loads((out / "result.json").read_text())
    assert all(c["satisfied"] for c in result["constraints"])
    # the simulated recorder adds 0.01 pu noise: a good fit sits at the noise variance
    assert 0.8e-4 < result["mse"] < 1.2e-4
    assert {r["optimizer"] for r in result["comparison"]} == {"mvmo", "de", "local", "open-loop"}
    # the result and diagnosis name their capture relative to their own folder: the demo folder
    # can be moved or reported on from any working directory
    assert [c["path"] for c in result["captures"]] == ["capture.csv"]
    diag = json.loads((out / "diagnosis.json").read_text())
    assert diag["capture"]["path"] == "capture.csv"
    assert diag["verdict"] == "none"                  # the simulated unit has no effect switched on
    audit = [json.loads(line) for line in (out / "audit.jsonl").read_text().splitlines()]
    assert audit
    html = (out / "report.html").read_text()
    assert "data:image/png;base64," in html and "http://" not in html and "https://" not in html
    # what the engineer reads: the identified parameters, the verdict, engineering values
    assert "identified: KAVR " in printed and "report verdict: PASS" in printed
    assert "setpoint restored (raw): 1.0000 pu, pre-test 1.0000 pu (register words identical)" in printed
    # a second run into the same folder is refused: captures are never overwritten
    assert main(["demo", "--out", str(out), "--evals", "400"]) == 2


@pytest.mark.slow
def test_demo_online_runs_the_reference_step_end_to_end(tmp_path, capsys):
    out = tmp_path / "demo-online"
    rc = main(["demo", "--online", "--out", str(out)])   # the budget a user runs
    printed = capsys.readouterr().out
    # the demo exits with its report's verdict; on line the report's numeric acceptance of efd is
    # noise-limited (the after window's MXE near 0.05 of a 2 % step's efd change with 0.01 pu noise),
    # so the verdict may be FAIL on that figure alone: the exit code must say so, nothing else fails
    verdict = next(line for line in printed.splitlines() if "report verdict:" in line)
    failed = [line.strip() for line in printed.splitlines() if line.strip().startswith("FAIL:")]
    assert all("numeric acceptance" in line and "MXE" in line for line in failed), printed
    assert rc == (1 if "FAIL" in verdict else 0), printed
    for name in ("capture.csv", "capture.json", "audit.jsonl", "result.json", "diagnosis.json", "report.html"):
        assert (out / name).is_file(), name
    # the embedded plant is the kernel's own machine: nothing is missing from the model
    assert json.loads((out / "diagnosis.json").read_text())["verdict"] == "none" and "verdict: none" in printed
    cap = read_capture(out / "capture.csv")
    assert {"p", "q", "ifd"} <= set(cap.columns()) and cap.meta["test"]["online"] is True
    result = json.loads((out / "result.json").read_text())
    # fitted on efd, Vt and Q of the unit on the grid: efd at the recorder's noise (0.01 pu)
    assert 0.8e-4 < result["mse"] < 1.3e-4
    html = (out / "report.html").read_text()
    assert "On line: P, Q, Vt and efd" in html
    assert "unit inside its bands" in printed and "online_step: PASSED" in printed


def test_the_demo_exits_with_the_reports_verdict():
    """Issue 48 item 15: `demo --online --evals 100` printed "report verdict: FAIL" and exited 0."""
    from types import SimpleNamespace

    from bench_ctl.commands.demo import demo_exit
    from bench_ctl.report.checks import FAIL

    fit = SimpleNamespace(constraints_violated=[], failed=False)
    assert demo_exit(fit, FAIL) == 1
    assert demo_exit(fit, "PASS") == 0 and demo_exit(fit, "PASS WITH WARNINGS") == 0
    assert demo_exit(SimpleNamespace(constraints_violated=["TA2 <= TA1"], failed=False), "PASS") == 1
    assert demo_exit(SimpleNamespace(constraints_violated=[], failed=True), "PASS") == 1


@pytest.mark.slow
def test_demo_online_with_a_small_budget_exits_as_its_report_says(tmp_path, capsys):
    out = tmp_path / "demo-small"
    rc = main(["demo", "--online", "--out", str(out), "--evals", "100"])
    printed = capsys.readouterr().out
    verdict = next((line for line in printed.splitlines() if "report verdict:" in line), None)
    if verdict is None and rc == 1 and "[FAIL] step hold error" in printed:
        # the on-line step measured its own hold off by more than its tolerance: the machine stalled
        # in real time (as test_demo_writes_every_artifact_and_fits skips it), no analysis was made
        pytest.skip("host stalled during the on-line step: "
                    + next(line for line in printed.splitlines() if "step hold error" in line).strip())
    assert verdict is not None, printed
    assert rc == (1 if "FAIL" in verdict else 0), printed
