"""The on-line step against faults of the unit and of the link (issue 48 items 1-4, 6, 16), as dry
runs: the simulated bench on line, its faults armed at start (`sim_options={"faults": ...}`), the
plant events (a loss of load, a limiter acting) set off by the step's own setpoint write.

How long the plant saw the step is read from the record (the recorder samples the plant's own
setpoint), not from the run's account of its writes.
"""
from __future__ import annotations

import io
import re
import tomllib

from bench_ctl.capture import read_capture
from bench_ctl.exitcodes import ExitCode
from bench_ctl.runner.audit import read_audit
from bench_ctl.runner.config import config_from_dict
from bench_ctl.runner.runner import run_procedure
from bench_ctl.units.overrides import apply_overrides
from bench_ctl.units.unit import load_unit
from pulse_bench import ROOT
from simulators.faults import Fault

#: a short step: 2 s held, 4 s recorded; the steady state over 0.5 s
FAST = {"hold_s": 2.0, "pre_trigger_s": 0.5, "record_s": 4.0, "steady_timeout_s": 0.5}
#: the step's first setpoint write (step on) sets a plant event off
AT_STEP = {"device": "exciter", "op": "write", "register": "setpoint", "count": 1}


def config(**limits):
    doc = tomllib.loads((ROOT / "bench_ctl" / "data" / "demo_bench_online.toml").read_text())
    doc["limits"].update({"steady_time_s": 0.5, **limits})
    return config_from_dict(doc, source="online-bench.toml")


def run(tmp_path, *faults: Fault, cfg=None, params=None, sim=None, **kwargs):
    sim_options = {"faults": list(faults), **(sim or {})}
    return run_procedure("online_step", cfg or config(), tmp_path / "run", dry_run=True,
                         params={**FAST, **(params or {})}, sim_options=sim_options, **kwargs)


def writes(out) -> list[str]:
    return [r["purpose"] for r in read_audit(out.audit_path)
            if r["kind"] == "write" and r.get("register") == "setpoint"]


def step_sent(out) -> dict:
    return next(r for r in read_audit(out.audit_path) if r["kind"] == "step_sent")


def failed(out) -> dict[str, str]:
    return {c.name: c.text() for c in out.criteria if not c.passed}


# ------------------------------------------------------------------ item 2: the step watches P
#: held long enough that a step ended by the watch is told from one that ran out, on a busy machine;
#: recorded 0.1 s past the hold (a step ended early still waits for its record to end)
LONG = {"hold_s": 4.0, "record_s": FAST["pre_trigger_s"] + 4.1}


def test_a_loss_of_load_during_the_step_ends_it_at_once_and_fails_the_test(tmp_path):
    """The unit loses its load 0.3 s into a 4 s hold (80 MW -> 0): the step ends as soon as the
    watch reads P out of its swing band, the test fails naming P, and the record is kept."""
    out = run(tmp_path, Fault("load", **AT_STEP, mw=0.0, delay_s=0.3), params=LONG)
    assert out.exit_code == ExitCode.FAILED, out.message
    assert "unit inside its bands" in failed(out)
    why = step_sent(out)["aborted"]
    assert why.startswith("p ") and ("load rejection" in why or "trip" in why), why
    assert writes(out)[1].startswith("abort (p ")
    cap = read_capture(out.capture_path)               # the evidence is saved
    assert cap.meta["test"]["band"]["left"] == why
    assert cap.meta["test"]["recorded"]["width_s"] < LONG["hold_s"] - 1.5   # the plant saw it end early
    assert "ABORTED: p " in out.message


def test_reverse_power_is_refused_before_any_write(tmp_path):
    """A motoring unit (-15 MW) passed `|p| >= 2 MW`; the unit's on-line range refuses it."""
    unit = apply_overrides(load_unit(None), ["P0=-0.15"])
    out = run(tmp_path, sim={"unit": unit})
    assert out.exit_code == ExitCode.ABORTED
    assert "p = -15.00 MW outside the unit's on-line range" in out.message
    assert "reverse power" in out.message and writes(out) == []


def test_p_below_the_units_minimum_load_is_refused_and_the_range_is_required(tmp_path):
    out = run(tmp_path, cfg=config(p_min_mw=85.0))
    assert out.exit_code == ExitCode.ABORTED and writes(out) == []
    assert "p = 80.00 MW outside the unit's on-line range limits.p_min_mw..p_max_mw = 85..100 MW" in out.message
    doc = tomllib.loads((ROOT / "bench_ctl" / "data" / "demo_bench_online.toml").read_text())
    del doc["limits"]["p_min_mw"], doc["limits"]["p_max_mw"]
    out = run(tmp_path / "b", cfg=config_from_dict(doc, source="no-range.toml"))
    assert out.exit_code == ExitCode.ABORTED and "no P range (limits.p_min_mw, p_max_mw" in out.message


# ------------------------------------------------------------------ item 3: limiters during the step
def test_a_limiter_acting_during_the_step_ends_it_and_names_it(tmp_path):
    out = run(tmp_path, Fault("limiter", **AT_STEP, bit="ceiling_limit", delay_s=0.3), params=LONG)
    assert out.exit_code == ExitCode.FAILED, out.message
    why = step_sent(out)["aborted"]
    assert why == "limiter acting: ceiling_limit (status bit set)"
    assert "ceiling_limit" in failed(out)["unit inside its bands"]
    assert read_capture(out.capture_path).meta["test"]["recorded"]["width_s"] < LONG["hold_s"] - 1.5


def test_a_limiter_acting_at_the_start_is_refused_before_any_write(tmp_path):
    on_first_read = {"device": "exciter", "op": "read", "register": "p", "count": 1, "delay_s": 0.0}
    out = run(tmp_path, Fault("limiter", **on_first_read, bit="rate_limit"))
    assert out.exit_code == ExitCode.ABORTED and writes(out) == []
    assert "limiter(s) acting: rate_limit" in out.message


# ------------------------------------------------------------------ item 4: the steady state
def test_a_unit_still_swinging_is_refused_before_any_write(tmp_path):
    """A load change (80 -> 60 MW) just as the run starts: P swings for seconds; with 0.5 s to
    wait beyond the steady time the run is refused, nothing written."""
    on_first_read = {"device": "exciter", "op": "read", "register": "p", "count": 1, "delay_s": 0.0}
    out = run(tmp_path, Fault("load", **on_first_read, mw=60.0))
    assert out.exit_code == ExitCode.ABORTED, out.message
    assert "refused before any write: the unit is not steady: p moved" in out.message
    assert writes(out) == [] and out.capture_path is None
    steady = [r for r in read_audit(out.audit_path) if r["kind"] == "steady"]
    assert steady and steady[-1]["refused"] and steady[-1]["moved"]["p"] > 2.0


def test_a_swing_that_starts_before_the_step_stops_the_step(tmp_path):
    """The load changes while the recorder arms (after the check before any write): the steady
    state is checked again right before the step; no setpoint is written, remote is given back,
    the recorder disarmed."""
    armed = {"device": "exciter", "op": "read", "register": "p", "after": "recorder.arm", "count": 1,
             "delay_s": 0.0}
    out = run(tmp_path, Fault("load", **armed, mw=60.0))
    assert out.exit_code == ExitCode.ABORTED, out.message
    assert "refused before the step: the unit is not steady" in out.message
    assert writes(out) == []
    assert out.safe and out.safe_state[1].action.startswith("disarmed")


# ------------------------------------------------------------------ item 6: a read lost in recovery
def test_one_lost_q_read_after_the_step_is_read_again_and_the_record_kept(tmp_path):
    out = run(tmp_path, Fault("no_reply", device="exciter", op="read", register="q", after="setpoint:2",
                              count=1))
    assert out.exit_code in (ExitCode.OK, ExitCode.FAILED), out.message
    assert out.capture_path is not None and read_capture(out.capture_path).n == 800
    assert "failed, retrying" in out.log_path.read_text()


def test_q_reads_lost_for_good_after_the_step_still_keep_the_record(tmp_path):
    """Every q read after the step times out: the record is still downloaded and saved, and the
    exit code says a communication error happened."""
    out = run(tmp_path, Fault("no_reply", device="exciter", op="read", register="q", after="setpoint:2",
                              count=None))
    assert out.exit_code == ExitCode.COMMS, out.message
    assert out.capture_path is not None and out.raw_path is not None
    assert read_capture(out.capture_path).n == 800
    assert "communication error: reading vt, q, p after the step: " in out.message
    assert "(the record was still downloaded and saved)" in out.message
    assert [r for r in read_audit(out.audit_path) if r["kind"] == "carried"]


# ------------------------------------------------------------------ item 1: the cap and the link
def test_a_hold_at_its_cap_is_refused_before_any_write(tmp_path):
    """hold_s = step_hold_max_s: the plant would see the step at least one reply longer than the cap."""
    out = run(tmp_path, cfg=config(step_hold_max_s=2.0))
    assert out.exit_code == ExitCode.ABORTED and writes(out) == []
    assert "the link is too slow for this test" in out.message
    assert "a 2.000 s step could last" in out.message and "above the cap limits.step_hold_max_s = 2.000 s" \
        in out.message


def test_a_slow_exciter_is_refused_before_any_write(tmp_path):
    slow = Fault("late_reply", device="exciter", count=None, delay_s=0.1, delay_max_s=0.45)
    out = run(tmp_path, slow)
    assert out.exit_code == ExitCode.ABORTED, out.message
    assert "refused before any write: the link is too slow for this test: the exciter answers in up to" \
        in out.message
    assert writes(out) == []
    check = next(r for r in read_audit(out.audit_path) if r["kind"] == "link_check")
    assert not check["accepted"] and check["samples"] >= 10 and check["max_s"] > 0.25


# ------------------------------------------------------------------ item 16: the readout
def test_the_readout_counts_the_time_held_up(tmp_path, monkeypatch):
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    tty = Tty()
    monkeypatch.setattr("sys.stderr", tty)
    out = run(tmp_path, progress=True, params={"record_s": FAST["pre_trigger_s"] + FAST["hold_s"] + 0.1})
    assert out.exit_code in (ExitCode.OK, ExitCode.FAILED), out.message   # a busy machine may fail the hold
    held = [float(t) for t in re.findall(r"step: vt \d\.\d{4} pu, q -?\d+\.\d\d Mvar, p -?\d+\.\d MW, "
                                         r"(\d+\.\d) s of 2\.0 s held", tty.getvalue())]
    assert len(held) >= 5 and held == sorted(held) and held[0] < 0.5 and held[-1] < 2.0
