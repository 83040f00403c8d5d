"""The unit on the grid: a GENROU synchronised through a reactance XE (and a resistance RE) to an
infinite bus, with both axes and the swing equation, under the kernel's excitation system
(`kernel.rhs.exciter`, every structure of the library) -- issue 27, item 1.

The machine is PSS/E's GENROU as ANDES writes it (stator transients and speed voltages neglected,
X''d = X''q, the quadratic saturation of |psi''| shared by both axes, on the d-axis with Se psi''d
and on the q-axis with Se psi''q (Xq - Xl) / (Xd - Xl)):

    psi''d = gd1 E'q + (1 - gd1) psikd            psi''q = gq1 E'd + (1 - gq1) psikq
    T'd0 dE'q/dt = Efd - XadIfd                   XadIfd = E'q + (Xd - X'd) (gd1 Id + gd2 (E'q - psikd)) + Se psi''d
    T''d0 dpsikd/dt = E'q - psikd - (X'd - Xl) Id
    T'q0 dE'd/dt = -(E'd + (Xq - X'q) (gq2 (E'd - psikq) - gq1 Iq) + Se psi''q gqd)
    T''q0 dpsikq/dt = E'd - psikq + (X'q - Xl) Iq
    d delta/dt = 2 pi fn (omega - 1)              2 H d omega/dt = Tm - Te - D (omega - 1)

with gd1 = (X''d - Xl)/(X'd - Xl), gd2 = (X'd - X''d)/(X'd - Xl)^2 (the same for q) and
gqd = (Xq - Xl)/(Xd - Xl). At no load (Id = Iq = 0) the d-axis is the kernel's generator (E'q,
E''q = psikd, KPP = gd1, KDA = (Xd - X'd) gd2).

A GENSAL (the kernel's SATEQ = 1: a salient-pole unit) has the same d-axis with its saturation
Sat(E'q) on E'q alone, and one q-axis circuit: psi''q = psikq, T''q0 dpsikq/dt = -psikq +
(Xq - X''d) Iq (E'd stays 0; X'q and T'q0 are not used).

The network is solved in closed form each stage: in the machine's frame (a phasor X of the grid
seen as X_dq = Xd + j Xq = j X e^{-j delta}), E'' = psi''q + j psi''d and the infinite bus
Vinf_dq = Vinf (sin delta + j cos delta):

    I = (E'' - Vinf_dq) / (RA + RE + j (X''d + XE)),   V = E'' - (RA + j X''d) I
    Vt = |V|, P = Re(V conj I), Q = Im(V conj I), Te = P + RA |I|^2

A power system stabiliser (PSS_KS > 0: ANDES' and PSS/E's IEEEST on the rotor speed, without its
notch filters A1..A6) adds its output to the reference:

    vs = clamp(KS (1 + s T1)/(1 + s T2) (1 + s T3)/(1 + s T4) s TW/(1 + s TW) (omega - 1), +-LSMAX)

(three states, 0 at the operating point; KS = 0, the default, is no stabiliser).

The initial operating point comes from the record's pre-step P, Q and Vt (machine base): the
steady state as ANDES initialises a GENROU, the infinite bus from V - (RE + j XE) I, its angle
the reference. The excitation system starts in its steady state at that field voltage and field
current (both XadIfd0).

Numerics as the kernel's: classical RK4 at the record's step, the setpoint zero-order hold with
each edge at its fitted instant (the step split there), the regulator lag held at its ceilings
inside each stage and clamped after the step (the ceilings move with Vt and Ifd; at a limit the
lag is held there, not moved with it). Not yet on line: the dead time, the setpoint ramp and the
recorder skew (refused). Candidates run as the kernel's: chunks of CHUNK in parallel, each chunk
time outer and candidates inner, its RK4 step one branch-free loop LLVM vectorises across the
candidates. The rotor angle is carried as its sine and cosine (turned at the slip speed, put back on
the unit circle after each step): with no SVML there is no vector sin / cos, and one call in the
loop would keep it scalar.
"""
from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence

import numba as nb
import numpy as np

from . import kernel as K
from .edges import EdgeSpec
from .kernel.blocks import ceilings_at, lead_lag_or_pi, regulator_input, steady_state
from .kernel.jit import FASTMATH
from .kernel.layout import (
    BLOWUP,
    CHUNK,
    D_ACON,
    D_DCON,
    D_EDGE0,
    D_GAIN,
    D_IT2,
    D_IT4,
    D_ITD0P,
    D_ITD0PP,
    D_ITE,
    D_ITR,
    D_KAVR,
    D_KFT,
    D_KI1,
    D_LIMOUT,
    D_P1,
    D_PID,
    D_R2,
    D_RATE,
    D_SATA,
    D_SATB,
    D_ST4,
    D_TRON,
    D_UREF0,
    D_VALID,
    D_VRIN,
    EDGE_EPS,
    N_DERIVED,
    ST4_SOME,
)
from .kernel.rhs import exciter, non_windup
from .kernel.rk4 import _fixed_view, _view_d  # the kernel's fixed-shape views (private to the model)
from .params import COL, MACHINE_CATALOGUE, MACHINE_DATA, MACHINE_DEFAULTS, MACHINE_PARAMS, MCOL, PARAMS

# ---- the machine's and the grid's parameters ---------------------------------------------------

#: the columns of the machine's derived matrix G (transposed as the kernel's: G[G_NAME, i])
(G_GD1, G_GQ1, G_GD2, G_GQ2, G_GQD, G_XD, G_XQ, G_XDP, G_XQP, G_XDPP, G_XL, G_ITQ0P, G_ITQ0PP, G_IM,
 G_DAMP, G_W0, G_RA, G_GT, G_BT, G_VINF, G_TM, G_E1Q0, G_E2D0, G_E1D0, G_E2Q0, G_DELTA0, G_VALID,
 G_SAL, G_KQ, G_PSS_KS, G_PSS_IT2, G_PSS_R1, G_PSS_IT4, G_PSS_R3, G_PSS_ITW, G_PSS_LIM) = range(36)
N_G = 36
#: the states of an on-line candidate: the kernel's eight (xm, x1, x2, VR lag, E'q, psikd, rate
#: feedback, DC/AC exciter), then E'd, psikq, sin delta, cos delta, omega (the rotor angle as its
#: sine and cosine: no sin / cos in the step, so the candidate loops vectorise), then the
#: stabiliser's two lead-lags and its washout
N_ONLINE = 16
#: the rows of a chunk's readout R: the recorded signals (efd, Vt, P, Q, Ifd) at the current state,
#: then the rest of the machine's algebra there (Id, Iq, Te, XaqI1q): with Vt and Ifd, what the next
#: RK4 step's first stage reads instead of solving the machine again
(R_EFD, R_VT, R_P, R_Q, R_IFD, R_ID, R_IQ, R_TE, R_XAQ) = range(9)
N_R = 9


def machine_matrix(values: Mapping[str, float] | Sequence[Mapping[str, float]]) -> np.ndarray:
    """The machine matrix (n, len(MACHINE_PARAMS)) of one or more parameter mappings; every name is
    needed but RA, RE, DAMP (0), FN (50) and the stabiliser's (PSS_KS 0: none; `params.MACHINE_DEFAULTS`). A name
    outside its range is an error that names it."""
    rows = [values] if isinstance(values, Mapping) else list(values)
    M = np.empty((len(rows), len(MACHINE_PARAMS)))
    defaults = MACHINE_DEFAULTS
    for r, row in enumerate(rows):
        unknown = set(row) - set(MACHINE_PARAMS)
        if unknown:
            raise ValueError(f"unknown machine parameter(s) {', '.join(sorted(unknown))}; "
                             f"known: {', '.join(MACHINE_PARAMS)}")
        for info in MACHINE_CATALOGUE:
            if info.name in row:
                value = float(row[info.name])
            elif info.name in defaults:
                value = defaults[info.name]
            else:
                raise ValueError(f"machine parameter {info.name} ({info.info}) is missing")
            info.check(value, "on-line machine: ")
            M[r, MCOL[info.name]] = value
    return M


#: a GENSAL's q-axis has one circuit: these are not its data
SALIENT_UNUSED = ("XQP", "Tq0p")
#: a machine to compile the loop with (a GENROU of typical data at a typical operating point)
TYPICAL_MACHINE: dict[str, float] = {"XD": 1.8, "XQ": 1.7, "XDP": 0.3, "XQP": 0.55, "XDPP": 0.25, "XLS": 0.15,
                                     "Tq0p": 0.4, "Tq0pp": 0.05, "H": 3.0, "XE": 0.2, "P0": 0.8, "Q0": 0.2}


def machine_data(unit) -> tuple[str, ...]:
    """The [grid] names the unit on line needs besides the operating point: the machine's data
    (a GENSAL, the kernel's SATEQ = 1, has no X'q, T'q0) and XE."""
    sal = float(unit.values().get("SATEQ", 0.0)) > 0.5
    return tuple(n for n in MACHINE_DATA if not (sal and n in SALIENT_UNUSED)) + ("XE",)


def unit_machine(unit, point: Mapping[str, float] | None = None) -> dict[str, float]:
    """The machine-on-the-grid values of a unit (its [grid], at `point`'s P0, Q0 when given); an
    error that names what is missing and where it can come from."""
    grid = {**unit.grid, **(point or {})}
    missing = [name for name in (*machine_data(unit), "P0", "Q0") if name not in grid]
    if missing:
        raise ValueError(f"the unit {unit.name!r} on line needs {', '.join(missing)}: give them under [grid] "
                         "in the unit file or with --set NAME=VALUE (the machine's data also come from a "
                         "GENROU or GENSAL record with --from-dyr)")
    return with_placeholders({k: v for k, v in grid.items() if k in MACHINE_PARAMS})


def with_placeholders(grid: Mapping[str, float]) -> dict[str, float]:
    """`grid` with a GENSAL's unused q-axis transient data (X'q = Xq, T'q0 = 1 s) where absent:
    placeholders the machine does not read for a GENSAL."""
    return {"XQP": grid.get("XQ", 1.0), "Tq0p": 1.0, **grid}


def derive_machine(P: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The machine's derived matrix G (n, N_G) and the field voltage XadIfd0 of the steady state at
    the operating point (P0, Q0, Vt0), as ANDES initialises a GENROU; a candidate whose
    reactances are out of order (Xd > X'd > X''d > Xl, Xq >= X'q >= X''d) is marked invalid (its
    row 0, its field voltage 1). Array arithmetic over the candidates: one batched call derives
    them all."""
    P = np.atleast_2d(np.asarray(P, float))
    M = np.atleast_2d(np.asarray(M, float))
    if M.shape != (P.shape[0], len(MACHINE_PARAMS)):
        raise ValueError(f"machine matrix of shape {M.shape}, expected ({P.shape[0]}, {len(MACHINE_PARAMS)})")
    n = P.shape[0]
    G = np.zeros((n, N_G))
    fld0 = np.ones(n)
    sat_a, sat_b = K.saturation_ab(P[:, COL["S10"]], P[:, COL["S12"]])
    m = {name: M[:, j] for name, j in MCOL.items()}
    sal = P[:, COL["SATEQ"]] > 0.5   # a GENSAL: saturation on E'q, one q-axis circuit
    xd, xq, x1d, x2, xl = m["XD"], m["XQ"], m["XDP"], m["XDPP"], m["XLS"]
    x1q = np.where(sal, xq, m["XQP"])
    vt0, p0, q0 = P[:, COL["Vt0"]], m["P0"], m["Q0"]
    ok = ((xd > x1d) & (x1d > x2) & (x2 > xl) & (xl >= 0.0) & (xq >= x1q) & (x1q >= x2) & (xq > x2)
          & (sal | (m["Tq0p"] > 0)) & (m["Tq0pp"] > 0) & (m["H"] > 0) & (vt0 > 0))
    if not ok.any():
        return G, fld0
    # the valid candidates only (an invalid one's reactances may divide by 0)
    k = np.flatnonzero(ok)
    sal, x1q, vt0, p0, q0, sat_a, sat_b = sal[k], x1q[k], vt0[k], p0[k], q0[k], sat_a[k], sat_b[k]
    m = {name: v[k] for name, v in m.items()}
    xd, xq, x1d, x2, xl = m["XD"], m["XQ"], m["XDP"], m["XDPP"], m["XLS"]
    gd1 = (x2 - xl) / (x1d - xl)
    gq1 = np.where(sal, 0.0, (x2 - xl) / (x1q - xl))
    gd2 = (x1d - x2) / (x1d - xl) ** 2
    gq2 = np.where(sal, 0.0, (x1q - x2) / (x1q - xl) ** 2)
    gqd = np.where(sal, 0.0, (xq - xl) / (xd - xl))
    ra, re, xe = m["RA"], m["RE"], m["XE"]
    # the operating point, the terminal voltage at angle 0 (ANDES' GENROU initialisation)
    v = vt0.astype(complex)
    it = (p0 - 1j * q0) / np.conj(v)
    zs = ra + 1j * x2
    psi20 = (it + v / zs) * zs
    psi_abs = np.abs(psi20)
    se0 = np.where((psi_abs >= sat_a) & ~sal, sat_b * (psi_abs - sat_a) ** 2 / psi_abs, 0.0)
    a = psi_abs * (1.0 + se0 * gqd)
    b = np.abs(it) * (x2 - xq)
    th = np.where(np.abs(it) > 0, np.angle(psi20) - np.angle(it), 0.0)
    delta0 = np.arctan(b * np.cos(th) / (b * np.sin(th) - a)) + np.angle(psi20)
    rot = 1j * np.exp(-1j * delta0)        # X_dq = j X e^{-j delta}
    psi_dq, i_dq = psi20 * rot, it * rot
    psi2q0, psi2d0 = psi_dq.real, psi_dq.imag
    id0, iq0 = i_dq.real, i_dq.imag
    e1q0 = psi2d0 + (x1d - x2) * id0
    sat_eq = np.where(sal, sat_b * np.maximum(e1q0 - sat_a, 0.0) ** 2, 0.0)   # a GENSAL's Sat(E'q)
    vinf = v - (re + 1j * xe) * it
    rt, xt = ra + re, x2 + xe   # the path to the infinite bus as its admittance 1 / (rt + j xt)
    G[k, G_GD1], G[k, G_GQ1], G[k, G_GD2], G[k, G_GQ2], G[k, G_GQD] = gd1, gq1, gd2, gq2, gqd
    G[k, G_XD], G[k, G_XQ], G[k, G_XDP], G[k, G_XQP], G[k, G_XDPP], G[k, G_XL] = xd, xq, x1d, x1q, x2, xl
    G[k, G_ITQ0P] = np.where(sal, 0.0, 1.0 / np.where(sal, 1.0, m["Tq0p"]))
    G[k, G_ITQ0PP] = 1.0 / m["Tq0pp"]
    G[k, G_SAL], G[k, G_KQ] = sal, np.where(sal, xq - x2, x1q - xl)
    G[k, G_IM], G[k, G_DAMP], G[k, G_W0] = 1.0 / (2.0 * m["H"]), m["DAMP"], 2.0 * math.pi * m["FN"]
    G[k, G_RA], G[k, G_GT], G[k, G_BT] = ra, rt / (rt * rt + xt * xt), xt / (rt * rt + xt * xt)
    G[k, G_VINF] = np.abs(vinf)
    G[k, G_TM] = p0 + ra * np.abs(it) ** 2
    G[k, G_E1Q0] = e1q0
    G[k, G_E2D0] = e1q0 - (x1d - xl) * id0
    G[k, G_E1D0] = np.where(sal, 0.0, iq0 * (xq - x1q) - se0 * gqd * psi2q0)
    G[k, G_E2Q0] = np.where(sal, psi2q0, -iq0 * (xl - xq) - se0 * gqd * psi2q0)
    G[k, G_DELTA0] = delta0 - np.angle(vinf)   # the infinite bus at angle 0
    G[k, G_PSS_KS], G[k, G_PSS_LIM] = m["PSS_KS"], m["PSS_LSMAX"]
    G[k, G_PSS_IT2], G[k, G_PSS_R1] = 1.0 / m["PSS_T2"], m["PSS_T1"] / m["PSS_T2"]
    G[k, G_PSS_IT4], G[k, G_PSS_R3] = 1.0 / m["PSS_T4"], m["PSS_T3"] / m["PSS_T4"]
    G[k, G_PSS_ITW] = 1.0 / m["PSS_TW"]
    G[k, G_VALID] = 1.0
    fld0[k] = (se0 + 1.0) * psi2d0 + (xd - x2) * id0 + sat_eq
    return G, fld0

# ---- the compiled machine, its right-hand side and RK4 step ------------------------------------


_FM = FASTMATH   # the kernel's fast-math flags


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=_FM)
def machine(D, G, i, e1q, e2d, e1d, e2q, sd, cd):
    """The machine's algebra at its states (sd, cd: sin and cos of the rotor angle):
    (Vt, XadIfd, Id, Iq, P, Q, Te, XaqI1q)."""
    gd1 = G[G_GD1, i]
    gq1 = G[G_GQ1, i]
    psd = gd1 * e1q + (1.0 - gd1) * e2d
    psq = gq1 * e1d + (1.0 - gq1) * e2q
    psi = math.sqrt(psd * psd + psq * psq)
    sal = G[G_SAL, i]
    x = psi - D[D_SATA, i]
    x = x if x > 0.0 else 0.0
    se = (1.0 - sal) * D[D_SATB, i] * x * x / (psi if psi > 1.0e-6 else 1.0e-6)
    xs = e1q - D[D_SATA, i]
    xs = xs if xs > 0.0 else 0.0
    sat_eq = sal * D[D_SATB, i] * xs * xs   # a GENSAL's Sat(E'q)
    vinf = G[G_VINF, i]
    ar = psq - vinf * sd
    ai = psd - vinf * cd
    gt = G[G_GT, i]
    bt = G[G_BT, i]
    cid = ar * gt + ai * bt
    ciq = ai * gt - ar * bt
    ra = G[G_RA, i]
    x2 = G[G_XDPP, i]
    vd = psq - ra * cid + x2 * ciq
    vq = psd - ra * ciq - x2 * cid
    vt = math.sqrt(vd * vd + vq * vq)
    p = vd * cid + vq * ciq
    q = vq * cid - vd * ciq
    te = p + ra * (cid * cid + ciq * ciq)
    gd2 = G[G_GD2, i]
    gq2 = G[G_GQ2, i]
    ifd = e1q + (G[G_XD, i] - G[G_XDP, i]) * (gd1 * cid + gd2 * (e1q - e2d)) + se * psd + sat_eq
    xaq = e1d + (G[G_XQ, i] - G[G_XQP, i]) * (gq2 * (e1d - e2q) - gq1 * ciq) + se * psq * G[G_GQD, i]
    return vt, ifd, cid, ciq, p, q, te, xaq


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=_FM)
def stabiliser(G, i, w, x13, x14, x15):
    """The stabiliser (IEEEST on the rotor speed, without its filters): the speed deviation through
    two lead-lags, the gain KS and the washout, limited to +-LSMAX; (vs, d13, d14, d15). With KS = 0
    it gives 0 and its states stay 0."""
    dw = w - 1.0
    y1 = x13 + G[G_PSS_R1, i] * (dw - x13)
    y2 = x14 + G[G_PSS_R3, i] * (y1 - x14)
    v = G[G_PSS_KS, i] * y2
    lim = G[G_PSS_LIM, i]
    vs = v - x15
    vs = vs if vs < lim else lim
    vs = vs if vs > -lim else -lim
    return vs, (dw - x13) * G[G_PSS_IT2, i], (y1 - x14) * G[G_PSS_IT4, i], (v - x15) * G[G_PSS_ITW, i]


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=_FM)
def swing_and_flux(D, G, i, fld, ifd, cid, ciq, te, xaq, x4, x5, x8, x9, x10, x11, x12):
    """The machine's derivatives at field voltage `fld` and its algebra (`machine`): E'q, psikd,
    E'd, psikq, the rotor angle's sine and cosine (turned at the slip speed) and the speed."""
    d4 = (fld - ifd) * D[D_ITD0P, i]
    d5 = (x4 - x5 - (G[G_XDP, i] - G[G_XL, i]) * cid) * D[D_ITD0PP, i]
    d8 = -xaq * G[G_ITQ0P, i]
    d9 = (x8 - x9 + G[G_KQ, i] * ciq) * G[G_ITQ0PP, i]
    wd = G[G_W0, i] * (x12 - 1.0)
    d12 = (G[G_TM, i] - te - G[G_DAMP, i] * (x12 - 1.0)) * G[G_IM, i]
    return d4, d5, d8, d9, x11 * wd, -x10 * wd, d12


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=_FM)
def end_of_step(D, G, i, y3, y4, y5, y8, y9, s, co):
    """After an RK4 step: the rotor angle's sine and cosine put back on the unit circle, the
    machine's algebra at the new state (`machine`'s tuple), the regulator lag clamped to the
    ceilings there unless they clamp the output; (VR lag, sin, cos, algebra, ceiling hi, lo)."""
    # one Newton step of 1 / sqrt(s^2 + co^2) from 1: an RK4 step leaves the pair on the circle
    # to far below the rounding (its error is the square of the drift), with no sqrt or division
    f = 1.5 - 0.5 * (s * s + co * co)
    s = s * f
    co = co * f
    r = machine(D, G, i, y4, y5, y8, y9, s, co)
    hi, lo = ceilings_at(D, i, r[0], r[1])
    z = y3 if y3 > lo else lo
    z = z if z < hi else hi
    y3 = z + D[D_LIMOUT, i] * (y3 - z)   # (ESST4B's lag: LIMOUT = 1, not limited)
    return y3, s, co, r, hi, lo


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=_FM)
def rhs_online(D, G, i, uref, x0, x1, x2, x3, x4, x5, x6, x7, x8, x9, x10, x11, x12, x13, x14, x15, st4):
    """Derivatives of the 16 on-line states (see N_ONLINE); the rotor angle as its sine and cosine,
    turned at the slip speed; the stabiliser's output added to the reference."""
    vt, ifd, cid, ciq, _p, _q, te, xaq = machine(D, G, i, x4, x5, x8, x9, x10, x11)
    return rhs_given(D, G, i, uref, x0, x1, x2, x3, x4, x5, x6, x7, x8, x9, x10, x11, x12, x13, x14, x15,
                     vt, ifd, cid, ciq, te, xaq, st4)


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=_FM)
def rhs_given(D, G, i, uref, x0, x1, x2, x3, x4, x5, x6, x7, x8, x9, x10, x11, x12, x13, x14, x15,
              vt, ifd, cid, ciq, te, xaq, st4):
    """`rhs_online` with the machine's algebra at the state given (a step's first stage: the
    previous step's end solved it)."""
    hi, lo = ceilings_at(D, i, vt, ifd)
    vs, d13, d14, d15 = stabiliser(G, i, x12, x13, x14, x15)
    dxm, dx1, dx2, de, fld, dxf, dxe = exciter(D, i, uref + vs, 0.0, x0, x1, x2, x3, x6, x7, vt, ifd, hi, lo, st4)
    de = non_windup(D, i, de, x3, hi, lo, 0.0, 0.0)   # held at a limit (the limit's motion not followed)
    d4, d5, d8, d9, d10, d11, d12 = swing_and_flux(D, G, i, fld, ifd, cid, ciq, te, xaq, x4, x5, x8, x9, x10, x11,
                                                   x12)
    return dxm, dx1, dx2, de, d4, d5, dxf, dxe, d8, d9, d10, d11, d12, d13, d14, d15


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=_FM)
def rk4_online(D, G, i, u, x0, x1, x2, x3, x4, x5, x6, x7, x8, x9, x10, x11, x12, x13, x14, x15, h, st4,
               vt0, ifd0, id0, iq0, te0, xaq0):
    """One RK4 step of length h at the setpoint reference u from the states x with the machine's
    algebra there (vt0 .. xaq0: `machine`'s): the 16 states at its end, the rotor angle's sine and
    cosine put back on the unit circle, the regulator lag clamped to the ceilings unless they clamp
    the output; then the recorded signals and the algebra at the end (the R rows 0-8, the field
    voltage at the reference u). Branch-free: candidate loops vectorise."""
    h2 = 0.5 * h
    a = rhs_given(D, G, i, u, x0, x1, x2, x3, x4, x5, x6, x7, x8, x9, x10, x11, x12, x13, x14, x15,
                  vt0, ifd0, id0, iq0, te0, xaq0, st4)
    b = rhs_online(D, G, i, u, x0 + h2 * a[0], x1 + h2 * a[1], x2 + h2 * a[2], x3 + h2 * a[3], x4 + h2 * a[4],
                   x5 + h2 * a[5], x6 + h2 * a[6], x7 + h2 * a[7], x8 + h2 * a[8], x9 + h2 * a[9],
                   x10 + h2 * a[10], x11 + h2 * a[11], x12 + h2 * a[12], x13 + h2 * a[13], x14 + h2 * a[14],
                   x15 + h2 * a[15], st4)
    c = rhs_online(D, G, i, u, x0 + h2 * b[0], x1 + h2 * b[1], x2 + h2 * b[2], x3 + h2 * b[3], x4 + h2 * b[4],
                   x5 + h2 * b[5], x6 + h2 * b[6], x7 + h2 * b[7], x8 + h2 * b[8], x9 + h2 * b[9],
                   x10 + h2 * b[10], x11 + h2 * b[11], x12 + h2 * b[12], x13 + h2 * b[13], x14 + h2 * b[14],
                   x15 + h2 * b[15], st4)
    d = rhs_online(D, G, i, u, x0 + h * c[0], x1 + h * c[1], x2 + h * c[2], x3 + h * c[3], x4 + h * c[4],
                   x5 + h * c[5], x6 + h * c[6], x7 + h * c[7], x8 + h * c[8], x9 + h * c[9],
                   x10 + h * c[10], x11 + h * c[11], x12 + h * c[12], x13 + h * c[13], x14 + h * c[14],
                   x15 + h * c[15], st4)
    h6 = h / 6.0
    y3 = x3 + h6 * (a[3] + 2.0 * b[3] + 2.0 * c[3] + d[3])
    y4 = x4 + h6 * (a[4] + 2.0 * b[4] + 2.0 * c[4] + d[4])
    y5 = x5 + h6 * (a[5] + 2.0 * b[5] + 2.0 * c[5] + d[5])
    y8 = x8 + h6 * (a[8] + 2.0 * b[8] + 2.0 * c[8] + d[8])
    y9 = x9 + h6 * (a[9] + 2.0 * b[9] + 2.0 * c[9] + d[9])
    s = x10 + h6 * (a[10] + 2.0 * b[10] + 2.0 * c[10] + d[10])
    co = x11 + h6 * (a[11] + 2.0 * b[11] + 2.0 * c[11] + d[11])
    y3, s, co, r, hi, lo = end_of_step(D, G, i, y3, y4, y5, y8, y9, s, co)
    y0 = x0 + h6 * (a[0] + 2.0 * b[0] + 2.0 * c[0] + d[0])
    y1 = x1 + h6 * (a[1] + 2.0 * b[1] + 2.0 * c[1] + d[1])
    y2 = x2 + h6 * (a[2] + 2.0 * b[2] + 2.0 * c[2] + d[2])
    y6 = x6 + h6 * (a[6] + 2.0 * b[6] + 2.0 * c[6] + d[6])
    y7 = x7 + h6 * (a[7] + 2.0 * b[7] + 2.0 * c[7] + d[7])
    y12 = x12 + h6 * (a[12] + 2.0 * b[12] + 2.0 * c[12] + d[12])
    y13 = x13 + h6 * (a[13] + 2.0 * b[13] + 2.0 * c[13] + d[13])
    y14 = x14 + h6 * (a[14] + 2.0 * b[14] + 2.0 * c[14] + d[14])
    y15 = x15 + h6 * (a[15] + 2.0 * b[15] + 2.0 * c[15] + d[15])
    vs = stabiliser(G, i, y12, y13, y14, y15)[0]
    fld = exciter(D, i, u + vs, 0.0, y0, y1, y2, y3, y6, y7, r[0], r[1], hi, lo, st4)[4]
    return ((y0, y1, y2, y3, y4, y5, y6, y7, y8, y9, s, co, y12, y13, y14, y15),
            (fld, r[0], r[4], r[5], r[1], r[2], r[3], r[6], r[7]))


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=_FM)
def exciter_ref(D, i, uref, xm, x1, x2, ef, vt, ifd):
    """`kernel.rhs.exciter` of a candidate on the reference blocks alone (`reference_blocks`):
    the transducer, the two lead-lags, the regulator lag, its derivative slew-limited but not yet
    held at the ceilings; (dxm, dx1, dx2, dVR-lag). The same sums as `exciter`'s, less the terms
    that are 0 for such a candidate; its field voltage is the lag's state."""
    tron = D[D_TRON, i]
    vm = tron * xm + (1.0 - tron) * vt
    e = uref - vm
    y1, _ys1 = lead_lag_or_pi(D, i, e, x1, x2)
    y2 = x2 + D[D_R2, i] * (y1 - x2)
    drive = regulator_input(D, i, D[D_KAVR, i] * y2, ifd)
    rate = D[D_RATE, i]
    de = (drive - ef) * D[D_ITE, i]
    de = de if de < rate else rate
    de = de if de > -rate else -rate
    return (vt - xm) * D[D_ITR, i], (e - x1) * D[D_IT2, i], (y1 - x2) * D[D_IT4, i], de


@nb.njit(cache=True, error_model="numpy")
def reference_blocks(D, G, i):
    """Whether candidate i runs on the reference blocks alone, with no stabiliser: no rate
    feedback, rotating exciter, output clamp, potential-source stage, PI or ST5B regulator input,
    and PSS_KS = 0. A chunk of such candidates steps with `rk4_chunk_ref`."""
    return (D[D_KFT, i] == 0.0 and D[D_DCON, i] == 0.0 and D[D_ACON, i] == 0.0 and D[D_LIMOUT, i] == 0.0
            and D[D_ST4, i] == 0.0 and D[D_VRIN, i] == 0.0 and D[D_KI1, i] == 0.0 and D[D_P1, i] == 0.0
            and D[D_PID, i] == 0.0 and G[G_PSS_KS, i] == 0.0)


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=_FM)
def rhs_online_ref(D, G, i, uref, x0, x1, x2, x3, x4, x5, x8, x9, x10, x11, x12):
    """`rhs_online` on the reference blocks alone (`reference_blocks`): the derivatives of the 11
    states that move (the rate feedback's, the rotating exciter's and the stabiliser's do not)."""
    vt, ifd, cid, ciq, _p, _q, te, xaq = machine(D, G, i, x4, x5, x8, x9, x10, x11)
    return rhs_given_ref(D, G, i, uref, x0, x1, x2, x3, x4, x5, x8, x9, x10, x11, x12, vt, ifd, cid, ciq, te, xaq)


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=_FM)
def rhs_given_ref(D, G, i, uref, x0, x1, x2, x3, x4, x5, x8, x9, x10, x11, x12, vt, ifd, cid, ciq, te, xaq):
    """`rhs_online_ref` with the machine's algebra at the state given."""
    hi, lo = ceilings_at(D, i, vt, ifd)
    dxm, dx1, dx2, de = exciter_ref(D, i, uref, x0, x1, x2, x3, vt, ifd)
    de = non_windup(D, i, de, x3, hi, lo, 0.0, 0.0)
    d4, d5, d8, d9, d10, d11, d12 = swing_and_flux(D, G, i, x3, ifd, cid, ciq, te, xaq, x4, x5, x8, x9, x10, x11,
                                                   x12)
    return dxm, dx1, dx2, de, d4, d5, d8, d9, d10, d11, d12


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=_FM)
def rk4_online_ref(D, G, i, u, x0, x1, x2, x3, x4, x5, x8, x9, x10, x11, x12, h, vt0, ifd0, id0, iq0, te0, xaq0):
    """`rk4_online` on the reference blocks alone: the 11 states that move at the step's end
    (states 0-5, 8-12), then the R rows there (efd, the lag's state, does not depend on u)."""
    h2 = 0.5 * h
    a = rhs_given_ref(D, G, i, u, x0, x1, x2, x3, x4, x5, x8, x9, x10, x11, x12, vt0, ifd0, id0, iq0, te0, xaq0)
    b = rhs_online_ref(D, G, i, u, x0 + h2 * a[0], x1 + h2 * a[1], x2 + h2 * a[2], x3 + h2 * a[3],
                       x4 + h2 * a[4], x5 + h2 * a[5], x8 + h2 * a[6], x9 + h2 * a[7], x10 + h2 * a[8],
                       x11 + h2 * a[9], x12 + h2 * a[10])
    c = rhs_online_ref(D, G, i, u, x0 + h2 * b[0], x1 + h2 * b[1], x2 + h2 * b[2], x3 + h2 * b[3],
                       x4 + h2 * b[4], x5 + h2 * b[5], x8 + h2 * b[6], x9 + h2 * b[7], x10 + h2 * b[8],
                       x11 + h2 * b[9], x12 + h2 * b[10])
    d = rhs_online_ref(D, G, i, u, x0 + h * c[0], x1 + h * c[1], x2 + h * c[2], x3 + h * c[3],
                       x4 + h * c[4], x5 + h * c[5], x8 + h * c[6], x9 + h * c[7], x10 + h * c[8],
                       x11 + h * c[9], x12 + h * c[10])
    h6 = h / 6.0
    y3 = x3 + h6 * (a[3] + 2.0 * b[3] + 2.0 * c[3] + d[3])
    y4 = x4 + h6 * (a[4] + 2.0 * b[4] + 2.0 * c[4] + d[4])
    y5 = x5 + h6 * (a[5] + 2.0 * b[5] + 2.0 * c[5] + d[5])
    y8 = x8 + h6 * (a[6] + 2.0 * b[6] + 2.0 * c[6] + d[6])
    y9 = x9 + h6 * (a[7] + 2.0 * b[7] + 2.0 * c[7] + d[7])
    s = x10 + h6 * (a[8] + 2.0 * b[8] + 2.0 * c[8] + d[8])
    co = x11 + h6 * (a[9] + 2.0 * b[9] + 2.0 * c[9] + d[9])
    y3, s, co, r, _hi, _lo = end_of_step(D, G, i, y3, y4, y5, y8, y9, s, co)
    return ((x0 + h6 * (a[0] + 2.0 * b[0] + 2.0 * c[0] + d[0]), x1 + h6 * (a[1] + 2.0 * b[1] + 2.0 * c[1] + d[1]),
             x2 + h6 * (a[2] + 2.0 * b[2] + 2.0 * c[2] + d[2]), y3, y4, y5, y8, y9, s, co,
             x12 + h6 * (a[10] + 2.0 * b[10] + 2.0 * c[10] + d[10])),
            (y3, r[0], r[4], r[5], r[1], r[2], r[3], r[6], r[7]))


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=_FM)
def readout(D, G, i, u, x0, x1, x2, x3, x4, x5, x6, x7, x8, x9, x10, x11, x12, x13, x14, x15, st4):
    """The R rows at a state: the recorded signals (efd, Vt, P, Q, Ifd), then Id, Iq, Te, XaqI1q."""
    vt, ifd, cid, ciq, p, q, te, xaq = machine(D, G, i, x4, x5, x8, x9, x10, x11)
    hi, lo = ceilings_at(D, i, vt, ifd)
    vs = stabiliser(G, i, x12, x13, x14, x15)[0]
    fld = exciter(D, i, u + vs, 0.0, x0, x1, x2, x3, x6, x7, vt, ifd, hi, lo, st4)[4]
    return fld, vt, p, q, ifd, cid, ciq, te, xaq


@nb.njit(cache=True, error_model="numpy", fastmath=_FM)
def initial_state(D, G, i, S, c):
    """Candidate i's 16 states at its operating point into column c of S: where a run starts (the
    stabiliser's at 0: the speed is nominal)."""
    x = steady_state(D, i)
    for q in range(8):
        S[q, c] = x[q]
    S[4, c] = G[G_E1Q0, i]
    S[5, c] = G[G_E2D0, i]
    S[8, c] = G[G_E1D0, i]
    S[9, c] = G[G_E2Q0, i]
    S[10, c] = math.sin(G[G_DELTA0, i])
    S[11, c] = math.cos(G[G_DELTA0, i])
    S[12, c] = 1.0
    S[13, c] = 0.0
    S[14, c] = 0.0
    S[15, c] = 0.0


# ---- the loops over a chunk's candidates (vectorised across them, as the kernel's) ----


# the chunk's 2-D arrays seen with their shape a constant of the code, as the kernel's RK4 loops see
# theirs (`kernel.rk4.fixed_views`, docs/decisions/0003): each array is then one group for LLVM's
# runtime overlap checks; with runtime row strides every written row is checked against every
# row read, past the vectoriser's limit, and the loop stays scalar
_view_g, _view_x, _view_r = (_fixed_view(rows) for rows in (N_G, N_ONLINE, N_R))


@nb.njit(cache=True, error_model="numpy")
def chunk_views(D, G, S):
    """D, G, S (N_DERIVED, N_G and N_ONLINE rows of CHUNK columns) as fixed-shape views."""
    if (D.shape[0] != N_DERIVED or G.shape[0] != N_G or S.shape[0] != N_ONLINE
            or D.shape[1] != CHUNK or G.shape[1] != CHUNK or S.shape[1] != CHUNK):
        raise ValueError("on-line chunk arrays of the wrong shape")
    return _view_d(D), _view_g(G), _view_x(S)


@nb.njit(cache=True, error_model="numpy")
def readout_views(D, G, S, R):
    """D, G, S as `chunk_views`, and the readout R (N_R rows of CHUNK columns)."""
    if R.shape[0] != N_R or R.shape[1] != CHUNK:
        raise ValueError("on-line readout array of the wrong shape")
    D, G, S = chunk_views(D, G, S)
    return D, G, S, _view_r(R)


@nb.njit(cache=True, inline="always", error_model="numpy")
def put_readout(R, c, r):
    """The R rows of candidate c (the N_R values of a step's end or a readout) into column c."""
    R[0, c] = r[0]
    R[1, c] = r[1]
    R[2, c] = r[2]
    R[3, c] = r[3]
    R[4, c] = r[4]
    R[5, c] = r[5]
    R[6, c] = r[6]
    R[7, c] = r[7]
    R[8, c] = r[8]


@nb.njit(cache=True, error_model="numpy", fastmath=_FM)
def rk4_chunk(D, G, S, U, H, m, R):
    """One RK4 step of every candidate c < m of a chunk (states S[:, c], reference U[c], length
    H[c]; H[c] = 0 leaves it where it is) from the machine's algebra in R (as `readout_chunk` or
    the previous step left it), leaving R at the step's end (the field voltage at U[c]): a
    branch-free loop LLVM vectorises across c. The one copy of the step: the chunks, the sub-steps
    around a jump and the real-time plant all run it. The arrays have CHUNK columns."""
    D, G, S, R = readout_views(D, G, S, R)
    for c in range(m):
        x, r = rk4_online(D, G, c, U[c], S[0, c], S[1, c], S[2, c], S[3, c], S[4, c], S[5, c], S[6, c], S[7, c],
                          S[8, c], S[9, c], S[10, c], S[11, c], S[12, c], S[13, c], S[14, c], S[15, c], H[c],
                          ST4_SOME, R[R_VT, c], R[R_IFD, c], R[R_ID, c], R[R_IQ, c], R[R_TE, c], R[R_XAQ, c])
        S[0, c] = x[0]
        S[1, c] = x[1]
        S[2, c] = x[2]
        S[3, c] = x[3]
        S[4, c] = x[4]
        S[5, c] = x[5]
        S[6, c] = x[6]
        S[7, c] = x[7]
        S[8, c] = x[8]
        S[9, c] = x[9]
        S[10, c] = x[10]
        S[11, c] = x[11]
        S[12, c] = x[12]
        S[13, c] = x[13]
        S[14, c] = x[14]
        S[15, c] = x[15]
        put_readout(R, c, r)


@nb.njit(cache=True, error_model="numpy", fastmath=_FM)
def rk4_chunk_ref(D, G, S, U, H, m, R):
    """`rk4_chunk` of a chunk whose candidates all run on the reference blocks alone
    (`reference_blocks`; the reference structure's and SEXS's chunks without a stabiliser): the
    11 states that move. The fast path, a second copy of the step as the kernel's `rk4_all_ref`."""
    D, G, S, R = readout_views(D, G, S, R)
    for c in range(m):
        x, r = rk4_online_ref(D, G, c, U[c], S[0, c], S[1, c], S[2, c], S[3, c], S[4, c], S[5, c], S[8, c],
                              S[9, c], S[10, c], S[11, c], S[12, c], H[c], R[R_VT, c], R[R_IFD, c], R[R_ID, c],
                              R[R_IQ, c], R[R_TE, c], R[R_XAQ, c])
        S[0, c] = x[0]
        S[1, c] = x[1]
        S[2, c] = x[2]
        S[3, c] = x[3]
        S[4, c] = x[4]
        S[5, c] = x[5]
        S[8, c] = x[6]
        S[9, c] = x[7]
        S[10, c] = x[8]
        S[11, c] = x[9]
        S[12, c] = x[10]
        put_readout(R, c, r)


@nb.njit(cache=True, error_model="numpy", fastmath=_FM)
def readout_chunk(D, G, S, U, m, R):
    """The R rows of every candidate c < m at its state and reference U[c] (CHUNK columns, as D,
    G, S): what is recorded, and the algebra the next RK4 step starts from."""
    D, G, S, R = readout_views(D, G, S, R)
    for c in range(m):
        r = readout(D, G, c, U[c], S[0, c], S[1, c], S[2, c], S[3, c], S[4, c], S[5, c], S[6, c], S[7, c],
                    S[8, c], S[9, c], S[10, c], S[11, c], S[12, c], S[13, c], S[14, c], S[15, c], ST4_SOME)
        put_readout(R, c, r)


# ---- the chunk runner and the parallel loop over chunks ----


@nb.njit(cache=True, nogil=True, error_model="numpy", fastmath=_FM)
def _run_chunk(D, G, lo, hi, usetp, usetp_pre, dt, eidx, ejump, etn, eslot, meas, w, store, traces, sse, ends,
               fail_step):
    """Candidates lo..hi-1 over the record (time outer, candidates inner, as the kernel's chunks):
    the reference of each step with its edges at their fitted instants, the readout, the errors,
    one vectorised RK4 step for all; a step with a jump inside is redone from its start in
    sub-steps between the jumps, in rounds of the same vectorised step (H = 0 for the others).
    Each step leaves the readout R at its end; it is solved again (`readout_chunk`) only where a
    candidate's reference differs from the one its last step used (the field voltage may follow
    the reference at once) or a candidate was parked."""
    m = hi - lo
    T = usetp.shape[0]
    ne = eidx.shape[0]
    Dc = np.zeros((D.shape[0], CHUNK))
    Gc = np.zeros((G.shape[0], CHUNK))
    Dc[:, :m] = D[:, lo:hi]
    Gc[:, :m] = G[:, lo:hi]
    S = np.zeros((N_ONLINE, CHUNK))
    S0 = np.zeros((N_ONLINE, m))   # the states at t_k of a step redone in sub-steps
    X0 = np.zeros((N_ONLINE, m))   # the operating point, where a candidate that blew up is parked
    U = np.zeros(CHUNK)
    Us = np.zeros(CHUNK)
    H = np.zeros(CHUNK)
    Hs = np.zeros(CHUNK)
    R = np.zeros((N_R, CHUNK))
    R0 = np.zeros((N_R, m))         # the readout at t_k of a step redone in sub-steps
    Ulast = np.zeros(CHUNK)         # the reference R's field voltage was computed with
    stale = True                    # R must be solved again (the start, a candidate parked)
    held = np.zeros((5, m))
    failed = np.zeros(m, np.bool_)
    nbrk = np.zeros(m, np.int64)   # jumps inside the step, per candidate
    bs = np.zeros((m, ne + 1))      # their instants (fractions of the step, sorted) and sizes
    bj = np.zeros((m, ne + 1))
    ke = np.zeros((m, ne))          # each edge's fitted instant in steps, per candidate
    mag = np.zeros(CHUNK)           # the size of each candidate's state (a blow-up test)
    # the reference blocks' fast path when every candidate of the chunk runs on them alone (an
    # invalid candidate, failed from the start, does not count: what it computes is not used);
    # its field voltage is a state: R does not follow the reference
    ref = True
    for c in range(m):
        if Dc[D_VALID, c] != 0.0 and Gc[G_VALID, c] != 0.0 and not reference_blocks(Dc, Gc, c):
            ref = False
    for c in range(m):
        for j in range(ne):
            ke[c, j] = (etn[j] + Dc[D_EDGE0 + eslot[j], c]) / dt
        initial_state(Dc, Gc, c, S, c)
        for q in range(N_ONLINE):
            X0[q, c] = S[q, c]
        H[c] = dt
        if Dc[D_VALID, c] == 0.0 or Gc[G_VALID, c] == 0.0:
            failed[c] = True
            fail_step[lo + c] = 0
    # the steps where some candidate's reference may differ from the record's (an edge between its
    # nominal sample and the fitted instants of the chunk): the edges are looked at there only (a
    # failed candidate's instants, whose reference is not used, and one that is not a number do
    # not move the window)
    win_lo = np.zeros(ne)
    win_hi = np.zeros(ne)
    for j in range(ne):
        kmin = eidx[j] * 1.0
        kmax = eidx[j] * 1.0
        for c in range(m):
            if not (failed[c] or math.isnan(ke[c, j])):
                kmin = min(kmin, ke[c, j])
                kmax = max(kmax, ke[c, j])
        win_lo[j] = math.floor(kmin) - 1.0
        win_hi[j] = math.ceil(kmax) + 1.0
    for k in range(T):
        # the reference over [t_k, t_k+1): the zero-order hold of the record, each edge at its
        # fitted instant (the candidate's offset); the jumps inside the step noted
        u_k = usetp[k] - usetp_pre
        rounds = 0
        inwin = False
        for j in range(ne):
            if win_lo[j] <= k <= win_hi[j]:
                inwin = True
        if not inwin:
            for c in range(m):
                U[c] = Dc[D_UREF0, c] + u_k
                nbrk[c] = 0
        for c in range(m if inwin else 0):
            u = Dc[D_UREF0, c] + u_k
            nb_ = 0
            for j in range(ne):
                kj = ke[c, j]
                fit_on = 1.0 if kj <= k + EDGE_EPS else 0.0
                nom_on = 1.0 if k >= eidx[j] else 0.0
                u += ejump[j] * (fit_on - nom_on)
                if k + EDGE_EPS < kj < k + 1.0 - EDGE_EPS and not failed[c]:
                    sv = kj - k   # insertion into the sorted few
                    jv = ejump[j]
                    b = nb_ - 1
                    while b >= 0 and bs[c, b] > sv:
                        bs[c, b + 1] = bs[c, b]
                        bj[c, b + 1] = bj[c, b]
                        b -= 1
                    bs[c, b + 1] = sv
                    bj[c, b + 1] = jv
                    nb_ += 1
            U[c] = u
            nbrk[c] = nb_
            if nb_ > 0:
                rounds = max(rounds, nb_ + 1)
        if not (stale or ref):
            for c in range(m):
                if U[c] != Ulast[c]:
                    stale = True
        if stale:
            readout_chunk(Dc, Gc, S, U, m, R)
            stale = False
        for c in range(m):
            if not failed[c]:
                held[0, c] = Dc[D_GAIN, c] * R[0, c]   # efd as recorded
                for q in range(1, 5):
                    held[q, c] = R[q, c]
        if store:
            for q in range(5):
                for c in range(m):
                    traces[q, lo + c, k] = held[q, c]
        for q in range(4):
            if w[q] > 0.0:
                mq = meas[q, k]
                for c in range(m):
                    e = held[q, c] - mq
                    sse[q, lo + c] += e * e
                    if k == 0 or k == T - 1:   # the trapezoid's half weight at both ends
                        ends[q, lo + c] += 0.5 * e * e
        if k == T - 1:
            break
        if rounds:
            for c in range(m):
                if nbrk[c]:
                    for q in range(N_ONLINE):
                        S0[q, c] = S[q, c]
                    for q in range(N_R):
                        R0[q, c] = R[q, c]
        if ref:
            rk4_chunk_ref(Dc, Gc, S, U, H, m, R)
        else:
            rk4_chunk(Dc, Gc, S, U, H, m, R)
        for c in range(m):
            Ulast[c] = U[c]
        if rounds:
            for c in range(m):
                if nbrk[c]:
                    for q in range(N_ONLINE):
                        S[q, c] = S0[q, c]
                    for q in range(N_R):
                        R[q, c] = R0[q, c]
            for r in range(rounds):   # sub-step r of every candidate with a jump inside
                for c in range(m):
                    Hs[c] = 0.0
                    Us[c] = U[c]
                    nb_ = nbrk[c]
                    if nb_ and r <= nb_:
                        sa = bs[c, r - 1] if r > 0 else 0.0
                        sb = bs[c, r] if r < nb_ else 1.0
                        Hs[c] = (sb - sa) * dt if sb - sa > 1.0e-12 else 0.0
                        for q in range(r):
                            Us[c] += bj[c, q]
                if ref:   # (H = 0 leaves a candidate, and its signals in R, where they are)
                    rk4_chunk_ref(Dc, Gc, S, Us, Hs, m, R)
                else:
                    rk4_chunk(Dc, Gc, S, Us, Hs, m, R)
                for c in range(m):
                    Ulast[c] = Us[c]
        for c in range(m):   # (written out: the loop vectorises)
            mag[c] = (abs(S[0, c]) + abs(S[1, c]) + abs(S[2, c]) + abs(S[3, c]) + abs(S[4, c]) + abs(S[5, c])
                      + abs(S[6, c]) + abs(S[7, c]) + abs(S[8, c]) + abs(S[9, c]) + abs(S[10, c]) + abs(S[11, c])
                      + abs(S[12, c]) + abs(S[13, c]) + abs(S[14, c]) + abs(S[15, c]))
        for c in range(m):
            if not (mag[c] < BLOWUP):
                if not failed[c]:
                    failed[c] = True
                    fail_step[lo + c] = k + 1
                for q in range(N_ONLINE):
                    S[q, c] = X0[q, c]
                stale = True


@nb.njit(cache=True, nogil=True, error_model="numpy", fastmath=_FM, parallel=True)
def _run(D, G, usetp, usetp_pre, dt, eidx, ejump, etn, eslot, meas, w, store, traces, sse, ends, fail_step):
    """Every chunk of CHUNK candidates, in parallel."""
    n = D.shape[1]
    for b in nb.prange((n + CHUNK - 1) // CHUNK):
        lo = b * CHUNK
        _run_chunk(D, G, lo, min(n, lo + CHUNK), usetp, usetp_pre, dt, eidx, ejump, etn, eslot, meas, w, store,
                   traces, sse, ends, fail_step)


#: the per-sample columns of `advance`: the no-load plant's seven (`plant_step.O_*`), then P, Q, Ifd
(A_USETP, A_EFD_REC, A_VT, A_EFD, A_EQP, A_UREF, A_FLAGS, A_P, A_Q, A_IFD) = range(10)
N_ADVANCE = 10
#: flag bits of A_FLAGS (the no-load plant's FLAG_CEILING and FLAG_FAILED)
A_FLAG_CEILING, A_FLAG_FAILED = 1, 8


@nb.njit(cache=True, nogil=True, error_model="numpy", fastmath=_FM)
def advance(D, G, S, X0, u, usetp_pre, dt, out, last):
    """Step candidate 0 (D, G transposed, S the states; CHUNK columns, column 0 used) over the setpoint series
    u, one sample per step as `_run_chunk` records it (the sample at t_k with the setpoint of step
    k, then the step): the real-time plant on line. `last` gets (efd, Vt, P, Q, Ifd, flags) at the
    final state. A state that leaves its sane range is parked at X0 (flag bit 8)."""
    U = np.zeros(CHUNK)
    H = np.zeros(CHUNK)
    H[0] = dt
    R = np.zeros((N_R, CHUNK))
    flags = 0.0
    for s in range(u.shape[0]):
        U[0] = D[D_UREF0, 0] + u[s] - usetp_pre
        readout_chunk(D, G, S, U, 1, R)
        out[s, A_USETP] = u[s]
        out[s, A_EFD_REC] = D[D_GAIN, 0] * R[0, 0]
        out[s, A_VT] = R[1, 0]
        out[s, A_EFD] = R[0, 0]
        out[s, A_EQP] = S[4, 0]
        out[s, A_UREF] = U[0]
        out[s, A_P] = R[2, 0]
        out[s, A_Q] = R[3, 0]
        out[s, A_IFD] = R[4, 0]
        hi, lo = ceilings_at(D, 0, R[1, 0], R[4, 0])
        flags = A_FLAG_CEILING if (S[3, 0] >= hi or S[3, 0] <= lo) else 0.0
        rk4_chunk(D, G, S, U, H, 1, R)   # (from the readout's algebra; the next readout solves it again)
        mag = 0.0
        for q in range(N_ONLINE):
            mag += abs(S[q, 0])
        if not (mag < BLOWUP):
            for q in range(N_ONLINE):
                S[q, 0] = X0[q]
            flags += A_FLAG_FAILED
        out[s, A_FLAGS] = flags
    U[0] = D[D_UREF0, 0] + (u[u.shape[0] - 1] if u.shape[0] else usetp_pre) - usetp_pre
    readout_chunk(D, G, S, U, 1, R)
    for q in range(5):
        last[q] = R[q, 0]
    last[5] = flags


K.drop_stale_cache((machine, stabiliser, swing_and_flux, end_of_step, rhs_online, rhs_given, rk4_online,
                    exciter_ref, reference_blocks, rhs_online_ref, rhs_given_ref, rk4_online_ref, readout,
                    initial_state, chunk_views, readout_views, put_readout, rk4_chunk, rk4_chunk_ref, readout_chunk,
                    _run_chunk, advance, _run), K.SOURCES + (__file__,), "online")

#: the recorded signals of an on-line run, in the order of its traces and weights
SIGNALS = ("efd", "vt", "p", "q", "ifd")
#: effects the on-line machine does not run yet (their kernel parameters must be neutral)
NOT_ON_LINE = ("TD", "RAMP", "SKEW")


def derive_on_line(P: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's and the machine's derived matrices of the candidates P on the grid M, transposed
    as the compiled loops read them (D[name, i], G[name, i]); an effect not simulated on line yet
    (NOT_ON_LINE) away from its neutral value is an error that names it."""
    for name in NOT_ON_LINE:
        neutral = PARAMS[name].neutral
        if np.any(P[:, COL[name]] != neutral):
            raise ValueError(f"{name} is not simulated on line yet: set it to its neutral value ({neutral})")
    G, fld0 = derive_machine(P, M)
    D = K.derive(P, field0=fld0)
    return np.ascontiguousarray(D.T), np.ascontiguousarray(G.T)


def run_online(P: np.ndarray, M: np.ndarray, usetp: np.ndarray, dt: float, usetp_pre: float, *,
               measured: Mapping[str, np.ndarray] | None = None, weights: Mapping[str, float] | None = None,
               store: bool = True, edges: EdgeSpec | None = None) -> dict[str, np.ndarray]:
    """Simulate the candidates P (n, len(KERNEL_PARAMS)) on the grid M (n, len(MACHINE_PARAMS))
    over the setpoint series `usetp` (step dt; `usetp_pre` before it), the edges as `run_kernel`'s.

    Returns `efd`, `vt`, `p`, `q`, `ifd` (n, T) when `store`; `sse_<signal>` for every measured
    signal among efd, vt, p, q; `obj`: the trapezoidal integral of the weighted squared errors, as
    `run_kernel`'s (weights default 1 for efd, 0 for the others); `fail_step` (-1: ran to the end;
    0: invalid parameters)."""
    P = np.atleast_2d(np.asarray(P, float))
    n = P.shape[0]
    usetp = np.require(usetp, np.float64, ("C", "W"))
    T = usetp.shape[0]
    if T < 2:
        raise ValueError("a simulation needs at least two samples")
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"time step {dt!r} must be positive")
    D, G = derive_on_line(P, M)
    measured = dict(measured or {})
    unknown = set(measured) - set(SIGNALS[:4])
    if unknown:
        raise ValueError(f"measured signal(s) {', '.join(sorted(unknown))}: the fit reads efd, vt, p, q")
    meas = np.zeros((4, T))
    w = np.zeros(4)
    weights = {"efd": 1.0, **dict(weights or {})}
    for q, name in enumerate(SIGNALS[:4]):
        if name in measured:
            series = np.asarray(measured[name], float)
            if series.shape != (T,):
                raise ValueError(f"measured {name} has {series.shape} samples, the setpoint {T}")
            meas[q] = series
            w[q] = float(weights.get(name, 0.0))
    edges = EdgeSpec.none() if edges is None else edges
    if edges.n and int(edges.index.max()) >= T:
        raise ValueError(f"edge at sample {int(edges.index.max())} lies beyond the record ({T} samples)")
    traces = np.zeros((5, n, T) if store else (5, 1, 1))
    sse = np.zeros((4, n))
    ends = np.zeros((4, n))
    fail_step = np.full(n, -1, dtype=np.int64)
    if n:
        args = (usetp, float(usetp_pre), float(dt),
                np.require(edges.index, np.int64, ("C", "W")), np.require(edges.jump, np.float64, ("C", "W")),
                np.require(edges.nominal_s, np.float64, ("C", "W")), np.require(edges.slot, np.int64, ("C", "W")),
                meas, w, bool(store), traces, sse, ends, fail_step)
        if n <= CHUNK:   # one chunk on this thread, beside a fit on another (`identification.threads`)
            _run_chunk(D, G, 0, n, *args)
        else:
            with K.PARALLEL_LOCK:
                _run(D, G, *args)
    out: dict[str, np.ndarray] = {"fail_step": fail_step}
    if store:
        out.update({name: traces[q] for q, name in enumerate(SIGNALS)})
    for q, name in enumerate(SIGNALS[:4]):
        if name in measured:
            out[f"sse_{name}"] = sse[q]
    if measured:
        out["obj"] = dt * (w @ (sse - ends))
    return out


def warm_up(P: np.ndarray) -> float:
    """Compile (or load from the cache) the on-line loop with the kernel values P (one row, no dead
    time, ramp or skew) on TYPICAL_MACHINE; seconds."""
    t0 = time.perf_counter()
    u = np.array([1.0, 1.0, 1.02, 1.02])
    # one chunk runs on the calling thread, more in parallel: compile both paths
    P = np.atleast_2d(np.asarray(P, float))[:1]
    M = machine_matrix(TYPICAL_MACHINE)
    for n in (1, CHUNK + 1):
        run_online(np.repeat(P, n, axis=0), np.repeat(M, n, axis=0), u, 1e-3, 1.0, measured={"efd": np.ones(4)})
    return time.perf_counter() - t0
