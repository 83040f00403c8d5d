"""What the on-line step (procedures/online_step.py) holds the unit to: the band that ends the
step when left (`Band`), and the steady state awaited before it (`Steady`)."""
from __future__ import annotations

import math

from procedures.recorded import signed


class Band:
    """What ends the step when left (limits.vt_*, q_*, p_*; the limiters): Vt and Q in their bands,
    P in the unit's on-line range and within `p_swing_mw` of its value at the start, no limiter
    acting. `worst` keeps the first excursion seen."""

    def __init__(self, vt: tuple[float, float], q: tuple[float, float], p: tuple[float, float],
                 p_swing_mw: float, p0_mw: float) -> None:
        self.vt, self.q, self.p = vt, q, p
        self.p_swing_mw, self.p0_mw = p_swing_mw, p0_mw
        self.worst: str | None = None    # the first excursion seen

    def outside(self, seen: dict[str, float], limiters: list[str] | None = None) -> str | None:
        """What is outside (None when all are in), and remember the first."""
        vt, q, p = seen["vt"], seen["q"], seen["p"]
        why = None
        if limiters:
            why = f"limiter acting: {', '.join(limiters)} (status bit set)"
        elif not (math.isfinite(p) and self.p[0] <= p <= self.p[1]):
            kind = "reverse power" if p < 0 else "a trip or a load rejection" if p < self.p[0] else "overload"
            why = f"p {p:.2f} MW outside the unit's range {self.p[0]:.2f}..{self.p[1]:.2f} MW ({kind})"
        elif abs(p - self.p0_mw) > self.p_swing_mw:
            why = (f"p {p:.2f} MW moved {signed(p - self.p0_mw, 2)} MW from {self.p0_mw:.2f} MW at the start, "
                   f"more than {self.p_swing_mw:.2f} MW (a load rejection or a load change)")
        elif not (math.isfinite(vt) and self.vt[0] <= vt <= self.vt[1]):
            why = f"vt {vt:.4f} pu outside {self.vt[0]:.4f}..{self.vt[1]:.4f} pu"
        elif not (math.isfinite(q) and self.q[0] <= q <= self.q[1]):
            why = f"q {q:.2f} Mvar outside {self.q[0]:.2f}..{self.q[1]:.2f} Mvar"
        if why is not None and self.worst is None:
            self.worst = why
        return why

    def text(self) -> str:
        return (f"vt {self.vt[0]:.4f}..{self.vt[1]:.4f} pu, q {self.q[0]:.2f}..{self.q[1]:.2f} Mvar, "
                f"p {self.p[0]:.2f}..{self.p[1]:.2f} MW and within {self.p_swing_mw:.2f} MW of "
                f"{self.p0_mw:.2f} MW, no limiter acting")


class Steady:
    """Samples of P, Q and Vt before the step: steady when they cover the last `time_s` without a
    gap longer than `max_gap_s` and each moved less than its band (max - min)."""

    def __init__(self, bands: dict[str, float], time_s: float, max_gap_s: float) -> None:
        self.bands, self.time_s, self.max_gap_s = bands, time_s, max_gap_s
        self._samples: list[tuple[float, dict[str, float]]] = []

    def add(self, t: float, seen: dict[str, float]) -> None:
        if self._samples and t - self._samples[-1][0] > self.max_gap_s:
            self._samples.clear()      # a gap (the operator's question): the window starts again
        self._samples.append((t, {k: seen[k] for k in self.bands}))
        start = t - self.time_s
        while len(self._samples) > 1 and self._samples[1][0] <= start:
            self._samples.pop(0)

    def moved(self) -> dict[str, float]:
        """max - min of each quantity over the window."""
        return {k: max(v[k] for _, v in self._samples) - min(v[k] for _, v in self._samples)
                for k in self.bands} if self._samples else {}

    def verdict(self) -> str | None:
        """None when steady; else what is not (not yet covered, or what moved more than its band)."""
        if not self._samples:
            return "not observed yet"
        span = self._samples[-1][0] - self._samples[0][0]
        moved = self.moved()
        units = {"p": "MW", "q": "Mvar", "vt": "pu"}
        over = [f"{k} moved {moved[k]:.4g} {units[k]} (band {self.bands[k]:g} {units[k]})"
                for k in self.bands if not moved[k] <= self.bands[k]]
        if over:
            return "; ".join(over) + f" over the last {span:.1f} s"
        if span < self.time_s:
            return f"observed {span:.1f} s of {self.time_s:g} s"
        return None
