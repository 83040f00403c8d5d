"""Which effect: re-identify the reference model plus each effect, rank, check, combine.

For every effect of the vocabulary the reference model's identified parameters and the effect's
parameters are fitted together, warm-started from the base fit (`fit_model`):

1. starting values for the effect (from the feature tests, e.g. the flat-top level as VRMAX,
   plus a small grid; for limits on efd also every assignment of the linear model's equivalent
   lags to TE, see `lag_variants`), all simulated in one kernel call;
2. from each start a profile least-squares run (effect parameters held, AVR parameters free),
   then everything free - on the coarse record (every 4 ms, up to 3 s after the trailing edge);
3. for the leaders not yet at the noise floor (`global_search`): MVMO over the whole box, and
   MVMO over the AVR parameters with the effect held at the local fit's values (a profile,
   then everything free), both started from the unit file's AVR values;
4. the leaders polished on the full record (`refine`), the others evaluated there as they are.

Ranking: BIC on the fitted record (n ln(mse) + k ln(n), k = added parameters) plus, when there
is a check record (the holdout capture, or the tail of the record not used to fit), the
predictive deviance n_c ln(mse_check) of the fitted model on it. An effect is significant when
it lowers the BIC by more than `SIGNIFICANT` and does not make the check record worse.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np

from bench_ctl.model.effects import EFFECTS, EFFECT_NAMES
from bench_ctl.model.unit import Unit

from .fit import FitResult, Record, Space, fit, kernel, mse_of, polish, simulate_efd

log = logging.getLogger(__name__)

#: BIC improvement (n ln mse units, i.e. -2 log-likelihood) an effect must bring to count
SIGNIFICANT = 10.0
#: BIC improvement that counts even when the base model is within the noise floor's uncertainty
#: (about a 1 % lower MSE on a 10 000-sample record)
STRONG = 100.0
#: two effects whose scores differ by less than this explain the capture equally well
AMBIGUOUS = 6.0

#: the whole-box search of `_global`: independent MVMO runs sharing the budget, and their swarm
#: (dead-time case from the blind suite, 600 evaluations: one run of 16 particles found the
#: optimum in 6 of 10 seeds, two runs of 300 with 32 particles in 12 of 12)
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


@dataclass(frozen=True, eq=False)
class Check:
    """Where a fitted model is validated: samples [k0, n) of `record` (full record simulated)."""
    record: Record
    k0: int
    floor: float
    label: str

    @property
    def n(self) -> int:
        return self.record.n - self.k0


@dataclass(frozen=True)
class ModelFit:
    effects: tuple[str, ...]
    params: dict[str, float]           # every fitted parameter (AVR + effects)
    mse: float
    mse_check: float | None
    k: int                             # added (effect) parameters
    evaluations: int
    feasible: bool = True
    start: dict[str, float] = field(default_factory=dict)

    def effect_params(self) -> dict[str, float]:
        return {p: self.params[p] for e in self.effects for p in EFFECTS[e].params}


def model_space(unit: Unit, effects: Sequence[str], base_values: Mapping[str, float]) -> Space:
    names = list(unit.identified_names)
    lo = [b.min for b in unit.identify.values()]
    hi = [b.max for b in unit.identify.values()]
    cons = list(unit.constraints)
    for e in effects:
        eff = EFFECTS[e]
        for p in eff.params:
            if p in names:
                continue
            names.append(p)
            lo.append(eff.bounds[p][0])
            hi.append(eff.bounds[p][1])
        cons += list(eff.constraints)
    return Space(tuple(names), np.array(lo), np.array(hi), dict(base_values), tuple(cons))


def check_mse(space: Space, x: np.ndarray, check: Check | None) -> float | None:
    if check is None:
        return None
    efd, failed = simulate_efd(space, np.atleast_2d(x), check.record)
    if failed[0]:
        return math.inf
    r = efd[0, check.k0:] - check.record.efd[check.k0:]
    return float(np.mean(r * r))


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
        grid = [5.0, 20.0, 80.0]
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
    """The base AVR parameters and the linear-equivalent sets with another lag in the TE slot.

    Without limits the model's transfer function is the same for any assignment of the lag time
    constants to TA2, TA4 and TE; a limit on efd (after TE) breaks that symmetry. Variants
    outside the unit's bounds or constraints are dropped."""
    out = [dict(avr)]
    lags = [n for n in LAGS if n in avr and n in unit.identify]
    if "TE" not in lags or len(lags) < 2:
        return out
    space = model_space(unit, (), unit.values())
    for other in lags:
        if other == "TE":
            continue
        v = dict(avr)
        v["TE"], v[other] = avr[other], avr["TE"]
        rest = sorted(v[n] for n in lags if n != "TE")
        for n, val in zip([n for n in ("TA2", "TA4") if n in lags], rest):
            v[n] = val
        x = np.array([v[n] for n in space.names])
        if np.all(x >= space.lo) and np.all(x <= space.hi) and space.violation(x)[0] <= 1e-12:
            if all(any(abs(v[n] - w[n]) > 1e-9 * max(1.0, abs(w[n])) for n in lags) for w in out):
                out.append(v)
    return out


def all_starts(unit: Unit, base_values: Mapping[str, float], rec: Record,
               avr_sets: Sequence[Mapping[str, float]], hints: Mapping[str, float],
               effects: Sequence[str] = EFFECT_NAMES) -> dict[str, list[dict[str, float]]]:
    """Starting points (AVR + effect parameters) for every effect, best first by their MSE on
    `rec`: each effect start with the base AVR parameters and, for the order-sensitive effects,
    with every lag variant. All starts of all effects are simulated in ONE kernel call."""
    from bench_ctl.model.simulate import param_matrix
    rows, owners = [], []
    for e in effects:
        sets = avr_sets if e in ORDER_SENSITIVE else avr_sets[:1]
        for avr in sets:
            for s in effect_starts(e, hints):
                v = dict(base_values)
                v.update(avr)
                v.update(s)
                rows.append(param_matrix(v)[0])
                owners.append((e, {**dict(avr), **s}))
    out = kernel(np.array(rows), rec, efd_meas=rec.efd, store=False)
    mse = np.where(out["fail_step"] >= 0, np.inf, out["sse_efd"] / rec.n)
    result: dict[str, list[tuple[float, dict[str, float]]]] = {}
    for (e, s), m in zip(owners, mse):
        result.setdefault(e, []).append((float(m), s))
    return {e: [s for _, s in sorted(v, key=lambda t: t[0])] for e, v in result.items()}


def fit_model(unit: Unit, base_values: Mapping[str, float], effects: Sequence[str], fine: Record,
              coarse: Record, check: Check | None, starts: Sequence[Mapping[str, float]], *, evals: int,
              seed: int, polish_coarse: int = 150, polish_fine: int = 60, multi: int = 8,
              floor_tol: float = 0.0, profile_evals: int = 0) -> ModelFit:
    """Fit AVR + `effects` (steps 2-3 of the module docstring) from the first `multi` starts; the
    best coarse solution polished on the full record with `polish_fine` simulations (0: only
    evaluated there)."""
    space = model_space(unit, effects, base_values)
    nfev = 0
    counter = [0]
    cands: list[tuple[float, np.ndarray]] = []
    first = np.array([starts[0][n] for n in space.names])
    # from each start: a profile (the effect parameters held at the start while the AVR parameters
    # move, so an effect that the AVR parameters partly absorb cannot slide back to its neutral
    # value before the AVR parameters have left the base fit's basin), then everything free
    eff_names = [n for n in space.names if n not in unit.identify]
    short = max(3 * (space.d + 1), polish_coarse // 3)
    for x0 in starts[:max(1, multi)]:
        vals = dict(base_values)
        vals.update({n: x0[n] for n in eff_names})
        prof = model_space(unit, (), vals)
        u, f, calls = polish(prof, coarse, prof.to_u(np.array([x0[n] for n in prof.names])), max_calls=short)
        nfev += calls
        xp = dict(zip(prof.names, prof.to_x(u)))
        xp.update({n: x0[n] for n in eff_names})
        x = np.array([xp[n] for n in space.names])
        u, f2, calls = polish(space, coarse, space.to_u(x), max_calls=polish_coarse)
        nfev += calls
        cands.append((f2, space.to_x(u)) if f2 <= f else (f, x))
    cands.sort(key=lambda c: c[0])
    if (evals > 0 or profile_evals > 0) and not cands[0][0] <= floor_tol:
        cands.append(_global(unit, base_values, space, coarse, cands[0][1], evals=evals,
                             profile_evals=profile_evals, seed=seed, polish_coarse=polish_coarse,
                             floor_tol=floor_tol, counter=counter))
        cands.sort(key=lambda c: c[0])
    nfev += counter[0]
    fitted = finish(space, effects, fine, check, cands[0][1], polish_fine=polish_fine)
    return replace(fitted, evaluations=fitted.evaluations + nfev,
                   start={n: float(v) for n, v in zip(space.names, first)})


def _global(unit: Unit, base_values: Mapping[str, float], space: Space, coarse: Record, x0: np.ndarray, *,
            evals: int, profile_evals: int, seed: int, polish_coarse: int, floor_tol: float,
            counter: list[int]) -> tuple[float, np.ndarray]:
    """Step 3 from the local fit x0. MVMO must not start from x0 itself: a local minimum in its
    first population pulls the whole swarm into that basin (measured: a dead-time fit stuck at
    16x the noise floor in 5 of 5 seeds from x0, found in 5 of 5 without it). The searches start
    from the unit file's AVR values with x0's effect values instead:
    a. MVMO over the whole box (`RESTARTS` runs sharing `evals`, 32 particles), then least squares;
    b. unless a reached the floor: MVMO over the AVR parameters with the effect held at x0's
       values (a profile), then everything free.
    Returns the best (coarse mse, x) of x0, a and b."""
    eff_names = [n for n in space.names if n not in unit.identify]
    best = (float(mse_of(space, x0, coarse)[0]), np.asarray(x0, float))
    counter[0] += 1
    xb = dict(zip(space.names, x0))
    typical = {n: (base_values[n] if n in unit.identify else xb[n]) for n in space.names}
    for r in range(RESTARTS if evals > 0 else 0):
        res = fit(space, coarse, x0=[typical[n] for n in space.names], evals=evals // RESTARTS,
                  seed=seed + 100 * r, polish_evals=polish_coarse, options=GLOBAL_OPTIONS)
        counter[0] += res.evaluations
        if res.feasible and res.mse < best[0]:
            best = (res.mse, res.x)
        if best[0] <= floor_tol:
            break
    if profile_evals > 0 and eff_names and not best[0] <= floor_tol:
        vals = dict(base_values)
        vals.update({n: xb[n] for n in eff_names})
        prof = model_space(unit, (), vals)
        res = fit(prof, coarse, x0=[typical[n] for n in prof.names], evals=profile_evals, seed=seed + 1,
                  polish_evals=polish_coarse // 3)
        xp = dict(zip(prof.names, res.x))
        xp.update({n: xb[n] for n in eff_names})
        u, f, calls = polish(space, coarse, space.to_u(np.array([xp[n] for n in space.names])),
                             max_calls=polish_coarse)
        counter[0] += res.evaluations + calls
        if f < best[0]:
            best = (f, space.to_x(u))
    return best


def global_search(unit: Unit, base_values: Mapping[str, float], m: ModelFit, fine: Record, coarse: Record,
                  check: Check | None, *, evals: int, profile_evals: int, seed: int, polish_coarse: int,
                  floor_tol: float) -> ModelFit:
    """Step 3 for a fit from `fit_model(..., evals=0, profile_evals=0)`; the better of the two."""
    space = model_space(unit, m.effects, base_values)
    counter = [0]
    f, x = _global(unit, base_values, space, coarse, np.array([m.params[n] for n in space.names]),
                   evals=evals, profile_evals=profile_evals, seed=seed, polish_coarse=polish_coarse,
                   floor_tol=floor_tol, counter=counter)
    out = finish(space, m.effects, fine, check, x, polish_fine=0)
    if not out.mse < m.mse:
        return replace(m, evaluations=m.evaluations + counter[0] + out.evaluations)
    return replace(out, evaluations=m.evaluations + counter[0] + out.evaluations, start=m.start)


def finish(space: Space, effects: Sequence[str], fine: Record, check: Check | None, x0: np.ndarray, *,
           polish_fine: int) -> ModelFit:
    """Polish x0 on the full record (`polish_fine` simulations; 0: evaluate x0 as it is) and
    evaluate the result on the check record."""
    nfev = 1
    x, f = x0, math.inf
    if polish_fine > 0:
        u, f, calls = polish(space, fine, space.to_u(x0), max_calls=polish_fine)
        nfev += calls
        x = space.to_x(u)
    if not (math.isfinite(f) and space.violation(x)[0] <= 1e-9):  # keep x0, evaluated on the full record
        x = np.asarray(x0, float)
        f = float(mse_of(space, x, fine)[0])
    k = sum(len(EFFECTS[e].params) for e in effects)
    return ModelFit(tuple(effects), {n: float(v) for n, v in zip(space.names, x)}, float(f),
                    check_mse(space, x, check), k, nfev, bool(space.violation(x)[0] <= 1e-9))


def refine(unit: Unit, base_values: Mapping[str, float], m: "ModelFit", fine: Record, check: Check | None, *,
           polish_fine: int) -> "ModelFit":
    """Polish a fit (from the coarse record) on the full record."""
    space = model_space(unit, m.effects, base_values)
    out = finish(space, m.effects, fine, check, np.array([m.params[n] for n in space.names]),
                 polish_fine=polish_fine)
    if out.mse > m.mse:
        return m
    return replace(out, evaluations=out.evaluations + m.evaluations, start=m.start)


def refine_base(unit: Unit, base_values: Mapping[str, float], rec: Record, base_x: np.ndarray,
                candidates: Sequence[Mapping[str, float]], *, polish_evals: int) -> FitResult | None:
    """The AVR parameters of the effect fits, tried in the base model (one kernel call); the best,
    when better than the base fit, polished. None when none is better."""
    space = model_space(unit, (), base_values)
    X = np.array([[c[n] for n in space.names] for c in candidates])
    m = mse_of(space, X, rec)
    m0 = float(mse_of(space, base_x, rec)[0])
    i = int(np.argmin(m))
    if not m[i] < m0 * (1.0 - 1e-4):
        return None
    u, f, calls = polish(space, rec, space.to_u(X[i]), max_calls=polish_evals)
    x = space.to_x(u)
    if not (f < m0 and space.violation(x)[0] <= 1e-9):
        return None
    return FitResult(space.names, x, f, calls + len(candidates), True, "refined from an effect fit")


def bic(n: int, mse: float, k: int) -> float:
    return n * math.log(mse) + k * math.log(n)


def aic(n: int, mse: float, k: int) -> float:
    return n * math.log(mse) + 2 * k


def score(m: ModelFit, n: int, n_check: int) -> float:
    """Lower is better: BIC on the fit record plus predictive deviance on the check record."""
    s = bic(n, m.mse, m.k)
    if m.mse_check is not None:
        s += n_check * math.log(m.mse_check) if m.mse_check > 0 else -math.inf
    return s
