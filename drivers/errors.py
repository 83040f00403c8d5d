"""Device errors people can act on: which device, which register, which value, and the last
frames on the link (docs/style.md, "Errors people can act on").

The classes say what the operator should do next:

- `CommError`: the link failed (no reply, connection lost, garbled frames); check the cable.
  `WriteUncertain` is the dangerous case of it: a write went out and its reply never came, so
  the device may or may not have applied it. It is never re-sent automatically.
- `ExceptionReply`: the device answered with a Modbus exception (it refused the request).
- `ReadbackMismatch`: a write was acknowledged but reading it back gave other raw words.
- `RangeError`: a value was refused before anything was sent (outside the register's range or
  not representable in it).
- `IntegrityError`: a download arrived but is inconsistent (length, sample count, contiguity,
  checksum).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

# Modbus exception codes (Modbus application protocol v1.1b3, section 7)
EXCEPTION_NAMES = {
    1: "illegal function",
    2: "illegal data address",
    3: "illegal data value",
    4: "server device failure",
    5: "acknowledge",
    6: "server device busy",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}


class DeviceError(Exception):
    """A device operation failed. `str()` is the full operator message."""

    def __init__(self, message: str, *, device: str = "", register: str | None = None,
                 value: Any = None, frames: Sequence[str] = (), hint: str = "") -> None:
        self.message = message
        self.device = device
        self.register = register
        self.value = value
        self.frames = list(frames)
        self.hint = hint      # what the device's own state says about it (e.g. watchdog tripped)
        super().__init__(self._compose())

    @property
    def summary(self) -> str:
        """The operator's line: device, what failed, register and value, the device's state;
        without the raw frames (those go to the audit and the -vv log)."""
        head = f"{self.device}: " if self.device else ""
        context = []
        if self.register is not None:
            context.append(f"register {self.register}")
        if self.value is not None:
            context.append(f"value {self.value!r}")
        text = head + self.message
        if context:
            text += " (" + ", ".join(context) + ")"
        if self.hint:
            text += f"; {self.hint}"
        return text

    def _compose(self) -> str:
        text = self.summary
        if self.frames:
            text += "\n  last frames on the link:\n    " + "\n    ".join(self.frames)
        return text

    def to_dict(self) -> dict[str, Any]:
        """For the audit log."""
        return {"error": type(self).__name__, "message": self.message, "device": self.device,
                "register": self.register, "value": self.value, "hint": self.hint,
                "frames": self.frames}


class CommError(DeviceError):
    """The link failed: no reply, connection lost or refused, garbled frames."""


class WriteUncertain(CommError):
    """A write was sent but no reply came: the device may or may not have applied it.
    Never re-sent automatically; the caller decides (read back, or restore)."""


class ExceptionReply(DeviceError):
    """The device answered with a Modbus exception reply."""

    def __init__(self, message: str, *, code: int, **kwargs: Any) -> None:
        self.code = code
        self.request = message
        name = EXCEPTION_NAMES.get(code, "unknown exception")
        super().__init__(f"{message}: device replied with exception {code} ({name})", **kwargs)

    def with_hint(self, hint: str) -> ExceptionReply:
        """The same reply, explained by the device's state (read after the refusal)."""
        return ExceptionReply(self.request, code=self.code, device=self.device,
                              register=self.register, value=self.value, frames=self.frames,
                              hint=hint)


class ReadbackMismatch(DeviceError):
    """A write was acknowledged but the read-back raw words differ."""


class RangeError(DeviceError, ValueError):
    """A value refused before anything was sent."""


class IntegrityError(DeviceError):
    """A download arrived but is inconsistent (length, sample count, contiguity, checksum)."""
