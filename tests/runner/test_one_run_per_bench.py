"""One run per exciter (issue 24 item 2): the host lock keyed by the exciter's endpoint, and the
device's own "remote owned by another master" state.

Two `bench-ctl run no_load_pulse --yes` started together against one simulated bench: exactly
one writes; the other is refused before any write, naming the holder. The lock is released on
every way out (a SIGKILLed holder's by the operating system). A second master (another host
address) holding remote is refused by the simulated exciter and by the procedure.
"""
from __future__ import annotations

import signal
import stat
import subprocess
import sys
import textwrap

import pytest
from pymodbus.client import ModbusTcpClient

from bench_ctl.runner.lock import LOCK_FOLDERS, BenchLock, endpoint_key, lock_dir
from bench_ctl.runner.runner import run_procedure
from bench_ctl.runner.safety import BenchBusy
from cli_runs import FAST_PARAMS, ROOT, bench_toml, run_argv, run_env, start_run
from pulse_bench import bench_config, config_doc
from simulators.bench import SimBench
from wire_proxy import WireProxy

MODE, HEARTBEAT, STATUS = 3, 2, 10
OTHER_MASTER = 1 << 4   # status.remote_other_master of the sim profile


def test_two_runs_started_together_exactly_one_writes(tmp_path):
    with SimBench() as sim:
        proxy = WireProxy(sim.endpoints.exciter_tcp)
        try:
            bench = bench_toml(tmp_path / "bench.toml", sim, exciter_url=proxy.url)
            procs = [start_run(run_argv(bench, tmp_path / f"run{i}")) for i in (0, 1)]
            results = [(p.pid, p.wait(120), *p.communicate()) for p in procs]
        finally:
            proxy.close()
    codes = sorted(r[1] for r in results)
    assert codes[1] == 2 and codes[0] in (0, 1), results
    (w_pid, _, w_out, w_err), (_, _, r_out, r_err) = sorted(results, key=lambda r: r[1])
    refused = r_out + r_err
    assert "refused before any write: another run holds the exciter" in refused
    assert f"pid {w_pid} on host" in refused and "procedure no_load_pulse" in refused
    assert "Traceback" not in refused + w_err
    # on the device: one remote, one pulse and its restore, one give-back
    kinds = [(k, round(v, 4)) for _, k, v in sim.exciter.events]
    assert kinds == [("remote", 1.0), ("setpoint", 1.05), ("setpoint", 1.0), ("local", 1.0)]
    assert [w for w in proxy.writes() if w[0] == MODE] == [(MODE, [3]), (MODE, [1])]


def test_the_lock_is_one_per_exciter_on_the_host_whatever_the_environment(tmp_path):
    """Issue 48 item 5: a run with XDG_RUNTIME_DIR set and one without it (and another TMPDIR)
    meet on one lock: exactly one writes."""
    (tmp_path / "xdg").mkdir()
    (tmp_path / "tmp").mkdir()
    envs = [run_env(XDG_RUNTIME_DIR=str(tmp_path / "xdg")),
            {k: v for k, v in run_env(TMPDIR=str(tmp_path / "tmp")).items() if k != "XDG_RUNTIME_DIR"}]
    with SimBench() as sim:
        bench = bench_toml(tmp_path / "bench.toml", sim)
        procs = [start_run(run_argv(bench, tmp_path / f"run{i}"), env=env) for i, env in enumerate(envs)]
        results = [(p.wait(120), *p.communicate()) for p in procs]
    codes = sorted(r[0] for r in results)
    assert codes[1] == 2 and codes[0] in (0, 1), results
    refused = next(out + err for code, out, err in results if code == 2)
    assert "refused before any write: another run holds the exciter" in refused
    kinds = [(k, round(v, 4)) for _, k, v in sim.exciter.events]
    assert kinds == [("remote", 1.0), ("setpoint", 1.05), ("setpoint", 1.0), ("local", 1.0)]


def test_the_lock_folder_is_host_wide_and_shared_by_every_user(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    a = lock_dir()
    monkeypatch.delenv("XDG_RUNTIME_DIR")
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    assert lock_dir() == a and a in LOCK_FOLDERS
    assert stat.S_IMODE(a.stat().st_mode) == 0o1777              # shared as /tmp: sticky, all write
    lock = BenchLock("tcp://127.0.0.1:1", 1, procedure="p", out_dir="o")
    with lock:
        assert lock.path.parent == a and stat.S_IMODE(lock.path.stat().st_mode) == 0o666
    assert not lock.path.exists()


def test_the_lock_names_its_holder_and_is_released_on_every_exit(tmp_path):
    a = BenchLock("tcp://localhost:5020", 1, procedure="no_load_pulse", out_dir="runs/a",
                  folder=tmp_path)
    b = BenchLock("tcp://127.0.0.1:5020", 1, procedure="no_load_pulse", out_dir="runs/b",
                  folder=tmp_path)
    assert a.key == b.key == endpoint_key("tcp://127.0.0.1:5020", 1)    # one exciter, two names
    other_unit = BenchLock("tcp://127.0.0.1:5020", 2, procedure="x", out_dir="y", folder=tmp_path)
    with a:
        with pytest.raises(BenchBusy, match=r"pid \d+ on host .*procedure no_load_pulse, started "
                                            r".*output runs/a"):
            b.acquire()
        with other_unit:                                # another unit id behind the same gateway
            pass
    with b:                                             # released: free again
        assert b.held
    assert list(tmp_path.iterdir()) == []               # no lock file left behind


def test_a_killed_holder_leaves_no_stale_lock(tmp_path):
    """SIGKILL skips every `finally`: the operating system releases the flock."""
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import sys, time
        from bench_ctl.runner.lock import BenchLock
        BenchLock("tcp://127.0.0.1:5020", 1, procedure="p", out_dir="o",
                  folder=__import__("pathlib").Path({str(tmp_path)!r})).acquire()
        print("held", flush=True)
        time.sleep(60)""")], stdout=subprocess.PIPE, text=True, env=run_env(), cwd=ROOT)
    try:
        assert holder.stdout.readline().strip() == "held"
        lock = BenchLock("tcp://127.0.0.1:5020", 1, procedure="q", out_dir="o", folder=tmp_path)
        with pytest.raises(BenchBusy, match=f"pid {holder.pid} "):
            lock.acquire()
        holder.send_signal(signal.SIGKILL)
        holder.wait(10)
        with lock:
            assert lock.held
    finally:
        if holder.poll() is None:
            holder.kill()


def test_a_refused_or_failed_run_releases_the_lock_and_comms_check_needs_none(tmp_path):
    with SimBench() as sim:
        proxy = WireProxy(sim.endpoints.exciter_tcp)
        try:
            cfg = bench_config(proxy, sim)
            sim.exciter.set_load_mw(50.0)                   # refused at the preconditions
            out = run_procedure("no_load_pulse", cfg, tmp_path / "a", yes=True, params=FAST_PARAMS,
                                lock_folder=tmp_path)
            assert out.exit_code == 2 and "no-load precondition failed" in out.message
            sim.exciter.set_load_mw(0.0)

            def boom(run):
                raise RuntimeError("a procedure bug")
            out = run_procedure("no_load_pulse", cfg, tmp_path / "b", yes=True, params=FAST_PARAMS,
                                hooks={"pulse_applied": boom}, lock_folder=tmp_path)
            assert out.exit_code == 2 and out.safe
            # a run holding the lock does not stop a read-only comms check
            with BenchLock(proxy.url, 1, procedure="someone", out_dir="x", folder=tmp_path):
                out = run_procedure("comms_check", cfg, tmp_path / "c", lock_folder=tmp_path)
                assert out.exit_code == 0
                out = run_procedure("no_load_pulse", cfg, tmp_path / "d", yes=True,
                                    params=FAST_PARAMS, lock_folder=tmp_path)
                assert out.exit_code == 2 and "another run holds the exciter" in out.message
        finally:
            proxy.close()
    assert list(tmp_path.glob("exciter-*.lock")) == []


def second_master(sim: SimBench) -> ModbusTcpClient:
    """Another controller: a Modbus client from another host address (127.0.0.2)."""
    c = ModbusTcpClient("127.0.0.1", port=sim.endpoints.exciter_port, timeout=1, retries=0,
                        source_address=("127.0.0.2", 0))
    assert c.connect()
    return c


def test_the_simulated_exciter_keeps_remote_for_the_master_that_took_it():
    with SimBench(serial=False, heartbeat_timeout_s=5.0) as sim:
        other = second_master(sim)
        me = ModbusTcpClient("127.0.0.1", port=sim.endpoints.exciter_port, timeout=1, retries=0)
        assert me.connect()
        try:
            assert not other.write_register(MODE, 3, device_id=1).isError()        # takes remote
            assert other.read_input_registers(STATUS, count=1, device_id=1).registers[0] & OTHER_MASTER == 0
            assert me.read_input_registers(STATUS, count=1, device_id=1).registers[0] & OTHER_MASTER
            for address, words in ((0, [0x3F86, 0x6666]), (HEARTBEAT, [7]), (MODE, [1])):
                r = me.write_registers(address, words, device_id=1)
                assert r.isError() and r.exception_code == 1, address
            assert sim.exciter.remote and sim.exciter.events == [(sim.exciter.events[0][0], "remote", 1.0)]
            assert not other.write_register(MODE, 1, device_id=1).isError()        # gives it back
            assert me.read_input_registers(STATUS, count=1, device_id=1).registers[0] & OTHER_MASTER == 0
            assert not me.write_register(MODE, 3, device_id=1).isError()           # now mine
            assert not me.write_register(MODE, 1, device_id=1).isError()
        finally:
            other.close()
            me.close()


@pytest.mark.parametrize("profile, why", [
    ("sim-exciter", "the exciter reports remote owned by another master (status.remote_other_master set)"),
    ("vendor-exciter", "the exciter is already in remote (mode bit remote set) before this run took it"),
])
def test_a_second_master_holding_remote_is_refused_before_any_write(tmp_path, profile, why):
    """Where the profile has the state bit the device says so; where it has not, remote already
    on says it."""
    from bench_ctl.runner.config import config_from_dict

    with SimBench(exciter_profile=profile) as sim:
        other = second_master(sim)
        mode = sim.exciter.profile["mode"]
        remote_word = (1 << mode.bits["remote"]) | (1 << mode.bits["auto"])
        assert not other.write_register(mode.address, remote_word, device_id=1).isError()
        proxy = WireProxy(sim.endpoints.exciter_tcp)
        try:
            doc = config_doc()
            doc["exciter"].update(url=proxy.url, profile=profile)
            doc["recorder"]["url"] = sim.endpoints.recorder_serial
            out = run_procedure("no_load_pulse", config_from_dict(doc, source="b.toml"), tmp_path,
                                yes=True, params=FAST_PARAMS, lock_folder=tmp_path)
        finally:
            proxy.close()
            other.close()
        assert out.exit_code == 2 and f"refused before any write: {why}" in out.message
        assert proxy.writes() == []
        assert [k for _, k, _ in sim.exciter.events] == ["remote"]      # the other master's only
        assert sim.exciter.remote                                       # left to its master
