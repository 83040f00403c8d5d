"""The simulated bench: one plant, the exciter on Modbus TCP, the recorder on Modbus RTU.

Embedding (tests, `bench-ctl run --dry-run`, `bench-ctl demo`)::

    from simulators.bench import SimBench
    with SimBench(unit=None, tcp=("127.0.0.1", 0)) as bench:
        ep = bench.endpoints
        ep.exciter_tcp          # ("127.0.0.1", port)   Modbus TCP, unit id 1
        ep.recorder_url         # "socket://127.0.0.1:port"  RTU framing over TCP, unit id 1
        ep.recorder_rtu_tcp     # "rtu+tcp://127.0.0.1:port" the same socket, as drivers reach it
        ep.recorder_serial      # "/dev/pts/N"  RTU on a pseudo-terminal (None with serial=False)
        bench.faults.set("no_reply", device="exciter", count=1)
        bench.exciter.set_load_mw(50.0)     # break the no-load precondition
        bench.plant.state()                 # PlantState (vt, efd, ...)

    SimBench(online=True, recorder_profile="sim-recorder-online")   # the unit on the grid: P, Q
        # follow the machine (its [grid] data), the recorder records p, q and ifd too
    SimBench(online=True, unit_set=("PSS_MODEL=IEEEST", "PSS_KS=5"))  # the unit with `--set`
        # overrides (here a stabiliser, switched by the exciter's pss_on)

`start()` returns once both servers listen and the plant runs (no sleeps to guess); `stop()`
(or leaving the `with`) shuts everything down. The servers run on an asyncio loop in a
background thread, the plant in its own thread; `async with SimBench(...)` works too (start
and stop run in an executor). Everything binds to 127.0.0.1 unless told otherwise.

While running, the bench lowers the interpreter's thread switch interval to 0.5 ms
(`switch_interval_s`, None leaves it alone; restored by `stop()`) so the plant thread keeps
real time while the server thread is busy. Once started it also freezes the objects that exist
(`gc.freeze()`, undone by `stop()`): a full collection over everything numba, numpy and pymodbus
import stops every Python thread of the process for tens of ms (docs/benchmarks.md, "Timed writes
and the garbage collector"); in a long-running bench one would hold a setpoint write back that
long, a wider pulse on the wire.
Frozen, a full collection walks only what was allocated since.
"""
from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import sys
import threading
from collections.abc import Iterable
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path

from bench_ctl.plants import OnlinePlant, Plant
from bench_ctl.units.overrides import apply_overrides
from bench_ctl.units.unit import Unit, load_unit
from drivers.profile import Profile, load_profile

from .control import start_control
from .exciter import ExciterDevice
from .faults import Fault, FaultSet
from .modbus import FaultTcpServer, start_server
from .pty_bridge import PtyBridge
from .recorder import RecorderDevice

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Endpoints:
    """Where the simulated devices listen."""

    exciter_host: str
    exciter_port: int
    exciter_unit_id: int
    recorder_host: str
    recorder_port: int
    recorder_unit_id: int
    recorder_serial: str | None = None     # /dev/pts/N
    recorder_link: str | None = None       # symlink to it, when asked for

    @property
    def exciter_tcp(self) -> tuple[str, int]:
        return (self.exciter_host, self.exciter_port)

    @property
    def recorder_url(self) -> str:
        """pyserial URL of the RTU-over-TCP socket (any serial client)."""
        return f"socket://{self.recorder_host}:{self.recorder_port}"

    @property
    def recorder_rtu_tcp(self) -> str:
        """The same socket as a driver endpoint (drivers.link: RTU framing on a TCP client)."""
        return f"rtu+tcp://{self.recorder_host}:{self.recorder_port}"

    def describe(self) -> str:
        lines = [f"exciter  Modbus TCP  {self.exciter_host}:{self.exciter_port}  unit {self.exciter_unit_id}",
                 f"recorder Modbus RTU   {self.recorder_rtu_tcp} (pyserial: {self.recorder_url})  "
                 f"unit {self.recorder_unit_id}"]
        if self.recorder_serial:
            link = f" (link {self.recorder_link})" if self.recorder_link else ""
            lines.append(f"recorder Modbus RTU   {self.recorder_serial}{link}  unit {self.recorder_unit_id}")
        return "\n".join(lines)


def _profile(p: str | Path | Profile) -> Profile:
    return p if isinstance(p, Profile) else load_profile(p)



_freeze_lock = threading.Lock()
_freeze_users = 0  # running benches in this process: the last one to stop thaws


def _freeze() -> None:
    """Collect, then keep what exists out of later full collections (see the module docstring)."""
    global _freeze_users
    with _freeze_lock:
        if _freeze_users == 0:
            gc.collect()
            gc.freeze()
        _freeze_users += 1


def _thaw() -> None:
    global _freeze_users
    with _freeze_lock:
        _freeze_users -= 1
        if _freeze_users == 0:
            gc.unfreeze()

async def _drain_tasks(rounds: int = 3) -> None:
    """End what a client's last requests left on the loop, so stopping while a client is
    connected is silent: let scheduled callbacks run (pymodbus hands each request to a task
    two callbacks later), then cancel and await every task still pending (asyncio reports a
    task destroyed while pending, and a coroutine never awaited, as errors at exit)."""
    for _ in range(rounds):
        await asyncio.sleep(0)
    me = asyncio.current_task()
    pending = [t for t in asyncio.all_tasks() if t is not me and not t.done()]
    for task in pending:
        task.cancel()
    await asyncio.gather(*pending, return_exceptions=True)


def bench_unit(unit: Unit | str | Path | None, unit_set: Iterable[str] = ()) -> Unit:
    """The bench's unit: a Unit, a unit file or the reference unit (None), with `unit_set`'s
    `--set NAME=VALUE` overrides applied."""
    unit = unit if isinstance(unit, Unit) else load_unit(unit)
    unit_set = tuple(unit_set)
    return apply_overrides(unit, unit_set) if unit_set else unit


def warm_plant(unit: Unit | str | Path | None = None, *, online: bool = False, mva: float = 100.0,
               unit_set: Iterable[str] = (), **_options: object) -> None:
    """Compile (or load from numba's cache) the plant a `SimBench` of these options steps: its
    engine variant and real-time loop. A dry run calls it before it starts the bench in a child
    process, so that a first run compiles in the process whose console says so."""
    unit = bench_unit(unit, unit_set)
    plant = OnlinePlant(unit, rt_priority=None, mva=mva) if online else Plant(unit, rt_priority=None)
    plant.warm()


class SimBench:
    """Both simulated devices around one real-time plant (see the module docstring)."""

    def __init__(self, unit: Unit | str | Path | None = None, *,
                 tcp: tuple[str, int] = ("127.0.0.1", 0),
                 recorder_tcp: tuple[str, int] = ("127.0.0.1", 0),
                 serial: bool | str | Path = True,
                 exciter_profile: str | Path | Profile = "sim-exciter",
                 recorder_profile: str | Path | Profile = "sim-recorder",
                 exciter_unit_id: int = 1, recorder_unit_id: int = 1,
                 heartbeat_timeout_s: float | None = None, load_mw: float = 0.0,
                 noise_pu: float = 0.01, seed: int | None = 0,
                 faults: Iterable[Fault] = (), switch_interval_s: float | None = 0.0005,
                 control: tuple[str, int] | None = None, rt_priority: int | None = 10,
                 online: bool = False, mva: float = 100.0, unit_set: Iterable[str] = ()) -> None:
        self.unit = bench_unit(unit, unit_set)
        self.tcp = tcp
        self.recorder_tcp = recorder_tcp
        self.serial = serial
        self.exciter_unit_id = exciter_unit_id
        self.recorder_unit_id = recorder_unit_id
        self.faults = FaultSet(faults)
        #: on line: the unit synchronised through XE (`OnlinePlant`, machine base `mva` MVA)
        self.plant = OnlinePlant(self.unit, rt_priority=rt_priority, mva=mva) if online \
            else Plant(self.unit, rt_priority=rt_priority)
        self.exciter = ExciterDevice(self.plant, _profile(exciter_profile),
                                     heartbeat_timeout_s=heartbeat_timeout_s, load_mw=load_mw)
        self.recorder = RecorderDevice(self.plant, _profile(recorder_profile), noise_pu=noise_pu,
                                       seed=seed)
        self.endpoints: Endpoints | None = None
        self.switch_interval_s = switch_interval_s
        self._old_switch: float | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._servers: list[FaultTcpServer] = []
        self._bridge: PtyBridge | None = None
        self.control = control
        self.control_address: tuple[str, int] | None = None
        self._control_server: asyncio.AbstractServer | None = None
        self._stop_requested: asyncio.Event | None = None
        self._frozen = False

    # ---------------------------------------------------------------- life cycle
    def start(self) -> Endpoints:
        """Start plant, servers and serial line; returns the endpoints once all listen."""
        if self._thread is not None:
            raise RuntimeError("bench already started")
        ready: Future = Future()
        if self.switch_interval_s is not None:
            # the plant thread must get the GIL within a fraction of a step; the default
            # switch interval (5 ms) lets a busy server thread hold it for several steps
            self._old_switch = sys.getswitchinterval()
            sys.setswitchinterval(self.switch_interval_s)
        self._stop_requested = asyncio.Event()   # bound to the bench's loop on first use
        self._thread = threading.Thread(target=self._run_loop, args=(ready,), name="sim-bench",
                                        daemon=True)
        self._thread.start()
        try:
            self.endpoints = ready.result(timeout=120)
        except BaseException:
            self.stop()
            raise
        _freeze()
        self._frozen = True
        return self.endpoints

    def _run_loop(self, ready: Future) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._serve(ready))
            loop.run_until_complete(loop.shutdown_asyncgens())
        finally:
            loop.close()

    async def _serve(self, ready: Future) -> None:
        """Start, serve until stop() asks, then shut down, all in one task: a stop() that
        arrives while starting or shutting down (a failed start) cannot cut the shutdown short."""
        try:
            await self._astart(ready)
            if ready.exception() is None:
                await self._stop_requested.wait()
        finally:
            await self._astop()

    async def _astart(self, ready: Future) -> None:
        try:
            self.plant.start()
            exc_srv = await start_server(self.exciter, self.exciter_unit_id, self.faults,
                                         self.tcp, rtu=False)
            self._servers.append(exc_srv)
            rec_srv = await start_server(self.recorder, self.recorder_unit_id, self.faults,
                                         self.recorder_tcp, rtu=True)
            self._servers.append(rec_srv)
            eh, ep = exc_srv.bound_address()
            rh, rp = rec_srv.bound_address()
            serial_path = link = None
            if self.serial:
                link = None if self.serial is True else str(self.serial)
                self._bridge = PtyBridge((rh, rp), link=link)
                serial_path = await self._bridge.start()
            if self.control is not None:
                self._control_server = await start_control(self, self.control)
                self.control_address = self._control_server.sockets[0].getsockname()[:2]
            ready.set_result(Endpoints(eh, ep, self.exciter_unit_id, rh, rp,
                                       self.recorder_unit_id, serial_path, link))
        except BaseException as exc:  # hand the failure to start()
            ready.set_exception(exc)

    async def _astop(self) -> None:
        if self._control_server is not None:
            self._control_server.close()
            self._control_server = None
        if self._bridge is not None:
            await self._bridge.stop()
            self._bridge = None
        for srv in self._servers:
            await srv.shutdown()
        self._servers = []
        self.plant.stop()
        await _drain_tasks()

    def stop(self) -> None:
        """Stop servers, serial line and plant (idempotent)."""
        loop, thread = self._loop, self._thread
        if loop is not None and thread is not None and thread.is_alive():
            with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                loop.call_soon_threadsafe(self._stop_requested.set)
            thread.join(timeout=10)
        self.plant.stop()
        self._thread = None
        self._loop = None
        if self._old_switch is not None:
            sys.setswitchinterval(self._old_switch)
            self._old_switch = None
        if self._frozen:
            _thaw()
            self._frozen = False

    def __enter__(self) -> SimBench:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    async def __aenter__(self) -> SimBench:
        await asyncio.get_running_loop().run_in_executor(None, self.start)
        return self

    async def __aexit__(self, *exc) -> None:
        await asyncio.get_running_loop().run_in_executor(None, self.stop)

    def call_soon(self, fn, *args) -> None:
        """Run fn(*args) on the bench's event loop (e.g. to drop connections from a test)."""
        if self._loop is None:
            raise RuntimeError("bench not started")
        self._loop.call_soon_threadsafe(fn, *args)
