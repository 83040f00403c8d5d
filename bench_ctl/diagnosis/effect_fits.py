"""Which effect: re-identify the unit's model plus each effect, check it where the fit did not look,
rank, combine.

Every model (the base model, base + one effect, base + several) is identification's `Problem` on
the capture: the unit's identified parameters, the effects' parameters and the instant of every
setpoint edge, fitted together (`Views.problem`). For each effect (`fit_model`):

1. starting values for the effect (from the feature tests, e.g. the flat-top level as VRMAX,
   plus a small grid; for limits on efd also every assignment of the linear model's equivalent
   lags to TE, see `lag_variants`), all simulated in one kernel call;
2. from each start a profile least-squares run (effect parameters held, model parameters free),
   then everything free - on the coarse record (every 4 ms, up to 3 s after the trailing edge),
   the edge instants held at the base fit's (a 4 ms grid cannot place them);
3. for the leaders not yet at the noise floor (`global_search`): MVMO over the whole box, and
   MVMO over the model parameters with the effect held at the local fit's values (a profile,
   then everything free), both started from the unit file's values;
4. the leaders polished on the full record with the edge instants free (`finish`), the others
   evaluated there as they are.

The check (`check_parts`), where a fitted model is judged on data it was not fitted to: the
holdout capture when there is one (the model held, only its own edge instants fitted), the
recorded terminal voltage when there is one and the fit did not use it, and always the
cross-validation windows of the capture - the leading edge, the plateau and the trailing edge
in turn (never the recovery: `diagnose.CV_SEGMENTS`): the model is re-fitted with the window left
out of the objective (the simulation running through it) and scored on it - the re-fit is the
Gauss-Newton step from the model's fit over the other samples, one Jacobian serving all windows.
So an effect that acts at the edges (a ceiling, a slew limit, a setpoint ramp, a delay) is judged
on an edge the fit never saw.

Ranking: BIC on the capture (n ln(mse) + k ln(n), k = added parameters) plus the predictive
deviance on the check, sum over its parts of n_i ln(mse_i). An effect is significant when it
lowers the BIC by more than `SIGNIFICANT` and the check's deviance by more than `CHECK_GAIN`.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Sequence

import numpy as np

from bench_ctl.capture import Capture
from bench_ctl.identification.constraints import parse_constraints
from bench_ctl.identification.problem import Problem, make_problem
from bench_ctl.model.effects import EFFECTS, EFFECT_NAMES
from bench_ctl.model.edges import EDGE_PARAMS
from bench_ctl.model.kernel import run_kernel
from bench_ctl.model.simulate import param_matrix
from bench_ctl.model.unit import Unit

from .fit import FAIL_PENALTY, FitResult, Space, fit, mse_of, polish, polish_full, std_of

log = logging.getLogger(__name__)

#: BIC improvement (n ln mse units, i.e. -2 log-likelihood) an effect must bring to count
SIGNIFICANT = 10.0
#: improvement of the check's deviance an effect must bring to count (the check's samples were
#: not fitted: an effect that only fits noise does not improve them)
CHECK_GAIN = 2.0
#: BIC improvement that counts even when the base model is within the noise floor's uncertainty
#: (about a 1 % lower MSE on a 10 000-sample record)
STRONG = 100.0
#: two effects whose scores differ by less than this explain the capture equally well
AMBIGUOUS = 6.0

#: the whole-box search of `_global`: independent MVMO runs sharing the budget, and their swarm
#: (two smaller runs find a narrow basin more often than one: docs/benchmarks.md, "Diagnosis
#: constants")
RESTARTS = 2
GLOBAL_OPTIONS = {"particles": 32}

SEPARATING_TESTS: dict[frozenset, str] = {
    frozenset({"dead_time", "time_skew"}):
        "record the AVR output or the field voltage at the exciter on a second channel (or efd and usetp "
        "on the same channel group): a recorder skew delays only the efd channel, a dead time delays the response",
    frozenset({"ceiling_limit", "rate_limit"}):
        "repeat with a step of another size (e.g. half the amplitude): a ceiling caps the level at the same "
        "value, a slew limit caps the slope",
    frozenset({"recorder_gain", "saturation"}):
        "repeat at another terminal voltage (e.g. Vt0 = 0.9 and 1.05 pu) or check the efd channel calibration: "
        "saturation grows with the voltage, a gain error scales every level alike",
    frozenset({"setpoint_ramp", "rate_limit"}):
        "read the device's active setpoint during the test (a setpoint ramp shows there), or a step of "
        "another size: a ramp lengthens the rise in proportion to the step, a slew limit caps the efd slope",
    frozenset({"setpoint_ramp", "dead_time"}):
        "read the device's active setpoint during the test, or a step of another size: a ramp's duration "
        "scales with the step, a dead time does not",
    frozenset({"transducer_lag", "dead_time"}):
        "record the transducer output (the AVR's measured voltage) beside Vt: a transducer lag shows there",
}
DEFAULT_TEST = ("a step of another size and a record of the AVR input (the transducer output) beside efd")


def separating_test(a: str, b: str) -> str:
    return SEPARATING_TESTS.get(frozenset({a, b}), DEFAULT_TEST)


def ambiguous_pairs(entries: Sequence[Mapping], tol: float = AMBIGUOUS) -> list[dict]:
    """The significant effects whose score is within `tol` of the best one's (entries ranked best
    first), each paired with the best one and the test that would separate the two."""
    top = next((e for e in entries if e.get("significant")), None)  # the verdict's entry
    if top is None:
        return []
    return [{"effects": [top["name"], e["name"]], "score_difference": e["score"] - top["score"],
             "separating_test": separating_test(top["name"], e["name"])}
            for e in entries if e is not top and e.get("significant") and e["score"] - top["score"] < tol]


@dataclass(frozen=True)
class Window:
    """A cross-validation window of the capture (s from its first sample, ends included)."""
    label: str
    t0: float
    t1: float


@dataclass(frozen=True)
class Part:
    """One part of a model's check: the holdout capture or a window left out of the fit."""
    label: str
    n: float      # samples scored
    mse: float    # pu^2 (inf: the simulation failed there)


@dataclass(frozen=True)
class ModelFit:
    effects: tuple[str, ...]
    params: dict[str, float]           # every fitted parameter (model, effects, edge offsets)
    mse: float
    checks: tuple[Part, ...] | None    # None: not checked (yet)
    k: int                             # added (effect) parameters
    evaluations: int
    feasible: bool = True
    start: dict[str, float] = field(default_factory=dict)
    fixed: dict[str, float] = field(default_factory=dict)   # the variant: values it holds (VRVT, ..)
    std: dict[str, float] = field(default_factory=dict)     # of the parameters, from the last polish
    extra: tuple[str, ...] = ()        # a variant's own fitted parameters (KC), counted in k

    def effect_params(self) -> dict[str, float]:
        out = {p: self.params[p] for e in self.effects for p in EFFECTS[e].params}
        out.update({p: self.params[p] for p in self.extra})
        return out

    @property
    def mse_check(self) -> float | None:
        """The check's pooled efd MSE (the efd parts' sample-weighted mean; not the Vt part, another
        channel on another scale), None when not checked."""
        parts = [p for p in self.checks or () if p.label != "vt"]
        n = sum(p.n for p in parts)
        return sum(p.n * p.mse for p in parts) / n if n > 0 else None

    def part(self, label: str) -> Part | None:
        return next((p for p in self.checks or () if p.label == label), None)


@dataclass(eq=False)
class Views:
    """How every model sees the capture: its problem (names, bounds, constraints, edges), the
    coarse copy the searches run on, and the check (holdout, cross-validation windows)."""
    unit: Unit
    capture: Capture
    holdout: Capture | None
    q: int                             # decimation of the coarse record
    n_coarse: int                      # its last fine sample
    offset: int                        # a fine sample kept on the coarse grid (the leading edge)
    windows: tuple[Window, ...]
    holdout_calls: int = 24            # least-squares simulations for the holdout's edge instants
    _cache: dict = field(default_factory=dict, repr=False)

    def problem(self, effects: Sequence[str] = (), fixed: Mapping[str, float] | None = None, *,
                with_effects: bool = True, extra: Sequence[str] = ()) -> Problem:
        """The model's problem on the capture: identified parameters + the effects' parameters
        and a variant's `extra` ones (with_effects=False: those held at `fixed`, a profile) + the
        edge instants."""
        fixed = dict(fixed or {})
        key = (tuple(effects), tuple(sorted(fixed.items())), with_effects, tuple(extra))
        p = self._cache.get(key)
        if p is None:
            names = list(self.unit.identified_names)
            if with_effects:
                for e in effects:
                    names += [n for n in EFFECTS[e].params if n not in names]
                names += [n for n in extra if n not in names]
            bounds = {n: b[n] for e in effects for b in (EFFECTS[e].bounds,) for n in b if n in names}
            p = make_problem([self.capture], self.unit, names=names, bounds=bounds, values=fixed or None)
            if len(self._cache) > 256:
                self._cache.clear()
            self._cache[key] = p
        return p

    def coarse(self, p: Problem) -> Problem:
        return p.decimated(self.q, n_max=self.n_coarse, offset=self.offset)

    def holdout_problem(self, values: Mapping[str, float]) -> Problem:
        """The holdout with the model held at `values`: only its own edge instants are fitted."""
        assert self.holdout is not None
        held = {k: v for k, v in values.items() if k not in EDGE_PARAMS}
        # no constraint: nothing of the model is fitted here (a fit left infeasible is still judged)
        return make_problem([self.holdout], self.unit, names=(), values=held, constraints=())


def edge_names(p: Problem) -> list[str]:
    return [n for n in p.names if n in EDGE_PARAMS]


def _mid(p: Problem, names: Sequence[str]) -> dict[str, float]:
    """The middle of each named parameter's bounds (where an edge instant starts)."""
    return {n: 0.5 * (lo + hi) for n, (lo, hi) in zip(p.names, p.bounds) if n in names}


def check_parts(views: Views, p: Problem, x: np.ndarray) -> tuple[Part, ...]:
    """The model at x judged where it was not fitted (module docstring): the holdout (the model
    held, its edge instants fitted), then each cross-validation window left out of a re-fit and
    scored. The re-fit without a window is the Gauss-Newton step from x on the other samples
    (`_left_out`): the linearised leave-window-out fit, from one Jacobian for all windows."""
    parts: list[Part] = []
    space = Space.of(p)
    values = space.base | dict(zip(space.names, (float(v) for v in x)))
    if views.holdout is not None:
        h = views.holdout_problem(values)
        hs = Space.of(h)
        x0 = hs.vector(_mid(h, h.names))
        u, f, _ = polish(h, hs.to_u(x0), max_calls=views.holdout_calls)
        if not math.isfinite(f):
            f = float(mse_of(h, x0)[0])
        parts.append(Part("holdout", h.n_scored()[0], f if f < FAIL_PENALTY else math.inf))
    parts += _left_out(views, p, x)
    vt = _vt_part(p, x)
    if vt is not None:
        parts.append(vt)
    return tuple(parts)


def _vt_part(p: Problem, x: np.ndarray) -> Part | None:
    """The recorded terminal voltage, when the capture has it and the fit did not use it (vt
    weight 0): how well the model predicts it. It separates effects that look alike in efd but
    act apart on the machine, e.g. a dead time in the loop (Vt follows the delayed efd) from a
    recorder skew of the efd channel (Vt follows the real, earlier one)."""
    rec = p.records[0]
    if rec.vt is None or p.w_vt > 0:
        return None
    from bench_ctl.model.kernel import run_kernel
    out = run_kernel(p.matrix(np.atleast_2d(x)), rec.usetp, rec.dt, rec.usetp_pre, edges=rec.edges)
    if out["fail_step"][0] >= 0:
        return Part("vt", float(rec.vt.size), math.inf)
    e = out["vt"][0] - rec.vt
    return Part("vt", float(e.size), float(np.mean(e * e)))


#: Levenberg damping of the leave-window-out step, relative to the mean curvature: a parameter
#: that only the left-out window determines (an edge instant, a limit reached only there) stays
#: where the full fit put it instead of taking an arbitrary step
LEAVE_OUT_DAMPING = 1e-6


def _left_out(views: Views, p: Problem, x: np.ndarray, step: float = 1e-5) -> list[Part]:
    """Per window: the efd MSE on the window of the model re-fitted without it, as the Gauss-Newton
    step from x over the other samples (exact for a model linear in its parameters; the full fit is
    the start, so the step is small). One kernel call of d + 1 candidates."""
    space = Space.of(p)
    d = space.d
    u = space.to_u(x)
    h = np.where(u + step <= 1.0, step, -step)
    U = np.vstack([u[None, :], u[None, :] + np.diag(h)])
    R, failed = p.residuals(space.to_x(U))
    rec = p.records[0]
    sl = p.efd_residual_slices()[0]
    R = R[:, sl]
    n = R.shape[1]
    if failed[0]:
        return [Part(w.label, 0.0, math.inf) for w in views.windows]
    r0 = R[0]
    J = ((R[1:] - r0[None, :]) / h[:, None]).T            # (n, d)
    c = np.ones(n)
    c[0] = c[-1] = 0.5
    wrow = np.sqrt(p.w_efd * c * rec.weights() * rec.dt)  # the residual of a sample is wrow * error
    t = (rec.i0 + np.arange(n)) * rec.dt
    out = []
    for w in views.windows:
        inw = (t >= w.t0 - 1e-9 * rec.dt) & (t <= w.t1 + 1e-9 * rec.dt)
        if not inw.any() or inw.all():
            continue
        Jr, rr = J[~inw], r0[~inw]
        A = Jr.T @ Jr
        lam = LEAVE_OUT_DAMPING * max(float(np.trace(A)) / max(d, 1), 1e-300)
        try:
            du = -np.linalg.solve(A + lam * np.eye(d), Jr.T @ rr)
        except np.linalg.LinAlgError:
            du = np.zeros(d)
        pred = (r0[inw] + J[inw] @ du) / np.where(wrow[inw] > 0, wrow[inw], 1.0)
        out.append(Part(w.label, float(inw.sum()), float(np.mean(pred * pred))))
    return out


def check_deviance(ref: ModelFit, m: ModelFit) -> float:
    """How much better m predicts the check than ref: sum over the parts of n_i ln(ref_i / m_i)
    (-inf when m failed on a part, +inf when only ref did)."""
    if not ref.checks or not m.checks:
        return -math.inf
    total = 0.0
    for a in ref.checks:
        b = m.part(a.label)
        if b is None:
            continue
        if not math.isfinite(b.mse):
            return -math.inf
        if not math.isfinite(a.mse):
            return math.inf
        total += a.n * math.log(max(a.mse, 1e-300) / max(b.mse, 1e-300))
    return total


def checked(views: Views, m: ModelFit) -> ModelFit:
    """`m` with its check computed (once)."""
    if m.checks is not None:
        return m
    p = views.problem(m.effects, m.fixed, extra=m.extra)
    x = np.array([m.params[n] for n in p.names])
    return replace(m, checks=check_parts(views, p, x))


def _clip(name: str, v: float, effect: str) -> float:
    lo, hi = EFFECTS[effect].bounds[name]
    return float(min(max(v, lo), hi))


def effect_starts(effect: str, hints: Mapping[str, float]) -> list[dict[str, float]]:
    """Starting values of an effect's parameters: from the feature tests plus a small grid."""
    c = lambda n, v: _clip(n, v, effect)  # noqa: E731
    if effect == "ceiling_limit":
        # both limits where the measured efd turns flat: a limit that is not there moves away
        # (its gradient pushes it out), one started outside the record would get no gradient
        return [{"VRMAX": c("VRMAX", hints["top_level"]), "VRMIN": c("VRMIN", hints["bottom_level"])}]
    if effect in ("dead_time", "time_skew"):
        p = "TD" if effect == "dead_time" else "SKEW"
        d = hints.get("delay_s", math.nan)
        grid = [0.003, 0.01, 0.02, 0.04]
        if math.isfinite(d) and d > 0:
            grid = [d, 0.6 * d, 1.5 * d] + grid
        return [{p: c(p, v)} for v in grid]
    if effect == "transducer_lag":
        return [{"TR": v} for v in (0.01, 0.03, 0.06, 0.1, 0.15, 0.2)]
    if effect == "saturation":
        s = hints.get("sat0", 0.0)
        s10s = [s] if s > 0.005 else []
        s10s += [0.03, 0.1]
        return [{"S10": c("S10", a), "S12": c("S12", a * r)} for a in s10s for r in (2.0, 4.0)]
    if effect == "rate_limit":
        s = max(hints.get("slope_up", math.nan), hints.get("slope_down", math.nan))
        grid = [3.0, 10.0, 30.0, 80.0]
        if math.isfinite(s) and s > 0:
            grid = [s, 0.8 * s, 1.2 * s] + grid
        return [{"RATE": c("RATE", v)} for v in grid]
    if effect == "setpoint_ramp":
        grid = [0.05, 0.1, 0.2, 0.4, 0.8, 2.0, 5.0]
        return [{"RAMP": c("RAMP", v)} for v in grid]
    if effect == "recorder_gain":
        g = hints.get("gain", 1.0)
        return [{"GAIN": c("GAIN", g)}, {"GAIN": 1.0}]
    raise ValueError(f"unknown effect {effect!r}")


#: effects acting between the exciter lag TE and the record (limits on the efd state): for them
#: it matters which of the equivalent lags of the linear model is TE, so every assignment is tried
ORDER_SENSITIVE = ("ceiling_limit", "rate_limit")
LAGS = ("TA2", "TA4", "TE")


def lag_variants(unit: Unit, avr: Mapping[str, float]) -> list[dict[str, float]]:
    """The base model's parameters and the linear-equivalent sets with another lag in the TE slot.

    Without limits the model's transfer function is the same for any assignment of the lag time
    constants to TA2, TA4 and TE; a limit on efd (after TE) breaks that symmetry. Variants
    outside the unit's bounds or constraints are dropped."""
    out = [dict(avr)]
    lags = [n for n in LAGS if n in avr and n in unit.identify]
    if "TE" not in lags or len(lags) < 2:
        return out
    names = list(unit.identified_names)
    cons = parse_constraints(unit.constraints, names)
    for other in lags:
        if other == "TE":
            continue
        v = dict(avr)
        v["TE"], v[other] = avr[other], avr["TE"]
        rest = sorted(v[n] for n in lags if n != "TE")
        for n, val in zip([n for n in ("TA2", "TA4") if n in lags], rest):
            v[n] = val
        x = np.array([v[n] for n in names])
        inside = all(unit.identify[n].min <= v[n] <= unit.identify[n].max for n in names)
        if inside and all(c.violation(x) <= 1e-12 for c in cons):
            if all(any(abs(v[n] - w[n]) > 1e-9 * max(1.0, abs(w[n])) for n in lags) for w in out):
                out.append(v)
    return out


def all_starts(views: Views, avr_sets: Sequence[Mapping[str, float]], hints: Mapping[str, float],
               effects: Sequence[str] = EFFECT_NAMES, fixed: Mapping[str, float] | None = None
               ) -> dict[str, list[dict[str, float]]]:
    """Starting points (model + effect parameters + edge instants) for every effect, best first by
    their MSE on the coarse record: each effect start with the base parameters and, for the
    order-sensitive effects, with every lag variant. All starts of all effects are simulated in
    ONE kernel call on the coarse record."""
    coarse = views.coarse(views.problem((), fixed)).records[0]
    base_values = {**views.unit.values(), **(fixed or {})}
    rows, owners = [], []
    for e in effects:
        sets = avr_sets if e in ORDER_SENSITIVE else avr_sets[:1]
        for avr in sets:
            for s in effect_starts(e, hints):
                v = {**base_values, **avr, **s}
                rows.append(param_matrix(v)[0])
                owners.append((e, {**dict(avr), **s}))
    out = run_kernel(np.array(rows), coarse.usetp, coarse.dt, coarse.usetp_pre, efd_meas=coarse.efd, store=False,
                     edges=coarse.edges)
    mse = np.where(out["fail_step"] >= 0, np.inf, out["sse_efd"] / coarse.efd.size)
    result: dict[str, list[tuple[float, dict[str, float]]]] = {}
    for (e, s), m in zip(owners, mse):
        result.setdefault(e, []).append((float(m), s))
    return {e: [s for _, s in sorted(v, key=lambda t: t[0])] for e, v in result.items()}


def _k(effects: Sequence[str]) -> int:
    return sum(len(EFFECTS[e].params) for e in effects)


def fit_model(views: Views, effects: Sequence[str], starts: Sequence[Mapping[str, float]], *, evals: int,
              seed: int, fixed: Mapping[str, float] | None = None, polish_coarse: int = 150,
              polish_fine: int = 60, multi: int = 8, floor_tol: float = 0.0, profile_evals: int = 0,
              check: bool = False, extra: Sequence[str] = (), profile: bool = True) -> ModelFit:
    """Fit the model + `effects` (steps 2-3 of the module docstring) from the first `multi` starts
    (maps of values; an edge instant it lacks starts mid-interval); the best coarse solution
    polished on the full record with `polish_fine` simulations (0: only evaluated there).
    profile=False: from each start everything free at once (no profile run first)."""
    fixed = dict(fixed or {})
    extra = tuple(extra)
    p = views.problem(effects, fixed, extra=extra)
    space = Space.of(p)
    edges = edge_names(p)
    mid = _mid(p, edges)
    held_edges = {n: float(starts[0].get(n, mid[n])) for n in edges}
    pc = views.coarse(p.held(held_edges)) if edges else views.coarse(p)
    sc = Space.of(pc)
    nfev = 0
    counter = [0]
    cands: list[tuple[float, dict[str, float]]] = []
    eff_names = [n for n in pc.names if n not in views.unit.identify]
    short = max(3 * (sc.d + 1), polish_coarse // 3)
    for x0 in starts[:max(1, multi)]:
        # a profile (the effect parameters held at the start while the model parameters move, so
        # an effect that the model partly absorbs cannot slide back to its neutral value before
        # the model has left the base fit's basin), then everything free
        xp, f = dict(x0), math.inf
        if profile:
            prof_p = views.problem(effects, {**fixed, **{n: x0[n] for n in eff_names}}, with_effects=False,
                                   extra=extra)
            prof = views.coarse(prof_p.held(held_edges)) if edges else views.coarse(prof_p)
            sp = Space.of(prof)
            u, f, calls = polish(prof, sp.to_u(sp.vector(x0)), max_calls=short)
            nfev += calls
            xp = {**dict(x0), **dict(zip(sp.names, sp.to_x(u)))}
        u, f2, calls = polish(pc, sc.to_u(sc.vector(xp)), max_calls=polish_coarse)
        nfev += calls
        cands.append((f2, dict(zip(sc.names, sc.to_x(u)))) if f2 <= f else (f, {k: xp[k] for k in sc.names}))
    cands.sort(key=lambda c: c[0])
    if (evals > 0 or profile_evals > 0) and not cands[0][0] <= floor_tol:
        cands.append(_global(views, effects, fixed, pc, cands[0][1], evals=evals, profile_evals=profile_evals,
                             seed=seed, polish_coarse=polish_coarse, floor_tol=floor_tol, counter=counter,
                             held_edges=held_edges, extra=extra))
        cands.sort(key=lambda c: c[0])
    nfev += counter[0]
    best = {**held_edges, **cands[0][1]}
    fitted = finish(views, effects, fixed, space.vector(best), polish_fine=polish_fine, check=check, extra=extra)
    return replace(fitted, evaluations=fitted.evaluations + nfev,
                   start={n: float(starts[0].get(n, held_edges.get(n, math.nan))) for n in space.names})


def _global(views: Views, effects: Sequence[str], fixed: Mapping[str, float], pc: Problem,
            x0: Mapping[str, float], *, evals: int, profile_evals: int, seed: int, polish_coarse: int,
            floor_tol: float, counter: list[int], held_edges: Mapping[str, float],
            extra: Sequence[str] = ()) -> tuple[float, dict[str, float]]:
    """Step 3 on the coarse problem `pc` from the local fit x0. MVMO must not start from x0 itself:
    a local minimum in its first population pulls the whole swarm into that basin
    (docs/benchmarks.md, "Diagnosis constants"). The searches start from the unit file's values
    with x0's effect values instead:
    a. MVMO over the whole box (`RESTARTS` runs sharing `evals`, 32 particles), then least squares;
    b. unless a reached the floor: MVMO over the model parameters with the effect held at x0's
       values (a profile), then everything free.
    Returns the best (coarse mse, values) of x0, a and b."""
    sc = Space.of(pc)
    eff_names = [n for n in sc.names if n not in views.unit.identify]
    best = (float(mse_of(pc, sc.vector(x0))[0]), dict(x0))
    counter[0] += 1
    unit_values = views.unit.values()
    typical = {n: (unit_values[n] if n in views.unit.identify else x0[n]) for n in sc.names}
    for r in range(RESTARTS if evals > 0 else 0):
        res = fit(pc, x0=sc.vector(typical), evals=evals // RESTARTS, seed=seed + 100 * r,
                  polish_evals=polish_coarse, options=GLOBAL_OPTIONS)
        counter[0] += res.evaluations
        if res.feasible and res.mse < best[0]:
            best = (res.mse, res.params())
        if best[0] <= floor_tol:
            break
    if profile_evals > 0 and eff_names and not best[0] <= floor_tol:
        prof_p = views.problem(effects, {**fixed, **{n: x0[n] for n in eff_names}}, with_effects=False, extra=extra)
        prof = views.coarse(prof_p.held(dict(held_edges))) if held_edges else views.coarse(prof_p)
        sp = Space.of(prof)
        res = fit(prof, x0=sp.vector(typical), evals=profile_evals, seed=seed + 1, polish_evals=polish_coarse // 3)
        xp = {**{n: x0[n] for n in eff_names}, **res.params()}
        u, f, calls = polish(pc, sc.to_u(sc.vector(xp)), max_calls=polish_coarse)
        counter[0] += res.evaluations + calls
        if f < best[0]:
            best = (f, dict(zip(sc.names, sc.to_x(u))))
    return best


def global_search(views: Views, m: ModelFit, *, evals: int, profile_evals: int, seed: int, polish_coarse: int,
                  floor_tol: float) -> ModelFit:
    """Step 3 for a fit from `fit_model(..., evals=0, profile_evals=0)`; the better of the two."""
    p = views.problem(m.effects, m.fixed, extra=m.extra)
    edges = edge_names(p)
    held_edges = {n: m.params[n] for n in edges}
    pc = views.coarse(p.held(held_edges)) if edges else views.coarse(p)
    counter = [0]
    _f, values = _global(views, m.effects, m.fixed, pc, {n: m.params[n] for n in pc.names}, evals=evals,
                         profile_evals=profile_evals, seed=seed, polish_coarse=polish_coarse, floor_tol=floor_tol,
                         counter=counter, held_edges=held_edges, extra=m.extra)
    out = finish(views, m.effects, m.fixed, Space.of(p).vector({**held_edges, **values}), polish_fine=0,
                 extra=m.extra)
    if not out.mse < m.mse:
        return replace(m, evaluations=m.evaluations + counter[0] + out.evaluations)
    return replace(out, evaluations=m.evaluations + counter[0] + out.evaluations, start=m.start)


def finish(views: Views, effects: Sequence[str], fixed: Mapping[str, float], x0: np.ndarray, *,
           polish_fine: int, check: bool = False, noise_variance: float | None = None,
           extra: Sequence[str] = ()) -> ModelFit:
    """Polish x0 on the full record, edge instants free (`polish_fine` simulations; 0: evaluate x0
    as it is); with `check`, judge the result on the check (`check_parts`); with the noise
    variance, the parameters' standard deviations from the polish."""
    p = views.problem(effects, fixed, extra=extra)
    space = Space.of(p)
    nfev = 1
    x, f = np.asarray(x0, float), math.inf
    std: dict[str, float] = {}
    if polish_fine > 0:
        pol = polish_full(p, space.to_u(x0), max_calls=polish_fine)
        nfev += pol.calls
        x, f = space.to_x(pol.u), pol.mse
        if noise_variance is not None and math.isfinite(f):
            std = std_of(p, pol, noise_variance)
    if not (math.isfinite(f) and space.violation(x)[0] <= 1e-9):  # keep x0, evaluated on the full record
        x = np.asarray(x0, float)
        f = float(mse_of(p, x)[0])
        std = {}
    m = ModelFit(tuple(effects), {n: float(v) for n, v in zip(space.names, x)}, float(f), None,
                 _k(effects) + len(tuple(extra)), nfev, bool(space.violation(x)[0] <= 1e-9), fixed=dict(fixed), std=std,
                 extra=tuple(extra))
    return checked(views, m) if check else m


def refine(views: Views, m: ModelFit, *, polish_fine: int) -> ModelFit:
    """Polish a fit (from the coarse record) on the full record."""
    p = views.problem(m.effects, m.fixed, extra=m.extra)
    out = finish(views, m.effects, m.fixed, Space.of(p).vector(m.params), polish_fine=polish_fine, extra=m.extra)
    if out.mse > m.mse:
        return m
    return replace(out, evaluations=out.evaluations + m.evaluations, start=m.start)


def refine_base(views: Views, base: ModelFit, candidates: Sequence[Mapping[str, float]], *,
                polish_evals: int) -> ModelFit | None:
    """The model parameters of the effect fits, tried in the base model (one kernel call); the best,
    when better than the base fit, polished. None when none is better."""
    p = views.problem((), base.fixed)
    space = Space.of(p)
    X = np.array([space.vector({**base.params, **{n: c[n] for n in space.names if n in c}}) for c in candidates])
    m = mse_of(p, X)
    i = int(np.argmin(m))
    if not m[i] < base.mse * (1.0 - 1e-4):
        return None
    u, f, calls = polish(p, space.to_u(X[i]), max_calls=polish_evals)
    x = space.to_x(u)
    if not (f < base.mse and space.violation(x)[0] <= 1e-9):
        return None
    return replace(base, params={n: float(v) for n, v in zip(space.names, x)}, mse=f, checks=None,
                   evaluations=base.evaluations + calls + len(candidates))


def as_fit_result(m: ModelFit) -> FitResult:
    names = tuple(m.params)
    return FitResult(names, np.array([m.params[n] for n in names]), m.mse, m.evaluations, m.feasible, "")


def bic(n: int, mse: float, k: int) -> float:
    return n * math.log(mse) + k * math.log(n)


def aic(n: int, mse: float, k: int) -> float:
    return n * math.log(mse) + 2 * k


def score(m: ModelFit, n: int) -> float:
    """Lower is better: BIC on the capture plus the predictive deviance on the check."""
    s = bic(n, m.mse, m.k)
    for part in m.checks or ():
        s += part.n * math.log(part.mse) if 0 < part.mse < math.inf else (math.inf if part.mse > 0 else -math.inf)
    return s


def describe_check(views: Views) -> dict[str, Any]:
    """The JSON `check`: what each model was judged on."""
    out: dict[str, Any] = {
        "kind": ("holdout + windows" if views.holdout is not None else "windows") if views.windows else "holdout",
        "windows": [{"label": w.label, "t0": w.t0, "t1": w.t1} for w in views.windows],
        "how": "each window in turn left out of the fit (the simulation runs through it; the re-fit is the "
               "Gauss-Newton step from the model's fit over the other samples) and scored on it; the holdout "
               "scored with the model held, its edge instants fitted; a recorded Vt the fit did not use "
               "scored as predicted",
        "holdout": (views.holdout.source or "holdout") if views.holdout is not None else None,
        "vt": bool(views.capture.vt is not None and float(views.unit.weights.get("vt", 0.0)) == 0.0),
    }
    return out
