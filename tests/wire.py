"""Raw Modbus RTU framing for the wire-level tests, written by hand so that golden frames do not
depend on the Modbus library under test. Checked against the two frames every Modbus text quotes
(tests/simulators/test_sim_golden.py::test_crc_helper_matches_the_textbook_frames)."""
from __future__ import annotations


def crc16(frame: bytes) -> bytes:
    """Modbus RTU CRC-16 (poly 0xA001 reflected, init 0xFFFF), low byte first."""
    crc = 0xFFFF
    for b in frame:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes([crc & 0xFF, crc >> 8])


def rtu(hexstr: str) -> bytes:
    """A frame from hex (spaces allowed) with its CRC appended."""
    frame = bytes.fromhex(hexstr)
    return frame + crc16(frame)
