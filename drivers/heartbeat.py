"""The heartbeat a host keeps writing while it holds a device's remote (`Exciter.take_remote`):
an incrementing counter every `period_s`; a failed beat is counted and the next beat writes the
next value (never a resend). If the host dies the device's watchdog acts by itself."""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass

from drivers.device import RegisterDevice
from drivers.errors import DeviceError
from drivers.link import HEARTBEAT as HEARTBEAT_PRIORITY

log = logging.getLogger(__name__)

HEARTBEAT = "heartbeat"


@dataclass(frozen=True)
class HeartbeatStats:
    """How the heartbeat went: beats written, beats that failed, the longest gap between two
    good beats (s)."""

    beats: int
    failures: int
    max_gap_s: float


class Heartbeat:
    """Background thread keeping the device's heartbeat register changing."""

    def __init__(self, device: RegisterDevice, period_s: float) -> None:
        self.device = device
        self.period_s = period_s
        self.beats = 0
        self.failures = 0
        self.last_error: DeviceError | None = None
        self.last_failed = False   # the most recent beat failed
        self.max_gap_s = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"{self.device.name}-heartbeat",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self.period_s + 5 * self.device.link.endpoint.timeout_s)
            self._thread = None

    @property
    def running(self) -> bool:
        return self._thread is not None

    def stats(self) -> HeartbeatStats:
        return HeartbeatStats(self.beats, self.failures, self.max_gap_s)

    def _run(self) -> None:
        # the beats get the link before the procedure's reads (never after a burst of them)
        with self.device.link.priority(HEARTBEAT_PRIORITY):
            self._beat()

    def _beat(self) -> None:
        try:
            counter = int(self.device.read_words(HEARTBEAT)[0])
        except DeviceError:
            counter = 0  # the first beat then tells whether the link works
        last_ok = time.monotonic()
        while not self._stop.is_set():
            counter = (counter + 1) & 0xFFFF
            try:
                self.device.write(HEARTBEAT, counter, purpose="heartbeat")
                now = time.monotonic()
                self.max_gap_s = max(self.max_gap_s, now - last_ok)
                last_ok = now
                self.beats += 1
                self.last_failed = False
            except Exception as exc:  # noqa: BLE001 - a beat failure must not kill the thread
                if not isinstance(exc, DeviceError):
                    exc = DeviceError(f"heartbeat write failed: {exc!r}", device=self.device.name,
                                      register=HEARTBEAT, value=counter)
                self.failures += 1
                self.last_error = exc
                self.last_failed = True
                log.warning("%s: heartbeat %d failed: %s", self.device.name, counter,
                            exc.message)
            self._stop.wait(self.period_s)
