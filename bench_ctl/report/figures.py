"""The report's figures, drawn with matplotlib (Agg, no pyplot state).

Each `draw_*` function draws into a given `Figure` or `SubFigure`, so the same drawing serves the
HTML (one figure per PNG, `png_bytes`) and the PDF (two figures per A4 page). Colours are fixed
(`COLORS`) so a rendered page can be checked for the plotted lines.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from io import BytesIO
from typing import Any

import numpy as np
from matplotlib.figure import Figure, SubFigure

from bench_ctl.diagnosis.diagnosis_file import EffectEntry, Left, Step
from bench_ctl.report.metrics import ErrorFigures, edge_times
from bench_ctl.signals.edges import EdgeSearch

DPI = 110
FIGSIZE = (9.6, 5.2)  # inches: 1056 x 572 px at DPI, fits an A4 page width when printed
COLORS = {
    "measured": "#1f77b4",   # blue
    "simulated": "#d62728",  # red
    "usetp": "#2ca02c",      # green
    "residual": "#9467bd",   # purple
    "residual_mean": "#3b0a57",  # dark purple
    "history": "#ff7f0e",    # orange
    "bar": "#17becf",        # cyan
}
SEGMENT_SHADES = {"pre_trigger": "#f0f0f0", "leading_edge": "#fde0c5", "plateau": "#e0ecf8",
                  "trailing_edge": "#f9d0d9", "recovery": "#e3f2d9", "whole record": "#f0f0f0"}
ZOOM_BEFORE_S = 0.1
ZOOM_AFTER_S = 0.5
#: the on-line figure: seconds shown before the leading edge and after the trailing one
ONLINE_BEFORE_S = 2.0
ONLINE_AFTER_S = 6.0
SMOOTH_S = 0.025

Canvas = Figure | SubFigure


def png_bytes(draw: Callable[[Canvas], None], figsize: tuple[float, float] = FIGSIZE,
              dpi: int = DPI) -> bytes:
    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    draw(fig)
    buf = BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def draw_response(fig: Canvas, time: np.ndarray, usetp: np.ndarray, meas: np.ndarray,
                  sim: np.ndarray, edges: EdgeSearch, title: str) -> None:
    ax, axu = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax.plot(time, meas, color=COLORS["measured"], lw=0.8, label="efd measured")
    ax.plot(time, sim, color=COLORS["simulated"], lw=1.4, label="efd simulated")
    ax.set_ylabel("efd (pu)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    axu.plot(time, usetp, color=COLORS["usetp"], lw=1.2, label="usetp (setpoint)")
    for t_edge in edge_times(edges):
        if t_edge is not None:
            for a in (ax, axu):
                a.axvline(t_edge, color="0.5", ls=":", lw=0.8)
    axu.set_ylabel("usetp (pu)")
    axu.set_xlabel("time (s)")
    axu.grid(alpha=0.3)
    axu.legend(loc="upper right", fontsize=8)


def draw_online(fig: Canvas, time: np.ndarray, meas: Mapping[str, np.ndarray], sim: Mapping[str, np.ndarray],
                edges: EdgeSearch) -> None:
    """An on-line record: efd, Vt, P, Q and, when `meas` has it, the stabiliser's output vs measured
    vs simulated, one panel each, dotted lines at the setpoint edges."""
    names = [name for name in ("efd", "vt", "p", "q", "vs") if meas.get(name) is not None]
    axes = fig.subplots(len(names), 1, sharex=True)
    for ax, name in zip(axes, names):
        ax.plot(time, meas[name], color=COLORS["measured"], lw=0.8, label=f"{name} measured")
        ax.plot(time, sim[name], color=COLORS["simulated"], lw=1.3, label=f"{name} simulated")
        for t_edge in edge_times(edges):
            if t_edge is not None:
                ax.axvline(t_edge, color="0.5", ls=":", lw=0.8)
        ax.set_ylabel(f"{name} (pu)")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=7)
    axes[0].set_title("On line: measured vs simulated", fontsize=10)
    axes[-1].set_xlabel("time (s)")
    lead_s, trail_s = edge_times(edges)
    if lead_s is not None:   # zoomed on the test: from before the step to after its return
        end = trail_s if trail_s is not None else lead_s
        axes[-1].set_xlim(max(float(time[0]), lead_s - ONLINE_BEFORE_S),
                          min(float(time[-1]), end + ONLINE_AFTER_S))


def draw_residual(fig: Canvas, time: np.ndarray, residual: np.ndarray,
                  figs: ErrorFigures) -> None:
    ax = fig.subplots()
    for seg in figs.segments:
        ax.axvspan(seg.t0, seg.t1, color=SEGMENT_SHADES.get(seg.name, "#eeeeee"), lw=0,
                   label=f"{seg.name.replace('_', ' ')}: {100 * seg.share:.1f} % of r²")
    ax.plot(time, residual, color=COLORS["residual"], lw=0.6, label="residual r = measured − simulated")
    dt = float(time[-1] - time[0]) / (time.size - 1)
    w = max(1, int(round(SMOOTH_S / dt)))
    if 1 < w < residual.size:
        smooth = np.convolve(residual, np.ones(w) / w, mode="same")
        ax.plot(time, smooth, color=COLORS["residual_mean"], lw=1.3,
                label=f"r, {1000 * SMOOTH_S:g} ms moving average")
    ax.plot([figs.peak_time_s], [figs.peak_signed], "o", mfc="none", mec="k", ms=9,
            label=f"peak |r| = {figs.peak_abs:.3g} pu at t = {figs.peak_time_s:.3f} s")
    ax.axhline(0.0, color="0.3", lw=0.6)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("residual efd (pu)")
    ax.set_title("Residual and its share per segment of the response", fontsize=10)
    ax.grid(alpha=0.3)
    fig.legend(loc="outside lower center", ncols=3, fontsize=8)


def draw_residuals(fig: Canvas, time: np.ndarray, residuals: Sequence[tuple[str, np.ndarray]]) -> None:
    """Several models' residuals on one axis (structure selection: the best two)."""
    ax = fig.subplots()
    dt = float(time[-1] - time[0]) / max(time.size - 1, 1)
    w = max(1, int(round(SMOOTH_S / dt)))
    for (label, r), color in zip(residuals, (COLORS["residual"], COLORS["history"], COLORS["bar"])):
        shown = np.convolve(r, np.ones(w) / w, mode="same") if 1 < w < r.size else r
        ax.plot(time, shown, color=color, lw=1.0, label=f"{label}: rms {float(np.sqrt(np.mean(r * r))):.3g} pu")
    ax.axhline(0.0, color="0.3", lw=0.6)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("residual efd (pu)")
    ax.set_title("Residual of the best two structures" + (f", {1000 * SMOOTH_S:g} ms moving average" if w > 1 else ""),
                 fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)


def _zoom(ax: Any, time: np.ndarray, usetp: np.ndarray, meas: np.ndarray, sim: np.ndarray,
          t_edge: float, title: str) -> None:
    lo, hi = max(time[0], t_edge - ZOOM_BEFORE_S), min(time[-1], t_edge + ZOOM_AFTER_S)
    m = (time >= lo) & (time <= hi)
    h1 = ax.plot(time[m], meas[m], color=COLORS["measured"], lw=0.9, label="efd measured")
    h2 = ax.plot(time[m], sim[m], color=COLORS["simulated"], lw=1.5, label="efd simulated")
    ax.axvline(t_edge, color="0.5", ls=":", lw=0.8)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("efd (pu)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    axu = ax.twinx()
    h3 = axu.step(time[m], usetp[m], where="post", color=COLORS["usetp"], lw=1.0, ls="--",
                  label="usetp")
    axu.set_ylabel("usetp (pu)")
    handles = h1 + h2 + h3
    ax.legend(handles, [h.get_label() for h in handles], loc="best", fontsize=8)


def draw_edges(fig: Canvas, time: np.ndarray, usetp: np.ndarray, meas: np.ndarray,
               sim: np.ndarray, edges: EdgeSearch) -> None:
    zooms = list(zip(("Leading edge", "Trailing edge"), edge_times(edges)))
    zooms = [(name, t) for name, t in zooms if t is not None]
    axes = np.atleast_1d(fig.subplots(1, len(zooms)))
    for ax, (name, t_edge) in zip(axes, zooms):
        _zoom(ax, time, usetp, meas, sim, t_edge, f"{name} at t = {t_edge:.3f} s")


def draw_convergence(fig: Canvas, history: Sequence[Sequence[float]], label: str) -> None:
    ax = fig.subplots()
    h = np.asarray(history, float)
    ax.step(h[:, 0], h[:, 1], where="post", color=COLORS["history"], lw=1.5, marker=".",
            ms=4, label=label)
    ax.set_yscale("log")
    ax.set_xlabel("objective evaluations")
    ax.set_ylabel("best objective (pu² s)")
    ax.set_title("Convergence: best objective vs evaluations", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="upper right", fontsize=8)


def draw_effects(fig: Canvas, effects: Sequence[EffectEntry]) -> None:
    names = [e.name for e in effects][::-1]
    gaps = [float(e.gap_closed) if e.gap_closed is not None else 0.0 for e in effects][::-1]
    ax = fig.subplots()
    y = np.arange(len(names))
    ax.barh(y, gaps, color=COLORS["bar"], label="gap closed")
    ax.set_yticks(y, names)
    ax.set_xlabel("gap closed (fraction of the base model's excess over the noise floor)")
    ax.set_title("Diagnosis: effects ranked by how much of the gap they close", fontsize=10)
    ax.axvline(0.0, color="0.3", lw=0.6)
    ax.grid(alpha=0.3, axis="x")
    ax.legend(loc="lower right", fontsize=8)
def draw_staircase(fig: Canvas, base_mse: float, floor: float, steps: Sequence[Step],
                   left: Left | None = None, base_check: float | None = None) -> None:
    """The error after each effect added (explained_by), over the noise floor, down to it."""
    labels = ["base model"] + [f"+ {s.name}" for s in steps]
    vals = [base_mse / floor] + [(s.mse if s.mse is not None else math.nan) / floor for s in steps]
    checks = [base_check] + [s.check.mse for s in steps]
    ax = fig.subplots()
    x = np.arange(len(labels))
    ax.step(x, vals, where="mid", color=COLORS["bar"], lw=2, label="MSE on the capture / noise floor")
    ax.plot(x, vals, "o", color=COLORS["bar"])
    chk = [(i, float(c) / floor) for i, c in enumerate(checks) if isinstance(c, (int, float))]
    if chk:
        ax.plot([i for i, _ in chk], [v for _, v in chk], "s", mfc="none", color="0.35",
                label="check MSE / noise floor (data not fitted)")
    ax.axhline(1.0, color="0.3", ls="--", lw=1, label="noise floor")
    ax.set_yscale("log")
    ax.set_xticks(x, labels)
    ax.set_ylabel("MSE / noise floor")
    note = f" - left: {left.note}" if left and left.note else ""
    ax.set_title("Diagnosis: the error after each effect added" + note[:90], fontsize=10)
    ax.grid(alpha=0.3, which="both", axis="y")
    ax.legend(loc="upper right", fontsize=8)


