"""Excitation-system driver (Modbus TCP), register map from a profile.

The test sequence it supports, in order:

0. `read_watchdog()` - the device's heartbeat watchdog period, read from the register the
   profile names (settings.watchdog_register); the runner refuses a run on it before any
   write (docs/decisions/0011); `remote_holder()` - whether another master holds remote;
1. `snapshot()` - read the pre-test setpoint and mode (nothing written);
2. `take_remote()` - start the heartbeat (refused when it is too slow for the watchdog read),
   then set the profile's `remote` mode bit (when the profile has one);
3. `write_setpoint(value, at_mono=...)` - timed, read back and compared;
4. `safe_state(reason)` - restore the pre-test setpoint (then the PSS switch, `write_pss`, when this
   run wrote it: drivers.pss), give remote back, stop the heartbeat;
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

from drivers.device import TIMED_WRITE_GUARD_S, RegisterDevice, SafeStateReport, WriteGuard, WriteListener, WriteRecord
from drivers.errors import CommError, DeviceError, ExceptionReply, WriteUncertain
from drivers.heartbeat import HEARTBEAT, Heartbeat, HeartbeatStats
from drivers.link import ModbusLink
from drivers.profile import Profile, a_device
from drivers.pss import PSS_ON, PssSwitch

log = logging.getLogger(__name__)

SETPOINT = "setpoint"
MODE = "mode"
STATUS = "status"


@dataclass(frozen=True)
class PreTest:
    """What `safe_state` puts back."""

    setpoint_words: tuple[int, ...]
    setpoint_pu: float
    mode: int | None  # None when the profile has no mode register


#: profile setting naming the register that holds the device's heartbeat watchdog period
WATCHDOG_REGISTER = "watchdog_register"
#: the profile's status bit the device sets while another master holds remote
OTHER_MASTER_BIT = "remote_other_master"


@dataclass(frozen=True)
class WatchdogReading:
    """The device's heartbeat watchdog period as read from it (never taken from the profile).
    `value_s` is None when the profile names no register or the read failed (`error`)."""

    value_s: float | None
    register: str | None = None     # e.g. "watchdog_timeout (input 11)"
    error: str = ""

    def text(self) -> str:
        """How the operator reads it: `2.000 s (read from input register watchdog_timeout 11)`."""
        if self.value_s is not None:
            return f"{self.value_s:.3f} s (read from the device, register {self.register})"
        return f"unknown ({self.error})"

    def to_dict(self) -> dict[str, object]:
        return {"value_s": self.value_s, "register": self.register, "error": self.error}


def watchdog_register(profile: Profile) -> str | None:
    """The register the profile names for the device's watchdog period (None: it names none).
    ValueError when the named register is not in the profile."""
    name = profile.settings.get(WATCHDOG_REGISTER)
    if name is None:
        return None
    if not isinstance(name, str) or name not in profile.registers:
        raise ValueError(f"profile {profile.name!r}: settings.{WATCHDOG_REGISTER} = {name!r} is not "
                         "a register of the profile")
    return name


def heartbeat_problems(watchdog_s: float, heartbeat_period_s: float, request_timeout_s: float,
                       *, timed_writes: bool = True) -> list[str]:
    """What is wrong with this host's heartbeat for a device watchdog of `watchdog_s` (the value
    read from the device): beats at least twice per watchdog period, and (with `timed_writes`) a
    timed write, which holds the link for up to one request timeout plus the guard, must not
    hold the beats off for a whole period. Empty when fine."""
    if heartbeat_period_s >= watchdog_s:
        return [f"the device's watchdog ({watchdog_s:.3f} s) is shorter than the heartbeat period "
                f"exciter.heartbeat_period_s = {heartbeat_period_s:.3f} s: the device would trip "
                "between two beats and drop remote"]
    problems = []
    if heartbeat_period_s > watchdog_s / 2:
        problems.append(f"exciter.heartbeat_period_s = {heartbeat_period_s:.3f} s is more than half "
                        f"the device watchdog ({watchdog_s:.3f} s): one late beat would trip it")
    gap = heartbeat_period_s + request_timeout_s + TIMED_WRITE_GUARD_S
    if timed_writes and gap >= watchdog_s:
        problems.append(f"exciter.timeout_s = {request_timeout_s:.3f} s is too long for the device "
                        f"watchdog ({watchdog_s:.3f} s): a timed write can hold the heartbeat off "
                        f"for {gap:.3f} s")
    return problems


class WatchdogError(DeviceError):
    """The device's watchdog (as read) does not allow this host's heartbeat; nothing was written."""


class Exciter(RegisterDevice):
    """Excitation system over Modbus TCP. No I/O before `connect()`."""

    def __init__(self, link: ModbusLink, profile: Profile, *, heartbeat_period_s: float = 0.25,
                 restore_deadline_s: float = 10.0, guard: WriteGuard | None = None,
                 listener: WriteListener | None = None) -> None:
        if profile.device != "exciter":
            raise ValueError(f"profile {profile.name!r} describes {a_device(profile.device)}, "
                             "not an exciter")
        for name in (SETPOINT, HEARTBEAT):
            profile[name]  # KeyError naming the profile when missing
        watchdog_register(profile)  # ValueError when the profile names a register it lacks
        super().__init__(link, profile, guard=guard, listener=listener)
        self.heartbeat = Heartbeat(self, heartbeat_period_s)
        self.restore_deadline_s = restore_deadline_s
        self.pretest: PreTest | None = None
        self._took_remote = False
        # words and outcome ("confirmed" | "uncertain") of the last setpoint write that may
        # have reached the device; exception replies (refused, nothing changed) do not count
        self._last_setpoint: tuple[tuple[int, ...], str] | None = None
        self._setpoint_attempted = False  # this run sent (or began to send) a setpoint write
        self.watchdog: WatchdogReading | None = None   # read by read_watchdog()
        self.pss = PssSwitch(self)   # the profile's pss_on (none: nothing read or restored)

    # -- reads -------------------------------------------------------------------------------
    def bit(self, register: str, name: str) -> bool | None:
        """A named bit of a register, or None when the profile does not define it."""
        reg = self.profile.registers.get(register)
        if reg is None or name not in reg.bits:
            return None
        return bool(int(self.read(register)) >> reg.bits[name] & 1)

    def bits(self, register: str) -> dict[str, bool]:
        """Every named bit of a register, read at once ({} when the profile lacks the register or
        names no bit of it)."""
        reg = self.profile.registers.get(register)
        if reg is None or not reg.bits:
            return {}
        return self.bits_of(register, self.read(register))

    def bits_of(self, register: str, value: float) -> dict[str, bool]:
        """The named bits of a value of `register` read earlier (e.g. by `read_many`)."""
        reg = self.profile.registers.get(register)
        if reg is None or not reg.bits:
            return {}
        word = int(value)
        return {name: bool(word >> bit & 1) for name, bit in reg.bits.items()}

    def read_watchdog(self) -> WatchdogReading:
        """Read the device's heartbeat watchdog period from the register the profile names
        (settings.watchdog_register); kept in `self.watchdog`. A read the device refuses is a
        reading with an error, not an exception (a comms check still runs); a lost link raises."""
        name = watchdog_register(self.profile)
        if name is None:
            reading = WatchdogReading(None, None, f"profile {self.profile.name!r} names no watchdog "
                                      f"register (settings.{WATCHDOG_REGISTER})")
        else:
            label = self._label(self.register(name))
            try:
                reading = WatchdogReading(float(self.read(name)), label)
            except CommError:
                raise
            except DeviceError as exc:
                reading = WatchdogReading(None, label, f"reading {label} failed: {exc.summary}")
        self.watchdog = reading
        return reading

    def remote_holder(self) -> str | None:
        """Why remote is not free for this host, read from the device (None when it is free):
        the status bit `remote_other_master` (where the profile has one), or the mode's remote
        bit already set before this run took it."""
        if self.bit(STATUS, OTHER_MASTER_BIT):
            return (f"the exciter reports remote owned by another master (status.{OTHER_MASTER_BIT} "
                    "set): another controller holds this unit")
        if not self._took_remote and self.bit(MODE, "remote"):
            return ("the exciter is already in remote (mode bit remote set) before this run took it: "
                    "another master may be controlling it")
        return None

    def heartbeat_stats(self) -> HeartbeatStats:
        """Beats, failures and the longest gap of this run's heartbeat so far."""
        return self.heartbeat.stats()

    def measure_link(self, reads: int, since_mono: float | None = None) -> list[float]:
        """Read the setpoint `reads` times (each tried once: a link that loses one before the first
        write raises CommError) and return the response times (s) of every request answered since
        `since_mono` (of those reads when None): what the link's check before the first write
        judges (docs/decisions/0023)."""
        t0 = time.monotonic()
        for _ in range(reads):
            self.read_words(SETPOINT, attempts=1)
        return self.link.response_times(since_mono=t0 if since_mono is None else since_mono)

    # -- test sequence -----------------------------------------------------------------------
    def snapshot(self) -> PreTest:
        """Record the pre-test setpoint and mode (reads only)."""
        words = tuple(self.read_words(SETPOINT))
        mode = int(self.read(MODE)) if MODE in self.profile.registers else None
        self.pretest = PreTest(setpoint_words=words,
                               setpoint_pu=self.profile[SETPOINT].decode(list(words)), mode=mode)
        self._setpoint_attempted = False
        self.pss.snapshot()
        return self.pretest

    def read_pss(self) -> bool | None:
        """The PSS switch now (True: the stabiliser's output on); None when the profile has none."""
        return self.pss.read() if self.pss.present else None

    def write_pss(self, on: bool, *, purpose: str, at_mono: float | None = None) -> WriteRecord:
        """Switch the stabiliser's output (pss_on), read back and compared; the safe state puts
        the pre-test switch back."""
        return self.pss.write(on, purpose=purpose, at_mono=at_mono)

    def _remote_mode_value(self) -> int | None:
        reg = self.profile.registers.get(MODE)
        if reg is None or "remote" not in reg.bits or self.pretest is None:
            return None
        return int(self.pretest.mode or 0) | (1 << reg.bits["remote"])

    def take_remote(self) -> WriteRecord | None:
        """Start the heartbeat, then set the remote bit (if the profile has one)."""
        if self.pretest is None:
            raise RuntimeError("snapshot() before take_remote(): nothing to restore to")
        reading = self.watchdog or self.read_watchdog()
        if reading.value_s is not None:
            problems = heartbeat_problems(reading.value_s, self.heartbeat.period_s,
                                          self.link.endpoint.timeout_s, timed_writes=False)
            if problems:
                raise WatchdogError("remote not taken: " + "; ".join(problems), device=self.name,
                                    register=reading.register, value=reading.value_s)
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
        pss_refused: ExceptionReply | None = None  # ... or the PSS switch's restore write
        setpoint_back = False   # the setpoint's part done (restored, or left as someone else set it)
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
                setpoint_back = True
                try:
                    pss = self.pss.restore(reason, writes, refused=pss_refused)
                except ExceptionReply as exc:
                    if pss_refused is None:   # as a refused setpoint: the watchdog puts it back
                        pss_refused = exc
                        self.heartbeat.stop()
                        log.error("%s: the device refused the PSS switch's restore write (%s); heartbeat "
                                  "stopped so that its watchdog puts the switch back", self.name, exc.message)
                    raise
                self._give_back_remote(writes, reason)
                self._took_remote = False
                return SafeStateReport(self.name, True, action,
                                       detail=f"setpoint read {list(words)}, pre-test "
                                       f"{list(pre.setpoint_words)} = {pre.setpoint_pu:.6g} pu"
                                       + (f"; {pss}" if pss else ""),
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
        if setpoint_back:   # the setpoint is back; the PSS switch is not
            detail = (f"{action}, but the PSS switch could not be put back "
                      f"{'on' if self.pss.pretest and self.pss.pretest.on else 'off'} within the deadline "
                      f"({attempts} attempts); heartbeat stopped, the device watchdog should put it back - "
                      "CHECK THE UNIT")
            if pss_refused is not None:
                detail += f"; the device refused the PSS switch's restore write ({pss_refused.message})"
            if last_error is not None and last_error is not pss_refused:
                detail += f"; last error: {last_error}"
            return SafeStateReport(self.name, False, "PSS SWITCH NOT RESTORED", detail=detail,
                                   reason=reason, attempts=attempts, reconnected=reconnected,
                                   writes=tuple(writes))
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
        """RegisterDevice.write, remembering what the last setpoint write did to the device; a
        setpoint or mode write the device refuses is explained by the device's state."""
        if name != SETPOINT:
            try:
                return super().write(name, value, purpose=purpose, at_mono=at_mono)
            except ExceptionReply as exc:
                if name not in (MODE, PSS_ON):
                    raise
                raise self._explained(exc) from None
        words = tuple(self.encode(name, value))
        self._setpoint_attempted = True  # before sending: a Ctrl-C inside the write skips the handlers
        try:
            record = super().write(name, value, purpose=purpose, at_mono=at_mono)
        except WriteUncertain:
            self._last_setpoint = (words, "uncertain")
            raise
        except ExceptionReply as exc:
            raise self._explained(exc) from None  # refused by the device: nothing changed
        except DeviceError:
            self._last_setpoint = (words, "uncertain")
            raise
        self._last_setpoint = (record.readback, "confirmed")
        return record

    def _explained(self, exc: ExceptionReply) -> ExceptionReply:
        """`exc` with what the device's status says about an "illegal function" refusal (the
        device's way to say "not now": watchdog tripped, remote held by another master, not in
        remote); `exc` itself for other codes (nothing more is sent after those) and when the
        status says nothing or cannot be read."""
        if exc.code != 1:
            return exc
        hints = []
        try:
            if self.bit(STATUS, "watchdog_tripped"):
                wd = self.watchdog.value_s if self.watchdog else None
                within = f" within {wd:.3f} s" if wd is not None else ""
                hints.append(f"the device's watchdog has tripped (status.watchdog_tripped): it saw no "
                             f"heartbeat change{within} and dropped remote")
            if self.bit(STATUS, OTHER_MASTER_BIT):
                hints.append(f"remote is owned by another master (status.{OTHER_MASTER_BIT})")
            if not hints and self.bit(MODE, "remote") is False and exc.register \
                    and exc.register.startswith((SETPOINT, PSS_ON)):
                hints.append("the exciter is not in remote (mode bit remote = 0)")
        except DeviceError:
            return exc
        return exc.with_hint("; ".join(hints)) if hints else exc

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
