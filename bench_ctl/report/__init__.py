"""The validation report an engineer hands to the grid operator (issue 6).

`render_report(result, out_html, diagnosis=None, pdf=None)` (an `IdentificationResult`, a
`Diagnosis`; `load_result` / `load_diagnosis` read their files) re-simulates the identified model on
the capture(s) the result names (after checking their SHA-256), and writes one self-contained
HTML page (inline CSS, figures as base64 PNG, nothing fetched from the network, print CSS for A4),
each figure as a PNG beside it, and optionally a PDF made with matplotlib's PdfPages.

Contents: pass / fail summary; measured vs simulated efd with the setpoint, residual, zooms on
both pulse edges; MSE / RMSE / NRMSE / peak error / segment shares; parameter table with units,
bounds, uncertainty, identifiability and equivalent sets; constraints; convergence; optimizer
comparison; on line, P, Q, Vt and the electromechanical mode, and the stabiliser test (PSS off vs on,
`stabiliser`) when the result holds a pss_step's two captures; diagnosis (when given); unit, test
and capture metadata; software and command lines.
"""
from bench_ctl.report.analysis import ReportData, analyse
from bench_ctl.report.inputs import ReportError, load_diagnosis, load_result
from bench_ctl.report.render import claim_report, figure_path, possible_figure_paths, render_report, write_report

__all__ = ["ReportData", "ReportError", "analyse", "claim_report", "figure_path", "load_diagnosis", "load_result",
           "possible_figure_paths", "render_report", "write_report"]
