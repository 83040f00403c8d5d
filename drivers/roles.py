"""The roles a procedure needs of each device, declared by the drivers as data.

A role is a register the drivers' test sequence relies on (docs/devices.md, "Roles"): the exciter's
setpoint it writes and restores, the heartbeat it keeps changing, the p and vt the pulse test's
preconditions read; the recorder's configuration, status and download registers. Each says
whether a profile must have it, what the host does with it (`access`: "rw" when the host writes
it, so the profile must make it writable; "r" when the host only reads it) and the unit the
drivers' arithmetic assumes (None for a counter or a bit field). A role is found under its own
name in the profile, unless `setting` names the profile setting that says which register plays
it (the watchdog), or `per_channel` makes it one register per recorded channel (the scales).

`role_problems(profile)` lists what a profile lacks or has wrong, one short text per role; the
bench config refuses such a profile when it is loaded, before any file or link is opened
(`bench_ctl.runner.config`). Vendors differ in addresses, types and scales, never in roles.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from drivers.profile import Profile

__all__ = ["EXCITER_ROLES", "RECORDER_ROLES", "ROLES", "Role", "role_problems", "role_register"]


@dataclass(frozen=True)
class Role:
    """One register a procedure relies on, through the drivers."""

    name: str
    required: bool
    access: str                     # "r": the host only reads it; "rw": the host writes it
    unit: str | None = None         # the unit the drivers assume; None: a count or bit field
    values: tuple[str, ...] = ()    # named values (profile `values`) the host relies on
    setting: str | None = None      # the profile setting naming the register, if not `name`
    per_channel: bool = False       # one register per recorded channel: name.format(channel=...)
    what: str = ""                  # what the host does with it, for the operator

    def __post_init__(self) -> None:
        if self.access not in ("r", "rw"):
            raise ValueError(f"role {self.name!r}: access {self.access!r} not in ('r', 'rw')")


#: what the exciter driver and the pulse test need of an excitation system's profile
EXCITER_ROLES: tuple[Role, ...] = (
    Role("setpoint", True, "rw", "pu", what="the AVR voltage setpoint: written, read back, restored"),
    Role("heartbeat", True, "rw", what="a counter the host keeps changing while remote"),
    Role("vt", True, "r", "pu", what="terminal voltage: the band before the test, the recovery after"),
    Role("p", True, "r", "MW", what="active power: the no-load precondition"),
    Role("mode", False, "rw", what="remote / local (bit remote): taken for the test, given back"),
    Role("status", False, "r", what="state bits: watchdog_tripped, remote_other_master"),
    Role("watchdog", False, "r", "s", setting="watchdog_register",
         what="the device's heartbeat watchdog period, read before the first write"),
    Role("active_setpoint", False, "r", "pu", what="the setpoint the AVR acts on"),
    Role("efd", False, "r", "pu", what="field voltage: the operator's live readout"),
    Role("ifd", False, "r", "pu", what="field current"),
    Role("q", False, "r", "Mvar", what="reactive power"),
    Role("device_code", False, "r", what="identity, recorded with the capture"),
    Role("firmware", False, "r", what="identity, recorded with the capture"),
)

#: the recorder states the drivers tell apart (the safe state disarms recording / armed /
#: triggered, the pulse test arms from idle or done and downloads when done)
RECORDER_STATES = ("idle", "recording", "armed", "triggered", "done")

#: what the recorder driver and the pulse test need of a transient recorder's profile
RECORDER_ROLES: tuple[Role, ...] = (
    Role("sample_rate", True, "rw", "Hz", what="configured before arming"),
    Role("pre_trigger", True, "rw", "s", what="configured before arming"),
    Role("record_length", True, "rw", "s", what="configured before arming"),
    Role("trigger_mode", True, "rw", values=("usetp_step",), what="the setpoint-step trigger"),
    Role("trigger_threshold", True, "rw", "pu", what="the setpoint step that triggers"),
    Role("arm", True, "rw", what="armed for the test, disarmed by the safe state"),
    Role("status", True, "r", values=RECORDER_STATES, what="waited on; decides the safe state"),
    Role("block_index", True, "rw", what="selects the block to download"),
    Role("block_echo", True, "r", what="the selected block, read back with its data"),
    Role("sample_count", True, "r", what="the stored record's size"),
    Role("channel_count", True, "r", what="the stored record's frame"),
    Role("block_count", True, "r", what="the stored record's blocks"),
    Role("record_crc", True, "r", what="the stored record's CRC-32"),
    Role("trigger_sample", True, "r", what="where the trigger fell in the record"),
    Role("record_rate", True, "r", "Hz", what="the stored record's sample rate"),
    Role("{channel}_scale", True, "r", "pu", per_channel=True,
         what="per unit per count of each recorded channel"),
    Role("trigger", False, "rw", what="a manual trigger"),
    Role("device_code", False, "r", what="identity, recorded with the capture"),
    Role("firmware", False, "r", what="identity, recorded with the capture"),
)

#: device kind -> its roles
ROLES: dict[str, tuple[Role, ...]] = {"exciter": EXCITER_ROLES, "recorder": RECORDER_ROLES}


def _channels(profile: Profile) -> list[str]:
    raw = profile.settings.get("channels")
    return [c.strip() for c in str(raw).split(",") if c.strip()] if raw is not None else []


def role_register(profile: Profile, role: Role) -> str | None:
    """The register of `profile` that plays `role` (a role not per channel), or None when the
    profile has none."""
    name = profile.settings.get(role.setting) if role.setting else role.name
    return name if isinstance(name, str) and name in profile.registers else None


def _problems_of(profile: Profile, role: Role, register: str | None, label: str) -> list[str]:
    if register is None:
        return [f"role {label}: missing ({role.what})"] if role.required else []
    reg = profile.registers[register]
    where = f"role {label}" + (f" (register {register})" if register != label else "")
    out = []
    if role.access == "rw" and not reg.writable:
        out.append(f"{where}: access {reg.access!r} ({reg.table} register), the host writes it: needs 'rw'")
    if role.unit is not None and reg.unit != role.unit:
        out.append(f"{where}: unit {reg.unit!r}, the drivers compute in {role.unit!r}")
    missing = [v for v in role.values if v not in reg.values]
    if missing:
        out.append(f"{where}: no named value{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                   f"(has {', '.join(reg.values) or 'none'})")
    return out


def role_problems(profile: Profile, roles: Sequence[Role] | None = None) -> list[str]:
    """What `profile` lacks or has wrong for `roles` (default: the roles of its device kind), one
    text per problem: `role p: missing (...)`, `role setpoint: access 'r' ...`, `role watchdog
    (register wd): unit 'ms', ...`. Empty when the profile fits."""
    roles = ROLES[profile.device] if roles is None else roles
    out: list[str] = []
    for role in roles:
        if role.per_channel:
            channels = _channels(profile)
            if role.required and not channels:
                out.append(f"role {role.name}: settings.channels names no channel")
            for ch in channels:
                name = role.name.format(channel=ch)
                out += _problems_of(profile, role, name if name in profile.registers else None, name)
            continue
        if role.setting and role.setting in profile.settings and role_register(profile, role) is None:
            out.append(f"role {role.name}: settings.{role.setting} = "
                       f"{profile.settings[role.setting]!r} is not a register of the profile")
            continue
        out += _problems_of(profile, role, role_register(profile, role), role.name)
    return out
