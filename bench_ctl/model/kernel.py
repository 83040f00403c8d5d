"""The compiled, batched simulation kernel of the reference unit with its eight effects.

One call simulates a whole population of parameter sets driven by one recorded setpoint series.
Time runs in the outer loop and candidates in the inner loop (states are arrays over candidates),
chunks of candidates run in parallel (DESIGN.md section 8).

Numerics: classical RK4 at the capture's sample step; the setpoint is zero-order hold (sample k
acts on [t_k, t_k+1)), so every input jump falls on a step boundary. The dead time delays the AVR
output VR; its history is kept as the right limit at t_j and the left limit at t_j+1 of every
step, so a delayed jump stays a jump instead of being smeared over a step. The efd recorder skew
reads the efd history by cubic Hermite interpolation with the one-sided derivatives of each step.
Non-smooth effects (non-windup ceiling, slew limit) are evaluated inside every RK stage and the
state is clamped after the step.

A candidate whose states leave a sane range (unstable loop, stiff parameters beyond what the step
resolves) is marked failed at that step and frozen; its outputs stay finite (held) and the caller
turns the failure step into a rankable penalty. No NaN ever leaves the kernel.

Derived per-candidate factors are computed once, in numpy, by `derive` (column order `D_*`).
"""
from __future__ import annotations

import math
import os

import llvmlite.binding as _llvm
import numba as nb
import numpy as np
from numba.core import types
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

from .edges import EdgeSpec
from .params import COL, KERNEL_PARAMS, RECORD_PARAMS

# The RK4 loop over candidates reads ~40 rows of 2-D arrays; LLVM's loop vectoriser needs a
# runtime alias check per pair and gives up past its default of 8 checks ("too many memory
# checks needed"), leaving the loop scalar. Raising the limit makes it vectorise (measured ~1.4x
# per core). Process-wide, it only raises a vectoriser limit. See docs/decisions/0003.
_llvm.set_option("", "-runtime-memory-check-threshold=256")
_llvm.set_option("", "-vectorize-memory-check-threshold=512")


def optimisation_note() -> str | None:
    """None when numba's code generator runs the "max" optimisation the kernel's RK4 loops need to
    be vectorised (bench_ctl sets NUMBA_OPT=max at import, see bench_ctl/__init__.py), else why
    not: numba was set up before bench_ctl was imported, or NUMBA_OPT was set otherwise."""
    try:
        from numba.core.registry import cpu_target
        codegen = cpu_target.target_context.codegen()
        ok = bool(getattr(codegen, "_loopvect", True)) and getattr(codegen, "_opt_level", 3) == 3
    except Exception:  # pragma: no cover - numba internals moved: do not guess
        return None
    if ok:
        return None
    return (f"numba runs without its 'max' optimisation (NUMBA_OPT={os.environ.get('NUMBA_OPT', '')!r}, or "
            "numba was set up before bench_ctl was imported): the kernel's RK4 loops stay scalar and the "
            "standard structures simulate ~2.5x slower")

# derived-column indices
(D_KAVR, D_R1, D_IT2, D_R2, D_IT4, D_ITE, D_ITR, D_ITD0P, D_ITD0PP, D_SATA, D_SATB,
 D_VRMAX, D_VRMIN, D_TD, D_RATE, D_RAMP, D_GAIN, D_SKEW, D_VT0, D_EFD0, D_E0, D_UREF0,
 D_VALID, D_TRON, D_TDON, D_VRVT, D_KC, D_EDGE0) = range(28)
# the blocks of the standard structures: rate feedback gain KF/TF and 1/TF, DC exciter (1/TEX, on,
# KE, quadratic saturation A, B), output clamp instead of a non-windup lag, the field voltage at
# the steady state (the kernel's output; D_EFD0 is the regulator output's)
(D_KFT, D_ITF, D_ITEX, D_DCON, D_KE, D_SEA, D_SEB, D_LIMOUT, D_OUT0, D_KPP, D_SATVT, D_KDA) = range(
    27 + len(RECORD_PARAMS), 27 + len(RECORD_PARAMS) + 12)
# the potential-source stage (ESST4B): on, the PI in place of lead-lag 1 (proportional gain added
# to the lead-lag's output, integral gain, output limits), KP (1 when off), VBMAX, the inner PI
# (KPM, KIM, limits), KG, and the rate-feedback state's steady state (the inner integrator's)
(D_ST4, D_P1, D_KI1, D_Y1MAX, D_Y1MIN, D_KPV, D_VBMAX, D_KPM, D_KIM, D_VMMAX, D_VMMIN, D_KG, D_XF0) = range(
    27 + len(RECORD_PARAMS) + 12, 27 + len(RECORD_PARAMS) + 25)
N_DERIVED = 27 + len(RECORD_PARAMS) + 25   # D_EDGE0 + slot: offset of setpoint edge `slot` (s)
#: the potential-source stage in a chunk (`_rhs`'s `st4`, a constant of each RK4 loop): no candidate
#: has it; some may (selected per candidate); every valid candidate has it (the output is VB VM,
#: no DC exciter, the ceilings not on the regulator lag: those blocks are left out)
ST4_NONE, ST4_SOME, ST4_ALL = 0, 1, 2
#: tracking gain of the anti-windup of the ESST4B's PI regulators (ANDES' PITrackAW default, ks = 2)
PI_TRACK = 2.0
#: an edge instant within this many steps of a sample instant is taken to fall on it
EDGE_EPS = 1.0e-9

#: candidates per parallel chunk (see run_kernel)
CHUNK = 32

#: a state magnitude beyond this marks the candidate failed (pu; physical values are < 20)
BLOWUP = 1.0e5


def saturation_ab(s10: np.ndarray, s12: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quadratic saturation Sat(x) = B (x - A)^2 for x > A through S(1.0) = S10, S(1.2) = S12."""
    s10 = np.asarray(s10, float)
    s12 = np.asarray(s12, float)
    on = (s10 > 0.0) & (s12 > s10)
    r = np.sqrt(np.where(on, s12, 1.0) / np.where(on, s10, 1.0))
    a = np.where(on, (r - 1.2) / np.where(on, r - 1.0, 1.0), 0.0)
    b = np.where(on, s10 / np.where(on, (1.0 - a) ** 2, 1.0), 0.0)
    return a, b


def exciter_saturation_ab(e1, se1, e2, se2) -> tuple[np.ndarray, np.ndarray]:
    """DC exciter saturation SE(Efd) Efd = B (Efd - A)^2 for Efd > A, through SE(E1) = SE1 and
    SE(E2) = SE2 (the quadratic form of IEEE 421.5 as PSS/E and ANDES' ExcQuadSat use it).
    Off (A = 0, B = 0) unless 0 < E1 < E2 and 0 < SE1 < SE2... with E2 SE2 > E1 SE1."""
    e1, se1, e2, se2 = (np.asarray(x, float) for x in (e1, se1, e2, se2))
    on = (e1 > 0) & (e2 > e1) & (se1 > 0) & (se2 * e2 > se1 * e1)
    r = np.sqrt(np.where(on, (e2 * se2) / np.where(on, e1 * se1, 1.0), 4.0))
    a = np.where(on, (r * e1 - e2) / np.where(on, r - 1.0, 1.0), 0.0)
    b = np.where(on, e1 * se1 / np.where(on, (e1 - a) ** 2, 1.0), 0.0)
    return a, b


def _vb_np(ve: np.ndarray, kc_ifd: np.ndarray, vbmax: np.ndarray) -> np.ndarray:
    """VB = VE FEX(KC Ifd / VE), at most VBMAX (numpy twin of `_vb`)."""
    ve = np.maximum(ve, 1.0e-6)
    x = kc_ifd / ve
    f = np.where(x <= 0.0, 1.0, np.where(x <= 0.433, 1.0 - 0.577 * x, np.where(
        x <= 0.75, np.sqrt(np.maximum(0.75 - x * x, 0.0)), np.where(x <= 1.0, 1.732 * (1.0 - x), 0.0))))
    return np.minimum(ve * f, vbmax)


def derive(P: np.ndarray) -> np.ndarray:
    """Per-candidate factors for the kernel from the parameter matrix (n, len(KERNEL_PARAMS))."""
    P = np.atleast_2d(np.asarray(P, dtype=np.float64))
    if P.shape[1] != len(KERNEL_PARAMS):
        raise ValueError(f"parameter matrix has {P.shape[1]} columns, expected {len(KERNEL_PARAMS)}")
    g = {name: P[:, i] for i, name in enumerate(KERNEL_PARAMS)}
    n = P.shape[0]
    D = np.zeros((n, N_DERIVED))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        valid = np.ones(n, bool)
        for name in ("KAVR", "TA2", "TA4", "TE", "Td0p", "Td0pp"):
            valid &= np.isfinite(g[name]) & (g[name] > 0.0)
        for name in ("TA1", "TA3", "TR", "TD", "SKEW", "Vt0", "S10", "S12"):
            valid &= np.isfinite(g[name]) & (g[name] >= 0.0)
        valid &= (g["RATE"] > 0.0) & (g["RAMP"] > 0.0) & np.isfinite(g["GAIN"])
        valid &= g["VRMAX"] > g["VRMIN"]
        valid &= (g["VRVT"] >= 0.0) & (g["VRVT"] <= 1.0) & (g["KC"] >= 0.0) & np.isfinite(g["KC"])
        valid &= np.isfinite(g["KF"]) & (g["KF"] >= 0.0) & ((g["KF"] == 0.0) | (g["TF"] > 0.0))
        valid &= np.isfinite(g["TEX"]) & (g["TEX"] >= 0.0) & np.isfinite(g["KE"])
        valid &= (g["KPP"] >= 0.0) & (g["KPP"] <= 1.0) & (g["KDA"] >= 0.0) & np.isfinite(g["KDA"])
        valid &= np.isfinite(g["KPV"]) & (g["KPV"] >= 0.0) & (g["VBMAX"] > 0.0)
        for name in ("KPI", "KII", "KPM", "KIM", "KG"):
            valid &= np.isfinite(g[name]) & (g[name] >= 0.0)
        valid &= (g["VPMAX"] > g["VPMIN"]) & (g["VMMAX"] > g["VMMIN"])
        for name in RECORD_PARAMS:
            valid &= np.isfinite(g[name])
        safe = lambda x: np.where(valid, x, 1.0)  # noqa: E731
        a, b = saturation_ab(g["S10"], g["S12"])
        vt0 = safe(g["Vt0"])
        sat0 = np.where(vt0 > a, b * (vt0 - a) ** 2, 0.0)
        fld0 = vt0 + sat0                      # the field voltage the generator needs
        dc = valid & (g["TEX"] > 0.0)
        sea, seb = exciter_saturation_ab(g["E1"], g["SE1"], g["E2"], g["SE2"])
        sea = np.where(dc, sea, 0.0)
        seb = np.where(dc, seb, 0.0)
        ke = np.where(dc, g["KE"], 0.0)
        # a DC exciter needs VR = (KE + SE(Efd)) Efd from the regulator; a static one, Efd itself
        efd0 = np.where(dc, ke * fld0 + seb * np.maximum(fld0 - sea, 0.0) ** 2, fld0)
        # the potential-source stage: Efd = VB VM; at the steady state (as ANDES initialises it)
        # the regulator's error is 0, its PI and lag hold KG Efd and the inner integrator Efd / VB
        st4 = valid & ~dc & (g["KPV"] > 0.0)
        vb0 = _vb_np(np.where(st4, g["KPV"], 1.0) * vt0, np.where(valid, g["KC"], 0.0) * fld0, g["VBMAX"])
        efd0 = np.where(st4, np.where(st4, g["KG"], 0.0) * fld0, efd0)
        D[:, D_KAVR] = safe(g["KAVR"])
        D[:, D_R1] = safe(g["TA1"] / g["TA2"])
        D[:, D_IT2] = safe(1.0 / g["TA2"])
        D[:, D_R2] = safe(g["TA3"] / g["TA4"])
        D[:, D_IT4] = safe(1.0 / g["TA4"])
        D[:, D_ITE] = safe(1.0 / g["TE"])
        D[:, D_ITR] = np.where(valid & (g["TR"] > 0.0), 1.0 / np.where(g["TR"] > 0, g["TR"], 1.0), 0.0)
        D[:, D_ITD0P] = safe(1.0 / g["Td0p"])
        D[:, D_ITD0PP] = safe(1.0 / g["Td0pp"])
        D[:, D_SATA] = a
        D[:, D_SATB] = b
        D[:, D_VRMAX] = g["VRMAX"]
        D[:, D_VRMIN] = g["VRMIN"]
        D[:, D_TD] = np.where(valid, g["TD"], 0.0)
        D[:, D_RATE] = g["RATE"]
        D[:, D_RAMP] = g["RAMP"]
        D[:, D_GAIN] = np.where(valid, g["GAIN"], 1.0)
        D[:, D_SKEW] = np.where(valid, g["SKEW"], 0.0)
        D[:, D_VT0] = vt0
        # steady state: Ifd = E'q + Sat(E'q) = efd0, the limits at Vt0
        scale0 = 1.0 + np.where(valid, g["VRVT"], 0.0) * (vt0 - 1.0)
        hi0 = g["VRMAX"] * scale0 - np.where(valid, g["KC"], 0.0) * efd0
        lo0 = g["VRMIN"] * scale0
        D[:, D_EFD0] = np.clip(efd0, lo0, np.maximum(hi0, lo0))
        D[:, D_VRVT] = np.where(valid, g["VRVT"], 0.0)
        D[:, D_KC] = np.where(valid, g["KC"], 0.0)
        D[:, D_E0] = D[:, D_EFD0] / D[:, D_KAVR]
        D[:, D_UREF0] = vt0 + np.where(st4, 0.0, D[:, D_E0])
        D[:, D_VALID] = valid.astype(np.float64)
        D[:, D_TRON] = (D[:, D_ITR] > 0.0).astype(np.float64)
        D[:, D_TDON] = (D[:, D_TD] > 0.0).astype(np.float64)
        for slot, name in enumerate(RECORD_PARAMS):
            D[:, D_EDGE0 + slot] = np.where(valid, g[name], 0.0)
        fb = valid & (g["KF"] > 0.0)
        D[:, D_KFT] = np.where(fb, g["KF"] / np.where(fb, g["TF"], 1.0), 0.0)
        D[:, D_ITF] = np.where(fb, 1.0 / np.where(fb, g["TF"], 1.0), 0.0)
        D[:, D_ITEX] = np.where(dc, 1.0 / np.where(dc, g["TEX"], 1.0), 0.0)
        D[:, D_DCON] = dc.astype(np.float64)
        D[:, D_KE] = ke
        D[:, D_SEA] = sea
        D[:, D_SEB] = seb
        D[:, D_LIMOUT] = np.where(valid & ~dc, g["LIMOUT"] > 0.5, False).astype(np.float64)
        # the output at the steady state: the DC exciter's Efd, else the (clamped) regulator output
        D[:, D_OUT0] = np.where(dc, fld0, D[:, D_EFD0])
        D[:, D_KPP] = np.where(valid, g["KPP"], 0.0)
        D[:, D_SATVT] = (D[:, D_KPP] > 0.0).astype(np.float64)
        D[:, D_KDA] = np.where(valid, g["KDA"], 0.0)
        D[:, D_ST4] = st4.astype(np.float64)
        D[:, D_R1] = np.where(st4, 0.0, D[:, D_R1])      # the PI replaces lead-lag 1
        D[:, D_IT2] = np.where(st4, 0.0, D[:, D_IT2])
        D[:, D_P1] = np.where(st4, g["KPI"], 0.0)
        D[:, D_KI1] = np.where(st4, g["KII"], 0.0)
        D[:, D_Y1MAX] = np.where(st4, g["VPMAX"], np.inf)
        D[:, D_Y1MIN] = np.where(st4, g["VPMIN"], -np.inf)
        D[:, D_KPV] = np.where(st4, g["KPV"], 1.0)
        D[:, D_VBMAX] = np.where(st4, g["VBMAX"], np.inf)
        D[:, D_KPM] = np.where(st4, g["KPM"], 0.0)
        D[:, D_KIM] = np.where(st4, g["KIM"], 0.0)
        D[:, D_VMMAX] = np.where(st4, g["VMMAX"], np.inf)
        D[:, D_VMMIN] = np.where(st4, g["VMMIN"], -np.inf)
        D[:, D_KG] = np.where(st4, g["KG"], 0.0)
        D[:, D_OUT0] = np.where(st4, fld0, D[:, D_OUT0])
        D[:, D_XF0] = np.where(st4, fld0 / np.where(st4, vb0, 1.0),
                               D[:, D_EFD0] + D[:, D_DCON] * (D[:, D_OUT0] - D[:, D_EFD0]))
    return D


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _avr(D, i, uref, vm, x1, x2, vf):
    """AVR lead-lags: returns (VR, e, y1) for error e = uref - Vm - Vf (Vf: rate feedback).
    With the potential-source stage the first lead-lag is a PI (KPI e + x1) within its limits."""
    e = uref - vm - vf
    y1 = _pi1(D, i, e, x1)[0]
    y2 = x2 + D[D_R2, i] * (y1 - x2)
    return D[D_KAVR, i] * y2, e, y1


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _pi1(D, i, e, x1):
    """The first lead-lag, or the ESST4B's PI regulator in its place: (output, its unlimited sum).
    Lead-lag: x1 + R1 (e - x1) (P1 = 0, no limits); PI: x1 + KPI e (R1 = 0), limited."""
    ys = x1 + D[D_R1, i] * (e - x1) + D[D_P1, i] * e
    y = ys if ys < D[D_Y1MAX, i] else D[D_Y1MAX, i]
    y = y if y > D[D_Y1MIN, i] else D[D_Y1MIN, i]
    return y, ys


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _vb(D, i, vt, ifd):
    """VB = VE FEX(IN), VE = KP Vt (no load: no current term), IN = KC Ifd / VE, at most VBMAX:
    the rectifier regulation characteristic of IEEE 421.5 (ESST4B). Branch-free selects."""
    ve = D[D_KPV, i] * vt
    ve = ve if ve > 1.0e-6 else 1.0e-6
    x = D[D_KC, i] * ifd / ve
    q = 0.75 - x * x
    q = q if q > 0.0 else 0.0
    f = 1.732 * (1.0 - x)
    f = f if x <= 1.0 else 0.0
    f = math.sqrt(q) if x <= 0.75 else f
    f = 1.0 - 0.577 * x if x <= 0.433 else f
    f = 1.0 if x <= 0.0 else f
    vb = ve * f
    return vb if vb < D[D_VBMAX, i] else D[D_VBMAX, i]


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _st4(D, i, ef, xf, vt, ifd, hi, lo):
    """The potential-source output stage: (Efd = VB VM, VM, its unlimited sum, VB). The inner PI
    VM = KPM (VA - KG Efd) + xf (xf its integrator, VA the regulator lag `ef`) with Efd = VB VM
    is solved in closed form, then VM limited (the limited VM is the consistent one: the sum
    falls as VM rises): to [VMMIN, VMMAX], and to [lo, hi] / VB, the diagnosis' `ceiling_limit`
    on Efd (`_limits`; +-inf unless that effect is on), so that the effect bounds ESST4B's field
    voltage the way VB VMMAX does rather than the regulator lag VA."""
    vb = _vb(D, i, vt, ifd)
    kpm = D[D_KPM, i]
    vm = (kpm * ef + xf) / (1.0 + kpm * D[D_KG, i] * vb)
    vm = vm if vm < D[D_VMMAX, i] else D[D_VMMAX, i]
    vm = vm if vm > D[D_VMMIN, i] else D[D_VMMIN, i]
    r = 1.0 / (vb if vb > 1.0e-9 else 1.0e-9)   # one division for both bounds
    vm = vm if vm < hi * r else hi * r
    vm = vm if vm > lo * r else lo * r
    fld = vb * vm
    return fld, vm, kpm * (ef - D[D_KG, i] * fld) + xf, vb


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _vt(D, i, eqp, eqpp):
    """Terminal voltage at no load: E''q, or with a GENROU-like flux share KPP of E'q,
    Vt = KPP E'q + (1 - KPP) E''q."""
    return eqpp + D[D_KPP, i] * (eqp - eqpp)


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _ifd(D, i, eqp, eqpp, vt):
    """The no-load field current on the air-gap base: E'q + KDA (E'q - E''q) + Sat."""
    d = eqp + D[D_SATVT, i] * (vt - eqp) - D[D_SATA, i]
    d = d if d > 0.0 else 0.0
    return eqp + D[D_KDA, i] * (eqp - eqpp) + D[D_SATB, i] * d * d


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _limits(D, i, eqp, eqpp):
    """Exciter ceilings (hi, lo): VRMAX, VRMIN, scaled by Vt when VRVT = 1 (bus-fed), the upper
    one less KC*Ifd, Ifd = E'q + Sat (the no-load field current on the air-gap base)."""
    vt = _vt(D, i, eqp, eqpp)
    d = eqp + D[D_SATVT, i] * (vt - eqp) - D[D_SATA, i]
    d = d if d > 0.0 else 0.0
    ifd = eqp + D[D_KDA, i] * (eqp - eqpp) + D[D_SATB, i] * d * d
    sc = 1.0 + D[D_VRVT, i] * (vt - 1.0)
    sc = sc if sc > 1.0e-3 else 1.0e-3
    return D[D_VRMAX, i] * sc - D[D_KC, i] * ifd, D[D_VRMIN, i] * sc


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _vf(D, i, ef, xf, xe):
    """Rate feedback KF s/(1 + s TF) of the exciter output (DC) or the regulator output (static)."""
    src = ef + D[D_DCON, i] * (xe - ef)
    return D[D_KFT, i] * (src - xf)


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _field(D, i, ef, eqp, eqpp, xf, xe):
    """The field voltage (the kernel's output): the DC exciter's, else the regulator output,
    clamped to the ceilings when they clamp the output (D_LIMOUT) rather than the lag, else
    (ESST4B) VB VM."""
    hi, lo = _limits(D, i, eqp, eqpp)
    efc = ef if ef > lo else lo
    efc = efc if efc < hi else hi
    efc = ef + D[D_LIMOUT, i] * (efc - ef)
    if D[D_ST4, i] != 0.0:   # a branch: the loops that record the output do not vectorise
        vt = _vt(D, i, eqp, eqpp)
        return _st4(D, i, ef, xf, vt, _ifd(D, i, eqp, eqpp, vt), hi, lo)[0]
    return efc + D[D_DCON, i] * (xe - efc)


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _rhs(D, i, uref, vrd, xm, x1, x2, ef, eqp, eqpp, xf, xe, st4=ST4_SOME):
    """Derivatives of (xm, x1, x2, VR lag (efd of a static exciter), E'q, E''q, rate feedback,
    DC exciter Efd); branch-free so candidate loops vectorise. `st4` (ST4_*, a constant where the
    caller passes one: the branches then fold away) includes the potential-source stage (ESST4B):
    a chunk without it does not pay for its square root and divisions (measured: 1.35x of a
    chunk's time), a chunk of ESST4B alone not for the DC exciter and the non-windup ceiling.

    `vrd` is the delayed VR (used when the candidate has a dead time, D_TDON = 1)."""
    tron = D[D_TRON, i]
    vt = _vt(D, i, eqp, eqpp)
    vm = tron * xm + (1.0 - tron) * vt
    src = ef if st4 == ST4_ALL else ef + D[D_DCON, i] * (xe - ef)
    e = uref - vm - D[D_KFT, i] * (src - xf)
    y1, ys1 = _pi1(D, i, e, x1)
    y2 = x2 + D[D_R2, i] * (y1 - x2)
    vr = D[D_KAVR, i] * y2
    dxm = (vt - xm) * D[D_ITR, i]
    # lead-lag 1, or the PI's integrator with tracking anti-windup (ANDES' PITrackAW)
    dx1 = (e - x1) * D[D_IT2, i] + D[D_KI1, i] * (e - PI_TRACK * (ys1 - y1))
    dx2 = (y1 - x2) * D[D_IT4, i]
    tdon = D[D_TDON, i]
    drive = vr + tdon * (vrd - vr)
    # plain compare-and-select (numba's min/max carry NaN branches that stop the vectoriser)
    rate = D[D_RATE, i]
    de = (drive - ef) * D[D_ITE, i]
    de = de if de < rate else rate
    de = de if de > -rate else -rate
    hi, lo = _limits(D, i, eqp, eqpp)
    # saturation of E'q (the reference model) or, with a GENROU-like flux share, of Vt = psi''
    satvt = D[D_SATVT, i]
    d = eqp + satvt * (vt - eqp) - D[D_SATA, i]
    d = d if d > 0.0 else 0.0
    # the field voltage: VB VM of the potential-source stage, the DC exciter's state, else the
    # regulator output (clamped when the ceilings clamp the output rather than the lag)
    limout = D[D_LIMOUT, i]
    if st4 == ST4_ALL:
        # the potential-source stage alone (ESST4B): Efd = VB VM, state 6 the inner PI's
        # integrator (tracking anti-windup as ANDES' PITrackAW); no DC exciter
        f4, vm4, ys4, _vb4 = _st4(D, i, ef, xf, vt, _ifd(D, i, eqp, eqpp, vt), hi, lo)
        fld = f4
        dxf = D[D_KIM, i] * (ef - D[D_KG, i] * f4 - PI_TRACK * (ys4 - vm4))
        dxe = 0.0
    else:
        efc = ef if ef > lo else lo
        efc = efc if efc < hi else hi
        efc = ef + limout * (efc - ef)
        dcon = D[D_DCON, i]
        fld = efc + dcon * (xe - efc)
        dx = xe - D[D_SEA, i]
        dx = dx if dx > 0.0 else 0.0
        dxe = (efc - D[D_KE, i] * xe - D[D_SEB, i] * dx * dx) * D[D_ITEX, i]
        dxf = (src - xf) * D[D_ITF, i]
        # the potential-source stage where a candidate has it, selected, not branched, so the
        # loop vectorises
        if st4 == ST4_SOME:
            s4 = D[D_ST4, i]
            f4, vm4, ys4, _vb4 = _st4(D, i, ef, xf, vt, _ifd(D, i, eqp, eqpp, vt), hi, lo)
            fld = fld + s4 * (f4 - fld)
            dxf = dxf + s4 * (D[D_KIM, i] * (ef - D[D_KG, i] * f4 - PI_TRACK * (ys4 - vm4)) - dxf)
    deqp = (fld - eqp - D[D_KDA, i] * (eqp - eqpp) - D[D_SATB, i] * d * d) * D[D_ITD0P, i]
    deqpp = (eqp - eqpp) * D[D_ITD0PP, i]
    dvt = deqpp + D[D_KPP, i] * (deqp - deqpp)
    # non-windup ceiling: at a limit efd may not pass it, and follows it where it moves (with Vt
    # for a bus-fed exciter, with Ifd through the commutation drop); fixed limits do not move.
    # Not when the ceilings clamp the output (the lag winds up beyond them, ESST1A/EXST1), nor on
    # ESST4B's regulator lag (its ceilings act on VM)
    if st4 != ST4_ALL:
        dsc = D[D_VRVT, i] * dvt
        dhi = D[D_VRMAX, i] * dsc - D[D_KC, i] * (deqp + D[D_KDA, i] * (deqp - deqpp)
                                                  + 2.0 * D[D_SATB, i] * d * (deqp + satvt * (dvt - deqp)))
        dlo = D[D_VRMIN, i] * dsc
        dhi = dhi if dhi == dhi else 0.0  # inf * 0 (no ceiling, fixed limits) is no movement
        dlo = dlo if dlo == dlo else 0.0
        nw = limout == 0.0
        de = (de if de < dhi else dhi) if (ef >= hi and nw) else de
        de = (de if de > dlo else dlo) if (ef <= lo and nw) else de
    return dxm, dx1, dx2, de, deqp, deqpp, dxf, dxe


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _delayed(vr_r, vr_l, jf, vjl, vjr, c, L, tau_steps, k, vr0, left):
    """VR at time tau_steps * dt from the per-step history kept in rings of length L.

    Step j keeps the right limit at t_j (`vr_r`), the left limit at t_j+1 (`vr_l`) and, when the
    setpoint jumped inside it at fraction `jf` > 0, the left and right limits there (`vjl`,
    `vjr`); VR is linear between. `left` reads the left limit at a jump (the end of an RK
    (sub-)step sees the delayed signal just before a delayed jump, the start just after it)."""
    r = math.floor(tau_steps + 0.5)
    if abs(tau_steps - r) < EDGE_EPS:
        tau_steps = r
    if tau_steps < 0.0 or (left and tau_steps <= 0.0):
        return vr0
    j = int(math.ceil(tau_steps)) - 1 if left else int(math.floor(tau_steps))
    if j >= k:  # inside the current step (TD shorter than a step): hold the right limit
        return vr_r[c, k % L]
    s = tau_steps - j
    q = j % L
    f = jf[c, q]
    if f > 0.0:
        if s < f - EDGE_EPS or (left and s <= f + EDGE_EPS):
            return vr_r[c, q] + (vjl[c, q] - vr_r[c, q]) * (s / f)
        return vjr[c, q] + (vr_l[c, (j + 1) % L] - vjr[c, q]) * ((s - f) / (1.0 - f))
    return vr_r[c, q] * (1.0 - s) + vr_l[c, (j + 1) % L] * s


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _hermite(y0, m0, y1, m1, s, h):
    s2 = s * s
    s3 = s2 * s
    return ((2 * s3 - 3 * s2 + 1) * y0 + (s3 - 2 * s2 + s) * h * m0
            + (-2 * s3 + 3 * s2) * y1 + (s3 - s2) * h * m1)


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _out_slope(D, i, ef, xf, eqp, eqpp, def_, dxf, other, st4):
    """The output's time derivative for the recorder-skew readout: `other` (the DC exciter's or
    the regulator lag's), or for the potential-source stage VB dVM/dt (VB's own slow change with
    Vt and Ifd left out; 0 while VM is at a limit)."""
    vt = _vt(D, i, eqp, eqpp)
    hi, lo = _limits(D, i, eqp, eqpp)
    f4, vm, ys, vb = _st4(D, i, ef, xf, vt, _ifd(D, i, eqp, eqpp, vt), hi, lo)
    kpm = D[D_KPM, i]
    sl = vb * (kpm * def_ + dxf) / (1.0 + kpm * D[D_KG, i] * vb)
    sl = sl if vm < D[D_VMMAX, i] else 0.0   # nested selects: `and` would branch (no vectorising)
    sl = sl if vm > D[D_VMMIN, i] else 0.0
    sl = sl if f4 < hi else 0.0
    sl = sl if f4 > lo else 0.0
    return sl if st4 == ST4_ALL else other + D[D_ST4, i] * (sl - other)


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _rk4(D, i, u0, u1, v0, vm, v1, x0, x1, x2, x3, x4, x5, x6, x7, h, st4=ST4_SOME):
    """One RK4 step of length h with input u0 -> u1 (linear) and delayed VR v0, vm, v1. Returns
    the 8 states and the output's derivative at both ends (the DC exciter's Efd, else VR lag)."""
    um = 0.5 * (u0 + u1)
    h2 = 0.5 * h
    a = _rhs(D, i, u0, v0, x0, x1, x2, x3, x4, x5, x6, x7, st4)
    b = _rhs(D, i, um, vm, x0 + h2 * a[0], x1 + h2 * a[1], x2 + h2 * a[2], x3 + h2 * a[3], x4 + h2 * a[4],
             x5 + h2 * a[5], x6 + h2 * a[6], x7 + h2 * a[7], st4)
    c = _rhs(D, i, um, vm, x0 + h2 * b[0], x1 + h2 * b[1], x2 + h2 * b[2], x3 + h2 * b[3], x4 + h2 * b[4],
             x5 + h2 * b[5], x6 + h2 * b[6], x7 + h2 * b[7], st4)
    d = _rhs(D, i, u1, v1, x0 + h * c[0], x1 + h * c[1], x2 + h * c[2], x3 + h * c[3], x4 + h * c[4],
             x5 + h * c[5], x6 + h * c[6], x7 + h * c[7], st4)
    h6 = h / 6.0
    y3 = x3 + h6 * (a[3] + 2 * b[3] + 2 * c[3] + d[3])
    y4 = x4 + h6 * (a[4] + 2 * b[4] + 2 * c[4] + d[4])
    y5 = x5 + h6 * (a[5] + 2 * b[5] + 2 * c[5] + d[5])
    if st4 != ST4_ALL:   # (ESST4B's lag is not limited)
        hi, lo = _limits(D, i, y4, y5)
        z3 = y3 if y3 > lo else lo
        z3 = z3 if z3 < hi else hi
        y3 = z3 + D[D_LIMOUT, i] * (y3 - z3)   # a lag that the ceilings do not limit winds up
    dcon = D[D_DCON, i]
    # the output's slope at both ends (for the recorder-skew readout): the DC exciter's or the
    # regulator lag's, or VB dVM/dt of the potential-source stage (at the end: at the state of
    # RK4's last stage, as for the others)
    m0 = a[3] + dcon * (a[7] - a[3])
    m1 = d[3] + dcon * (d[7] - d[3])
    if st4 != ST4_NONE:
        m0 = _out_slope(D, i, x3, x6, x4, x5, a[3], a[6], m0, st4)
        m1 = _out_slope(D, i, x3 + h * c[3], x6 + h * c[6], x4 + h * c[4], x5 + h * c[5], d[3], d[6], m1, st4)
    return (x0 + h6 * (a[0] + 2 * b[0] + 2 * c[0] + d[0]), x1 + h6 * (a[1] + 2 * b[1] + 2 * c[1] + d[1]),
            x2 + h6 * (a[2] + 2 * b[2] + 2 * c[2] + d[2]), y3, y4, y5,
            x6 + h6 * (a[6] + 2 * b[6] + 2 * c[6] + d[6]), x7 + h6 * (a[7] + 2 * b[7] + 2 * c[7] + d[7]),
            m0, m1)


def _fixed_view(rows: int):
    """An intrinsic: the view of a C-contiguous 2-D float array of `rows` x CHUNK elements with that
    shape as constants in the code (the caller checks the size). numba indexes a C array by its
    shape, and LLVM then sees every row a constant distance from the others."""
    @intrinsic
    def view(typingctx, ary):
        if not (isinstance(ary, types.Array) and ary.ndim == 2 and ary.layout == "C"):
            return None

        def codegen(context, builder, sig, args):
            src = make_array(ary)(context, builder, args[0])
            dst = make_array(ary)(context, builder)
            intp = context.get_value_type(types.intp)
            item = context.get_abi_sizeof(context.get_data_type(ary.dtype))
            populate_array(dst, data=src.data, shape=[intp(rows), intp(CHUNK)],
                           strides=[intp(CHUNK * item), intp(item)], itemsize=src.itemsize,
                           meminfo=src.meminfo, parent=src.parent)
            return impl_ret_borrowed(context, builder, ary, dst._getvalue())
        return ary(ary), codegen
    return view


_view_d, _view_s, _view_u, _view_v = (_fixed_view(r) for r in (N_DERIVED, 10, 2, 3))


@nb.njit(cache=True, inline="always", error_model="numpy")
def _fixed(D, S, U, V):
    """The chunk's arrays (derived factors, states, setpoint, delayed VR: N_DERIVED, 10, 2 and 3 rows
    of CHUNK columns) as views whose shape is a constant of the code. The RK4 loop reads ~50 rows
    and writes 10: with runtime row strides LLVM checks every written row against every other row
    for overlap before each call of the vectorised loop (~600 compares, 28 % of an ESST4B run in
    `perf`, once a step for only 32 candidates); with constant ones it checks each array once.
    See docs/decisions/0003."""
    if (D.shape[0] != N_DERIVED or S.shape[0] != 10 or U.shape[0] != 2 or V.shape[0] != 3
            or D.shape[1] != CHUNK or S.shape[1] != CHUNK or U.shape[1] != CHUNK or V.shape[1] != CHUNK):
        raise ValueError("kernel chunk arrays of the wrong shape")
    return _view_d(D), _view_s(S), _view_u(U), _view_v(V)


@nb.njit(cache=True, error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _rk4_all(D, S, U, V, dt, m):
    """One RK4 step for every candidate of a chunk: a branch-free loop LLVM vectorises across c.

    Only four arrays take part (D, V read; U = [u at start, u at end] read; S = 8 states plus the
    output's derivative at both ends, written), each seen with a constant shape (`_fixed`), so
    LLVM checks them for overlap once per array before the loop. Kept as its own function: inside
    the big chunk loop numba's reference counting of the array arguments stops the vectoriser."""
    D, S, U, V = _fixed(D, S, U, V)
    for c in range(m):
        r = _rk4(D, c, U[0, c], U[1, c], V[0, c], V[1, c], V[2, c], S[0, c], S[1, c], S[2, c], S[3, c],
                 S[4, c], S[5, c], S[6, c], S[7, c], dt, ST4_NONE)
        S[0, c] = r[0]; S[1, c] = r[1]; S[2, c] = r[2]; S[3, c] = r[3]; S[4, c] = r[4]; S[5, c] = r[5]
        S[6, c] = r[6]; S[7, c] = r[7]; S[8, c] = r[8]; S[9, c] = r[9]


@nb.njit(cache=True, error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _rk4_all_st4(D, S, U, V, dt, m):
    """`_rk4_all` with the potential-source stage selected per candidate (a chunk where some valid
    candidates have it and others not)."""
    D, S, U, V = _fixed(D, S, U, V)
    for c in range(m):
        r = _rk4(D, c, U[0, c], U[1, c], V[0, c], V[1, c], V[2, c], S[0, c], S[1, c], S[2, c], S[3, c],
                 S[4, c], S[5, c], S[6, c], S[7, c], dt, ST4_SOME)
        S[0, c] = r[0]; S[1, c] = r[1]; S[2, c] = r[2]; S[3, c] = r[3]; S[4, c] = r[4]; S[5, c] = r[5]
        S[6, c] = r[6]; S[7, c] = r[7]; S[8, c] = r[8]; S[9, c] = r[9]


@nb.njit(cache=True, error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _rk4_all_st4_only(D, S, U, V, dt, m):
    """`_rk4_all` of a chunk whose valid candidates all have the potential-source stage (ESST4B)."""
    D, S, U, V = _fixed(D, S, U, V)
    for c in range(m):
        r = _rk4(D, c, U[0, c], U[1, c], V[0, c], V[1, c], V[2, c], S[0, c], S[1, c], S[2, c], S[3, c],
                 S[4, c], S[5, c], S[6, c], S[7, c], dt, ST4_ALL)
        S[0, c] = r[0]; S[1, c] = r[1]; S[2, c] = r[2]; S[3, c] = r[3]; S[4, c] = r[4]; S[5, c] = r[5]
        S[6, c] = r[6]; S[7, c] = r[7]; S[8, c] = r[8]; S[9, c] = r[9]


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _limits_ref(D, i, eqp, eqpp):
    """`_limits` of the reference blocks only (no GENROU flux shares): the fast path.
    Exciter ceilings (hi, lo): VRMAX, VRMIN, scaled by Vt = E''q when VRVT = 1 (bus-fed), the
    upper one less KC*Ifd, Ifd = E'q + Sat(E'q) (the no-load field current on the air-gap base)."""
    d = eqp - D[D_SATA, i]
    d = d if d > 0.0 else 0.0
    ifd = eqp + D[D_SATB, i] * d * d
    sc = 1.0 + D[D_VRVT, i] * (eqpp - 1.0)
    sc = sc if sc > 1.0e-3 else 1.0e-3
    return D[D_VRMAX, i] * sc - D[D_KC, i] * ifd, D[D_VRMIN, i] * sc


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _rhs_ref(D, i, uref, vrd, xm, x1, x2, ef, eqp, eqpp):
    """`_rhs` of the reference blocks only (6 states): the fast path of a chunk none of whose
    candidates uses a block of the standard structures (`_needs_full`). Derivatives of (xm, x1, x2,
    efd, E'q, E''q); branch-free so candidate loops vectorise.

    `vrd` is the delayed VR (used when the candidate has a dead time, D_TDON = 1)."""
    tron = D[D_TRON, i]
    vm = tron * xm + (1.0 - tron) * eqpp
    e = uref - vm
    y1 = x1 + D[D_R1, i] * (e - x1)
    y2 = x2 + D[D_R2, i] * (y1 - x2)
    vr = D[D_KAVR, i] * y2
    dxm = (eqpp - xm) * D[D_ITR, i]
    dx1 = (e - x1) * D[D_IT2, i]
    dx2 = (y1 - x2) * D[D_IT4, i]
    tdon = D[D_TDON, i]
    drive = vr + tdon * (vrd - vr)
    # plain compare-and-select (numba's min/max carry NaN branches that stop the vectoriser)
    rate = D[D_RATE, i]
    de = (drive - ef) * D[D_ITE, i]
    de = de if de < rate else rate
    de = de if de > -rate else -rate
    d = eqp - D[D_SATA, i]
    d = d if d > 0.0 else 0.0
    deqp = (ef - eqp - D[D_SATB, i] * d * d) * D[D_ITD0P, i]
    deqpp = (eqp - eqpp) * D[D_ITD0PP, i]
    # non-windup ceiling: at a limit efd may not pass it, and follows it where it moves (with Vt
    # for a bus-fed exciter, with Ifd through the commutation drop); fixed limits do not move
    hi, lo = _limits_ref(D, i, eqp, eqpp)
    dsc = D[D_VRVT, i] * deqpp
    dhi = D[D_VRMAX, i] * dsc - D[D_KC, i] * (1.0 + 2.0 * D[D_SATB, i] * d) * deqp
    dlo = D[D_VRMIN, i] * dsc
    dhi = dhi if dhi == dhi else 0.0  # inf * 0 (no ceiling, fixed limits) is no movement
    dlo = dlo if dlo == dlo else 0.0
    de = (de if de < dhi else dhi) if ef >= hi else de
    de = (de if de > dlo else dlo) if ef <= lo else de
    return dxm, dx1, dx2, de, deqp, deqpp


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _rk4_ref(D, i, u0, u1, v0, vm, v1, x0, x1, x2, x3, x4, x5, h):
    """`_rk4` on the reference blocks only (see `_rhs_ref`)."""
    um = 0.5 * (u0 + u1)
    h2 = 0.5 * h
    a = _rhs_ref(D, i, u0, v0, x0, x1, x2, x3, x4, x5)
    b = _rhs_ref(D, i, um, vm, x0 + h2 * a[0], x1 + h2 * a[1], x2 + h2 * a[2], x3 + h2 * a[3], x4 + h2 * a[4], x5 + h2 * a[5])
    c = _rhs_ref(D, i, um, vm, x0 + h2 * b[0], x1 + h2 * b[1], x2 + h2 * b[2], x3 + h2 * b[3], x4 + h2 * b[4], x5 + h2 * b[5])
    d = _rhs_ref(D, i, u1, v1, x0 + h * c[0], x1 + h * c[1], x2 + h * c[2], x3 + h * c[3], x4 + h * c[4], x5 + h * c[5])
    h6 = h / 6.0
    y3 = x3 + h6 * (a[3] + 2 * b[3] + 2 * c[3] + d[3])
    y4 = x4 + h6 * (a[4] + 2 * b[4] + 2 * c[4] + d[4])
    y5 = x5 + h6 * (a[5] + 2 * b[5] + 2 * c[5] + d[5])
    hi, lo = _limits_ref(D, i, y4, y5)
    y3 = y3 if y3 > lo else lo
    y3 = y3 if y3 < hi else hi
    return (x0 + h6 * (a[0] + 2 * b[0] + 2 * c[0] + d[0]), x1 + h6 * (a[1] + 2 * b[1] + 2 * c[1] + d[1]),
            x2 + h6 * (a[2] + 2 * b[2] + 2 * c[2] + d[2]), y3, y4, y5, a[3], d[3])


@nb.njit(cache=True, error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _rk4_all_ref(D, S, U, V, dt, m):
    """`_rk4_all` on the reference blocks only: states 6, 7 (rate feedback, DC exciter) untouched."""
    D, S, U, V = _fixed(D, S, U, V)
    for c in range(m):
        r = _rk4_ref(D, c, U[0, c], U[1, c], V[0, c], V[1, c], V[2, c], S[0, c], S[1, c], S[2, c], S[3, c],
                     S[4, c], S[5, c], dt)
        S[0, c] = r[0]; S[1, c] = r[1]; S[2, c] = r[2]; S[3, c] = r[3]; S[4, c] = r[4]; S[5, c] = r[5]
        S[8, c] = r[6]; S[9, c] = r[7]


@nb.njit(cache=True, error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _split_step(D, c, k, dt, S, S0, nbrk, bs, bj, target, uref, base, td_on, L, vr_r, vr_l, jf, vjl, vjr,
                skew_on, Ls, kf, kef, kdl, kdr):
    """Step k of candidate c from the state S0 at t_k, in RK4 sub-steps between the break points
    bs[:nbrk] (sorted fractions of the step in (0, 1)): where the setpoint jumps inside the step
    (a fitted edge instant, the target jumps by bj there) and where the delayed VR jumps (the
    delayed sample boundary, a delayed setpoint jump). Writes the state at t_k+1 into S; returns
    (setpoint reference at t_k+1, efd' at t_k, efd' at t_k+1). With `skew_on` the efd kink at
    the (first) setpoint jump is kept for the recorder-skew readout (`kf`, `kef`, `kdl`, `kdr`)."""
    x0, x1, x2, x3, x4, x5, x6, x7 = S0[0, c], S0[1, c], S0[2, c], S0[3, c], S0[4, c], S0[5, c], S0[6, c], S0[7, c]
    ramp = D[D_RAMP, c]
    ramp_on = ramp < 1.0e300
    e0 = D[D_EFD0, c]
    tg = target
    ur = uref
    sa = 0.0
    d_start = 0.0
    d_end = 0.0
    first = True
    pending = False
    for q in range(nbrk + 1):
        sb = bs[q] if q < nbrk else 1.0
        h = (sb - sa) * dt
        if h > 1.0e-12 * dt:
            if ramp_on:
                ua = ur
                st = tg - ur
                lim = ramp * h
                st = st if st < lim else lim
                st = st if st > -lim else -lim
                ub = ur + st
            else:
                ua = tg
                ub = tg
            va = 0.0
            vm = 0.0
            vb = 0.0
            if td_on:
                va = _delayed(vr_r, vr_l, jf, vjl, vjr, c, L, base + sa, k, e0, False)
                vm = _delayed(vr_r, vr_l, jf, vjl, vjr, c, L, base + 0.5 * (sa + sb), k, e0, False)
                vb = _delayed(vr_r, vr_l, jf, vjl, vjr, c, L, base + sb, k, e0, True)
            r = _rk4(D, c, ua, ub, va, vm, vb, x0, x1, x2, x3, x4, x5, x6, x7, h)
            x0, x1, x2, x3, x4, x5, x6, x7 = r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7]
            if first:
                d_start = r[8]
                first = False
            if pending:
                kdr[c, k % Ls] = r[8]
                pending = False
            d_end = r[9]
            ur = ub
        if q < nbrk and bj[q] != 0.0:
            if td_on and not ramp_on:  # VR jumps here: keep both limits for the delayed reads
                vmeas = x0 if D[D_ITR, c] > 0.0 else _vt(D, c, x4, x5)
                vf = _vf(D, c, x3, x6, x7)
                vjl[c, k % L] = _avr(D, c, tg, vmeas, x1, x2, vf)[0]
                vjr[c, k % L] = _avr(D, c, tg + bj[q], vmeas, x1, x2, vf)[0]
                jf[c, k % L] = sb
            if skew_on and kf[c, k % Ls] == 0.0 and not first:
                kf[c, k % Ls] = sb
                kef[c, k % Ls] = _field(D, c, x3, x4, x5, x6, x7)
                kdl[c, k % Ls] = d_end
                pending = True
            tg += bj[q]
        sa = sb
    S[0, c] = x0; S[1, c] = x1; S[2, c] = x2; S[3, c] = x3; S[4, c] = x4; S[5, c] = x5
    S[6, c] = x6; S[7, c] = x7
    return (ur if ramp_on else tg), d_start, d_end


@nb.njit(cache=True, error_model="numpy", fastmath={"contract", "arcp", "reassoc", "afn"})
def _run_chunk(D, lo, hi, usetp, usetp_pre, dt, L, Ls, efd_meas, vt_meas, w_efd, w_vt,
               store, any_delay, any_skew, any_ramp, efd_out, vt_out, sse_efd, sse_vt, obj, fail_step,
               eidx, ejump, etn, eslot, ewin):
    T = usetp.shape[0]
    m = hi - lo
    # the RK4 loops see every array with CHUNK columns (`_fixed`); columns m.. are never used
    Dm = D
    D = np.zeros((Dm.shape[0], CHUNK))
    D[:, :m] = Dm
    S = np.zeros((10, CHUNK))       # states xm, x1, x2, VR lag, E'q, E''q, rate feedback, DC Efd;
    #                                 the output's derivative at step start, end
    S0 = np.empty((8, m))           # state at t_k, kept for split steps
    uref = np.empty(m)
    U = np.zeros((2, CHUNK))        # setpoint reference at the start and the end of the step
    ua = U[0]
    ub = U[1]
    V = np.zeros((3, CHUNK))        # delayed VR at stage times 0, 1/2, 1
    failed = np.zeros(m, np.bool_)
    e_first = np.zeros(m); e_last = np.zeros(m)
    out_e = np.zeros(m)
    vr_r = np.zeros((m, L)); vr_l = np.zeros((m, L))  # VR right/left limits per step (dead time)
    jf = np.zeros((m, L)); vjl = np.zeros((m, L)); vjr = np.zeros((m, L))  # a jump inside a step
    ne = eidx.shape[0]
    tg0 = np.empty(m)
    cross = np.zeros(m, np.bool_)
    bs = np.empty(ne + 3)
    bj = np.empty(ne + 3)
    ef_h = np.zeros((m, Ls)); der_r = np.zeros((m, Ls)); der_l = np.zeros((m, Ls))  # efd history (skew)
    kf = np.zeros((m, Ls)); kef = np.zeros((m, Ls)); kdl = np.zeros((m, Ls)); kdr = np.zeros((m, Ls))
    for c in range(m):
        i = lo + c
        vt0 = D[D_VT0, c]
        S[0, c] = vt0; S[4, c] = vt0; S[5, c] = vt0
        S[3, c] = D[D_EFD0, c]
        S[1, c] = D[D_E0, c]; S[2, c] = D[D_E0, c]
        S[6, c] = D[D_XF0, c]
        S[7, c] = D[D_OUT0, c]
        uref[c] = D[D_UREF0, c]
        out_e[c] = D[D_GAIN, c] * D[D_OUT0, c]
        if D[D_VALID, c] == 0.0:
            failed[c] = True
            fail_step[i] = 0
        for q in range(L):
            vr_r[c, q] = D[D_EFD0, c]; vr_l[c, q] = D[D_EFD0, c]
        for q in range(Ls):
            ef_h[c, q] = D[D_OUT0, c]
    # the full blocks when some candidate of the chunk uses a block of the standard structures
    # and the potential-source stage: where some candidate has it, or for all (an invalid candidate,
    # failed from the start, does not count: what it computes is not used)
    full = False
    st4 = False
    st4_all = True
    for c in range(m):
        if (D[D_KFT, c] != 0.0 or D[D_DCON, c] != 0.0 or D[D_LIMOUT, c] != 0.0 or D[D_KPP, c] != 0.0
                or D[D_KDA, c] != 0.0 or D[D_ST4, c] != 0.0):
            full = True
        if D[D_ST4, c] != 0.0:
            st4 = True
        if D[D_VALID, c] != 0.0 and (D[D_ST4, c] == 0.0 or D[D_LIMOUT, c] == 0.0 or D[D_DCON, c] != 0.0):
            st4_all = False
    for k in range(T):
        # ---- record sample k (states at t_k); failed candidates hold their last output ----
        if any_skew:
            for c in range(m):
                i = lo + c
                skew = D[D_SKEW, c]
                y = _field(D, c, S[3, c], S[4, c], S[5, c], S[6, c], S[7, c])
                if skew > 0.0:
                    tau = k - skew / dt
                    if tau <= 0.0:
                        y = D[D_OUT0, c]
                    else:
                        j = int(math.floor(tau))
                        if j < k:
                            q = j % Ls
                            s = tau - j
                            f = kf[c, q]
                            if f <= 0.0:
                                y = _hermite(ef_h[c, q], der_r[c, q], ef_h[c, (j + 1) % Ls],
                                             der_l[c, (j + 1) % Ls], s, dt)
                            elif s < f:  # a setpoint jump inside that step: the efd kink kept
                                y = _hermite(ef_h[c, q], der_r[c, q], kef[c, q], kdl[c, q], s / f, f * dt)
                            else:
                                y = _hermite(kef[c, q], kdr[c, q], ef_h[c, (j + 1) % Ls],
                                             der_l[c, (j + 1) % Ls], (s - f) / (1.0 - f), (1.0 - f) * dt)
                if not failed[c]:
                    out_e[c] = D[D_GAIN, c] * y
        else:
            for c in range(m):
                if not failed[c]:
                    out_e[c] = D[D_GAIN, c] * _field(D, c, S[3, c], S[4, c], S[5, c], S[6, c], S[7, c])
        if store:
            for c in range(m):
                efd_out[lo + c, k] = out_e[c]
                vt_out[lo + c, k] = _vt(D, c, S[4, c], S[5, c])
        if w_efd > 0.0:
            em = efd_meas[k]
            for c in range(m):
                d = out_e[c] - em
                sse_efd[lo + c] += d * d
            if k == 0 or k == T - 1:
                for c in range(m):
                    d = out_e[c] - em
                    if k == 0:
                        e_first[c] += w_efd * d * d
                    else:
                        e_last[c] += w_efd * d * d
        if w_vt > 0.0:
            vmeas = vt_meas[k]
            for c in range(m):
                d = _vt(D, c, S[4, c], S[5, c]) - vmeas
                sse_vt[lo + c] += d * d
            if k == 0 or k == T - 1:
                for c in range(m):
                    d = _vt(D, c, S[4, c], S[5, c]) - vmeas
                    if k == 0:
                        e_first[c] += w_vt * d * d
                    else:
                        e_last[c] += w_vt * d * d
        if k == T - 1:
            break
        # ---- setpoint over [t_k, t_k+1): ZOH target (each edge moved to its fitted instant),
        # or a ramp towards it ----
        base_u = usetp[k] - usetp_pre
        for c in range(m):
            tg0[c] = D[D_UREF0, c] + base_u
        inwin = ne > 0 and ewin[k] != 0
        if inwin:
            for c in range(m):
                corr = 0.0
                cr = False
                for j in range(ne):
                    ke = (etn[j] + D[D_EDGE0 + eslot[j], c]) / dt
                    fit_on = 1.0 if ke <= k + EDGE_EPS else 0.0
                    nom_on = 1.0 if k >= eidx[j] else 0.0
                    corr += ejump[j] * (fit_on - nom_on)
                    if k + EDGE_EPS < ke < k + 1.0 - EDGE_EPS:
                        cr = True
                tg0[c] += corr
                cross[c] = cr
        for c in range(m):
            ua[c] = tg0[c]
            ub[c] = tg0[c]
        if any_ramp:
            for c in range(m):
                i = lo + c
                ramp = D[D_RAMP, c]
                if ramp < 1.0e300:
                    step = min(max(ub[c] - uref[c], -ramp * dt), ramp * dt)
                    ua[c] = uref[c]
                    ub[c] = uref[c] + step
        # ---- dead time: VR right limit at t_k, delayed VR at the stage times ----
        if any_delay:
            for c in range(m):
                i = lo + c
                td = D[D_TD, c]
                if td > 0.0:
                    vm0 = S[0, c] if D[D_ITR, c] > 0.0 else _vt(D, c, S[4, c], S[5, c])
                    vf = _vf(D, c, S[3, c], S[6, c], S[7, c])
                    vr_r[c, k % L] = _avr(D, c, ua[c], vm0, S[1, c], S[2, c], vf)[0]
                    jf[c, k % L] = 0.0
                    base = k - td / dt
                    V[0, c] = _delayed(vr_r, vr_l, jf, vjl, vjr, c, L, base, k, D[D_EFD0, c], False)
                    V[1, c] = _delayed(vr_r, vr_l, jf, vjl, vjr, c, L, base + 0.5, k, D[D_EFD0, c], False)
                    V[2, c] = _delayed(vr_r, vr_l, jf, vjl, vjr, c, L, base + 1.0, k, D[D_EFD0, c], True)
        # ---- RK4 step, one fused straight-line body per candidate (vectorises across c) ----
        if any_skew:
            for c in range(m):
                ef_h[c, k % Ls] = _field(D, c, S[3, c], S[4, c], S[5, c], S[6, c], S[7, c])
                kf[c, k % Ls] = 0.0
        if any_delay or inwin:
            for c in range(m):
                for q in range(8):
                    S0[q, c] = S[q, c]
        if st4 and st4_all:
            _rk4_all_st4_only(D, S, U, V, dt, m)
        elif st4:
            _rk4_all_st4(D, S, U, V, dt, m)
        elif full:
            _rk4_all(D, S, U, V, dt, m)
        else:
            _rk4_all_ref(D, S, U, V, dt, m)
        for c in range(m):
            uref[c] = ub[c]
        # ---- steps with a jump inside: the setpoint at a fitted edge instant, the delayed VR at
        # a delay that is not a whole number of steps; such a step is redone from t_k in
        # sub-steps between the jumps ----
        if any_delay or inwin:
            for c in range(m):
                if failed[c]:
                    continue
                nbrk = 0
                if inwin and cross[c]:
                    for j in range(ne):
                        ke = (etn[j] + D[D_EDGE0 + eslot[j], c]) / dt
                        if k + EDGE_EPS < ke < k + 1.0 - EDGE_EPS:
                            bs[nbrk] = ke - k
                            bj[nbrk] = ejump[j]
                            nbrk += 1
                td = D[D_TD, c]
                base = 0.0
                td_on = any_delay and td > 0.0
                if td_on:
                    base = k - td / dt
                    j0 = int(math.floor(base))
                    frac = base - j0
                    if j0 + 1 < k:
                        if frac >= EDGE_EPS:
                            bs[nbrk] = 1.0 - frac
                            bj[nbrk] = 0.0
                            nbrk += 1
                        if j0 >= 0:
                            f = jf[c, j0 % L]
                            if f > frac + EDGE_EPS:
                                bs[nbrk] = f - frac
                                bj[nbrk] = 0.0
                                nbrk += 1
                        if j0 + 1 >= 0:
                            f = jf[c, (j0 + 1) % L]
                            if f > 0.0 and f < frac - EDGE_EPS:
                                bs[nbrk] = 1.0 - frac + f
                                bj[nbrk] = 0.0
                                nbrk += 1
                if nbrk == 0:
                    continue
                for a in range(1, nbrk):  # insertion sort of the few break points
                    sv = bs[a]
                    jv = bj[a]
                    b = a - 1
                    while b >= 0 and bs[b] > sv:
                        bs[b + 1] = bs[b]
                        bj[b + 1] = bj[b]
                        b -= 1
                    bs[b + 1] = sv
                    bj[b + 1] = jv
                r = _split_step(D, c, k, dt, S, S0, nbrk, bs, bj, tg0[c], ua[c], base, td_on, L,
                                vr_r, vr_l, jf, vjl, vjr, any_skew, Ls, kf, kef, kdl, kdr)
                uref[c] = r[0]
                ub[c] = r[0]
                S[8, c] = r[1]
                S[9, c] = r[2]
        if any_skew:
            for c in range(m):
                der_r[c, k % Ls] = S[8, c]
                der_l[c, (k + 1) % Ls] = S[9, c]
        for c in range(m):
            i = lo + c
            mag = (abs(S[0, c]) + abs(S[1, c]) + abs(S[2, c]) + abs(S[3, c]) + abs(S[4, c]) + abs(S[5, c])
                   + abs(S[6, c]) + abs(S[7, c]))
            if not (mag < BLOWUP):
                if not failed[c]:
                    failed[c] = True
                    fail_step[i] = k + 1
                # park the state at the steady state so the arithmetic stays finite
                S[0, c] = D[D_VT0, c]; S[4, c] = D[D_VT0, c]; S[5, c] = D[D_VT0, c]
                S[3, c] = D[D_EFD0, c]; S[1, c] = D[D_E0, c]; S[2, c] = D[D_E0, c]
                S[6, c] = D[D_XF0, c]
                S[7, c] = D[D_OUT0, c]
        if any_skew:
            for c in range(m):
                ef_h[c, (k + 1) % Ls] = _field(D, c, S[3, c], S[4, c], S[5, c], S[6, c], S[7, c])
        if any_delay:
            for c in range(m):
                i = lo + c
                if D[D_TD, c] > 0.0:  # left limit of VR at t_k+1 (state k+1, input of step k)
                    vm = S[0, c] if D[D_ITR, c] > 0.0 else _vt(D, c, S[4, c], S[5, c])
                    vf = _vf(D, c, S[3, c], S[6, c], S[7, c])
                    vr_l[c, (k + 1) % L] = _avr(D, c, ub[c], vm, S[1, c], S[2, c], vf)[0]
    for c in range(m):
        i = lo + c
        obj[i] = dt * (w_efd * sse_efd[i] + w_vt * sse_vt[i] - 0.5 * (e_first[c] + e_last[c]))


@nb.njit(cache=True, parallel=True, error_model="numpy")
def _run(D, usetp, usetp_pre, dt, L, Ls, efd_meas, vt_meas, w_efd, w_vt, store, chunk,
         any_delay, any_skew, any_ramp, efd_out, vt_out, sse_efd, sse_vt, obj, fail_step,
         eidx, ejump, etn, eslot, ewin):
    n = D.shape[1]
    nchunks = (n + chunk - 1) // chunk
    for b in nb.prange(nchunks):
        lo = b * chunk
        hi = min(n, lo + chunk)
        _run_chunk(np.ascontiguousarray(D[:, lo:hi]), lo, hi, usetp, usetp_pre, dt, L, Ls, efd_meas, vt_meas, w_efd, w_vt,
                   store, any_delay, any_skew, any_ramp, efd_out, vt_out, sse_efd, sse_vt, obj, fail_step,
                   eidx, ejump, etn, eslot, ewin)


def _edge_window(D: np.ndarray, edges: EdgeSpec, dt: float, T: int) -> np.ndarray:
    """1 for every step where some candidate's setpoint differs from the zero-order hold of the
    record (between an edge's nominal and fitted instants) or jumps inside the step."""
    win = np.zeros(T, dtype=np.uint8)
    for j in range(edges.n):
        ke = (edges.nominal_s[j] + D[:, D_EDGE0 + edges.slot[j]]) / dt
        lo = int(math.floor(min(float(ke.min()), float(edges.index[j])))) - 1
        hi = int(math.ceil(max(float(ke.max()), float(edges.index[j])))) + 1
        win[max(0, lo): max(0, min(T, hi + 1))] = 1
    return win


def run_kernel(P: np.ndarray, usetp: np.ndarray, dt: float, usetp_pre: float, *,
               efd_meas: np.ndarray | None = None, vt_meas: np.ndarray | None = None,
               w_efd: float = 1.0, w_vt: float = 0.0, store: bool = True, chunk: int | None = None,
               edges: EdgeSpec | None = None):
    """Run the kernel on a parameter matrix P (n, len(KERNEL_PARAMS)).

    `edges`: the record's setpoint edges; each moves to its nominal instant plus the candidate's
    offset in column EDGE1.. (slot) of P, the step it falls in split there. None: every change
    of usetp acts at the sample that shows it (zero-order hold).

    Returns a dict with `efd`, `vt` (n, T) traces when `store`, and when measurements are given
    `obj` (trapezoidal integral of the weighted squared error), `sse_efd`, `sse_vt` (sums of
    squared sample errors) and always `fail_step` (-1 for candidates that did not fail).
    """
    D = derive(P)
    n = D.shape[0]
    usetp = np.ascontiguousarray(usetp, dtype=np.float64)
    T = usetp.shape[0]
    if T < 2:
        raise ValueError("a simulation needs at least two samples")
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"time step {dt!r} must be positive")
    td_max = float(np.max(D[:, D_TD])) if n else 0.0
    sk_max = float(np.max(D[:, D_SKEW])) if n else 0.0
    L = int(math.ceil(td_max / dt)) + 3 if td_max > 0 else 1
    Ls = int(math.ceil(sk_max / dt)) + 3 if sk_max > 0 else 1
    have_efd = efd_meas is not None
    have_vt = vt_meas is not None
    em = np.ascontiguousarray(efd_meas if have_efd else np.zeros(T), dtype=np.float64)
    vm = np.ascontiguousarray(vt_meas if have_vt else np.zeros(T), dtype=np.float64)
    if em.shape[0] != T or vm.shape[0] != T:
        raise ValueError("measured signals must have the same length as usetp")
    we = float(w_efd) if have_efd else 0.0
    wv = float(w_vt) if have_vt else 0.0
    shape = (n, T) if store else (1, 1)
    efd_out = np.zeros(shape)
    vt_out = np.zeros(shape)
    sse_efd = np.zeros(n)
    sse_vt = np.zeros(n)
    obj = np.zeros(n)
    fail_step = np.full(n, -1, dtype=np.int64)
    if chunk is None:
        # fixed, not from the thread count: a candidate then sits at the same place of its chunk
        # (vectorised body or remainder loop, which fastmath may round differently) however many
        # threads run, so a result is bit-identical alone, in a batch worker, on any machine
        chunk = CHUNK
    if not 1 <= int(chunk) <= CHUNK:
        raise ValueError(f"chunk={chunk!r}: the kernel runs 1 to {CHUNK} candidates a chunk")
    edges = EdgeSpec.none() if edges is None else edges
    if edges.n and int(edges.index.max()) >= T:
        raise ValueError(f"edge at sample {int(edges.index.max())} lies beyond the record ({T} samples)")
    earr = (edges.index, edges.jump, edges.nominal_s, edges.slot)
    if n:
        any_ramp = bool(np.any(D[:, D_RAMP] < 1.0e300))
        Dt = np.ascontiguousarray(D.T)
        ewin = _edge_window(D, edges, float(dt), T) if edges.n else np.zeros(T, dtype=np.uint8)
        if n <= chunk:  # one chunk: waking the thread pool costs more than it saves (measured)
            _run_chunk(Dt, 0, n, usetp, float(usetp_pre), float(dt), L, Ls, em, vm, we, wv, bool(store),
                       td_max > 0, sk_max > 0, any_ramp, efd_out, vt_out, sse_efd, sse_vt, obj, fail_step,
                       *earr, ewin)
        else:
            _run(Dt, usetp, float(usetp_pre), float(dt), L, Ls, em, vm, we, wv, bool(store), int(chunk),
                 td_max > 0, sk_max > 0, any_ramp, efd_out, vt_out, sse_efd, sse_vt, obj, fail_step,
                 *earr, ewin)
    out = {"fail_step": fail_step}
    if store:
        out["efd"] = efd_out
        out["vt"] = vt_out
    if have_efd or have_vt:
        out["obj"] = obj
        out["sse_efd"] = sse_efd
        out["sse_vt"] = sse_vt
    return out


def column(name: str) -> int:
    return COL[name]
