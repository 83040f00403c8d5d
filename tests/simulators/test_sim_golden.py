"""Golden frames: the exact bytes on the wire, hand-written from the documented register map
(docs/devices.md), independent of the profile files and of any Modbus library.
RTU CRCs were computed by hand-rolled CRC-16/MODBUS, itself checked against the two frames
every Modbus text quotes (01 03 00 00 00 01 -> 84 0A, 01 03 00 00 00 0A -> C5 CD)."""
from __future__ import annotations

import socket
import time

import pytest
import serial

from simulators.bench import SimBench
from wire import crc16


def test_crc_helper_matches_the_textbook_frames():
    assert crc16(bytes.fromhex("010300000001")) == bytes.fromhex("840a")
    assert crc16(bytes.fromhex("01030000000a")) == bytes.fromhex("c5cd")


@pytest.fixture(scope="module")
def bench():
    with SimBench(heartbeat_timeout_s=10.0) as b:
        yield b


def exchange(sock: socket.socket, request: str, reply_len: int) -> str:
    sock.sendall(bytes.fromhex(request))
    data = b""
    deadline = time.monotonic() + 2.0
    while len(data) < reply_len and time.monotonic() < deadline:
        data += sock.recv(reply_len - len(data))
    return data.hex(" ")


# (request, expected reply) on Modbus TCP, unit 1, in order
TCP_GOLDEN = [
    # read input 2..5: vt, efd at the no-load steady state = 1.0f, 1.0f (3F80 0000)
    ("00 01 00 00 00 06 01 04 00 02 00 04",
     "00 01 00 00 00 0b 01 04 08 3f 80 00 00 3f 80 00 00"),
    # setpoint write while local: exception 01
    ("00 02 00 00 00 0b 01 10 00 00 00 02 04 3f 86 66 66",
     "00 02 00 00 00 03 01 90 01"),
    # mode = 3 (auto + remote), FC06 echo
    ("00 03 00 00 00 06 01 06 00 03 00 03",
     "00 03 00 00 00 06 01 06 00 03 00 03"),
    # setpoint = 1.05f (3F86 6666), FC16
    ("00 04 00 00 00 0b 01 10 00 00 00 02 04 3f 86 66 66",
     "00 04 00 00 00 06 01 10 00 00 00 02"),
    # setpoint = 1.2f (3F99 999A): above 1.1 -> exception 03
    ("00 05 00 00 00 0b 01 10 00 00 00 02 04 3f 99 99 9a",
     "00 05 00 00 00 03 01 90 03"),
    # read back the setpoint: still 1.05f
    ("00 06 00 00 00 06 01 03 00 00 00 02",
     "00 06 00 00 00 07 01 03 04 3f 86 66 66"),
    # device code at input 20: 'EC'
    ("00 07 00 00 00 06 01 04 00 14 00 01",
     "00 07 00 00 00 05 01 04 02 45 43"),
    # half of vt (input 3) -> exception 02
    ("00 08 00 00 00 06 01 04 00 03 00 01",
     "00 08 00 00 00 03 01 84 02"),
    # back to 1.0f and local
    ("00 09 00 00 00 0b 01 10 00 00 00 02 04 3f 80 00 00",
     "00 09 00 00 00 06 01 10 00 00 00 02"),
    ("00 0a 00 00 00 06 01 06 00 03 00 01",
     "00 0a 00 00 00 06 01 06 00 03 00 01"),
]


def test_exciter_tcp_golden_frames(bench):
    with socket.create_connection(bench.endpoints.exciter_tcp, timeout=2.0) as s:
        for request, reply in TCP_GOLDEN:
            assert exchange(s, request, len(bytes.fromhex(reply))) == reply, request


# (request, expected reply) on Modbus RTU, unit 1 (CRC low byte first)
RTU_GOLDEN = [
    # sample_rate (holding 0) = 1000
    ("01 03 00 00 00 01 84 0a", "01 03 02 03 e8 b8 fa"),
    # device_code, firmware (input 30..31) = 'RC', 0x0100
    ("01 04 00 1e 00 02 11 cd", "01 04 04 52 43 01 00 1b 78"),
    # status (input 0) = idle
    ("01 04 00 00 00 01 31 ca", "01 04 02 00 00 b9 30"),
    # manual trigger while idle -> exception 06 (busy)
    ("01 06 00 08 00 01 c9 c8", "01 86 06 c2 62"),
]


def test_recorder_rtu_golden_frames_on_the_url(bench):
    with socket.create_connection((bench.endpoints.recorder_host, bench.endpoints.recorder_port),
                                  timeout=2.0) as s:
        for request, reply in RTU_GOLDEN:
            assert exchange(s, request, len(bytes.fromhex(reply))) == reply, request


def test_recorder_rtu_golden_frames_on_the_pty(bench):
    with serial.Serial(bench.endpoints.recorder_serial, 19200, timeout=2.0) as port:
        for request, reply in RTU_GOLDEN:
            port.write(bytes.fromhex(request))
            assert port.read(len(bytes.fromhex(reply))).hex(" ") == reply, request
