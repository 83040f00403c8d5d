"""Golden frames: the bytes the drivers put on the wire, pinned by hand.

The expected requests below are written from the Modbus specification and the register
addresses in the device manuals (here: docs/devices.md), not
derived from drivers/profile.py, so a wrong address, word order or scale in the shared codec or
a profile cannot pass by agreeing with itself. A scripted server plays the device: it checks
nothing, records what it receives and sends the canned replies.
"""
from __future__ import annotations

import socket
import threading

import pytest

from drivers.errors import ExceptionReply, RangeError, ReadbackMismatch, WriteUncertain
from drivers.exciter import Exciter
from drivers.link import Endpoint, ModbusLink
from drivers.profile import load_profile
from drivers.recorder import Recorder
from wire import crc16, rtu


class ScriptedDevice:
    """Accepts one TCP connection; for each (request length, reply) reads that many bytes,
    records them, then sends the reply (None: stay silent)."""

    def __init__(self, script: list[tuple[int, bytes | None]]) -> None:
        self.script = script
        self.received: list[bytes] = []
        self.extra = b""
        self._srv = socket.socket()
        self._srv.bind(("127.0.0.1", 0))
        self._srv.listen(1)
        self.port = self._srv.getsockname()[1]
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        conn, _ = self._srv.accept()
        conn.settimeout(2.0)
        try:
            for length, reply in self.script:
                data = b""
                while len(data) < length:
                    chunk = conn.recv(length - len(data))
                    if not chunk:
                        return
                    data += chunk
                self.received.append(data)
                if reply is not None:
                    conn.sendall(reply)
            conn.settimeout(0.3)  # anything more (a resend) would be recorded here
            try:
                self.extra = conn.recv(4096)
            except OSError:
                pass
        finally:
            conn.close()
            self._done.set()

    def finish(self) -> None:
        assert self._done.wait(5), "the scripted device did not finish"
        self._srv.close()


def h(hexstr: str) -> bytes:
    return bytes.fromhex(hexstr)


def exciter(profile: str, port: int, timeout_s: float = 1.0) -> Exciter:
    link = ModbusLink(Endpoint(f"tcp://127.0.0.1:{port}", unit_id=1, timeout_s=timeout_s),
                      "exciter")
    ex = Exciter(link, load_profile(profile))
    ex.connect()
    return ex


def test_crc_reference_vector():
    # the specification's example: read holding register 0, count 1, unit 1 -> CRC 84 0A
    assert crc16(h("010300000001")) == h("840a")


def test_setpoint_write_sim_profile_float32_abcd():
    # setpoint = holding 0-1, float32 high word first; 1.05 = 0x3F866666
    dev = ScriptedDevice([
        (17, h("0001 0000 0006 01 10 0000 0002")),
        (12, h("0002 0000 0007 01 03 04 3f86 6666")),
    ])
    ex = exciter("sim-exciter", dev.port)
    rec = ex.write("setpoint", 1.05)
    ex.close()
    dev.finish()
    assert dev.received == [h("0001 0000 000b 01 10 0000 0002 04 3f86 6666"),
                            h("0002 0000 0006 01 03 0000 0002")]
    assert rec.raw == rec.readback == (0x3F86, 0x6666)


def test_setpoint_write_vendor_profile_int32_cdab_scaled():
    # vendor manual: setpoint = holding 1000-1001 (0x03E8), int32, 0.0001 pu/count, low word
    # first: 1.05 pu = 10500 = 0x00002904 -> words 2904 0000
    dev = ScriptedDevice([
        (17, h("0001 0000 0006 01 10 03e8 0002")),
        (12, h("0002 0000 0007 01 03 04 2904 0000")),
        # p = input 2005-2006 (0x07D5), int32 CDAB, 0.01 MW: -12.34 MW = -1234 = 0xFFFFFB2E
        (12, h("0003 0000 0007 01 04 04 fb2e ffff")),
    ])
    ex = exciter("vendor-exciter", dev.port)
    ex.write("setpoint", 1.05)
    p_mw = ex.read("p")
    ex.close()
    dev.finish()
    assert dev.received == [h("0001 0000 000b 01 10 03e8 0002 04 2904 0000"),
                            h("0002 0000 0006 01 03 03e8 0002"),
                            h("0003 0000 0006 01 04 07d5 0002")]
    assert p_mw == pytest.approx(-12.34, abs=1e-9)


@pytest.mark.parametrize("scheme", ["socket://", "rtu+tcp://"])  # pyserial URL, TCP client + RTU framer
def test_recorder_arm_rtu_frames(scheme):
    # recorder: arm = holding 7, write 1 (function 16), unit 1, RTU framing with CRC
    dev = ScriptedDevice([
        (11, rtu("01 10 0007 0001")),
        (8, rtu("01 03 02 0001")),
    ])
    link = ModbusLink(Endpoint(f"{scheme}127.0.0.1:{dev.port}", unit_id=1, timeout_s=1.0),
                      "recorder")
    rec = Recorder(link, load_profile("sim-recorder"))
    rec.connect()
    rec.arm()
    rec.close()
    dev.finish()
    assert dev.received == [rtu("01 10 0007 0001 02 0001"), rtu("01 03 0007 0001")]


def test_lost_reply_is_write_uncertain_and_never_resent():
    dev = ScriptedDevice([(17, None)])
    ex = exciter("sim-exciter", dev.port, timeout_s=0.2)
    with pytest.raises(WriteUncertain) as err:
        ex.write("setpoint", 1.05)
    ex.close()
    dev.finish()
    assert dev.received == [h("0001 0000 000b 01 10 0000 0002 04 3f86 6666")]
    assert dev.extra == b""                      # no resend, no read-back after a lost reply
    text = str(err.value)
    assert "exciter" in text and "setpoint (holding 0)" in text and "value 1.05" in text
    assert "tx 00 01 00 00 00 0b 01 10 00 00 00 02 04 3f 86 66 66" in text
    assert "not re-sent" in text


def test_exception_reply_names_code_and_stops():
    dev = ScriptedDevice([(17, h("0001 0000 0003 01 90 03"))])
    ex = exciter("sim-exciter", dev.port)
    with pytest.raises(ExceptionReply) as err:
        ex.write("setpoint", 1.05)
    ex.close()
    dev.finish()
    assert err.value.code == 3
    assert "exception 3 (illegal data value)" in str(err.value)
    assert dev.extra == b""                      # no read-back of a refused write


def test_out_of_range_value_is_refused_before_sending():
    dev = ScriptedDevice([])
    ex = exciter("sim-exciter", dev.port)
    with pytest.raises(RangeError, match="above max 1.1"):
        ex.write("setpoint", 1.2)
    with pytest.raises(RangeError, match="read-only"):
        ex.write("vt", 1.0)
    ex.close()
    dev.finish()
    assert dev.extra == b""


def test_readback_mismatch_is_an_error_with_both_words():
    dev = ScriptedDevice([
        (17, h("0001 0000 0006 01 10 0000 0002")),
        (12, h("0002 0000 0007 01 03 04 3f80 0000")),
    ])
    ex = exciter("sim-exciter", dev.port)
    with pytest.raises(ReadbackMismatch, match=r"read back \[16256, 0\] after writing "
                                               r"\[16262, 26214\]"):
        ex.write("setpoint", 1.05)
    ex.close()
    dev.finish()
