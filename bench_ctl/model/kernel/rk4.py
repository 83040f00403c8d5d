"""The RK4 step and the loops that run it over a chunk's candidates (vectorised across them),
the fixed-shape views those loops need, and the step split at a jump inside it.
"""
from __future__ import annotations

from numba.core import types
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

from .blocks import (
    avr,
    ceilings,
    ceilings_ref,
    delayed_vr,
    field_voltage,
    output_slope,
    rate_feedback,
    terminal_voltage,
)
from .jit import njit
from .layout import (
    BLOWUP,
    CHUNK,
    D_DCON,
    D_GAIN,
    D_ITR,
    D_LIMOUT,
    D_OUTK,
    D_RAMP,
    D_UREF0,
    D_VR0,
    N_DERIVED,
    ST4_ALL,
    ST4_NONE,
    ST4_SOME,
)
from .rhs import rhs, rhs_ref

# ---- the RK4 step of one candidate -------------------------------------------------------------


@njit()
def rk4_step(D, i, u0, u1, v0, vm, v1, x0, x1, x2, x3, x4, x5, x6, x7, h, st4=ST4_SOME):
    """One RK4 step of length h with input u0 -> u1 (linear) and delayed VR v0, vm, v1. Returns
    the 8 states and the output's derivative at both ends (the DC exciter's Efd, else VR lag)."""
    um = 0.5 * (u0 + u1)
    h2 = 0.5 * h
    a = rhs(D, i, u0, v0, x0, x1, x2, x3, x4, x5, x6, x7, st4)
    b = rhs(D, i, um, vm, x0 + h2 * a[0], x1 + h2 * a[1], x2 + h2 * a[2], x3 + h2 * a[3], x4 + h2 * a[4],
             x5 + h2 * a[5], x6 + h2 * a[6], x7 + h2 * a[7], st4)
    c = rhs(D, i, um, vm, x0 + h2 * b[0], x1 + h2 * b[1], x2 + h2 * b[2], x3 + h2 * b[3], x4 + h2 * b[4],
             x5 + h2 * b[5], x6 + h2 * b[6], x7 + h2 * b[7], st4)
    d = rhs(D, i, u1, v1, x0 + h * c[0], x1 + h * c[1], x2 + h * c[2], x3 + h * c[3], x4 + h * c[4],
             x5 + h * c[5], x6 + h * c[6], x7 + h * c[7], st4)
    h6 = h / 6.0
    y3 = x3 + h6 * (a[3] + 2 * b[3] + 2 * c[3] + d[3])
    y4 = x4 + h6 * (a[4] + 2 * b[4] + 2 * c[4] + d[4])
    y5 = x5 + h6 * (a[5] + 2 * b[5] + 2 * c[5] + d[5])
    if st4 != ST4_ALL:   # (ESST4B's lag is not limited)
        hi, lo = ceilings(D, i, y4, y5)
        z3 = y3 if y3 > lo else lo
        z3 = z3 if z3 < hi else hi
        y3 = z3 + D[D_LIMOUT, i] * (y3 - z3)   # a lag that the ceilings do not limit winds up
    dcon = D[D_DCON, i]
    # the output's slope at both ends (for the recorder-skew readout): the DC exciter's or the
    # regulator lag's, or VB dVM/dt of the potential-source stage (at the end: at the state of
    # RK4's last stage, as for the others)
    outk = D[D_OUTK, i]   # (the AC exciter's Efd = VE FEX: FEX's own change left out)
    m0 = a[3] + dcon * (outk * a[7] - a[3])
    m1 = d[3] + dcon * (outk * d[7] - d[3])
    if st4 != ST4_NONE:
        m0 = output_slope(D, i, x3, x6, x4, x5, a[3], a[6], m0, st4)
        m1 = output_slope(D, i, x3 + h * c[3], x6 + h * c[6], x4 + h * c[4], x5 + h * c[5], d[3], d[6], m1, st4)
    return (x0 + h6 * (a[0] + 2 * b[0] + 2 * c[0] + d[0]), x1 + h6 * (a[1] + 2 * b[1] + 2 * c[1] + d[1]),
            x2 + h6 * (a[2] + 2 * b[2] + 2 * c[2] + d[2]), y3, y4, y5,
            x6 + h6 * (a[6] + 2 * b[6] + 2 * c[6] + d[6]), x7 + h6 * (a[7] + 2 * b[7] + 2 * c[7] + d[7]),
            m0, m1)


@njit()
def rk4_step_ref(D, i, u0, u1, v0, vm, v1, x0, x1, x2, x3, x4, x5, h, limited):
    """`rk4_step` on the reference blocks only (see `rhs_ref`, and its `limited`)."""
    um = 0.5 * (u0 + u1)
    h2 = 0.5 * h
    a = rhs_ref(D, i, u0, v0, x0, x1, x2, x3, x4, x5, limited)
    b = rhs_ref(D, i, um, vm, x0 + h2 * a[0], x1 + h2 * a[1], x2 + h2 * a[2], x3 + h2 * a[3],
                x4 + h2 * a[4], x5 + h2 * a[5], limited)
    c = rhs_ref(D, i, um, vm, x0 + h2 * b[0], x1 + h2 * b[1], x2 + h2 * b[2], x3 + h2 * b[3],
                x4 + h2 * b[4], x5 + h2 * b[5], limited)
    d = rhs_ref(D, i, u1, v1, x0 + h * c[0], x1 + h * c[1], x2 + h * c[2], x3 + h * c[3], x4 + h * c[4],
                x5 + h * c[5], limited)
    h6 = h / 6.0
    y3 = x3 + h6 * (a[3] + 2 * b[3] + 2 * c[3] + d[3])
    y4 = x4 + h6 * (a[4] + 2 * b[4] + 2 * c[4] + d[4])
    y5 = x5 + h6 * (a[5] + 2 * b[5] + 2 * c[5] + d[5])
    if limited:
        hi, lo = ceilings_ref(D, i, y4, y5)
        y3 = y3 if y3 > lo else lo
        y3 = y3 if y3 < hi else hi
    return (x0 + h6 * (a[0] + 2 * b[0] + 2 * c[0] + d[0]), x1 + h6 * (a[1] + 2 * b[1] + 2 * c[1] + d[1]),
            x2 + h6 * (a[2] + 2 * b[2] + 2 * c[2] + d[2]), y3, y4, y5, a[3], d[3])

# ---- the loops over a chunk's candidates -------------------------------------------------------


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


_view_d, _view_s, _view_u, _view_v, _view_w = (_fixed_view(r) for r in (N_DERIVED, 10, 2, 3, 4))


@njit(fastmath=False)
def fixed_views(D, S, U, V):
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


@njit(inline=False)
def rk4_all(D, S, U, V, dt, m):
    """One RK4 step for every candidate of a chunk: a branch-free loop LLVM vectorises across c.

    Only four arrays take part (D, V read; U = [u at start, u at end] read; S = 8 states plus the
    output's derivative at both ends, written), each seen with a constant shape (`fixed_views`), so
    LLVM checks them for overlap once per array before the loop. Kept as its own function: inside
    the big chunk loop numba's reference counting of the array arguments stops the vectoriser."""
    D, S, U, V = fixed_views(D, S, U, V)
    for c in range(m):
        r = rk4_step(D, c, U[0, c], U[1, c], V[0, c], V[1, c], V[2, c], S[0, c], S[1, c], S[2, c], S[3, c],
                 S[4, c], S[5, c], S[6, c], S[7, c], dt, ST4_NONE)
        S[0, c] = r[0]
        S[1, c] = r[1]
        S[2, c] = r[2]
        S[3, c] = r[3]
        S[4, c] = r[4]
        S[5, c] = r[5]
        S[6, c] = r[6]
        S[7, c] = r[7]
        S[8, c] = r[8]
        S[9, c] = r[9]


@njit(inline=False)
def rk4_all_st4(D, S, U, V, dt, m):
    """`rk4_all` with the potential-source stage selected per candidate (a chunk where some valid
    candidates have it and others not)."""
    D, S, U, V = fixed_views(D, S, U, V)
    for c in range(m):
        r = rk4_step(D, c, U[0, c], U[1, c], V[0, c], V[1, c], V[2, c], S[0, c], S[1, c], S[2, c], S[3, c],
                 S[4, c], S[5, c], S[6, c], S[7, c], dt, ST4_SOME)
        S[0, c] = r[0]
        S[1, c] = r[1]
        S[2, c] = r[2]
        S[3, c] = r[3]
        S[4, c] = r[4]
        S[5, c] = r[5]
        S[6, c] = r[6]
        S[7, c] = r[7]
        S[8, c] = r[8]
        S[9, c] = r[9]


@njit(inline=False)
def rk4_all_st4_only(D, S, U, V, dt, m):
    """`rk4_all` of a chunk whose valid candidates all have the potential-source stage (ESST4B)."""
    D, S, U, V = fixed_views(D, S, U, V)
    for c in range(m):
        r = rk4_step(D, c, U[0, c], U[1, c], V[0, c], V[1, c], V[2, c], S[0, c], S[1, c], S[2, c], S[3, c],
                 S[4, c], S[5, c], S[6, c], S[7, c], dt, ST4_ALL)
        S[0, c] = r[0]
        S[1, c] = r[1]
        S[2, c] = r[2]
        S[3, c] = r[3]
        S[4, c] = r[4]
        S[5, c] = r[5]
        S[6, c] = r[6]
        S[7, c] = r[7]
        S[8, c] = r[8]
        S[9, c] = r[9]


@njit(inline=False)
def rk4_all_ref(D, S, U, V, dt, m):
    """`rk4_all` on the reference blocks only: states 6, 7 (rate feedback, DC exciter) untouched."""
    D, S, U, V = fixed_views(D, S, U, V)
    for c in range(m):
        r = rk4_step_ref(D, c, U[0, c], U[1, c], V[0, c], V[1, c], V[2, c], S[0, c], S[1, c], S[2, c], S[3, c],
                     S[4, c], S[5, c], dt, True)
        S[0, c] = r[0]
        S[1, c] = r[1]
        S[2, c] = r[2]
        S[3, c] = r[3]
        S[4, c] = r[4]
        S[5, c] = r[5]
        S[8, c] = r[6]
        S[9, c] = r[7]


@njit(inline=False)
def run_span_ref(D, S, W, usetp, efd_meas, k0, k1, usetp_pre, dt, m, store, efd_out, vt_out, lo):
    """Samples and steps k0..k1-1 of a chunk on the reference blocks alone where nothing else acts
    (no dead time, skew, setpoint ramp or fitted edge; efd scored, Vt not): each sample's output
    into the squared error (and with `store` into the traces, rows lo.. of `efd_out`, `vt_out`),
    then the step, in one loop over time with a vectorised loop over the candidates inside: what
    `run_chunk` does step by step, without its per-step calls and small loops, which cost about as
    much as a step of one candidate.

    W: the output (row 0, held where failed), failed (row 1, 1.0), the sum of squared efd errors
    (row 2), the state's magnitude after the step (row 3, the blow-up test). Returns the step
    count done: k1, or the step after which some candidate blew up (its state is at t_k+1; the
    caller parks it). The output's slopes (S rows 8, 9, for the skew) are not written."""
    return _span_ref(D, S, W, usetp, efd_meas, k0, k1, usetp_pre, dt, m, store, efd_out, vt_out, lo, True)


@njit(inline=False)
def run_span_unlimited(D, S, W, usetp, efd_meas, k0, k1, usetp_pre, dt, m, store, efd_out, vt_out, lo):
    """`run_span_ref` of a chunk none of whose candidates has a slew limit or a finite ceiling
    (`rhs_ref`'s `limited` False): the paper's unit. The same numbers without the limits'
    arithmetic, a third of a step's, which is also most of the chain a step of one candidate
    waits on."""
    return _span_ref(D, S, W, usetp, efd_meas, k0, k1, usetp_pre, dt, m, store, efd_out, vt_out, lo, False)


@njit()
def _span_ref(D, S, W, usetp, efd_meas, k0, k1, usetp_pre, dt, m, store, efd_out, vt_out, lo, limited):
    """`run_span_ref`'s body, `limited` a constant of its callers' code."""
    if (D.shape[0] != N_DERIVED or S.shape[0] != 10 or W.shape[0] != 4
            or D.shape[1] != CHUNK or S.shape[1] != CHUNK or W.shape[1] != CHUNK):
        raise ValueError("kernel chunk arrays of the wrong shape")
    D = _view_d(D)
    S = _view_s(S)
    W = _view_w(W)
    for k in range(k0, k1):
        em = efd_meas[k]
        base_u = usetp[k] - usetp_pre
        if store:  # a loop of its own: a trace's stores in the loop below stop its vectoriser
            for c in range(m):
                y = D[D_GAIN, c] * S[3, c]
                efd_out[lo + c, k] = W[0, c] if W[1, c] != 0.0 else y
                vt_out[lo + c, k] = terminal_voltage(D, c, S[4, c], S[5, c])
        blown = 0
        for c in range(m):
            y = D[D_GAIN, c] * S[3, c]
            y = W[0, c] if W[1, c] != 0.0 else y
            W[0, c] = y
            d = y - em
            W[2, c] += d * d
            u = D[D_UREF0, c] + base_u
            r = rk4_step_ref(D, c, u, u, 0.0, 0.0, 0.0, S[0, c], S[1, c], S[2, c], S[3, c], S[4, c], S[5, c], dt,
                             limited)
            S[0, c] = r[0]
            S[1, c] = r[1]
            S[2, c] = r[2]
            S[3, c] = r[3]
            S[4, c] = r[4]
            S[5, c] = r[5]
            mag = (abs(r[0]) + abs(r[1]) + abs(r[2]) + abs(r[3]) + abs(r[4]) + abs(r[5]) + abs(S[6, c])
                   + abs(S[7, c]))
            W[3, c] = mag
            blown += 0 if mag < BLOWUP else 1
        if blown:
            return k + 1
    return k1


# ---- a step with jumps inside ------------------------------------------------------------------


@njit(inline=False)
def split_step(D, c, k, dt, S, S0, nbrk, bs, bj, target, uref, base, td_on, L, vr_r, vr_l, jf, vjl, vjr,
                skew_on, Ls, kf, kef, kdl, kdr):
    """Step k of candidate c from the state S0 at t_k, in RK4 sub-steps between the break points
    bs[:nbrk] (sorted fractions of the step in (0, 1)): where the setpoint jumps inside the step
    (a fitted edge instant, the target jumps by bj there) and where the delayed VR jumps (a
    setpoint change, on a sample or at a fitted instant, seen through the dead time). Writes the
    state at t_k+1 into S; returns (setpoint reference at t_k+1, efd' at t_k, efd' at t_k+1).
    With `skew_on` the efd kink at the (first) setpoint jump is kept for the recorder-skew
    readout (`kf`, `kef`, `kdl`, `kdr`)."""
    x0, x1, x2, x3, x4, x5, x6, x7 = S0[0, c], S0[1, c], S0[2, c], S0[3, c], S0[4, c], S0[5, c], S0[6, c], S0[7, c]
    ramp = D[D_RAMP, c]
    ramp_on = ramp < 1.0e300
    e0 = D[D_VR0, c]
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
                va = delayed_vr(vr_r, vr_l, jf, vjl, vjr, c, L, base + sa, k, e0, False)
                vm = delayed_vr(vr_r, vr_l, jf, vjl, vjr, c, L, base + 0.5 * (sa + sb), k, e0, False)
                vb = delayed_vr(vr_r, vr_l, jf, vjl, vjr, c, L, base + sb, k, e0, True)
            r = rk4_step(D, c, ua, ub, va, vm, vb, x0, x1, x2, x3, x4, x5, x6, x7, h)
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
                vmeas = x0 if D[D_ITR, c] > 0.0 else terminal_voltage(D, c, x4, x5)
                vf = rate_feedback(D, c, x3, x6, x7, x4, x5)
                vjl[c, k % L] = avr(D, c, tg, vmeas, x1, x2, vf)[0]
                vjr[c, k % L] = avr(D, c, tg + bj[q], vmeas, x1, x2, vf)[0]
                jf[c, k % L] = sb
            if skew_on and kf[c, k % Ls] == 0.0 and not first:
                kf[c, k % Ls] = sb
                kef[c, k % Ls] = field_voltage(D, c, x3, x4, x5, x6, x7)
                kdl[c, k % Ls] = d_end
                pending = True
            tg += bj[q]
        sa = sb
    S[0, c] = x0
    S[1, c] = x1
    S[2, c] = x2
    S[3, c] = x3
    S[4, c] = x4
    S[5, c] = x5
    S[6, c] = x6
    S[7, c] = x7
    return (ur if ramp_on else tg), d_start, d_end
