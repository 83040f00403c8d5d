"""The simulated transient recorder: samples usetp, efd and vt of the shared plant (and p, q, ifd
on line, when its profile's `channels` lists them: `sim-recorder-online`).

State machine (status values from the profile, see docs/devices.md):
idle -> (arm = 1) recording (pre-trigger filling, triggers not accepted) -> armed (waiting)
-> (manual trigger, or |usetp - usetp at armed| >= threshold) triggered -> done.

Samples are taken every `1000 / sample_rate` plant steps from the first plant step after the
arm write. usetp is the digital setpoint (1e-4 pu per count, noise-free); efd (as recorded:
recorder_gain and time_skew act here), vt and the other channels get Gaussian noise and 12-bit
quantisation over +-10 pu (counts saturate at -2048..2047, like an ADC). The stored record is a
flat array of int16 words, frames [usetp, efd, vt, ...] in the profile's channel order,
downloaded in blocks of `block_words` through a data window; integrity: sample_count,
block_count, CRC-32 of the words (big-endian bytes).
"""
from __future__ import annotations

import logging
import math
import threading
import time
import zlib
from collections import deque
from collections.abc import Mapping, Sequence

import numpy as np
from pymodbus.constants import ExcCodes

from bench_ctl.plants import O_USETP, Plant
from drivers.profile import Profile, Register, a_device

log = logging.getLogger(__name__)

REQUIRED = ("sample_rate", "pre_trigger", "record_length", "trigger_mode", "trigger_threshold",
            "arm", "trigger", "block_index", "status", "sample_count", "block_count",
            "record_crc", "trigger_sample", "usetp_scale", "efd_scale", "vt_scale")
CONFIG = ("sample_rate", "pre_trigger", "record_length", "trigger_mode", "trigger_threshold")
DEFAULT_STATUS = {"idle": 0, "recording": 1, "armed": 2, "triggered": 3, "done": 4}
DEVICE_CODE = 0x5243
FIRMWARE = 0x0100
USETP_LSB = 1e-4
ADC_LSB = 20.0 / 4096
ADC_MIN, ADC_MAX = -2048, 2047


class RecorderDevice:
    """Device logic of the recorder around a shared `Plant`."""

    kind = "recorder"

    def __init__(self, plant: Plant, profile: Profile, *, noise_pu: float = 0.01,
                 seed: int | None = 0) -> None:
        if profile.device != "recorder":
            raise ValueError(f"profile {profile.name!r} is for {a_device(profile.device)}, not a recorder")
        missing = [n for n in REQUIRED if n not in profile.registers]
        if missing:
            raise ValueError(f"recorder profile {profile.name!r} lacks registers {missing}")
        if not profile.data_window_spans():
            raise ValueError(f"recorder profile {profile.name!r}: settings lack block_data_address")
        self.plant = plant
        self.profile = profile
        #: the frame's channels (the profile's `channels`), each a column the plant hands out
        self.channels = tuple(c.strip() for c in str(profile.settings.get("channels", "usetp,efd,vt")).split(","))
        absent = [c for c in self.channels if c not in plant.channels]
        if absent or self.channels[0] != "usetp":
            raise ValueError(f"recorder profile {profile.name!r} records {', '.join(self.channels)}: the "
                             f"{'on-line' if plant.on_line else 'no-load'} plant has "
                             f"{', '.join(plant.channels)}, and usetp comes first")
        missing = [f"{c}_scale" for c in self.channels if f"{c}_scale" not in profile.registers]
        if missing:
            raise ValueError(f"recorder profile {profile.name!r} lacks registers {missing}")
        self._cols = [plant.channels[c] for c in self.channels]
        self.block_words = int(profile.settings["block_words"])
        self.noise_pu = float(noise_pu)
        self._rng = np.random.default_rng(seed)
        st = dict(profile["status"].values) or DEFAULT_STATUS
        missing = set(DEFAULT_STATUS) - set(st)
        if missing:
            raise ValueError(f"recorder profile {profile.name!r}: status lacks values {sorted(missing)}")
        self._code = st
        self._lock = threading.Lock()
        self.config = {"sample_rate": 1000.0, "pre_trigger": 1.0, "record_length": 10.0,
                       "trigger_mode": 1.0, "trigger_threshold": 0.01}
        self.status = "idle"
        self.arm_value = 0
        self._triggered = False
        self._manual_step: int | None = None
        self._arm_step = 0
        self._decim = 1
        self._pre_n = 0
        self._post_n = 0
        self._pre: deque = deque()
        self._post: list = []
        self._pre_frames: list = []
        self._ref = 0.0
        self._stored = 0
        self.trigger_step: int | None = None       # plant step of the trigger sample
        self.first_step: int | None = None         # plant step of record sample 0
        self.record: np.ndarray | None = None      # (n, 3) int16 frames
        self._words: np.ndarray | None = None
        self._crc = 0
        self._rate = 0.0
        self._trigger_sample = 0
        self.block_index: int | None = None
        plant.add_listener(self._on_plant)

    # ---------------------------------------------------------------- image interface
    def snapshot(self) -> Mapping[str, float]:
        with self._lock:
            n = 0 if self.record is None else self.record.shape[0]
            snap = dict(self.config)
            snap.update(
                arm=self.arm_value, trigger=1.0 if (self._triggered or self._manual_step is not None) else 0.0,
                block_index=self.block_index or 0, status=self._code[self.status], sample_count=n,
                channel_count=len(self.channels), block_count=self._blocks(), record_crc=self._crc,
                trigger_sample=self._trigger_sample if self.record is not None else 0,
                **{f"{c}_scale": ADC_LSB for c in self.channels[1:]}, usetp_scale=USETP_LSB,
                record_rate=self._rate if self.record is not None else 0, samples_stored=self._stored,
                trigger_time=(self.trigger_step * self.plant.dt
                              if self.record is not None and self.trigger_step is not None else 0.0),
                device_code=DEVICE_CODE, firmware=FIRMWARE,
                block_echo=0xFFFF if self.block_index is None else self.block_index)
        return snap

    def _blocks(self) -> int:
        if self._words is None:
            return 0
        return -(-self._words.size // self.block_words)

    def read_window(self, offset: int, count: int) -> list[int] | ExcCodes:
        with self._lock:
            if self.status != "done" or self.block_index is None or self._words is None:
                return ExcCodes.DEVICE_BUSY
            base = self.block_index * self.block_words + offset
            chunk = self._words[base:base + count]
            words = [int(w) for w in chunk] + [0] * (count - chunk.size)
        return words

    def write(self, items: Sequence[tuple[Register, float]]) -> ExcCodes | None:
        with self._lock:
            for reg, value in items:
                exc = self._check(reg.name, value)
                if exc is not None:
                    log.info("recorder refuses %s = %r: exception %s", reg.name, value, exc.name)
                    return exc
            for reg, value in items:
                self._apply(reg.name, value)
        return None

    def _running(self) -> bool:
        return self.status in ("recording", "armed", "triggered")

    def _check(self, name: str, value: float) -> ExcCodes | None:
        if name in CONFIG:
            if self._running():
                return ExcCodes.DEVICE_BUSY
            if name == "sample_rate":
                per = 1.0 / (self.plant.dt * value)
                if abs(per - round(per)) > 1e-9:
                    return ExcCodes.ILLEGAL_VALUE
        elif name == "arm":
            if value == 1:
                rate = self.config["sample_rate"]
                # in samples, as the record is stored: at least one sample after the trigger
                if not round(self.config["pre_trigger"] * rate) < round(self.config["record_length"] * rate):
                    return ExcCodes.ILLEGAL_VALUE
        elif name == "trigger":
            if value == 1 and self.status != "armed":
                return ExcCodes.DEVICE_BUSY
        elif name == "block_index":
            if self.status != "done":
                return ExcCodes.DEVICE_BUSY
            if not 0 <= value < self._blocks():
                return ExcCodes.ILLEGAL_VALUE
        return None

    def _apply(self, name: str, value: float) -> None:
        if name in CONFIG:
            self.config[name] = value
        elif name == "arm":
            self.arm_value = int(value)
            if value == 1:
                self._arm()
            elif self._running():
                self.status = "idle"
                log.info("recorder disarmed")
        elif name == "trigger":
            if value == 1:
                now = time.monotonic()
                t0 = self.plant.t0
                self._manual_step = self.plant.step if t0 is None else \
                    max(self.plant.step, math.ceil((now - t0) / self.plant.dt - 1e-9))
        elif name == "block_index":
            self.block_index = int(value)

    def _arm(self) -> None:
        rate = self.config["sample_rate"]
        self._decim = int(round(1.0 / (self.plant.dt * rate)))
        n_total = int(round(self.config["record_length"] * rate))
        self._pre_n = int(round(self.config["pre_trigger"] * rate))
        self._post_n = n_total - self._pre_n
        t0 = self.plant.t0
        self._arm_step = self.plant.step if t0 is None else \
            max(self.plant.step, math.ceil((time.monotonic() - t0) / self.plant.dt - 1e-9))
        self._pre = deque(maxlen=max(self._pre_n, 1))
        self._post = []
        self._pre_frames = []
        self._triggered = False
        self._manual_step = None
        self._stored = 0
        self.record = None
        self._words = None
        self._crc = 0
        self.block_index = None
        self.trigger_step = None
        self.first_step = None
        self._rate = rate
        self.status = "recording"
        log.info("recorder armed: %g Hz, %d pre + %d post samples from plant step %d",
                 rate, self._pre_n, self._post_n, self._arm_step)

    # ---------------------------------------------------------------- sampling
    def _on_plant(self, k0: int, out: np.ndarray) -> None:
        if self.status not in ("recording", "armed", "triggered"):
            return
        with self._lock:
            if not self._running():
                return
            n = out.shape[0]
            ks = np.arange(k0, k0 + n)
            sel = (ks >= self._arm_step) & ((ks - self._arm_step) % self._decim == 0)
            if not sel.any():
                return
            ks = ks[sel]
            rows = out[sel]
            u = rows[:, O_USETP]
            frames = np.empty((rows.shape[0], len(self._cols)), dtype=np.int16)
            frames[:, 0] = np.clip(np.round(u / USETP_LSB), -32768, 32767)
            for col, src in enumerate(self._cols[1:], start=1):
                x = rows[:, src]
                if self.noise_pu > 0:
                    x = x + self._rng.normal(0.0, self.noise_pu, size=x.shape)
                frames[:, col] = np.clip(np.round(x / ADC_LSB), ADC_MIN, ADC_MAX)
            for i in range(frames.shape[0]):
                self._sample(int(ks[i]), float(u[i]), frames[i])
                if self.status == "done":
                    break

    def _sample(self, k: int, usetp: float, frame: np.ndarray) -> None:
        if self.status == "recording":
            if self._pre_n > 0:
                self._pre.append((k, frame))
            self._stored = len(self._pre) if self._pre_n else 0
            if len(self._pre) >= self._pre_n:
                self.status = "armed"
                self._ref = usetp
                log.info("recorder armed (pre-trigger full) at plant step %d", k)
            return
        if self.status == "armed":
            thr = self.config["trigger_threshold"]
            manual = self._manual_step is not None and k >= self._manual_step
            step = self.config["trigger_mode"] == 1 and abs(usetp - self._ref) >= thr - 1e-12
            if manual or step:
                self.status = "triggered"
                self._triggered = True
                self.trigger_step = k
                self._pre_frames = list(self._pre)[-self._pre_n:] if self._pre_n else []
                self._post = [(k, frame)]
                self._stored = len(self._pre_frames) + 1
                log.info("recorder triggered (%s) at plant step %d", "manual" if manual else "usetp step", k)
                if len(self._post) >= self._post_n:
                    self._finish()
            elif self._pre_n > 0:
                self._pre.append((k, frame))
            return
        if self.status == "triggered":
            self._post.append((k, frame))
            self._stored += 1
            if len(self._post) >= self._post_n:
                self._finish()

    def _finish(self) -> None:
        both = self._pre_frames + self._post
        self.record = np.array([f for _, f in both], dtype=np.int16).reshape(-1, len(self.channels))
        self.first_step = both[0][0]
        self._trigger_sample = len(self._pre_frames)
        self._words = self.record.reshape(-1).view(np.uint16).copy()
        self._crc = zlib.crc32(self._words.astype(">u2").tobytes())
        self.status = "done"
        self._pre = deque()
        self._post = []
        log.info("recorder done: %d samples, %d blocks, crc %08x", self.record.shape[0],
                 self._blocks(), self._crc)

    # ---------------------------------------------------------------- helpers for tests / bench
    def record_pu(self) -> dict[str, np.ndarray] | None:
        """The stored record in pu (what a correct download must give: counts times the
        float32 scale registers), or None."""
        with self._lock:
            if self.record is None:
                return None
            r = self.record.astype(float)
            t = (np.arange(r.shape[0]) - self._trigger_sample) / self._rate
            u, a = float(np.float32(USETP_LSB)), float(np.float32(ADC_LSB))   # published scales
            return {"time": t, "usetp": r[:, 0] * u, **{c: r[:, j] * a for j, c in enumerate(self.channels) if j}}
