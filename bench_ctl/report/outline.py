"""The whole report in order: the fit's sections (`fit_sections`, the model's `parameter_sections`;
after the on-line one the stabiliser test's when the result holds a `pss_step`'s two captures),
then the diagnosis when given, the metadata and the provenance (`record_sections`)."""
from __future__ import annotations

from bench_ctl.report import fit_sections as fit
from bench_ctl.report import parameter_sections as model
from bench_ctl.report.analysis import ReportData
from bench_ctl.report.document import Section
from bench_ctl.report.record_sections import diagnosis, metadata, provenance
from bench_ctl.report.stabiliser import stabiliser


def sections(d: ReportData, *, pdf: bool = False) -> list[Section]:
    out = [fit.summary(d), fit.response(d)]
    on_line = fit.online(d)
    if on_line is not None:
        out.append(on_line)
    pss = stabiliser(d)
    if pss is not None:
        out.append(pss)
    out += [fit.errors(d), fit.acceptance(d), model.parameters(d)]
    chosen = fit.selection(d)
    if chosen is not None:
        out.append(chosen)
    out += [model.constraints(d), fit.convergence(d), fit.comparison(d)]
    diag = diagnosis(d)
    if diag is not None:
        out.append(diag)
    out += [metadata(d), provenance(d, pdf)]
    return out
