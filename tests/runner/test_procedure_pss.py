"""The stabiliser test (procedures/pss_step.py, issue 49 item 3): the on-line step with the PSS off,
then on, end to end as a dry run (two captures, the mode damped more with the PSS on); and the PSS
switch as found whatever ends the run (Ctrl-C, SIGTERM, SIGHUP, SIGQUIT, a link cut during the step,
a lost reply to the switch's write, a refusal after the switch was written, a step ended by a loss
of load), against a simulated bench
in this process so that the device's own switch is read at the end."""
from __future__ import annotations

import os
import signal
import tomllib

import pytest

from bench_ctl.capture import read_capture
from bench_ctl.exitcodes import ExitCode
from bench_ctl.runner.audit import read_audit
from bench_ctl.runner.config import ConfigError, config_from_dict
from bench_ctl.runner.runner import run_procedure
from procedures.pss_step import MODE_SPAN_S, SIMULATED_BENCH
from pulse_bench import ROOT
from simulators.bench import SimBench
from simulators.faults import Fault
from wire_proxy import WireProxy

#: a short test: a 3 % step held 4.5 s (the mode fitted over 4 s of it), 7 s recorded, steady over 0.5 s
FAST = {"amplitude_pu": 0.03, "hold_s": 4.5, "pre_trigger_s": 0.5, "record_s": 7.0, "steady_timeout_s": 5.0}
#: the faults' runs: the shortest step pss_step takes (held the mode's 4 s, recorded 0.1 s past the
#: step back); a run ended early still waits for its record to end, which none of their claims reads
FAULTS = {**FAST, "hold_s": MODE_SPAN_S, "record_s": FAST["pre_trigger_s"] + MODE_SPAN_S + 0.1}


def _doc(**limits):
    doc = tomllib.loads((ROOT / "bench_ctl" / "data" / "demo_bench_online.toml").read_text())
    doc["limits"].update({"steady_time_s": 0.5, **limits})
    return doc


def pss_writes(out) -> list[str]:
    return [r["purpose"] for r in read_audit(out.audit_path)
            if r["kind"] == "write" and r.get("register") == "pss_on"]


def test_pss_step_dry_run_end_to_end(tmp_path):
    out = run_procedure("pss_step", config_from_dict(_doc(), source="online-bench.toml"), tmp_path / "run",
                        dry_run=True, params=FAST)
    assert out.exit_code == ExitCode.OK, [c.text() for c in out.criteria if not c.passed]
    off, on = (read_capture(tmp_path / "run" / f"capture_{p}.csv") for p in ("pss_off", "pss_on"))
    assert off.meta["test"]["pss_on"] is False and on.meta["test"]["pss_on"] is True
    assert {"p", "q", "usetp"} <= set(off.columns()) and off.n == on.n == 1400
    assert (tmp_path / "run" / "recorder_raw_pss_off.bin").exists()
    # switched off for the first step only; the first step's release put it back on
    assert pss_writes(out) == ["PSS off for the step (pss_off)",
                               "restore pre-test PSS switch (on-line step complete)"]
    modes = out.data["modes"]
    assert modes["pss_on"]["damping"] > modes["pss_off"]["damping"] + 0.05, modes
    assert 1.0 < modes["pss_off"]["frequency_hz"] < 2.5
    assert all(c.passed for c in out.criteria), [c.text() for c in out.criteria if not c.passed]
    print(f"modes {modes}, run {out.duration_s:.1f} s")


def test_a_hold_shorter_than_the_modes_span_is_refused_before_anything_starts(tmp_path):
    with pytest.raises(ConfigError, match="hold_s = 3 s shorter than the 4 s the mode is fitted over"):
        run_procedure("pss_step", config_from_dict(_doc(), source="online-bench.toml"), tmp_path / "run",
                      dry_run=True, params={**FAST, "hold_s": 3.0})


@pytest.fixture
def pss_bench():
    sim = SimBench(online=True, recorder_profile="sim-recorder-online", unit_set=SIMULATED_BENCH["unit_set"])
    sim.start()
    yield sim
    sim.stop()


def _run(sim, tmp_path, *faults: Fault, params=None, url=None, limits=None, **kwargs):
    for f in faults:
        sim.faults.add(f)
    doc = _doc(**(limits or {}))
    host, port = sim.endpoints.exciter_tcp
    doc["exciter"]["url"] = url or f"tcp://{host}:{port}"
    doc["recorder"]["url"] = sim.endpoints.recorder_serial
    return run_procedure("pss_step", config_from_dict(doc, source="test-bench.toml"), tmp_path / "run", yes=True,
                         params={**FAULTS, **(params or {})}, **kwargs)


def _as_found(sim, out) -> None:
    assert sim.exciter.pss_on is True and sim.plant.pss_on is True, out.message
    assert sim.exciter.setpoint == pytest.approx(sim.plant.usetp_pre) and not sim.exciter.remote
    assert out.safe, out.message


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT],
                         ids=lambda s: signal.Signals(s).name)
def test_a_signal_during_the_step_with_the_pss_off_leaves_it_as_found(pss_bench, tmp_path, sig):
    out = _run(pss_bench, tmp_path, hooks={"step_applied": lambda run: os.kill(os.getpid(), sig)})
    assert out.exit_code == ExitCode.ABORTED, out.message
    why = ("interrupted by the operator (Ctrl-C)" if sig == signal.SIGINT
           else f"terminated by {signal.Signals(sig).name}")
    assert pss_writes(out) == ["PSS off for the step (pss_off)", f"restore pre-test PSS switch ({why})"]
    assert "PSS switch restored to on by host" in out.safe_state[0].detail
    _as_found(pss_bench, out)


def test_a_link_cut_during_the_step_with_the_pss_off_leaves_it_as_found(pss_bench, tmp_path):
    """The exciter's link is cut for 0.6 s during the step: the safe state reconnects, restores
    the setpoint, then switches the PSS back on."""
    proxy = WireProxy(pss_bench.endpoints.exciter_tcp)
    try:
        out = _run(pss_bench, tmp_path, url=proxy.url, hooks={"step_applied": lambda run: proxy.cut(0.6)})
    finally:
        proxy.close()
    assert out.exit_code in (ExitCode.ABORTED, ExitCode.COMMS), out.message
    assert "PSS switch restored to on by host" in out.safe_state[0].detail, out.safe_state[0]
    _as_found(pss_bench, out)


def test_a_lost_reply_to_the_switch_write_leaves_it_as_found(pss_bench, tmp_path):
    """The PSS-off write reaches the device, its reply is lost: the run ends, the safe state reads
    the switch off and writes it back on."""
    out = _run(pss_bench, tmp_path, Fault("no_reply", device="exciter", op="write", register="pss_on", count=1))
    assert out.exit_code == ExitCode.COMMS, out.message
    assert [w for w in pss_writes(out) if w.startswith("restore")], pss_writes(out)
    _as_found(pss_bench, out)


def test_a_refusal_after_the_switch_was_written_leaves_it_as_found(pss_bench, tmp_path):
    """A limiter starts acting as the PSS is switched off: the step is refused (no steady state)
    after the switch was written; the safe state switches it back on."""
    out = _run(pss_bench, tmp_path, Fault("limiter", device="exciter", op="write", register="pss_on", count=1,
                                           bit="rate_limit", delay_s=0.0), params={"steady_timeout_s": 0.5})
    assert out.exit_code == ExitCode.ABORTED, out.message
    assert "refused before the step: the unit is not steady: limiter(s) acting: rate_limit" in out.message
    assert pss_writes(out)[-1].startswith("restore pre-test PSS switch")
    _as_found(pss_bench, out)


def test_a_step_ended_by_a_loss_of_load_keeps_its_record_and_leaves_the_pss_as_found(pss_bench, tmp_path):
    out = _run(pss_bench, tmp_path, Fault("load", device="exciter", op="write", register="setpoint", count=1,
                                           mw=0.0, delay_s=0.3))
    assert out.exit_code == ExitCode.FAILED, out.message
    assert (tmp_path / "run" / "capture_pss_off.csv").exists()
    assert not (tmp_path / "run" / "capture_pss_on.csv").exists()    # no second step after an abort
    # the PSS back on right after the setpoint, not when the record ends (4.1 s after the step)
    writes = pss_writes(out)
    assert writes[0] == "PSS off for the step (pss_off)" and len(writes) == 2, writes
    assert writes[1].startswith("abort (") and writes[1].endswith("PSS back on at once (pss_off)"), writes
    ev = pss_bench.exciter.events
    t_step = next(t for t, k, v in ev if k == "setpoint" and v != pytest.approx(pss_bench.plant.usetp_pre))
    t_back = next(t for t, k, v in ev if k == "setpoint" and t > t_step)
    t_pss = next(t for t, k, v in ev if k == "pss_on" and v == 1.0 and t > t_step)
    assert 0.0 <= t_pss - t_back < 0.5, (t_step, t_back, t_pss)
    _as_found(pss_bench, out)


def test_a_refused_restore_of_the_switch_is_left_to_the_watchdog_and_said_as_such(pss_bench, tmp_path):
    """The device refuses the write that puts the PSS back on after the PSS-off step: the safe
    state stops the heartbeat (as for a refused setpoint restore) and reads until the device's
    watchdog has put the switch back; the report names the switch, never the setpoint."""
    out = _run(pss_bench, tmp_path, Fault("exception", device="exciter", op="write", register="pss_on", skip=1,
                                           count=1, code=4))
    audit = out.audit_path.read_text()     # the release after the PSS-off step is in the audit
    assert "SETPOINT NOT RESTORED" not in audit + out.message
    assert "PSS switch put back on by the device watchdog after the device refused" in audit, out.message
    assert any(k == "watchdog" for _, k, _ in pss_bench.exciter.events)   # the device put it back
    _as_found(pss_bench, out)


def test_a_switch_the_watchdog_cannot_put_back_in_time_is_reported_as_the_switch(pss_bench, tmp_path):
    """The same refusal with a restore deadline shorter than the device's watchdog: the release
    after the PSS-off step is not confirmed and says it is the PSS switch (the setpoint is back)."""
    out = _run(pss_bench, tmp_path, Fault("exception", device="exciter", op="write", register="pss_on", skip=1,
                                           count=1, code=4), limits={"restore_deadline_s": 0.5})
    assert out.exit_code == ExitCode.COMMS, out.message
    assert "but the PSS switch could not be put back on within the deadline" in out.message, out.message
    assert "the device refused the PSS switch's restore write" in out.message
    assert "SETPOINT NOT RESTORED" not in out.message
    assert (tmp_path / "run" / "capture_pss_off.csv").exists()     # the record kept
    assert pss_bench.exciter.setpoint == pytest.approx(pss_bench.plant.usetp_pre)
