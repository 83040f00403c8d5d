"""The simulated recorder over Modbus RTU: arm, trigger on a usetp step or manually, block
download with CRC; on the RTU-over-TCP URL and on the pseudo-terminal. Addresses and the
protocol are hand-written from docs/devices.md."""
from __future__ import annotations

import math
import struct
import time
import zlib

import numpy as np
import pytest
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from simulators.bench import SimBench

# holding
RATE, PRE, LENGTH, MODE, THRESH, ARM, TRIG, BLOCK = 0, 1, 2, 4, 5, 7, 8, 9
# input
STATUS, COUNT, NCH, NBLK, CRC, TRIGSAMPLE, SCALES, RRATE = 0, 1, 3, 4, 5, 7, 9, 15
ECHO = 100
IDLE, RECORDING, ARMED, TRIGGERED, DONE = range(5)


def u32(words) -> int:
    return (words[0] << 16) | words[1]


def f32(words) -> float:
    return struct.unpack(">f", struct.pack(">HH", *words))[0]


@pytest.fixture(scope="module")
def bench():
    with SimBench(heartbeat_timeout_s=5.0, seed=1) as b:
        yield b


def rtu(port: str) -> ModbusSerialClient:
    c = ModbusSerialClient(port, timeout=1.0, retries=0, baudrate=115200)
    assert c.connect()
    return c


def hold(c, address, count):
    r = c.read_holding_registers(address, count=count, device_id=1)
    assert not r.isError(), r
    return r.registers


def inp(c, address, count):
    r = c.read_input_registers(address, count=count, device_id=1)
    assert not r.isError(), r
    return r.registers


def wait_status(c, want, timeout=5.0):
    deadline = time.monotonic() + timeout
    while (s := inp(c, STATUS, 1)[0]) != want:
        assert time.monotonic() < deadline, f"status {s}, waiting for {want}"
        time.sleep(0.01)


def download(c) -> tuple[np.ndarray, dict]:
    head = inp(c, 0, 18)
    n, nblk, crc = u32(head[COUNT:COUNT + 2]), head[NBLK], u32(head[CRC:CRC + 2])
    assert head[NCH] == 3
    words: list[int] = []
    for b in range(nblk):
        r = c.write_register(BLOCK, b, device_id=1)
        assert not r.isError(), r
        win = inp(c, ECHO, 121)
        assert win[0] == b
        words.extend(win[1:])
    assert len(words) == nblk * 120 and nblk == math.ceil(3 * n / 120)
    words = words[: 3 * n]
    assert zlib.crc32(struct.pack(f">{len(words)}H", *words)) == crc
    frames = np.array(words, dtype=np.uint16).view(np.int16).reshape(n, 3)
    meta = {"n": n, "trigger_sample": u32(head[TRIGSAMPLE:TRIGSAMPLE + 2]),
            "scales": [f32(head[SCALES + 2 * i:SCALES + 2 * i + 2]) for i in range(3)],
            "rate": head[RRATE]}
    return frames, meta


def test_defaults_and_identity(bench):
    c = rtu(bench.endpoints.recorder_url)
    try:
        regs = hold(c, 0, 10)
        assert regs[RATE] == 1000 and regs[PRE] == 1000 and u32(regs[LENGTH:LENGTH + 2]) == 10000
        assert regs[MODE] == 1 and f32(regs[THRESH:THRESH + 2]) == pytest.approx(0.01)
        assert inp(c, 30, 2) == [0x5243, 0x0100]
        assert inp(c, ECHO, 1) == [0xFFFF]
    finally:
        c.close()


def test_usetp_step_trigger_records_the_exciter_setpoint(bench):
    c = rtu(bench.endpoints.recorder_serial)
    e = ModbusTcpClient(bench.endpoints.exciter_host, port=bench.endpoints.exciter_port,
                        timeout=1.0, retries=0)
    assert e.connect()
    try:
        assert not c.write_register(PRE, 200, device_id=1).isError()          # 0.2 s
        assert not c.write_registers(LENGTH, [0, 600], device_id=1).isError()  # 0.6 s
        assert not c.write_register(MODE, 1, device_id=1).isError()
        assert not c.write_register(ARM, 1, device_id=1).isError()
        assert inp(c, STATUS, 1)[0] == RECORDING
        r = c.write_register(RATE, 500, device_id=1)                           # busy while running
        assert r.isError() and r.exception_code == 6
        wait_status(c, ARMED)
        assert not e.write_register(3, 3, device_id=1).isError()              # remote
        assert not e.write_registers(0, [0x3F86, 0x6666], device_id=1).isError()   # 1.05
        step = bench.exciter.last_setpoint_step
        wait_status(c, DONE)
        frames, meta = download(c)
        trigger_time_ms = u32(inp(c, 18, 2))
        e.write_registers(0, [0x3F80, 0x0000], device_id=1)
        e.write_register(3, 1, device_id=1)
    finally:
        c.close()
        e.close()
    assert meta["n"] == 600 and meta["trigger_sample"] == 200 and meta["rate"] == 1000
    us, es, vs = meta["scales"]
    assert us == pytest.approx(1e-4) and es == pytest.approx(20 / 4096) and vs == pytest.approx(20 / 4096)
    usetp = frames[:, 0] * us
    assert np.all(frames[:200, 0] == 10000) and np.all(frames[200:, 0] == 10500)
    # the trigger sample is the plant step from which the written setpoint acted
    t_write = next(t for t, what, _ in reversed(bench.exciter.events) if what == "setpoint"
                   and _ == pytest.approx(1.05, abs=1e-6))
    assert 0 <= step - math.ceil((t_write - bench.plant.t0) / bench.plant.dt - 1e-9) <= 1
    assert bench.recorder.trigger_step == step
    assert bench.plant.timing().late_setpoints == 0
    assert trigger_time_ms == step                                  # 1 ms plant steps
    efd = frames[:, 1] * es
    # noise (0.01 pu) and quantisation: pre-trigger efd scatters around 1.0
    assert abs(efd[:200].mean() - 1.0) < 0.01 and 0.005 < efd[:200].std() < 0.02
    assert np.all(np.abs(efd / es - np.round(efd / es)) < 1e-9)
    assert efd[205:260].mean() > 2.0                 # the field is driven up by the step
    assert np.array_equal(usetp, bench.recorder.record_pu()["usetp"])


def test_manual_trigger_on_the_url(bench):
    c = rtu(bench.endpoints.recorder_url)
    try:
        for reg, val in ((RATE, 500), (PRE, 100), (MODE, 0)):
            assert not c.write_register(reg, val, device_id=1).isError()
        assert not c.write_registers(LENGTH, [0, 300], device_id=1).isError()
        assert not c.write_register(ARM, 1, device_id=1).isError()
        r = c.write_register(BLOCK, 0, device_id=1)
        assert r.isError() and r.exception_code == 6                           # no record yet
        r = c.read_input_registers(ECHO + 1, count=120, device_id=1)
        assert r.isError() and r.exception_code == 6
        r = c.write_register(TRIG, 1, device_id=1)
        assert r.isError() and r.exception_code == 6                           # pre-trigger filling
        wait_status(c, ARMED)
        time.sleep(0.05)                                   # armed but no step: must not trigger
        assert inp(c, STATUS, 1)[0] == ARMED
        assert not c.write_register(TRIG, 1, device_id=1).isError()
        assert hold(c, TRIG, 1) == [1]
        wait_status(c, DONE)
        frames, meta = download(c)
        assert meta["n"] == 150 and meta["trigger_sample"] == 50 and meta["rate"] == 500
        r = c.write_register(BLOCK, inp(c, NBLK, 1)[0], device_id=1)
        assert r.isError() and r.exception_code == 3                           # past the end
        assert np.all(frames[:, 0] == 10000)
        rec = bench.recorder
        assert rec.trigger_step - rec.first_step == 100                        # 50 samples * 2 steps
        # arm = 0 keeps a finished record; arm = 1 starts a new one
        assert not c.write_register(ARM, 0, device_id=1).isError()
        assert inp(c, STATUS, 1)[0] == DONE
    finally:
        c.write_register(RATE, 1000, device_id=1)
        c.write_register(MODE, 1, device_id=1)
        c.close()


def test_arm_refuses_a_pre_trigger_that_fills_the_whole_record(bench):
    """0.95 s of 0.99 s at 10 Hz is 10 of 10 samples: nothing left after the trigger."""
    c = rtu(bench.endpoints.recorder_url)
    try:
        for reg, val in ((RATE, 10), (PRE, 950), (MODE, 0)):
            assert not c.write_register(reg, val, device_id=1).isError()
        assert not c.write_registers(LENGTH, [0, 990], device_id=1).isError()
        r = c.write_register(ARM, 1, device_id=1)
        assert r.isError() and r.exception_code == 3
        assert not c.write_register(PRE, 850, device_id=1).isError()   # 8 + 2 samples: fine
        assert not c.write_register(ARM, 1, device_id=1).isError()
        assert not c.write_register(ARM, 0, device_id=1).isError()
    finally:
        for reg, val in ((RATE, 1000), (PRE, 1000), (MODE, 1)):
            c.write_register(reg, val, device_id=1)
        c.write_registers(LENGTH, [0, 10000], device_id=1)
        c.close()


def test_bench_freezes_the_start_up_objects_for_the_collector_and_thaws_them():
    """A full collection over numba/numpy/pymodbus objects stalls every thread for ~60 ms; a
    running bench keeps them out of it (gc.freeze); the last bench to stop gives them back."""
    import gc

    import simulators.bench as B

    others = B._freeze_users  # a module-scoped bench of another test may be running
    with SimBench(serial=False) as outer:
        assert outer.endpoints.recorder_rtu_tcp.startswith("rtu+tcp://127.0.0.1:")
        frozen = gc.get_freeze_count()
        assert frozen > 10_000
        with SimBench(serial=False):
            assert B._freeze_users == others + 2
        assert gc.get_freeze_count() > frozen // 2  # the inner stop did not thaw the outer bench
    assert B._freeze_users == others
    assert (gc.get_freeze_count() == 0) == (others == 0)
