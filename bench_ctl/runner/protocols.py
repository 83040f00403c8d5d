"""What a procedure may ask of the bench and its devices: small `typing.Protocol`s.

Procedures (`procedures/`) are typed against these, never against the drivers' classes, so a
procedure cannot come to depend on a driver's insides (its link, its profile, its heartbeat
thread): it reads and writes registers by name, asks whether an optional one is mapped
(`has("efd")`), runs the test sequence the drivers implement, and reads what it must show
(`endpoint_url`, `heartbeat_stats()`). `tests/test_layers.py` refuses a procedure that reaches
`.link`, `.profile` or `.heartbeat`. The drivers (`drivers.exciter.Exciter`,
`drivers.recorder.Recorder`) and the runner's `Bench` satisfy them; `tests/runner/test_protocols.py`
checks that they keep doing so.
"""
from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import Protocol, runtime_checkable

from drivers.device import SafeStateReport, WriteRecord
from drivers.exciter import HeartbeatStats, PreTest
from drivers.recorder import Progress, RawRecord, RecordSettings

__all__ = ["Device", "ExcitationSystem", "HeartbeatStats", "PreTest", "ProcedureBench", "RawRecord",
           "Recorder", "RecordSettings", "SafeStateReport", "WriteRecord"]


@runtime_checkable
class Device(Protocol):
    """Registers of one device by name, and where it is reached."""

    name: str

    @property
    def endpoint_url(self) -> str: ...

    @property
    def unit_id(self) -> int: ...

    @property
    def request_timeout_s(self) -> float: ...

    def has(self, name: str) -> bool: ...

    def register_names(self) -> tuple[str, ...]: ...

    def read(self, name: str, *, attempts: int | None = None) -> float: ...

    def read_words(self, name: str, *, attempts: int | None = None) -> list[int]: ...

    def read_many(self, names: tuple[str, ...] | list[str], *, attempts: int | None = None,
                  start_by: float | None = None) -> dict[str, float]: ...

    def decode(self, name: str, words: list[int] | tuple[int, ...]) -> float: ...

    def encode(self, name: str, value: float) -> list[int]: ...


@runtime_checkable
class ExcitationSystem(Device, Protocol):
    """The exciter's test sequence (docs/devices.md, "Exciter protocol")."""

    def remote_holder(self) -> str | None: ...

    def snapshot(self) -> PreTest: ...

    def take_remote(self) -> WriteRecord | None: ...

    def write_setpoint(self, value_pu: float, *, purpose: str,
                       at_mono: float | None = None) -> WriteRecord: ...

    def read_pss(self) -> bool | None: ...

    def write_pss(self, on: bool, *, purpose: str, at_mono: float | None = None) -> WriteRecord: ...

    def heartbeat_stats(self) -> HeartbeatStats: ...

    def measure_link(self, reads: int, since_mono: float | None = None) -> list[float]: ...

    def bits(self, register: str) -> dict[str, bool]: ...

    def bits_of(self, register: str, value: float) -> dict[str, bool]: ...

    def safe_state(self, reason: str, *, deadline_s: float | None = None, reconnect: bool = False,
                   cancel: threading.Event | None = None) -> SafeStateReport: ...


@runtime_checkable
class Recorder(Device, Protocol):
    """The recorder's sequence (docs/devices.md, "Recorder protocol")."""

    #: the recorded channels, in frame order (the profile's `channels`)
    channels: tuple[str, ...]

    def status(self) -> str: ...

    def configure(self, rec: RecordSettings) -> list[WriteRecord]: ...

    def arm(self) -> WriteRecord: ...

    def wait_status(self, targets: tuple[str, ...], timeout_s: float, *, poll_s: float = 0.02,
                    check: Callable[[], None] | None = None) -> str: ...

    def download(self, progress: Progress | None = None) -> RawRecord: ...


@runtime_checkable
class ProcedureBench(Protocol):
    """The bench as a procedure sees it: both devices and the heartbeat's health check."""

    @property
    def exciter(self) -> ExcitationSystem: ...

    @property
    def recorder(self) -> Recorder: ...

    @property
    def devices(self) -> Sequence[Device]: ...

    def check(self) -> None: ...
