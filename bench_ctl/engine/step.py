"""The RK4 step of every machine and block, and the loop that runs it over a chunk's candidates.

The step is written once against the seam's slots -- the excitation system (`exc_*`), the machine
(`gen_*`), the stabiliser (`pss_*`) -- which a variant binds to one plug-in each (`variants`); until
then they hold the no-load machine under every block without a stabiliser. A stage: the machine's
algebra at its states (Vt, Ifd, ...), the stabiliser's output from the speed and the power, the
ceilings at Vt and Ifd, the exciter's derivatives and field voltage, the machine's derivatives at
that field voltage, then the exciter's non-windup ceilings moving as the machine moves Vt and Ifd.

Numerics (docs/decisions/0003): classical RK4; the reference moves linearly from u0 to u1 over the
step (a setpoint ramp; constant otherwise) and the dead time's delayed VR is read at the stage
times (v0, vm, v1); after the step the machine's states are put back where they belong (the rotor
angle's sine and cosine on the unit circle) and the regulator lag inside its ceilings at the new
Vt and Ifd. The step returns the field voltage and the stabiliser's output there and the output's
slope at both ends (the recorder skew's readout interpolates with them).
"""
from __future__ import annotations

from numba.core import types
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

from . import exciter as _exciter
from .exciter import ST4_SOME, ceilings_at, limit_motion
from .jit import njit
from .layout import CHUNK, N_DERIVED
from .machines import noload as _noload
from .stabilisers import none as _none

#: the rows of a chunk's state array (the exciter's six, the largest machine's seven, the largest
#: stabiliser's: PSS2A / PSS2B's seventeen), of its readout array (field voltage, stabiliser
#: output, the largest machine algebra), and of its step-input array U (u0, u1, v0, vm, v1)
N_ROWS = 30
#: the rows a variant's states use (the runner's copies and blow-up test read no more): a slot
#: (`variants`), all of them until bound
ROWS = N_ROWS
N_READOUT = 10
N_INPUT = 5

# ---- the seam's slots: `variants.specialise` binds them per variant -----------------------------
ST4 = ST4_SOME
exc_load, exc_store, exc_axpy, exc_combine = (_exciter.full_load, _exciter.full_store, _exciter.full_axpy,
                                              _exciter.full_combine)
exc_rhs, exc_limit, exc_output, exc_clamp = (_exciter.full_rhs, _exciter.full_limit, _exciter.full_output,
                                             _exciter.full_clamp)
exc_slope, exc_vr, exc_park = _exciter.full_slope, _exciter.full_vr, _exciter.full_park
gen_load, gen_store, gen_axpy, gen_combine = _noload.load, _noload.store, _noload.axpy, _noload.combine
gen_algebra, gen_alg_load, gen_alg_store, gen_signals = (_noload.algebra, _noload.alg_load, _noload.alg_store,
                                                         _noload.signals)
gen_speed, gen_power, gen_rhs, gen_end, gen_park, gen_valid, gen_flux = (
    _noload.speed, _noload.power, _noload.rhs, _noload.end, _noload.park, _noload.valid, _noload.flux)
pss_load, pss_store, pss_axpy, pss_combine = _none.load, _none.store, _none.axpy, _none.combine
pss_rhs, pss_output, pss_park = _none.rhs, _none.output, _none.park

# ---- a stage and the step -----------------------------------------------------------------------


@njit
def stage_at(D, c, t, u, vrd, xa, xg, xs, alg, ext):
    """The derivatives of the exciter's, the machine's and the stabiliser's states at reference u,
    delayed VR vrd, instant t (steps from the record's start) and the machine's algebra `alg` at
    xg; the field voltage."""
    vt, ifd = alg[0], alg[1]
    vs, dxs = pss_rhs(D, c, xs, gen_speed(xg), gen_power(alg))
    hi, lo = ceilings_at(D, c, vt, ifd)
    dxa, fld = exc_rhs(D, c, u + vs, vrd, xa, vt, ifd, hi, lo, ST4)
    dxg, dvt, difd = gen_rhs(D, c, t, xg, alg, fld, ext)
    dhi, dlo = limit_motion(D, c, dvt, difd)
    return exc_limit(D, c, dxa, xa, hi, lo, dhi, dlo, ST4), dxg, dxs, alg


@njit
def stage(D, c, t, u, vrd, xa, xg, xs, ext):
    """`stage_at` with the machine's algebra solved at xg."""
    return stage_at(D, c, t, u, vrd, xa, xg, xs, gen_algebra(D, c, t, xg, ext), ext)


@njit
def rk4(D, c, when, u, v, xa, xg, xs, alg0, ext):
    """One RK4 step from states (xa, xg, xs) with the machine's algebra alg0 there. when = (t,
    the length in steps, the length in s); u = (u0, u1) the reference at both ends; v = (v0, vm,
    v1) the delayed VR at the stage times. Returns (xa, xg, xs, the algebra, the field voltage,
    the stabiliser's output) at the step's end and the output's slope at both ends."""
    t, hs, h = when
    u0, u1 = u
    v0, vm, v1 = v
    um = 0.5 * (u0 + u1)
    h2 = 0.5 * h
    tm = t + 0.5 * hs
    a = stage_at(D, c, t, u0, v0, xa, xg, xs, alg0, ext)
    b = stage(D, c, tm, um, vm, exc_axpy(xa, a[0], h2), gen_axpy(xg, a[1], h2), pss_axpy(xs, a[2], h2), ext)
    k = stage(D, c, tm, um, vm, exc_axpy(xa, b[0], h2), gen_axpy(xg, b[1], h2), pss_axpy(xs, b[2], h2), ext)
    xad = exc_axpy(xa, k[0], h)
    d = stage(D, c, t + hs, u1, v1, xad, gen_axpy(xg, k[1], h), pss_axpy(xs, k[2], h), ext)
    h6 = h / 6.0
    yg = gen_end(D, c, gen_combine(xg, a[1], b[1], k[1], d[1], h6))
    ys = pss_combine(xs, a[2], b[2], k[2], d[2], h6)
    alg = gen_algebra(D, c, t + hs, yg, ext)
    vt, ifd = alg[0], alg[1]
    hi, lo = ceilings_at(D, c, vt, ifd)
    ya = exc_clamp(D, c, exc_combine(xa, a[0], b[0], k[0], d[0], h6), hi, lo, ST4)
    fld = exc_output(D, c, ya, vt, ifd, hi, lo, ST4)
    vs = pss_output(D, c, ys, gen_speed(yg), gen_power(alg))
    m0 = exc_slope(D, c, xa, a[0], alg0[0], alg0[1], ST4)
    m1 = exc_slope(D, c, xad, d[0], d[3][0], d[3][1], ST4)
    return ya, yg, ys, alg, fld, vs, m0, m1


@njit
def readout(D, c, xa, xg, xs, ext, t):
    """The machine's algebra, the field voltage and the stabiliser's output at the states (a run's
    start, a candidate parked, a step redone in sub-steps)."""
    alg = gen_algebra(D, c, t, xg, ext)
    hi, lo = ceilings_at(D, c, alg[0], alg[1])
    return alg, exc_output(D, c, xa, alg[0], alg[1], hi, lo, ST4), pss_output(D, c, xs, gen_speed(xg),
                                                                                gen_power(alg))

# ---- the loop over a chunk's candidates ---------------------------------------------------------


def fixed_view(rows: int):
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


view_d, view_s, view_r, view_u, view_m = (fixed_view(r) for r in (N_DERIVED, N_ROWS, N_READOUT, N_INPUT, 2))


@njit(fastmath=False)
def check_chunk(D, S, R, U, M):
    """The chunk's arrays have the shapes the fixed views give them."""
    if (D.shape[0] != N_DERIVED or S.shape[0] != N_ROWS or R.shape[0] != N_READOUT or U.shape[0] != N_INPUT
            or M.shape[0] != 2 or D.shape[1] != CHUNK or S.shape[1] != CHUNK or R.shape[1] != CHUNK
            or U.shape[1] != CHUNK or M.shape[1] != CHUNK):
        raise ValueError("engine chunk arrays of the wrong shape")


@njit(vector=True)
def step_all(D, S, R, U, M, k, dt, m, ext):
    """One RK4 step of sample k for every candidate c < m of a chunk: states S[:, c], the readout
    R[:, c] (the algebra the step starts from; the step's end is written back), the inputs
    U[:, c] (u0, u1, v0, vm, v1), the output's slopes at both ends into M[:, c]. A branch-free
    loop LLVM vectorises across c: each array is seen with a constant shape, so LLVM checks the
    arrays for overlap once before the loop instead of every row against every other
    (docs/decisions/0003). A function of its own:
    inside the chunk runner numba's reference counting of the arrays stops the vectoriser."""
    check_chunk(D, S, R, U, M)
    D = view_d(D)
    S = view_s(S)
    R = view_r(R)
    U = view_u(U)
    M = view_m(M)
    t = k * 1.0
    for c in range(m):
        r = rk4(D, c, (t, 1.0, dt), (U[0, c], U[1, c]), (U[2, c], U[3, c], U[4, c]), exc_load(S, c),
                gen_load(S, c), pss_load(S, c), gen_alg_load(R, c), ext)
        exc_store(S, c, r[0])
        gen_store(S, c, r[1])
        pss_store(S, c, r[2])
        gen_alg_store(R, c, r[3])
        R[0, c] = r[4]
        R[1, c] = r[5]
        M[0, c] = r[6]
        M[1, c] = r[7]
