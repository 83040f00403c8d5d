"""The report's sections about the identified model, as blocks (see `blocks`): the structure and
its parameters (value, bounds, uncertainty, equivalent sets, correlations), the fixed values and
the constraints. The fit's other sections are in `fit_sections`; `outline` orders them all.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from bench_ctl.identification.result_file import EquivalentSet, Identifiability, IdentificationResult
from bench_ctl.model.structures import StructureError, structure
from bench_ctl.report.analysis import ReportData
from bench_ctl.report.document import NOT_AVAILABLE, Block, Num, Para, Section, Status, fmt, num, table

#: an estimate pair whose correlation is at least this (in magnitude) is listed
STRONG_CORRELATION = 0.9


def _strong_pairs(ident: Identifiability) -> list[tuple[str, float]]:
    names = ident.names
    c = np.asarray(ident.correlation, float)
    if c.shape != (len(names), len(names)):
        return []
    out = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if abs(c[i, j]) >= STRONG_CORRELATION:
                out.append((f"{names[i]} – {names[j]}", float(c[i, j])))
    return out


def _set_verdict(s: EquivalentSet) -> str:
    if s.verdict:
        return s.verdict
    return "; ".join([*s.outside_bounds, *(f"violates {c}" for c in s.constraints_violated)])


def _determined(det: Any, reasons: Any) -> str:
    if det is None:
        return NOT_AVAILABLE
    text = "yes" if det is True else "NO"
    if isinstance(reasons, list) and reasons:
        text += ": " + "; ".join(map(str, reasons))
    elif isinstance(reasons, str) and reasons:
        text += ": " + reasons
    return text


def _model_blocks(r: IdentificationResult) -> list[Block]:
    """The structure by name and its parameters under their standard names: value, unit, meaning,
    identified (and determined by the capture) or fixed, simulated or kept for the record."""
    model = r.model
    if model is None or not model.name:
        return [Para("AVR / exciter model: the reference structure (this result names no model).", "note")]
    try:
        st = structure(model.name)
    except StructureError:
        return [Para(f"AVR / exciter model: {model.name} (not in this version's library).", "na")]
    values = model.params
    ident = set(model.identified)
    det = model.determined
    rows = []
    for p in st.params:
        if p.name in ident:
            role = "identified, " + ("determined by the capture" if det.get(p.name) else "NOT determined")
        elif p.kernel is None:
            role = f"for the record only ({p.note})" if p.note else "for the record only"
        else:
            role = "fixed"
        rows.append((p.name, Num(num(values.get(p.name)), f"model-{p.name}"), p.unit, p.info, role))
    gen = model.generator
    text = (f"AVR / exciter model: {st.name} — {st.title}. PSS/E record: {st.dyr_model or 'none'} "
            f"(bench-ctl export --dyr). Block diagram: " + "; ".join(st.diagram) + ".")
    blocks: list[Block] = [Para(text, "model"),
                           table(("parameter", "value", "unit", "meaning", "role"), rows, id="model-params",
                                 caption=f"{st.name} parameters under their standard names")]
    if gen:
        blocks.append(Para("No-load generator: " + ", ".join(f"{k} = {fmt(v, 4)}" for k, v in gen.items())
                           + " (KPP, KDA: the GENROU / GENSAL flux shares, 0 in the reference model; SATEQ = 1: "
                           "saturation on E'q, a GENSAL's).", "note"))
    return blocks


def parameters(d: ReportData) -> Section:
    r = d.result
    params = r.params
    bounds = r.bounds
    ident = r.identifiability
    rows = []
    for name, value in params.items():
        info = r.describe(name)     # the result speaks the structure's names
        b = bounds.get(name) or (None, None)
        rel = num(ident.rel_std.get(name)) if ident else None
        det = ident.determined.get(name) if ident else None
        rows.append((name, Num(num(value), f"param-{name}"),
                     info[0] if info else "?",
                     info[1] if info else "", Num(num(b[0])), Num(num(b[1])),
                     Num(num(ident.std.get(name) if ident else None), f"std-{name}", 3),
                     Num(None if rel is None else 100.0 * rel, digits=3),
                     Num(num(ident.sensitivity.get(name) if ident else None), digits=3),
                     _determined(det, (ident.reasons or {}).get(name) if ident else None)))
    blocks: list[Block] = _model_blocks(r) + [table(("parameter", "value", "unit", "meaning", "lower bound",
                                  "upper bound", "std", "rel. std (%)", "sensitivity",
                                  "determined"), rows, id="params",
                                 caption="Identified parameters")]
    if ident is None:
        blocks.append(Para("Identifiability (uncertainty, sensitivity, determined, equivalent "
                           f"parameter sets): {NOT_AVAILABLE} in this result.", "na"))
    else:
        blocks.append(Para("std from the Fisher information (Gauss–Newton) at the optimum; "
                           "sensitivity = relative sensitivity norm of efd to the parameter.",
                           "note"))
        sets = ident.equivalent_sets
        if sets:
            blocks.append(table(("#", "parameters", "MSE (pu²)", "note", "allowed", "verdict"),
                                [(str(i + 1), fmt(s.params, 5), Num(num(s.mse)),
                                  s.note, fmt(s.allowed), _set_verdict(s))
                                 for i, s in enumerate(sets)],
                                id="equivalent-sets",
                                caption="Equivalent parameter sets (same response within noise)"))
        else:
            blocks.append(Para("Equivalent parameter sets: none reported.", "note"))
        pairs = _strong_pairs(ident)
        if pairs:
            blocks.append(table(("pair", "correlation"), [(p, Num(c, digits=3)) for p, c in pairs],
                                id="correlations",
                                caption=f"Strongly correlated estimates (|r| ≥ {STRONG_CORRELATION:g})"))
        for note in ident.notes:
            blocks.append(Para(note, "note"))
    fixed = r.fixed
    frows = []
    for name, value in fixed.items():
        info = r.describe(name)
        if value is None:
            neutral = info[2] if info and info[2] is not None else float("inf")
            text: Any = f"{fmt(neutral)} (effect off)"
        else:
            text = Num(num(value), f"fixed-{name}")
        frows.append((name, text, info[0] if info else "?", info[1] if info else ""))
    if frows:
        blocks.append(table(("parameter", "value", "unit", "meaning"), frows, id="fixed",
                            caption="Fixed parameters used in the simulation"))
    else:
        blocks.append(Para(f"Fixed parameters: {NOT_AVAILABLE}.", "na"))
    return Section("parameters", "Parameters", tuple(blocks))


def constraints(d: ReportData) -> Section:
    if not d.constraints:
        return Section("constraints", "Constraints",
                       (Para("The result lists no constraints.", "na"),))
    rows = []
    for c in d.constraints:
        rep, re_ok = c.get("satisfied"), c.get("recheck_satisfied")
        ok = rep is True and re_ok is not False
        rows.append((str(c.get("expr", "?")), Status("pass" if ok else "fail"),
                     fmt(rep) if isinstance(rep, bool) else NOT_AVAILABLE,
                     Num(num(c.get("margin"))), Num(c.get("recheck_margin")),
                     "not re-evaluated" if re_ok is None else fmt(re_ok)))
    return Section("constraints", "Constraints", (
        table(("constraint", "status", "satisfied (reported)", "margin (reported)",
               "margin (re-evaluated)", "satisfied (re-evaluated)"), rows, id="constraints"),
        Para("Margin = slack of the inequality at the identified values (≥ 0 when satisfied); "
             "re-evaluated by the report from params + fixed.", "note")))
