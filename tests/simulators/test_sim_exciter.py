"""The simulated excitation system over Modbus TCP (pymodbus client; addresses hand-written
from docs/devices.md so a wrong map cannot pass by being copied)."""
from __future__ import annotations

import struct
import time

import pytest
from pymodbus.client import ModbusTcpClient

from simulators.bench import SimBench

SETPOINT, HEARTBEAT, MODE = 0, 2, 3          # holding
ACTIVE, VT, EFD, IFD, P, STATUS, WD = 0, 2, 4, 6, 8, 10, 11   # input


def f32(x: float) -> list[int]:
    b = struct.pack(">f", x)
    return [int.from_bytes(b[:2], "big"), int.from_bytes(b[2:], "big")]


def from_f32(words) -> float:
    return struct.unpack(">f", struct.pack(">HH", *words))[0]


@pytest.fixture(scope="module")
def bench():
    with SimBench(serial=False, heartbeat_timeout_s=0.4, load_mw=0.0) as b:
        yield b


@pytest.fixture()
def client(bench):
    c = ModbusTcpClient(bench.endpoints.exciter_host, port=bench.endpoints.exciter_port,
                        timeout=1.0, retries=0)
    assert c.connect()
    yield c
    # leave the device local at its pre-remote setpoint for the next test
    if bench.exciter.remote:
        c.write_registers(SETPOINT, f32(1.0), device_id=1)
        c.write_register(MODE, 1, device_id=1)
    c.close()


def inputs(c, address, count):
    r = c.read_input_registers(address, count=count, device_id=1)
    assert not r.isError(), r
    return r.registers


def test_readings_at_no_load_steady_state(client):
    regs = inputs(client, 0, 12)
    assert from_f32(regs[VT:VT + 2]) == pytest.approx(1.0, abs=1e-6)
    assert from_f32(regs[EFD:EFD + 2]) == pytest.approx(1.0, abs=1e-6)
    assert from_f32(regs[IFD:IFD + 2]) == pytest.approx(1.0, abs=1e-6)
    assert from_f32(regs[P:P + 2]) == 0.0
    assert regs[STATUS] == 0
    assert regs[WD] == 400                    # 0.4 s at 1 ms per count
    assert client.read_holding_registers(MODE, count=1, device_id=1).registers == [1]  # auto, local
    assert inputs(client, 20, 2) == [0x4543, 0x0100]


def test_setpoint_needs_remote_then_moves_the_plant(bench, client):
    r = client.write_registers(SETPOINT, f32(1.02), device_id=1)
    assert r.isError() and r.exception_code == 1          # local: wrong state
    assert not client.write_register(MODE, 3, device_id=1).isError()
    t_write = time.monotonic()
    assert not client.write_registers(SETPOINT, f32(1.02), device_id=1).isError()
    back = client.read_holding_registers(SETPOINT, count=2, device_id=1).registers
    assert back == f32(1.02)
    step0 = bench.plant.step
    hb = 0
    while bench.plant.step < step0 + 300:
        hb += 1
        client.write_register(HEARTBEAT, hb, device_id=1)
        time.sleep(0.02)
    regs = inputs(client, 0, 6)
    assert from_f32(regs[ACTIVE:ACTIVE + 2]) == pytest.approx(1.02, abs=1e-6)
    assert from_f32(regs[EFD:EFD + 2]) > 1.02      # AVR drives the field up after a +2 % step
    assert 1.0 < from_f32(regs[VT:VT + 2]) < 1.02
    assert bench.exciter.events[-1][1] == "setpoint" and bench.exciter.events[-1][0] >= t_write


def test_out_of_range_setpoint_is_refused_and_nothing_changes(bench, client):
    client.write_register(MODE, 3, device_id=1)
    for bad in (1.2, 0.5):
        r = client.write_registers(SETPOINT, f32(bad), device_id=1)
        assert r.isError() and r.exception_code == 3
    assert client.read_holding_registers(SETPOINT, count=2, device_id=1).registers == f32(1.0)
    assert bench.plant.state().usetp == 1.0


def test_partial_and_unmapped_access_refused(client):
    client.write_register(MODE, 3, device_id=1)
    r = client.write_register(SETPOINT, 0x3F80, device_id=1)          # half a float
    assert r.isError() and r.exception_code == 2
    r = client.read_input_registers(VT + 1, count=2, device_id=1)       # straddles vt / efd
    assert r.isError() and r.exception_code == 2
    r = client.read_input_registers(12, count=1, device_id=1)           # unmapped
    assert r.isError() and r.exception_code == 2
    r = client.write_registers(VT, f32(1.0), device_id=1)               # input table: FC16 -> holding 2
    assert r.isError()
    r = client.write_register(MODE, 2, device_id=1)                     # manual not simulated
    assert r.isError() and r.exception_code == 3


def test_watchdog_reverts_setpoint_when_heartbeat_stops(bench, client):
    client.write_registers(SETPOINT, f32(1.0), device_id=1) if bench.exciter.remote else None
    assert not client.write_register(MODE, 3, device_id=1).isError()
    assert not client.write_registers(SETPOINT, f32(1.03), device_id=1).isError()
    # heartbeat kept alive for 0.8 s (twice the timeout): no trip
    t_end = time.monotonic() + 0.8
    hb = 100
    while time.monotonic() < t_end:
        hb += 1
        t_last = time.monotonic()       # just before the last heartbeat that changed
        client.write_register(HEARTBEAT, hb, device_id=1)
        time.sleep(0.05)
    assert bench.exciter.remote and not bench.exciter.watchdog_tripped
    # the same value again does not count as a heartbeat
    while not bench.exciter.watchdog_tripped and time.monotonic() < t_last + 2.0:
        client.write_register(HEARTBEAT, hb, device_id=1)
        time.sleep(0.05)
    tripped_at = next(t for t, what, _ in reversed(bench.exciter.events) if what == "watchdog")
    assert 0.4 <= tripped_at - t_last <= 0.5
    assert client.read_holding_registers(SETPOINT, count=2, device_id=1).registers == f32(1.0)
    assert client.read_holding_registers(MODE, count=1, device_id=1).registers == [1]
    assert inputs(client, STATUS, 1)[0] & (1 << 2)                      # watchdog_tripped
    # re-taking remote clears the latch
    client.write_register(MODE, 3, device_id=1)
    assert not inputs(client, STATUS, 1)[0] & (1 << 2)


def test_load_is_visible_as_active_power(bench, client):
    bench.exciter.set_load_mw(250.0)
    try:
        assert from_f32(inputs(client, P, 2)) == 250.0
    finally:
        bench.exciter.set_load_mw(0.0)


VENDOR = """
[profile]
name = "vendor-test"
device = "exciter"
[identity]
vendor = "ACME"
model = "X9"
[settings]
heartbeat_timeout_s = 5.0
[registers.setpoint]
table = "holding"
address = 1000
type = "uint32"
word_order = "CDAB"
scale = 0.00001
unit = "pu"
access = "rw"
min = 0.95
max = 1.08
[registers.heartbeat]
table = "holding"
address = 1010
type = "uint16"
access = "rw"
[registers.mode]
table = "holding"
address = 1011
type = "uint16"
access = "rw"
bits = { auto = 0, remote = 3 }
[registers.ack]
table = "holding"
address = 1012
type = "uint16"
access = "rw"
[registers.vt]
table = "input"
address = 500
type = "int32"
word_order = "CDAB"
scale = 0.0001
unit = "pu"
[registers.efd]
table = "input"
address = 502
type = "int16"
scale = 0.001
unit = "pu"
[registers.active_setpoint]
table = "input"
address = 503
type = "uint16"
scale = 0.0001
[registers.ifd]
table = "input"
address = 504
type = "int16"
scale = 0.001
[registers.p]
table = "input"
address = 505
type = "int16"
scale = 0.1
unit = "MW"
[registers.status]
table = "input"
address = 506
type = "uint16"
bits = { watchdog_tripped = 7, ceiling_limit = 1 }
"""


def test_any_profile_is_served_vendor_cdab_scaled(tmp_path):
    path = tmp_path / "vendor-test.toml"
    path.write_text(VENDOR)
    with SimBench(serial=False, exciter_profile=path) as b:
        c = ModbusTcpClient(b.endpoints.exciter_host, port=b.endpoints.exciter_port, timeout=1,
                            retries=0)
        assert c.connect()
        try:
            regs = c.read_input_registers(500, count=7, device_id=1).registers
            # vt = 1.0 pu = 10000 counts of 1e-4 as int32 low word first: [10000, 0]
            assert regs[0:2] == [10000, 0]
            assert regs[2] == 1000 and regs[3] == 10000 and regs[5] == 0
            r = c.write_registers(1000, [0x9A28, 0x0001], device_id=1)    # 105000 = 0x00019A28
            assert r.isError() and r.exception_code == 1                  # local
            assert not c.write_register(1011, 0b1001, device_id=1).isError()   # auto + remote(bit 3)
            r = c.write_registers(1000, [0xADB0, 0x0001], device_id=1)    # 110000 = 1.1 pu > 1.08
            assert r.isError() and r.exception_code == 3
            assert not c.write_registers(1000, [0x9A28, 0x0001], device_id=1).isError()  # 1.05
            assert not c.write_register(1012, 7, device_id=1).isError()   # extra register kept
            assert c.read_holding_registers(1012, count=1, device_id=1).registers == [7]
            deadline = time.monotonic() + 2.0
            while b.plant.state().usetp != pytest.approx(1.05, abs=1e-12):
                assert time.monotonic() < deadline, "setpoint never reached the plant"
                time.sleep(0.005)
            assert c.read_input_registers(503, count=1, device_id=1).registers == [10500]
            r = c.read_input_registers(2, count=2, device_id=1)           # sim-exciter address
            assert r.isError() and r.exception_code == 2
        finally:
            c.close()


def test_async_embedding_and_clean_stop():
    import asyncio

    from pymodbus.client import AsyncModbusTcpClient

    async def run() -> tuple[list[int], int]:
        async with SimBench(serial=False) as b:
            c = AsyncModbusTcpClient(b.endpoints.exciter_host, port=b.endpoints.exciter_port,
                                     timeout=1.0, retries=0)
            assert await c.connect()
            r = await c.read_input_registers(VT, count=2, device_id=1)
            c.close()
            return r.registers, b.endpoints.exciter_port

    regs, port = asyncio.run(run())
    assert regs == f32(1.0)
    with pytest.raises(OSError):                    # nothing listens after the stop
        import socket
        socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
