"""solve_ivp for the tests' reference equations whose right side jumps at known instants (a
setpoint pulse's edges): integrated piece by piece between the jumps, each piece's right side
seen with its time held inside the piece, so that no step straddles a jump and the step size is the
tolerance's alone (no max_step: a 2e-4 s cap made a 4 s reference 20 000 steps of Python)."""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np


def solve_pieces(f: Callable, t: np.ndarray, y0: Sequence[float], jumps: Sequence[float], *,
                 method: str = "DOP853", rtol: float = 1e-10, atol: float = 1e-12) -> np.ndarray:
    """The solution of y' = f(t, y) at the instants `t` (states x len(t), as solve_ivp's `y`), the
    right side discontinuous only at `jumps`: a sample at a jump belongs to the piece it starts.
    A piece that fails to integrate raises AssertionError."""
    from scipy.integrate import solve_ivp

    cuts = [float(t[0])] + sorted(float(j) for j in jumps if t[0] < j < t[-1]) + [float(t[-1])]
    z, parts = np.asarray(y0, dtype=float), []
    for k, (lo, hi) in enumerate(zip(cuts[:-1], cuts[1:])):
        span = hi - lo
        inside = lambda s, x, lo=lo, span=span: f(lo + min(max(s - lo, 1e-9 * span), (1 - 1e-9) * span), x)  # noqa: E731
        sol = solve_ivp(inside, (lo, hi), z, method=method, rtol=rtol, atol=atol, dense_output=True)
        if not sol.success:
            raise AssertionError(f"the reference's integration failed on {lo:g}..{hi:g} s: {sol.message}")
        last = k == len(cuts) - 2
        seg = t[(t >= lo) & ((t <= hi) if last else (t < hi))]
        parts.append(sol.sol(seg))
        z = sol.y[:, -1]
    return np.concatenate(parts, axis=1)
