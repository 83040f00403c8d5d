"""Synthetic captures with known parameters, for tests and benchmarks of identification.

`synthetic_capture` simulates a unit (its `value`s are the truth) under the reference pulse and
records it like the bench recorder (noise, quantisation); `random_parameters` draws identified
parameters inside the unit's bounds that satisfy its constraints and give a plausible response
(damped closed loop, efd within an exciter-like range).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from bench_ctl.capture import Capture
from bench_ctl.engine.simulate import RecorderModel, pulse_usetp, simulate, synthetic_record
from bench_ctl.units.overrides import apply_overrides
from bench_ctl.units.unit import Unit

from .construction import make_problem

__all__ = ["synthetic_capture", "random_parameters", "noise_variance", "closed_loop_poles", "with_values"]


def noise_variance(recorder: RecorderModel) -> float:
    """Variance of the recorder error: white noise plus uniform quantisation (lsb^2 / 12)."""
    return recorder.noise_pu ** 2 + recorder.lsb_pu ** 2 / 12.0


def synthetic_capture(unit: Unit, *, duration: float = 10.0, rate: float = 1000.0, seed: int = 0,
                      noise_pu: float = 0.01, amplitude: float = 0.05, width: float | None = 1.0,
                      start: float = 1.0, source: str = "") -> Capture:
    """A capture of `unit` (truth = its values) under a setpoint pulse, as the recorder stores it.

    width=None gives a step. The sidecar-like `meta` records the truth and the test."""
    t, u = pulse_usetp(amplitude=amplitude, width=width if width is not None else 10 * duration,
                       start=start, duration=duration, rate=rate)
    rec = RecorderModel(noise_pu=noise_pu)
    data = synthetic_record(unit, t, u, rec, seed)
    meta = {"synthetic": {"truth": {n: b.value for n, b in unit.identify.items()}, "seed": seed,
                          "noise_pu": noise_pu, "lsb_pu": rec.lsb_pu,
                          "noise_variance": noise_variance(rec)},
            "test": {"kind": "pulse" if width is not None else "step", "start_s": start,
                     "amplitude_pu": amplitude, "width_s": width}}
    return Capture(time=data["time"], usetp=data["usetp"], efd=data["efd"], vt=data["vt"],
                   meta=meta, source=source)


def closed_loop_poles(values: dict[str, float]) -> np.ndarray:
    """Eigenvalues of the linear closed loop (reference model, no effects, TR = 0) at `values`.

    States x1, x2 (lead-lag lags), efd, E'q, E''q; docs/model.md."""
    k, t1, t2, t3, t4, te = (values[n] for n in ("KAVR", "TA1", "TA2", "TA3", "TA4", "TE"))
    tp, tpp = values["Td0p"], values["Td0pp"]
    r1, r2 = t1 / t2, t3 / t4
    # e = -E''q (deviation); y1 = (1 - r1) x1 + r1 e; y2 = (1 - r2) x2 + r2 y1
    A = np.zeros((5, 5))
    A[0] = [-1 / t2, 0, 0, 0, -1 / t2]
    y1 = np.array([1 - r1, 0, 0, 0, -r1])
    A[1] = (y1 - np.array([0, 1, 0, 0, 0])) / t4
    y2 = (1 - r2) * np.array([0, 1, 0, 0, 0]) + r2 * y1
    A[2] = (k * y2 - np.array([0, 0, 1, 0, 0])) / te
    A[3] = [0, 0, 1 / tp, -1 / tp, 0]
    A[4] = [0, 0, 0, 1 / tpp, -1 / tpp]
    return np.linalg.eigvals(A)


def random_parameters(unit: Unit, rng: np.random.Generator, *, names: Sequence[str] | None = None,
                      log_uniform: bool = True, min_damping: float = 0.05, efd_limit: float = 10.0,
                      duration: float = 10.0, rate: float = 1000.0,
                      max_tries: int = 100000) -> dict[str, float]:
    """Identified parameters drawn inside the unit's bounds (log-uniform for positive bounds)
    that satisfy the unit's constraints and give a physically plausible pulse response: every
    closed-loop pole with damping ratio >= `min_damping` and |efd| <= `efd_limit` pu over the
    reference 5 %/1 s pulse recorded for `duration` s."""
    names = tuple(unit.identified_names if names is None else names)
    t, u = pulse_usetp(duration=duration, rate=rate)
    cap = Capture(time=t, usetp=u, efd=np.zeros_like(t))
    prob = make_problem([cap], unit, names=names, fit_edges=False)  # model parameters only
    lo, hi = prob.lower, prob.upper
    for _ in range(max_tries):
        r = rng.random(len(names))
        if log_uniform and np.all(lo > 0):
            x = np.exp(np.log(lo) + r * (np.log(hi) - np.log(lo)))
        else:
            x = lo + r * (hi - lo)
        if prob.violated(x):
            continue
        vals = prob.values(x)
        poles = closed_loop_poles(vals)
        if np.any(-poles.real < min_damping * np.abs(poles)):
            continue
        efd, _, fail = simulate(vals, u, float(t[1] - t[0]))
        if fail < 0 and np.max(np.abs(efd)) <= efd_limit:
            return {n: float(v) for n, v in zip(names, x)}
    raise RuntimeError(f"no plausible parameter set satisfying {list(unit.constraints)} "
                       f"found in {max_tries} draws")


def with_values(unit: Unit, values: dict[str, float]) -> Unit:
    """The unit with its identified parameters' `value`s (the truth of a synthetic capture) set."""
    return apply_overrides(unit, [f"{k}={float(v)!r}" for k, v in values.items()
                                  if math.isfinite(v)])
