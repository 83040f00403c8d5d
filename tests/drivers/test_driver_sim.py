"""The drivers against the real-protocol simulators (Modbus TCP exciter, RTU recorder on a pty).

The same driver code serves the simulator's own profile and the vendor-like profile (other
addresses, CDAB, scaled integers, other bit positions): only the profile file differs.
"""
from __future__ import annotations

import time
import zlib

import numpy as np
import pytest

from drivers.errors import CommError, IntegrityError, WriteUncertain
from drivers.exciter import Exciter
from drivers.link import Endpoint, ModbusLink
from drivers.profile import load_profile
from drivers.recorder import Recorder, RecordSettings
from simulators.bench import SimBench


def wait_for(cond, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.005)


def make_exciter(sim: SimBench, profile: str, **kw) -> Exciter:
    ep = sim.endpoints
    link = ModbusLink(Endpoint(f"tcp://{ep.exciter_host}:{ep.exciter_port}",
                               unit_id=ep.exciter_unit_id, timeout_s=0.5), "exciter")
    ex = Exciter(link, load_profile(profile), **kw)
    ex.connect()
    return ex


def make_recorder(url: str, **kw) -> Recorder:
    rec = Recorder(ModbusLink(Endpoint(url, timeout_s=0.2), "recorder"),
                   load_profile("sim-recorder"), **kw)
    rec.connect()
    return rec


@pytest.mark.parametrize("profile", ["sim-exciter", "vendor-exciter"])
def test_exciter_sequence_same_code_two_profiles(profile):
    with SimBench(exciter_profile=profile, serial=False) as sim:
        ex = make_exciter(sim, profile, heartbeat_period_s=0.1)
        values = ex.read_all()
        assert set(values) == set(load_profile(profile).registers)
        assert values["vt"] == pytest.approx(1.0, abs=0.01)
        assert values["p"] == pytest.approx(0.0, abs=0.01)
        pre = ex.snapshot()
        assert pre.setpoint_pu == pytest.approx(sim.exciter.setpoint, abs=1e-4)
        ex.take_remote()
        assert sim.exciter.remote                      # the profile's remote bit reached it
        rec = ex.write_setpoint(1.02, purpose="step")
        assert rec.matched
        assert sim.exciter.setpoint == pytest.approx(1.02, abs=1e-6)
        report = ex.safe_state("test end")
        assert report.ok and report.action == "setpoint restored by host"
        assert not sim.exciter.remote and not ex.heartbeat.running
        kinds = [(e[1], round(e[2], 4)) for e in sim.exciter.events]
        assert kinds == [("remote", 1.0), ("setpoint", 1.02), ("setpoint", 1.0), ("local", 1.0)]
        ex.close()


def test_heartbeat_holds_the_watchdog_off_and_its_absence_trips_it():
    with SimBench(serial=False, heartbeat_timeout_s=0.3) as sim:
        ex = make_exciter(sim, "sim-exciter", heartbeat_period_s=0.1)
        ex.snapshot()
        ex.take_remote()
        ex.write_setpoint(1.03, purpose="step")
        beats = ex.heartbeat.beats
        wait_for(lambda: ex.heartbeat.beats >= beats + 8, 3.0, "8 heartbeats")  # > 2 timeouts
        assert sim.exciter.remote and not sim.exciter.watchdog_tripped
        ex.heartbeat.stop()                             # the host "dies"
        wait_for(lambda: sim.exciter.watchdog_tripped, 2.0, "the watchdog")
        assert sim.exciter.setpoint == pytest.approx(1.0)
        report = ex.safe_state("after watchdog")
        assert report.ok and report.action == "setpoint restored by the device watchdog"
        assert report.writes == ()                      # nothing needed writing
        ex.close()


def test_a_dropped_connection_on_a_read_is_retried_once():
    with SimBench(serial=False) as sim:
        ex = make_exciter(sim, "sim-exciter")
        sim.faults.set("drop_connection", device="exciter", op="read", count=1)
        assert ex.read("vt") == pytest.approx(1.0, abs=0.01)
        sim.faults.set("drop_connection", device="exciter", op="read", count=2)
        with pytest.raises(CommError) as err:
            ex.read("vt")
        assert "vt (input 2)" in str(err.value) and "tx " in str(err.value)
        ex.close()


@pytest.fixture(scope="module")
def recorded():
    """A simulated bench holding a finished 0.3 s record (manual trigger)."""
    with SimBench() as sim:
        rec = make_recorder(sim.endpoints.recorder_serial)  # the pseudo-terminal
        rec.configure(RecordSettings(rate_hz=1000, pre_trigger_s=0.1, length_s=0.3,
                                     trigger="manual"))
        rec.arm()
        rec.wait_status(("armed",), 5.0)
        rec.trigger()
        rec.wait_status(("done",), 5.0)
        yield sim, rec
        rec.close()


def test_download_checks_and_converts(recorded, tmp_path):
    sim, rec = recorded
    raw = rec.download()
    assert raw.sample_count == 300 and raw.blocks == 8 and raw.block_retries == 0
    assert raw.trigger_sample == 100
    assert zlib.crc32(raw.payload()) == raw.crc32
    data = raw.convert()
    assert data["time"][-1] == pytest.approx(0.299)
    assert np.all(np.abs(data["usetp"] - 1.0) < 1e-3)
    assert np.all(np.abs(data["vt"] - 1.0) < 0.1)
    path, head = raw.save(tmp_path / "raw.bin")
    assert path.read_bytes() == raw.payload()
    with pytest.raises(FileExistsError):
        raw.save(tmp_path / "raw.bin")


def test_rtu_over_tcp_downloads_the_same_record(recorded):
    """A serial device server (rtu+tcp://) reaches the same recorder: same bytes as the pty."""
    sim, rec = recorded
    over_tcp = make_recorder(sim.endpoints.recorder_rtu_tcp)
    try:
        a, b = rec.download(), over_tcp.download()
    finally:
        over_tcp.close()
    assert b.payload() == a.payload() and b.block_retries == 0 and b.sample_count == 300


def test_corrupted_blocks_are_detected_and_read_again(recorded):
    sim, rec = recorded
    clean = rec.download()
    sim.faults.set("corrupt", device="recorder", register="block", skip=2, count=2)
    try:
        again = rec.download()
    finally:
        sim.faults.clear()
    assert again.block_retries == 2
    np.testing.assert_array_equal(again.words, clean.words)


def test_crc_mismatch_downloads_the_record_again(recorded, monkeypatch):
    sim, rec = recorded
    clean = rec.download()
    real_read = rec.link.read
    flips = {"left": 1}

    def flipping_read(table, address, count, **kw):
        words = real_read(table, address, count, **kw)
        if count > 100 and flips["left"]:   # a data window: one bit wrong, CRC-16 "passed"
            flips["left"] -= 1
            words[5] ^= 0x0001
        return words

    monkeypatch.setattr(rec.link, "read", flipping_read)
    raw = rec.download()
    assert raw.record_attempts == 2
    np.testing.assert_array_equal(raw.words, clean.words)
    flips["left"] = 10**6                        # wrong every time: refused, never short
    with pytest.raises(IntegrityError, match="record rejected after 3 downloads: CRC-32"):
        rec.download()


def test_lost_reply_to_take_remote_still_gives_remote_back():
    """The device applied the mode write but its reply was lost: the host must still give
    remote back (reads the mode, writes only because it differs)."""
    with SimBench(serial=False) as sim:
        ex = make_exciter(sim, "sim-exciter", heartbeat_period_s=0.1)
        ex.snapshot()
        sim.faults.set("no_reply", device="exciter", op="write", register="mode", count=1)
        with pytest.raises(WriteUncertain):
            ex.take_remote()
        assert sim.exciter.remote                      # it reached the device
        report = ex.safe_state("take remote uncertain")
        assert report.ok and not sim.exciter.remote and not ex.heartbeat.running
        assert [w.register for w in report.writes] == ["mode"]
        ex.close()


def test_setpoint_moved_by_someone_else_is_left_as_found():
    """This run never wrote the setpoint; the local operator moved it after the snapshot. The
    safe state must not write the old value back onto the unit."""
    with SimBench(serial=False) as sim:
        ex = make_exciter(sim, "sim-exciter", heartbeat_period_s=0.1)
        ex.snapshot()
        ex.take_remote()
        other = make_exciter(sim, "sim-exciter")       # another client: the local operator
        other.snapshot()
        other.write_setpoint(1.01, purpose="operator")
        other.close()
        report = ex.safe_state("operator declined")
        assert report.ok and "not written by this run" in report.action
        assert sim.exciter.setpoint == pytest.approx(1.01, abs=1e-6)
        assert [w.register for w in report.writes] == ["mode"]   # remote given back, nothing else
        assert not sim.exciter.remote and not ex.heartbeat.running
        ex.close()


def test_timed_write_takes_the_link_before_a_silent_device_can_delay_it():
    """A beat in flight to a device that does not answer holds the link for one request timeout;
    the timed write asks for the link that much earlier, so it still leaves on time."""
    with SimBench(serial=False) as sim:
        ex = make_exciter(sim, "sim-exciter", heartbeat_period_s=0.05)
        ex.snapshot()
        ex.take_remote()
        timeout = ex.link.endpoint.timeout_s
        deadline = time.monotonic() + timeout + 0.4
        # the next beats go unanswered from now on, one of them in flight when the guard opens
        sim.faults.set("no_reply", device="exciter", op="write", register="heartbeat", count=None)
        rec = ex.write_setpoint(1.02, purpose="timed", at_mono=deadline)
        sim.faults.clear()
        assert rec.t_tx_mono - deadline < 0.005, rec.t_tx_mono - deadline
        ex.safe_state("end")
        ex.close()


# ------------------------------------------------------------------ the link's order and reads
def test_the_link_lock_serves_a_timed_write_then_the_heartbeat_then_the_rest():
    """Waiters get the link by priority, then in order of arrival; the holder may take it again
    (re-entrant); a wait interrupted leaves the queue as it was."""
    import threading

    from drivers.link import HEARTBEAT, ROUTINE, TIMED, LinkLock

    lock, order, started = LinkLock(), [], []
    lock.acquire()
    lock.acquire()                                   # re-entrant
    lock.release()

    def wait(name: str, level: int) -> None:
        started.append(name)
        with lock.held(level):
            order.append(name)

    threads = []
    for name, level in (("read 1", ROUTINE), ("beat", HEARTBEAT), ("read 2", ROUTINE), ("restore", TIMED)):
        t = threading.Thread(target=wait, args=(name, level))
        t.start()
        threads.append(t)
        wait_for(lambda n=name: n in started and len(lock._queue) == len(started), 2.0, f"{name} queued")
    lock.release()
    for t in threads:
        t.join(2.0)
    assert order == ["restore", "beat", "read 1", "read 2"]
    with pytest.raises(RuntimeError, match="does not hold"):
        lock.release()


def test_read_many_reads_registers_back_to_back_in_one_request():
    with SimBench(serial=False, online=True, recorder_profile="sim-recorder-online") as sim:
        ex = make_exciter(sim, "sim-exciter")
        try:
            t0 = time.monotonic()
            many = ex.read_many(("vt", "q", "p", "status"))
            assert len(ex.link.response_times(since_mono=t0)) == 1    # input 2..13 in one request
            assert list(many) == ["vt", "q", "p", "status"]
            assert many["p"] == pytest.approx(80.0, abs=0.01) and many["q"] == pytest.approx(10.0, abs=0.01)
            assert many["vt"] == pytest.approx(ex.read("vt"), abs=1e-6) and many["status"] == 0
            t0 = time.monotonic()
            apart = ex.read_many(("setpoint", "vt", "firmware"))         # holding 0; input 2, input 21
            assert len(ex.link.response_times(since_mono=t0)) == 3        # 14..19 are not mapped
            assert apart["setpoint"] == pytest.approx(1.0) and apart["firmware"] == 0x0100
        finally:
            ex.close()


def test_the_heartbeat_is_not_starved_by_a_reader_on_a_slow_exciter():
    """Replies 0.1-0.2 s late and a thread reading as fast as the link answers: the heartbeat
    still gets the link next each time (a beat waits for one request in flight, not a burst)."""
    import threading

    with SimBench(serial=False, heartbeat_timeout_s=5.0) as sim:
        ex = make_exciter(sim, "sim-exciter", heartbeat_period_s=0.1)
        stop = threading.Event()

        def reader() -> None:
            while not stop.is_set():
                ex.read("vt")

        try:
            ex.snapshot()
            sim.faults.set("late_reply", device="exciter", count=None, delay_s=0.1, delay_max_s=0.2)
            t = threading.Thread(target=reader)
            t.start()
            ex.take_remote()
            time.sleep(3.0)
            stop.set()
            t.join(5.0)
            stats = ex.heartbeat_stats()
            # a beat: its write and read-back (2 x 0.2 s), the read in flight (0.2 s), the period
            assert stats.failures == 0 and stats.beats >= 4
            assert stats.max_gap_s < 0.1 + 3 * 0.2 + 0.1, stats
            assert not sim.exciter.watchdog_tripped
        finally:
            sim.faults.clear()
            ex.safe_state("test end")
            ex.close()


def test_interrupts_never_leave_the_link_lock_half_changed():
    """Ctrl-C raises in the main thread at any point of its Python code, the link lock's own
    bookkeeping included: cut there, a waiter stayed queued (or the lock owned) forever and every
    later request, the safe state's restore included, waited forever (the fault matrix saw a run
    hang after a SIGHUP). The handler defers the interrupt inside the bookkeeping; the lock raises
    it where its state is whole. Here: SIGINT every 0.3-3 ms at the main thread while it takes and
    gives back the lock against a second thread, then the lock must be free and its queue empty."""
    import signal
    import threading

    from drivers.link import HEARTBEAT, LinkLock, defer_interrupt, in_link_bookkeeping

    armed = [False]   # interrupts only inside the loop's try (the runner's CtrlC: while it is armed)

    def handler(signum, frame):
        if not armed[0]:
            return
        exc = KeyboardInterrupt()
        if in_link_bookkeeping():
            defer_interrupt(exc)
            return
        raise exc

    lock, stop = LinkLock(), threading.Event()
    main = threading.main_thread().ident

    def other() -> None:           # the heartbeat: takes the lock too, between pauses
        while not stop.is_set():
            with lock.held(HEARTBEAT):
                time.sleep(0.0002)
            time.sleep(0.0005)

    def pester() -> None:
        import random

        rng = random.Random(5)
        while not stop.is_set():
            signal.pthread_kill(main, signal.SIGINT)
            time.sleep(rng.uniform(0.0003, 0.003))

    import gc

    gc.collect()      # other tests' garbage: a finalizer run meanwhile would swallow an interrupt
    gc.disable()
    old = signal.signal(signal.SIGINT, handler)
    threads = [threading.Thread(target=other), threading.Thread(target=pester)]
    interrupts = cycles = 0
    try:
        for t in threads:
            t.start()
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            try:
                armed[0] = True
                with lock.held():
                    cycles += 1
                armed[0] = False
            except KeyboardInterrupt:
                armed[0] = False
                interrupts += 1
    finally:
        armed[0] = False
        stop.set()
        for t in threads:
            t.join(5.0)
        signal.signal(signal.SIGINT, old)
        gc.enable()
    assert interrupts > 50 and cycles > 50, (interrupts, cycles)
    assert not any(t.is_alive() for t in threads)          # the other thread was never locked out
    assert lock._owner is None and lock._queue == [] and lock._depth == 0
    got = threading.Event()
    t = threading.Thread(target=lambda: (lock.acquire(), got.set(), lock.release()))
    t.start()
    assert got.wait(1.0)
    t.join()
