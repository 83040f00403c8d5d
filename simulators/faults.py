"""Fault injection for the simulated devices, switchable at run time.

A fault is armed on a device (or on both) and hits the next matching requests:

- ``no_reply``: the request is executed, the reply is not sent;
- ``late_reply``: the request is executed, the reply is sent ``delay_s`` later (with
  ``delay_max_s``: a delay drawn for each request, uniformly in ``delay_s..delay_max_s``, from
  the fault set's seeded generator);
- ``slow``: the device takes ``delay_s`` (or ``delay_s..delay_max_s``) to serve the request: it
  is executed that late, then answered at once (a busy device, a slow gateway: what it writes
  reaches the plant late, unlike ``late_reply``);
- ``drop_connection``: the request is executed, the connection is closed instead of replying
  (on the recorder's pseudo-terminal the link is a bridge that reconnects: it looks like no reply);
- ``corrupt``: the reply frame is damaged on the wire (``mode`` ``flip``: one byte inverted so
  the CRC fails; ``truncate``: only the first half is sent; ``garbage``: noise bytes before it);
- ``exception``: the request is NOT executed, a Modbus exception reply with ``code`` is sent.

Plant events (exciter only; the request itself is served normally, these act ``delay_s`` after it):

- ``load``: the turbine's mechanical power is set to ``mw`` MW (on line: a load rejection, a trip,
  reverse power; at no load the exciter's p reads ``mw``);
- ``limiter``: the exciter's status bit ``bit`` (a limiter: ``ceiling_limit``, ``rate_limit``...)
  reads 1 for ``duration_s`` (None: until cleared), as when the device's limiter acts.

Matching: ``device`` (exciter | recorder | any), ``op`` (read | write | any), ``register`` (a
register name of the device's profile, or ``block`` for the recorder's data window: only
requests touching it), ``after`` (``REGISTER:N``: only once the device has received N writes to
that register, the Nth included, e.g. ``setpoint:2``: from the end of a pulse or a step on),
``skip`` (let that many matching requests through first), ``count`` (how many requests it hits;
None = until cleared). ``after`` may name the other device: ``recorder.arm:1`` (once the recorder
is armed). A request meets at most one reply fault (the first armed that matches) and
any number of plant events.

Example::

    bench.faults.set("no_reply", device="exciter", count=1)
    bench.faults.set("exception", device="exciter", op="write", register="setpoint", code=4)
    bench.faults.set("corrupt", device="recorder", register="block", skip=3, count=2)
    bench.faults.set("late_reply", device="exciter", count=None, delay_s=0.1, delay_max_s=0.45)
    bench.faults.set("load", device="exciter", op="write", register="setpoint", mw=0.0, delay_s=0.5)
    bench.faults.set("no_reply", device="exciter", op="read", register="q", after="setpoint:2")
    bench.faults.clear()

CLI form (``--fault``): ``KIND[:key=value,...]``, e.g. ``late_reply:device=recorder,delay_s=0.3``.
"""
from __future__ import annotations

import logging
import random
import threading
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, fields

from pymodbus.constants import ExcCodes

log = logging.getLogger(__name__)

#: faults on the request's reply (or its service)
REPLY_KINDS = ("no_reply", "late_reply", "slow", "drop_connection", "corrupt", "exception")
#: events in the plant the request sets off (exciter only)
EVENT_KINDS = ("load", "limiter")
KINDS = REPLY_KINDS + EVENT_KINDS
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
    delay_max_s: float | None = None   # late_reply / slow: a delay drawn in delay_s..delay_max_s
    after: str | None = None           # "[DEVICE.]REGISTER:N": only from that device's Nth write to it
    mw: float | None = None            # load: the turbine's power (MW)
    bit: str | None = None             # limiter: the status bit that reads 1
    duration_s: float | None = None    # limiter: how long (None: until cleared)

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
        if self.delay_max_s is not None and not self.delay_s <= self.delay_max_s <= 600.0:
            raise ValueError(f"fault delay_max_s {self.delay_max_s!r} must be within delay_s..600 s")
        if self.after is not None:
            self.after_write()   # ValueError when malformed
        if self.kind in EVENT_KINDS and self.device != "exciter":
            raise ValueError(f"fault {self.kind!r} acts on the exciter's plant: device must be exciter")
        if self.kind == "load" and (self.mw is None or self.mw != self.mw or abs(self.mw) == float("inf")):
            raise ValueError("fault load needs mw (the turbine's power, MW)")
        if self.kind == "limiter" and not self.bit:
            raise ValueError("fault limiter needs bit (the status bit, e.g. ceiling_limit)")
        if self.duration_s is not None and not 0.0 < self.duration_s <= 3600.0:
            raise ValueError(f"fault duration_s {self.duration_s!r} must be within 0..3600 s")

    @property
    def is_event(self) -> bool:
        """A plant event (load, limiter), not a fault on the reply."""
        return self.kind in EVENT_KINDS

    def after_write(self) -> tuple[str | None, str, int] | None:
        """`after` as (device or None: the request's own, register, N), or None."""
        if self.after is None:
            return None
        where, _, n = self.after.partition(":")
        device, dot, name = where.rpartition(".")
        try:
            count = int(n) if n else 1
        except ValueError:
            count = 0
        if not name or count < 1 or (dot and device not in ("exciter", "recorder")):
            raise ValueError(f"fault after {self.after!r}: expected [exciter.|recorder.]REGISTER[:N] with N >= 1")
        return (device or None), name, count

    def matches(self, device: str, op: str, names: Iterable[str],
                writes: Counter[tuple[str, str]] | None = None) -> bool:
        if self.device not in ("any", device):
            return False
        if self.op not in ("any", op):
            return False
        after = self.after_write()
        if after is not None and (writes or Counter())[(after[0] or device, after[1])] < after[2]:
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

    def __init__(self, faults: Iterable[Fault] = (), *, seed: int | None = 0) -> None:
        self._lock = threading.Lock()
        self._armed: list[list] = []   # [fault, remaining (None = forever), skip_left]
        self.history: list[FaultEvent] = []
        #: writes each device received, by register name (the `after` of a fault counts them)
        self.writes: Counter[tuple[str, str]] = Counter()
        self._rng = random.Random(seed)
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
        """The first armed reply fault matching this request, consumed by one hit (None: no
        fault). A write is counted first (the `after` of the faults); plant events are taken
        apart (`take_events`)."""
        names = tuple(names)
        with self._lock:
            if op == "write":
                for name in names:
                    self.writes[(device, name)] += 1
            for entry in list(self._armed):
                if not entry[0].is_event and self._hit(entry, device, op, names):
                    return entry[0]
        return None

    def take_events(self, device: str, op: str, names: Iterable[str]) -> list[Fault]:
        """Every armed plant event matching this request (call after `take`, which counts it),
        each consumed by one hit."""
        names = tuple(names)
        with self._lock:
            return [entry[0] for entry in list(self._armed)
                    if entry[0].is_event and self._hit(entry, device, op, names)]

    def _hit(self, entry: list, device: str, op: str, names: tuple[str, ...]) -> bool:
        fault = entry[0]
        if not fault.matches(device, op, names, self.writes):
            return False
        if entry[2] > 0:
            entry[2] -= 1
            return False
        if entry[1] is not None:
            entry[1] -= 1
            if entry[1] <= 0:
                self._armed.remove(entry)
        self.history.append(FaultEvent(time.monotonic(), fault, device, op, names))
        log.info("fault %s hits %s %s %s", fault.kind, device, op, names)
        return True

    def delay_for(self, fault: Fault) -> float:
        """The delay of one hit of a late_reply / slow fault (drawn when it has a range)."""
        if fault.delay_max_s is None:
            return fault.delay_s
        with self._lock:
            return self._rng.uniform(fault.delay_s, fault.delay_max_s)


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
            elif key in ("delay_s", "delay_max_s", "mw"):
                kwargs[key] = float(value)
            elif key == "duration_s":
                kwargs[key] = None if value in ("inf", "none", "None") else float(value)
            else:
                kwargs[key] = value
        except ValueError:
            raise ValueError(f"fault {text!r}: {key} = {value!r} is not a valid value") from None
    try:
        return Fault(kind=kind.strip(), **kwargs)  # type: ignore[arg-type]
    except ValueError as exc:
        raise ValueError(f"fault {text!r}: {exc}") from None
