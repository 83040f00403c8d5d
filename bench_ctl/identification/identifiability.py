"""What a capture determines: sensitivities, uncertainty, correlations, equivalent parameter sets.

At the optimum x* the residual vector of the objective (weighted efd and vt errors, see
`Problem.residuals`) is differentiated with respect to the log of every fitted parameter by
central differences (all 2 d perturbed candidates in ONE batched kernel call per capture). With
J that Jacobian and s^2 = SSE / (N - d) the residual variance, the Gauss-Newton approximation of
the covariance of the log-parameters is s^2 (J^T J)^-1 (the inverse Fisher information for white
noise). From it: the relative standard deviation (= std of ln x, first order), the standard
deviation std = x * rel_std, and the correlation matrix. The relative sensitivity of a parameter
is the RMS change of the simulated efd (pu) per unit relative change of the parameter.

A parameter is flagged as not determined when its relative std exceeds `max_rel_std` (25 %),
when it is almost fully correlated with another (|corr| > `max_corr`, 0.999), when it takes part in a
(numerically) singular direction of J, or when an equivalent parameter set that respects the
bounds and constraints gives it a different value. Pairs with |corr| > `note_corr` (0.99) are named in the
notes: the marginal std already accounts for the correlation, so such a pair can still be
determined, but the capture fixes their combination better than each one.

Equivalent sets: the reference AVR's transfer function KAVR (1 + s TA1)(1 + s TA3) /
((1 + s TA2)(1 + s TA4)) is unchanged when the lead-lag pairs (TA1, TA2) and (TA3, TA4) trade
places, and when only the two leads (TA1, TA3) or only the two lags (TA2, TA4) trade places.
Every structure adds the near-symmetric pairs it declares (`Structure.swaps`: the reference's
lags TA2 and TA4 against TE, IEEEX1's TA and TE); a declared pair that is not fitted is named in the
notes as not examined. Each swapped set is built, checked against the bounds and the constraints,
simulated, and reported with its MSE and whether it is equivalent (same fit within the noise); a
swap the constraints or bounds rule out is reported as such.

`analyse` returns the result's `Identifiability` record in the problem's (kernel) names: its
tables keyed by them, its texts `Note`s that carry them as data (`bench_ctl.model.dialect.Note`);
the result's writer says both in the structure's names (`Identifiability.renamed`).
"""
from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np

from bench_ctl.model.dialect import Note, slots
from bench_ctl.model.params import RECORD_PARAMS
from bench_ctl.model.stabilisers import IEEEST, stabiliser
from bench_ctl.model.structures import DEFAULT as DEFAULT_MODEL

from .problem import Problem
from .result_file import EquivalentSet, Identifiability, IdentifiabilitySettings

logger = logging.getLogger(__name__)

__all__ = ["analyse", "exchanges", "SWAPS"]

#: (note, mapping new_name -> source_name) of the lead-lag symmetries of the reference AVR
SWAPS: tuple[tuple[Note, dict[str, str]], ...] = (
    (Note("({},{}) <-> ({},{}) swapped", "TA1", "TA2", "TA3", "TA4"),
     {"TA1": "TA3", "TA2": "TA4", "TA3": "TA1", "TA4": "TA2"}),
    (Note("leads {} <-> {} swapped", "TA1", "TA3"), {"TA1": "TA3", "TA3": "TA1"}),
    (Note("lags {} <-> {} swapped", "TA2", "TA4"), {"TA2": "TA4", "TA4": "TA2"}),
)


def _weights(problem: Problem) -> np.ndarray:
    """Per-sample weights sqrt(alpha c dt w) of the efd residuals, in `residuals` order."""
    parts = []
    for r in problem.records:
        c = np.ones(r.i1 - r.i0)
        c[0] = c[-1] = 0.5
        w = np.sqrt(r.alpha * problem.w_efd * c * r.dt)
        parts.append(w)
        for _ in problem.signals(r)[1:]:   # vt, Q blocks: not part of the efd sensitivity
            parts.append(np.full(r.i1 - r.i0, np.nan))
    return np.concatenate(parts)


def _active(problem: Problem) -> np.ndarray:
    """Residual rows that count (a capture of weight alpha = 0 contributes rows of zeros)."""
    parts = []
    for r in problem.records:
        for _ in problem.signals(r):
            parts.append(np.full(r.i1 - r.i0, r.alpha > 0))
    return np.concatenate(parts)


def analyse(problem: Problem, x: Sequence[float], *, rel_step: float = 1e-4,
            max_rel_std: float = 0.25, max_corr: float = 0.999, note_corr: float = 0.99, cond_limit: float = 1e-8,
            equivalence_tol: float | None = None) -> Identifiability:
    """The `identifiability` block of the result (docs/formats.md) for `problem` at `x`."""
    x = np.asarray(x, dtype=float).reshape(-1)
    names = list(problem.names)
    d = len(names)
    notes: list[str] = []       # `Note`s: the names they carry are said by the writer
    reasons: dict[str, list[str]] = {n: [] for n in names}
    # log steps for positive model parameters; additive (s) for the edge offsets, whose sign is free
    positive = (x > 0) & np.array([n not in RECORD_PARAMS for n in names])
    # central differences in log x (additive for a parameter at 0, which has no log)
    h = np.where(positive, x * (math.exp(rel_step) - 1.0), rel_step)
    hm = np.where(positive, x * (1.0 - math.exp(-rel_step)), rel_step)
    X = np.vstack([x, x + np.diag(h), x - np.diag(hm)])
    R, failed = problem.residuals(X)
    if failed[0]:
        raise ValueError(f"the model fails to simulate at the point analysed {problem.params(x)}")
    if failed.any():
        notes.append("some perturbed candidates failed to simulate; their derivatives are unreliable")
    r0 = R[0]
    J = (R[1:d + 1] - R[d + 1:]).T / (2.0 * rel_step)  # d r / d ln x (per unit relative change)
    active = _active(problem)
    n_res = int(np.count_nonzero(active))
    sse = float(r0 @ r0)
    dof = max(1, n_res - d)
    s2 = sse / dof

    # relative sensitivity: RMS change of efd (pu) per unit relative change
    w = _weights(problem)
    efd_rows = np.isfinite(w) & active
    Je = J[efd_rows] / w[efd_rows, None]
    sens = np.sqrt(np.mean(Je * Je, axis=0))

    # Gauss-Newton covariance via SVD (robust to near-singular J)
    U, sv, Vt = np.linalg.svd(J, full_matrices=False)
    smax = float(sv[0]) if sv.size else 0.0
    small = sv <= cond_limit * smax if smax > 0 else np.ones_like(sv, bool)
    inv = np.where(small, 0.0, 1.0 / np.where(small, 1.0, sv) ** 2)
    cov_log = s2 * (Vt.T * inv) @ Vt
    std_log = np.sqrt(np.maximum(np.diag(cov_log), 0.0))
    for k in np.flatnonzero(small):
        v = Vt[k]
        involved = [names[i] for i in np.flatnonzero(np.abs(v) > 0.2)]
        notes.append(Note(f"singular direction (singular value {sv[k]:.3g} vs max {smax:.3g}) involving "
                          f"{slots(len(involved))}: the capture cannot tell these apart", *involved))
        for n in involved:
            reasons[n].append("part of a singular direction")
            std_log[names.index(n)] = math.inf
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_log / np.outer(std_log, std_log)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    np.fill_diagonal(corr, 1.0)
    rel_std = std_log  # std of ln x = relative std of x (first order)
    std = np.where(positive, x * rel_std, std_log)

    for i, n in enumerate(names):
        if rel_std[i] > max_rel_std and "part of a singular direction" not in reasons[n]:
            shown = f"{rel_std[i]:.0%}" if rel_std[i] < 10 else "> 1000%"
            reasons[n].append(f"relative std {shown} > {max_rel_std:.0%}")
        for j, m in enumerate(names):
            if j != i and abs(corr[i, j]) > max_corr:
                reasons[n].append(Note(f"|corr| with {{}} = {abs(corr[i, j]):.4f} > {max_corr}", m))
    pairs = [Note(f"{{}}-{{}} ({corr[i, j]:+.4f})", names[i], names[j]) for i in range(d) for j in range(i + 1, d)
             if abs(corr[i, j]) > note_corr]
    if pairs:
        notes.append(Note(f"strongly correlated: {slots(len(pairs))}; the capture fixes their combination "
                          "better than each one", *pairs))
    lo, hi = problem.lower, problem.upper
    for i, n in enumerate(names):
        span = hi[i] - lo[i]
        if x[i] <= lo[i] + 1e-6 * span or x[i] >= hi[i] - 1e-6 * span:
            notes.append(Note(f"{{}} = {x[i]:.6g} sits on its bound; the capture may want it beyond", n))
    for c in problem.constraint_report(x):
        if c["margin"] is not None and c["satisfied"] and abs(c["margin"]) <= 1e-6 * (1 + np.max(np.abs(x))):
            notes.append(Note("constraint {} is active: it, not the capture, fixes the parameters it links",
                              c["expr"]))

    mse_opt = float(np.mean(problem.mse(x)))
    n_efd = int(efd_rows.sum())
    tol = equivalence_tol if equivalence_tol is not None else max(1e-3 * mse_opt,
                                                                   3.0 * mse_opt * math.sqrt(2.0 / n_efd))
    eq_sets = _equivalent_sets(problem, x, mse_opt, tol, reasons, notes)

    determined = {n: not reasons[n] for n in names}
    undetermined = [n for n in names if not determined[n]]
    if undetermined:
        notes.append(Note(f"not determined by this capture: {slots(len(undetermined))}", *undetermined))
    logger.info("identifiability: s2 %.3g, rel std %s, undetermined %s", s2,
                dict(zip(names, np.round(rel_std, 4))), undetermined)
    return Identifiability(
        names=names,
        sensitivity={n: float(v) for n, v in zip(names, sens)},
        std={n: _num(v) for n, v in zip(names, std)},
        rel_std={n: _num(v) for n, v in zip(names, rel_std)},
        correlation=[[float(v) for v in row] for row in corr],
        determined=determined,
        reasons={n: r for n, r in reasons.items() if r},
        singular_values=[float(v) for v in sv],
        residual_variance=float(s2),
        equivalent_sets=tuple(eq_sets),
        notes=notes,
        settings=IdentifiabilitySettings(rel_step=rel_step, max_rel_std=max_rel_std, max_corr=max_corr,
                                         note_corr=note_corr, cond_limit=cond_limit, equivalence_tol_mse=tol),
    )


def not_analysed(names: Sequence[str]) -> Identifiability:
    """The block of a fit that failed: nothing determined, said so."""
    return Identifiability(names=list(names), sensitivity={}, std={}, rel_std={}, correlation=[],
                           determined={n: False for n in names}, equivalent_sets=(),
                           notes=["not analysed: the fit failed"])


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def exchanges(problem: Problem) -> list[tuple[Note, dict[str, str]]]:
    """Every exchange to examine, as (note, mapping new_name -> source_name, kernel names): the
    reference AVR's lead-lag symmetries (in a standard structure only where all four are fitted),
    every pair the structure declares (`Structure.swaps`, its note in its own names), fitted or
    not, so that one left out is said, and on line the stabiliser's exchanged leads and lags
    (`Stabiliser.exchanges`) where both are fitted."""
    st = problem.unit.structure
    names = list(problem.names)
    swaps = list(SWAPS) if st.name == DEFAULT_MODEL else [(n, m) for n, m in SWAPS if set(m) <= set(names)]
    simulated = [p.kernel for p in st.params if p.kernel is not None]
    for note, a, b in st.kernel_swaps(simulated):
        mapping = {a: b, b: a}
        if all(m != mapping for _, m in swaps):
            swaps.append((Note(note), mapping))
    if any(n.startswith("PSS") for n in problem.grid_names):
        pss = stabiliser(problem.unit.grid.get("PSS_MODEL", IEEEST))
        for a, b in pss.exchanges():
            if {a, b} <= set(names):
                swaps.append((Note(f"{pss.name} {{}} <-> {{}} swapped (lead-lags in series)", a, b), {a: b, b: a}))
    return swaps


def _equivalent_sets(problem: Problem, x: np.ndarray, mse_opt: float, tol: float,
                     reasons: dict[str, list[str]], notes: list[str]) -> list[EquivalentSet]:
    names = list(problem.names)
    values = problem.values(x)
    cands, meta = [], []
    for note, mapping in exchanges(problem):
        if not set(mapping) <= set(names):
            fixed = sorted(set(mapping) - set(names))
            notes.append(Note(f"{{}}: not examined, {slots(len(fixed))} not fitted", note, *fixed))
            continue
        new = dict(values)
        for dst, src in mapping.items():
            new[dst] = values[src]
        xs = np.array([new[n] for n in names])
        if np.allclose(xs, x, rtol=1e-9, atol=0.0):
            notes.append(Note("{}: gives the same point (the swapped values are equal)", note))
            continue
        lo, hi = problem.lower, problem.upper
        out = [Note(f"{{}} = {xs[i]:.6g} outside [{lo[i]:g}, {hi[i]:g}]", n) for i, n in enumerate(names)
               if not lo[i] <= xs[i] <= hi[i]]
        cands.append(xs)
        meta.append((note, mapping, out, list(problem.violated(xs))))
    if not cands:
        return []
    mses = problem.mse_many(np.array(cands)).mean(axis=0)
    sets = []
    for xs, m, (note, mapping, out, viol) in zip(cands, mses, meta):
        equivalent = bool(math.isfinite(m) and abs(m - mse_opt) <= tol)
        allowed = not out and not viol
        if equivalent and allowed:
            verdict = "equally good and allowed: the capture cannot choose between them"
            for n in mapping:
                if not math.isclose(values[n], values[mapping[n]], rel_tol=1e-6):
                    reasons[n].append(Note("exchangeable ({}) within bounds and constraints", note))
        elif equivalent:
            why = "; ".join(([f"constraints {slots(len(viol))}"] if viol else []) + (["bounds"] if out else []))
            verdict = Note(f"equally good but ruled out by {why}", *viol)
        else:
            verdict = "not equivalent (different response)"
        sets.append(EquivalentSet(params=problem.params(xs), mse=_num(float(m)), note=note, equivalent=equivalent,
                                  in_bounds=not out, outside_bounds=out, constraints_violated=viol,
                                  allowed=allowed, verdict=verdict))
    return sets
