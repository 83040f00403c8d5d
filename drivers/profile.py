"""Device profiles: register maps as data (TOML) and the codec between registers and values.

A profile describes one device kind (``exciter`` or ``recorder``): its identity, free device
settings and one entry per register (table, 0-based address, type, word order, scale, unit,
access, limits). Drivers and simulators work on register *names*; the profile alone decides
addresses and encodings, so two vendors differ in data, not in code.

TOML form (``drivers/profiles/NAME.toml``)::

    [profile]
    name = "sim-exciter"
    device = "exciter"            # exciter | recorder
    description = "..."           # optional

    [identity]                    # free strings / numbers: vendor, model, ...
    vendor = "bench-ctl"
    model = "SIM-EXC-1"

    [settings]                    # optional free device settings (scalars)
    heartbeat_timeout_s = 2.0

    [registers.setpoint]
    table = "holding"             # holding | input
    address = 0                   # 0-based
    type = "float32"              # uint16 | int16 | uint32 | int32 | float32
    word_order = "ABCD"           # ABCD = high word first, CDAB = low word first (32-bit only)
    scale = 1.0                   # engineering = raw * scale
    unit = "pu"
    access = "rw"                 # r | rw (input registers are always r)
    min = 0.9                     # engineering, optional
    max = 1.1                     # engineering, optional
    description = "AVR voltage setpoint"
    bits = { auto = 0, remote = 1 }          # optional: named bits of an integer register
    values = { idle = 0, armed = 2 }         # optional: named values of an integer register

Unknown keys anywhere are errors naming the file and the key; registers overlapping in the
same table are errors.
"""

from __future__ import annotations

import logging
import math
import struct
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench_ctl.limits import read_text

log = logging.getLogger(__name__)

PROFILE_DIR = Path(__file__).resolve().parent / "profiles"

TABLES = ("holding", "input")
TYPES = ("uint16", "int16", "uint32", "int32", "float32")
WORD_ORDERS = ("ABCD", "CDAB")
ACCESS = ("r", "rw")
DEVICES = ("exciter", "recorder")

_INT_RANGE = {
    "uint16": (0, 0xFFFF),
    "int16": (-0x8000, 0x7FFF),
    "uint32": (0, 0xFFFFFFFF),
    "int32": (-0x80000000, 0x7FFFFFFF),
}
_FLOAT32_MAX = 3.4028234663852886e38
# A scaled integer must be this close to a whole count to be "representable" (absorbs the
# binary rounding of e.g. 1.05 / 0.0001 = 10500.000000000002, refuses 1.05123 at 0.0001).
_COUNT_TOL = 1e-6


@dataclass(frozen=True)
class Register:
    """One register (or 32-bit register pair) of a device profile."""

    name: str
    table: str
    address: int
    type: str
    word_order: str = "ABCD"
    scale: float = 1.0
    unit: str = ""
    access: str = "r"
    min: float | None = None
    max: float | None = None
    description: str = ""
    bits: Mapping[str, int] = field(default_factory=dict, hash=False, compare=False)
    values: Mapping[str, int] = field(default_factory=dict, hash=False, compare=False)

    def __post_init__(self) -> None:
        where = f"register {self.name!r}"
        if self.table not in TABLES:
            raise ValueError(f"{where}: table {self.table!r} not in {TABLES}")
        if self.type not in TYPES:
            raise ValueError(f"{where}: type {self.type!r} not in {TYPES}")
        if self.word_order not in WORD_ORDERS:
            raise ValueError(f"{where}: word_order {self.word_order!r} not in {WORD_ORDERS}")
        if self.access not in ACCESS:
            raise ValueError(f"{where}: access {self.access!r} not in {ACCESS}")
        if self.table == "input" and self.access != "r":
            raise ValueError(f"{where}: input registers are read-only (access must be 'r')")
        if isinstance(self.address, bool) or not isinstance(self.address, int):
            raise ValueError(f"{where}: address {self.address!r} is not an integer")
        if not 0 <= self.address <= 0xFFFF - (self.count - 1):
            raise ValueError(f"{where}: address {self.address} outside 0..65535")
        if not (isinstance(self.scale, (int, float)) and math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"{where}: scale {self.scale!r} must be a finite number > 0")
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError(f"{where}: min {self.min} > max {self.max}")
        if (self.bits or self.values) and self.type == "float32":
            raise ValueError(f"{where}: bits/values need an integer type, not float32")
        for bname, bit in self.bits.items():
            if not (isinstance(bit, int) and 0 <= bit < 16 * self.count):
                raise ValueError(f"{where}: bit {bname!r}={bit!r} outside 0..{16 * self.count - 1}")

    @property
    def count(self) -> int:
        """Number of 16-bit words (1 or 2)."""
        return 1 if self.type in ("uint16", "int16") else 2

    @property
    def end(self) -> int:
        """One past the last address used."""
        return self.address + self.count

    @property
    def writable(self) -> bool:
        return self.access == "rw"

    def check_range(self, value: float) -> None:
        """Raise ValueError when ``value`` (engineering) is outside min/max or not finite."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"register {self.name!r}: value {value!r} is not a number")
        if not math.isfinite(value):
            raise ValueError(f"register {self.name!r}: value {value!r} is not finite")
        if self.min is not None and value < self.min:
            raise ValueError(
                f"register {self.name!r}: value {value!r} {self.unit} below min {self.min}")
        if self.max is not None and value > self.max:
            raise ValueError(
                f"register {self.name!r}: value {value!r} {self.unit} above max {self.max}")

    def encode(self, value: float) -> list[int]:
        """Engineering value -> register words; ValueError when out of range or not representable."""
        self.check_range(value)
        raw = value / self.scale
        if self.type == "float32":
            if abs(raw) > _FLOAT32_MAX:
                raise ValueError(f"register {self.name!r}: value {value!r} overflows float32")
            (u32,) = struct.unpack(">I", struct.pack(">f", raw))
        else:
            count = round(raw)
            if abs(raw - count) > _COUNT_TOL * max(1.0, abs(raw)):
                raise ValueError(
                    f"register {self.name!r}: value {value!r} is not a multiple of the scale "
                    f"{self.scale} (raw {raw!r}); nearest representable is {count * self.scale!r}")
            lo, hi = _INT_RANGE[self.type]
            if not lo <= count <= hi:
                raise ValueError(
                    f"register {self.name!r}: value {value!r} (raw {count}) outside {self.type} "
                    f"range {lo}..{hi}")
            if self.count == 1:
                return [count & 0xFFFF]
            u32 = count & 0xFFFFFFFF
        hi_w, lo_w = (u32 >> 16) & 0xFFFF, u32 & 0xFFFF
        return [hi_w, lo_w] if self.word_order == "ABCD" else [lo_w, hi_w]

    def decode(self, words: Sequence[int]) -> float:
        """Register words -> engineering value (raw * scale)."""
        if len(words) != self.count:
            raise ValueError(
                f"register {self.name!r}: expected {self.count} word(s), got {len(words)}")
        for w in words:
            if isinstance(w, bool) or not isinstance(w, int) or not 0 <= w <= 0xFFFF:
                raise ValueError(f"register {self.name!r}: word {w!r} is not a 16-bit value")
        if self.count == 1:
            raw: float = words[0] - 0x10000 if (self.type == "int16" and words[0] & 0x8000) else words[0]
            return raw * self.scale
        hi_w, lo_w = (words[0], words[1]) if self.word_order == "ABCD" else (words[1], words[0])
        u32 = (hi_w << 16) | lo_w
        if self.type == "float32":
            (raw,) = struct.unpack(">f", struct.pack(">I", u32))
        elif self.type == "int32":
            raw = u32 - 0x100000000 if u32 & 0x80000000 else u32
        else:
            raw = u32
        return raw * self.scale

    def representable(self, value: float) -> float:
        """The value the register would read back after ``encode(value)`` (no range check)."""
        if self.type == "float32":
            return float(struct.unpack(">f", struct.pack(">f", value / self.scale))[0]) * self.scale
        return round(value / self.scale) * self.scale


@dataclass(frozen=True)
class Profile:
    """A device's register map, identity and free settings."""

    name: str
    device: str
    identity: dict[str, Any]
    registers: dict[str, Register]
    settings: dict[str, Any] = field(default_factory=dict)
    description: str = ""
    path: str = ""

    def __post_init__(self) -> None:
        if self.device not in DEVICES:
            raise ValueError(f"profile {self.name!r}: device {self.device!r} not in {DEVICES}")
        check_overlaps(self.registers.values(), where=f"profile {self.name!r}",
                       extra=self.data_window_spans())

    def data_window_spans(self) -> list[tuple[str, str, int, int]]:
        """The recorder's block data window from settings, as (name, table, start, end)."""
        if "block_data_address" not in self.settings:
            return []
        table = self.settings.get("block_table", "input")
        start = self.settings["block_data_address"]
        words = self.settings.get("block_words")
        if table not in TABLES or not isinstance(start, int) or not isinstance(words, int) \
                or not 1 <= words <= 123 or not 0 <= start <= 0xFFFF - words + 1:
            raise ValueError(
                f"profile {self.name!r}: block_table/block_data_address/block_words = "
                f"{table!r}/{start!r}/{words!r} do not describe a data window of 1..123 words")
        return [("block data window", table, start, start + words)]

    def __getitem__(self, name: str) -> Register:
        try:
            return self.registers[name]
        except KeyError:
            raise KeyError(f"profile {self.name!r} has no register {name!r}") from None

    def by_table(self, table: str) -> list[Register]:
        """Registers of one table sorted by address."""
        return sorted((r for r in self.registers.values() if r.table == table),
                      key=lambda r: r.address)


def check_overlaps(registers: Any, where: str = "profile",
                   extra: Sequence[tuple[str, str, int, int]] = ()) -> None:
    """Raise ValueError when two registers (or extra (name, table, start, end) spans) overlap."""
    spans = [(r.table, r.address, r.end, r.name) for r in registers]
    spans += [(t, a, e, n) for n, t, a, e in extra]
    spans.sort()
    for (t1, a1, e1, n1), (t2, a2, e2, n2) in zip(spans, spans[1:]):
        if t1 == t2 and a2 < e1:
            raise ValueError(
                f"{where}: {t1} registers {n1!r} ({a1}..{e1 - 1}) and {n2!r} ({a2}..{e2 - 1}) overlap")


_TOP_KEYS = {"profile", "identity", "settings", "registers"}
_PROFILE_KEYS = {"name", "device", "description"}
_REGISTER_KEYS = {"table", "address", "type", "word_order", "scale", "unit", "access", "min",
                  "max", "description", "bits", "values"}


def resolve_profile_path(name_or_path: str | Path) -> Path:
    """A bare name resolves to drivers/profiles/NAME.toml; anything else is a path."""
    text = str(name_or_path)
    if "/" not in text and "\\" not in text and not text.endswith(".toml"):
        return PROFILE_DIR / f"{text}.toml"
    return Path(text)


def load_profile(name_or_path: str | Path) -> Profile:
    """Read and validate a profile TOML; errors name the file and the offending key. Only a
    regular file within the limit of "a profile" is read (`bench_ctl.limits`: a device or a pipe
    is refused unread; an `InputError` is a ValueError)."""
    path = resolve_profile_path(name_or_path)
    if not path.exists():   # a bare name resolved to drivers/profiles/NAME.toml: say where
        raise FileNotFoundError(f"profile {path}: no such file")
    try:
        doc = tomllib.loads(read_text(path, "a profile"))
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"profile {path}: {exc}") from None
    return profile_from_dict(doc, source=str(path))


def profile_from_dict(doc: Mapping[str, Any], source: str = "<dict>") -> Profile:
    """Build a Profile from the parsed TOML document (see module docstring)."""
    _no_unknown(doc, _TOP_KEYS, source, "")
    head = doc.get("profile")
    if not isinstance(head, Mapping):
        raise ValueError(f"profile {source}: missing [profile] table with name and device")
    _no_unknown(head, _PROFILE_KEYS, source, "profile.")
    for key in ("name", "device"):
        if not isinstance(head.get(key), str):
            raise ValueError(f"profile {source}: profile.{key} missing or not a string")
    identity = dict(doc.get("identity", {}))
    settings = dict(doc.get("settings", {}))
    for key, val in settings.items():
        if not isinstance(val, (str, int, float, bool)):
            raise ValueError(f"profile {source}: settings.{key} must be a scalar, got {val!r}")
    regs_doc = doc.get("registers")
    if not isinstance(regs_doc, Mapping) or not regs_doc:
        raise ValueError(f"profile {source}: no [registers.NAME] tables")
    registers: dict[str, Register] = {}
    for rname, rdoc in regs_doc.items():
        if not isinstance(rdoc, Mapping):
            raise ValueError(f"profile {source}: registers.{rname} is not a table")
        _no_unknown(rdoc, _REGISTER_KEYS, source, f"registers.{rname}.")
        for key in ("table", "address", "type"):
            if key not in rdoc:
                raise ValueError(f"profile {source}: registers.{rname}.{key} missing")
        kwargs = dict(rdoc)
        for key in ("bits", "values"):
            if key in kwargs:
                if not isinstance(kwargs[key], Mapping):
                    raise ValueError(f"profile {source}: registers.{rname}.{key} must be a table")
                kwargs[key] = dict(kwargs[key])
        for key in ("scale", "min", "max"):
            if key in kwargs and (isinstance(kwargs[key], bool)
                                  or not isinstance(kwargs[key], (int, float))):
                raise ValueError(
                    f"profile {source}: registers.{rname}.{key} = {kwargs[key]!r} is not a number")
            if key in kwargs:
                kwargs[key] = float(kwargs[key])
        try:
            registers[rname] = Register(name=rname, **kwargs)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"profile {source}: {exc}") from exc
    try:
        return Profile(name=head["name"], device=head["device"], identity=identity,
                       registers=registers, settings=settings,
                       description=str(head.get("description", "")), path=source)
    except ValueError as exc:
        raise ValueError(f"profile {source}: {exc}") from exc


def _no_unknown(doc: Mapping[str, Any], allowed: set[str], source: str, prefix: str) -> None:
    for key in doc:
        if key not in allowed:
            raise ValueError(
                f"profile {source}: unknown key {prefix}{key!r} (allowed: {sorted(allowed)})")


def a_device(kind: str) -> str:
    """`an exciter`, `a recorder`: a device kind with its article, for messages."""
    return f"{'an' if kind[:1] in 'aeiou' else 'a'} {kind}"
