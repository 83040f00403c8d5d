"""One Modbus link (TCP, or RTU on a serial port / pyserial URL) with a log of its last frames.

`ModbusLink` wraps a pymodbus *sync* client and is the only place that talks to pymodbus:

- the client is built with `retries=0`, so pymodbus never re-sends a request by itself; reads
  (idempotent) are retried here, explicitly and once, writes never (a write whose reply is lost
  raises `WriteUncertain`);
- every frame on the wire goes through `FrameLog` (pymodbus' `trace_packet` hook), so each
  error carries the last frames and a write knows the monotonic time its request left;
- a lock serialises requests from the procedure and the heartbeat thread, and serves its waiters
  by priority, then in order of arrival (`LinkLock`): a timed write first (`hold()` takes the
  link before its deadline, so no other request delays it), then the heartbeat (a thread that
  runs `with link.priority(HEARTBEAT)`: no burst of other reads starves it), then the rest;
- every answered request's response time is kept (`response_times()`): the runner measures the
  link with it before the first write (docs/decisions/0023);
- `connect()` raises instead of returning False; `reconnect(deadline)` retries until a deadline.

Endpoint URLs: `tcp://HOST:PORT` (Modbus TCP); `rtu+tcp://HOST:PORT` (Modbus RTU frames over a
TCP socket: a serial device server / gateway in transparent mode, or the simulated recorder);
anything else is a serial port for Modbus RTU: a device path (`/dev/ttyUSB0`, a pty) or a
pyserial URL (`socket://HOST:PORT`, which works but is slow: pymodbus' serial client waits on
pyserial's `in_waiting`, which a socket reports as 0 or 1 byte, ~50 ms a request).
"""
from __future__ import annotations

import contextlib
import heapq
import itertools
import logging
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException
from pymodbus.framer import FramerType

from drivers.errors import CommError, DeviceError, ExceptionReply, WriteUncertain

log = logging.getLogger(__name__)

FRAMES_KEPT = 32       # frames kept per link
FRAMES_IN_ERRORS = 8   # frames appended to an error message
RESPONSES_KEPT = 256   # response times kept per link

#: who waits for the link first (`LinkLock`): a timed write, then the heartbeat, then the rest
TIMED, HEARTBEAT, ROUTINE = 0, 1, 2


#: per thread: how deep it is in a link lock's own bookkeeping (its queue, owner and count)
_BOOKKEEPING = threading.local()
#: interrupts a signal handler was asked to raise in the main thread while it was in that
#: bookkeeping: raised as soon as the bookkeeping is whole again (`defer_interrupt`)
_PENDING: list[BaseException] = []


def in_link_bookkeeping() -> bool:
    """The calling thread (a signal handler: the main thread) is changing a link lock's state: an
    exception raised now would leave the lock half changed (a waiter queued forever, an owner
    never cleared: every later request, the safe state's included, would wait forever)."""
    return getattr(_BOOKKEEPING, "depth", 0) > 0


def defer_interrupt(exc: BaseException) -> None:
    """Raise `exc` (a Ctrl-C, a SIGTERM) in the main thread once its link lock bookkeeping is
    whole: a waiter gives up its wait within 50 ms, nothing held; a lock just taken or given back
    raises it at once after."""
    _PENDING.append(exc)


def _enter_bookkeeping() -> None:
    _BOOKKEEPING.depth = getattr(_BOOKKEEPING, "depth", 0) + 1


def _leave_bookkeeping() -> None:
    _BOOKKEEPING.depth -= 1


def _raise_pending() -> None:
    if _PENDING and threading.current_thread() is threading.main_thread() and not in_link_bookkeeping():
        exc = _PENDING.pop(0)
        _PENDING.clear()
        raise exc


class LinkLock:
    """A re-entrant lock whose waiters get it by priority (lowest first: TIMED, HEARTBEAT,
    ROUTINE), then in order of arrival. A plain lock lets the thread that releases it take it
    again at once: a procedure reading in a loop could then hold off the heartbeat, or a timed
    write, for several requests of a slow device.

    Its bookkeeping is Python code, which a signal handler raising in the main thread (Ctrl-C,
    SIGTERM) could cut in half; the runner's handler defers the interrupt while the main thread
    takes, holds or gives back a link lock (`in_link_bookkeeping`, `defer_interrupt`), and the lock
    raises it where its state is whole: a wait is given up (within 50 ms) with nothing held, a
    lock held raises it as soon as it is given back (one request later at most)."""

    def __init__(self) -> None:
        self._cond = threading.Condition(threading.Lock())
        self._owner: int | None = None
        self._depth = 0
        self._queue: list[tuple[int, int, int]] = []
        self._tickets = itertools.count()

    def _acquire(self, priority: int, may_give_up: bool) -> bool:
        """Take the lock (True), or give up the wait for an interrupt pending (False, nothing held;
        only a thread holding no link lock may give up). Runs inside the bookkeeping."""
        me = threading.get_ident()
        with self._cond:
            if self._owner == me:
                self._depth += 1
                return True
            entry = (priority, next(self._tickets), me)
            heapq.heappush(self._queue, entry)
            while self._owner is not None or self._queue[0] is not entry:
                self._cond.wait(0.05)
                if may_give_up and _PENDING and threading.current_thread() is threading.main_thread():
                    self._queue.remove(entry)
                    heapq.heapify(self._queue)
                    self._cond.notify_all()
                    return False
            heapq.heappop(self._queue)
            self._owner, self._depth = me, 1
            return True

    def acquire(self, priority: int = ROUTINE) -> None:
        """Take the lock. The calling thread stays in the bookkeeping until the matching `release`
        has given it back: an interrupt meanwhile is deferred to that point (a request lasts at
        most its timeout), so no exception can leave between taking the lock and the code that
        gives it back (a `with` block's own set-up included)."""
        may_give_up = not in_link_bookkeeping()
        _enter_bookkeeping()
        try:
            got = self._acquire(priority, may_give_up)
        except BaseException:
            _leave_bookkeeping()
            raise
        if not got:
            _leave_bookkeeping()
            _raise_pending()

    def release(self) -> None:
        """Give the lock back; the bookkeeping is left only by a thread that held it (a generator
        of `held` finalised by the garbage collector in another thread must not unbalance it)."""
        with self._cond:
            if self._owner != threading.get_ident():
                raise RuntimeError("release of a link lock this thread does not hold")
            self._depth -= 1
            if self._depth == 0:
                self._owner = None
                self._cond.notify_all()
        _leave_bookkeeping()
        _raise_pending()

    @contextlib.contextmanager
    def held(self, priority: int = ROUTINE) -> Iterator[None]:
        self.acquire(priority)          # from here an interrupt is deferred ...
        try:
            yield
        finally:
            self.release()              # ... to the end of this

    def __enter__(self) -> LinkLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()



@dataclass(frozen=True)
class Frame:
    """One chunk on the wire: direction 'tx' / 'rx', monotonic time, bytes."""

    direction: str
    t_mono: float
    data: bytes

    def format(self, t0: float) -> str:
        return f"{(self.t_mono - t0) * 1e3:+10.1f} ms {self.direction} {self.data.hex(' ')}"


class FrameLog:
    """The last frames of a link; `trace_packet` is pymodbus' hook (it may not alter data).

    pymodbus hands the receive hook the whole buffer accumulated so far, so a received chunk
    that extends the previous rx entry replaces it instead of being logged twice.
    """

    def __init__(self, keep: int = FRAMES_KEPT) -> None:
        self._frames: deque[Frame] = deque(maxlen=keep)
        self._lock = threading.Lock()
        self.last_tx_mono: float | None = None

    def trace_packet(self, sending: bool, data: bytes) -> bytes:
        now = time.monotonic()
        with self._lock:
            if sending:
                self.last_tx_mono = now
                self._frames.append(Frame("tx", now, bytes(data)))
            elif data:
                last = self._frames[-1] if self._frames else None
                if last is not None and last.direction == "rx" and data.startswith(last.data):
                    self._frames[-1] = Frame("rx", last.t_mono, bytes(data))
                else:
                    self._frames.append(Frame("rx", now, bytes(data)))
        return data

    def frames(self) -> list[Frame]:
        with self._lock:
            return list(self._frames)

    def last(self, n: int = FRAMES_IN_ERRORS) -> list[str]:
        """The last `n` frames as text, times relative to the newest one."""
        frames = self.frames()[-n:]
        if not frames:
            return ["(no frames on this link yet)"]
        t0 = frames[-1].t_mono
        return [f.format(t0) for f in frames]


@dataclass(frozen=True)
class Endpoint:
    """Where a device is and how to reach it (serial settings are ignored for TCP)."""

    url: str
    unit_id: int = 1
    timeout_s: float = 1.0
    baudrate: int = 115200
    parity: str = "N"
    stopbits: int = 1
    bytesize: int = 8

    @property
    def is_tcp(self) -> bool:
        """Modbus TCP (MBAP framing)."""
        return self.url.startswith("tcp://")

    @property
    def is_rtu_over_tcp(self) -> bool:
        """Modbus RTU framing on a TCP socket."""
        return self.url.startswith("rtu+tcp://")

    def host_port(self) -> tuple[str, int]:
        """(host, port) of a tcp:// or rtu+tcp:// URL; ValueError naming the URL otherwise."""
        scheme = "tcp://" if self.is_tcp else "rtu+tcp://" if self.is_rtu_over_tcp else ""
        host, sep, port = self.url[len(scheme):].rpartition(":") if scheme else ("", "", "")
        if not (sep and host and port.isdigit() and 0 < int(port) < 65536):
            raise ValueError(f"endpoint {self.url!r}: expected tcp://HOST:PORT or rtu+tcp://HOST:PORT")
        return host.strip("[]"), int(port)


def _make_client(ep: Endpoint, frames: FrameLog) -> ModbusTcpClient | ModbusSerialClient:
    common: dict[str, Any] = dict(timeout=ep.timeout_s, retries=0, reconnect_delay=0,
                                  trace_packet=frames.trace_packet)
    if ep.is_tcp or ep.is_rtu_over_tcp:
        host, port = ep.host_port()
        framer = FramerType.RTU if ep.is_rtu_over_tcp else FramerType.SOCKET
        return ModbusTcpClient(host, port=port, framer=framer, **common)
    return ModbusSerialClient(ep.url, framer=FramerType.RTU, baudrate=ep.baudrate,
                              parity=ep.parity, stopbits=ep.stopbits, bytesize=ep.bytesize,
                              **common)


class ModbusLink:
    """Requests to one device on one link. No I/O before `connect()`."""

    def __init__(self, endpoint: Endpoint, device: str, *, read_attempts: int = 2) -> None:
        self.endpoint = endpoint
        self.device = device
        self.read_attempts = read_attempts
        self.frames = FrameLog()
        self._client = _make_client(endpoint, self.frames)
        self._lock = LinkLock()
        self._priority = threading.local()
        self._ends = threading.local()      # per thread: when its last request ended
        self._responses: deque[tuple[float, float]] = deque(maxlen=RESPONSES_KEPT)

    # -- connection --------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the link; CommError naming the endpoint when it cannot."""
        with self._lock:
            if not self._client.connect():
                raise CommError(f"cannot connect to {self.endpoint.url}", device=self.device,
                                frames=self.frames.last())
            log.debug("%s: connected to %s", self.device, self.endpoint.url)

    def close(self) -> None:
        with self._lock:
            self._client.close()

    @property
    def connected(self) -> bool:
        return bool(self._client.connected)

    def reconnect(self, deadline_mono: float, *, backoff_s: float = 0.05,
                  cancel: threading.Event | None = None) -> bool:
        """Close and reopen until it works, the monotonic deadline passes or `cancel` is set
        (checked between attempts); True when open."""
        attempt = 0
        while True:
            if attempt and cancel is not None and cancel.is_set():
                log.error("%s: reconnecting to %s stopped by the operator", self.device, self.endpoint.url)
                return False
            attempt += 1
            with self._lock:
                self._client.close()
                if self._client.connect():
                    log.warning("%s: reconnected to %s (attempt %d)", self.device,
                                self.endpoint.url, attempt)
                    return True
            if time.monotonic() + backoff_s > deadline_mono:
                log.error("%s: could not reconnect to %s within the deadline (%d attempts)",
                          self.device, self.endpoint.url, attempt)
                return False
            time.sleep(backoff_s)
            backoff_s = min(backoff_s * 2, 0.5)

    @contextlib.contextmanager
    def hold(self) -> Iterator[None]:
        """Keep the link for a timed sequence (other threads' requests wait); it is given before
        anything else that waits (the request in flight ends first)."""
        with self._lock.held(TIMED):
            yield

    @contextlib.contextmanager
    def priority(self, level: int) -> Iterator[None]:
        """This thread's requests wait for the link at `level` (HEARTBEAT for the heartbeat
        thread) inside the block."""
        old = getattr(self._priority, "level", ROUTINE)
        self._priority.level = level
        try:
            yield
        finally:
            self._priority.level = old

    def _request(self) -> contextlib.AbstractContextManager[None]:
        return self._lock.held(getattr(self._priority, "level", ROUTINE))

    def last_request_end(self) -> float | None:
        """When this thread's last request on the link ended (answered or failed), monotonic."""
        return getattr(self._ends, "t", None)

    def response_times(self, since_mono: float | None = None) -> list[float]:
        """The response times (s) of the answered requests kept (the last RESPONSES_KEPT), those
        sent at or after `since_mono` when given: request sent to reply read."""
        return [d for t, d in list(self._responses) if since_mono is None or t >= since_mono]

    # -- requests ----------------------------------------------------------------------------
    def _call(self, what: str, register: str | None, value: Any, fn: Any, *,
              write: bool, **kwargs: Any) -> Any:
        t0 = time.monotonic()
        try:
            reply = fn(**kwargs, device_id=self.endpoint.unit_id)
            self._responses.append((t0, time.monotonic() - t0))
        except (ConnectionException, ModbusException, OSError) as exc:
            self._ends.t = time.monotonic()
            cls = WriteUncertain if write and self.frames.last_tx_mono is not None else CommError
            text = f"{what} failed: {exc}"
            if cls is WriteUncertain:
                text += ("; the request may have reached the device (not re-sent: read back "
                         "before acting)")
            raise cls(text, device=self.device, register=register, value=value,
                      frames=self.frames.last()) from None
        self._ends.t = time.monotonic()
        if reply.isError():
            code = int(getattr(reply, "exception_code", 0) or 0)
            raise ExceptionReply(what, code=code, device=self.device, register=register,
                                 value=value, frames=self.frames.last())
        return reply

    def read(self, table: str, address: int, count: int, *, register: str | None = None,
             attempts: int | None = None) -> list[int]:
        """Read `count` words; on a link error tried again up to `attempts` (default
        `read_attempts`) times in all - reads are idempotent."""
        fn_name = "read_holding_registers" if table == "holding" else "read_input_registers"
        what = f"reading {count} {table} register(s) at {address}"
        attempts = self.read_attempts if attempts is None else attempts
        for attempt in range(1, attempts + 1):
            with self._request():
                fn = getattr(self._client, fn_name)
                try:
                    reply = self._call(what, register, None, fn, write=False,
                                       address=address, count=count)
                except CommError:
                    if attempt == attempts:
                        raise
                    log.warning("%s: %s failed, retrying (attempt %d of %d)", self.device, what,
                                attempt + 1, attempts)
                    continue
            words = list(reply.registers)
            if len(words) != count:
                raise CommError(f"{what}: got {len(words)} words", device=self.device,
                                register=register, frames=self.frames.last())
            return words
        raise AssertionError("unreachable")  # pragma: no cover

    def write(self, address: int, words: list[int], *, register: str | None = None,
              value: Any = None) -> float:
        """Write holding registers (function 16) once, never re-sent; returns the monotonic time
        the request frame left. WriteUncertain when the reply is lost."""
        # the words are in the frames (audit, -vv log), not in the operator's message
        what = f"writing {len(words)} holding register(s) at {address}"
        log.debug("%s: writing %s to holding register(s) at %d", self.device, words, address)
        with self._request():
            self.frames.last_tx_mono = None
            self._call(what, register, value, self._client.write_registers, write=True,
                       address=address, values=list(words))
            t_tx = self.frames.last_tx_mono
        assert t_tx is not None
        return t_tx


@contextlib.contextmanager
def gc_paused() -> Iterator[None]:
    """Collect garbage now, then keep the collector off for a short timed sequence (a pulse):
    a full collection stops every thread of the interpreter for tens of ms, which would land on
    whatever deadline is running (docs/benchmarks.md, "Timed writes and the garbage collector")."""
    import gc

    was_enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def wait_until(deadline_mono: float) -> None:
    """Return at the monotonic deadline. Plain sleeps: on Linux they wake within ~0.1 ms, and
    unlike a spin they do not hold the GIL against the threads that must serve the request
    (docs/benchmarks.md, "Timed writes and the garbage collector")."""
    while (left := deadline_mono - time.monotonic()) > 0:
        time.sleep(left)


__all__ = ["HEARTBEAT", "ROUTINE", "TIMED", "DeviceError", "Endpoint", "Frame", "FrameLog", "LinkLock",
           "ModbusLink", "defer_interrupt", "gc_paused", "in_link_bookkeeping", "wait_until"]
