"""The excitation system alone, driven by a recorded terminal voltage and field current (open loop).

The check issue 13 asks of every structure: the AVR / exciter of the engine, with the generator cut
away, fed the Vt and Ifd another simulator (or a unit) recorded, must give the efd it recorded. It
is the engine with the played-back machine (`machines.recorded`), so that what is checked is what
identification simulates: the recorded Vt and Ifd are interpolated linearly to each RK4 stage.

The setpoint jumps at given instants (inside a sample where the record puts them there); a step
holding one is split there, as in a closed-loop run. The exciter starts in the steady state of the
unit's values (as the closed loop does); a record that does not start there shows the difference
as error, which is part of what the check measures. Effects that have no open-loop meaning here
(dead time, setpoint ramp, recorder skew) are refused.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from bench_ctl.model.params import KERNEL_PARAMS

from . import edge_plan, run


def run_open_loop(values: Mapping[str, float], time: np.ndarray, vt: np.ndarray, ifd: np.ndarray,
                  edge_times: Sequence[float] = (), edge_jumps: Sequence[float] = ()) -> np.ndarray:
    """efd of the excitation system of `values` (every kernel parameter) fed the recorded `vt` and
    `ifd` (pu, on a uniform `time` grid), its setpoint starting where the steady state of `values`
    puts it and jumping by `edge_jumps[j]` (pu) at `edge_times[j]` (s, on the record's clock)."""
    missing = [n for n in KERNEL_PARAMS if n not in values]
    if missing:
        raise ValueError(f"open loop: no value for {missing}")
    for name in ("TD", "SKEW"):
        if float(values[name]) != 0.0:
            raise ValueError(f"open loop: {name} = {values[name]!r}; the exciter alone has no {name}")
    if np.isfinite(float(values["RAMP"])):
        raise ValueError(f"open loop: RAMP = {values['RAMP']!r}; a setpoint ramp needs the closed loop")
    t = np.asarray(time, float)
    vt = np.ascontiguousarray(vt, dtype=np.float64)
    ifd = np.ascontiguousarray(ifd, dtype=np.float64)
    if not (t.size == vt.size == ifd.size) or t.size < 2:
        raise ValueError(f"open loop: time, vt, ifd must have one equal length >= 2 "
                         f"(got {t.size}, {vt.size}, {ifd.size})")
    dt = float(t[1] - t[0])
    if not dt > 0 or not np.allclose(np.diff(t), dt, rtol=1e-6, atol=1e-12):
        raise ValueError("open loop: the time grid must be uniform and increasing")
    if len(edge_times) != len(edge_jumps):
        raise ValueError("open loop: one jump per edge time")
    P = np.array([[float(values[n]) if n not in ("EDGE1", "EDGE2", "EDGE3", "EDGE4") else 0.0
                   for n in KERNEL_PARAMS]])
    # the setpoint the record shows at each sample, each jump at the first sample at or after it,
    # moved to its instant inside the step by the engine (the edges' nominal instants)
    at = (np.asarray(edge_times, float) - t[0]) / dt
    index = np.maximum(1, np.ceil(at - 1.0e-9).astype(np.int64))
    usetp = np.zeros(t.size)
    for k, jump in zip(index, edge_jumps):
        if k < t.size:
            usetp[k:] += float(jump)
    inside = index < t.size
    edges = edge_plan.build(index[inside], np.asarray(edge_jumps, float)[inside], at[inside] * dt,
                            np.zeros(int(inside.sum()), np.int64))
    out = run(P, usetp, dt, 0.0, ext=np.vstack([vt, ifd]), edges=edges, keep=("efd",))
    if out["fail_step"][0] == 0:
        raise ValueError("open loop: the values are not a valid unit (see `bench-ctl models`)")
    return out["efd"][0]
