"""The AC exciters' algebra written apart from the kernel, for the tests that solve their
equations with solve_ivp (tests/model/test_exac1.py, test_ac8b.py, test_structures.py)."""
from __future__ import annotations

import numpy as np


def fex(i_n: float) -> float:
    """IEEE 421.5 rectifier regulation FEX(IN)."""
    if i_n <= 0.0:
        return 1.0
    if i_n <= 0.433:
        return 1.0 - 0.577 * i_n
    if i_n <= 0.75:
        return float(np.sqrt(0.75 - i_n * i_n))
    if i_n <= 1.0:
        return 1.732 * (1.0 - i_n)
    return 0.0


def quad(x1: float, y1: float, x2: float, y2: float):
    """B (x - A)^2 through (x1, y1) and (x2, y2), 0 below A."""
    r = np.sqrt(y2 / y1)
    a = (r * x1 - x2) / (r - 1.0)
    b = y1 / (x1 - a) ** 2
    return lambda x: b * max(x - a, 0.0) ** 2
