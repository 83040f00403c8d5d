"""The simulated bench on line over Modbus TCP (addresses hand-written from docs/devices.md): P and
Q are the machine's in MW and Mvar on its base, the turbine register moves P, the setpoint moves Q;
at no load the turbine register is refused; a recorder profile the plant cannot fill is an error."""
from __future__ import annotations

import struct
import time

import pytest
from pymodbus.client import ModbusTcpClient

from drivers.profile import load_profile
from simulators.bench import SimBench

SETPOINT, HEARTBEAT, MODE, MECH = 0, 2, 3, 4      # holding
VT, P, Q = 2, 8, 12                               # input


def f32(x: float) -> list[int]:
    b = struct.pack(">f", x)
    return [int.from_bytes(b[:2], "big"), int.from_bytes(b[2:], "big")]


def value(c, address) -> float:
    r = c.read_input_registers(address, count=2, device_id=1)
    assert not r.isError(), r
    return struct.unpack(">f", struct.pack(">HH", *r.registers))[0]


def wait_for(c, address, ok, timeout=10.0) -> float:
    deadline = time.monotonic() + timeout
    while not ok(x := value(c, address)):
        assert time.monotonic() < deadline, f"register {address} reads {x}"
        time.sleep(0.05)
    return x


@pytest.fixture()
def online():
    with SimBench(serial=False, online=True, mva=250.0, recorder_profile="sim-recorder-online") as b:
        c = ModbusTcpClient(b.endpoints.exciter_host, port=b.endpoints.exciter_port, timeout=1.0, retries=0)
        assert c.connect()
        yield b, c
        c.close()


def test_online_bench_serves_p_and_q_of_the_machine_and_the_turbine_moves_p(online):
    bench, c = online
    grid = bench.unit.grid
    assert value(c, P) == pytest.approx(grid["P0"] * 250.0, abs=0.05)      # MW on a 250 MVA base
    assert value(c, Q) == pytest.approx(grid["Q0"] * 250.0, abs=0.05)
    assert not c.write_registers(MECH, f32(150.0), device_id=1).isError()
    wait_for(c, P, lambda p: abs(p - 150.0) < 1.0)
    # the reference moves Q (remote taken first, as the device requires)
    assert not c.write_register(MODE, 3, device_id=1).isError()
    q0 = value(c, Q)
    assert not c.write_registers(SETPOINT, f32(1.02), device_id=1).isError()
    wait_for(c, Q, lambda q: q > q0 + 10.0)
    assert c.write_registers(MECH, f32(1000.0), device_id=1).isError()   # 4 pu: out of range (03)


def test_turbine_register_is_refused_at_no_load():
    with SimBench(serial=False) as bench:
        c = ModbusTcpClient(bench.endpoints.exciter_host, port=bench.endpoints.exciter_port, timeout=1.0,
                            retries=0)
        assert c.connect()
        r = c.write_registers(MECH, f32(50.0), device_id=1)
        c.close()
    assert r.isError() and r.exception_code == 1


def test_recorder_profile_must_fit_the_plant():
    with pytest.raises(ValueError, match="no-load plant has usetp, efd, vt"):
        SimBench(serial=False, recorder_profile="sim-recorder-online")
    assert load_profile("sim-recorder-online").settings["channels"] == "usetp,efd,vt,p,q,ifd"
