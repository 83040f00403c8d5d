"""Fault injection: parsing, matching, and each fault kind observed on the wire (raw frames)."""
from __future__ import annotations

import socket
import time

import pytest
import serial

from simulators.bench import SimBench
from simulators.control import execute
from simulators.faults import Fault, FaultSet, parse_fault
from wire import crc16


# ------------------------------------------------------------------ parsing and matching
def test_parse_fault():
    f = parse_fault("late_reply:device=recorder,delay_s=0.25,count=inf,register=block")
    assert f == Fault("late_reply", device="recorder", delay_s=0.25, count=None, register="block")
    assert parse_fault("exception:code=0x06").code == 6
    for bad in ("explode", "no_reply:colour=red", "no_reply:device=pump", "exception:code=9",
                "no_reply:count=x", "corrupt:mode=smear", "late_reply:delay_s=0.3,delay_max_s=0.1",
                "no_reply:after=setpoint:0", "no_reply:after=pump.arm", "load:device=exciter",
                "load:device=recorder,mw=0", "limiter:device=exciter",
                "limiter:device=exciter,bit=ceiling_limit,duration_s=-1"):
        with pytest.raises(ValueError, match="fault"):
            parse_fault(bad)
    f = parse_fault("late_reply:device=exciter,count=inf,delay_s=0.1,delay_max_s=0.45")
    assert (f.delay_s, f.delay_max_s, f.count) == (0.1, 0.45, None)
    f = parse_fault("load:device=exciter,op=write,register=setpoint,mw=-15,delay_s=0.5")
    assert f.is_event and f.mw == -15.0
    assert parse_fault("no_reply:op=read,register=q,after=setpoint:2").after_write() == (None, "setpoint", 2)
    assert parse_fault("no_reply:after=recorder.arm").after_write() == ("recorder", "arm", 1)
    assert parse_fault("limiter:device=exciter,bit=ceiling_limit,duration_s=inf").duration_s is None


def test_faultset_draws_delays_in_range_and_counts_writes_for_after():
    fs = FaultSet(seed=3)
    slow = fs.set("late_reply", device="exciter", count=None, delay_s=0.1, delay_max_s=0.45)
    delays = [fs.delay_for(slow) for _ in range(200)]
    assert 0.1 <= min(delays) < 0.15 and 0.40 < max(delays) <= 0.45
    assert FaultSet(seed=3).delay_for(slow) == delays[0]                   # seeded
    fs.clear()
    fs.set("no_reply", device="exciter", op="read", register="q", after="setpoint:2")
    fs.set("load", device="exciter", op="write", register="setpoint", mw=0.0, skip=1)
    assert fs.take("exciter", "read", ["q"]) is None                        # no setpoint write yet
    assert fs.take("exciter", "write", ["setpoint"]) is None
    assert fs.take_events("exciter", "write", ["setpoint"]) == []          # skipped: the first write
    assert fs.take("exciter", "read", ["q"]) is None                        # one write only
    assert fs.take("exciter", "write", ["setpoint"]) is None                # the second: events only
    assert [e.kind for e in fs.take_events("exciter", "write", ["setpoint"])] == ["load"]
    assert fs.take("exciter", "read", ["vt"]) is None
    assert fs.take("exciter", "read", ["vt", "p", "status", "q"]).kind == "no_reply"
    assert fs.writes[("exciter", "setpoint")] == 2 and fs.active() == []
    fs.set("load", device="exciter", op="read", register="p", after="recorder.arm", mw=60.0)
    assert fs.take_events("exciter", "read", ["p"]) == []                  # the recorder not armed
    fs.take("recorder", "write", ["arm"])
    assert [e.mw for e in fs.take_events("exciter", "read", ["p"])] == [60.0]


def test_faultset_skip_count_and_filters():
    fs = FaultSet()
    fs.set("no_reply", device="exciter", op="write", register="setpoint", skip=1, count=2)
    assert fs.take("exciter", "read", ["setpoint"]) is None         # op does not match
    assert fs.take("recorder", "write", ["setpoint"]) is None       # device does not match
    assert fs.take("exciter", "write", ["heartbeat"]) is None       # register does not match
    assert fs.take("exciter", "write", ["setpoint"]) is None        # skipped
    assert fs.take("exciter", "write", ["setpoint"]).kind == "no_reply"
    assert fs.take("exciter", "write", ["setpoint"]).kind == "no_reply"
    assert fs.take("exciter", "write", ["setpoint"]) is None        # used up
    assert fs.active() == [] and len(fs.history) == 2
    fs.set("corrupt", count=None)
    for _ in range(5):
        assert fs.take("recorder", "read", ["block"]) is not None
    assert fs.clear(kind="corrupt") == 1 and fs.active() == []


# ------------------------------------------------------------------ on the wire
@pytest.fixture(scope="module")
def bench():
    with SimBench(heartbeat_timeout_s=30.0) as b:
        yield b


@pytest.fixture(autouse=True)
def _clean(bench):
    bench.faults.clear()
    yield
    bench.faults.clear()


READ_VT = "00 {tid:02x} 00 00 00 06 01 04 00 02 00 02"


def tcp(bench) -> socket.socket:
    s = socket.create_connection(bench.endpoints.exciter_tcp, timeout=2.0)
    return s


def recv_for(s: socket.socket, seconds: float) -> bytes:
    s.settimeout(seconds)
    try:
        return s.recv(256)
    except TimeoutError:
        return b"<timeout>"
    finally:
        s.settimeout(2.0)


def test_no_reply_then_normal(bench):
    bench.faults.set("no_reply", device="exciter", count=1)
    with tcp(bench) as s:
        s.sendall(bytes.fromhex(READ_VT.format(tid=1)))
        assert recv_for(s, 0.3) == b"<timeout>"
        s.sendall(bytes.fromhex(READ_VT.format(tid=2)))
        reply = recv_for(s, 2.0)
        assert reply[:2] == b"\x00\x02" and reply[7:9] == b"\x04\x04"


def test_late_reply_keeps_its_transaction_id(bench):
    bench.faults.set("late_reply", device="exciter", delay_s=0.3)
    with tcp(bench) as s:
        t = time.monotonic()
        s.sendall(bytes.fromhex(READ_VT.format(tid=7)))
        reply = recv_for(s, 2.0)
        assert time.monotonic() - t >= 0.3
        assert reply[:2] == b"\x00\x07" and reply[7] == 0x04


def test_late_replies_drawn_in_a_range(bench):
    bench.faults.set("late_reply", device="exciter", count=4, delay_s=0.15, delay_max_s=0.3)
    with tcp(bench) as s:
        for tid in range(4):
            t = time.monotonic()
            s.sendall(bytes.fromhex(READ_VT.format(tid=tid)))
            reply = recv_for(s, 2.0)
            assert 0.15 <= time.monotonic() - t < 0.3 + 0.2, tid
            assert reply[:2] == bytes([0, tid])
        t = time.monotonic()
        s.sendall(bytes.fromhex(READ_VT.format(tid=9)))                       # used up
        assert recv_for(s, 2.0)[:2] == b"\x00\x09" and time.monotonic() - t < 0.15


def test_a_slow_device_executes_the_request_late(bench):
    """`slow`: the write reaches the device's state only after the delay (a late reply does not
    hold back the write itself: `late_reply` executes at once)."""
    bench.faults.set("slow", device="exciter", op="write", register="heartbeat", delay_s=0.3)
    bench.faults.set("late_reply", device="exciter", op="write", register="heartbeat", skip=1,
                     delay_s=0.3)
    with tcp(bench) as s:
        t = time.monotonic()
        s.sendall(bytes.fromhex("00 01 00 00 00 06 01 06 00 02 00 21"))   # heartbeat = 0x21
        time.sleep(0.1)
        assert bench.exciter.heartbeat != 0x21                              # not yet served
        assert recv_for(s, 2.0)[:2] == b"\x00\x01" and time.monotonic() - t >= 0.3
        assert bench.exciter.heartbeat == 0x21
        s.sendall(bytes.fromhex("00 02 00 00 00 06 01 06 00 02 00 22"))   # late reply only
        time.sleep(0.1)
        assert bench.exciter.heartbeat == 0x22                              # served at once
        assert recv_for(s, 2.0)[:2] == b"\x00\x02"


def test_a_limiter_event_sets_its_status_bit_for_its_duration(bench):
    bench.faults.set("limiter", device="exciter", op="read", register="firmware", bit="ceiling_limit",
                     delay_s=0.0, duration_s=0.4)
    with tcp(bench) as s:
        def status() -> int:
            s.sendall(bytes.fromhex("00 05 00 00 00 06 01 04 00 0a 00 01"))
            return recv_for(s, 2.0)[-1]
        assert status() & 1 == 0
        s.sendall(bytes.fromhex("00 06 00 00 00 06 01 04 00 15 00 01"))   # firmware: sets it off
        recv_for(s, 2.0)
        deadline = time.monotonic() + 2
        while not status() & 1:
            assert time.monotonic() < deadline
        t_on = time.monotonic()
        while status() & 1:
            assert time.monotonic() < deadline
        assert 0.2 < time.monotonic() - t_on < 0.6
    assert [k for _, k, _ in bench.exciter.events] == ["limiter"]
    bench.exciter.events.clear()


def test_drop_connection_executes_then_closes(bench):
    bench.faults.set("drop_connection", device="exciter", op="write", register="heartbeat")
    with tcp(bench) as s:
        s.sendall(bytes.fromhex("00 01 00 00 00 06 01 06 00 02 12 34"))   # heartbeat = 0x1234
        assert recv_for(s, 2.0) == b""                                      # EOF, no reply
    assert bench.exciter.heartbeat == 0x1234
    with tcp(bench) as s:                                                   # server still serves
        s.sendall(bytes.fromhex(READ_VT.format(tid=3)))
        assert recv_for(s, 2.0)[:2] == b"\x00\x03"


def test_exception_reply_leaves_the_device_unchanged(bench):
    with tcp(bench) as s:
        s.sendall(bytes.fromhex("00 01 00 00 00 06 01 06 00 03 00 03"))   # remote
        assert recv_for(s, 2.0).hex(" ") == "00 01 00 00 00 06 01 06 00 03 00 03"
        bench.faults.set("exception", device="exciter", op="write", register="setpoint", code=4)
        s.sendall(bytes.fromhex("00 02 00 00 00 0b 01 10 00 00 00 02 04 3f 86 66 66"))
        assert recv_for(s, 2.0).hex(" ") == "00 02 00 00 00 03 01 90 04"
        assert bench.exciter.setpoint == 1.0 and bench.plant.state().usetp == 1.0
        s.sendall(bytes.fromhex("00 03 00 00 00 06 01 06 00 03 00 01"))   # local again
        recv_for(s, 2.0)


def test_corrupted_serial_bytes_on_block_reads_only(bench):
    rec = bench.recorder
    with serial.Serial(bench.endpoints.recorder_serial, 115200, timeout=1.0) as port:
        def ask(hexreq: str, n: int) -> bytes:
            req = bytes.fromhex(hexreq)
            port.write(req + crc16(req))
            return port.read(n)

        # make a short record: 0.05 s, no pre-trigger, manual trigger
        for reg, val in ((1, 0), (4, 0)):
            assert len(ask(f"01 06 00 {reg:02x} 00 {val:02x}", 8)) == 8
        ask("01 10 00 02 00 02 04 00 00 00 32", 8)                          # length 50 ms
        ask("01 06 00 07 00 01", 8)                                         # arm
        deadline = time.monotonic() + 3
        while rec.status != "armed":
            assert time.monotonic() < deadline
            time.sleep(0.005)
        ask("01 06 00 08 00 01", 8)                                         # trigger
        while rec.status != "done":
            assert time.monotonic() < deadline
            time.sleep(0.005)
        assert len(ask("01 06 00 09 00 00", 8)) == 8                        # block 0
        bench.faults.set("corrupt", device="recorder", register="block", count=1)
        good_status = ask("01 04 00 00 00 01", 7)                           # not a block read
        assert crc16(good_status[:-2]) == good_status[-2:]
        bad = ask("01 04 00 64 00 79", 5 + 2 * 121)                         # echo + 120 words
        assert len(bad) == 247 and crc16(bad[:-2]) != bad[-2:]
        good = ask("01 04 00 64 00 79", 5 + 2 * 121)
        assert crc16(good[:-2]) == good[-2:]
        assert sum(a != b for a, b in zip(bad, good)) == 1                  # one byte flipped
        bench.faults.set("corrupt", device="recorder", mode="truncate")
        short = ask("01 04 00 00 00 01", 7)
        assert len(short) < 7
        port.reset_input_buffer()
        ask("01 06 00 04 00 01", 8)                                         # trigger_mode back


def test_control_port_commands(bench):
    assert execute(bench, "fault no_reply device=recorder count=2").startswith("ok ")
    assert "no_reply" in execute(bench, "list")
    assert execute(bench, "clear") == "ok cleared 1"
    assert execute(bench, "load 12.5") == "ok load 12.5 MW" and bench.exciter.load_mw == 12.5
    bench.exciter.set_load_mw(0.0)
    assert execute(bench, "state").startswith("ok step=")
    assert execute(bench, "fault explode").startswith("error ")
    assert execute(bench, "fault load device=exciter mw=3 op=read register=firmware delay_s=0").startswith("ok ")
    assert execute(bench, "fault limiter device=exciter bit=rate_limit op=read register=firmware "
                          "delay_s=0").startswith("ok ")
    with tcp(bench) as s:
        s.sendall(bytes.fromhex("00 06 00 00 00 06 01 04 00 15 00 01"))   # firmware: sets both off
        recv_for(s, 2.0)
    deadline = time.monotonic() + 2
    while bench.exciter.load_mw != 3.0 or "rate_limit" not in bench.exciter.forced_bits:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    assert execute(bench, "state").startswith("ok step=") and " p=3.000 " in execute(bench, "state")
    assert execute(bench, "clear limiter") == "ok cleared 0" and bench.exciter.forced_bits == {}
    bench.exciter.set_load_mw(0.0)
    bench.exciter.events.clear()
    assert execute(bench, "dance").startswith("error unknown command")


def test_other_unit_ids_get_no_reply(bench):
    with tcp(bench) as s:
        s.sendall(bytes.fromhex("00 01 00 00 00 06 02 04 00 02 00 02"))   # unit 2
        assert recv_for(s, 0.3) == b"<timeout>"
    with serial.Serial(bench.endpoints.recorder_serial, 19200, timeout=0.3) as port:
        req = bytes.fromhex("02 04 00 00 00 01")
        port.write(req + crc16(req))
        assert port.read(7) == b""
        req = bytes.fromhex("01 04 00 00 00 01")                          # unit 1 still answers
        port.write(req + crc16(req))
        assert len(port.read(7)) == 7
