"""The electromechanical mode of an on-line record: frequency and damping of the rotor swing seen in
the active power after a setpoint step (issue 27: the report compares the measured one with the
simulated one).

After a voltage-reference step P settles along a slow exponential while the rotor swings about
it. Over a span after the edge the record is fitted, by variable projection, with

    p(t) = c0 + c1 exp(-t / tau) + exp(-sigma t) (a cos(omega t) + b sin(omega t))

the linear coefficients solved for each (tau, sigma, omega) and those three found by
`scipy.optimize.least_squares`, started from the FFT peak of the detrended span. Frequency
f = omega / 2 pi, damping ratio zeta = sigma / sqrt(sigma^2 + omega^2). A swing smaller than
`min_amplitude` times the noise is not a mode (None).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: the band where an electromechanical mode of a unit against the grid lies (Hz)
BAND_HZ = (0.2, 3.0)


@dataclass(frozen=True)
class Mode:
    frequency_hz: float
    damping: float          # ratio zeta
    amplitude: float        # of the swing at the edge (pu of P)
    rms_residual: float     # of the fit (pu)


def _basis(t: np.ndarray, tau: float, sigma: float, omega: float) -> np.ndarray:
    e = np.exp(-sigma * t)
    return np.column_stack([np.ones_like(t), np.exp(-t / tau), e * np.cos(omega * t), e * np.sin(omega * t)])


def electromechanical_mode(time: np.ndarray, p: np.ndarray, t_edge: float, span_s: float = 4.0,
                           min_amplitude: float = 3.0) -> Mode | None:
    """The mode in P over `span_s` seconds from `t_edge` (skipping the first 20 ms), or None when
    the record is too short or the swing is not above `min_amplitude` times the fit's residual."""
    from scipy.optimize import least_squares

    time = np.asarray(time, float)
    p = np.asarray(p, float)
    sel = (time >= t_edge + 0.02) & (time <= t_edge + span_s)
    if np.count_nonzero(sel) < 50:
        return None
    t = time[sel] - time[sel][0]
    y = p[sel]
    dt = float(t[1] - t[0])
    # the start: the FFT peak of the span less a straight line, inside the band
    detr = y - np.polyval(np.polyfit(t, y, 1), t)
    spec = np.abs(np.fft.rfft(detr * np.hanning(detr.size), n=8 * detr.size))
    freqs = np.fft.rfftfreq(8 * detr.size, dt)
    band = (freqs >= BAND_HZ[0]) & (freqs <= BAND_HZ[1])
    if not band.any():
        return None
    f0 = float(freqs[band][np.argmax(spec[band])])

    def residual(z: np.ndarray) -> np.ndarray:
        tau, sigma, omega = math.exp(z[0]), z[1], z[2]
        A = _basis(t, tau, sigma, omega)
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        return A @ coef - y

    starts = [np.array([math.log(tau0), sigma0, 2 * math.pi * f0]) for tau0 in (0.3, 1.5) for sigma0 in (0.3, 1.5)]
    lo = np.array([math.log(0.02), -0.5, 2 * math.pi * BAND_HZ[0]])
    hi = np.array([math.log(50.0), 20.0, 2 * math.pi * BAND_HZ[1]])
    best = None
    for z0 in starts:
        fit = least_squares(residual, np.clip(z0, lo + 1e-9, hi - 1e-9), bounds=(lo, hi))
        if best is None or fit.cost < best.cost:
            best = fit
    assert best is not None
    tau, sigma, omega = math.exp(best.x[0]), float(best.x[1]), float(best.x[2])
    coef, *_ = np.linalg.lstsq(_basis(t, tau, sigma, omega), y, rcond=None)
    amp = float(math.hypot(coef[2], coef[3]))
    rms = float(np.sqrt(np.mean(residual(best.x) ** 2)))
    if amp < min_amplitude * rms:
        return None
    return Mode(omega / (2 * math.pi), sigma / math.hypot(sigma, omega), amp, rms)
