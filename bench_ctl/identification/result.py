"""What every optimiser run returns: MVMO, its peers (de, local, open-loop), the polish, and the
diagnosis' fits alike (docs/decisions/0015-one-fitting-stack.md).

Shaped after scipy's `OptimizeResult` (x, fun, nfev, success, message, jac) with the standard
deviations and the bookkeeping a report needs; frozen, so a fit is a value.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Result"]


@dataclass(frozen=True, eq=False)
class Result:
    """One optimiser run on a `Problem`.

    x: the point found (the problem's `names`, original units); fun: `Problem.objective` there
    (a failed simulation's penalty when it could not be simulated); nfev: simulations used;
    success: x was simulated to a finite objective (a run may still break a constraint: the
    `local` peer ignores them by design, `violated` lists them); jac: d(residuals)/dz at x in the
    search space's coordinates (`SearchSpace`), when a least-squares polish computed it;
    std: standard deviation of each parameter from that Jacobian, when a noise variance was given.
    """

    x: np.ndarray
    fun: float
    nfev: int
    success: bool
    message: str = ""
    names: tuple[str, ...] = ()
    std: Mapping[str, float] | None = None
    jac: np.ndarray | None = field(default=None, repr=False)
    method: str = ""
    history: tuple[tuple[int, float], ...] = ()
    wall_s: float = 0.0
    settings: Mapping[str, Any] = field(default_factory=dict)
    seed: int | None = None
    violated: tuple[str, ...] = ()

    def params(self) -> dict[str, float]:
        """name -> value of x."""
        return {n: float(v) for n, v in zip(self.names, np.asarray(self.x, float).reshape(-1))}
