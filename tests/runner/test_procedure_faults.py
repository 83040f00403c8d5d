"""Faults during the pulse test, each asserting the end state of the DEVICE (simulator) and of
the run (exit code, message, audit, files kept).

Faults are injected deterministically: at the `pulse_applied` moment the procedure announces
right after the pulse write was read back (link cut by the wire proxy, Ctrl-C as a real
SIGINT), or by the simulator's fault injection (exception reply, corrupted serial bytes).
What reached the device is read from the wire proxy and the simulator's event log, not from
the drivers' own records.
"""
from __future__ import annotations

import os
import signal
import time

import pytest

from bench_ctl.commands.run import print_outcome
from bench_ctl.runner.audit import read_audit
from bench_ctl.runner.runner import run_procedure
from pulse_bench import MODE_ADDR, SETPOINT_ADDR, SP_1_00, SP_1_05, bench_config, device_writes
from simulators.bench import SimBench
from wire_proxy import WireProxy

# short but real: 0.3 s pulse inside a 1.5 s record
FAST = {"pre_trigger_s": 0.2, "record_s": 1.5, "width_s": 0.3, "recovery_timeout_s": 3.0,
        "width_tolerance_s": 0.02}
PULSE_AND_RESTORE = [(MODE_ADDR, [3]), (SETPOINT_ADDR, SP_1_05), (SETPOINT_ADDR, SP_1_00),
                     (MODE_ADDR, [1])]


def wait_for(cond, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


def sim_and_proxy(**sim_kw):
    sim = SimBench(**sim_kw)
    sim.start()
    return sim, WireProxy(sim.endpoints.exciter_tcp)


#: the host side of a 0.5 s device watchdog: beats every 0.1 s, and a request timeout short
#: enough that a timed write (0.1 + 0.2 + 0.1 s guard) cannot hold the beats off for 0.5 s
FAST_HOST = {"heartbeat_period_s": 0.1, "timeout_s": 0.2}


@pytest.fixture
def fast_watchdog_bench():
    """The exciter's watchdog at 0.5 s (the host beats every 0.1 s)."""
    sim, proxy = sim_and_proxy(heartbeat_timeout_s=0.5)
    yield sim, proxy
    proxy.close()
    sim.stop()


def events(sim: SimBench) -> list[tuple[str, float]]:
    return [(kind, round(value, 4)) for _, kind, value in sim.exciter.events]


def audit_kinds(out) -> list[str]:
    return [r["kind"] for r in read_audit(out.audit_path)]


def test_link_cut_during_pulse_restored_after_reconnect(bench, tmp_path):
    sim, proxy = bench
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                        params=FAST, hooks={"pulse_applied": lambda run: proxy.cut(0.6)})
    assert out.exit_code == 3 and out.status == "communication error"
    assert out.safe_state[0].ok
    assert out.safe_state[0].action == "setpoint restored by host after reconnect"
    assert "setpoint restored by host after reconnect" in out.message
    assert device_writes(proxy) == PULSE_AND_RESTORE
    assert events(sim) == [("remote", 1.0), ("setpoint", 1.05), ("setpoint", 1.0),
                           ("local", 1.0)]
    assert not sim.exciter.watchdog_tripped
    assert out.audit_path.exists() and "run_end" in audit_kinds(out)


def test_link_cut_longer_than_the_watchdog_restored_by_the_device(fast_watchdog_bench,
                                                                   tmp_path):
    sim, proxy = fast_watchdog_bench
    out = run_procedure("no_load_pulse", bench_config(proxy, sim, exciter=FAST_HOST), tmp_path,
                        yes=True, params=FAST, hooks={"pulse_applied": lambda run: proxy.cut(1.5)})
    assert out.exit_code == 3
    assert out.safe_state[0].ok
    assert out.safe_state[0].action == "setpoint restored by the device watchdog"
    assert "restored by the device watchdog" in out.message
    # nothing was written after the pulse: the device reverted by itself and went local
    assert device_writes(proxy) == PULSE_AND_RESTORE[:2]
    assert events(sim) == [("remote", 1.0), ("setpoint", 1.05), ("watchdog", 1.0)]


def test_restore_that_fails_is_loud_and_the_watchdog_takes_over(fast_watchdog_bench,
                                                                tmp_path):
    sim, proxy = fast_watchdog_bench
    cfg = bench_config(proxy, sim, exciter=FAST_HOST, restore_deadline_s=0.4)
    out = run_procedure("no_load_pulse", cfg, tmp_path, yes=True, params=FAST,
                        hooks={"pulse_applied": lambda run: proxy.cut(2.0)})
    assert out.exit_code == 3 and not out.safe
    assert out.safe_state[0].action == "SETPOINT NOT RESTORED"
    assert out.message.startswith("SAFE STATE NOT CONFIRMED")
    assert "CHECK THE UNIT" in out.message
    ends = [r for r in read_audit(out.audit_path) if r["kind"] == "run_end"]
    assert ends[0]["exit_code"] == 3 and ends[0]["safe_state"][0]["ok"] is False
    # the host stopped its heartbeat, so the device's watchdog reverts the setpoint
    wait_for(lambda: sim.exciter.watchdog_tripped, 3.0, "the device watchdog")
    assert sim.exciter.setpoint == pytest.approx(1.0)


def test_refused_restore_stops_the_heartbeat_so_the_watchdog_reverts_at_once(fast_watchdog_bench,
                                                                           tmp_path):
    """The exciter answers exception 6 to every setpoint write after the pulse-on: the host must
    stop its heartbeat at the first refused restore, so the device's watchdog (0.5 s) reverts
    the setpoint, instead of holding the pulse for the restore deadline (3 s) plus the watchdog."""
    sim, proxy = fast_watchdog_bench

    def refuse(run) -> None:
        sim.faults.set("exception", device="exciter", op="write", register="setpoint", code=6,
                       count=None)

    out = run_procedure("no_load_pulse", bench_config(proxy, sim, exciter=FAST_HOST), tmp_path,
                        yes=True, params=FAST, hooks={"pulse_applied": refuse})
    assert out.exit_code == 2 and "exception 6" in out.message
    assert out.safe_state[0].ok
    assert out.safe_state[0].action.startswith("setpoint reverted by the device watchdog after the "
                                                "device refused the host's restore")
    ev = sim.exciter.events
    on = next(t for t, kind, v in ev if kind == "setpoint" and v > 1.01)
    back = next(t for t, kind, _ in ev if kind == "watchdog")
    # pulse (0.3 s) + watchdog (0.5 s) + a few request timeouts, far below deadline + watchdog
    assert back - on < FAST["width_s"] + 0.5 + 1.0, f"held {back - on:.2f} s"
    assert sim.exciter.setpoint == pytest.approx(1.0)


def test_ctrl_c_during_the_safe_state_retries_leaves_it_to_the_watchdog(fast_watchdog_bench, tmp_path):
    """A link cut longer than the deadline: the host retries its restore; a Ctrl-C meanwhile
    stops the retries (not the first attempt) and the heartbeat, and says so."""
    sim, proxy = fast_watchdog_bench
    cfg = bench_config(proxy, sim, exciter=FAST_HOST, restore_deadline_s=3.0)

    def cut_then_ctrl_c(run) -> None:
        proxy.cut(3.0)
        os.kill(os.getpid(), signal.SIGINT)  # the first: interrupts the procedure

    import threading

    def second_ctrl_c() -> None:  # the operator presses again once the safe state retries
        audit = tmp_path / "audit.jsonl"
        wait_for(lambda: audit.exists() and any(r["kind"] == "error" for r in read_audit(audit)),
                 10.0, "the interrupted procedure")
        time.sleep(0.3)  # the operator's second key press comes later: a stimulus, not a wait
        os.kill(os.getpid(), signal.SIGINT)

    t0 = time.monotonic()
    threading.Thread(target=second_ctrl_c, daemon=True).start()
    out = run_procedure("no_load_pulse", cfg, tmp_path, yes=True, params=FAST,
                        hooks={"pulse_applied": cut_then_ctrl_c})
    took = time.monotonic() - t0
    assert out.exit_code == 3 and not out.safe
    assert "stopped the host's restore (Ctrl-C)" in out.safe_state[0].detail
    assert took < 3.0, f"the run went on for {took:.1f} s after the second Ctrl-C"
    wait_for(lambda: sim.exciter.watchdog_tripped, 3.0, "the device watchdog")


def test_ctrl_c_during_pulse_restores_and_exits_non_zero(bench, tmp_path):
    sim, proxy = bench
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                        params=FAST,
                        hooks={"pulse_applied": lambda run: os.kill(os.getpid(), signal.SIGINT)})
    assert out.exit_code == 2 and "interrupted by the operator (Ctrl-C)" in out.message
    assert out.safe and out.safe_state[0].action == "setpoint restored by host after reconnect"
    assert device_writes(proxy) == PULSE_AND_RESTORE
    assert events(sim) == [("remote", 1.0), ("setpoint", 1.05), ("setpoint", 1.0),
                           ("local", 1.0)]
    # the setpoint back, the record the recorder had triggered on is finished and kept (raw)
    assert out.safe_state[1].action == "left in state done" and sim.recorder.status == "done"
    assert out.raw_path.exists() and out.capture_path is None
    assert "the recorder's record of the aborted test was downloaded and saved raw" in out.message
    rows = read_audit(out.audit_path)
    kept = [r for r in rows if r["kind"] == "record_kept"]
    assert kept and kept[0]["state_before"] == "triggered"
    restore = [r for r in rows if r["kind"] == "write" and r["register"] == "setpoint"][-1]
    assert restore["step"] == "safe state" and restore["matched"]
    assert rows.index(restore) < rows.index(kept[0])     # the setpoint back before the record is kept
    assert rows[-1]["kind"] == "run_end" and rows[-1]["exit_code"] == 2


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT],
                         ids=lambda s: signal.Signals(s).name)
def test_sigterm_sighup_and_sigquit_during_pulse_end_in_the_safe_state(bench, tmp_path, sig):
    """A kill, a closed terminal or Ctrl-\\ is handled like Ctrl-C: restore, disarm, audit
    closed (SIGQUIT's default would dump core with the pulse on until the watchdog)."""
    sim, proxy = bench
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True, params=FAST,
                        hooks={"pulse_applied": lambda run: os.kill(os.getpid(), sig)})
    assert out.exit_code == 2 and f"terminated by {signal.Signals(sig).name}" in out.message
    assert out.safe and out.safe_state[0].action.startswith("setpoint restored by host")
    assert device_writes(proxy) == PULSE_AND_RESTORE
    assert sim.recorder.status == "done" and out.raw_path.exists()     # the record kept
    rows = read_audit(out.audit_path)
    assert rows[-1]["kind"] == "run_end" and rows[-1]["exit_code"] == 2


def test_exception_reply_to_the_pulse_write_leaves_nothing_changed(bench, tmp_path, capsys):
    sim, proxy = bench
    sim.faults.set("exception", device="exciter", op="write", register="setpoint", code=4)
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                        params=FAST)
    assert out.exit_code == 2
    assert "device replied with exception 4 (server device failure)" in out.message
    assert "register setpoint (holding 0), value 1.05" in out.message
    assert out.safe_state[0].action == "setpoint unchanged (no setpoint write took effect)"
    # the refused write changed nothing; remote was given back; the recorder disarmed
    assert events(sim) == [("remote", 1.0), ("local", 1.0)]
    assert sim.exciter.setpoint == pytest.approx(1.0) and not sim.exciter.remote
    assert device_writes(proxy) == [(MODE_ADDR, [3]), (SETPOINT_ADDR, SP_1_05), (MODE_ADDR, [1])]
    assert out.safe_state[1].action.startswith("disarmed")
    assert out.capture_path is None and out.audit_path.exists()
    # the operator reads that there is no capture, not only an error
    capsys.readouterr()
    print_outcome(out)
    assert "capture: NOT SAVED - the run ended before its capture was written" in capsys.readouterr().err


def test_corrupted_download_is_retried_and_the_capture_complete(bench, tmp_path, capsys):
    sim, proxy = bench
    sim.faults.set("corrupt", device="recorder", register="block", skip=5, count=2)
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                        params=FAST)
    assert out.exit_code in (0, 1), out.message
    assert out.data["block_retries"] == 2
    side = out.capture_path.with_suffix(".json")
    assert side.exists() and out.raw_path.exists()
    assert len(out.capture_path.read_text().splitlines()) == 1 + 1500   # header + every sample
    capsys.readouterr()
    print_outcome(out)
    printed = capsys.readouterr()
    assert f"capture: {out.capture_path}" in printed.out and "NOT SAVED" not in printed.out + printed.err


def test_download_that_stays_corrupted_fails_loudly_keeping_what_there_is(bench, tmp_path):
    sim, proxy = bench
    sim.faults.set("corrupt", device="recorder", register="block", skip=5, count=None)
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                        params=FAST)
    assert out.exit_code == 3
    assert "block 5 failed 3 times" in out.message
    assert out.capture_path is None and out.raw_path is None        # never a short capture
    assert not (tmp_path / "capture.csv").exists()
    assert out.safe and out.audit_path.exists() and out.log_path.exists()
    assert device_writes(proxy) == PULSE_AND_RESTORE                 # the test itself was done


def test_host_stall_during_the_pulse_fails_the_width_and_says_whose_fault(bench, tmp_path):
    """The process stalls past the restore deadline (as a loaded VM does for tens of ms): the
    recorded pulse is too wide, the test fails, and the summary puts it on the host."""
    sim, proxy = bench
    stall_s = FAST["width_s"] + 0.08
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                        params=FAST, hooks={"pulse_applied": lambda run: time.sleep(stall_s)})
    assert out.exit_code == 1, out.message
    width = [c for c in out.criteria if c.name == "pulse width error"][0]
    assert not width.passed and width.value > FAST["width_tolerance_s"]
    late_ms = (out.data["commanded_width_s"] - FAST["width_s"]) * 1e3
    assert late_ms > 70
    assert "the restore write left +" in out.message
    assert "the cause: this host: the process or the machine stalled" in out.message
    assert abs(out.data["width_err_s"] * 1e3 - late_ms) < 5  # the wire width is what the host sent
    assert device_writes(proxy) == PULSE_AND_RESTORE


def test_pulse_above_the_cap_is_refused_before_any_write(bench, tmp_path):
    sim, proxy = bench
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                        params={**FAST, "amplitude_pu": 0.08})
    assert out.exit_code == 2
    assert "|amplitude_pu| = 0.08 pu above the cap limits.pulse_amplitude_max_pu = 0.06" \
        in out.message
    assert proxy.requests                     # it did talk to the device (reads) ...
    assert proxy.writes() == []               # ... but no write reached it, not even a beat
    assert sim.exciter.events == []
    assert "write" not in audit_kinds(out)
