"""An independent plant: the no-load unit of docs/model.md written apart from the kernel.

Records made here are what every accuracy figure is measured on (tests and benchmarks), so that
bench-ctl is never judged only against its own model (issue 11). Nothing here imports
`bench_ctl.model`: the equations are written again from docs/model.md, integrated by fixed-step RK4
at `sub` sub-steps per recorder sample, with the integration split exactly at the setpoint
edges, which may fall anywhere inside a sample interval. A recorder then samples the setpoint
and efd at the same instants (a change first seen at sample k happened in (t[k-1], t[k]]), adds
noise (seeded) and quantises (an ADC of `bits` over +-`range_pu`).

Effects (docs/model.md, "The eight effects"; any combination): ceiling_limit (non-windup; `VRVT` = 1 scales both
limits with Vt, `KC` drops the upper one by KC*Ifd), dead_time (VR delayed, history interpolated
linearly between sub-steps), transducer_lag, saturation (quadratic through S(1.0), S(1.2)),
rate_limit, setpoint_ramp, recorder_gain and time_skew (efd read from the sub-step history).
Ifd at no load is E'q + Sat(E'q) (the field current on the air-gap-line base).
"""
from __future__ import annotations

import bisect
import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

GENERATOR = {"Td0p": 7.5, "Td0pp": 0.05, "Vt0": 1.0}
NO_EFFECT = {"VRMAX": math.inf, "VRMIN": -math.inf, "VRVT": 0.0, "KC": 0.0, "TD": 0.0, "TR": 0.0,
             "S10": 0.0, "S12": 0.0, "RATE": math.inf, "RAMP": math.inf, "GAIN": 1.0, "SKEW": 0.0}
EFFECT_PARAMS = {"ceiling_limit": ("VRMAX", "VRMIN"), "dead_time": ("TD",), "transducer_lag": ("TR",),
                 "saturation": ("S10", "S12"), "rate_limit": ("RATE",), "setpoint_ramp": ("RAMP",),
                 "recorder_gain": ("GAIN",), "time_skew": ("SKEW",)}


@dataclass(frozen=True)
class Test:
    """A setpoint pulse (width_s) or step (width_s None) of amplitude_pu at on_s (any instant)."""
    __test__ = False  # a setpoint test, not a pytest class
    on_s: float = 1.0
    amplitude_pu: float = 0.05
    width_s: float | None = 1.0
    usetp0_pu: float = 1.0

    def edges(self) -> list[tuple[float, float]]:
        out = [(self.on_s, self.amplitude_pu)]
        if self.width_s is not None:
            out.append((self.on_s + self.width_s, -self.amplitude_pu))
        return out

    def usetp(self, t: float) -> float:
        return self.usetp0_pu + sum(a for te, a in self.edges() if t >= te)


@dataclass(frozen=True)
class Recorder:
    rate_hz: float = 1000.0
    duration_s: float = 10.0
    noise_pu: float = 0.01
    bits: int = 16
    range_pu: float = 10.0
    #: noise of the Vt channel (a transducer output on its own range: smaller than efd's)
    noise_vt_pu: float = 0.002

    def quantise(self, x: np.ndarray) -> np.ndarray:
        if self.bits <= 0:
            return x
        lsb = 2.0 * self.range_pu / 2 ** self.bits
        return np.round(x / lsb) * lsb


@dataclass
class Record:
    time: np.ndarray
    usetp: np.ndarray
    efd: np.ndarray
    vt: np.ndarray
    ifd: np.ndarray
    truth: dict = field(default_factory=dict)

    def write_csv(self, path: str | Path, *, vt: bool = False, ifd: bool = False) -> Path:
        """The record as a capture CSV (time, usetp, efd[, vt][, ifd]), full float precision."""
        path = Path(path)
        cols = {"time": self.time, "usetp": self.usetp, "efd": self.efd}
        if vt:
            cols["vt"] = self.vt
        if ifd:
            cols["ifd"] = self.ifd
        with path.open("w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(list(cols))
            for row in zip(*cols.values()):
                w.writerow([repr(float(v)) for v in row])
        return path


def _sat_coefficients(s10: float, s12: float) -> tuple[float, float]:
    """Sat(x) = B (x - A)^2 above A, through S(1.0) = s10 and S(1.2) = s12 (none when s10 = 0)."""
    if s10 <= 0.0:
        return 0.0, 0.0
    r = math.sqrt(s12 / s10)
    a = (1.2 - r) / (1.0 - r)  # from (1.2 - a) / (1 - a) = r
    return a, s10 / (1.0 - a) ** 2


class Plant:
    """One parameter set (AVR + generator + effects) integrated through one test."""

    def __init__(self, params: dict[str, float]):
        p = {**GENERATOR, **NO_EFFECT, **params}
        self.p = p
        self.sa, self.sb = _sat_coefficients(p["S10"], p["S12"])
        vt0 = p["Vt0"]
        self.efd0 = vt0 + self.sat(vt0)
        self.uref0 = vt0 + self.efd0 / p["KAVR"]
        self.r1, self.r2 = p["TA1"] / p["TA2"], p["TA3"] / p["TA4"]

    def sat(self, x: float) -> float:
        return self.sb * (x - self.sa) ** 2 if x > self.sa else 0.0

    def limits(self, eqp: float, eqpp: float) -> tuple[float, float]:
        p = self.p
        scale = 1.0 + p["VRVT"] * (eqpp - 1.0)
        return p["VRMAX"] * scale - p["KC"] * (eqp + self.sat(eqp)), p["VRMIN"] * scale

    def vr(self, uref: float, s: tuple) -> float:
        """AVR output for the state s = (vm_filter, w1, w2, efd, E'q, E''q) (w: lead-lag states)."""
        p = self.p
        vm = s[0] if p["TR"] > 0 else s[5]
        y1 = self.r1 * (uref - vm) + (1.0 - self.r1) * s[1]
        return p["KAVR"] * (self.r2 * y1 + (1.0 - self.r2) * s[2])

    def deriv(self, uref: float, drive: float | None, s: tuple) -> tuple:
        p = self.p
        vm = s[0] if p["TR"] > 0 else s[5]
        e = uref - vm
        y1 = self.r1 * e + (1.0 - self.r1) * s[1]
        u_exc = p["KAVR"] * (self.r2 * y1 + (1.0 - self.r2) * s[2]) if drive is None else drive
        de = (u_exc - s[3]) / p["TE"]
        de = max(-p["RATE"], min(p["RATE"], de))
        hi, lo = self.limits(s[4], s[5])
        if s[3] >= hi and de > 0.0:   # non-windup: held at the limit (the clamp makes it follow)
            de = 0.0
        if s[3] <= lo and de < 0.0:
            de = 0.0
        return ((s[5] - s[0]) / p["TR"] if p["TR"] > 0 else 0.0, (e - s[1]) / p["TA2"], (y1 - s[2]) / p["TA4"],
                de, (s[3] - s[4] - self.sat(s[4])) / p["Td0p"], (s[4] - s[5]) / p["Td0pp"])

    def run(self, test: Test, recorder: Recorder, *, sub: int = 10, seed: int = 0) -> Record:
        """Integrate the test and sample it as the recorder would."""
        p = self.p
        dt = 1.0 / recorder.rate_hz
        n = int(round(recorder.duration_s * recorder.rate_hz)) + 1
        t_end = (n - 1) * dt
        # the integration grid: uniform sub-steps, plus every setpoint edge instant
        grid = np.arange(0, (n - 1) * sub + 1) * (dt / sub)
        # ... and where the delayed VR jumps (an edge seen through the dead time, and again)
        jumps = [te + j * p["TD"] for te, _ in test.edges() for j in range(4 if p["TD"] > 0 else 1)]
        edges = sorted(te for te in jumps if 0.0 < te < t_end)
        grid = np.unique(np.concatenate([grid, edges])).tolist()
        e0 = self.efd0 / p["KAVR"]  # AVR error at steady state: uref0 - Vt0
        s = (p["Vt0"], e0, e0, self.efd0, p["Vt0"], p["Vt0"])
        uref = self.uref0
        hist_t, hist_s = [0.0], [s]
        vr_t, vr_v = [0.0], [self.efd0]   # VR history: left and right limits at a jump
        td, ramp = p["TD"], p["RAMP"]
        ramped = math.isfinite(ramp)

        def delayed(t: float, left: bool = False) -> float | None:
            """VR at t - TD; `left`: just before a jump there (the end of a sub-step)."""
            if td <= 0.0:
                return None
            tq = t - td
            if tq <= 0.0:
                return self.efd0
            near = bisect.bisect_left(vr_t, tq - 1e-9 * dt)  # t - TD lands on a history point
            if near < len(vr_t) and abs(vr_t[near] - tq) <= 1e-9 * dt:
                tq = vr_t[near]
            find = bisect.bisect_left if left else bisect.bisect_right
            j = min(max(find(vr_t, tq) - (0 if left else 1), 0), len(vr_t) - 2)
            if left:
                j = max(0, j - 1)
            if j < 0:
                return self.efd0
            t0, t1 = vr_t[j], vr_t[j + 1]
            w = (tq - t0) / (t1 - t0) if t1 > t0 else 1.0
            return vr_v[j] + w * (vr_v[j + 1] - vr_v[j])

        def add(x, k, h):
            return tuple(a + h * b for a, b in zip(x, k))

        for a, b in zip(grid[:-1], grid[1:]):
            h = b - a
            target = self.uref0 + (test.usetp(a + 0.5 * h) - test.usetp0_pu)
            if ramped:
                u_a, u_b = uref, uref + max(-ramp * h, min(ramp * h, target - uref))
            else:
                u_a = u_b = target
            u_m = 0.5 * (u_a + u_b)
            k1 = self.deriv(u_a, delayed(a), s)
            k2 = self.deriv(u_m, delayed(a + 0.5 * h), add(s, k1, 0.5 * h))
            k3 = self.deriv(u_m, delayed(a + 0.5 * h), add(s, k2, 0.5 * h))
            k4 = self.deriv(u_b, delayed(b, left=True), add(s, k3, h))
            s = tuple(x + h / 6.0 * (q1 + 2 * q2 + 2 * q3 + q4) for x, q1, q2, q3, q4 in zip(s, k1, k2, k3, k4))
            hi, lo = self.limits(s[4], s[5])
            s = (s[0], s[1], s[2], min(max(s[3], lo), hi), s[4], s[5])
            uref = u_b
            hist_t.append(b)
            hist_s.append(s)
            if td > 0.0:
                vr_t.append(b)
                vr_v.append(self.vr(u_b, s))  # left limit at b
                after = uref if ramped else self.uref0 + (test.usetp(b) - test.usetp0_pu)
                if after != u_b:  # a setpoint jump at b: the right limit too
                    vr_t.append(b)
                    vr_v.append(self.vr(after, s))
        H = np.array(hist_s)
        T = np.array(hist_t)
        t = np.arange(n) * dt
        efd_true = np.interp(t - p["SKEW"], T, H[:, 3], left=self.efd0)
        vt = np.interp(t, T, H[:, 5])
        eqp = np.interp(t, T, H[:, 4])
        ifd = eqp + np.array([self.sat(x) for x in eqp])
        rng = np.random.default_rng(seed)
        efd = recorder.quantise(p["GAIN"] * efd_true + rng.normal(0.0, recorder.noise_pu, n))
        if recorder.noise_pu > 0.0:  # drawn after efd's: efd is the same with or without it
            vt = recorder.quantise(vt + rng.normal(0.0, recorder.noise_vt_pu, n))
        usetp = np.array([test.usetp(x) for x in t])  # the recorder samples the setpoint
        truth = {"params": dict(p), "edges_s": [te for te, _ in test.edges()],
                 "noise_pu": recorder.noise_pu, "efd_clean": p["GAIN"] * efd_true}
        return Record(t, usetp, efd, vt, ifd, truth)


# ---------------------------------------------------------------------- random cases

AVR_RANGES = {"KAVR": (100.0, 400.0), "TA1": (0.3, 3.0), "TA2": (0.05, 0.6), "TA3": (0.05, 1.0),
              "TA4": (1.0, 20.0), "TE": (0.005, 0.05)}


def draw_avr(rng: np.random.Generator) -> dict[str, float]:
    """AVR parameters inside the reference unit's bounds with TA2 <= TA1 and TA4 >= TA2, whose
    closed loop at no load is stable and settles (checked by a short simulation)."""
    for _ in range(1000):
        x = {n: float(math.exp(rng.uniform(math.log(lo), math.log(hi)))) for n, (lo, hi) in AVR_RANGES.items()}
        if not (x["TA2"] <= x["TA1"] and x["TA4"] >= x["TA2"]):
            continue
        rec = Plant(x).run(Test(on_s=0.5), Recorder(rate_hz=200.0, duration_s=6.0, noise_pu=0.0, bits=0), sub=10)
        efd = rec.truth["efd_clean"]
        if np.all(np.isfinite(efd)) and 1.5 < efd.max() < 8.0 and efd.min() > -6.0 \
                and abs(efd[-1] - efd[0]) < 0.05:
            return x
    raise RuntimeError("no stable AVR parameter set drawn")


def draw_effect(name: str, rng: np.random.Generator, free_efd: np.ndarray, dt: float) -> dict[str, float]:
    """Effect parameters that visibly change the pulse response `free_efd` (no effect) and stay
    physically plausible (the ranges of a commissioning record)."""
    efd0 = float(free_efd[0])
    if name == "ceiling_limit":
        return {"VRMAX": efd0 + (1.0 - rng.uniform(0.15, 0.4)) * (float(free_efd.max()) - efd0),
                "VRMIN": efd0 - (1.0 - rng.uniform(0.15, 0.4)) * (efd0 - float(free_efd.min()))}
    if name == "dead_time":
        return {"TD": float(rng.uniform(0.005, 0.04))}
    if name == "transducer_lag":
        return {"TR": float(rng.uniform(0.02, 0.12))}
    if name == "saturation":
        s10 = float(rng.uniform(0.03, 0.15))
        return {"S10": s10, "S12": s10 * float(rng.uniform(2.5, 5.0))}
    if name == "rate_limit":
        slope = float(np.max(np.abs(np.diff(free_efd)))) / dt
        return {"RATE": float(np.clip(rng.uniform(0.2, 0.6) * slope, 2.0, 500.0))}
    if name == "setpoint_ramp":
        return {"RAMP": 0.05 / float(rng.uniform(0.05, 0.3))}
    if name == "recorder_gain":
        return {"GAIN": 1.0 + float(rng.choice([-1.0, 1.0]) * rng.uniform(0.03, 0.1))}
    if name == "time_skew":
        return {"SKEW": float(rng.uniform(0.005, 0.03))}
    raise ValueError(f"unknown effect {name!r}")


#: the effects `draw_one_regime` draws
ONE_REGIME = ("saturation", "ceiling_limit")


def draw_one_regime(name: str, rng: np.random.Generator, free_efd: np.ndarray, dt: float) -> dict[str, float]:
    """Effect parameters whose evidence lies in one regime of the pulse response `free_efd`:
    saturation with its knee just below the pre-step Vt of 1.0 (S(1.0) 0.005-0.02, S(1.2) 0.3-0.8:
    S(1.05) is 3-15 times S(1.0), so the plateau carries it); a ceiling reached on the leading edge
    only (VRMAX cuts 15-40 % off the overshoot, VRMIN out of reach)."""
    efd0 = float(free_efd[0])
    if name == "saturation":
        return {"S10": float(rng.uniform(0.005, 0.02)), "S12": float(rng.uniform(0.3, 0.8))}
    if name == "ceiling_limit":
        return {"VRMAX": efd0 + (1.0 - rng.uniform(0.15, 0.4)) * (float(free_efd.max()) - efd0),
                "VRMIN": efd0 - 3.0 * (efd0 - float(free_efd.min())) - 1.0}
    raise ValueError(f"{name!r} has no one-regime form: choose one of {', '.join(ONE_REGIME)}")


def random_edges(rng: np.random.Generator, test: Test, dt: float, where: str = "inside") -> Test:
    """The test with each edge moved off the sample grid: `inside` to its own random instant inside
    the sample interval before the nominal sample, `early` a whole sample before it, `on` on it."""
    def shift() -> float:
        if where == "inside":
            return -float(rng.uniform(0.02, 0.98)) * dt
        if where == "early":
            return -dt
        if where == "on":
            return 0.0
        raise ValueError(f"edges {where!r}: choose inside, early or on")

    on = test.on_s + shift()
    width = None if test.width_s is None else test.on_s + test.width_s + shift() - on
    return Test(on_s=on, amplitude_pu=test.amplitude_pu, width_s=width, usetp0_pu=test.usetp0_pu)
