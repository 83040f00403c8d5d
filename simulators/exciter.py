"""The simulated excitation system: setpoint, mode, heartbeat watchdog, readings from the plant.

Works on register names (see docs/devices.md); any exciter profile that names the
registers below can be served. Required: setpoint, active_setpoint, vt, efd, ifd, p, mode,
status, heartbeat. Optional: watchdog_timeout, device_code, firmware, q, mech_power (on line: P and
Q are the machine's in MW / Mvar on its base, mech_power sets the turbine; at no load p reads the
set load, q 0, and a mech_power write is refused with exception 01), pss_on (the stabiliser's output
switch, 1 at power-up: written in remote only, as the setpoint; on line it switches the plant's
stabiliser output, `OnlinePlant.set_pss`; 0 or 1 only, else exception 03). Other writable registers
a vendor profile adds are stored and read back as written.

Behaviour:
- starts in auto + local with setpoint = the plant's initial setpoint (Vt0);
- setpoint writes need remote mode (when the profile's `require_remote` setting is true,
  default) -> else exception 01; out of the register's min/max -> exception 03 (register image);
- local -> remote remembers the pre-remote setpoint and starts the watchdog; while remote the
  heartbeat must change within `heartbeat_timeout_s`, else the setpoint reverts to the
  pre-remote value (the PSS switch too), the mode drops to local and status.watchdog_tripped latches (until the
  next local -> remote); the watchdog period is served in the profile's watchdog register
  (settings.watchdog_register), and a period that register cannot hold exactly is refused;
- remote belongs to the master that took it, known by its address as many devices know their
  master (a host that reconnects after a lost link is the same master): setpoint, heartbeat and
  mode writes from any other address are refused (exception 01) while it holds remote, and
  status.remote_other_master (where the profile has that bit) reads 1 to them. The hold ends
  when remote is given back or the watchdog trips. The device's own panel (the model called
  directly, as tests do) is never refused;
- manual mode is not simulated: a mode write without the auto bit -> exception 03;
- plant events of the fault injection (`plant_event`): a `load` sets the turbine's power (a load
  rejection, a trip, reverse power on line), a `limiter` makes a status bit read 1 for a while (a
  limiter acting, as the device reports it).
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping, Sequence

import numpy as np
from pymodbus.constants import ExcCodes

from bench_ctl.plants import FLAG_CEILING, FLAG_RAMP, FLAG_RATE, TURBINE_PU, Plant
from drivers.exciter import OTHER_MASTER_BIT, watchdog_register
from drivers.profile import Profile, Register, a_device

from .faults import Fault
from .regmap import CLIENT

log = logging.getLogger(__name__)

REQUIRED = ("setpoint", "active_setpoint", "vt", "efd", "ifd", "p", "mode", "status", "heartbeat")
DEFAULT_MODE_BITS = {"auto": 0, "remote": 1}
DEFAULT_STATUS_BITS = {"ceiling_limit": 0, "rate_limit": 1, "watchdog_tripped": 2,
                       "setpoint_ramping": 3, OTHER_MASTER_BIT: 4}
#: registers only the master holding remote may write
MASTER_ONLY = ("setpoint", "heartbeat", "mode", "pss_on")
DEVICE_CODE = 0x4543
FIRMWARE = 0x0100


class ExciterDevice:
    """Device logic of the excitation system around a shared `Plant`."""

    kind = "exciter"

    def __init__(self, plant: Plant, profile: Profile, *, heartbeat_timeout_s: float | None = None,
                 load_mw: float = 0.0, require_remote: bool | None = None) -> None:
        if profile.device != "exciter":
            raise ValueError(f"profile {profile.name!r} is for {a_device(profile.device)}, not an exciter")
        missing = [n for n in REQUIRED if n not in profile.registers]
        if missing:
            raise ValueError(f"exciter profile {profile.name!r} lacks registers {missing}")
        self.plant = plant
        self.profile = profile
        timeout = heartbeat_timeout_s if heartbeat_timeout_s is not None \
            else float(profile.settings.get("heartbeat_timeout_s", 2.0))
        if not timeout > 0:
            raise ValueError(f"heartbeat timeout {timeout!r} s must be > 0")
        self.heartbeat_timeout_s = float(timeout)
        self.watchdog_register = watchdog_register(profile) or (
            "watchdog_timeout" if "watchdog_timeout" in profile.registers else None)
        if self.watchdog_register is not None:
            reg = profile[self.watchdog_register]
            try:
                reg.encode(self.heartbeat_timeout_s)
            except ValueError as exc:
                raise ValueError(f"heartbeat timeout {timeout!r} s cannot be served in register "
                                 f"{reg.name} ({reg.type}, {reg.scale:g} {reg.unit or 's'} per count): "
                                 f"{exc}; the device must report the watchdog it runs") from None
        self.require_remote = bool(profile.settings.get("require_remote", True)
                                   if require_remote is None else require_remote)
        self._mode_bits = dict(profile["mode"].bits) or DEFAULT_MODE_BITS
        self._status_bits = dict(profile["status"].bits) or DEFAULT_STATUS_BITS
        for need in ("auto", "remote"):
            if need not in self._mode_bits:
                raise ValueError(f"exciter profile {profile.name!r}: mode register lacks bit {need!r}")
        self._lock = threading.Lock()
        self.setpoint = plant.usetp_pre
        self.remote = False
        self.heartbeat = 0
        self._hb_changed = time.monotonic()
        self.pre_remote_setpoint = self.setpoint
        #: the stabiliser's output switch (pss_on), and its value when remote was taken
        self.pss_on = True
        self.pre_remote_pss = True
        self.watchdog_tripped = False
        self._owner: str | None = None   # the master (address) holding remote (None: anyone)
        self.load_mw = float(load_mw)
        #: plant step from which the last written setpoint acts
        self.last_setpoint_step: int | None = None
        self._extra: dict[str, float] = {}
        #: status bits forced on by a `limiter` fault: name -> monotonic end (inf: until cleared)
        self.forced_bits: dict[str, float] = {}
        #: (monotonic time, event, value) of what happened to the device, for tests and logs
        self.events: list[tuple[float, str, float]] = []
        plant.add_listener(self._on_plant)

    # ---------------------------------------------------------------- state for the image
    def mode_word(self) -> int:
        word = 1 << self._mode_bits["auto"]
        if self.remote:
            word |= 1 << self._mode_bits["remote"]
        return word

    def snapshot(self) -> Mapping[str, float]:
        st = self.plant.state()
        flags = 0
        sb = self._status_bits
        now = time.monotonic()
        for name, until in list(self.forced_bits.items()):
            if name in sb and now < until:
                flags |= 1 << sb[name]
        for name, on in (("ceiling_limit", st.flags & FLAG_CEILING),
                         ("rate_limit", st.flags & FLAG_RATE),
                         ("setpoint_ramping", st.flags & FLAG_RAMP),
                         ("watchdog_tripped", self.watchdog_tripped),
                         (OTHER_MASTER_BIT, self._held_by_other(CLIENT.get()))):
            if on and name in sb:
                flags |= 1 << sb[name]
        with self._lock:
            snap = dict(self._extra)
            snap.update(setpoint=self.setpoint, heartbeat=self.heartbeat, mode=self.mode_word(),
                        pss_on=float(self.pss_on))
        on_line = self.plant.on_line
        snap.update(active_setpoint=st.active_setpoint, vt=st.vt, efd=st.efd, ifd=st.ifd,
                    p=st.p * self.plant.mva if on_line else self.load_mw,
                    q=st.q * self.plant.mva if on_line else 0.0,
                    mech_power=self.plant.mech_power * self.plant.mva if on_line else 0.0,
                    status=flags, device_code=DEVICE_CODE, firmware=FIRMWARE)
        if self.watchdog_register is not None:
            snap[self.watchdog_register] = self.heartbeat_timeout_s
        return snap

    def _held_by_other(self, client: str | None) -> bool:
        """Remote is held by a master other than `client` (the panel, None, never is refused)."""
        owner = self._owner
        return self.remote and client is not None and owner is not None and owner != client

    def read_window(self, offset: int, count: int) -> list[int] | ExcCodes:
        return ExcCodes.ILLEGAL_ADDRESS

    # ---------------------------------------------------------------- writes
    def write(self, items: Sequence[tuple[Register, float]]) -> ExcCodes | None:
        now = time.monotonic()
        client = CLIENT.get()
        with self._lock:
            for reg, value in items:       # validate all before applying any
                if reg.name in MASTER_ONLY and self._held_by_other(client):
                    log.info("exciter refuses %s = %r: remote is held by another master", reg.name,
                             value)
                    return ExcCodes.ILLEGAL_FUNCTION
                exc = self._check(reg.name, value)
                if exc is not None:
                    log.info("exciter refuses %s = %r: exception %s", reg.name, value, exc.name)
                    return exc
            for reg, value in items:
                self._apply(reg.name, value, now, client)
        return None

    def _check(self, name: str, value: float) -> ExcCodes | None:
        if name in ("setpoint", "pss_on") and self.require_remote and not self.remote:
            return ExcCodes.ILLEGAL_FUNCTION
        if name == "pss_on" and value not in (0.0, 1.0):
            return ExcCodes.ILLEGAL_VALUE
        if name == "mech_power":
            if not self.plant.on_line:
                return ExcCodes.ILLEGAL_FUNCTION   # no turbine to set at no load
            if not TURBINE_PU[0] <= value / self.plant.mva <= TURBINE_PU[1]:
                return ExcCodes.ILLEGAL_VALUE
        if name == "mode":
            word = int(value)
            known = (1 << self._mode_bits["auto"]) | (1 << self._mode_bits["remote"])
            if word != value or word & ~known or not word & (1 << self._mode_bits["auto"]):
                return ExcCodes.ILLEGAL_VALUE
        return None

    def _apply(self, name: str, value: float, now: float, client: str | None = None) -> None:
        if name == "setpoint":
            self.setpoint = value
            # time-stamped by the plant as it queues the change: "from the next plant step"
            self.last_setpoint_step = self.plant.write_setpoint(value)
            self.events.append((now, "setpoint", value))
            log.debug("setpoint %.6f from plant step %d", value, self.last_setpoint_step)
        elif name == "pss_on":
            self._switch_pss(bool(value))
            self.events.append((now, "pss_on", value))
        elif name == "heartbeat":
            if int(value) != self.heartbeat:
                self._hb_changed = now
            self.heartbeat = int(value)
        elif name == "mode":
            remote = bool(int(value) & (1 << self._mode_bits["remote"]))
            if remote and not self.remote:
                self.pre_remote_setpoint = self.setpoint
                self.pre_remote_pss = self.pss_on
                self.watchdog_tripped = False
                self._hb_changed = now
                self._owner = client
                self.events.append((now, "remote", self.setpoint))
            elif not remote and self.remote:
                self._owner = None
                self.events.append((now, "local", self.setpoint))
            self.remote = remote
        elif name == "mech_power":
            self.set_load_mw(value)
        else:
            self._extra[name] = value

    def _switch_pss(self, on: bool) -> None:
        """The stabiliser's output switch; on line the plant's (its states run either way)."""
        self.pss_on = on
        set_pss = getattr(self.plant, "set_pss", None)
        if set_pss is not None:
            set_pss(on)

    def set_load_mw(self, p_mw: float) -> None:
        """Change the simulated active power (e.g. to test a no-load precondition); on line, the
        turbine's mechanical power, which the machine's P follows."""
        if not np.isfinite(p_mw):
            raise ValueError(f"load {p_mw!r} MW is not finite")
        if self.plant.on_line:
            self.plant.set_mech_power(p_mw / self.plant.mva)
        self.load_mw = float(p_mw)

    def plant_event(self, event: Fault) -> None:
        """A plant event of the fault injection (simulators.faults): `load` sets the turbine's
        power to `event.mw` MW; `limiter` makes status bit `event.bit` read 1 for
        `event.duration_s` (until cleared when None)."""
        now = time.monotonic()
        try:
            if event.kind == "load":
                self.set_load_mw(float(event.mw))
                self.events.append((now, "load", float(event.mw)))
            elif event.kind == "limiter":
                if event.bit not in self._status_bits:
                    raise ValueError(f"status has no bit {event.bit!r} (bits: {', '.join(self._status_bits)})")
                end = now + event.duration_s if event.duration_s is not None else float("inf")
                self.forced_bits[event.bit] = end
                self.events.append((now, "limiter", 1.0))
        except ValueError as exc:
            log.warning("plant event %s not applied: %s", event.kind, exc)
            return
        log.info("plant event: %s", event)

    def clear_forced_bits(self) -> None:
        """End every limiter a fault forced."""
        self.forced_bits.clear()

    # ---------------------------------------------------------------- watchdog
    def _on_plant(self, k0: int, out: np.ndarray) -> None:
        if not self.remote:
            return
        now = time.monotonic()
        with self._lock:
            if self.remote and now - self._hb_changed > self.heartbeat_timeout_s:
                self.remote = False
                self._owner = None
                self.watchdog_tripped = True
                self.setpoint = self.pre_remote_setpoint
                self.last_setpoint_step = self.plant.write_setpoint(self.setpoint)
                if self.pss_on != self.pre_remote_pss:
                    self._switch_pss(self.pre_remote_pss)
                self.events.append((now, "watchdog", self.setpoint))
                log.warning("exciter watchdog: heartbeat unchanged for %.3f s; setpoint reverted "
                            "to %.6f pu, mode local", now - self._hb_changed, self.setpoint)
