"""On-line captures made by another simulator, ANDES, stored as test fixtures: the unit synchronised
to an infinite bus, a step of its voltage reference.

The GENROU of the no-load fixtures (`GENERATOR` in benchmarks/andes_captures.py; Sn = 100 MVA =
the system base, so P and Q are on the machine base) at bus 1, tied by a line of reactance XE
(r = 0, no charging) to bus 2, where an ANDES `Slack` is the infinite bus; the line stays in. Power
flow: PV at bus 1 with P0 = 0.8, V0 = 1.0 (Q from the power flow), Slack at 1.0 pu, angle 0. The
exciter is SEXS or ESST1A with the unscaled values of `EXCITERS` there; XE 0.2 or 0.4: four
captures, NAME = `sexs_xe02`, `esst1a_xe04`, ... Two more, `sexs_xe02_pss` and `esst1a_xe02_pss`,
are sexs_xe02 and esst1a_xe02 with a power system stabiliser that bench-ctl's model does not have:
ANDES' `IEEEST` on the exciter (avr = 1), input the rotor speed deviation (MODE 1), its output
vsout added to the exciter's input, with the values of `PSS` (washout T5 = T6 = 10 s, two
lead-lags, gain KS, output limits +-0.1 pu; ANDES documents T6 as 0.04 .. 2 s but does not
enforce it); everything else is the same. The record starts at 0.5 s of ANDES time (the
steady state since t = 0); the reference `vref0` is raised by 2 % of the power-flow terminal
voltage at `EDGE_ON` after the record's start and lowered back at `EDGE_OFF`, both off the 1 kHz
grid, by stopping the time-domain simulation there, changing `vref0` and running on. The
integration is the no-load script's: a fixed 0.2 ms step, 0.01 ms for the 5 ms after each edge.
The output is resampled linearly onto a uniform 1 kHz grid (of points at the same instant the last
is kept): `time`, `usetp` (1 + the reference change, as a recorder samples it), `efd` (GENROU
vf), `vt` (bus 1 voltage), `p`, `q` (GENROU Pe, Qe), `ifd` (XadIfd), `delta` (rad), `omega` (pu).
No noise: the consumers add seeded noise. Files: tests/fixtures/andes_online/NAME.csv and
manifest.json (true parameters, XE, the power-flow operating point, edges, step, excursions,
limits, the electromechanical mode, the checks below, the ANDES version, the command, sha256);
the PSS captures under `pss_captures` (not `captures`, which the consumers that model the unit
read), each with the PSS's values as given to ANDES, its output's largest excursion, whether that
reached the limits, and the mode of the capture without the PSS.

The electromechanical mode of each capture is measured on `p` over 0.02 .. 4.9 s after the first
edge, by a least-squares fit (variable projection: the linear coefficients solved for each set of
the nonlinear ones, those found by scipy's least_squares from the FFT peak of the span) of

    p(t) = c0 + c1 exp(-t / tau) + exp(-sigma t) (a cos(w t) + b sin(w t)),   t from the true edge,

f = w / 2 pi, damping ratio zeta = sigma / sqrt(sigma^2 + w^2). Kept beside it as checks: the
matrix pencil on `p` and on `delta` (0.5 .. 4.9 s after the edge, 100 Hz), and ANDES' own
eigenvalue analysis (EIG: the complex mode in which the rotor speed participates most, of the
system linearised at the initial operating point, before the step). A fit of the same model to
`delta` is no check: delta drifts to its new angle along a slow, well damped 0.1 Hz mode that one
exponential does not follow. With the PSS the swing has died out about 1.5 s after the edge and
the FFT peak of the span is the slow drift's (the fit found 0.35 Hz, zeta 0.96, on trial runs):
the fit starts at the frequency of the capture without the PSS instead.

Checks, measured on the captures (ANDES 2.0.0):
1. The Slack holds bus 2: over the whole run (all of ANDES' points, 0 .. 10.51 s) max |v - 1| and
   max |angle| of bus 2 are 0.0 exactly (in the time domain ANDES keeps the Slack's equations
   a = a0, v = v0); no other infinite bus was needed.
2. Before the first edge every column equals ANDES' initial value exactly (max |deviation| of efd,
   vt, p, q 0.0 in each capture): the initialisation from the power flow is a steady state.
3. Largest excursions from the initial values, efd / vt / q (pu): sexs_xe02 0.428 / 0.0226 /
   0.114, sexs_xe04 0.404 / 0.0231 / 0.0559, esst1a_xe02 0.852 / 0.0215 / 0.108, esst1a_xe04
   0.841 / 0.0220 / 0.0537 (vt overshoots the 0.02 step); no limit is reached (0 ms at ceiling
   or floor in all four).
4. ANDES' own time-step error: esst1a_xe04 made again with 0.1 ms (0.005 ms after the edges)
   differs from the stored one by at most 1.2e-4 pu in efd, 2.0e-7 pu in vt, 7.0e-7 pu in q
   (2.3e-6 in p, 1.7e-6 rad in delta).
5. The PSS damps the mode (fit on p, f Hz / zeta, without -> with): sexs_xe02 1.717 / 0.078 ->
   1.812 / 0.311, esst1a_xe02 1.725 / 0.071 -> 1.701 / 0.303 (ANDES' eigenvalues with it: 1.741 /
   0.326 and 1.640 / 0.328, the matrix pencil on p within 1.1 % of them; the fit's frequency is
   about 4 % above them: ANDES' eigenvalues show a second, heavily damped mode beside the swing,
   1.86 Hz zeta 0.83 and 2.61 Hz zeta 0.75). The PSS output's largest excursion is 0.0079 and
   0.0075 pu, far from its +-0.1 pu limits; efd / vt / q excursions 0.430 / 0.0224 / 0.113 and
   0.794 / 0.0215 / 0.108, no exciter limit reached. sexs_xe02 made again after the PSS was
   added to the script is byte-identical to the stored one.
The modes and the time each capture took are in docs/benchmarks.md.

ANDES is a benchmark extra (`pip install -e '.[andes]'`), never a runtime dependency; the tests
read the fixtures without it. ANDES writes generated code under $HOME/.andes: HOME is pointed at
a temporary folder here. Each `System.add` gets a fresh dict (ANDES mutates the one it gets).

Usage: python benchmarks/andes_online.py [--out tests/fixtures/andes_online]
           [--only sexs_xe02,...,sexs_xe02_pss,esst1a_xe02_pss] [--convergence esst1a_xe04|none] [--json OUT]
(all six captures without --only; a PSS capture made alone takes its base's mode from the
manifest in OUT, else makes the base capture too)
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import andes_captures as ac  # the no-load script: its generator, exciters, steps and helpers
from andes_captures import EXCITERS, FINE_SPAN, FINE_STEP, GENERATOR, RATE, STEP

ROOT = Path(__file__).resolve().parents[1]
RECORD_START = 0.5          # s of ANDES time: the unit has been in its steady state since t = 0
DURATION = 10.0             # s of record
EDGE_ON = 1.00037           # s after the record's start: between samples 1000 and 1001
EDGE_OFF = 6.00021          # ... between samples 6000 and 6001
STEP_OF_VT0 = 0.02          # the reference step, a fraction of the power-flow terminal voltage
P0 = 0.8                    # pu, the PV's active power at bus 1
V0 = 1.0                    # pu, the PV's voltage at bus 1 and the Slack's at bus 2
XES = (0.2, 0.4)            # line reactances (pu on the system base)
MODELS = ("SEXS", "ESST1A")
FLAT_TOL = 1e-5             # pu: the steady state before the first edge must be flatter than this
MODE_SPAN = (0.02, 4.9)     # s after the first edge over which the mode is fitted
PENCIL_SPAN = (0.5, 4.9)    # ... and the matrix pencil's span (after the exciter's fast part)
PENCIL_ORDER = 6            # poles for p; delta, which drifts to its new angle along a slow mode
PENCIL_ORDER_DELTA = 8      # as well, needs 8
BAND_HZ = (0.2, 3.0)        # where an electromechanical mode lies
COLUMNS = ("time", "usetp", "efd", "vt", "p", "q", "ifd", "delta", "omega")
LIMITS = {"ESST1A": "VRMAX*Vt - KC*Ifd / VRMIN*Vt", "SEXS": "EMAX / EMIN"}
PSS_MODEL = "IEEEST"        # ANDES' IEEE ST stabiliser, on the exciter (avr = 1)
PSS_XE = 0.2                # the PSS captures' line
#: the IEEEST filter's A1 given to ANDES for "no filter": 1 ms rather than 0. ANDES' EIG mishandles
#: A1 = A2 = 0 (a real eigenvalue at +1.1/s that the time domain does not show); in a trial
#: time-domain run (2 ms step) A1 0 and 1 ms gave the same mode to 0.001. Over a whole capture
#: (0.2 ms step, andes_online_dyr.py) A1 = A2 = 0 stopped ANDES at 6.5 s ("time step reduced to zero")
ANDES_NO_FILTER_A1 = 0.001
_PSS_COMMON = dict(MODE=1,  # input: the GENROU's speed deviation omega - 1 (pu)
                   # A1 .. A6 (filters) off, A1 as ANDES_NO_FILTER_A1
                   A1=ANDES_NO_FILTER_A1, A2=0.0, A3=0.0, A4=0.0, A5=0.0, A6=0.0,
                   T5=10.0, T6=10.0,                 # washout T5 s / (1 + T6 s): 10 s, unity gain
                   LSMAX=0.1, LSMIN=-0.1,            # output limits
                   VCU=999.0, VCL=-999.0)            # no cut-off by the terminal voltage
#: IEEEST values per exciter, as given to ANDES: two lead-lags (1 + T1 s)/(1 + T2 s) (1 + T3 s)/(1 + T4 s)
#: and the gain KS, tuned on ANDES' eigenvalues for a damping ratio of about 0.3 at a nearly
#: unchanged frequency. One lead-lag 0.2 / 0.05 s (37 degrees at 1.7 Hz) is far too little: with
#: SEXS at KS 20 it raised the frequency 1.72 -> 1.92 Hz and lowered zeta 0.078 -> 0.061 (a torque
#: nearly all synchronising: exciter and field lag by more than 90 + 37 degrees there); ESST1A,
#: whose TC1 / TB1 lead, needs less lead than SEXS
PSS = {"SEXS": dict(_PSS_COMMON, T1=0.2, T2=0.02, T3=0.2, T4=0.02, KS=15.0),
       "ESST1A": dict(_PSS_COMMON, T1=0.15, T2=0.03, T3=0.15, T4=0.03, KS=10.0)}


def case_name(model: str, xe: float) -> str:
    return f"{model.lower()}_xe{int(round(xe * 10)):02d}"


CASES = {case_name(m, xe): (m, xe) for m in MODELS for xe in XES}
#: with the PSS: NAME_pss -> (model, XE, the capture without it)
PSS_CASES = {case_name(m, PSS_XE) + "_pss": (m, PSS_XE, case_name(m, PSS_XE)) for m in MODELS}


def _network(andes, xe: float):
    """The generator bus with the unit's PV (ID 1), the line of reactance `xe`, the Slack as
    infinite bus."""
    ss = andes.System()
    ss.add("Bus", dict(idx=1, name="G", Vn=20.0, v0=V0))
    ss.add("Bus", dict(idx=2, name="INF", Vn=20.0, v0=V0))
    ss.add("Line", dict(idx="L1", bus1=1, bus2=2, r=0.0, x=xe, b=0.0, Vn1=20.0, Vn2=20.0))
    ss.add("Slack", dict(idx=10, bus=2, Vn=20.0, v0=V0, a0=0.0, p0=0.0, Sn=100.0))
    ss.add("PV", dict(idx=20, bus=1, Vn=20.0, v0=V0, p0=P0, Sn=100.0, subidx=1))
    return ss


def _system(andes, model: str, xe: float, step: float = STEP, pss: dict | None = None):
    """The network and the unit: the GENROU and the exciter with the values of `EXCITERS`; with
    `pss` (IEEEST values) an IEEEST on the exciter as well."""
    ss = _network(andes, xe)
    ss.add("GENROU", dict(idx=1, bus=1, gen=20, **GENERATOR))
    ss.add(model, dict(idx=1, syn=1, **EXCITERS[model]))
    if pss is not None:
        ss.add(PSS_MODEL, dict(idx=1, avr=1, **pss))
    return ac._ready(ss, f"{model}, XE {xe}" + (" with PSS" if pss is not None else ""), step)


def system_from_dyr(andes, xe: float, dyr_path: str, step: float = STEP):
    """The same network, the unit's generator and exciter read by ANDES' own PSS/E reader from
    `dyr_path` (an exciter record beside `andes_captures.generator_record()`, bus 1, ID 1);
    benchmarks/andes_online_dyr.py runs bench-ctl's exported record so."""
    from andes.io import psse
    ss = _network(andes, xe)
    if not psse.read_add(ss, dyr_path):
        raise RuntimeError(f"ANDES could not read {dyr_path}")
    return ac._ready(ss, f"{dyr_path}, XE {xe}", step)


def _bus(ss, idx: int) -> int:
    return int(ss.Bus.idx2uid(idx))


def make_capture(andes, model: str, xe: float, step: float = STEP, fine_step: float = FINE_STEP,
                 ss=None, pss: dict | None = None) -> dict:
    """A +2 % / -2 % reference step on the unit on line; `step`, `fine_step`: ANDES' integration
    steps (the time-step check halves both); `ss`: a ready system made with `step` (else built
    here with the values of `EXCITERS`, by which the time at a limit is judged either way, and
    with an IEEEST of the values `pss` if given). With a PSS in the system, "pss" holds its
    output `vsout`: the largest excursion over all of ANDES' points and whether it reached its
    limits."""
    ss = _system(andes, model, xe, step, pss) if ss is None else ss
    b1, b2 = _bus(ss, 1), _bus(ss, 2)
    op = {"P0_pu": float(ss.PV.p0.v[0]), "Q0_pu": float(ss.PV.q.v[0]), "Vt0_pu": float(ss.Bus.v.v[b1]),
          "Vt0_angle_rad": float(ss.Bus.a.v[b1]), "infinite_bus_v_pu": float(ss.Bus.v.v[b2]),
          "infinite_bus_angle_rad": float(ss.Bus.a.v[b2])}
    exc, g = getattr(ss, model), ss.GENROU
    amp = STEP_OF_VT0 * op["Vt0_pu"]
    ac._run_until(ss, RECORD_START + EDGE_ON)
    ac._edge(ss, exc, amp, step=step, fine_step=fine_step, fine_span=FINE_SPAN)
    ac._run_until(ss, RECORD_START + EDGE_OFF)
    ac._edge(ss, exc, -amp, step=step, fine_step=fine_step, fine_span=FINE_SPAN)
    ac._run_until(ss, RECORD_START + DURATION + 0.01)
    ts = ss.dae.ts
    t_raw = np.asarray(ts.t, float)
    x, y = np.asarray(ts.x, float), np.asarray(ts.y, float)
    ifd_var = exc.XadIfd if hasattr(exc, "XadIfd") else g.XadIfd
    raw = {"efd": y[:, int(g.vf.a[0])], "vt": y[:, int(ss.Bus.v.a[b1])], "p": y[:, int(g.Pe.a[0])],
           "q": y[:, int(g.Qe.a[0])], "ifd": y[:, int(ifd_var.a[0])], "delta": x[:, int(g.delta.a[0])],
           "omega": x[:, int(g.omega.a[0])]}
    inf_v, inf_a = y[:, int(ss.Bus.v.a[b2])], y[:, int(ss.Bus.a.a[b2])]
    pss_out = None
    if getattr(ss, PSS_MODEL).n:
        st = getattr(ss, PSS_MODEL)
        vs = y[:, int(st.vsout.a[0])]
        hi_s, lo_s = float(st.LSMAX.v[0]), float(st.LSMIN.v[0])
        pss_out = {"variable": f"{PSS_MODEL}.vsout", "initial_pu": float(vs[0]),
                   "max_excursion_pu": float(np.max(np.abs(vs - vs[0]))),
                   "range_pu": [float(vs.min()), float(vs.max())], "limits_pu": [lo_s, hi_s],
                   "limits_reached": bool(vs.max() >= hi_s - 1e-9 or vs.min() <= lo_s + 1e-9)}
    initial = {k: float(v[0]) for k, v in raw.items()}  # ANDES' initialised values at t = 0
    # ANDES keeps the state before and after an event at the same instant: take the last one
    keep = np.r_[np.diff(t_raw) > 0, True]
    n = int(round(DURATION * RATE)) + 1
    t = np.arange(n) / RATE
    ta = RECORD_START + t
    out = {"time": t, "usetp": 1.0 + np.where((t >= EDGE_ON) & (t < EDGE_OFF), amp, 0.0)}
    for k in COLUMNS[2:]:
        out[k] = np.interp(ta, t_raw[keep], raw[k][keep])
    hi, lo = ac._limits(model, EXCITERS[model], out["vt"], out["ifd"])
    before = t < EDGE_ON
    return {"data": out, "operating_point": op, "initial": initial, "step_pu": amp,
            "ceiling_ms": 1e3 * float((out["efd"] >= hi - 1e-3).sum()) / RATE,
            "floor_ms": 1e3 * float((out["efd"] <= lo + 1e-3).sum()) / RATE,
            # check 1: over the whole run, raw ANDES points
            "infinite_bus_max_dev": {"v_pu": float(np.max(np.abs(inf_v - op["infinite_bus_v_pu"]))),
                                     "angle_rad": float(np.max(np.abs(inf_a - op["infinite_bus_angle_rad"])))},
            # check 2: the record before the first edge against ANDES' initial values
            "flat_before_edge": {k: float(np.max(np.abs(out[k][before] - initial[k]))) for k in COLUMNS[2:]},
            # check 3
            "max_excursion": {k: float(np.max(np.abs(out[k] - initial[k]))) for k in COLUMNS[2:]},
            "pss": pss_out}


def _mode_basis(t: np.ndarray, tau: float, sigma: float, w: float) -> np.ndarray:
    e = np.exp(-sigma * t)
    return np.column_stack([np.ones_like(t), np.exp(-t / tau), e * np.cos(w * t), e * np.sin(w * t)])


def fit_mode(time_s: np.ndarray, y: np.ndarray, t_edge: float, span: tuple[float, float] = MODE_SPAN,
             f_start: float | None = None) -> dict:
    """The damped sinusoid beside a constant and a slow exponential in `y` after `t_edge` (see the
    module's docstring): frequency (Hz), damping ratio, the swing's amplitude at the edge and the
    fit's rms residual. The search starts at `f_start` (Hz), else at the FFT peak in the band of
    the span less a parabola."""
    from scipy.optimize import least_squares

    sel = (time_s >= t_edge + span[0]) & (time_s <= t_edge + span[1])
    t, yy = time_s[sel] - t_edge, y[sel]
    if f_start is None:
        detr = yy - np.polyval(np.polyfit(t, yy, 2), t)
        spec = np.abs(np.fft.rfft(detr * np.hanning(detr.size), n=8 * detr.size))
        freqs = np.fft.rfftfreq(8 * detr.size, float(t[1] - t[0]))
        band = (freqs >= BAND_HZ[0]) & (freqs <= BAND_HZ[1])
        f_start = float(freqs[band][np.argmax(spec[band])])
    w0 = 2 * math.pi * f_start

    def residual(z):
        a = _mode_basis(t, math.exp(z[0]), z[1], z[2])
        coef = np.linalg.lstsq(a, yy, rcond=None)[0]
        return a @ coef - yy

    best = None
    for tau0 in (0.3, 1.0, 3.0, 10.0):
        for zeta0 in (0.02, 0.1):
            r = least_squares(residual, [math.log(tau0), zeta0 * w0, w0], x_scale=[1.0, 0.1, 1.0],
                              bounds=([math.log(0.02), -5.0, 0.5 * w0], [math.log(100.0), 20.0, 1.5 * w0]))
            if best is None or r.cost < best.cost:
                best = r
    tau, sigma, w = math.exp(best.x[0]), float(best.x[1]), float(best.x[2])
    coef = np.linalg.lstsq(_mode_basis(t, tau, sigma, w), yy, rcond=None)[0]
    return {"frequency_hz": w / (2 * math.pi), "damping": sigma / math.hypot(sigma, w), "span_s": list(span),
            "amplitude": float(math.hypot(coef[2], coef[3])), "slow_tau_s": tau,
            "rms_residual": float(np.sqrt(np.mean(best.fun ** 2)))}


def pencil_mode(time_s: np.ndarray, y: np.ndarray, t_edge: float, span: tuple[float, float] = PENCIL_SPAN,
                order: int = PENCIL_ORDER, every: int = 10) -> dict:
    """A second estimate, by the matrix pencil: `y` less its mean over `span` after the edge, every
    `every`-th sample (100 Hz), `order` poles from the pencil's SVD; of the poles in the band, the
    one of largest amplitude (from a least-squares fit of all poles' exponentials to the span)."""
    sel = (time_s >= t_edge + span[0]) & (time_s <= t_edge + span[1])
    yy = y[sel][::every] - np.mean(y[sel][::every])
    dt = float(time_s[1] - time_s[0]) * every
    n = yy.size
    lag = n // 3
    hank = np.array([yy[i:i + lag + 1] for i in range(n - lag)])
    v = np.linalg.svd(hank, full_matrices=False)[2][:order].conj().T
    z = np.linalg.eigvals(np.linalg.pinv(v[:-1]) @ v[1:]).astype(complex)
    amp = np.abs(np.linalg.lstsq(np.vander(z, n, increasing=True).T, yy.astype(complex), rcond=None)[0])
    lam = np.log(z) / dt
    f = lam.imag / (2 * math.pi)
    cand = np.flatnonzero((f >= BAND_HZ[0]) & (f <= BAND_HZ[1]))
    k = int(cand[np.argmax(amp[cand])])
    return {"frequency_hz": float(f[k]), "damping": float(-lam[k].real / abs(lam[k])), "span_s": list(span),
            "order": order, "rate_hz": 1.0 / dt}


def eig_mode(andes, model: str, xe: float, pss: dict | None = None) -> dict:
    """ANDES' small-signal analysis at the same operating point: the complex mode (0.2 .. 3 Hz) in
    which the GENROU's speed participates most (with the IEEEST of the values `pss` if given)."""
    ss = _system(andes, model, xe, pss=pss)
    ss.TDS.init()
    ss.EIG.run()
    mu = np.asarray(ss.EIG.mu)
    pf = np.abs(np.asarray(ss.EIG.W)) * np.abs(np.asarray(ss.EIG.N))   # [state, mode]
    names = [str(n) for n in ss.EIG.x_name]
    k_omega = next(i for i, n in enumerate(names) if n.startswith("omega") and "GENROU" in n)
    share = pf[k_omega] / pf.sum(axis=0)
    f = np.abs(mu.imag) / (2 * math.pi)
    cand = np.flatnonzero((mu.imag > 0) & (f >= BAND_HZ[0]) & (f <= BAND_HZ[1]))
    k = int(cand[np.argmax(share[cand])])
    lam = complex(mu[k])
    return {"eigenvalue": [lam.real, lam.imag], "frequency_hz": abs(lam.imag) / (2 * math.pi),
            "damping": -lam.real / abs(lam), "omega_participation": float(share[k])}


def _read_csv(path: Path) -> dict:
    cols = path.read_text("utf-8").splitlines()[0].split(",")
    a = np.loadtxt(path, delimiter=",", skiprows=1)
    return {c: a[:, i] for i, c in enumerate(cols)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "tests" / "fixtures" / "andes_online"))
    ap.add_argument("--only", default=None,
                    help="comma-separated capture names among " + ",".join([*CASES, *PSS_CASES]))
    ap.add_argument("--convergence", default="esst1a_xe04",
                    help="the capture made again with half the steps (check 4), or 'none'")
    ap.add_argument("--json", dest="json_out", default=None)
    argv_list = list(sys.argv[1:] if argv is None else argv)
    args = ap.parse_args(argv_list)
    names = args.only.split(",") if args.only else [*CASES, *PSS_CASES]
    if not set(names) <= set(CASES) | set(PSS_CASES):
        ap.error(f"--only {args.only}: choose among {', '.join([*CASES, *PSS_CASES])}")
    if args.convergence != "none" and args.convergence not in CASES:
        ap.error(f"--convergence {args.convergence}: choose among {', '.join(CASES)} or none")
    flat: dict = {}
    with tempfile.TemporaryDirectory(prefix="andes-home-") as home:
        os.environ["HOME"] = home  # ANDES writes generated code under $HOME/.andes
        import andes
        andes.config_logger(stream_level=40)
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        # the command that made the fixtures; where the --json figures went is no part of them
        kept = [a for a in argv_list if a != "--json" and a != args.json_out and not a.startswith("--json=")]
        manifest = {"generator": "benchmarks/andes_online.py", "andes_version": andes.__version__,
                    "command": " ".join(["python", "benchmarks/andes_online.py", *kept]),
                    "network": "GENROU at bus 1 -- line (r 0, x XE, no charging) -- Slack at bus 2 as the "
                               "infinite bus; power flow PV P0 0.8 V0 1.0 at bus 1, Slack 1.0 pu angle 0",
                    "record": {"start_in_andes_s": RECORD_START, "duration_s": DURATION, "rate_hz": RATE,
                               "andes_step_s": STEP, "andes_step_after_edges_s": [FINE_STEP, FINE_SPAN],
                               "columns": list(COLUMNS),
                               "units": "pu on the machine base (= the system base, 100 MVA); delta rad, "
                                        "omega pu; time s from the record's start"},
                    "generator_params": dict(GENERATOR),
                    "mode_method": "least-squares fit of p over 0.02 .. 4.9 s after the first (true) edge: "
                                   "c0 + c1 exp(-t/tau) + exp(-sigma t) (a cos wt + b sin wt), linear "
                                   "coefficients by least squares for each (tau, sigma, w), those by "
                                   "scipy.optimize.least_squares from the FFT peak; f = w / 2 pi, "
                                   "damping = sigma / sqrt(sigma^2 + w^2). Checks beside it (mode_checks): "
                                   "the matrix pencil on p (6 poles) and on delta (8 poles) over 0.5 .. 4.9 s "
                                   "at 100 Hz, and ANDES' EIG eigenvalue with the largest rotor-speed "
                                   "participation, linearised at the initial (pre-step) operating point",
                    "pss_mode_method": "the same fit, started at the frequency of the capture without "
                                       "the PSS (the swing, damped within about 1.5 s, is no longer the FFT "
                                       "peak of the span)",
                    "captures": {}, "pss_captures": {}}
        if args.only and (out / "manifest.json").exists():  # add to the captures already there
            old = json.loads((out / "manifest.json").read_text("utf-8"))
            manifest["captures"] = old["captures"]
            manifest["pss_captures"] = old.get("pss_captures", {})
            manifest["step_convergence"] = old.get("step_convergence")
            manifest["command"] = f"{old['command']} && {manifest['command']}"  # the commands in turn
        print(f"{'capture':<14}{'Q0':>8}{'efd0':>8}{'d efd':>8}{'d vt':>8}{'d q':>8}{'flat':>9}{'inf bus':>9}"
              f"{'f Hz':>7}{'zeta':>8}{'eig f':>7}{'eig z':>8}{'lim ms':>7}{'s':>6}")
        made, modes = {}, {}
        for name in sorted(names, key=lambda n: n in PSS_CASES):  # a PSS capture after its base
            model, xe, base = PSS_CASES[name] if name in PSS_CASES else (*CASES[name], None)
            pss = PSS[model] if base else None
            t0 = time.perf_counter()
            cap = make_capture(andes, model, xe, pss=pss)
            wall = time.perf_counter() - t0
            d = cap["data"]
            made[name] = d
            sha = ac._write_csv(out / f"{name}.csv", d)
            if base:  # the capture without the PSS: its mode by the same fit, made here if need be
                if base not in modes and base in manifest["captures"]:
                    modes[base] = manifest["captures"][base]["mode"]
                elif base not in modes:
                    bd = make_capture(andes, model, xe)["data"]
                    modes[base] = {"from": "p", **fit_mode(bd["time"], bd["p"], EDGE_ON)}
            f_start = modes[base]["frequency_hz"] if base else None
            mode_p = fit_mode(d["time"], d["p"], EDGE_ON, f_start=f_start)
            modes[name] = {"from": "p", **mode_p}
            pencil_p = pencil_mode(d["time"], d["p"], EDGE_ON)
            pencil_delta = pencil_mode(d["time"], d["delta"], EDGE_ON, order=PENCIL_ORDER_DELTA)
            mode_eig = eig_mode(andes, model, xe, pss)
            flat_dev = max(cap["flat_before_edge"][k] for k in ("efd", "vt", "p", "q"))
            inf_dev = max(cap["infinite_bus_max_dev"].values())
            entry = {
                "file": f"{name}.csv", "sha256": sha, "exciter": model, "exciter_params": dict(EXCITERS[model]),
                "xe_pu": xe, "operating_point": cap["operating_point"], "initial_values": cap["initial"],
                "step_of_vt0": STEP_OF_VT0, "usetp_step_pu": cap["step_pu"],
                "edges_nominal_s": [float(np.ceil(EDGE_ON * RATE) / RATE), float(np.ceil(EDGE_OFF * RATE) / RATE)],
                "edges_true_s": [EDGE_ON, EDGE_OFF],
                "ceiling_ms": cap["ceiling_ms"], "floor_ms": cap["floor_ms"], "limits": LIMITS[model],
                "max_excursion": cap["max_excursion"], "flat_before_edge_max_dev": cap["flat_before_edge"],
                "flat_before_edge": bool(flat_dev < FLAT_TOL),
                "infinite_bus_max_dev": cap["infinite_bus_max_dev"],
                "mode": {"from": "p", **mode_p},
                "mode_checks": {"pencil_p": pencil_p, "pencil_delta": pencil_delta,
                                "andes_eig_at_the_initial_point": mode_eig}}
            if base:
                entry.update({"without_pss": base, "pss_model": PSS_MODEL,
                              "pss_connection": "avr = 1 (the exciter); MODE 1: input the GENROU's speed "
                                                "deviation omega - 1 (pu), output vsout added to the "
                                                "exciter's input vi",
                              "pss_params": dict(pss), "pss_output": cap["pss"],
                              "mode_without_pss": modes[base]})
                manifest["pss_captures"][name] = entry
            else:
                manifest["captures"][name] = entry
            ex = cap["max_excursion"]
            print(f"{name:<14}{cap['operating_point']['Q0_pu']:>8.4f}{cap['initial']['efd']:>8.4f}{ex['efd']:>8.4f}"
                  f"{ex['vt']:>8.4f}{ex['q']:>8.4f}{flat_dev:>9.1e}{inf_dev:>9.1e}{mode_p['frequency_hz']:>7.3f}"
                  f"{mode_p['damping']:>8.4f}{mode_eig['frequency_hz']:>7.3f}{mode_eig['damping']:>8.4f}"
                  f"{cap['ceiling_ms'] + cap['floor_ms']:>7.0f}{wall:>6.0f}", flush=True)
            if flat_dev >= FLAT_TOL:
                print(f"  {name}: NOT flat before the edge ({flat_dev:.2e} pu)", flush=True)
            if base:
                po = cap["pss"]
                print(f"  {name}: without the PSS {modes[base]['frequency_hz']:.3f} Hz, zeta "
                      f"{modes[base]['damping']:.4f}; vsout max |excursion| {po['max_excursion_pu']:.4f} pu, "
                      f"limits {'REACHED' if po['limits_reached'] else 'not reached'}", flush=True)
                flat.update({f"{name}_pss_max_excursion": po["max_excursion_pu"],
                             f"{name}_pss_limits_reached": po["limits_reached"],
                             f"{name}_mode_hz_without_pss": modes[base]["frequency_hz"],
                             f"{name}_mode_damping_without_pss": modes[base]["damping"]})
            flat.update({f"{name}_wall_s": wall, f"{name}_efd_excursion": ex["efd"], f"{name}_vt_excursion": ex["vt"],
                         f"{name}_q_excursion": ex["q"], f"{name}_ceiling_ms": cap["ceiling_ms"],
                         f"{name}_floor_ms": cap["floor_ms"], f"{name}_flat_max_dev": flat_dev,
                         f"{name}_infinite_bus_max_dev": inf_dev, f"{name}_mode_hz": mode_p["frequency_hz"],
                         f"{name}_mode_damping": mode_p["damping"]})
        if args.convergence != "none":
            name = args.convergence
            model, xe = CASES[name]
            t0 = time.perf_counter()
            half = make_capture(andes, model, xe, step=STEP / 2, fine_step=FINE_STEP / 2)["data"]
            wall = time.perf_counter() - t0
            ref = made.get(name) or _read_csv(out / f"{name}.csv")
            diff = {k: float(np.max(np.abs(half[k] - ref[k]))) for k in COLUMNS[2:]}
            manifest["step_convergence"] = {"capture": name, "andes_step_s": STEP / 2,
                                            "andes_step_after_edges_s": [FINE_STEP / 2, FINE_SPAN],
                                            "max_abs_difference": diff}
            print(f"{name} at half the steps ({wall:.0f} s): max |difference| efd {diff['efd']:.2e},"
                  f" vt {diff['vt']:.2e}, q {diff['q']:.2e}, p {diff['p']:.2e}, delta {diff['delta']:.2e} rad",
                  flush=True)
            flat.update({f"convergence_{k}": v for k, v in diff.items()})
            flat["convergence_wall_s"] = wall
        (out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    if args.json_out:
        flat["captures"] = len(manifest["captures"])
        flat["pss_captures"] = len(manifest["pss_captures"])
        Path(args.json_out).write_text(json.dumps(flat, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
