"""The report's sections about the record and the run rather than the fit: the gap diagnosis
(when one is given), unit / test / capture metadata, and provenance (software, command lines).
The fit's own sections are in `fit_sections`; `outline.sections` puts them all in order.
"""
from __future__ import annotations

from collections.abc import Mapping
from functools import partial
from typing import Any

import bench_ctl
from bench_ctl.diagnosis.diagnosis_file import Diagnosis
from bench_ctl.model.unit_record import UnitEntry
from bench_ctl.report import figures as F
from bench_ctl.report.analysis import ReportData
from bench_ctl.report.document import NOT_AVAILABLE, Block, Fig, Heading, Num, Para, Section, flatten, fmt, num, table
from bench_ctl.report.inputs import same_file

NO_GAP = "n/a: base model at the noise floor"

PDF_METHOD = "matplotlib PdfPages (text pages with the tables, then the figures, A4)"


def diagnosis(d: ReportData) -> Section | None:
    g = d.diagnosis
    if g is None:
        return None
    blocks: list[Block] = []
    cap = g.capture
    if not any(same_file(cap, a.loaded) for a in d.captures):
        blocks.append(Para(f"Note: the diagnosis was made on {cap.path or '?'} (SHA-256 "
                           f"{cap.sha256 or '?'}), not on a capture of this result.", "note"))
    base = g.base
    hold = g.holdout
    rows = [("verdict", g.verdict),
            ("noise floor (pu²)", Num(num(g.noise_floor), "diag-noise-floor")),
            ("base model MSE (pu²)", Num(num(base.mse), "diag-base-mse")),
            ("base model MSE on hold-out (pu²)", Num(num(base.mse_holdout))),
            ("capture", f"{cap.path or '?'} (SHA-256 {cap.sha256 or '?'})"),
            ("hold-out capture", f"{hold.path or '?'} (SHA-256 {hold.sha256 or '?'})"
             if hold else "none")]
    rows.insert(3, ("base model at the noise floor", fmt(base.at_noise_floor)))
    rows.append(("validation (fit / check records)", fmt(g.validation.to_json(), 5)))
    rows.append(("decision criteria", fmt(g.criteria.to_json(), 5)))
    blocks.append(table(("item", "value"), rows, id="diagnosis-summary", kind="kv"))
    effects = g.effects
    at_floor = base.at_noise_floor
    if effects:
        blocks.append(table(
            ("rank", "effect", "parameters", "MSE (pu²)", "MSE hold-out (pu²)", "gap closed",
             "score", "AIC", "significant"),
            [(str(i + 1), e.name, fmt(e.params, 4),
              Num(num(e.mse)), Num(num(e.mse_holdout)),
              (NO_GAP if at_floor else Num(num(e.gap_closed), f"gap-{e.name}", 3)),
              Num(num(e.score), digits=4), Num(num(e.aic), digits=5), fmt(e.significant))
             for i, e in enumerate(effects)], id="diagnosis-effects",
            caption="Effects ranked, best first (gap closed: fraction of the base model's "
                    "excess MSE over the noise floor that the effect removes)"))
        if at_floor:
            blocks.append(Para("Gap closed is not applicable: the base model already fits to within the "
                               "noise floor, so there is no gap to close. Effects are ranked by score "
                               "(likelihood on the fit and check records).", "na"))
        elif any(e.gap_closed is not None for e in effects):
            blocks.append(Fig("diagnosis_effects", "How much of the gap between the base model "
                              "and the noise floor each effect closes.",
                              partial(F.draw_effects, effects=effects),
                              size=(F.FIGSIZE[0], 1.6 + 0.45 * len(effects))))
    else:
        blocks.append(Para(f"Effects: {NOT_AVAILABLE}.", "na"))
    segs, bands = g.localization.segments, g.localization.bands
    if segs:
        blocks.append(table(("segment", "from (s)", "to (s)", "share", "MSE (pu²)"),
                            [(s.name, Num(num(s.t0), digits=5), Num(num(s.t1), digits=5),
                              Num(num(s.share), digits=3), Num(num(s.mse))) for s in segs],
                            id="diagnosis-segments", caption="Localization: residual share per "
                            "segment (as computed by the diagnosis)"))
    if bands:
        blocks.append(table(("band", "from (Hz)", "to (Hz)", "share"),
                            [(b.name, Num(num(b.f0_hz), digits=4), Num(num(b.f1_hz), digits=4),
                              Num(num(b.share), digits=3)) for b in bands], id="diagnosis-bands",
                            caption="Localization: residual share per frequency band"))
    if not segs and not bands:
        blocks.append(Para(f"Localization: {NOT_AVAILABLE}.", "na"))
    feats = g.features
    blocks.append(table(("feature", "detected", "evidence"),
                        [(f.name, fmt(f.detected), f.evidence) for f in feats],
                        id="diagnosis-features", caption="Features of the residual")
                  if feats else Para(f"Features: {NOT_AVAILABLE}.", "na"))
    amb = g.ambiguous
    blocks.append(table(("effects", "test that would separate them"),
                        [(", ".join(a.effects), a.separating_test) for a in amb],
                        id="diagnosis-ambiguous", caption="Ambiguities")
                  if amb else Para("Ambiguities: none reported.", "note"))
    seq = g.sequence
    blocks.append(table(("step", "effect added", "MSE hold-out (pu²)"),
                        [(str(i + 1), s.added, Num(num(s.mse_holdout))) for i, s in enumerate(seq)],
                        id="diagnosis-sequence",
                        caption="Greedy sequence: effects added one after another")
                  if seq else Para(f"Greedy sequence: {NOT_AVAILABLE}.", "na"))
    blocks += _check(g)
    blocks += _explained_by(g)
    return Section("diagnosis", "Diagnosis of the remaining gap", tuple(blocks))


def _explained_by(g: Diagnosis) -> list[Block]:
    """The staircase: the error after each effect added (jointly re-fitted), down to what is left."""
    steps = g.explained_by
    left = g.left
    base = g.base
    floor = num(g.noise_floor)
    rows = [("base model", "", Num(num(base.mse), digits=4),
             Num(base.mse / floor if floor and base.mse is not None else None, digits=3),
             "", Num(num(base.mse_holdout), digits=4))]
    for s in steps:
        params = ", ".join(f"{k} {fmt(v, 4)}" for k, v in s.params.items())
        rows.append((f"+ {s.name}", params, Num(num(s.mse), digits=4),
                     Num(num(s.mse_over_floor), digits=3), Num(num(s.gap_closed), digits=3),
                     Num(num(s.check.mse), digits=4)))
    out: list[Block] = [table(("model", "effect parameters", "MSE (pu²)", "MSE / noise floor", "gap closed",
                               "check MSE (pu²)"), rows, id="diagnosis-explained-by",
                              caption="The effects that together explain the record, in the order added "
                                      "(each step re-fits every parameter): the error after each, down to "
                                      "the noise floor")]
    base_mse = num(base.mse)
    if steps and floor and base_mse is not None:
        out.append(Fig("diagnosis_staircase", "The staircase: the error after each effect added, over the noise "
                       "floor (log scale), down to it; squares: the same on the check.",
                       partial(F.draw_staircase, base_mse=base_mse, floor=floor, steps=steps, left=left,
                               base_check=num(base.check.mse if base.check else None))))
    out.append(Para(f"What is left: {left.note}.", "note"))
    return out


def _check(g: Diagnosis) -> list[Block]:
    """What every model was judged on: the holdout and the cross-validation windows."""
    chk = g.check
    parts_in: list[tuple[str, str, Any]] = [("holdout", f"holdout capture {chk.holdout.capture or ''}",
                                             chk.holdout)] if chk.holdout else []
    parts_in += [(w.label, w.label, w) for w in chk.windows]
    mse = {p.label: num(p.mse) for p in (g.base.check.parts if g.base.check else ())}
    rows = [(name, Num(num(w.t0), digits=4), Num(num(w.t1), digits=4), Num(mse.get(key), digits=4))
            for key, name, w in parts_in]
    return [table(("check part", "from (s)", "to (s)", "base model MSE there (pu²)"), rows, id="diagnosis-check",
                  caption=f"The check ({chk.kind}): {chk.how}")]


def _user_view(x: Any) -> Any:
    """`x` without its `kernel` keys: the kernel's names are for debugging, the report speaks the
    structure's (docs/formats.md)."""
    if isinstance(x, Mapping):
        return {k: _user_view(v) for k, v in x.items() if k != "kernel"}
    if isinstance(x, list):
        return [_user_view(v) for v in x]
    return x


def _unit_rows(unit: UnitEntry) -> list[tuple[str, str]]:
    """The result's unit as rows: one per identified parameter, the rest as flattened keys."""
    rows = []
    for key, value in _user_view(unit.to_json()).items():
        if key == "identify" and isinstance(value, Mapping):
            for name, spec in value.items():
                spec = spec if isinstance(spec, Mapping) else {}
                rows.append((f"identify {name}", f"start {fmt(spec.get('value'))}, bounds "
                             f"{fmt(spec.get('min'))} … {fmt(spec.get('max'))}"))
        elif isinstance(value, Mapping) and value and all(
                not isinstance(v, (Mapping, list)) for v in value.values()):
            rows.append((str(key), fmt(value)))
        else:
            rows += flatten({key: value})
    return rows


def metadata(d: ReportData) -> Section:
    blocks: list[Block] = [Heading("Unit"), table(("key", "value"), _unit_rows(d.result.unit), id="unit", kind="kv")]
    for a in d.captures:
        cap = a.loaded.capture
        blocks.append(Heading(f"Capture {a.loaded.index + 1}: test, recorder and bench"))
        rows = [("file", str(a.loaded.path)), ("SHA-256 (verified)", a.loaded.sha256),
                ("samples", Num(cap.n)), ("rate (Hz)", Num(cap.rate_hz)),
                ("duration (s)", Num(float(cap.time[-1] - cap.time[0]))),
                ("weight in the objective", Num(num(a.loaded.entry.weight)))]
        meta = _user_view(cap.meta or a.loaded.entry.meta or {})
        rows += [(f"sidecar: {k}", v) for k, v in flatten(meta)] if meta else \
            [("sidecar", "none (no test / bench description recorded)")]
        blocks.append(table(("key", "value"), rows, id=f"capture{a.suffix or '_1'}",
                            kind="kv"))
    return Section("metadata", "Unit, test and capture metadata", tuple(blocks))


def provenance(d: ReportData, pdf: bool) -> Section:
    r = d.result
    rows = [("result schema", r.schema),
            ("result software version", r.software_version),
            ("result command line", r.command_line),
            ("result created (UTC)", r.created_utc)]
    if d.diagnosis is not None:
        rows += [("diagnosis schema", d.diagnosis.schema),
                 ("diagnosis software version", d.diagnosis.software_version),
                 ("diagnosis command line", d.diagnosis.command_line),
                 ("diagnosis created (UTC)", d.diagnosis.created_utc)]
    rows += [("report software version", bench_ctl.__version__),
             ("report command line", d.report_command or NOT_AVAILABLE),
             ("report generated (UTC)", d.generated_utc),
             ("PDF", PDF_METHOD if pdf else "not requested")]
    return Section("provenance", "Software and command lines",
                   (table(("item", "value"), rows, id="provenance", kind="kv"),))
