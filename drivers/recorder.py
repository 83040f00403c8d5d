"""Transient-recorder driver (Modbus RTU on a serial port or pyserial URL), map from a profile.

Configure, arm, (trigger), wait, then download the stored record block by block:
select block i (write `block_index`), read the window (`block_echo` + data words) and check
the echo is i - the selection's read-back and the contiguity check in one. A block whose read
fails or whose echo is wrong is read again (reads are idempotent) up to `attempts` times. The
whole record must then match the device's sample count, block count and CRC-32, else it is
downloaded again; a record that never checks out raises IntegrityError - never a silently short
capture.

The download protocol's layout is profile data (`[settings]`): `channels` (frame order),
`block_data_address`, `block_words`, `block_table`, `crc` ("crc32": zlib CRC-32 of the record
words as big-endian bytes). `RawRecord` is what came off the wire; `RawRecord.save` writes it
before `RawRecord.convert` turns counts into per-unit channels.
"""
from __future__ import annotations

import json
import logging
import math
import os
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.device import RegisterDevice, SafeStateReport, WriteGuard, WriteListener, WriteRecord
from drivers.errors import CommError, DeviceError, IntegrityError, ReadbackMismatch
from drivers.link import ModbusLink
from drivers.profile import Profile, a_device

log = logging.getLogger(__name__)

ACTIVE_STATES = ("recording", "armed", "triggered")


@dataclass(frozen=True)
class RecordSettings:
    """What to record: rate in Hz, pre-trigger and total length in s, trigger mode."""

    rate_hz: int = 1000
    pre_trigger_s: float = 1.0
    length_s: float = 10.0
    trigger: str = "usetp_step"          # manual | usetp_step
    threshold_pu: float = 0.02


@dataclass(frozen=True)
class RawRecord:
    """The stored record as downloaded: interleaved int16 sample frames as uint16 words."""

    words: np.ndarray             # uint16, sample_count * channel_count, no padding
    channels: tuple[str, ...]
    sample_count: int
    rate_hz: float
    trigger_sample: int
    scales: dict[str, float]      # pu per count
    crc32: int
    blocks: int
    block_retries: int
    record_attempts: int
    download_s: float

    def payload(self) -> bytes:
        """The words as big-endian bytes (what the device's CRC covers)."""
        return self.words.astype(">u2").tobytes()

    def header(self) -> dict[str, Any]:
        return {"format": "bench-ctl/recorder-raw/1", "dtype": "int16 big-endian, interleaved",
                "channels": list(self.channels), "sample_count": self.sample_count,
                "rate_hz": self.rate_hz, "trigger_sample": self.trigger_sample,
                "scales_pu_per_count": self.scales, "crc32": self.crc32, "blocks": self.blocks,
                "block_retries": self.block_retries, "record_attempts": self.record_attempts,
                "download_s": self.download_s}

    def save(self, path: str | Path) -> tuple[Path, Path]:
        """Write PATH (raw bytes) and PATH.json (header); refuses to overwrite either. Each file
        appears whole or not at all (written beside it, fsynced, then linked to its name), so a
        full disk leaves no half download under the name."""
        path = Path(path)
        head = path.with_name(path.name + ".json")
        _write_whole(path, self.payload())   # on disk before the capture made from it (docs/safety.md)
        _write_whole(head, (json.dumps(self.header(), indent=2) + "\n").encode("utf-8"))
        return path, head

    def convert(self) -> dict[str, np.ndarray]:
        """Per-unit channels and `time` (s, 0 at the first sample)."""
        counts = self.words.astype(np.uint16).view(np.int16).astype(np.float64)
        frames = counts.reshape(self.sample_count, len(self.channels))
        out = {"time": np.arange(self.sample_count) / self.rate_hz}
        for i, ch in enumerate(self.channels):
            out[ch] = frames[:, i] * self.scales[ch]
        return out


def _write_whole(target: Path, payload: bytes) -> None:
    """`payload` under `target`, whole or not at all; FileExistsError when `target` exists."""
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "xb") as fh:
            fh.write(payload)
            fh.flush()
            os.fsync(fh.fileno())
        try:
            os.link(tmp, target)   # atomic; refuses an existing target
        except FileExistsError:
            raise
        except OSError:            # a file system without hard links: check, then rename
            if target.exists():
                raise FileExistsError(f"{target} exists") from None
            os.replace(tmp, target)
    finally:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass


Progress = Callable[[int, int], None]   # (blocks done, blocks total)


class Recorder(RegisterDevice):
    """Recorder over Modbus RTU. No I/O before `connect()`."""

    #: the recorded channels in frame order (the profile's `channels`)
    channels: tuple[str, ...] = ()

    def __init__(self, link: ModbusLink, profile: Profile, *, attempts: int = 3,
                 guard: WriteGuard | None = None,
                 listener: WriteListener | None = None) -> None:
        if profile.device != "recorder":
            raise ValueError(f"profile {profile.name!r} describes {a_device(profile.device)}, "
                             "not a recorder")
        super().__init__(link, profile, guard=guard, listener=listener)
        s = profile.settings
        try:
            self.channels = tuple(c.strip() for c in str(s["channels"]).split(","))
            self.block_address = int(s["block_data_address"])
            self.block_words = int(s["block_words"])
            self.block_table = str(s.get("block_table", "input"))
        except KeyError as exc:
            raise ValueError(f"profile {profile.name!r}: settings.{exc.args[0]} missing "
                             "(download layout)") from None
        if s.get("crc", "crc32") != "crc32":
            raise ValueError(f"profile {profile.name!r}: settings.crc = {s['crc']!r}; "
                             "only crc32 is implemented")
        self.attempts = attempts
        self.armed_by_us = False

    # -- state -------------------------------------------------------------------------------
    def status(self) -> str:
        reg = self.profile["status"]
        value = int(self.read("status"))
        names = {v: k for k, v in reg.values.items()}
        return names.get(value, f"unknown({value})")

    def wait_status(self, targets: tuple[str, ...], timeout_s: float, *,
                    poll_s: float = 0.02, check: Callable[[], None] | None = None) -> str:
        """Poll until the status is one of `targets` (calling `check` between polls);
        DeviceError when `timeout_s` passes first."""
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.status()
            if state in targets:
                return state
            if check is not None:
                check()
            if time.monotonic() >= deadline:
                raise DeviceError(f"status {state!r} after {timeout_s:g} s, expected one of "
                                  f"{targets}", device=self.name, register="status")
            time.sleep(poll_s)

    # -- configuration and commands ----------------------------------------------------------
    def configure(self, rec: RecordSettings) -> list[WriteRecord]:
        mode = self.profile["trigger_mode"].values.get(rec.trigger)
        if mode is None:
            raise ValueError(f"trigger {rec.trigger!r} not in the profile's trigger_mode values "
                             f"{sorted(self.profile['trigger_mode'].values)}")
        writes = [self.write("sample_rate", rec.rate_hz, purpose="configure"),
                  self.write("pre_trigger", rec.pre_trigger_s, purpose="configure"),
                  self.write("record_length", rec.length_s, purpose="configure"),
                  self.write("trigger_mode", mode, purpose="configure")]
        if rec.trigger == "usetp_step":
            writes.append(self.write("trigger_threshold", rec.threshold_pu, purpose="configure"))
        return writes

    def arm(self) -> WriteRecord:
        self.armed_by_us = True  # before sending: a lost reply may still have armed it
        return self.write("arm", 1, purpose="arm")

    def trigger(self) -> WriteRecord:
        """Manual trigger (sent once; a lost reply is WriteUncertain, never re-sent)."""
        return self.write("trigger", 1, purpose="manual trigger")

    def safe_state(self, reason: str, *, reconnect: bool = False) -> SafeStateReport:
        """Disarm when a record we started is still running; otherwise leave it alone."""
        if not self.armed_by_us:
            return SafeStateReport(self.name, True, "nothing to do (not armed by this run)",
                                   reason=reason)
        try:
            if reconnect:
                self.link.close()
                self.link.connect()
            state = self.status()
            if state not in ACTIVE_STATES:
                self.armed_by_us = False
                return SafeStateReport(self.name, True, f"left in state {state}", reason=reason)
            record = self.write("arm", 0, purpose=f"disarm ({reason})")
            self.armed_by_us = False
            return SafeStateReport(self.name, True, f"disarmed (was {state})", reason=reason,
                                   writes=(record,))
        except DeviceError as exc:
            return SafeStateReport(self.name, False, "NOT DISARMED", detail=str(exc),
                                   reason=reason)

    # -- download ----------------------------------------------------------------------------
    def _expect(self) -> tuple[int, int, int, int, int]:
        samples = int(self.read("sample_count"))
        nch = int(self.read("channel_count"))
        blocks = int(self.read("block_count"))
        crc = int(self.read("record_crc"))
        trig = int(self.read("trigger_sample"))
        if nch != len(self.channels):
            raise IntegrityError(f"channel_count {nch} but the profile lists {self.channels}",
                                 device=self.name, register="channel_count", value=nch)
        if samples <= 0:
            raise IntegrityError("no stored record (sample_count 0)", device=self.name,
                                 register="sample_count", value=samples)
        want = math.ceil(samples * nch / self.block_words)
        if blocks != want:
            raise IntegrityError(f"block_count {blocks} does not fit sample_count {samples} x "
                                 f"{nch} channels in blocks of {self.block_words} words "
                                 f"(expected {want})", device=self.name,
                                 register="block_count", value=blocks)
        return samples, nch, blocks, crc, trig

    def _read_block(self, index: int) -> tuple[list[int], int]:
        """Words of one block and how many retries it took.

        Selecting a block is a write whose read-back is the window's `block_echo` word (the
        device says which block it shows), compared raw like any read-back; with the echo next
        to the data, one read serves both."""
        echo = self.profile["block_echo"]
        contiguous = echo.address + 1 == self.block_address and echo.table == self.block_table
        last: DeviceError | None = None
        for attempt in range(self.attempts):
            try:
                words, t_tx = self.send("block_index", index, purpose="download")
                if contiguous:
                    window = self.link.read(self.block_table, echo.address,
                                            1 + self.block_words, register="block window",
                                            attempts=1)  # retried here, selection and all
                    got, data = window[:1], window[1:]
                else:
                    got = self.read_words("block_echo")
                    data = self.link.read(self.block_table, self.block_address,
                                          self.block_words, register="block window", attempts=1)
                self.confirm("block_index", index, words, got, t_tx, "download")
                return data, attempt
            except (CommError, ReadbackMismatch) as exc:
                last = exc
                log.warning("%s: block %d attempt %d failed: %s", self.name, index,
                            attempt + 1, exc.message)
        assert last is not None
        raise type(last)(f"block {index} failed {self.attempts} times: {last.message}",
                         device=self.name, register=last.register, value=last.value,
                         frames=last.frames)

    def download(self, progress: Progress | None = None) -> RawRecord:
        """The stored record (status must be done); see the module docstring for the checks."""
        state = self.status()
        if state != "done":
            raise DeviceError(f"no finished record to download (status {state!r})",
                              device=self.name, register="status")
        t0 = time.monotonic()
        retries = 0
        problem = ""
        for attempt in range(1, self.attempts + 1):
            samples, nch, blocks, crc, trig = self._expect()
            total = samples * nch
            words: list[int] = []
            for i in range(blocks):
                data, r = self._read_block(i)
                retries += r
                words.extend(data[: min(self.block_words, total - len(words))])
                if progress is not None:
                    progress(i + 1, blocks)
            arr = np.array(words, dtype=np.uint16)
            got_crc = zlib.crc32(arr.astype(">u2").tobytes())
            if arr.size != total:
                problem = f"{arr.size} words, expected {total}"
            elif got_crc != crc:
                problem = f"CRC-32 {got_crc:08x} != device record_crc {crc:08x}"
            elif (int(self.read("sample_count")), int(self.read("record_crc"))) != (samples, crc):
                problem = "the stored record changed during the download"
            else:
                scales = {ch: float(self.read(f"{ch}_scale")) for ch in self.channels}
                rate = float(self.read("record_rate"))
                return RawRecord(words=arr, channels=self.channels, sample_count=samples,
                                 rate_hz=rate, trigger_sample=trig, scales=scales, crc32=crc,
                                 blocks=blocks, block_retries=retries, record_attempts=attempt,
                                 download_s=time.monotonic() - t0)
            log.warning("%s: download attempt %d rejected: %s", self.name, attempt, problem)
        raise IntegrityError(f"record rejected after {self.attempts} downloads: {problem}",
                             device=self.name, register="record_crc",
                             frames=self.link.frames.last())
