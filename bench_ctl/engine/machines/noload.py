"""The d-axis generator at no load: T'd0 dE'q/dt = Efd - E'q - KDA (E'q - E''q) - Sat,
T''d0 dE''q/dt = E'q - E''q, Vt = E''q + KPP (E'q - E''q) (KPP = KDA = 0: the reference model;
a GENROU's flux shares otherwise, saturation then on Vt = psi'' unless SATEQ); Id = Iq = 0, so P
and Q are 0 and the field current is E'q + KDA (E'q - E''q) + Sat. States (E'q, E''q), algebra
(Vt, Ifd). Its ceilings move with Vt and Ifd as the machine's derivatives move them.
"""
from __future__ import annotations

from ..jit import njit
from ..layout import D_ITD0P, D_ITD0PP, D_KDA, D_KPP, D_SATA, D_SATB, D_SATVT, D_VT0

#: the machine's states in a chunk's state array (after the exciter's six rows), its algebra's
#: rows in the readout array (after the field voltage and the stabiliser's output)
N_STATES = 2
N_ALG = 2


@njit
def load(S, c):
    return S[6, c], S[7, c]


@njit
def store(S, c, x):
    S[6, c] = x[0]
    S[7, c] = x[1]


@njit
def axpy(x, k, h):
    return x[0] + h * k[0], x[1] + h * k[1]


@njit
def combine(x, a, b, c, d, h6):
    return x[0] + h6 * (a[0] + 2.0 * b[0] + 2.0 * c[0] + d[0]), x[1] + h6 * (a[1] + 2.0 * b[1] + 2.0 * c[1] + d[1])


@njit
def _sat_arg(D, c, eqp, vt):
    """x - A of the saturation B (x - A)^2: x = E'q, or Vt with a GENROU's flux share; >= 0."""
    d = eqp + D[D_SATVT, c] * (vt - eqp) - D[D_SATA, c]
    return d if d > 0.0 else 0.0


@njit
def algebra(D, c, t, x, ext):
    """(Vt, Ifd) at the states x = (E'q, E''q)."""
    eqp, eqpp = x
    vt = eqpp + D[D_KPP, c] * (eqp - eqpp)
    d = _sat_arg(D, c, eqp, vt)
    return vt, eqp + D[D_KDA, c] * (eqp - eqpp) + D[D_SATB, c] * d * d


@njit
def alg_load(R, c):
    return R[2, c], R[3, c]


@njit
def alg_store(R, c, a):
    R[2, c] = a[0]
    R[3, c] = a[1]


@njit
def signals(a):
    """(Vt, Ifd, P, Q) of the algebra a."""
    return a[0], a[1], 0.0, 0.0


@njit
def speed(x):
    return 1.0


@njit
def power(a):
    return 0.0


@njit
def rhs(D, c, t, x, a, fld, ext):
    """The derivatives at field voltage `fld`, and how fast Vt and Ifd move (dVt, dIfd)."""
    eqp, eqpp = x
    satvt = D[D_SATVT, c]
    d = _sat_arg(D, c, eqp, a[0])
    deqp = (fld - eqp - D[D_KDA, c] * (eqp - eqpp) - D[D_SATB, c] * d * d) * D[D_ITD0P, c]
    deqpp = (eqp - eqpp) * D[D_ITD0PP, c]
    dvt = deqpp + D[D_KPP, c] * (deqp - deqpp)
    difd = deqp + D[D_KDA, c] * (deqp - deqpp) + 2.0 * D[D_SATB, c] * d * (deqp + satvt * (dvt - deqp))
    return (deqp, deqpp), dvt, difd


@njit
def end(D, c, x):
    return x


@njit
def park(D, c):
    """The states at the steady state: E'q = E''q = Vt0."""
    return D[D_VT0, c], D[D_VT0, c]


@njit
def valid(D, c):
    return True


@njit
def flux(x):
    """E'q (a plant reports it)."""
    return x[0]
