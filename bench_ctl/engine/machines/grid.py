"""The unit on the grid: a GENROU (or GENSAL) synchronised through a reactance XE (and a resistance
RE) to an infinite bus, with both axes and the swing equation (docs/decisions/0017).

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
gqd = (Xq - Xl)/(Xd - Xl). At no load (Id = Iq = 0) the d-axis is the no-load machine (E'q, E''q =
psikd, KPP = gd1, KDA = (Xd - X'd) gd2).

A GENSAL (the unit's SATEQ = 1: a salient-pole unit) has the same d-axis with its saturation
Sat(E'q) on E'q alone, and one q-axis circuit: psi''q = psikq, T''q0 dpsikq/dt = -psikq +
(Xq - X''d) Iq (E'd stays 0; X'q and T'q0 are not used).

The network is solved in closed form at every stage: in the machine's frame (a phasor X of the
grid seen as X_dq = Xd + j Xq = j X e^{-j delta}), E'' = psi''q + j psi''d and the infinite bus
Vinf_dq = Vinf (sin delta + j cos delta):

    I = (E'' - Vinf_dq) / (RA + RE + j (X''d + XE)),   V = E'' - (RA + j X''d) I
    Vt = |V|, P = Re(V conj I), Q = Im(V conj I), Te = P + RA |I|^2

The initial operating point comes from the record's pre-step P, Q and Vt (machine base): the
steady state as ANDES initialises a GENROU, the infinite bus from V - (RE + j XE) I, its angle the
reference. The rotor angle is carried as its sine and cosine (turned at the slip speed, put back on
the unit circle after each step): with no SVML there is no vector sin / cos, and one call in the
loop would keep it scalar. At a ceiling the exciter's lag is held there, not moved with it (the
ceilings' motion is 0 here).

States (E'q, psikd, E'd, psikq, sin delta, cos delta, omega); algebra (Vt, XadIfd, Id, Iq, P, Q,
Te, XaqI1q).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from bench_ctl.model.params import COL, MACHINE_CATALOGUE, MACHINE_DATA, MACHINE_DEFAULTS, MACHINE_PARAMS, MCOL
from bench_ctl.model.stabilisers import check_stabiliser

from .. import derived as _derived
from ..jit import njit
from ..layout import (
    D_BT,
    D_DAMP,
    D_DELTA0,
    D_E1D0,
    D_E1Q0,
    D_E2D0,
    D_E2Q0,
    D_GD1,
    D_GD2,
    D_GQ1,
    D_GQ2,
    D_GQD,
    D_GT,
    D_GVALID,
    D_IM,
    D_ITD0P,
    D_ITD0PP,
    D_ITQ0P,
    D_ITQ0PP,
    D_KQ,
    D_RA,
    D_SAL,
    D_SATA,
    D_SATB,
    D_TM,
    D_VINF,
    D_W0,
    D_XD,
    D_XDP,
    D_XDPP,
    D_XL,
    D_XQ,
    D_XQP,
)

N_STATES = 7
N_ALG = 8

# ---- the machine's and the grid's parameters (Python) -------------------------------------------

#: a GENSAL's q-axis has one circuit: these are not its data
SALIENT_UNUSED = ("XQP", "Tq0p")
#: a machine to compile the loop with (a GENROU of typical data at a typical operating point)
TYPICAL_MACHINE: dict[str, float] = {"XD": 1.8, "XQ": 1.7, "XDP": 0.3, "XQP": 0.55, "XDPP": 0.25, "XLS": 0.15,
                                     "Tq0p": 0.4, "Tq0pp": 0.05, "H": 3.0, "XE": 0.2, "P0": 0.8, "Q0": 0.2}


def machine_matrix(values: Mapping[str, float] | Sequence[Mapping[str, float]]) -> np.ndarray:
    """The machine matrix (n, len(MACHINE_PARAMS)) of one or more parameter mappings; every name is
    needed but RA, RE, DAMP (0), FN (50) and the stabiliser's (`params.MACHINE_DEFAULTS`). A name
    outside its range, or a stabiliser's values that do not go together (`check_stabiliser`), is
    an error that names it."""
    rows = [values] if isinstance(values, Mapping) else list(values)
    M = np.empty((len(rows), len(MACHINE_PARAMS)))
    for r, row in enumerate(rows):
        unknown = set(row) - set(MACHINE_PARAMS)
        if unknown:
            raise ValueError(f"unknown machine parameter(s) {', '.join(sorted(unknown))}; "
                             f"known: {', '.join(MACHINE_PARAMS)}")
        for info in MACHINE_CATALOGUE:
            if info.name in row:
                value = float(row[info.name])
            elif info.name in MACHINE_DEFAULTS:
                value = MACHINE_DEFAULTS[info.name]
            else:
                raise ValueError(f"machine parameter {info.name} ({info.info}) is missing")
            info.check(value, "on-line machine: ")
            M[r, MCOL[info.name]] = value
        check_stabiliser(dict(zip(MACHINE_PARAMS, M[r])), "on-line machine: ")
    return M


def machine_data(unit) -> tuple[str, ...]:
    """The [grid] names the unit on line needs besides the operating point: the machine's data
    (a GENSAL, SATEQ = 1, has no X'q, T'q0) and XE."""
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


def derive_grid(P: np.ndarray, M: np.ndarray) -> np.ndarray:
    """The derived matrix (n, N_DERIVED) of the candidates P on the grid M: the machine's columns
    (D_GD1 ..) and the field voltage XadIfd0 of the steady state at the operating point (P0, Q0,
    Vt0) as ANDES initialises a GENROU, the excitation system's steady state at that field voltage
    (`derive`), the stabilisers' columns (`stabilisers.derive_columns`). A candidate whose
    reactances are out of order (Xd > X'd > X''d > Xl, Xq >= X'q >= X''d) gets D_GVALID 0 and
    field voltage 1."""
    from ..stabilisers import derive_columns

    P = np.atleast_2d(np.asarray(P, float))
    M = np.atleast_2d(np.asarray(M, float))
    if M.shape != (P.shape[0], len(MACHINE_PARAMS)):
        raise ValueError(f"machine matrix of shape {M.shape}, expected ({P.shape[0]}, {len(MACHINE_PARAMS)})")
    cols, fld0 = _machine_columns(P, M)
    D = _derived.derive(P, field0=fld0)
    for name, values in cols.items():
        D[:, name] = values
    derive_columns(D, M)
    return D


def _machine_columns(P: np.ndarray, M: np.ndarray) -> tuple[dict[int, np.ndarray], np.ndarray]:
    """The machine's derived columns (by column) and XadIfd0 (array arithmetic over the candidates;
    a candidate out of order gets zeros and field voltage 1)."""
    n = P.shape[0]
    out = {col: np.zeros(n) for col in (D_GD1, D_GQ1, D_GD2, D_GQ2, D_GQD, D_XD, D_XQ, D_XDP, D_XQP, D_XDPP,
                                         D_XL, D_ITQ0P, D_ITQ0PP, D_IM, D_DAMP, D_W0, D_RA, D_GT, D_BT, D_VINF,
                                         D_TM, D_E1Q0, D_E2D0, D_E1D0, D_E2Q0, D_DELTA0, D_GVALID, D_SAL, D_KQ)}
    fld0 = np.ones(n)
    sat = np.array([_derived.saturation_ab.py_func(s10, s12) for s10, s12 in P[:, [COL["S10"], COL["S12"]]]])
    sat_a, sat_b = (sat[:, 0], sat[:, 1]) if n else (np.zeros(0), np.zeros(0))
    m = {name: M[:, j] for name, j in MCOL.items()}
    sal = P[:, COL["SATEQ"]] > 0.5   # a GENSAL: saturation on E'q, one q-axis circuit
    xd, xq, x1d, x2, xl = m["XD"], m["XQ"], m["XDP"], m["XDPP"], m["XLS"]
    x1q = np.where(sal, xq, m["XQP"])
    vt0, p0, q0 = P[:, COL["Vt0"]], m["P0"], m["Q0"]
    ok = ((xd > x1d) & (x1d > x2) & (x2 > xl) & (xl >= 0.0) & (xq >= x1q) & (x1q >= x2) & (xq > x2)
          & (sal | (m["Tq0p"] > 0)) & (m["Tq0pp"] > 0) & (m["H"] > 0) & (vt0 > 0))
    if not ok.any():
        return out, fld0
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
    put = {D_GD1: gd1, D_GQ1: gq1, D_GD2: gd2, D_GQ2: gq2, D_GQD: gqd, D_XD: xd, D_XQ: xq, D_XDP: x1d,
           D_XQP: x1q, D_XDPP: x2, D_XL: xl,
           D_ITQ0P: np.where(sal, 0.0, 1.0 / np.where(sal, 1.0, m["Tq0p"])), D_ITQ0PP: 1.0 / m["Tq0pp"],
           D_SAL: sal, D_KQ: np.where(sal, xq - x2, x1q - xl), D_IM: 1.0 / (2.0 * m["H"]), D_DAMP: m["DAMP"],
           D_W0: 2.0 * math.pi * m["FN"], D_RA: ra, D_GT: rt / (rt * rt + xt * xt), D_BT: xt / (rt * rt + xt * xt),
           D_VINF: np.abs(vinf), D_TM: p0 + ra * np.abs(it) ** 2, D_E1Q0: e1q0, D_E2D0: e1q0 - (x1d - xl) * id0,
           D_E1D0: np.where(sal, 0.0, iq0 * (xq - x1q) - se0 * gqd * psi2q0),
           D_E2Q0: np.where(sal, psi2q0, -iq0 * (xl - xq) - se0 * gqd * psi2q0),
           D_DELTA0: delta0 - np.angle(vinf), D_GVALID: 1.0}   # (the infinite bus at angle 0)
    for col, values in put.items():
        out[col][k] = values
    fld0[k] = (se0 + 1.0) * psi2d0 + (xd - x2) * id0 + sat_eq
    return out, fld0

# ---- the compiled machine -----------------------------------------------------------------------


@njit
def load(S, c):
    return S[6, c], S[7, c], S[8, c], S[9, c], S[10, c], S[11, c], S[12, c]


@njit
def store(S, c, x):
    S[6, c] = x[0]
    S[7, c] = x[1]
    S[8, c] = x[2]
    S[9, c] = x[3]
    S[10, c] = x[4]
    S[11, c] = x[5]
    S[12, c] = x[6]


@njit
def axpy(x, k, h):
    return (x[0] + h * k[0], x[1] + h * k[1], x[2] + h * k[2], x[3] + h * k[3], x[4] + h * k[4], x[5] + h * k[5],
            x[6] + h * k[6])


@njit
def combine(x, a, b, c, d, h6):
    return (x[0] + h6 * (a[0] + 2.0 * b[0] + 2.0 * c[0] + d[0]), x[1] + h6 * (a[1] + 2.0 * b[1] + 2.0 * c[1] + d[1]),
            x[2] + h6 * (a[2] + 2.0 * b[2] + 2.0 * c[2] + d[2]), x[3] + h6 * (a[3] + 2.0 * b[3] + 2.0 * c[3] + d[3]),
            x[4] + h6 * (a[4] + 2.0 * b[4] + 2.0 * c[4] + d[4]), x[5] + h6 * (a[5] + 2.0 * b[5] + 2.0 * c[5] + d[5]),
            x[6] + h6 * (a[6] + 2.0 * b[6] + 2.0 * c[6] + d[6]))


@njit
def algebra(D, c, t, x, ext):
    """(Vt, XadIfd, Id, Iq, P, Q, Te, XaqI1q) at the states x."""
    e1q, e2d, e1d, e2q, sd, cd, _w = x
    gd1 = D[D_GD1, c]
    gq1 = D[D_GQ1, c]
    psd = gd1 * e1q + (1.0 - gd1) * e2d
    psq = gq1 * e1d + (1.0 - gq1) * e2q
    psi = math.sqrt(psd * psd + psq * psq)
    sal = D[D_SAL, c]
    s = psi - D[D_SATA, c]
    s = s if s > 0.0 else 0.0
    se = (1.0 - sal) * D[D_SATB, c] * s * s / (psi if psi > 1.0e-6 else 1.0e-6)
    xs = e1q - D[D_SATA, c]
    xs = xs if xs > 0.0 else 0.0
    sat_eq = sal * D[D_SATB, c] * xs * xs   # a GENSAL's Sat(E'q)
    vinf = D[D_VINF, c]
    ar = psq - vinf * sd
    ai = psd - vinf * cd
    gt = D[D_GT, c]
    bt = D[D_BT, c]
    cid = ar * gt + ai * bt
    ciq = ai * gt - ar * bt
    ra = D[D_RA, c]
    x2 = D[D_XDPP, c]
    vd = psq - ra * cid + x2 * ciq
    vq = psd - ra * ciq - x2 * cid
    vt = math.sqrt(vd * vd + vq * vq)
    p = vd * cid + vq * ciq
    q = vq * cid - vd * ciq
    te = p + ra * (cid * cid + ciq * ciq)
    ifd = e1q + (D[D_XD, c] - D[D_XDP, c]) * (gd1 * cid + D[D_GD2, c] * (e1q - e2d)) + se * psd + sat_eq
    xaq = e1d + (D[D_XQ, c] - D[D_XQP, c]) * (D[D_GQ2, c] * (e1d - e2q) - gq1 * ciq) + se * psq * D[D_GQD, c]
    return vt, ifd, cid, ciq, p, q, te, xaq


@njit
def alg_load(R, c):
    return R[2, c], R[3, c], R[4, c], R[5, c], R[6, c], R[7, c], R[8, c], R[9, c]


@njit
def alg_store(R, c, a):
    R[2, c] = a[0]
    R[3, c] = a[1]
    R[4, c] = a[2]
    R[5, c] = a[3]
    R[6, c] = a[4]
    R[7, c] = a[5]
    R[8, c] = a[6]
    R[9, c] = a[7]


@njit
def signals(a):
    """(Vt, Ifd, P, Q) of the algebra a."""
    return a[0], a[1], a[4], a[5]


@njit
def speed(x):
    return x[6]


@njit
def power(a):
    return a[6]


@njit
def rhs(D, c, t, x, a, fld, ext):
    """The derivatives at field voltage `fld` and the algebra a: E'q, psikd, E'd, psikq, the rotor
    angle's sine and cosine (turned at the slip speed) and the speed; the ceilings' motion is 0
    (held at a limit)."""
    x4, x5, x8, x9, x10, x11, x12 = x
    _vt, ifd, cid, ciq, _p, _q, te, xaq = a
    d4 = (fld - ifd) * D[D_ITD0P, c]
    d5 = (x4 - x5 - (D[D_XDP, c] - D[D_XL, c]) * cid) * D[D_ITD0PP, c]
    d8 = -xaq * D[D_ITQ0P, c]
    d9 = (x8 - x9 + D[D_KQ, c] * ciq) * D[D_ITQ0PP, c]
    wd = D[D_W0, c] * (x12 - 1.0)
    d12 = (D[D_TM, c] - te - D[D_DAMP, c] * (x12 - 1.0)) * D[D_IM, c]
    return (d4, d5, d8, d9, x11 * wd, -x10 * wd, d12), 0.0, 0.0


@njit
def end(D, c, x):
    """After an RK4 step: the rotor angle's sine and cosine put back on the unit circle (one Newton
    step of 1 / sqrt(s^2 + co^2) from 1: an RK4 step leaves the pair on the circle to far below the
    rounding, its error is the square of the drift, with no sqrt or division)."""
    s = x[4]
    co = x[5]
    f = 1.5 - 0.5 * (s * s + co * co)
    return x[0], x[1], x[2], x[3], s * f, co * f, x[6]


@njit
def park(D, c):
    """The states at the operating point."""
    return (D[D_E1Q0, c], D[D_E2D0, c], D[D_E1D0, c], D[D_E2Q0, c], math.sin(D[D_DELTA0, c]),
            math.cos(D[D_DELTA0, c]), 1.0)


@njit
def valid(D, c):
    return D[D_GVALID, c] != 0.0


@njit
def flux(x):
    """E'q (a plant reports it)."""
    return x[0]


def steady_field(P: np.ndarray, M: np.ndarray) -> np.ndarray:
    """The field voltage XadIfd0 of the candidates P at their operating points on the grid M (1 for
    a candidate whose machine data are out of order)."""
    return _machine_columns(np.atleast_2d(np.asarray(P, float)), np.atleast_2d(np.asarray(M, float)))[1]
