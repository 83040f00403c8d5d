"""The device's own watchdog, read from the device before the first write (issue 24 item 1).

The simulated exciter serves the watchdog it runs in the register its profile names, so
`bench-ctl sim --heartbeat-timeout 20` is what the host reads. A watchdog longer than the
limits allow, one too short for the host's heartbeat, or one the device does not report is
refused before any write, naming the value found and the limit; one the host accepts bounds
how long a pulse outlives a host killed mid-pulse (SIGKILL, no safe state at all).
"""
from __future__ import annotations

import signal
import time

import pytest
from pymodbus.client import ModbusTcpClient

from bench_ctl.cli import main
from bench_ctl.runner.audit import read_audit
from bench_ctl.runner.runner import run_procedure
from cli_runs import FAST_PARAMS, audit_rows, bench_toml, run_argv, start_run, wait_for
from drivers.profile import load_profile
from pulse_bench import bench_config
from simulators.bench import SimBench
from wire_proxy import WireProxy


@pytest.fixture
def sim_proxy(request):
    """(SimBench with the watchdog the test asks for, WireProxy in front of its exciter)."""
    sim = SimBench(heartbeat_timeout_s=request.param)
    sim.start()
    proxy = WireProxy(sim.endpoints.exciter_tcp)
    yield sim, proxy
    proxy.close()
    sim.stop()


@pytest.mark.parametrize("profile, timeout_s, words", [("sim-exciter", 20.0, 20000),
                                                      ("vendor-exciter", 3.0, 300)])
def test_the_simulated_exciter_serves_the_watchdog_it_runs(profile, timeout_s, words):
    with SimBench(exciter_profile=profile, serial=False, heartbeat_timeout_s=timeout_s) as sim:
        reg = load_profile(profile)["watchdog_timeout"]
        c = ModbusTcpClient("127.0.0.1", port=sim.endpoints.exciter_port, timeout=1, retries=0)
        assert c.connect()
        try:
            assert c.read_input_registers(reg.address, count=1, device_id=1).registers == [words]
        finally:
            c.close()
        assert sim.exciter.heartbeat_timeout_s == timeout_s


def test_a_watchdog_the_register_cannot_hold_is_refused_by_the_simulator(capsys):
    with pytest.raises(ValueError, match="cannot be served in register watchdog_timeout"):
        SimBench(serial=False, heartbeat_timeout_s=100.0)        # uint16 ms: at most 65.535 s
    assert main(["sim", "--tcp", "127.0.0.1:0", "--heartbeat-timeout", "2.0005"]) == 2
    err = capsys.readouterr().err
    assert "not a multiple of the scale" in err and "Traceback" not in err


@pytest.mark.parametrize("sim_proxy", [20.0], indirect=True)
def test_a_watchdog_longer_than_the_limit_is_refused_before_any_write(sim_proxy, tmp_path):
    """The issue's case: the device runs a 20 s watchdog while the profile says 2 s."""
    sim, proxy = sim_proxy
    asked = []
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, params=FAST_PARAMS,
                        confirm=lambda s: asked.append(s) or True)
    assert out.exit_code == 2 and not asked
    assert ("refused before any write: the exciter's watchdog reads 20.000 s (watchdog_timeout "
            "(input 11)), longer than the limit 3.000 s = limits.pulse_width_max_s 1.500 s + "
            "margin 1.500 s") in out.message
    assert proxy.writes() == [] and sim.exciter.events == []
    checks = [r for r in read_audit(out.audit_path) if r["kind"] == "watchdog_check"]
    assert checks[0]["accepted"] is False and checks[0]["reading"]["value_s"] == 20.0


@pytest.mark.parametrize("sim_proxy", [2.0], indirect=True)
def test_the_limit_is_a_bench_config_limit(sim_proxy, tmp_path):
    sim, proxy = sim_proxy
    out = run_procedure("no_load_pulse", bench_config(proxy, sim, watchdog_max_s=1.9), tmp_path,
                        yes=True, params=FAST_PARAMS)
    assert out.exit_code == 2
    assert "reads 2.000 s (watchdog_timeout (input 11)), longer than the limit " \
           "limits.watchdog_max_s = 1.900 s" in out.message
    assert proxy.writes() == []


@pytest.mark.parametrize("sim_proxy", [0.2], indirect=True)
def test_a_watchdog_shorter_than_the_heartbeat_period_is_named_as_such(sim_proxy, tmp_path):
    """Today's symptom was 'exception 1 (illegal function)' at the pulse write."""
    sim, proxy = sim_proxy
    out = run_procedure("no_load_pulse", bench_config(proxy, sim, exciter={"heartbeat_period_s": 0.25}),
                        tmp_path, yes=True, params=FAST_PARAMS)
    assert out.exit_code == 2
    assert ("the device's watchdog (0.200 s) is shorter than the heartbeat period "
            "exciter.heartbeat_period_s = 0.250 s: the device would trip between two beats") in out.message
    assert "illegal function" not in out.message
    assert proxy.writes() == [] and sim.exciter.events == []


def test_a_profile_naming_no_watchdog_register_is_refused(tmp_path):
    """A device whose watchdog cannot be read: nobody knows how long a pulse outlives the host."""
    from bench_ctl.runner.config import config_from_dict
    from pulse_bench import ROOT, config_doc

    text = (ROOT / "drivers" / "profiles" / "sim-exciter.toml").read_text()
    (tmp_path / "nowd.toml").write_text(text.replace('watchdog_register = "watchdog_timeout"', ""))
    with SimBench() as sim:
        proxy = WireProxy(sim.endpoints.exciter_tcp)
        try:
            doc = config_doc()
            doc["exciter"].update(url=proxy.url, profile=str(tmp_path / "nowd.toml"))
            doc["recorder"]["url"] = sim.endpoints.recorder_serial
            out = run_procedure("no_load_pulse", config_from_dict(doc, source="nowd-bench.toml"),
                                tmp_path / "run", yes=True, params=FAST_PARAMS)
        finally:
            proxy.close()
    assert out.exit_code == 2
    assert "the exciter's watchdog period is unknown (profile 'sim-exciter' names no watchdog " \
           "register (settings.watchdog_register))" in out.message
    assert proxy.writes() == []


def test_a_host_killed_mid_pulse_leaves_it_to_the_watchdog_it_read(tmp_path):
    """SIGKILL during the pulse: no safe state runs at all; the device's watchdog (0.6 s, read
    and accepted) ends the pulse, 0.6 s after the last heartbeat, not the profile's 2 s."""
    with SimBench(heartbeat_timeout_s=0.6) as sim:
        bench = bench_toml(tmp_path / "bench.toml", sim, exciter={"timeout_s": 0.2})
        proc = start_run(run_argv(bench, tmp_path / "run", params={**FAST_PARAMS, "width_s": 1.0,
                                                                   "record_s": 2.0}))
        try:
            wait_for(lambda: any(k == "setpoint" for _, k, _ in sim.exciter.events) or
                     proc.poll() is not None, 60, "the pulse")
            assert proc.poll() is None, proc.communicate()
            t_kill = time.monotonic()
            proc.send_signal(signal.SIGKILL)
            proc.wait(10)
            wait_for(lambda: sim.exciter.watchdog_tripped, 3.0, "the device watchdog")
        finally:
            if proc.poll() is None:
                proc.kill()
        ev = sim.exciter.events
        on = next(t for t, k, v in ev if k == "setpoint" and v > 1.01)
        back = next(t for t, k, _ in ev if k == "watchdog")
        assert sim.exciter.setpoint == pytest.approx(1.0) and not sim.exciter.remote
        assert back - t_kill <= 0.6 + 0.05, back - t_kill   # the last beat came before the kill
        assert back - on <= 1.0 + 0.6                       # within the width cap + watchdog
    rows = audit_rows(tmp_path / "run" / "audit.jsonl")
    wd = [r for r in rows if r["kind"] == "watchdog_check"]
    assert wd and wd[0]["accepted"] and wd[0]["reading"]["value_s"] == 0.6


def test_a_tripped_watchdog_is_named_when_the_device_refuses_a_write():
    """Were the watchdog to trip anyway (a host stalled past it), the refused setpoint write says
    so instead of a bare 'exception 1 (illegal function)'."""
    from drivers.errors import ExceptionReply
    from drivers.exciter import Exciter
    from drivers.link import Endpoint, ModbusLink

    with SimBench(serial=False, heartbeat_timeout_s=0.3) as sim:
        ep = sim.endpoints
        ex = Exciter(ModbusLink(Endpoint(f"tcp://{ep.exciter_host}:{ep.exciter_port}", timeout_s=0.1),
                                "exciter"), load_profile("sim-exciter"), heartbeat_period_s=0.1)
        ex.connect()
        try:
            assert ex.read_watchdog().value_s == pytest.approx(0.3)
            ex.snapshot()
            ex.take_remote()
            ex.heartbeat.stop()                              # the host stalls
            wait_for(lambda: sim.exciter.watchdog_tripped, 2.0, "the watchdog")
            with pytest.raises(ExceptionReply) as err:
                ex.write_setpoint(1.02, purpose="late")
            assert err.value.code == 1
            assert err.value.summary.endswith(
                "device replied with exception 1 (illegal function) (register setpoint (holding 0), "
                "value 1.02); the device's watchdog has tripped (status.watchdog_tripped): it saw no "
                "heartbeat change within 0.300 s and dropped remote")
        finally:
            ex.close()


def test_the_watchdog_limit_in_the_bench_config():
    from bench_ctl.runner.config import ConfigError, config_from_dict
    from pulse_bench import config_doc

    assert config_from_dict(config_doc(), source="b.toml").limits.watchdog_limit_s == 3.0
    assert config_from_dict(config_doc(pulse_width_max_s=1.0), source="b.toml").limits \
        .watchdog_limit_s == 2.5
    assert config_from_dict(config_doc(watchdog_max_s=4), source="b.toml").limits.watchdog_limit_s == 4.0
    for bad in (0, -1.0):
        with pytest.raises(ConfigError, match=f"limits.watchdog_max_s = {float(bad)!r} must be > 0"):
            config_from_dict(config_doc(watchdog_max_s=bad), source="b.toml")
    with pytest.raises(ConfigError, match="limits.watchdog_max_s = 'long' must be a float"):
        config_from_dict(config_doc(watchdog_max_s="long"), source="b.toml")
