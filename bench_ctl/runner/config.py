"""The bench config (TOML): where the devices are, their profiles, and the safety limits.

Every key is known; an unknown or mistyped key is an error naming the file and the key (a
typo in a limit must never fall back to a default). Quantities carry their unit in the name.
Each device's profile is loaded and checked against the roles its driver declares
(`drivers.roles`: a required register missing, one the host writes that is read-only, a unit the
drivers do not compute in) when the config is loaded, before any file or link is opened: one
ConfigError line naming the profile, the role and what is wrong.

    [bench]
    name = "Unit 3 excitation bench"

    [exciter]                         # Modbus TCP
    url = "tcp://192.0.2.10:502"
    unit_id = 1
    profile = "sim-exciter"           # drivers/profiles/NAME.toml, or a path (relative to this file)
    timeout_s = 0.5
    heartbeat_period_s = 0.25

    [recorder]                        # Modbus RTU on a serial port or pyserial URL
    url = "/dev/ttyUSB0"              # or "rtu+tcp://HOST:PORT" (a serial device server in
                                      # transparent mode); a pyserial "socket://HOST:PORT" works
                                      # but is slow (pymodbus 3.16 reads it ~1 byte per ms)
    unit_id = 1
    profile = "sim-recorder"
    timeout_s = 0.5
    baudrate = 115200
    parity = "N"                      # N | E | O
    stopbits = 1
    download_attempts = 3             # per block; block reads are idempotent

    [limits]                          # checked before the first write; refuse, never clip
    pulse_amplitude_max_pu = 0.06     # |pulse amplitude| cap
    pulse_width_max_s = 1.5
    setpoint_min_pu = 0.95            # absolute band for every setpoint written
    setpoint_max_pu = 1.08
    no_load_p_max_mw = 2.0            # no-load precondition: |p| below this
    restore_deadline_s = 10.0         # reconnect-and-restore budget on a lost link
    watchdog_max_s = 3.0              # optional: the longest device watchdog accepted (read from
                                      # the device before the first write); default
                                      # pulse_width_max_s + WATCHDOG_MARGIN_S
    vt_min_pu = 0.95                  # optional, on line: the band Vt must stay in during the
    vt_max_pu = 1.08                  # test (default the setpoint band); leaving it aborts
    q_min_mvar = -30.0                # on line: the band Q must stay in (the unit's capability
    q_max_mvar = 60.0                 # at this P, less a margin); without it no on-line test
    p_min_mw = 30.0                   # on line: the unit's on-line range of P (its minimum stable
    p_max_mw = 100.0                  # load .. its rating); P outside it before the step refuses
                                      # the test, during it ends the step (a trip, a load
                                      # rejection, reverse power); without it no on-line test
    p_swing_max_mw = 10.0             # optional, on line: how far P may move from its value at the
                                      # start while the step is held (default 10 % of p_max_mw)
    step_hold_max_s = 30.0            # on line: the longest hold of a reference step
    steady_time_s = 2.0               # optional, on line: P, Q and Vt steady this long before the
    steady_p_band_mw = 2.0            # step, each within its band (max - min): defaults 2 s,
    steady_q_band_mvar = 5.0          # 2 % of p_max_mw, 5 % of the Q band, 0.005 pu
    steady_vt_band_pu = 0.005

    [procedures.no_load_pulse]        # optional: keyword parameters of a procedure
    amplitude_pu = 0.05
    width_s = 1.0
"""
from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from bench_ctl.exitcodes import BadInput
from bench_ctl.limits import InputError, read_text
from drivers.link import Endpoint
from drivers.profile import load_profile
from drivers.roles import role_problems


class ConfigError(BadInput):
    """A bench config that cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class DeviceConfig:
    url: str
    profile: str
    unit_id: int = 1
    timeout_s: float = 0.5
    # exciter
    heartbeat_period_s: float = 0.25
    # recorder (serial)
    baudrate: int = 115200
    parity: str = "N"
    stopbits: int = 1
    download_attempts: int = 3

    def endpoint(self) -> Endpoint:
        return Endpoint(url=self.url, unit_id=self.unit_id, timeout_s=self.timeout_s,
                        baudrate=self.baudrate, parity=self.parity, stopbits=self.stopbits)


#: how much longer than the pulse width cap the device's watchdog may be by default: a host
#: that dies during a pulse leaves it to the watchdog, so this bounds how far past the cap a
#: pulse can last. 1.5 s accepts the 2-3 s watchdogs real excitation systems ship with against
#: a 1.5 s cap (docs/decisions/0011).
WATCHDOG_MARGIN_S = 1.5
#: on line, the defaults of the P swing allowed during a step and of the steady-state bands before
#: it: shares of the unit's P range top (p_max_mw) and of the Q band's width
P_SWING_SHARE = 0.10
STEADY_P_SHARE = 0.02
STEADY_Q_SHARE = 0.05


@dataclass(frozen=True)
class Limits:
    pulse_amplitude_max_pu: float
    pulse_width_max_s: float
    setpoint_min_pu: float
    setpoint_max_pu: float
    no_load_p_max_mw: float
    restore_deadline_s: float = 10.0
    watchdog_max_s: float | None = None   # None: pulse_width_max_s + WATCHDOG_MARGIN_S
    # on line (procedures/online_step.py): the band Vt and Q must stay in, the hold cap
    vt_min_pu: float | None = None        # None: setpoint_min_pu
    vt_max_pu: float | None = None        # None: setpoint_max_pu
    q_min_mvar: float | None = None       # None: no on-line test (the unit's capability is needed)
    q_max_mvar: float | None = None
    step_hold_max_s: float = 30.0
    # on line: the unit's range of P (None: no on-line test), how far P may swing during the step
    p_min_mw: float | None = None
    p_max_mw: float | None = None
    p_swing_max_mw: float | None = None   # None: P_SWING_SHARE of p_max_mw
    # on line: the steady state before the step (each band: max - min over steady_time_s)
    steady_time_s: float = 2.0
    steady_p_band_mw: float | None = None      # None: STEADY_P_SHARE of p_max_mw
    steady_q_band_mvar: float | None = None    # None: STEADY_Q_SHARE of the Q band's width
    steady_vt_band_pu: float = 0.005

    @property
    def p_swing_mw(self) -> float | None:
        """How far P may move from its value at the start of an on-line step (None without a P range)."""
        if self.p_swing_max_mw is not None:
            return self.p_swing_max_mw
        return None if self.p_max_mw is None else P_SWING_SHARE * self.p_max_mw

    def steady_bands(self) -> dict[str, float] | None:
        """The steady-state bands before an on-line step, {"p": MW, "q": Mvar, "vt": pu} (None
        without the P range or the Q band, which their defaults derive from)."""
        if self.p_max_mw is None or self.q_min_mvar is None or self.q_max_mvar is None:
            return None
        return {"p": self.steady_p_band_mw if self.steady_p_band_mw is not None else STEADY_P_SHARE * self.p_max_mw,
                "q": self.steady_q_band_mvar if self.steady_q_band_mvar is not None
                else STEADY_Q_SHARE * (self.q_max_mvar - self.q_min_mvar),
                "vt": self.steady_vt_band_pu}

    @property
    def vt_band_pu(self) -> tuple[float, float]:
        """The terminal voltage band of an on-line test (limits.vt_min_pu / vt_max_pu, or the
        setpoint band)."""
        return (self.setpoint_min_pu if self.vt_min_pu is None else self.vt_min_pu,
                self.setpoint_max_pu if self.vt_max_pu is None else self.vt_max_pu)

    @property
    def watchdog_limit_s(self) -> float:
        """The longest device watchdog a run accepts (limits.watchdog_max_s, or the width cap
        plus WATCHDOG_MARGIN_S)."""
        if self.watchdog_max_s is not None:
            return self.watchdog_max_s
        return self.pulse_width_max_s + WATCHDOG_MARGIN_S

    def watchdog_limit_text(self) -> str:
        """Where the watchdog limit comes from, for the operator."""
        if self.watchdog_max_s is not None:
            return f"limits.watchdog_max_s = {self.watchdog_max_s:.3f} s"
        return (f"{self.watchdog_limit_s:.3f} s = limits.pulse_width_max_s "
                f"{self.pulse_width_max_s:.3f} s + margin {WATCHDOG_MARGIN_S:.3f} s "
                "(set limits.watchdog_max_s to change it)")


@dataclass(frozen=True)
class BenchConfig:
    name: str
    exciter: DeviceConfig
    recorder: DeviceConfig
    limits: Limits
    procedures: dict[str, dict[str, Any]] = field(default_factory=dict)
    source: str = "<in memory>"

    def to_dict(self) -> dict[str, Any]:
        """Plain data (the capture sidecar and the audit log record it)."""
        return {"name": self.name, "source": self.source, "exciter": asdict(self.exciter),
                "recorder": asdict(self.recorder), "limits": asdict(self.limits),
                "procedures": {k: dict(v) for k, v in self.procedures.items()}}

    def with_endpoints(self, *, exciter_url: str | None = None, recorder_url: str | None = None,
                       exciter_unit_id: int | None = None,
                       recorder_unit_id: int | None = None) -> BenchConfig:
        """The same bench pointed at other addresses (a dry run points it at the simulators)."""
        exc, rec = self.exciter, self.recorder
        if exciter_url is not None:
            exc = replace(exc, url=exciter_url)
        if exciter_unit_id is not None:
            exc = replace(exc, unit_id=exciter_unit_id)
        if recorder_url is not None:
            rec = replace(rec, url=recorder_url)
        if recorder_unit_id is not None:
            rec = replace(rec, unit_id=recorder_unit_id)
        return replace(self, exciter=exc, recorder=rec)

    def procedure_params(self, name: str) -> dict[str, Any]:
        return dict(self.procedures.get(name, {}))


# key -> (type, required); float accepts int
_DEVICE_KEYS: dict[str, tuple[type, bool]] = {
    "url": (str, True), "profile": (str, True), "unit_id": (int, False),
    "timeout_s": (float, False),
}
_EXCITER_KEYS = {**_DEVICE_KEYS, "heartbeat_period_s": (float, False)}
_RECORDER_KEYS = {**_DEVICE_KEYS, "baudrate": (int, False), "parity": (str, False),
                  "stopbits": (int, False), "download_attempts": (int, False)}
_LIMIT_KEYS = {"pulse_amplitude_max_pu": (float, True), "pulse_width_max_s": (float, True),
               "setpoint_min_pu": (float, True), "setpoint_max_pu": (float, True),
               "no_load_p_max_mw": (float, True), "restore_deadline_s": (float, False),
               "watchdog_max_s": (float, False), "vt_min_pu": (float, False), "vt_max_pu": (float, False),
               "q_min_mvar": (float, False), "q_max_mvar": (float, False), "step_hold_max_s": (float, False),
               "p_min_mw": (float, False), "p_max_mw": (float, False), "p_swing_max_mw": (float, False),
               "steady_time_s": (float, False), "steady_p_band_mw": (float, False),
               "steady_q_band_mvar": (float, False), "steady_vt_band_pu": (float, False)}
_BENCH_KEYS = {"name": (str, False)}
_TOP = {"bench", "exciter", "recorder", "limits", "procedures"}


def _section(doc: Mapping[str, Any], name: str, keys: dict[str, tuple[type, bool]],
             src: str) -> dict[str, Any]:
    table = doc.get(name)
    if table is None:
        table = {}
        if any(req for _, req in keys.values()):
            raise ConfigError(f"{src}: missing [{name}] table")
    if not isinstance(table, Mapping):
        raise ConfigError(f"{src}: {name} must be a table")
    out: dict[str, Any] = {}
    for key, value in table.items():
        if key not in keys:
            raise ConfigError(f"{src}: unknown key {name}.{key} (allowed: "
                              f"{', '.join(sorted(keys))})")
        typ, _ = keys[key]
        ok = (isinstance(value, typ) and not isinstance(value, bool)) or (
            typ is float and isinstance(value, int) and not isinstance(value, bool))
        if not ok:
            raise ConfigError(f"{src}: {name}.{key} = {value!r} must be a {typ.__name__}")
        if typ is float:
            value = float(value)
            if not math.isfinite(value):
                raise ConfigError(f"{src}: {name}.{key} = {value!r} must be finite")
        out[key] = value
    for key, (_, required) in keys.items():
        if required and key not in out:
            raise ConfigError(f"{src}: missing key {name}.{key}")
    return out


def _positive(src: str, where: str, values: Mapping[str, Any], names: tuple[str, ...]) -> None:
    for key in names:
        if key in values and not values[key] > 0:
            raise ConfigError(f"{src}: {where}.{key} = {values[key]!r} must be > 0")


def _resolve_profile(profile: str, base: Path | None) -> str:
    """Bare names stay names (drivers/profiles/NAME.toml); paths are made relative to the config."""
    if base is not None and ("/" in profile or profile.endswith(".toml")):
        p = Path(profile)
        return str(p if p.is_absolute() else (base / p).resolve())
    return profile


def config_from_dict(doc: Mapping[str, Any], source: str = "<dict>",
                     base: Path | None = None) -> BenchConfig:
    """Validate a parsed bench config (see the module docstring)."""
    for key in doc:
        if key not in _TOP:
            raise ConfigError(f"{source}: unknown table or key {key!r} (allowed: "
                              f"{', '.join(sorted(_TOP))})")
    bench = _section(doc, "bench", _BENCH_KEYS, source)
    devices = {}
    for name, keys in (("exciter", _EXCITER_KEYS), ("recorder", _RECORDER_KEYS)):
        vals = _section(doc, name, keys, source)
        _positive(source, name, vals, ("timeout_s", "heartbeat_period_s", "baudrate",
                                       "download_attempts"))
        if not 0 <= vals.get("unit_id", 1) <= 247:
            raise ConfigError(f"{source}: {name}.unit_id = {vals['unit_id']} outside 0..247")
        if vals.get("parity", "N") not in ("N", "E", "O"):
            raise ConfigError(f"{source}: {name}.parity = {vals['parity']!r} must be N, E or O")
        if vals.get("stopbits", 1) not in (1, 2):
            raise ConfigError(f"{source}: {name}.stopbits = {vals['stopbits']!r} must be 1 or 2")
        vals["profile"] = _resolve_profile(vals["profile"], base)
        devices[name] = DeviceConfig(**vals)
    if not devices["exciter"].url.startswith("tcp://"):
        raise ConfigError(f"{source}: exciter.url = {devices['exciter'].url!r}: the exciter is "
                          "Modbus TCP, expected tcp://HOST:PORT")
    try:
        devices["exciter"].endpoint().host_port()
    except ValueError as exc:
        raise ConfigError(f"{source}: exciter.url: {exc}") from None
    lim = _section(doc, "limits", _LIMIT_KEYS, source)
    _positive(source, "limits", lim, ("pulse_amplitude_max_pu", "pulse_width_max_s",
                                      "no_load_p_max_mw", "restore_deadline_s",
                                      "setpoint_min_pu", "watchdog_max_s", "vt_min_pu",
                                      "step_hold_max_s", "p_max_mw", "p_swing_max_mw", "steady_time_s",
                                      "steady_p_band_mw", "steady_q_band_mvar", "steady_vt_band_pu"))
    if lim["setpoint_min_pu"] >= lim["setpoint_max_pu"]:
        raise ConfigError(f"{source}: limits.setpoint_min_pu {lim['setpoint_min_pu']} must be "
                          f"below limits.setpoint_max_pu {lim['setpoint_max_pu']}")
    for lo, hi in (("vt_min_pu", "vt_max_pu"), ("q_min_mvar", "q_max_mvar"), ("p_min_mw", "p_max_mw")):
        if (lo in lim) != (hi in lim):
            raise ConfigError(f"{source}: limits.{lo} and limits.{hi} go together (a band has two ends)")
        if lo in lim and lim[lo] >= lim[hi]:
            raise ConfigError(f"{source}: limits.{lo} {lim[lo]} must be below limits.{hi} {lim[hi]}")
    procs = doc.get("procedures", {})
    if not isinstance(procs, Mapping) or not all(isinstance(v, Mapping) for v in procs.values()):
        raise ConfigError(f"{source}: [procedures.NAME] must be tables of parameters")
    for name, device in devices.items():
        check_profile(name, device.profile, source)
    return BenchConfig(name=bench.get("name", Path(source).stem), exciter=devices["exciter"],
                       recorder=devices["recorder"], limits=Limits(**lim),
                       procedures={k: dict(v) for k, v in procs.items()}, source=source)


def check_profile(device: str, profile: str, source: str) -> None:
    """The `device`'s profile (a name or a path) exists, describes that kind of device and plays
    every role its driver declares (`drivers.roles`); one ConfigError line otherwise."""
    key = f"{source}: {device}.profile = {profile!r}"
    try:
        prof = load_profile(profile)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{source}: {device}.profile: {exc}") from None
    if prof.device != device:
        article = {"exciter": "an", "recorder": "a"}
        raise ConfigError(f"{key} describes {article[prof.device]} {prof.device} (profile {prof.name!r}), "
                          f"not {article[device]} {device}")
    problems = role_problems(prof)
    if problems:
        raise ConfigError(f"{key} (profile {prof.name!r}) does not fit the {device} driver: "
                          + "; ".join(problems))


def load_bench_config(path: str | Path) -> BenchConfig:
    """Read a bench config TOML; ConfigError naming the file and key on anything wrong. Only a
    regular file within the limit of "a bench config" is read (`bench_ctl.limits`: a device or
    a pipe is refused unread)."""
    path = Path(path)
    try:
        doc = tomllib.loads(read_text(path, "a bench config"))
    except InputError as exc:
        raise ConfigError(str(exc)) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return config_from_dict(doc, source=str(path), base=path.resolve().parent)
