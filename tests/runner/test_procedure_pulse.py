"""Procedures end to end through the runner, on the real-protocol simulators.

The dry run starts its own simulated bench (as `bench-ctl run --dry-run` does); the other tests
put a `WireProxy` in front of the simulated exciter so they can assert which writes reached
the device, independently of the drivers' own logs.
"""
from __future__ import annotations

import json
import zlib

import pytest

from bench_ctl.capture import read_capture
from bench_ctl.cli import main
from bench_ctl.runner.audit import read_audit
from bench_ctl.runner.config import ConfigError, config_from_dict
from bench_ctl.runner.runner import OutputExists, run_procedure
from drivers.profile import load_profile
from pulse_bench import (
    ROOT,
    SHORT,
    bench_config,
    config_doc,
)
from simulators.bench import SimBench
from wire_proxy import WireProxy


def test_dry_run_pulse_end_to_end(tmp_path):
    out = run_procedure("no_load_pulse", ROOT / "benches" / "example.toml", tmp_path / "run",
                        dry_run=True, params=SHORT)
    assert out.exit_code == 0, out.message
    assert out.safe and out.dry_run
    assert [r.action for r in out.safe_state] == [
        "setpoint at pre-test value (restored by the procedure)", "left in state done"]
    # the capture and its sidecar
    cap = read_capture(out.capture_path)
    assert cap.n == 2000 and cap.rate_hz == pytest.approx(1000.0)
    side = cap.meta
    assert side["bench_config"]["limits"]["pulse_amplitude_max_pu"] == 0.06
    assert side["bench_config"]["exciter"]["url"].startswith("tcp://127.0.0.1:")  # the sim
    assert side["devices"]["exciter"]["device_code_read"] == 0x4543
    assert side["devices"]["recorder"]["model"] == "SIM-REC-1"
    assert side["test"]["recorded"]["width_s"] == pytest.approx(1.0, abs=0.02)
    assert side["test"]["start_s"] == pytest.approx(0.3)
    purposes = [w["purpose"] for w in side["writes"]
                if w["device"] == "exciter" and w["purpose"] != "heartbeat"]
    assert purposes == ["take remote", "pulse on", "pulse off (restore pre-test setpoint)",
                             "give back remote (pulse test complete)"]
    assert all(w["matched"] for w in side["writes"])
    # the raw download was saved as received and checks against the device CRC
    raw = out.raw_path.read_bytes()
    head = json.loads(out.raw_path.with_name(out.raw_path.name + ".json").read_text())
    assert zlib.crc32(raw) == head["crc32"] and len(raw) == 2 * 3 * 2000
    # the audit: every write with its read-back, steps in order, the end
    rows = read_audit(out.audit_path)
    assert rows[0]["kind"] == "run_start" and rows[-1]["kind"] == "run_end"
    steps = [r["step"] for r in rows if r["kind"] == "step_start"]
    assert steps == ["bench lock", "connect", "preconditions", "arm recorder", "take remote",
                     "pulse", "recovery", "release exciter", "download", "save capture"]
    assert [r for r in rows if r["kind"] == "confirmation"][0]["asked"] is False
    writes = [r for r in rows if r["kind"] == "write"]
    assert writes and all(r["readback"] == r["raw"] for r in writes)
    assert out.log_path.stat().st_size > 0


def test_comms_check_reads_every_register_and_writes_nothing(bench, tmp_path):
    sim, proxy = bench

    def must_not_ask(summary):
        raise AssertionError("comms_check asked for confirmation")

    out = run_procedure("comms_check", bench_config(proxy, sim), tmp_path, confirm=must_not_ask)
    assert out.exit_code == 0, out.message
    values = out.data["values"]
    assert values["exciter"]["device_code"] == 0x4543 and values["recorder"]["channel_count"] == 3
    for dev in ("exciter", "recorder"):
        assert set(values[dev]) == set(load_profile(f"sim-{dev}").registers)
        assert not [v for v in values[dev].values() if isinstance(v, str)]  # no errors
    assert proxy.requests and proxy.writes() == []
    assert [r for r in read_audit(out.audit_path) if r["kind"] == "write"] == []


def test_real_devices_need_confirmation_and_a_no_writes_nothing(bench, tmp_path):
    sim, proxy = bench
    asked = []
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, params=SHORT,
                        confirm=lambda summary: asked.append(summary) or False)
    assert out.exit_code == 2 and "did not confirm" in out.message
    assert len(asked) == 1 and "1.0000 pu -> 1.0500 pu for 1.000 s" in asked[0]
    assert proxy.writes() == [] and sim.exciter.events == []
    conf = [r for r in read_audit(out.audit_path) if r["kind"] == "confirmation"]
    assert conf[0]["asked"] is True and conf[0]["answer"] is False


def test_loaded_unit_is_refused_before_any_write(bench, tmp_path):
    sim, proxy = bench
    sim.exciter.set_load_mw(50.0)
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                        params=SHORT)
    assert out.exit_code == 2
    assert "no-load precondition failed: active power p = 50 MW" in out.message
    assert proxy.writes() == [] and sim.exciter.events == []


def test_outputs_are_never_overwritten_and_params_are_checked(bench, tmp_path):
    sim, proxy = bench
    cfg = bench_config(proxy, sim)
    out = run_procedure("comms_check", cfg, tmp_path)
    assert out.exit_code == 0
    before = out.audit_path.read_bytes()
    with pytest.raises(OutputExists, match="audit.jsonl"):
        run_procedure("comms_check", cfg, tmp_path)
    assert out.audit_path.read_bytes() == before
    with pytest.raises(ConfigError, match="unknown parameter procedures.no_load_pulse.amplitude"):
        run_procedure("no_load_pulse", cfg, tmp_path / "x", params={"amplitude": 0.05})
    with pytest.raises(ConfigError, match="no procedure 'nope'"):
        run_procedure("nope", cfg, tmp_path / "y")


def test_cli_run_comms_check_dry_run(tmp_path, capsys):
    code = main(["run", "comms_check", "--bench", str(ROOT / "benches" / "example.toml"),
                 "--dry-run", "--out", str(tmp_path / "cc")])
    assert code == 0
    text = capsys.readouterr().out
    assert "comms_check: PASSED (exit 0)" in text and "audit:" in text
    code = main(["run", "comms_check", "--bench", str(ROOT / "benches" / "example.toml"),
                 "--dry-run", "--out", str(tmp_path / "cc")])
    assert code == 2                                   # refuses to reuse the folder


def test_vendor_profile_pulse_same_code_other_bytes(tmp_path):
    """The bench config names the vendor-like profile; nothing else changes. On the wire:
    setpoint at holding 1000 as int32 CDAB x 0.0001 pu, mode at 1011 with remote = bit 0 and
    auto = bit 2 (values from the vendor manual, written out by hand)."""
    with SimBench(exciter_profile="vendor-exciter") as sim:
        proxy = WireProxy(sim.endpoints.exciter_tcp)
        try:
            doc = config_doc()
            doc["exciter"].update(url=proxy.url, profile="vendor-exciter")
            doc["recorder"]["url"] = sim.endpoints.recorder_serial
            cfg = config_from_dict(doc, source="vendor-bench.toml")
            out = run_procedure("no_load_pulse", cfg, tmp_path, yes=True,
                                params={"pre_trigger_s": 0.2, "record_s": 1.5, "width_s": 0.3,
                                        "width_tolerance_s": 0.02})
        finally:
            proxy.close()
    assert out.exit_code == 0, out.message
    writes = [w for w in proxy.writes() if w[0] != 1010]          # heartbeat at 1010
    assert writes == [(1011, [0b101]), (1000, [0x2904, 0x0000]), (1000, [0x2710, 0x0000]),
                      (1011, [0b100])]
    assert out.data["recorded"]["width_s"] == pytest.approx(0.3, abs=0.02)


def test_unattended_run_without_yes_is_refused_in_one_line(bench, tmp_path, monkeypatch, capsys):
    """`bench-ctl run no_load_pulse --bench B.toml < /dev/null` on a real bench: nobody can be
    asked, so nothing is written, exit 2, one line saying why, and the audit says so."""
    import io

    from bench_ctl.commands.run import print_outcome

    sim, proxy = bench
    monkeypatch.setattr("sys.stdin", io.StringIO(""))  # end of input at the question
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, params=SHORT)
    assert out.exit_code == 2
    assert out.message.startswith("no operator confirmed") and "--yes" in out.message
    assert proxy.writes() == [] and sim.exciter.events == []
    conf = [r for r in read_audit(out.audit_path) if r["kind"] == "confirmation"]
    assert conf[0]["refused"] == "no operator" and conf[0]["answer"] is None
    capsys.readouterr()
    print_outcome(out)
    printed = capsys.readouterr()
    assert "Traceback" not in printed.out + printed.err and "Abort" not in printed.out + printed.err


def test_heartbeat_too_slow_for_the_watchdog_read_from_the_device_is_refused(bench, tmp_path):
    """The host's heartbeat (1.5 s) against the watchdog the device reports (2 s): refused before
    any write, naming both; the read-only comms check still runs."""
    sim, proxy = bench
    cfg = bench_config(proxy, sim, exciter={"heartbeat_period_s": 1.5})
    out = run_procedure("no_load_pulse", cfg, tmp_path / "run", yes=True, params=SHORT)
    assert out.exit_code == 2
    assert ("the exciter's watchdog reads 2.000 s (watchdog_timeout (input 11)): "
            "exciter.heartbeat_period_s = 1.500 s is more than half the device watchdog") in out.message
    assert proxy.writes() == [] and sim.exciter.events == []
    assert run_procedure("comms_check", cfg, tmp_path / "cc").exit_code == 0


def test_a_watchdog_longer_than_the_width_cap_is_said_before_the_first_write(bench, tmp_path):
    """The simulated exciter's watchdog (2 s, read from it) exceeds a 1.2 s width cap but not the
    watchdog limit (1.2 + 1.5 s): the operator is told in the question before the first write,
    and the audit keeps it."""
    sim, proxy = bench
    asked = []
    out = run_procedure("no_load_pulse", bench_config(proxy, sim, pulse_width_max_s=1.2), tmp_path,
                        params=SHORT, confirm=lambda summary: asked.append(summary) or False)
    assert out.exit_code == 2
    assert "WARNING: the exciter's watchdog (2.000 s, read from the device)" in asked[0]
    assert "pulse width cap (1.200 s)" in asked[0]
    assert "watchdog  2.000 s (read from the device, register watchdog_timeout (input 11)); " \
           "limit 2.700 s = limits.pulse_width_max_s 1.200 s + margin 1.500 s" in asked[0]
    warns = [r for r in read_audit(out.audit_path) if r["kind"] == "warning"]
    assert len(warns) == 1 and "up to 2.000 s after the last heartbeat" in warns[0]["message"]


def test_a_run_on_a_terminal_shows_its_steps_and_a_live_readout(tmp_path, monkeypatch):
    """On a terminal the operator sees each step end and vt / efd while the unit recovers;
    off a terminal (logs, CI) nothing is written."""
    import io

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    tty = Tty()
    monkeypatch.setattr("sys.stderr", tty)
    out = run_procedure("no_load_pulse", ROOT / "benches" / "example.toml", tmp_path / "run",
                        dry_run=True, params=SHORT, progress=True)
    shown = tty.getvalue()
    assert out.exit_code in (0, 1), out.message
    for step in ("connect: ok", "arm recorder: ok", "pulse: ok", "recovery: ok", "download: ok"):
        assert step in shown, shown[-500:]
    assert "recovery: recording, vt " in shown and "efd " in shown
    plain = io.StringIO()
    monkeypatch.setattr("sys.stderr", plain)
    run_procedure("no_load_pulse", ROOT / "benches" / "example.toml", tmp_path / "run2",
                  dry_run=True, params=SHORT, progress=True)
    assert "pulse: ok" not in plain.getvalue()
