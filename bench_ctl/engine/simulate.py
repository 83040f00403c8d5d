"""High-level simulation: parameter matrices from named values, pulse inputs, synthetic captures.

`param_matrix` turns a unit's values plus a population of candidate values for some named
parameters into the kernel's parameter matrix. `simulate` runs one parameter set;
`synthetic_record` produces what a recorder would have stored (noise, quantisation).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bench_ctl import engine
from bench_ctl.engine.derived import saturation_ab
from bench_ctl.engine.machines.grid import machine_matrix, unit_machine, with_placeholders
from bench_ctl.engine.runner import Edges
from bench_ctl.model.params import COL, KERNEL_PARAMS, PARAMS, RECORD_PARAMS, STRUCTURE_PARAMS
from bench_ctl.units.unit import Unit, UnitError


def param_matrix(base: Mapping[str, float], names: Sequence[str] = (), X: np.ndarray | None = None, *,
                 row: np.ndarray | None = None) -> np.ndarray:
    """Kernel parameter matrix: every row starts from `base`; columns `names` take the rows of X.
    The record's edge offsets (EDGE1..) default to 0, the zero-order hold; the blocks of the
    standard structures (KF, TEX, ...) to absent. `row`: `base_row(base)`, when the caller keeps it
    (an optimizer's every evaluation starts from the same base)."""
    if row is None:
        row = base_row(base)
    if X is None:
        return row[None, :].copy()
    X = np.atleast_2d(np.asarray(X, dtype=np.float64))
    if X.shape[1] != len(names):
        raise ValueError(f"candidate matrix has {X.shape[1]} columns for {len(names)} names")
    P = np.repeat(row[None, :], X.shape[0], axis=0)
    for j, name in enumerate(names):
        P[:, COL[name]] = X[:, j]
    return P


def base_row(base: Mapping[str, float]) -> np.ndarray:
    """The kernel parameter row of `base` (`param_matrix`)."""
    row = np.empty(len(KERNEL_PARAMS))
    for i, name in enumerate(KERNEL_PARAMS):
        if name in base:
            row[i] = base[name]
        elif name in RECORD_PARAMS:
            row[i] = 0.0
        elif name in STRUCTURE_PARAMS:
            row[i] = float(PARAMS[name].neutral)  # type: ignore[arg-type]
        else:
            raise KeyError(f"no value for model parameter {name!r}")
    return row


def pre_trigger_mean(usetp: np.ndarray, dt: float, start_s: float | None = None) -> float:
    """usetp_pre: mean of the samples before the first change (or before start_s when given)."""
    usetp = np.asarray(usetp, float)
    if start_s is not None:
        n = max(1, int(round(start_s / dt)))
        return float(np.mean(usetp[:n]))
    changed = np.flatnonzero(np.abs(usetp - usetp[0]) > 1e-9)
    n = int(changed[0]) if changed.size else usetp.size
    return float(np.mean(usetp[: max(1, n)]))


def simulate(values: Mapping[str, float], usetp: np.ndarray, dt: float,
             usetp_pre: float | None = None, edges: Edges | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Simulate one parameter set; returns (efd as recorded, vt, fail_step or -1). `edges`: the
    record's setpoint edges, moved by the EDGE offsets in `values`."""
    pre = pre_trigger_mean(usetp, dt) if usetp_pre is None else usetp_pre
    out = engine.run(param_matrix(values), usetp, dt, pre, edges=edges)
    return out["efd"][0], out["vt"][0], int(out["fail_step"][0])


#: an on-line record's operating point: the means over this long before the setpoint first changes
OPERATING_POINT_S = 1.0


def operating_point(usetp: np.ndarray, p: np.ndarray, q: np.ndarray, vt: np.ndarray, dt: float) -> dict[str, float]:
    """An on-line record's operating point before the test: P0, Q0 and Vt0, the means of its P, Q
    and Vt over the OPERATING_POINT_S before the setpoint first changes (a unit's P drifts over a
    long record: the test starts from where it was just before)."""
    return {name: pre_step_mean(usetp, x, dt) for name, x in (("P0", p), ("Q0", q), ("Vt0", vt))}


def pre_step_mean(usetp: np.ndarray, x: np.ndarray, dt: float) -> float:
    """The mean of a recorded signal x over the OPERATING_POINT_S before the setpoint first
    changes (`operating_point`'s window)."""
    usetp = np.asarray(usetp, float)
    changed = np.flatnonzero(np.abs(usetp - usetp[0]) > 1e-9)
    end = max(1, int(changed[0]) if changed.size else usetp.size)
    pre = slice(max(0, end - max(1, int(round(OPERATING_POINT_S / dt)))), end)
    return float(np.mean(np.asarray(x, float)[pre]))


def simulate_on_line(values: Mapping[str, float], grid: Mapping[str, float], point: Mapping[str, float],
                     usetp: np.ndarray, dt: float, edges: Edges | None = None) -> dict[str, np.ndarray]:
    """One parameter set on the grid (`engine.run` with a machine) from an operating point (P0, Q0, Vt0,
    `operating_point`): efd (as recorded), vt, p, q, vs (the stabiliser's output), ifd and fail_step."""
    machine = machine_matrix(with_placeholders({**grid, "P0": point["P0"], "Q0": point["Q0"]}))
    out = engine.run(param_matrix({**values, "Vt0": point["Vt0"]}), usetp, dt, pre_trigger_mean(usetp, dt),
                     machine=machine, edges=edges)
    return {**{name: out[name][0] for name in ("efd", "vt", "p", "q", "vs", "ifd")},
            "fail_step": int(out["fail_step"][0])}


def generator_saturation(s10: float, s12: float) -> Callable[[float], float]:
    """The no-load generator's saturation Sat(x) through S(1.0) = `s10` and S(1.2) = `s12`, the
    curve the kernel integrates (docs/model.md): for code outside the model that needs the
    unit's no-load field (the import's efd base) without reaching into the kernel."""
    a, b = saturation_ab(float(s10), float(s12))

    def sat(x: float) -> float:
        return b * (x - a) ** 2 if x > a else 0.0

    return sat


def pulse_usetp(*, amplitude: float = 0.05, width: float = 1.0, start: float = 1.0,
                duration: float = 10.0, rate: float = 1000.0, usetp0: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Time and a rectangular setpoint pulse (zero-order hold on the sample grid)."""
    if rate <= 0 or duration <= 0:
        raise ValueError("rate and duration must be positive")
    n = int(round(duration * rate)) + 1
    t = np.arange(n) / rate
    k0 = int(round(start * rate))
    k1 = int(round((start + width) * rate)) if width is not None else n
    u = np.full(n, usetp0, dtype=float)
    u[k0:k1] += amplitude
    return t, u


@dataclass(frozen=True)
class RecorderModel:
    """Noise and quantisation of a recorder channel (defaults: 0.01 pu, 12 bit over +-10 pu)."""
    noise_pu: float = 0.01
    lsb_pu: float = 20.0 / 4096

    def apply(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        y = np.asarray(x, float)
        if self.noise_pu > 0:
            y = y + rng.normal(0.0, self.noise_pu, size=y.shape)
        if self.lsb_pu > 0:
            y = np.round(y / self.lsb_pu) * self.lsb_pu
        return y


def synthetic_record(unit: Unit, t: np.ndarray, usetp: np.ndarray, recorder: RecorderModel,
                     seed: int | None, *, online: bool = False) -> dict[str, np.ndarray]:
    """What the recorder stores: usetp is the AVR's digital setpoint (recorded exactly); efd and vt
    are measured channels with the recorder's noise and quantisation. `online`: the unit on the
    grid (its [grid] data), with P, Q and Ifd measured too."""
    dt = float(t[1] - t[0])
    if online:
        try:
            machine = unit_machine(unit)
        except ValueError as exc:   # the [grid] data the unit lacks, named: the unit's to give
            raise UnitError(str(exc)) from None
        out = engine.run(param_matrix(unit.values()), usetp, dt, pre_trigger_mean(usetp, dt),
                         machine=machine_matrix(machine))
        series = {name: out[name][0] for name in ("efd", "vt", "p", "q", "ifd")}
        fail = int(out["fail_step"][0])
    else:
        efd, vt, fail = simulate(unit.values(), usetp, dt)
        series = {"efd": efd, "vt": vt}
    if fail >= 0:
        raise UnitError(f"the unit {unit.name!r} is unstable with these parameters (failed at t = {fail * dt:.3f} s)")
    rng = np.random.default_rng(seed)
    return {"time": t, "usetp": usetp, **{name: recorder.apply(x, rng) for name, x in series.items()}}
