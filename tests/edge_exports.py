"""Recorder exports without a setpoint channel, for the edge finder and import tests: the
independent plant's response (tests/independent_plant.py, not bench-ctl's model) computed on a fine
grid, then sampled at jittered instants as a trending recorder does, with noise, its edges moved to
known sub-sample instants (the plant is time-invariant: the response to an edge at on_s + shift is
the fine response shifted by `shift`).

Channels: efd and vt as the plant gives them, ifd (E'q + Sat), and the regulator output
vr = efd + TE d(efd)/dt (the exciter lag run backwards; a plant without a ceiling).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import independent_plant as ip

AVR = {"KAVR": 200.0, "TA1": 1.0, "TA2": 0.2, "TA3": 0.5, "TA4": 10.0, "TE": 0.02}
FINE_HZ = 4000.0


@dataclass(frozen=True)
class Fine:
    t: np.ndarray
    channels: dict[str, np.ndarray]
    edges_s: tuple[float, ...]
    on_s: float


@functools.lru_cache(maxsize=8)
def fine_response(amplitude: float = 0.05, width_s: float | None = 1.5, s10: float = 0.0, s12: float = 0.0,
                  duration_s: float = 4.0, on_s: float = 1.0, vrmax: float = math.inf,
                  vrmin: float = -math.inf) -> Fine:
    """The plant's clean response on a FINE_HZ grid to a step (width None) or pulse at on_s, with
    the exciter's ceiling (VRMAX, VRMIN) when given (vr is then efd's, held at the limits too)."""
    plant = ip.Plant({**AVR, "S10": s10, "S12": s12, "VRMAX": vrmax, "VRMIN": vrmin})
    test = ip.Test(on_s=on_s, amplitude_pu=amplitude, width_s=width_s)
    rec = plant.run(test, ip.Recorder(rate_hz=FINE_HZ, duration_s=duration_s, noise_pu=0.0, bits=0), sub=2)
    efd = rec.truth["efd_clean"]
    # VR jumps at an edge: the forward difference puts the jump on the first fine sample at or
    # after it, and `sampled` holds vr between fine samples (never before the edge)
    vr = np.clip(efd + AVR["TE"] * np.append(np.diff(efd) / np.diff(rec.time), 0.0), vrmin, vrmax)
    return Fine(rec.time, {"efd": efd, "vt": rec.vt, "ifd": rec.ifd, "vr": vr},
                tuple(e for e, _ in test.edges()), on_s)


#: noise of each channel as a recorder gives it (pu; vr: the regulator's own output)
NOISE = {"efd": 0.01, "vt": 2e-4, "ifd": 2e-4, "vr": 0.01}


def sampled(fine: Fine, *, seed: int, rate_hz: float = 208.0, jitter: float = 0.04, duration_s: float = 3.5,
            noise: dict[str, float] | None = None) -> tuple[np.ndarray, dict[str, np.ndarray], list[float]]:
    """(time, channels, true edge instants): the fine response sampled at steps drawn uniformly in
    (1 +- jitter) / rate_hz (clock text to 100 ns), its edges shifted by a random fraction of a
    second, plus seeded noise."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * rate_hz)
    steps = np.round(rng.uniform(1 - jitter, 1 + jitter, n - 1) / rate_hz * 1e7) / 1e7
    time = np.concatenate([[0.0], np.cumsum(steps)])
    shift = float(rng.uniform(-0.3, 0.3))
    out = {}
    for name, x in fine.channels.items():
        if name == "vr":   # held: a jump shows at the first sample after it, never before
            clean = x[np.clip(np.searchsorted(fine.t, time - shift, side="right") - 1, 0, x.size - 1)]
        else:
            clean = np.interp(time - shift, fine.t, x)
        out[name] = clean + rng.normal(0.0, (noise or NOISE).get(name, 0.0), time.size)
    return time, out, [e + shift for e in fine.edges_s]


def clock_text(seconds: float) -> str:
    """HH:MM:SS.fffffff after 10:51:42 (a trending recorder's 7 fraction digits)."""
    ticks = int(round(seconds * 1e7)) + (10 * 3600 + 51 * 60 + 42) * 10**7
    whole, frac = divmod(ticks, 10**7)
    return f"{whole // 3600:02d}:{whole // 60 % 60:02d}:{whole % 60:02d}.{frac:07d}"


def write_export(path: Path, time: np.ndarray, columns: dict[str, np.ndarray]) -> Path:
    """A trending-recorder export: date, time (clock), then the given columns."""
    lines = [",".join(["date", "time", *columns])]
    for k in range(time.size):
        lines.append(",".join(["20.09.2015", clock_text(float(time[k]))]
                              + [f"{float(v[k]):.9f}" for v in columns.values()]))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


#: the import options of such an export (bench-ctl import EXPORT -o CAP ...)
CLOCK_ARGS = ["--date-column", "date", "--clock-column", "time", "--date-format", "%d.%m.%Y"]
