"""Register image: serves a device model through any profile of its kind.

The device models (`exciter.py`, `recorder.py`) work on register *names* and engineering
values; this module turns a Modbus request (table, address, count[, words]) into those names
using the profile, and back into words. Rules, as a strict real device:

- a read or write must cover whole registers (no half of a 32-bit value) and no unmapped
  address -> exception 02 (illegal data address);
- writes to read-only registers -> 02; values outside the register's min/max -> 03;
- readings are rounded to the register's resolution and saturate at its type range (what a
  device does with a value it cannot show; this is the device, not the host, so it is allowed).
"""
from __future__ import annotations

import contextvars
import logging
import math
import struct
from collections.abc import Mapping, Sequence
from typing import Protocol

from pymodbus.constants import ExcCodes

from drivers.profile import Profile, Register

log = logging.getLogger(__name__)

#: the master (client address) the request being served came from, set by the Modbus server for
#: each request; None when a device model is called directly (the device's own panel). A device
#: that tracks which master holds it (the exciter's remote) reads it.
CLIENT: contextvars.ContextVar[str | None] = contextvars.ContextVar("modbus_client", default=None)

_INT_RANGE = {"uint16": (0, 0xFFFF), "int16": (-0x8000, 0x7FFF),
              "uint32": (0, 0xFFFFFFFF), "int32": (-0x80000000, 0x7FFFFFFF)}


class DeviceModel(Protocol):
    """What a simulated device offers to the register image."""

    kind: str
    profile: Profile

    def snapshot(self) -> Mapping[str, float]:
        """Engineering value of every readable register name, taken at one instant."""

    def write(self, items: Sequence[tuple[Register, float]]) -> ExcCodes | None:
        """Apply decoded writes (range already checked), or refuse with an exception code."""

    def read_window(self, offset: int, count: int) -> list[int] | ExcCodes:
        """Raw words of a data window (recorder block), offset from the window start."""


def encode_reading(reg: Register, value: float) -> list[int]:
    """A device reading -> words: rounded to resolution, saturated at the type range."""
    if not math.isfinite(value):
        value = 0.0 if math.isnan(value) else math.copysign(3.0e38, value)
    raw = value / reg.scale
    if reg.type == "float32":
        raw = max(min(raw, 3.4028234e38), -3.4028234e38)
        (u32,) = struct.unpack(">I", struct.pack(">f", raw))
    else:
        lo, hi = _INT_RANGE[reg.type]
        count = min(max(int(round(raw)), lo), hi)
        if reg.count == 1:
            return [count & 0xFFFF]
        u32 = count & 0xFFFFFFFF
    hi_w, lo_w = (u32 >> 16) & 0xFFFF, u32 & 0xFFFF
    return [hi_w, lo_w] if reg.word_order == "ABCD" else [lo_w, hi_w]


class RegisterImage:
    """Maps requests on a profile's tables to a device model."""

    def __init__(self, device: DeviceModel) -> None:
        self.device = device
        self.profile = device.profile
        self._start: dict[tuple[str, int], Register] = {}
        for reg in self.profile.registers.values():
            self._start[(reg.table, reg.address)] = reg
        self._window = None
        spans = self.profile.data_window_spans()
        if spans:
            _, table, start, end = spans[0]
            self._window = (table, start, end)

    def table_end(self, table: str) -> int:
        """One past the highest address used in a table (0 when unused)."""
        ends = [r.end for r in self.profile.registers.values() if r.table == table]
        if self._window and self._window[0] == table:
            ends.append(self._window[2])
        return max(ends, default=0)

    def names(self, table: str, address: int, count: int) -> list[str]:
        """Register names a request touches ('block' for the data window); for fault matching."""
        out = []
        end = address + count
        for reg in self.profile.registers.values():
            if reg.table == table and reg.address < end and address < reg.end:
                out.append(reg.name)
        if self._window and self._window[0] == table and self._window[1] < end \
                and address < self._window[2]:
            out.append("block")
        return out

    def _layout(self, table: str, address: int, count: int) -> list | ExcCodes:
        """[(Register, None) | ("window", (offset, n))] covering the request exactly."""
        parts: list = []
        a, end = address, address + count
        while a < end:
            win = self._window
            if win and win[0] == table and win[1] <= a < win[2]:
                n = min(end, win[2]) - a
                parts.append(("window", (a - win[1], n)))
                a += n
                continue
            reg = self._start.get((table, a))
            if reg is None or reg.end > end:
                return ExcCodes.ILLEGAL_ADDRESS
            parts.append((reg, None))
            a = reg.end
        return parts

    def read(self, table: str, address: int, count: int) -> list[int] | ExcCodes:
        layout = self._layout(table, address, count)
        if isinstance(layout, ExcCodes):
            return layout
        snap = self.device.snapshot() if any(p[0] != "window" for p in layout) else {}
        words: list[int] = []
        for reg, extra in layout:
            if reg == "window":
                got = self.device.read_window(*extra)
                if isinstance(got, ExcCodes):
                    return got
                words.extend(got)
            else:
                words.extend(encode_reading(reg, float(snap.get(reg.name, 0.0))))
        return words

    def write(self, table: str, address: int, values: Sequence[int]) -> ExcCodes | None:
        layout = self._layout(table, address, len(values))
        if isinstance(layout, ExcCodes):
            return layout
        items: list[tuple[Register, float]] = []
        pos = 0
        for reg, _ in layout:
            if reg == "window" or not reg.writable:
                return ExcCodes.ILLEGAL_ADDRESS
            words = list(values[pos:pos + reg.count])
            pos += reg.count
            value = reg.decode(words)
            try:
                reg.check_range(value)
            except ValueError as exc:
                log.info("%s refuses write: %s", self.device.kind, exc)
                return ExcCodes.ILLEGAL_VALUE
            items.append((reg, value))
        return self.device.write(items)
