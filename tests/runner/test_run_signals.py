"""Signals from the operator's terminal reach the run, not the dry run's simulated bench
(issue 24 item 5), and Ctrl-\\ (SIGQUIT) is handled like SIGTERM (item 4).

`bench-ctl run --dry-run` is started as a terminal would start it (its own process group), and
the signal is sent to the whole group with killpg, as the terminal driver does for Ctrl-C,
Ctrl-\\ and a hang-up. The embedded simulator runs in its own session, so it keeps serving and
the run restores the setpoint against it.
"""
from __future__ import annotations

import os
import signal
import sys

import pytest

from cli_runs import ROOT, audit_rows, start_run, wait_for

PARAMS = ("width_s=1.0", "record_s=2.0", "pre_trigger_s=0.3", "width_tolerance_s=0.02")


def pulse_is_on(audit) -> bool:
    return any(r.get("kind") == "write" and r.get("purpose") == "pulse on" for r in audit_rows(audit))


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGHUP, signal.SIGQUIT],
                         ids=lambda s: signal.Signals(s).name)
def test_a_terminal_signal_to_the_dry_run_group_restores_against_a_living_simulator(tmp_path, sig):
    out = tmp_path / "run"
    argv = [sys.executable, "-m", "bench_ctl.cli", "run", "no_load_pulse", "--bench",
            str(ROOT / "benches" / "example.toml"), "--dry-run", "--out", str(out)]
    for p in PARAMS:
        argv += ["--param", p]
    proc = start_run(argv, start_new_session=True)   # a terminal's foreground group
    try:
        wait_for(lambda: pulse_is_on(out / "audit.jsonl") or proc.poll() is not None, 180,
                 "the pulse", every_s=0.005)
        assert proc.poll() is None, proc.communicate()
        os.killpg(proc.pid, sig)                               # the whole group, as the terminal
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    text = stdout + stderr
    assert proc.returncode == 2, text
    why = "interrupted by the operator (Ctrl-C)" if sig == signal.SIGINT \
        else f"terminated by {signal.Signals(sig).name}"
    assert why in text and "SAFE STATE NOT CONFIRMED" not in text, text
    assert "safe state exciter: setpoint restored by host" in text
    end = audit_rows(out / "audit.jsonl")[-1]
    assert end["kind"] == "run_end" and all(r["ok"] for r in end["safe_state"])
    restore = [r for r in audit_rows(out / "audit.jsonl")
               if r.get("kind") == "write" and r.get("step") == "safe state"
               and r.get("register") == "setpoint"]
    assert restore and restore[0]["matched"]
