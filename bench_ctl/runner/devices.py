"""What a procedure needs of the devices, through the runner (docs/architecture.md: procedures
reach devices only through the runner, never `drivers/` directly).

- `CommError`, `DeviceError`: what a device step may raise (a lost link, a refused request).
- `RecordSettings`: how the recorder is armed (rate, pre-trigger, length, trigger).
- `hold_gc()`: keep the garbage collector out of a short timed sequence (the pulse): a full
  collection stops every thread for tens of ms, which would land on the pulse's deadlines.
- `TIMED_WRITE_GUARD_S`: a timed write takes the link this long (plus one request timeout)
  before its deadline; nothing else may hold the link then.
"""
from __future__ import annotations

from drivers.device import TIMED_WRITE_GUARD_S
from drivers.errors import CommError, DeviceError
from drivers.link import gc_paused as hold_gc
from drivers.recorder import RecordSettings

__all__ = ["TIMED_WRITE_GUARD_S", "CommError", "DeviceError", "RecordSettings", "hold_gc"]
