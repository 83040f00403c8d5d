"""The exciter's PSS switch: the profile's `pss_on` register (1 the stabiliser's output on, 0 off).

Read with the pre-test snapshot, written like the setpoint (once, read back and compared, at a
monotonic time when asked), and put back by the exciter's safe state when this run wrote it and it
differs; a switch this run never wrote is left as found (someone else moved it), as the setpoint
is. A profile without the register has no switch: nothing is read, written or restored.
"""
from __future__ import annotations

from dataclasses import dataclass

from drivers.device import RegisterDevice, WriteRecord
from drivers.errors import DeviceError, ExceptionReply

PSS_ON = "pss_on"


@dataclass(frozen=True)
class PssPreTest:
    """The switch before the test: its raw words and what they mean."""

    words: tuple[int, ...]
    on: bool


class PssSwitch:
    """The pss_on register of one device: its pre-test state, whether this run wrote it."""

    def __init__(self, device: RegisterDevice) -> None:
        self.device = device
        self.pretest: PssPreTest | None = None
        self.attempted = False   # this run sent (or began to send) a pss_on write

    @property
    def present(self) -> bool:
        return self.device.has(PSS_ON)

    def snapshot(self) -> PssPreTest | None:
        """Read the switch before the test (None when the profile has none)."""
        self.attempted = False
        self.pretest = None
        if self.present:
            words = tuple(self.device.read_words(PSS_ON))
            self.pretest = PssPreTest(words, bool(round(self.device.decode(PSS_ON, words))))
        return self.pretest

    def read(self) -> bool:
        """The switch now (a read of the device)."""
        return bool(round(self.device.read(PSS_ON)))

    def write(self, on: bool, *, purpose: str, at_mono: float | None = None) -> WriteRecord:
        """Write the switch once, read it back and compare (RegisterDevice.write)."""
        if self.pretest is None:
            raise RuntimeError("snapshot() before the first PSS switch write: a test must know what to "
                               "restore" if self.present else
                               f"the profile {self.device.profile.name!r} has no {PSS_ON} register")
        self.attempted = True   # before sending: a Ctrl-C inside the write skips the handlers
        return self.device.write(PSS_ON, 1.0 if on else 0.0, purpose=purpose, at_mono=at_mono)

    def restore(self, reason: str, writes: list[WriteRecord], refused: ExceptionReply | None = None) -> str:
        """Put the pre-test switch back when this run wrote it and it differs (the write appended to
        `writes`); what was done, in words ("" without a switch). Device errors propagate: the
        safe state's loop reconnects and tries again. After the device `refused` that write, it is
        not sent again: the switch is read until the device's watchdog has put it back."""
        pre = self.pretest
        if pre is None:
            return ""
        state = "on" if pre.on else "off"
        words = tuple(self.device.read_words(PSS_ON))
        if words == pre.words:
            if refused is not None:
                return (f"PSS switch put back {state} by the device watchdog after the device refused the "
                        f"host's restore ({refused.message})")
            return f"PSS switch {state} as before the test"
        if not self.attempted:
            return (f"PSS switch not written by this run; it changed since the pre-test snapshot (by "
                    f"someone else) and was left as found ({list(words)}, pre-test {state})")
        if refused is not None:
            raise DeviceError(f"PSS switch still {list(words)} after the refused restore; waiting for the "
                              "device watchdog", device=self.device.name)
        writes.append(self.device.write(PSS_ON, 1.0 if pre.on else 0.0,
                                        purpose=f"restore pre-test PSS switch ({reason})"))
        return f"PSS switch restored to {state} by host"
