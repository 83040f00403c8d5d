"""Per-candidate factors of the kernel (the derived matrix, columns `layout.D_*`), in numpy, once a
call: each block's factors, then the steady state the run starts from.

An invalid candidate (a parameter outside what the kernel can run) gets harmless factors and
D_VALID = 0: the kernel marks it failed at step 0.
"""
from __future__ import annotations

import numpy as np

from ..params import KERNEL_PARAMS, RECORD_PARAMS
from .layout import (
    D_DCON,
    D_E0,
    D_EDGE0,
    D_EFD0,
    D_GAIN,
    D_IT2,
    D_IT4,
    D_ITD0P,
    D_ITD0PP,
    D_ITE,
    D_ITEX,
    D_ITF,
    D_ITR,
    D_KAVR,
    D_KC,
    D_KDA,
    D_KE,
    D_KFT,
    D_KG,
    D_KI1,
    D_KIM,
    D_KPM,
    D_KPP,
    D_KPV,
    D_LIMOUT,
    D_OUT0,
    D_P1,
    D_R1,
    D_R2,
    D_RAMP,
    D_RATE,
    D_SATA,
    D_SATB,
    D_SATVT,
    D_SEA,
    D_SEB,
    D_SKEW,
    D_ST4,
    D_TD,
    D_TDON,
    D_TRON,
    D_UREF0,
    D_VALID,
    D_VBMAX,
    D_VMMAX,
    D_VMMIN,
    D_VRMAX,
    D_VRMIN,
    D_VRVT,
    D_VT0,
    D_XF0,
    D_Y1MAX,
    D_Y1MIN,
    N_DERIVED,
)

Params = dict[str, np.ndarray]


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


def bridge_voltage_np(ve: np.ndarray, kc_ifd: np.ndarray, vbmax: np.ndarray) -> np.ndarray:
    """VB = VE FEX(KC Ifd / VE), at most VBMAX (numpy twin of `bridge_voltage`)."""
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
    D = np.zeros((P.shape[0], N_DERIVED))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        valid = _valid(g)
        D[:, D_VALID] = valid.astype(np.float64)
        vt0, fld0 = _generator(D, g, valid)
        dc = _dc_exciter(D, g, valid)
        st4 = _potential_source(D, g, valid, dc)
        _regulator(D, g, valid, st4)
        _rate_feedback(D, g, valid)
        _effects(D, g, valid, dc)
        _steady_state(D, g, valid, dc, st4, vt0, fld0)
    return D


def _valid(g: Params) -> np.ndarray:
    """The candidates the kernel can run: time constants, gains and limits in their domain."""
    valid = np.ones(len(g["KAVR"]), bool)
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
    return valid


def _safe(valid: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.where(valid, x, 1.0)


def _generator(D: np.ndarray, g: Params, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The generator at no load (time constants, saturation, GENROU-like flux shares); returns Vt0
    and the field voltage it needs at the steady state."""
    a, b = saturation_ab(g["S10"], g["S12"])
    vt0 = _safe(valid, g["Vt0"])
    sat0 = np.where(vt0 > a, b * (vt0 - a) ** 2, 0.0)
    D[:, D_ITD0P] = _safe(valid, 1.0 / g["Td0p"])
    D[:, D_ITD0PP] = _safe(valid, 1.0 / g["Td0pp"])
    D[:, D_SATA] = a
    D[:, D_SATB] = b
    D[:, D_VT0] = vt0
    D[:, D_KPP] = np.where(valid, g["KPP"], 0.0)
    D[:, D_SATVT] = (D[:, D_KPP] > 0.0).astype(np.float64)
    D[:, D_KDA] = np.where(valid, g["KDA"], 0.0)
    return vt0, vt0 + sat0


def _dc_exciter(D: np.ndarray, g: Params, valid: np.ndarray) -> np.ndarray:
    """The DC exciter (TEX > 0): 1 / TEX, KE, its saturation; returns where it is on."""
    dc = valid & (g["TEX"] > 0.0)
    sea, seb = exciter_saturation_ab(g["E1"], g["SE1"], g["E2"], g["SE2"])
    D[:, D_ITEX] = np.where(dc, 1.0 / np.where(dc, g["TEX"], 1.0), 0.0)
    D[:, D_DCON] = dc.astype(np.float64)
    D[:, D_KE] = np.where(dc, g["KE"], 0.0)
    D[:, D_SEA] = np.where(dc, sea, 0.0)
    D[:, D_SEB] = np.where(dc, seb, 0.0)
    return dc


def _potential_source(D: np.ndarray, g: Params, valid: np.ndarray, dc: np.ndarray) -> np.ndarray:
    """The potential-source stage (ESST4B: KP > 0, no DC exciter): the PI regulator in place of
    lead-lag 1, the bridge (KP, VBMAX), the inner PI and KG; neutral elsewhere. Returns where on."""
    st4 = valid & ~dc & (g["KPV"] > 0.0)
    D[:, D_ST4] = st4.astype(np.float64)
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
    return st4


def _regulator(D: np.ndarray, g: Params, valid: np.ndarray, st4: np.ndarray) -> None:
    """The AVR: gain, lead-lags (the first replaced by the PI where the potential-source stage is
    on), the regulator lag."""
    D[:, D_KAVR] = _safe(valid, g["KAVR"])
    D[:, D_R1] = np.where(st4, 0.0, _safe(valid, g["TA1"] / g["TA2"]))
    D[:, D_IT2] = np.where(st4, 0.0, _safe(valid, 1.0 / g["TA2"]))
    D[:, D_R2] = _safe(valid, g["TA3"] / g["TA4"])
    D[:, D_IT4] = _safe(valid, 1.0 / g["TA4"])
    D[:, D_ITE] = _safe(valid, 1.0 / g["TE"])


def _rate_feedback(D: np.ndarray, g: Params, valid: np.ndarray) -> None:
    """Rate feedback KF s / (1 + s TF): KF / TF and 1 / TF, 0 without (KF = 0)."""
    fb = valid & (g["KF"] > 0.0)
    D[:, D_KFT] = np.where(fb, g["KF"] / np.where(fb, g["TF"], 1.0), 0.0)
    D[:, D_ITF] = np.where(fb, 1.0 / np.where(fb, g["TF"], 1.0), 0.0)


def _effects(D: np.ndarray, g: Params, valid: np.ndarray, dc: np.ndarray) -> None:
    """The ceilings (and whether they clamp the output), transducer lag, dead time, slew limit,
    setpoint ramp, recorder gain and skew, the setpoint edges' offsets."""
    D[:, D_VRMAX] = g["VRMAX"]
    D[:, D_VRMIN] = g["VRMIN"]
    D[:, D_VRVT] = np.where(valid, g["VRVT"], 0.0)
    D[:, D_KC] = np.where(valid, g["KC"], 0.0)
    D[:, D_LIMOUT] = np.where(valid & ~dc, g["LIMOUT"] > 0.5, False).astype(np.float64)
    D[:, D_ITR] = np.where(valid & (g["TR"] > 0.0), 1.0 / np.where(g["TR"] > 0, g["TR"], 1.0), 0.0)
    D[:, D_TRON] = (D[:, D_ITR] > 0.0).astype(np.float64)
    D[:, D_TD] = np.where(valid, g["TD"], 0.0)
    D[:, D_TDON] = (D[:, D_TD] > 0.0).astype(np.float64)
    D[:, D_RATE] = g["RATE"]
    D[:, D_RAMP] = g["RAMP"]
    D[:, D_GAIN] = np.where(valid, g["GAIN"], 1.0)
    D[:, D_SKEW] = np.where(valid, g["SKEW"], 0.0)
    for slot, name in enumerate(RECORD_PARAMS):
        D[:, D_EDGE0 + slot] = np.where(valid, g[name], 0.0)


def _steady_state(D: np.ndarray, g: Params, valid: np.ndarray, dc: np.ndarray, st4: np.ndarray,
                  vt0: np.ndarray, fld0: np.ndarray) -> None:
    """The steady state at Vt0 the run starts from (`blocks.steady_state`): the regulator lag's
    output, the lead-lags' states, the reference, the output, the rate feedback's state. A DC
    exciter needs VR = (KE + SE(Efd)) Efd from the regulator, a static one Efd itself; the
    potential-source stage Efd = VB VM, its regulator's error 0 and its PI and lag at KG Efd, the
    inner integrator at Efd / VB (as ANDES initialises it)."""
    efd0 = np.where(dc, D[:, D_KE] * fld0 + D[:, D_SEB] * np.maximum(fld0 - D[:, D_SEA], 0.0) ** 2, fld0)
    vb0 = bridge_voltage_np(np.where(st4, g["KPV"], 1.0) * vt0, np.where(valid, g["KC"], 0.0) * fld0, g["VBMAX"])
    efd0 = np.where(st4, np.where(st4, g["KG"], 0.0) * fld0, efd0)
    # Ifd = E'q + Sat(E'q) = efd0, the limits at Vt0
    scale0 = 1.0 + D[:, D_VRVT] * (vt0 - 1.0)
    hi0 = g["VRMAX"] * scale0 - D[:, D_KC] * efd0
    lo0 = g["VRMIN"] * scale0
    D[:, D_EFD0] = np.clip(efd0, lo0, np.maximum(hi0, lo0))
    D[:, D_E0] = D[:, D_EFD0] / D[:, D_KAVR]
    D[:, D_UREF0] = vt0 + np.where(st4, 0.0, D[:, D_E0])
    # the output: the DC exciter's Efd, VB VM of the potential source, else the regulator output
    D[:, D_OUT0] = np.where(st4, fld0, np.where(dc, fld0, D[:, D_EFD0]))
    D[:, D_XF0] = np.where(st4, fld0 / np.where(st4, vb0, 1.0),
                           D[:, D_EFD0] + D[:, D_DCON] * (D[:, D_OUT0] - D[:, D_EFD0]))
