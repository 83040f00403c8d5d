"""The bench a procedure receives: the exciter and recorder drivers built from the bench config.

`Bench.safe_state` makes every device safe in the reverse order the test set them up (the
recorder is armed before the exciter is taken to remote, so the exciter is restored first).
"""
from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from bench_ctl.runner.config import BenchConfig
from drivers.device import SafeStateReport, WriteGuard, WriteListener
from drivers.errors import CommError
from drivers.exciter import Exciter
from drivers.link import ModbusLink
from drivers.profile import load_profile
from drivers.recorder import Recorder

log = logging.getLogger(__name__)

IDENTITY_REGISTERS = ("device_code", "firmware")


class Bench:
    """Both devices of a bench. No I/O before `connect()`."""

    def __init__(self, config: BenchConfig, *, guard: WriteGuard | None = None,
                 listener: WriteListener | None = None) -> None:
        self.config = config
        exc, rec = config.exciter, config.recorder
        self.exciter = Exciter(ModbusLink(exc.endpoint(), "exciter"), load_profile(exc.profile),
                               heartbeat_period_s=exc.heartbeat_period_s,
                               restore_deadline_s=config.limits.restore_deadline_s,
                               guard=guard, listener=listener)
        self.recorder = Recorder(ModbusLink(rec.endpoint(), "recorder"),
                                 load_profile(rec.profile), attempts=rec.download_attempts,
                                 guard=guard, listener=listener)

    @property
    def devices(self) -> tuple[Exciter | Recorder, ...]:
        return (self.exciter, self.recorder)

    def connect(self) -> None:
        for dev in self.devices:
            dev.connect()

    def close(self) -> None:
        for dev in self.devices:
            try:
                dev.close()
            except Exception:  # closing must not hide the run's own outcome
                log.exception("%s: close failed", dev.name)

    def identities(self) -> dict[str, dict[str, Any]]:
        """Profile identity plus the identity registers read from each device."""
        out = {}
        for dev in self.devices:
            ident = dev.identity()
            for name in IDENTITY_REGISTERS:
                if name in dev.profile.registers:
                    ident[f"{name}_read"] = int(dev.read(name))
            out[dev.name] = ident
        return out

    def check(self) -> None:
        """Raise the heartbeat's error when its last beat failed (the link is in trouble)."""
        hb = self.exciter.heartbeat
        if hb.running and hb.last_error is not None and hb.failures and hb.last_failed:
            raise CommError(f"heartbeat failing ({hb.failures} failed beats): "
                            f"{hb.last_error.message}", device=self.exciter.name,
                            register="heartbeat", frames=hb.last_error.frames)

    def safe_state(self, reason: str, *, reconnect: bool = False,
                   cancel: threading.Event | None = None,
                   between: Callable[[], None] | None = None) -> list[SafeStateReport]:
        """Exciter first (restore the setpoint), then the recorder (disarm). Never raises.
        `cancel` (a Ctrl-C during the safe state) stops the exciter's restore retries. `between`
        runs once the exciter's safe state is over, before the recorder's (the runner keeps the
        record of an aborted test there; an exciter NOT made safe is said first, loudly: the host
        can do no more for it, its heartbeat is stopped); what it raises is logged."""
        reports = []
        for dev in (self.exciter, self.recorder):
            if dev is self.recorder and between is not None:
                if reports and not reports[0].ok:
                    log.critical("%s: %s - %s", reports[0].device, reports[0].action, reports[0].detail)
                try:
                    between()
                except Exception:  # noqa: BLE001 - the recorder's safe state must still run
                    log.exception("keeping the record before the recorder's safe state failed")
            try:
                extra = {"cancel": cancel} if dev is self.exciter and cancel is not None else {}
                reports.append(dev.safe_state(reason, reconnect=reconnect, **extra))
            except Exception as exc:  # noqa: BLE001 - drivers report failures; this is a last
                # resort, and whatever escaped (a refused write, a full disk under the audit log)
                # must end as a failed safe state, not skip the next device
                log.exception("%s: safe state raised", dev.name)
                reports.append(SafeStateReport(dev.name, False, "SAFE STATE FAILED",
                                               detail=f"{type(exc).__name__}: {exc}", reason=reason))
        return reports
