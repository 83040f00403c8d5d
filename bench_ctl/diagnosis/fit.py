"""Fitting the reference model, with or without an effect, to one record (diagnosis engine).

A thin objective on the batched kernel (`run_kernel`) rather than the identification `Problem`:
the diagnosis fits on *windows* of a capture and on a decimated copy (`coarse_record`) for its
searches, starts from many warm points, and needs every fit driven to its local minimum, so that
the MSE of "base model" and "base model + effect" differ by what the effect explains and not by
how far an optimizer happened to get. Tools: `fit` = MVMO (vectorised, one kernel call per
generation, optionally in a box around a start) followed by `polish`, a bounded least-squares
run (scipy `least_squares`, TRF) whose forward-difference Jacobian is one kernel call of `d`
candidates. Small kernel calls run on one thread (`SMALL_CALL`).

Parameters are searched in a normalised space `u` in [0, 1]: logarithmic for strictly positive
parameters whose bounds span a decade or more (gains, time constants, rates), linear otherwise.
Constraints (unit file and effect) are linear in the physical parameters; constraints on
parameters that are not free are evaluated at their fixed values.
"""
from __future__ import annotations

import logging
import math
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Iterator, Mapping, Sequence

import numba
import numpy as np
from scipy.optimize import least_squares

from bench_ctl.capture import Capture
from bench_ctl.identification import mvmo
from bench_ctl.identification.constraints import parse_constraints
from bench_ctl.identification.timing import EDGE_PARAMS, Edge, edge_spec, record_edges
from bench_ctl.model.edges import EdgeSpec
from bench_ctl.model.kernel import run_kernel
from bench_ctl.model.params import KERNEL_PARAMS
from bench_ctl.model.simulate import param_matrix, pre_trigger_mean
from bench_ctl.model.unit import Unit

log = logging.getLogger(__name__)

#: MVMO settings of the diagnosis' searches: the defaults (`mvmo.DEFAULT_OPTIONS`), whose local
#: searches from good particles late in the run find the AVR model's narrow basins more reliably
#: than one polish of the final best (profile fit of a ceiling case: 5 of 6 seeds against 2 of 6)
MVMO_OPTIONS: Mapping = {}

#: objective of a candidate whose simulation blew up (mse units; real MSEs are << 1)
FAIL_PENALTY = 1.0e3


@dataclass(frozen=True, eq=False)
class Record:
    """The part of a capture a model is fitted to or checked on (samples [0, n) of the capture)."""

    usetp: np.ndarray
    efd: np.ndarray
    dt: float
    usetp_pre: float
    label: str = ""
    edges: EdgeSpec = field(default_factory=EdgeSpec.none)  # moved by the EDGE offsets in use
    edge_list: tuple[Edge, ...] = ()                         # the same edges with their intervals

    @property
    def n(self) -> int:
        return int(self.efd.size)

    def edge_names(self) -> tuple[str, ...]:
        return tuple(EDGE_PARAMS[s] for s in self.edges.slot.tolist())


def record_of(capture: Capture, *, n: int | None = None, label: str = "", slot0: int = 0) -> Record:
    """The first `n` samples of a capture (all when None); usetp_pre from its pre-trigger part.
    Its setpoint edges get the EDGE columns from `slot0` on (those beyond the last stay nominal)."""
    pre = pre_trigger_mean(capture.usetp, capture.dt)
    m = capture.n if n is None else int(n)
    if not 2 <= m <= capture.n:
        raise ValueError(f"{capture.source or 'capture'}: window of {m} samples out of 2..{capture.n}")
    edges = [e for e in record_edges(capture)][: max(0, len(EDGE_PARAMS) - slot0)]
    inside = [(e, slot0 + i) for i, e in enumerate(edges) if e.index < m]
    return Record(np.ascontiguousarray(capture.usetp[:m]), np.ascontiguousarray(capture.efd[:m]),
                  capture.dt, pre, label or capture.source,
                  edge_spec([e for e, _ in inside], [s for _, s in inside]), tuple(e for e, _ in inside))


def coarse_record(rec: Record, *, q: int, n_max: int, offset: int = 0) -> Record:
    """Every q-th sample from `offset` (use the leading edge's index mod q so the edge stays on
    the coarse grid), at most up to sample n_max: the cheap record the global searches run on.
    The kernel integrates at the coarse step; a final polish on the full record removes the
    small bias this leaves."""
    q = max(1, int(q))
    n_max = min(int(n_max), rec.n)
    idx = np.arange(offset % q, n_max, q)
    if idx.size < 2:
        return rec
    e = rec.edges.decimated(q, offset, rec.dt)
    keep = e.index < idx.size
    edges = EdgeSpec(e.index[keep], e.jump[keep], e.nominal_s[keep], e.slot[keep])
    return Record(np.ascontiguousarray(rec.usetp[idx]), np.ascontiguousarray(rec.efd[idx]), rec.dt * q,
                  rec.usetp_pre, rec.label + f" (every {q}th sample)", edges, rec.edge_list)


LAGS = ("TA2", "TA4", "TE", "TR", "Td0pp")


def coarse_factor(unit: Unit, dt: float, target: float) -> int:
    """Decimation factor q for the coarse record: a step near `target` but not above the shortest
    lag the unit can have (RK4 at a step of one time constant is still accurate to ~2 % per step;
    at two it no longer decays right)."""
    shortest = math.inf
    values = unit.values()
    for name in LAGS:
        if name in unit.identify:
            lo = unit.identify[name].min
        else:
            lo = values.get(name, 0.0)
        if lo > 0:
            shortest = min(shortest, lo)
    step = min(target, shortest)
    return max(1, int(math.floor(step / dt + 1e-9)))


@dataclass(frozen=True, eq=False)
class Space:
    """Free parameters, their bounds and scaling, the fixed values, the constraints."""

    names: tuple[str, ...]
    lo: np.ndarray
    hi: np.ndarray
    base: Mapping[str, float]          # every kernel parameter (free ones are overwritten)
    constraints: tuple[str, ...] = ()
    log_scale: np.ndarray = field(default=None)  # type: ignore[assignment]
    _A: np.ndarray = field(default=None, repr=False)  # type: ignore[assignment]
    _b: np.ndarray = field(default=None, repr=False)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        lo = np.asarray(self.lo, float)
        hi = np.asarray(self.hi, float)
        if lo.shape != (len(self.names),) or hi.shape != lo.shape or not np.all(hi > lo):
            raise ValueError(f"bad bounds for {self.names}: {lo} .. {hi}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        object.__setattr__(self, "log_scale", (lo > 0) & (hi / np.where(lo > 0, lo, 1.0) >= 10.0))
        missing = set(KERNEL_PARAMS) - set(self.base)
        if missing:
            raise ValueError(f"no value for kernel parameter(s) {sorted(missing)}")
        # linear constraints A x <= b over the free names (fixed names folded into b)
        rows, rhs = [], []
        for con in parse_constraints(self.constraints, KERNEL_PARAMS):
            coef = dict(zip(KERNEL_PARAMS, con.coef))
            a = np.array([coef[n] for n in self.names])
            b = con.rhs - sum(c * float(self.base[n]) for n, c in coef.items() if n not in self.names and c)
            if np.any(a != 0.0):
                rows.append(a)
                rhs.append(b)
            elif b < -1e-12:
                raise ValueError(f"constraint {con.expr!r} is broken by the fixed parameter values")
        object.__setattr__(self, "_A", np.array(rows).reshape(len(rows), len(self.names)))
        object.__setattr__(self, "_b", np.array(rhs))

    @property
    def d(self) -> int:
        return len(self.names)

    def to_x(self, U: np.ndarray) -> np.ndarray:
        U = np.clip(np.asarray(U, float), 0.0, 1.0)
        lin = self.lo + U * (self.hi - self.lo)
        with np.errstate(divide="ignore"):
            lg = self.lo * np.exp(U * np.log(np.where(self.log_scale, self.hi / self.lo, 1.0)))
        return np.where(self.log_scale, lg, lin)

    def to_u(self, X: np.ndarray) -> np.ndarray:
        X = np.clip(np.asarray(X, float), self.lo, self.hi)
        lin = (X - self.lo) / (self.hi - self.lo)
        with np.errstate(divide="ignore", invalid="ignore"):
            lg = np.log(X / self.lo) / np.log(np.where(self.log_scale, self.hi / self.lo, 2.0))
        return np.where(self.log_scale, lg, lin)

    def violation(self, X: np.ndarray) -> np.ndarray:
        """Sum of constraint violations (physical units) per candidate row."""
        X = np.atleast_2d(X)
        if not self._A.size:
            return np.zeros(X.shape[0])
        return np.maximum(0.0, X @ self._A.T - self._b).sum(axis=1)

    def values(self, x: Sequence[float]) -> dict[str, float]:
        out = dict(self.base)
        out.update({n: float(v) for n, v in zip(self.names, x)})
        return out

    def matrix(self, X: np.ndarray) -> np.ndarray:
        return param_matrix(self.base, self.names, np.atleast_2d(X))


#: below this many candidate-steps a kernel call runs on one thread: waking the worker threads
#: costs more than it saves for the small batches of the least-squares polish, several times
#: more when the machine is busy (measured: 1 candidate x 1250 steps 21 ms on 2 threads under
#: load, 2.6 ms on one)
SMALL_CALL = 300_000


@contextmanager
def _threads_for(n_cand: int, n_steps: int) -> Iterator[None]:
    if n_cand * n_steps >= SMALL_CALL or numba.get_num_threads() == 1:
        yield
        return
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(old)


def kernel(P: np.ndarray, rec: Record, **kwargs) -> dict:
    """`run_kernel` on the record, on one thread for small batches (see SMALL_CALL)."""
    with _threads_for(P.shape[0], rec.n):
        return run_kernel(P, rec.usetp, rec.dt, rec.usetp_pre, edges=rec.edges, **kwargs)


def simulate_efd(space: Space, X: np.ndarray, rec: Record) -> tuple[np.ndarray, np.ndarray]:
    """Recorded-efd traces (n_cand, n) and failure flags of candidates X (physical units)."""
    out = kernel(space.matrix(X), rec, store=True)
    return out["efd"], out["fail_step"] >= 0


def mse_of(space: Space, X: np.ndarray, rec: Record) -> np.ndarray:
    """Per-candidate MSE of efd on the record; failed candidates get FAIL_PENALTY."""
    X = np.atleast_2d(X)
    out = kernel(space.matrix(X), rec, efd_meas=rec.efd, store=False)
    mse = out["sse_efd"] / rec.n
    return np.where(out["fail_step"] >= 0, FAIL_PENALTY + mse, mse)


@dataclass(frozen=True)
class FitResult:
    names: tuple[str, ...]
    x: np.ndarray
    mse: float
    evaluations: int
    feasible: bool
    message: str

    def params(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, self.x)}


def fit(space: Space, rec: Record, *, x0: Sequence[float] | None = None, evals: int = 400,
        seed: int = 0, box: float | None = None, polish_evals: int = 60,
        options: Mapping | None = None) -> FitResult:
    """MVMO (in a box of half-width `box` in normalised units around x0, or the full bounds)
    followed by a least-squares polish. `polish_evals` bounds the polish in kernel calls."""
    d = space.d
    u0 = space.to_u(np.asarray(x0, float)) if x0 is not None else None
    lo_u = np.zeros(d)
    hi_u = np.ones(d)
    if box is not None and u0 is not None:
        lo_u = np.clip(u0 - box, 0.0, 1.0)
        hi_u = np.clip(u0 + box, 0.0, 1.0)
        hi_u = np.where(hi_u - lo_u < 1e-6, np.minimum(lo_u + 1e-3, 1.0), hi_u)
        lo_u = np.minimum(lo_u, hi_u - 1e-3)
    nfev = 0

    def fun(U: np.ndarray) -> np.ndarray:
        nonlocal nfev
        U = np.atleast_2d(U)
        nfev += U.shape[0]
        return mse_of(space, space.to_x(U), rec)

    def viol(u: np.ndarray) -> float:
        return float(space.violation(space.to_x(u))[0])

    cons = (viol,) if space._A.size else ()
    best_u = u0
    best_f = math.inf
    if u0 is not None:
        best_f = float(fun(u0)[0])
        if space.violation(space.to_x(u0))[0] > 1e-9:
            best_f = math.inf
    if evals > 0:
        res = mvmo.minimize(fun, list(zip(lo_u, hi_u)), constraints=cons, max_evals=int(evals), seed=seed,
                            vectorized=True, x0=None if u0 is None else np.clip(u0, lo_u, hi_u),
                            options=dict(MVMO_OPTIONS if options is None else options))
        if res.feasible and res.fun < best_f:
            best_u, best_f = np.asarray(res.x, float), float(res.fun)
        elif best_u is None:
            best_u, best_f = np.asarray(res.x, float), float(res.fun)
    assert best_u is not None
    u, f, n_pol = polish(space, rec, best_u, max_calls=polish_evals)
    nfev += n_pol
    if f < best_f:
        best_u, best_f = u, f
    x = space.to_x(best_u)
    feasible = bool(space.violation(x)[0] <= 1e-9)
    return FitResult(space.names, x, float(best_f), nfev, feasible, "")


def polish(space: Space, rec: Record, u0: np.ndarray, *, max_calls: int = 60,
           step: float = 1e-5) -> tuple[np.ndarray, float, int]:
    """Bounded Gauss-Newton (TRF) from u0; returns (u, mse, simulations used)."""
    d = space.d
    sq = math.sqrt(rec.n)
    calls = 0
    cache: dict[bytes, np.ndarray] = {}

    def residual_batch(U: np.ndarray) -> np.ndarray:
        nonlocal calls
        X = space.to_x(U)
        efd, failed = simulate_efd(space, X, rec)
        calls += U.shape[0]
        r = (efd - rec.efd[None, :]) / sq
        r[failed] += math.sqrt(FAIL_PENALTY / rec.n)
        pen = 10.0 * space.violation(X)
        return np.concatenate([r, pen[:, None]], axis=1)

    def f(u: np.ndarray) -> np.ndarray:
        key = u.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = residual_batch(u[None, :])[0]
        return cache[key]

    def jac(u: np.ndarray) -> np.ndarray:
        r0 = f(u)
        h = np.where(u + step <= 1.0, step, -step)
        U = np.repeat(u[None, :], d, axis=0) + np.diag(h)
        R = residual_batch(U)
        return ((R - r0[None, :]) / h[:, None]).T

    try:
        res = least_squares(f, np.clip(u0, 0.0, 1.0), jac=jac, bounds=(0.0, 1.0), method="trf",
                            x_scale="jac", max_nfev=max(2, max_calls // (d + 1)), ftol=1e-7, xtol=1e-7)
        u = np.clip(res.x, 0.0, 1.0)
    except (ValueError, np.linalg.LinAlgError) as exc:  # pragma: no cover - defensive
        log.debug("polish failed: %s", exc)
        u = np.asarray(u0, float)
    x = space.to_x(u)
    mse = float(mse_of(space, x, rec)[0])
    calls += 1
    if space.violation(x)[0] > 1e-9:
        mse = math.inf  # the caller keeps the feasible start
    return u, mse, calls
