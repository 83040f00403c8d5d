"""A Modbus device seen through its profile: read and write registers by name.

Shared by the exciter and recorder drivers. Every write is checked against the register's
range before anything is sent (`RangeError`), passed to an optional guard (the runner refuses
writes before the operator confirmed), sent once, then read back and compared word for word
(`ReadbackMismatch`); the resulting `WriteRecord` goes to an optional listener (the audit log).
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bench_ctl.timestamps import utc_at_monotonic
from drivers.errors import RangeError, ReadbackMismatch
from drivers.link import ModbusLink, wait_until
from drivers.profile import Profile, Register

log = logging.getLogger(__name__)

# A timed write sleeps without the link until this long before its deadline, then takes the
# link (so a heartbeat request in flight ends and no new one starts) and sleeps to the
# deadline. Longer than two request round trips of a slow device.
TIMED_WRITE_GUARD_S = 0.1
#: the most words `read_many` asks for in one request (Modbus allows 125)
MAX_READ_WORDS = 125


@dataclass(frozen=True)
class WriteRecord:
    """One write and its read-back, as the audit log and the capture sidecar keep it."""

    device: str
    register: str
    value: float
    raw: tuple[int, ...]
    readback: tuple[int, ...]
    t_tx_mono: float          # monotonic time the request frame left
    t_utc: str                # wall-clock time of the same moment
    purpose: str = ""
    at_mono: float | None = None       # a timed write: its deadline (monotonic)
    t_ask_mono: float | None = None    # a timed write: when it asked for the link
    t_prev_mono: float | None = None   # a timed write: when its thread's request before it ended
    t_link_mono: float | None = None   # a timed write: when it got the link (a request in flight ended)

    @property
    def matched(self) -> bool:
        return self.raw == self.readback

    def to_dict(self) -> dict[str, Any]:
        return {"device": self.device, "register": self.register, "value": self.value,
                "raw": list(self.raw), "readback": list(self.readback),
                "matched": self.matched, "t_tx_mono": self.t_tx_mono, "t_utc": self.t_utc,
                "purpose": self.purpose,
                **({"at_mono": self.at_mono, "t_ask_mono": self.t_ask_mono, "t_link_mono": self.t_link_mono,
                    "t_prev_mono": self.t_prev_mono} if self.at_mono is not None else {})}


@dataclass(frozen=True)
class SafeStateReport:
    """Outcome of one device's safe state. `ok` False means the device was NOT made safe."""

    device: str
    ok: bool
    action: str
    detail: str = ""
    reason: str = ""
    attempts: int = 0
    reconnected: bool = False
    writes: tuple[WriteRecord, ...] = field(default=())

    def to_dict(self) -> dict[str, Any]:
        return {"device": self.device, "ok": self.ok, "action": self.action,
                "detail": self.detail, "reason": self.reason, "attempts": self.attempts,
                "reconnected": self.reconnected, "writes": [w.to_dict() for w in self.writes]}


WriteGuard = Callable[[str, str, float, str], None]      # device, register, value, purpose
WriteListener = Callable[[WriteRecord], None]


class RegisterDevice:
    """Registers of one device by name. No I/O before `connect()`."""

    def __init__(self, link: ModbusLink, profile: Profile, *, guard: WriteGuard | None = None,
                 listener: WriteListener | None = None) -> None:
        self.link = link
        self.profile = profile
        self.name = link.device
        self.guard = guard
        self.listener = listener
        #: per thread: the last timed write's deadline and the moment it got the link (monotonic)
        self._timed = threading.local()

    # -- connection --------------------------------------------------------------------------
    def connect(self) -> None:
        self.link.connect()

    def close(self) -> None:
        self.link.close()

    def __enter__(self) -> RegisterDevice:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def identity(self) -> dict[str, Any]:
        """Who this device is: profile identity, profile name and where it was reached."""
        return {"device": self.name, "profile": self.profile.name, **self.profile.identity,
                "url": self.link.endpoint.url, "unit_id": self.link.endpoint.unit_id}

    @property
    def endpoint_url(self) -> str:
        """Where the device is reached (`tcp://HOST:PORT`, a serial port, `rtu+tcp://...`)."""
        return self.link.endpoint.url

    @property
    def unit_id(self) -> int:
        return self.link.endpoint.unit_id

    @property
    def request_timeout_s(self) -> float:
        """How long one request may take before it counts as lost."""
        return self.link.endpoint.timeout_s

    # -- registers ---------------------------------------------------------------------------
    def has(self, name: str) -> bool:
        """Whether the profile maps register `name` (an optional role such as efd)."""
        return name in self.profile.registers

    def register_names(self) -> tuple[str, ...]:
        """Every register of the profile, holding then input, in address order."""
        return tuple(reg.name for table in ("holding", "input") for reg in self.profile.by_table(table))

    def register(self, name: str) -> Register:
        return self.profile[name]

    def decode(self, name: str, words: list[int] | tuple[int, ...]) -> float:
        """The engineering value of register words read earlier (`read_words`)."""
        return self.register(name).decode(list(words))

    def read_words(self, name: str, *, attempts: int | None = None) -> list[int]:
        reg = self.register(name)
        return self.link.read(reg.table, reg.address, reg.count, register=self._label(reg),
                              attempts=attempts)

    def read(self, name: str, *, attempts: int | None = None) -> float:
        """Engineering value of one register (`attempts`: tries on a link error, default the
        link's; 1 where a read must never hold the link longer than one request timeout)."""
        reg = self.register(name)
        return reg.decode(self.read_words(name, attempts=attempts))

    def read_many(self, names: tuple[str, ...] | list[str], *, attempts: int | None = None,
                  start_by: float | None = None) -> dict[str, float]:
        """Engineering values of several registers in as few requests as the map allows: one
        request per run of registers that lie back to back in one table (every address between
        them mapped, at most MAX_READ_WORDS words), so a watch of vt, q, p and status costs one
        round trip on a map that keeps them together. Each request is as `read` (`attempts`).
        With `start_by` (monotonic) no request starts after it: what was not read by then is left
        out of the result (a read while a timed write is due: nothing of it can end later than one
        request after `start_by`)."""
        out: dict[str, float] = {}
        for table, start, count, regs in self._spans(tuple(dict.fromkeys(names))):
            if start_by is not None and time.monotonic() >= start_by:
                break
            words = self.link.read(table, start, count, register=", ".join(self._label(r) for r in regs),
                                   attempts=attempts)
            for reg in regs:
                out[reg.name] = reg.decode(words[reg.address - start:reg.end - start])
        return {name: out[name] for name in names if name in out}

    def _spans(self, names: tuple[str, ...]) -> list[tuple[str, int, int, list[Register]]]:
        """(table, start, count, registers) of each request `read_many` sends."""
        regs = sorted((self.register(n) for n in names), key=lambda r: (r.table, r.address))
        by_start = {(r.table, r.address): r for r in self.profile.registers.values()}
        spans: list[tuple[str, int, int, list[Register]]] = []
        for reg in regs:
            if spans:
                table, start, count, members = spans[-1]
                end = start + count
                if table == reg.table and reg.end - start <= MAX_READ_WORDS:
                    while end < reg.address and (table, end) in by_start:  # the registers between
                        end = by_start[(table, end)].end
                    if end == reg.address or reg.address < start + count:
                        spans[-1] = (table, start, max(start + count, reg.end) - start, [*members, reg])
                        continue
            spans.append((reg.table, reg.address, reg.count, [reg]))
        return spans

    def read_all(self) -> dict[str, float]:
        """Every register of the profile once, in table and address order."""
        return {name: self.read(name) for name in self.register_names()}

    def encode(self, name: str, value: float) -> list[int]:
        """Words for `value`, or RangeError (nothing sent)."""
        reg = self.register(name)
        if not reg.writable:
            raise RangeError("register is read-only", device=self.name,
                             register=self._label(reg), value=value)
        try:
            return reg.encode(value)
        except ValueError as exc:
            raise RangeError(f"value refused before sending: {exc}", device=self.name,
                             register=self._label(reg), value=value) from None

    def send(self, name: str, value: float, *, purpose: str = "",
             at_mono: float | None = None) -> tuple[list[int], float]:
        """Range check, guard, then send the write once (at `at_mono` when given); returns the
        words and the monotonic time the request left. No read-back: use `write`, or verify
        with `confirm` (the recorder checks its block selection against the block echo)."""
        reg = self.register(name)
        words = self.encode(name, value)
        if self.guard is not None:
            self.guard(self.name, name, value, purpose)
        label = self._label(reg)
        if at_mono is not None:
            # ask for the link one request timeout before the guard: a request in flight (the
            # heartbeat) to a slow device then ends, answered or timed out, before the deadline
            t_prev = self.link.last_request_end()
            wait_until(at_mono - TIMED_WRITE_GUARD_S - self.link.endpoint.timeout_s)
            t_ask = time.monotonic()
            with self.link.hold():
                t_held = time.monotonic()
                self._timed.value = (at_mono, t_ask, t_held, t_prev)
                wait_until(at_mono)
                t_tx = self.link.write(reg.address, words, register=label, value=value)
            log.debug("%s: timed write of %s: link held %.3f ms before the deadline, request "
                      "left %.3f ms after it", self.name, name, (at_mono - t_held) * 1e3,
                      (t_tx - at_mono) * 1e3)
        else:
            t_tx = self.link.write(reg.address, words, register=label, value=value)
        return words, t_tx

    def confirm(self, name: str, value: float, words: list[int], readback: list[int],
                t_tx: float, purpose: str, *, at_mono: float | None = None,
                t_ask_mono: float | None = None, t_link_mono: float | None = None,
                t_prev_mono: float | None = None) -> WriteRecord:
        """Record a write with its read-back words (listener), ReadbackMismatch when they
        differ from the words sent."""
        record = WriteRecord(device=self.name, register=name, value=value, raw=tuple(words),
                             readback=tuple(readback), t_tx_mono=t_tx, t_utc=utc_at_monotonic(t_tx),
                             purpose=purpose, at_mono=at_mono, t_ask_mono=t_ask_mono, t_link_mono=t_link_mono,
                             t_prev_mono=t_prev_mono)
        if self.listener is not None:
            self.listener(record)
        if not record.matched:
            raise ReadbackMismatch(f"read back {list(readback)} after writing {list(words)}",
                                   device=self.name, register=self._label(self.register(name)),
                                   value=value, frames=self.link.frames.last())
        log.debug("%s: wrote %s = %r %s (%s)", self.name, name, value, words, purpose)
        return record

    def write(self, name: str, value: float, *, purpose: str = "",
              at_mono: float | None = None) -> WriteRecord:
        """Write `value` once (at the monotonic time `at_mono` when given), read it back and
        compare the raw words. Never re-sent: a lost reply raises WriteUncertain."""
        self._timed.value = None
        words, t_tx = self.send(name, value, purpose=purpose, at_mono=at_mono)
        timed = self._timed.value if at_mono is not None else None
        reg = self.register(name)
        readback = self.link.read(reg.table, reg.address, reg.count, register=self._label(reg))
        at, ask, held, prev = timed if timed else (None, None, None, None)
        return self.confirm(name, value, words, readback, t_tx, purpose, at_mono=at, t_ask_mono=ask,
                            t_link_mono=held, t_prev_mono=prev)

    def _label(self, reg: Register) -> str:
        return f"{reg.name} ({reg.table} {reg.address})"
