"""The audit file: one JSON object per line, written and flushed as things happen.

Each line has `t_utc` (ISO 8601), `t_mono_s` (monotonic seconds since the run started),
`kind` (run_start, config, identity, step_start, step_end, precondition, write, heartbeat,
safe_state, error, result, run_end, ...), `step` (the current step or null) and the event's own
fields. A write line carries register, value, raw words, read-back words, its send time and
whether they matched. The file is opened in exclusive-create mode (an audit is never
overwritten). Every line is flushed at once (a crashed process loses nothing); lines that
matter after a power loss too are also fsynced - all but routine ones (heartbeats, download
block selections), whose fsync (~5 ms here) would slow the download several-fold.

Writing the audit never stops a run: the devices' safe state must not depend on a disk. When a
line cannot be written (disk full, read-only, a removed medium) the audit stops writing, counts
the lines it loses and keeps the first error (`lost`, `error`); the run reports it and ends
with exit 2 (or 3). Only `open()` raises: a run that cannot start its audit does not start.
"""
from __future__ import annotations

import json
import logging
import math
import os
import threading
import time
from pathlib import Path
from typing import Any

from bench_ctl.timestamps import utc_now_text

log = logging.getLogger(__name__)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, float) and not math.isfinite(obj):
        return repr(obj)
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (str, int, float, bool)) or obj is None:
        return obj
    if isinstance(obj, (bytes, bytearray)):
        return obj.hex()
    if hasattr(obj, "to_dict"):
        return _jsonable(obj.to_dict())
    if hasattr(obj, "item"):  # numpy scalar
        return _jsonable(obj.item())
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return repr(obj)


class AuditLog:
    """Append-only JSON-lines audit of one run (thread-safe: the heartbeat writes here too)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._fh = None
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self.step: str | None = None
        self.count = 0
        self.lost = 0                      # lines that could not be written
        self.error: OSError | None = None  # the first write error
        self._closed = False

    def open(self) -> AuditLog:
        self._fh = open(self.path, "x", encoding="utf-8")  # never overwrite an audit
        return self

    @property
    def intact(self) -> bool:
        """Every line so far is in the file."""
        return self.error is None

    def loss_text(self) -> str:
        """`audit.jsonl: NOT SAVED: 12 of 80 lines lost ([Errno 28] No space left on device)`."""
        if self.error is None:
            return ""
        return (f"{self.path}: NOT SAVED: {self.lost} of {self.count + self.lost} lines lost "
                f"({_reason(self.error)})")

    def event(self, kind: str, *, durable: bool = True, **fields: Any) -> dict[str, Any]:
        """Append one line, flushed, and fsynced when `durable`; returns the record. A line
        that cannot be written is counted as lost (see the module docstring), never raised."""
        now = time.monotonic()
        record = {"t_utc": utc_now_text("microseconds"),
                  "t_mono_s": round(now - self._t0, 6), "kind": kind, "step": self.step}
        record.update(_jsonable(fields))
        line = json.dumps(record, allow_nan=False)
        with self._lock:
            if self._fh is None and not self._closed and self.error is None:
                raise RuntimeError(f"audit {self.path} is not open")
            if self._fh is None:
                self.lost += 1
                return record
            try:
                self._fh.write(line + "\n")
                self._fh.flush()
                if durable:
                    os.fsync(self._fh.fileno())
            except OSError as exc:
                self._broken(exc)
                return record
            self.count += 1
        return record

    def _broken(self, exc: OSError) -> None:
        """Stop writing after the first failure (a line half on disk is followed by nothing)."""
        self.lost += 1
        self.error = exc
        fh, self._fh = self._fh, None
        try:
            if fh is not None:
                fh.close()
        except OSError:
            pass  # the buffered remainder cannot be written either
        log.error("audit %s: cannot write (%s); the run goes on to its safe state and will say "
                  "what was not saved", self.path, _reason(exc))

    def close(self) -> None:
        with self._lock:
            self._closed = True
            if self._fh is not None:
                try:
                    self._fh.flush()
                    os.fsync(self._fh.fileno())
                    self._fh.close()
                except OSError as exc:
                    self._broken(exc)
                    self.lost -= 1  # no line was lost by closing; the file may be short
                self._fh = None

    def __enter__(self) -> AuditLog:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()


def _reason(exc: OSError) -> str:
    return f"[Errno {exc.errno}] {exc.strerror}" if exc.errno else str(exc)


def read_audit(path: str | Path) -> list[dict[str, Any]]:
    """All records of an audit file (tests and reports use it)."""
    with open(path, encoding="utf-8") as fh:
        return [json.loads(line) for line in fh if line.strip()]
