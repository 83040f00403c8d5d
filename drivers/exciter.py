"""Excitation-system driver (Modbus TCP), register map from a profile.

The test sequence it supports, in order:

1. `snapshot()` - read the pre-test setpoint and mode (nothing written);
2. `take_remote()` - start the heartbeat, then set the profile's `remote` mode bit (when the
   profile has one);
3. `write_setpoint(value, at_mono=...)` - timed, read back and compared;
4. `safe_state(reason)` - restore the pre-test setpoint, give remote back, stop the heartbeat;
   reconnecting and retrying within a deadline when the link is lost. It reports which way the
   setpoint got back (host write, already there, device watchdog) or that it did NOT.

The heartbeat thread writes an incrementing counter every `heartbeat_period_s`; a failed beat is
counted and the next beat writes the next value (never a resend). If the host dies the device's
watchdog reverts the setpoint by itself.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass

from drivers.device import (TIMED_WRITE_GUARD_S, RegisterDevice, SafeStateReport, WriteGuard,
                            WriteListener, WriteRecord)
from drivers.errors import CommError, DeviceError, ExceptionReply, WriteUncertain
from drivers.link import ModbusLink
from drivers.profile import Profile

log = logging.getLogger(__name__)

SETPOINT = "setpoint"
HEARTBEAT = "heartbeat"
MODE = "mode"
STATUS = "status"


@dataclass(frozen=True)
class PreTest:
    """What `safe_state` puts back."""

    setpoint_words: tuple[int, ...]
    setpoint_pu: float
    mode: int | None  # None when the profile has no mode register


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

    def _run(self) -> None:
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


def watchdog_s(profile: Profile) -> float | None:
    """The device's heartbeat watchdog period from its profile (None when it does not say)."""
    timeout = profile.settings.get("heartbeat_timeout_s")
    return float(timeout) if isinstance(timeout, (int, float)) and not isinstance(timeout, bool) else None


def check_heartbeat_timing(profile: Profile, heartbeat_period_s: float, request_timeout_s: float) -> None:
    """Refuse (ValueError) a heartbeat too slow for the device watchdog: beats at least twice per
    watchdog period, and a timed write (which holds the link for up to one request timeout plus
    the guard) must not hold the beats off for a whole period."""
    timeout = watchdog_s(profile)
    if timeout is None:
        return
    if heartbeat_period_s > timeout / 2:
        raise ValueError(f"heartbeat_period_s {heartbeat_period_s} s is more than half the "
                         f"device watchdog ({timeout} s, profile {profile.name!r})")
    gap = heartbeat_period_s + request_timeout_s + TIMED_WRITE_GUARD_S
    if gap >= timeout:
        raise ValueError(f"the exciter's request timeout {request_timeout_s} s is too long "
                         f"for its watchdog ({timeout} s, profile {profile.name!r}): a timed write "
                         f"can hold the heartbeat off for {gap:.2f} s")


class Exciter(RegisterDevice):
    """Excitation system over Modbus TCP. No I/O before `connect()`."""

    def __init__(self, link: ModbusLink, profile: Profile, *, heartbeat_period_s: float = 0.25,
                 restore_deadline_s: float = 10.0, guard: WriteGuard | None = None,
                 listener: WriteListener | None = None) -> None:
        if profile.device != "exciter":
            raise ValueError(f"profile {profile.name!r} describes a {profile.device}, "
                             "not an exciter")
        for name in (SETPOINT, HEARTBEAT):
            profile[name]  # KeyError naming the profile when missing
        check_heartbeat_timing(profile, heartbeat_period_s, link.endpoint.timeout_s)
        super().__init__(link, profile, guard=guard, listener=listener)
        self.heartbeat = Heartbeat(self, heartbeat_period_s)
        self.restore_deadline_s = restore_deadline_s
        self.pretest: PreTest | None = None
        self._took_remote = False
        # words and outcome ("confirmed" | "uncertain") of the last setpoint write that may
        # have reached the device; exception replies (refused, nothing changed) do not count
        self._last_setpoint: tuple[tuple[int, ...], str] | None = None
        self._setpoint_attempted = False  # this run sent (or began to send) a setpoint write

    # -- reads -------------------------------------------------------------------------------
    def bit(self, register: str, name: str) -> bool | None:
        """A named bit of a register, or None when the profile does not define it."""
        reg = self.profile.registers.get(register)
        if reg is None or name not in reg.bits:
            return None
        return bool(int(self.read(register)) >> reg.bits[name] & 1)

    # -- test sequence -----------------------------------------------------------------------
    def snapshot(self) -> PreTest:
        """Record the pre-test setpoint and mode (reads only)."""
        words = tuple(self.read_words(SETPOINT))
        mode = int(self.read(MODE)) if MODE in self.profile.registers else None
        self.pretest = PreTest(setpoint_words=words,
                               setpoint_pu=self.profile[SETPOINT].decode(list(words)), mode=mode)
        self._setpoint_attempted = False
        return self.pretest

    def _remote_mode_value(self) -> int | None:
        reg = self.profile.registers.get(MODE)
        if reg is None or "remote" not in reg.bits or self.pretest is None:
            return None
        return int(self.pretest.mode or 0) | (1 << reg.bits["remote"])

    def take_remote(self) -> WriteRecord | None:
        """Start the heartbeat, then set the remote bit (if the profile has one)."""
        if self.pretest is None:
            raise RuntimeError("snapshot() before take_remote(): nothing to restore to")
        self.heartbeat.start()
        value = self._remote_mode_value()
        if value is None or value == self.pretest.mode:
            return None
        # set before sending: a lost reply or Ctrl-C must not leave remote on unnoticed
        # (_give_back_remote reads the mode first and writes only when it differs)
        self._took_remote = True
        return self.write(MODE, value, purpose="take remote")

    def write_setpoint(self, value_pu: float, *, purpose: str,
                       at_mono: float | None = None) -> WriteRecord:
        if self.pretest is None:
            raise RuntimeError("snapshot() before the first setpoint write: a test must know "
                               "what to restore")
        return self.write(SETPOINT, value_pu, purpose=purpose, at_mono=at_mono)

    def safe_state(self, reason: str, *, deadline_s: float | None = None,
                   reconnect: bool = False, cancel: threading.Event | None = None) -> SafeStateReport:
        """Restore the pre-test setpoint, give remote back, stop the heartbeat.

        Reads first and writes only what differs (so nothing is re-sent blindly); on a link
        error reconnects and starts over until the deadline. `reconnect` forces a fresh
        connection first (after Ctrl-C the old one may hold a half-read reply). A setpoint this
        run never wrote is not written back: if it moved since the snapshot, someone else moved
        it, and the report says so. The heartbeat is stopped on every way out, and at once when
        the device refuses the restore write (its watchdog must then revert the setpoint, which a
        running heartbeat would prevent); the host then only reads, watching for the revert.
        `cancel` (set by a Ctrl-C during the safe state) stops the retries: the heartbeat stops
        and the device is left to its watchdog.
        """
        try:
            return self._safe_state(reason, deadline_s, reconnect, cancel)
        finally:
            self.heartbeat.stop()  # also when something unexpected escapes the restore

    def _safe_state(self, reason: str, deadline_s: float | None, reconnect: bool,
                    cancel: threading.Event | None) -> SafeStateReport:
        if self.pretest is None:
            return SafeStateReport(self.name, True, "nothing to restore (no test started)",
                                   reason=reason)
        deadline = time.monotonic() + (self.restore_deadline_s if deadline_s is None
                                       else deadline_s)
        pre = self.pretest
        writes: list[WriteRecord] = []
        attempts, reconnected, need_reconnect = 0, False, reconnect or not self.link.connected
        last_error: DeviceError | None = None
        action = ""
        refused: ExceptionReply | None = None  # the device refused the restore write
        while True:
            if cancel is not None and cancel.is_set() and attempts > 0:  # the first try always runs
                self.heartbeat.stop()
                detail = (f"the operator stopped the host's restore (Ctrl-C) after {attempts} attempts; "
                          "heartbeat stopped, the device watchdog should revert the setpoint to "
                          f"{pre.setpoint_pu:.6g} pu - CHECK THE UNIT")
                return SafeStateReport(self.name, False, "SETPOINT NOT RESTORED", detail=detail,
                                       reason=reason, attempts=attempts, reconnected=reconnected,
                                       writes=tuple(writes))
            attempts += 1
            try:
                if need_reconnect:
                    if not self.link.reconnect(deadline, cancel=cancel):
                        if cancel is not None and cancel.is_set():
                            continue  # the top of the loop reports the operator's stop
                        break
                    reconnected, need_reconnect = True, False
                words = tuple(self.read_words(SETPOINT))
                if words != pre.setpoint_words and not self._setpoint_attempted:
                    action = ("setpoint not written by this run; it changed since the pre-test "
                              "snapshot (by someone else) and was left as found")
                elif words != pre.setpoint_words and refused is None:
                    try:
                        writes.append(self.write(SETPOINT, pre.setpoint_pu,
                                                 purpose=f"restore pre-test setpoint ({reason})"))
                    except ExceptionReply as exc:
                        refused = exc
                        self.heartbeat.stop()
                        log.error("%s: the device refused the restore write (%s); heartbeat stopped "
                                  "so that its watchdog reverts the setpoint", self.name, exc.message)
                        raise
                    action = "setpoint restored by host" + (" after reconnect" if reconnected
                                                            else "")
                elif words != pre.setpoint_words:
                    raise DeviceError(f"setpoint still {list(words)} after the refused restore; "
                                      "waiting for the device watchdog", device=self.name)
                elif refused is not None:
                    action = ("setpoint reverted by the device watchdog after the device refused the "
                              f"host's restore ({refused.message})")
                elif not action:
                    action = self._how_restored(reconnected)
                self._give_back_remote(writes, reason)
                self._took_remote = False
                return SafeStateReport(self.name, True, action,
                                       detail=f"setpoint read {list(words)}, pre-test "
                                       f"{list(pre.setpoint_words)} = {pre.setpoint_pu:.6g} pu",
                                       reason=reason, attempts=attempts,
                                       reconnected=reconnected, writes=tuple(writes))
            except CommError as exc:
                last_error, need_reconnect = exc, True
                log.warning("%s: safe state attempt %d: %s", self.name, attempts, exc.message)
            except ExceptionReply as exc:   # e.g. remote lost meanwhile: read again
                last_error = exc
                log.warning("%s: safe state attempt %d: %s", self.name, attempts, exc.message)
            except DeviceError as exc:      # read-back mismatch: read again
                last_error = exc
            if time.monotonic() >= deadline:
                break
            time.sleep(0.05)
        # the heartbeat stops on the way out: a host that cannot reach the device leaves it to
        # its watchdog
        detail = (f"could not restore the pre-test setpoint {pre.setpoint_pu:.6g} pu within "
                  f"the deadline ({attempts} attempts); heartbeat stopped, the device watchdog "
                  "should revert it - CHECK THE UNIT")
        if refused is not None:
            detail += f"; the device refused the restore write ({refused.message})"
        if last_error is not None:
            detail += f"; last error: {last_error}"
        return SafeStateReport(self.name, False, "SETPOINT NOT RESTORED", detail=detail,
                               reason=reason, attempts=attempts, reconnected=reconnected,
                               writes=tuple(writes))

    def write(self, name: str, value: float, *, purpose: str = "",
              at_mono: float | None = None) -> WriteRecord:
        """RegisterDevice.write, remembering what the last setpoint write did to the device."""
        if name != SETPOINT:
            return super().write(name, value, purpose=purpose, at_mono=at_mono)
        words = tuple(self.encode(name, value))
        self._setpoint_attempted = True  # before sending: a Ctrl-C inside the write skips the handlers
        try:
            record = super().write(name, value, purpose=purpose, at_mono=at_mono)
        except WriteUncertain:
            self._last_setpoint = (words, "uncertain")
            raise
        except ExceptionReply:
            raise  # refused by the device: nothing changed
        except DeviceError:
            self._last_setpoint = (words, "uncertain")
            raise
        self._last_setpoint = (record.readback, "confirmed")
        return record

    def _how_restored(self, reconnected: bool) -> str:
        """Why the setpoint reads the pre-test value although safe_state did not write it."""
        assert self.pretest is not None
        if self._last_setpoint is None:
            return "setpoint unchanged (no setpoint write took effect)"
        words, outcome = self._last_setpoint
        if outcome == "confirmed" and words == self.pretest.setpoint_words:
            return "setpoint at pre-test value (restored by the procedure)"
        if self.bit(STATUS, "watchdog_tripped"):
            return "setpoint restored by the device watchdog"
        where = " after reconnect" if reconnected else ""
        if words == self.pretest.setpoint_words:
            return f"setpoint found at pre-test value{where} (the unconfirmed restore write " \
                   "reached the device)"
        return f"setpoint found at pre-test value{where}"

    def _give_back_remote(self, writes: list[WriteRecord], reason: str) -> None:
        if not self._took_remote or self.pretest is None or self.pretest.mode is None:
            return
        if int(self.read(MODE)) != self.pretest.mode:
            writes.append(self.write(MODE, self.pretest.mode,
                                     purpose=f"give back remote ({reason})"))
