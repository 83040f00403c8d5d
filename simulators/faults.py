"""Fault injection for the simulated devices, switchable at run time.

A fault is armed on a device (or on both) and hits the next matching requests:

- ``no_reply``: the request is executed, the reply is not sent;
- ``late_reply``: the request is executed, the reply is sent ``delay_s`` later;
- ``drop_connection``: the request is executed, the connection is closed instead of replying
  (on the recorder's pseudo-terminal the link is a bridge that reconnects: it looks like no reply);
- ``corrupt``: the reply frame is damaged on the wire (``mode`` ``flip``: one byte inverted so
  the CRC fails; ``truncate``: only the first half is sent; ``garbage``: noise bytes before it);
- ``exception``: the request is NOT executed, a Modbus exception reply with ``code`` is sent.

Matching: ``device`` (exciter | recorder | any), ``op`` (read | write | any), ``register`` (a
register name of the device's profile, or ``block`` for the recorder's data window: only
requests touching it), ``skip`` (let that many matching requests through first), ``count``
(how many requests it hits; None = until cleared).

Example::

    bench.faults.set("no_reply", device="exciter", count=1)
    bench.faults.set("exception", device="exciter", op="write", register="setpoint", code=4)
    bench.faults.set("corrupt", device="recorder", register="block", skip=3, count=2)
    bench.faults.clear()

CLI form (``--fault``): ``KIND[:key=value,...]``, e.g. ``late_reply:device=recorder,delay_s=0.3``.
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass, fields

from pymodbus.constants import ExcCodes

log = logging.getLogger(__name__)

KINDS = ("no_reply", "late_reply", "drop_connection", "corrupt", "exception")
DEVICES = ("exciter", "recorder", "any")
OPS = ("read", "write", "any")
CORRUPT_MODES = ("flip", "truncate", "garbage")
_EXC_CODES = {int(c) for c in ExcCodes}


@dataclass(frozen=True)
class Fault:
    """One armed fault (see the module docstring)."""

    kind: str
    device: str = "any"
    count: int | None = 1
    op: str = "any"
    register: str | None = None
    skip: int = 0
    delay_s: float = 0.5
    code: int = 4
    mode: str = "flip"

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"fault kind {self.kind!r} not in {KINDS}")
        if self.device not in DEVICES:
            raise ValueError(f"fault device {self.device!r} not in {DEVICES}")
        if self.op not in OPS:
            raise ValueError(f"fault op {self.op!r} not in {OPS}")
        if self.count is not None and self.count < 1:
            raise ValueError(f"fault count {self.count!r} must be >= 1 (or None = until cleared)")
        if self.skip < 0:
            raise ValueError(f"fault skip {self.skip!r} must be >= 0")
        if not 0.0 <= self.delay_s <= 600.0:
            raise ValueError(f"fault delay_s {self.delay_s!r} must be within 0..600 s")
        if self.code not in _EXC_CODES:
            raise ValueError(f"fault code {self.code!r} is not a Modbus exception code "
                             f"{sorted(_EXC_CODES)}")
        if self.mode not in CORRUPT_MODES:
            raise ValueError(f"fault mode {self.mode!r} not in {CORRUPT_MODES}")

    def matches(self, device: str, op: str, names: Iterable[str]) -> bool:
        if self.device not in ("any", device):
            return False
        if self.op not in ("any", op):
            return False
        return self.register is None or self.register in set(names)


@dataclass(frozen=True)
class FaultEvent:
    """A fault that hit a request (kept in `FaultSet.history`)."""

    time: float               # time.monotonic()
    fault: Fault
    device: str
    op: str
    names: tuple[str, ...]


class FaultSet:
    """The faults armed on a bench; thread-safe (set from any thread, consumed by the servers)."""

    def __init__(self, faults: Iterable[Fault] = ()) -> None:
        self._lock = threading.Lock()
        self._armed: list[list] = []   # [fault, remaining (None = forever), skip_left]
        self.history: list[FaultEvent] = []
        for f in faults:
            self.add(f)

    def set(self, kind: str, **kwargs) -> Fault:
        """Arm a fault: ``set("no_reply", device="exciter", count=1)``; returns it."""
        fault = Fault(kind=kind, **kwargs)
        self.add(fault)
        return fault

    def add(self, fault: Fault) -> None:
        with self._lock:
            self._armed.append([fault, fault.count, fault.skip])
        log.info("fault armed: %s", fault)

    def clear(self, kind: str | None = None, device: str | None = None) -> int:
        """Disarm faults (all, or of one kind / device); returns how many were removed."""
        with self._lock:
            keep = [e for e in self._armed
                    if not ((kind is None or e[0].kind == kind)
                            and (device is None or e[0].device == device))]
            removed = len(self._armed) - len(keep)
            self._armed = keep
        return removed

    def active(self) -> list[Fault]:
        with self._lock:
            return [e[0] for e in self._armed]

    def take(self, device: str, op: str, names: Iterable[str]) -> Fault | None:
        """The first armed fault matching this request, consumed by one hit (None: no fault)."""
        names = tuple(names)
        with self._lock:
            for entry in self._armed:
                fault = entry[0]
                if not fault.matches(device, op, names):
                    continue
                if entry[2] > 0:
                    entry[2] -= 1
                    continue
                if entry[1] is not None:
                    entry[1] -= 1
                    if entry[1] <= 0:
                        self._armed.remove(entry)
                self.history.append(FaultEvent(time.monotonic(), fault, device, op, names))
                log.info("fault %s hits %s %s %s", fault.kind, device, op, names)
                return fault
        return None


_FIELD_TYPES = {f.name: f.type for f in fields(Fault)}


def parse_fault(text: str) -> Fault:
    """``KIND[:key=value,...]`` -> Fault; ``count=inf`` (or 0) arms it until cleared."""
    kind, _, rest = text.partition(":")
    kwargs: dict[str, object] = {}
    for item in filter(None, (p.strip() for p in rest.split(","))):
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or key not in _FIELD_TYPES or key == "kind":
            raise ValueError(f"fault {text!r}: bad item {item!r}; keys: "
                             f"{', '.join(k for k in _FIELD_TYPES if k != 'kind')}")
        try:
            if key == "count":
                kwargs[key] = None if value in ("inf", "0", "none", "None") else int(value)
            elif key in ("skip", "code"):
                kwargs[key] = int(value, 0)
            elif key == "delay_s":
                kwargs[key] = float(value)
            else:
                kwargs[key] = value
        except ValueError:
            raise ValueError(f"fault {text!r}: {key} = {value!r} is not a valid value") from None
    try:
        return Fault(kind=kind.strip(), **kwargs)  # type: ignore[arg-type]
    except ValueError as exc:
        raise ValueError(f"fault {text!r}: {exc}") from None
