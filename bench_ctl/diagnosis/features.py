"""Feature tests on a capture against the base fit: evidence for (or against) each effect.

Each test returns a `Feature` with `detected`, a one-line `evidence` text with the numbers, and
the numbers themselves (`values`), which also seed the effect fits (e.g. the flat-top level is
the starting VRMAX). Thresholds are in units of the noise (sigma = sqrt(noise floor)) so that
the tests mean the same on a quiet and on a noisy recorder.

- flat_top: the measured efd dwells at a level (a limit) where the base model overshoots it;
  also relative to Vt (a bus-fed exciter's ceiling VRMAX*Vt rises with Vt).
- delay: the measured response starts later after the setpoint edge than the model's.
- steady_state_ratio: efd / Vt in the pre-trigger steady state; above 1 at no load means
  saturation (Efd0 = Vt0 + Sat(Vt0)) or a recorder gain error.
- pre_trigger_level: recorded efd0 against the model's Vt0 + Sat(Vt0) (a gain error).
- asymmetry: the up and down excursions / slopes of the measured response against the model.
- edge_shape: the steepest slope of the measured leading edge against the model's (a setpoint
  ramp or a slew limit rounds the jump into a ramp).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bench_ctl.signals.edges import EdgeSearch

from .diagnosis_file import FeatureEntry


@dataclass(frozen=True)
class Feature:
    name: str
    detected: bool
    evidence: str
    values: dict[str, float] = field(default_factory=dict)

    def entry(self) -> FeatureEntry:
        """The diagnosis' record of the test (non-finite values as None)."""
        return FeatureEntry(self.name, bool(self.detected), self.evidence,
                            {k: _finite(v) for k, v in self.values.items()})


def _finite(v: float) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


#: what an evidence text says in place of a figure that could not be measured (never "nan")
UNMEASURED = "not measurable"


def _fig(v: float, spec: str, unit: str = "", scale: float = 1.0) -> str:
    """A figure of an evidence text: `v * scale` formatted, or UNMEASURED (issue 49 item 7: no
    nan in anything an engineer reads)."""
    v = float(v)
    return f"{v * scale:{spec}}{unit}" if math.isfinite(v) else UNMEASURED


def _smooth(y: np.ndarray, m: int) -> np.ndarray:
    if m <= 1:
        return np.asarray(y, float)
    k = np.ones(m) / m
    return np.convolve(y, k, mode="same")


def _dwell(y: np.ndarray, level: float, tol: float, above: bool) -> int:
    """Samples of y within tol of its extreme `level` (y >= level - tol when above)."""
    return int(np.count_nonzero(y >= level - tol) if above else np.count_nonzero(y <= level + tol))


def flat_top(meas: np.ndarray, model: np.ndarray, dt: float, edges: EdgeSearch, sigma: float, *,
             vt: np.ndarray | None = None, vt_recorded: bool = False) -> Feature:
    """A limit: the measured extreme is a plateau (long dwell within the noise of the extreme)
    and the base model goes beyond it. With the terminal voltage (`vt`: recorded, else the base
    model's) the plateau is also looked for in efd / Vt: the ceiling of a bus-fed static exciter
    is VRMAX*Vt, so its top rises with Vt and is flat only relative to it."""
    k0 = edges.lead.index
    k1 = meas.size if edges.trail_index is None else min(meas.size, edges.trail_index + int(round(1.0 / dt)))
    m = max(1, int(round(0.005 / dt)))
    cut = slice(m, -m or None)
    ys = _smooth(meas[k0:k1], m)[cut]
    mod = model[k0:k1][cut]
    tol = 3.0 * sigma / math.sqrt(m) + 0.002
    scale = None
    if vt is not None:
        v = _smooth(np.asarray(vt, float)[k0:k1], m)[cut]
        scale = np.where(np.abs(v) > 0.05, v, np.nan)
    vals: dict[str, float] = {}
    parts, detected = [], False
    for side, above in (("top", True), ("bottom", False)):
        lvl = float(ys.max() if above else ys.min())
        mlvl = float(mod.max() if above else mod.min())
        dw = _dwell(ys, lvl, tol, above) * dt
        mdw = _dwell(mod, mlvl, tol, above) * dt
        over = (mlvl - lvl) if above else (lvl - mlvl)
        # level of the plateau: mean of the measured samples within the tolerance of the extreme
        sel = ys >= lvl - tol if above else ys <= lvl + tol
        plateau = float(np.mean(ys[sel]))
        flat = dw >= 0.02 and dw > 2.0 * mdw + 0.01
        text = (f"{side}: measured efd stays within {tol:.3f} pu of {plateau:.3f} pu for {dw * 1e3:.0f} ms "
                f"(base model {mdw * 1e3:.0f} ms, model beyond it by {over:+.3f} pu)")
        vals.update({f"{side}_level": plateau, f"{side}_dwell_s": dw, f"model_{side}_dwell_s": mdw,
                     f"model_{side}_overshoot": over})
        if scale is not None:
            # the same in efd / Vt, around the measured extreme (a ceiling x Vt is flat there)
            j = int(np.argmax(ys) if above else np.argmin(ys))
            r = ys / scale
            rm = mod / scale
            rl = float(r[j])
            tol_r = tol / float(abs(scale[j])) if math.isfinite(float(scale[j])) else math.inf
            near = np.abs(np.arange(r.size) - j) * dt <= 0.2   # the extreme's own excursion
            dw_r = float(np.count_nonzero(near & (np.abs(r - rl) <= tol_r))) * dt
            mlvl_r = float(np.nanmax(rm[near]) if above else np.nanmin(rm[near]))
            mdw_r = float(np.count_nonzero(near & (np.abs(rm - mlvl_r) <= tol_r))) * dt
            flat_r = dw_r >= 0.02 and dw_r > 2.0 * mdw_r + 0.01 and dw_r > 1.5 * dw
            sel_r = near & (np.abs(r - rl) <= tol_r)
            level_r = float(np.nanmean(r[sel_r])) if np.any(sel_r) else rl
            vals.update({f"{side}_level_vt": level_r, f"{side}_dwell_vt_s": dw_r,
                         f"model_{side}_dwell_vt_s": mdw_r})
            if flat_r:
                flat = True
                text += (f"; relative to Vt ({'recorded' if vt_recorded else 'the base model'}'s) it is flat "
                         f"for {dw_r * 1e3:.0f} ms at efd/Vt = {level_r:.3f} (base model {mdw_r * 1e3:.0f} ms): "
                         "a ceiling that scales with Vt")
        det = flat and over > -3.0 * sigma
        detected |= det
        parts.append(text)
    return Feature("flat_top", detected, "; ".join(parts), vals)


def _onset(y: np.ndarray, k: int, level: float, thresh: float, window: int) -> float:
    seg = np.abs(y[k:k + window] - level)
    hit = np.flatnonzero(seg > thresh)
    if not hit.size:
        return math.nan
    j = int(hit[0])
    if j == 0:
        return 0.0
    a, b = seg[j - 1], seg[j]  # linear interpolation of the crossing
    return (j - 1) + (thresh - a) / (b - a) if b > a else float(j)


def delay(meas: np.ndarray, model: np.ndarray, dt: float, edges: EdgeSearch, sigma: float) -> Feature:
    """Onset of the response after each setpoint edge, measured vs model, and the lag of the
    cross-correlation of their derivatives around the edges."""
    window = int(round(0.25 / dt))
    thresh = 6.0 * sigma + 0.01
    vals: dict[str, float] = {}
    lags = []
    k_off = edges.trail_index
    names = [("leading", edges.lead.index)] + ([("trailing", k_off)] if k_off is not None else [])
    for label, k in names:
        lvl_m = float(np.mean(meas[max(0, k - 50):k])) if k > 0 else float(meas[0])
        lvl_s = float(np.mean(model[max(0, k - 50):k])) if k > 0 else float(model[0])
        tm = _onset(meas, k, lvl_m, thresh, window)
        ts = _onset(model, k, lvl_s, thresh, window)
        # cross-correlation of derivatives (smoothed), lags up to 0.1 s
        a = np.diff(_smooth(meas[max(0, k - 20):k + window], 3))
        b = np.diff(model[max(0, k - 20):k + window])
        L = int(round(0.1 / dt))
        cc = np.array([np.dot(a[max(0, s):len(a) + min(0, s)], b[max(0, -s):len(b) - max(0, s)])
                       for s in range(-L, L + 1)])
        i = int(np.argmax(cc))
        frac = 0.0
        if 0 < i < cc.size - 1:
            den = cc[i - 1] - 2 * cc[i] + cc[i + 1]
            frac = 0.5 * (cc[i - 1] - cc[i + 1]) / den if den != 0 else 0.0
        lag = (i - L + frac) * dt
        vals[f"{label}_onset_s"] = tm * dt
        vals[f"{label}_model_onset_s"] = ts * dt
        vals[f"{label}_xcorr_lag_s"] = lag
        if math.isfinite(tm) and math.isfinite(ts):
            lags.append((tm - ts) * dt)
    d = float(np.median(lags)) if lags else math.nan
    vals["delay_s"] = d
    detected = math.isfinite(d) and d >= 2.0 * dt
    onsets = ", ".join(f"{lab} {_fig(vals[f'{lab}_onset_s'], '.1f', ' ms', 1e3)} vs "
                       f"{_fig(vals[f'{lab}_model_onset_s'], '.1f', ' ms', 1e3)}" for lab, _ in names)
    lags = ", ".join(_fig(vals[f"{lab}_xcorr_lag_s"], ".1f", " ms", 1e3) for lab, _ in names)
    later = (f"{d * 1e3:.1f} ms later than the base model" if math.isfinite(d) else
             f"at a time {UNMEASURED} against the base model (no onset beyond {thresh:.3g} pu within "
             f"{window * dt * 1e3:.0f} ms of an edge)")
    ev = (f"the measured efd leaves its pre-edge level {later} "
          f"(onsets: " + onsets + "; derivative cross-correlation lags " + lags
          + "); a dead time and a recorder skew both delay the record, only the dead time changes the loop")
    return Feature("delay", detected, ev, vals)


def steady_state_ratio(efd_pre: float, efd_se: float, vt_pre: float | None, vt0_model: float) -> Feature:
    vt = vt_pre if vt_pre is not None else vt0_model
    src = "recorded vt" if vt_pre is not None else "the unit's Vt0"
    r = efd_pre / vt
    se = efd_se / vt
    detected = r - 1.0 > max(4.0 * se, 0.01)
    ev = (f"pre-trigger efd / Vt = {efd_pre:.4f} / {vt:.4f} ({src}) = {r:.4f}; at no load without saturation "
          f"it is 1; above 1 means Sat(Vt0) = {efd_pre - vt:+.4f} pu, or a recorder gain error "
          f"(a test at another voltage level separates them)")
    return Feature("steady_state_ratio", detected, ev, {"ratio": r, "ratio_se": se, "vt": vt})


def pre_trigger_level(efd_pre: float, efd_se: float, efd0_model: float, *, on_line: bool = False) -> Feature:
    """The recorded pre-trigger efd against the model's steady state: at no load Vt0 + Sat(Vt0), on
    line the field voltage of the machine at the record's P, Q and Vt."""
    g = efd_pre / efd0_model
    se = efd_se / abs(efd0_model)
    detected = abs(g - 1.0) > max(4.0 * se, 0.005)
    model = "the model's steady state at the record's P, Q, Vt" if on_line else "the model's Vt0 + Sat(Vt0)"
    ev = (f"recorded pre-trigger efd {efd_pre:.4f} pu against {model} = {efd0_model:.4f} pu: "
          f"ratio {g:.4f} +- {se:.4f}")
    return Feature("pre_trigger_level", detected, ev, {"ratio": g, "ratio_se": se, "efd_pre": efd_pre,
                                                       "efd0_model": efd0_model})


#: the measured slope is a sliding least-squares line over this long (s): over a few ms the
#: recorder noise alone reads as a steep slope and hides slower slew limits (docs/benchmarks.md,
#: "Diagnosis constants")
SLOPE_WINDOW_S = 0.015


def _slopes(y: np.ndarray, dt: float, k0: int, k1: int, m: int) -> tuple[float, float]:
    """Steepest rise and fall (pu/s) of y[k0:k1]: a sliding straight-line fit (Savitzky-Golay,
    first derivative) over SLOPE_WINDOW_S for a measured record (m > 1), the sample differences for
    a noise-free model trace (m = 1)."""
    from scipy.signal import savgol_filter
    seg = np.asarray(y[max(0, k0):k1], float)
    if m <= 1:
        d = np.diff(seg) / dt
    else:
        L = max(5, int(round(SLOPE_WINDOW_S / dt)) | 1)
        if seg.size < L + 2:
            return math.nan, math.nan
        d = savgol_filter(seg, L, 1, deriv=1, delta=dt, mode="interp")
    return (float(d.max()), float(-d.min())) if d.size else (math.nan, math.nan)


def asymmetry(meas: np.ndarray, model: np.ndarray, dt: float, edges: EdgeSearch, sigma: float) -> Feature:
    k_on, k_off = edges.lead.index, edges.trail_index
    if k_off is None:
        return Feature("asymmetry", False, "step test: no down edge to compare", {})
    pre = float(np.mean(meas[:k_on]))
    pre_m = float(np.mean(model[:k_on]))
    k_end = min(meas.size, k_off + int(round(1.0 / dt)))
    up, down = float(meas[k_on:k_off].max() - pre), float(pre - meas[k_off:k_end].min())
    up_m, down_m = float(model[k_on:k_off].max() - pre_m), float(pre_m - model[k_off:k_end].min())
    m = max(1, int(round(0.003 / dt)))
    w = int(round(0.1 / dt))
    su, _ = _slopes(meas, dt, k_on - 2 * m, k_on + w, m)
    _, sd = _slopes(meas, dt, k_off - 2 * m, k_off + w, m)
    su_m, _ = _slopes(model, dt, k_on - 2 * m, k_on + w, 1)
    _, sd_m = _slopes(model, dt, k_off - 2 * m, k_off + w, 1)
    r, r_m = up / down if down > 0 else math.inf, up_m / down_m if down_m > 0 else math.inf
    tol = 4.0 * sigma * (1.0 / max(up, 1e-9) + 1.0 / max(down, 1e-9)) + 0.02
    detected = math.isfinite(r) and math.isfinite(r_m) and abs(r / r_m - 1.0) > tol
    ev = (f"up excursion {up:.3f} pu, down {down:.3f} pu (ratio {_fig(r, '.3f')}; base model {_fig(r_m, '.3f')}); "
          f"steepest slope up {_fig(su, '.1f', ' pu/s')}, down {_fig(sd, '.1f', ' pu/s')} (model {_fig(su_m, '.1f')}, "
          f"{_fig(sd_m, '.1f')}); equal capped slopes point to a slew limit, unequal excursions to a ceiling on one "
          "side")
    return Feature("asymmetry", detected, ev, {"up": up, "down": down, "ratio": r, "model_ratio": r_m,
                                               "slope_up": su, "slope_down": sd, "model_slope_up": su_m,
                                               "model_slope_down": sd_m})


def _rise(y: np.ndarray, k: int, w: int, sgn: float, m: int, dt: float) -> tuple[float, float, float]:
    """(10-90 % rise time to the first peak, that peak, straightness) of y after the edge at k.

    Straightness = time from 10 % to 50 % of the peak / time from 50 % to 90 %: 0.37 for the
    exponential rise of a first-order lag, 1 for a straight ramp (threshold crossings of the
    smoothed record, so sample noise hardly moves it)."""
    pre = float(np.mean(y[max(0, k - 50):k]))
    lo = max(0, k - 2 * m)
    seg = sgn * (_smooth(y[lo:k + w], m)[k - lo:] - pre)
    j = int(np.argmax(seg))
    peak = float(seg[j])
    if peak <= 0 or j < 2:
        return math.nan, peak, math.nan
    first = [np.flatnonzero(seg[:j + 1] >= f * peak) for f in (0.1, 0.5, 0.9)]
    if not all(x.size for x in first):
        return math.nan, peak, math.nan
    t10, t50, t90 = (int(x[0]) for x in first)
    if not t10 < t50 < t90:
        return math.nan, peak, math.nan
    return (t90 - t10) * dt, peak, (t50 - t10) / (t90 - t50)


def _rise_text(label: str, tr: float, peak: float, st: float, tr_m: float, st_m: float, window_s: float) -> str:
    """One edge's part of the edge_shape evidence; a rise that could not be measured (no first
    peak above the pre-edge level within the window, or thresholds crossed out of order) is said
    so, never as nan."""
    why = f"{UNMEASURED} (no rise to a first peak within {window_s * 1e3:.0f} ms of the edge)"
    meas = (f"10-90 % rise {tr * 1e3:.1f} ms to {peak:.3f} pu, straightness {st:.2f}" if math.isfinite(tr)
            else f"rise {why}")
    model = f"{tr_m * 1e3:.1f} ms, {st_m:.2f}" if math.isfinite(tr_m) else f"rise {UNMEASURED}"
    return f"{label} edge: {meas} (base model {model})"


def edge_shape(meas: np.ndarray, model: np.ndarray, dt: float, edges: EdgeSearch, sigma: float,
               amplitude: float) -> Feature:
    """Shape of the response to each setpoint edge: a first-order lag rises steepest at once and
    then slower; a setpoint ramp or a slew limit gives a straight rise at a capped slope."""
    m = max(1, int(round(0.003 / dt)))
    vals: dict[str, float] = {}
    parts, straight_edges = [], 0
    sgn = 1.0 if amplitude >= 0 else -1.0
    k_off = edges.trail_index
    names = [("leading", edges.lead.index, sgn)] + ([("trailing", k_off, -sgn)] if k_off is not None else [])
    for label, k, sg in names:
        end = meas.size if label == "trailing" or k_off is None else k_off
        w = max(3, min(int(round(0.5 / dt)), end - k))
        tr, peak, st = _rise(meas, k, w, sg, m, dt)
        tr_m, peak_m, st_m = _rise(model, k, w, sg, 1, dt)
        measurable = math.isfinite(tr) and tr >= 6 * m * dt and peak > 10 * sigma
        straight = measurable and st > 0.65 and (not math.isfinite(st_m) or st > st_m + 0.15)
        straight_edges += straight
        vals.update({f"{label}_rise_s": tr, f"{label}_straightness": st, f"{label}_model_rise_s": tr_m,
                     f"{label}_model_straightness": st_m, f"{label}_slope": 0.8 * peak / tr if tr else math.nan})
        parts.append(_rise_text(label, tr, peak, st, tr_m, st_m, w * dt))
    detected = straight_edges > 0
    ev = ("; ".join(parts) + "; a straight rise (straightness near 1, a first-order lag gives 0.37) points to a "
          "setpoint ramp or a slew limit")
    return Feature("edge_shape", detected, ev, vals)
