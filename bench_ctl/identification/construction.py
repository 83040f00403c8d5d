"""Building an identification problem: `make_problem` checks captures, unit, names, bounds,
constraints and weights, and binds them into a `Problem` (`problem.py`).

`make_problem` binds one or several captures to a unit and a list of parameter names to fit
(default: the unit's identified parameters; effect parameters such as VRMAX, TD may be added, so
the diagnosis can fit "reference model + effect"), and the instants of the setpoint edges. A fit
window (`fit_window=(t0, t1)` in s, or `segment=slice(i0, i1)` in samples) restricts the
objective and the MSE to part of each record. A capture with P and Q channels is an on-line
record: its machine on the grid starts from the record's own pre-step P, Q and Vt (`_on_line`);
its stabiliser's output `vs`, when recorded, is fitted with efd, Vt and Q (weight `vs`, default
`units.unit.VS_WEIGHT`).

Constraints are read from the unit's text (and those of any effect whose parameters are fitted)
over all kernel parameters, then reduced to the fitted names: a term on a parameter that is not
fitted becomes a constant. A constraint with no fitted parameter left is not handed to the
optimizer but still checked and reported (`fixed_constraints`). Constraints no parameter set
inside the bounds satisfies are refused before any fit.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from bench_ctl.capture import Capture
from bench_ctl.engine.layout import BLOWUP
from bench_ctl.engine.machines.grid import machine_data, machine_matrix, unit_machine
from bench_ctl.engine.simulate import operating_point, pre_step_mean, pre_trigger_mean
from bench_ctl.model.dialect import Note, prose
from bench_ctl.model.effects import EFFECTS
from bench_ctl.model.params import KERNEL_PARAMS, MCOL, PARAMS
from bench_ctl.signals.edges import EDGE_PARAMS, Edge
from bench_ctl.units.switched import grid_as_recorded, pss_switched_off
from bench_ctl.units.unit import VS_WEIGHT, Unit

from .constraints import LinearConstraint, parse_constraints
from .fit_record import FitRecord, ProblemError, apply_window, segment_window
from .problem import Problem
from .timing import edge_plan_of, record_edges

logger = logging.getLogger(__name__)

__all__ = ["make_problem", "default_bounds", "scored_vs", "ProblemError"]

#: the largest recorded-efd gain the kernel may apply (recorder_gain upper physical limit)
_MAX_GAIN = PARAMS["GAIN"].hi


def default_bounds(unit: Unit, name: str) -> tuple[float, float]:
    """Search bounds of `name`: the unit's [identify] bounds, else the bounds of its effect."""
    if name in unit.identify:
        b = unit.identify[name]
        return float(b.min), float(b.max)
    for eff in EFFECTS.values():
        if name in eff.bounds:
            lo, hi = eff.bounds[name]
            return float(lo), float(hi)
    raise ProblemError(Note(f"no default bounds for {{!r}}: it is neither identified in unit {prose(repr(unit.name))} "
                            "nor an effect parameter; pass bounds={{{!r}: (lo, hi)}}", name, name))


def _reduce_constraints(texts: Sequence[str], names: Sequence[str], base: dict[str, float]
                        ) -> tuple[list[LinearConstraint], list[tuple[str, bool]]]:
    """Parse over all kernel parameters, keep fitted names, fold the rest into the bound."""
    full = parse_constraints(list(texts), KERNEL_PARAMS)
    idx = [KERNEL_PARAMS.index(n) for n in names]
    fitted, fixed = [], []
    for c in full:
        sub = c.coef[idx]
        rest = c.coef.copy()
        rest[idx] = 0.0
        const = 0.0
        for j in np.flatnonzero(rest):
            v = base[KERNEL_PARAMS[j]]
            if not math.isfinite(v):
                raise ProblemError(Note(f"constraint {{!r}} uses {{}} = {v}, which is not fitted and not finite "
                                        "(fit it or give it a value)", c.expr, KERNEL_PARAMS[j]))
            const += rest[j] * v
        if np.any(sub != 0.0):
            fitted.append(LinearConstraint(expr=c.expr, coef=sub, rhs=c.rhs - const, names=tuple(names)))
        else:
            fixed.append((c.expr, bool(const <= c.rhs + 1e-9)))
    return fitted, fixed


def _check_feasible(fitted: Sequence[LinearConstraint], fixed: Sequence[tuple[str, bool]],
                    names: Sequence[str], bounds: Sequence[tuple[float, float]]) -> None:
    """Refuse, before any fit, constraints that no parameter set inside the bounds satisfies
    (a linear feasibility problem), or that the fixed values already break."""
    broken = [expr for expr, ok in fixed if not ok]
    if broken:
        raise ProblemError(Note("constraint(s) {} are broken by the fixed parameter values; nothing the fit can "
                                "change satisfies them", str(broken)))
    if not fitted:
        return
    from scipy.optimize import linprog

    A = np.array([c.coef for c in fitted])
    b = np.array([c.rhs for c in fitted])
    res = linprog(np.zeros(len(names)), A_ub=A, b_ub=b, bounds=list(bounds), method="highs")
    if res.status == 2:
        box = Note(", ".join(f"{{}} in [{lo:g}, {hi:g}]" for lo, hi in bounds), *names)
        raise ProblemError(Note("the constraints {} contradict each other inside the bounds ({}): no parameter "
                                "set satisfies them all", str([c.expr for c in fitted]), box))


def make_problem(captures: Sequence[Capture], unit: Unit, *, names: Sequence[str] | None = None,
                 bounds: dict[str, tuple[float, float]] | None = None,
                 constraints: Sequence[str] | None = None, weights: Sequence[float] | None = None,
                 segment: slice | None = None, fit_window: tuple[float, float] | None = None,
                 values: dict[str, float] | None = None, fit_edges: bool = True) -> Problem:
    """Bind captures and a unit into a `Problem`.

    names: parameters to fit (default `unit.identified_names`; effect parameters allowed; none, when
    only the edge instants are fitted, e.g. a holdout's timing under a model held fixed).
    bounds: per-name (lo, hi) overriding `default_bounds`. constraints: texts (default: the
    unit's, plus those of every effect with a fitted parameter). weights: alpha_k per capture
    (default 1). segment / fit_window: restrict the objective and MSE (samples / seconds from
    the record's start). values: kernel parameter values overriding the unit's for the
    parameters that are not fitted (e.g. a previous fit's result). fit_edges: fit the instant
    of every setpoint edge (`EDGE1`.. appended to the names, bounds from `timing.record_edges`);
    at most four edges over all captures are fitted, the others stay at their nominal sample.
    """
    caps = tuple(captures)
    if not caps:
        raise ProblemError("no capture given")
    names_t = tuple(unit.identified_names if names is None else names)
    if set(names_t) & set(EDGE_PARAMS):
        raise ProblemError(f"{sorted(set(names_t) & set(EDGE_PARAMS))}: edge offsets are set from the "
                           "captures (fit_edges), not named")
    caps_edges: list[list[Edge]] = [record_edges(c) for c in caps] if fit_edges else [[] for _ in caps]
    caps_slots: list[list[int | None]] = []
    edge_bounds: dict[str, tuple[float, float]] = {}
    for edges in caps_edges:
        slots: list[int | None] = []
        for e in edges:
            if len(edge_bounds) < len(EDGE_PARAMS):
                slot = len(edge_bounds)
                edge_bounds[EDGE_PARAMS[slot]] = (e.lo_s, e.hi_s)
                slots.append(slot)
            else:
                slots.append(None)
        caps_slots.append(slots)
    if not names_t and not edge_bounds:
        raise ProblemError("no parameter to fit")
    if any(s is None for slots in caps_slots for s in slots):
        logger.warning("more than %d setpoint edges over the captures: the later ones stay at their "
                       "nominal sample", len(EDGE_PARAMS))
    for n in names_t:
        if n not in PARAMS:
            raise ProblemError(Note("unknown parameter {!r}; known: {}", n, ", ".join(KERNEL_PARAMS)))
    if len(set(names_t)) != len(names_t):
        raise ProblemError(Note("parameter names repeat: {}", str(list(names_t))))
    bounds = dict(bounds or {})
    unknown = set(bounds) - set(names_t)
    if unknown:
        raise ProblemError(Note("bounds given for {}, which are not fitted ({})", str(sorted(unknown)),
                                str(list(names_t))))
    bnds = []
    for n in names_t:
        lo, hi = (float(v) for v in bounds.get(n, default_bounds(unit, n)))
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ProblemError(Note(f"bounds of {{}}: need finite lo < hi, got ({lo}, {hi})", n))
        bnds.append((lo, hi))
    names_t = names_t + tuple(edge_bounds)
    for n in edge_bounds:
        lo, hi = edge_bounds[n]
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ProblemError(Note(f"bounds of {{}}: need finite lo < hi, got ({lo}, {hi})", n))
        bnds.append((lo, hi))
    base = unit.values()
    grid_names = tuple(unit.grid_identify)
    base.update({k: b.value for k, b in unit.grid_identify.items()})
    if values:
        bad = set(values) - set(KERNEL_PARAMS)
        if bad:
            raise ProblemError(Note("values for unknown parameter(s) {}", str(sorted(bad))))
        base.update({k: float(v) for k, v in values.items()})

    if constraints is None:
        texts = list(unit.constraints)
        for eff in EFFECTS.values():
            if set(eff.params) & set(names_t):
                texts += [t for t in eff.constraints if t not in texts]
    else:
        texts = list(constraints)
    fitted, fixed = _reduce_constraints(texts, names_t, base)
    if grid_names:   # the [grid] values fitted on line: after the kernel's, in no constraint
        fitted = [LinearConstraint(expr=c.expr, coef=np.concatenate([c.coef, np.zeros(len(grid_names))]), rhs=c.rhs,
                                   names=names_t + grid_names) for c in fitted]
        bnds += [(unit.grid_identify[k].min, unit.grid_identify[k].max) for k in grid_names]
        names_t = names_t + grid_names
    _check_feasible(fitted, fixed, names_t, bnds)

    if weights is None:
        alphas = [1.0] * len(caps)
    else:
        alphas = [float(w) for w in weights]
        if len(alphas) != len(caps) or not all(math.isfinite(a) and a >= 0 for a in alphas):
            raise ProblemError(f"weights {list(weights)}: need one finite value >= 0 per capture "
                               f"({len(caps)})")
    w_efd = float(unit.weights.get("efd", 1.0))
    w_vt = float(unit.weights.get("vt", 0.0))
    if w_efd < 0 or w_vt < 0 or (w_efd == 0 and w_vt == 0):
        raise ProblemError(f"signal weights {unit.weights}: need >= 0 and at least one > 0")
    if w_efd == 0 and not any(c.vt is not None for c in caps):
        raise ProblemError("efd weight is 0 and no capture has a vt channel: nothing to fit")
    w_q = float(unit.weights.get("q", 1.0))
    w_vs = float(unit.weights.get("vs", VS_WEIGHT))
    for name, w in (("q", w_q), ("vs", w_vs)):
        if not (math.isfinite(w) and w >= 0):
            raise ProblemError(f"signal weight {name} = {w}: need a finite value >= 0")

    if segment is not None and fit_window is not None:
        raise ProblemError("give either segment or fit_window, not both")
    recs = []
    bound_total = 0.0
    for c, a, edges, slots in zip(caps, alphas, caps_edges, caps_slots):
        owner = c.source or "<capture in memory>"
        if c.n < 3:
            raise ProblemError(f"{owner}: {c.n} samples are too few to identify anything")
        dt = float(c.dt)
        # a writable copy: the engine takes a capture's read-only series as a copy, on every call
        usetp = np.require(c.usetp, float, ("C", "W"))
        vt = np.ascontiguousarray(c.vt, dtype=float) if c.vt is not None else None
        moved = [(e, s) for e, s in zip(edges, slots) if s is not None]
        spec = edge_plan_of([e for e, _ in moved], [s for _, s in moved])
        r = FitRecord(usetp=usetp, efd=np.ascontiguousarray(c.efd, dtype=float), vt=vt, dt=dt,
                    usetp_pre=pre_trigger_mean(usetp, dt), alpha=a, i0=0, i1=c.n, source=owner,
                    edges=spec, edge_list=tuple(edges), edge_slots=tuple(slots), **_on_line(c, unit, owner))
        window = segment_window(segment, c) if segment is not None else fit_window
        recs.append(apply_window(r, window, c))
        # a finite (non-failed) simulation keeps |states| < BLOWUP: bound its objective
        dur = dt * (c.n - 1)
        e_max = (_MAX_GAIN * BLOWUP + float(np.max(np.abs(c.efd)))) ** 2 * w_efd
        v_max = (BLOWUP + float(np.max(np.abs(vt)))) ** 2 * w_vt if vt is not None else 0.0
        q_max = (BLOWUP + float(np.max(np.abs(r.q)))) ** 2 * w_q if r.q is not None else 0.0
        s_max = (BLOWUP + float(np.max(np.abs(r.vs)))) ** 2 * w_vs if r.vs is not None else 0.0
        bound_total += a * (e_max + v_max + q_max + s_max) * dur
    if grid_names and not any(r.machine is not None for r in recs):
        raise ProblemError(f"{', '.join(grid_names)} fitted (--set {grid_names[0]}.min/max): only an on-line record "
                           "(a capture with p and q) determines the grid; these captures are at no load")
    window_used = fit_window if segment is None else segment_window(segment, caps[0])
    return Problem(captures=caps, unit=unit, names=names_t, bounds=tuple(bnds),
                   constraints=tuple(fitted), constraint_texts=tuple(texts),
                   fixed_constraints=tuple(fixed), weights=tuple(alphas), w_efd=w_efd, w_vt=w_vt,
                   base=base, records=tuple(recs), window=window_used,
                   penalty_base=max(1.0e20, 10.0 * bound_total), w_q=w_q, grid_names=grid_names,
                   w_vs=w_vs)


def scored_vs(c: Capture) -> np.ndarray | None:
    """The stabiliser's output a fit scores on capture c, as recorded: its `vs` channel on an
    on-line record taken with the PSS's output on; None otherwise (not recorded, at no load, or
    the PSS's output switched off, when the model's is held at 0 whatever the PSS computes)."""
    vs = c.channel("vs")
    return vs if vs is not None and c.on_line and not pss_switched_off(c) else None


def _on_line(c: Capture, unit: Unit, owner: str) -> dict[str, Any]:
    """A capture with P and Q channels is an on-line record: the unit's machine on the grid at the
    record's pre-step P, Q and Vt (FitRecord.machine, vt0, q), its stabiliser's output held at 0
    when the record was taken with the PSS off (`grid_as_recorded`); the recorded stabiliser
    output `vs` less its pre-step level (the model's is 0 there, every stabiliser's washouts see
    to it: a recorder channel's offset is not the model's to fit) where a fit scores it
    (`scored_vs`); a no-load record: nothing."""
    p, q = c.channel("p"), c.channel("q")
    if p is None and q is None:
        return {}
    if p is None or q is None or c.vt is None:
        have = [name for name, x in (("p", p), ("q", q), ("vt", c.vt)) if x is not None]
        raise ProblemError(f"{owner}: an on-line record needs p, q and vt; it has {', '.join(have)}")
    point = operating_point(c.usetp, p, q, c.vt, float(c.dt))
    missing = [name for name in machine_data(unit) if name not in unit.grid and name not in unit.grid_identify]
    if missing:
        raise ProblemError(f"{owner} is an on-line record (it has p and q): the unit {unit.name!r} needs "
                           f"{', '.join(missing)} under [grid] or with --set (the machine's data also come "
                           "from a GENROU or GENSAL record with --from-dyr)")
    try:
        start = {k: b.value for k, b in unit.grid_identify.items()}
        as_taken = {**start, "P0": point["P0"], "Q0": point["Q0"]}   # the stabiliser as the record was taken
        machine = machine_matrix(unit_machine(unit, grid_as_recorded(as_taken, c)))[0]
    except ValueError as exc:
        raise ProblemError(f"{owner}: {exc}") from None
    vs = scored_vs(c)
    if vs is not None:
        vs = np.ascontiguousarray(vs - pre_step_mean(c.usetp, vs, float(c.dt)), dtype=float)
    return {"machine": machine, "vt0": point["Vt0"], "q": np.ascontiguousarray(q, dtype=float),
            "grid_cols": tuple(MCOL[k] for k in unit.grid_identify), "vs": vs}

