"""The report's stabiliser test section: when a result holds a `pss_step`'s two captures (the same
on-line step with the PSS off, then on: their sidecars' `test.pss_on`), the electromechanical mode
in P of each, measured and simulated, and one figure of P after the step, off vs on.

The simulated mode of the PSS-off record is the identified model re-simulated with its
stabiliser's output held at 0 (its output limits 0, its states running: the simulated exciter's
switch); the PSS-on record's is the report's own re-simulation (`CaptureAnalysis.online`).
"""
from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np

from bench_ctl.identification.timing import fitted_edge_plan
from bench_ctl.report.analysis import CaptureAnalysis, ReportData, simulate_record
from bench_ctl.report.blocks import Block, Fig, Num, Para, Section, Table
from bench_ctl.report.metrics import edge_times
from bench_ctl.signals.mode import Mode, electromechanical_mode

#: the [grid] values that hold a stabiliser's output at 0 (IEEEST's +-LSMAX, PSS2A/PSS2B's VSTMAX
#: and VSTMIN), its states running
PSS_OUTPUT_OFF = {"PSS_LSMAX": 0.0, "PSS2_VSTMAX": 0.0, "PSS2_VSTMIN": 0.0}
#: seconds of P shown after the step
SHOWN_S = 6.0


def pss_captures(d: ReportData) -> tuple[CaptureAnalysis, CaptureAnalysis] | None:
    """The PSS-off and PSS-on on-line captures of the result (the first of each), or None."""
    def first(on: bool) -> CaptureAnalysis | None:
        return next((a for a in d.captures if a.online is not None
                     and (a.loaded.capture.meta.get("test") or {}).get("pss_on") is on), None)
    off, on = first(False), first(True)
    return (off, on) if off is not None and on is not None else None


def _simulated_off(d: ReportData, a: CaptureAnalysis) -> np.ndarray:
    """P of the model on the PSS-off record, the stabiliser's output held at 0."""
    cap = a.loaded.capture
    spec, offsets = fitted_edge_plan(a.loaded.entry.edges, cap.n)
    grid = {**(d.result.unit.grid or {}), **PSS_OUTPUT_OFF}
    return simulate_record({**d.values, **offsets}, cap, grid, spec, a.loaded.path.name)["p"]


def _mode_cells(m: Mode | None, key: str) -> tuple[Any, Any]:
    if m is None:
        return "n/a", "n/a"
    return Num(m.frequency_hz, f"{key}-hz", 3), Num(m.damping, f"{key}-zeta", 3)


def stabiliser(d: ReportData) -> Section | None:
    """The stabiliser test section, or None when the result holds no PSS-off and PSS-on pair."""
    parts = pss_captures(d)
    if parts is None:
        return None
    rows, curves, damping = [], [], {}
    for label, a in zip(("PSS off", "PSS on"), parts):
        cap = a.loaded.capture
        lead_s = edge_times(a.edges)[0]
        p_meas = cap.channel("p")
        assert p_meas is not None and a.online is not None   # an on-line capture
        p_sim = _simulated_off(d, a) if label == "PSS off" else a.online["p"]
        modes = [None if lead_s is None else electromechanical_mode(cap.time, p, lead_s) for p in (p_meas, p_sim)]
        key = "pss-off" if label == "PSS off" else "pss-on"
        rows.append((label, *_mode_cells(modes[0], f"{key}-measured"), *_mode_cells(modes[1], f"{key}-simulated")))
        damping[label] = [m.damping if m is not None else None for m in modes]
        if lead_s is not None:
            curves.append((label, cap.time - lead_s, p_meas, p_sim))
    gain = ["n/a" if off is None or on is None else Num(on - off, None, 3)
            for off, on in zip(damping["PSS off"], damping["PSS on"])]
    rows.append(("damping added by the PSS", "", gain[0], "", gain[1]))
    blocks: list[Block] = [
        Table(("", "measured frequency (Hz)", "measured damping ratio", "simulated frequency (Hz)",
               "simulated damping ratio"), tuple(rows), id="stabiliser-modes",
              caption="The electromechanical mode in P after the step (fitted over 4 s; n/a: no swing above "
                      "three times the fit's residual), the same step with the PSS off, then on. Simulated: the "
                      "identified model, its stabiliser's output held at 0 for the PSS-off record."),
        Fig("stabiliser", "Active power after the step, minus its value at the step: PSS off vs on, measured "
            "(thin) and simulated (thick).", partial(_draw, curves=curves), size=(7.5, 4.0))]
    if not (d.result.unit.grid or {}).get("PSS_KS") and not (d.result.unit.grid or {}).get("PSS2_KS1"):
        blocks.insert(0, Para("Note: the identified model carries no stabiliser gain ([grid] PSS_KS / PSS2_KS1 "
                              "0 or absent): its simulated modes are the same off and on.", "note"))
    return Section("stabiliser", "Stabiliser test: PSS off vs on", tuple(blocks))


def _draw(fig: Any, curves: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]) -> None:
    ax = fig.subplots()
    for (label, t, meas, sim), color in zip(curves, ("#d62728", "#1f77b4")):
        sel = (t >= -0.5) & (t <= SHOWN_S)
        at = int(np.searchsorted(t, 0.0))
        ax.plot(t[sel], meas[sel] - meas[at], color=color, lw=0.7, label=f"{label} measured")
        ax.plot(t[sel], sim[sel] - sim[at], color=color, lw=1.6, alpha=0.6, label=f"{label} simulated")
    ax.set_xlabel("time after the step (s)")
    ax.set_ylabel("p - p at the step (pu)")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=7)
    ax.set_title("Stabiliser test: P after the step", fontsize=10)

