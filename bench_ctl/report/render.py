"""`render_report`: a result (+ optional diagnosis) -> the HTML report, one PNG per figure beside
it, and optionally a PDF. See `bench_ctl.report` for what the report contains.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

from bench_ctl.diagnosis.diagnosis_file import Diagnosis
from bench_ctl.identification.result_file import IdentificationResult
from bench_ctl.outputs import Outputs
from bench_ctl.report import checks as chk
from bench_ctl.report.analysis import ReportData, analyse
from bench_ctl.report.document import Fig, Section
from bench_ctl.report.figures import FIGSIZE, png_bytes
from bench_ctl.report.html_page import render_html
from bench_ctl.report.metrics import DEFAULT_EDGE_WINDOW_S
from bench_ctl.report.outline import sections as build_sections
from bench_ctl.report.pdf_doc import pdf_bytes

log = logging.getLogger(__name__)


def figure_path(out_html: Path, name: str) -> Path:
    """Where figure `name` is written: `<html stem>_<name>.png` beside the HTML
    (`report_response.png` for `report.html`)."""
    return out_html.with_name(f"{out_html.stem}_{name}.png")


#: the figures of one capture (named with the capture's suffix when a result has several) and of
#: the report as a whole
CAPTURE_FIGURES = ("response", "residual", "edges")
REPORT_FIGURES = ("convergence", "diagnosis_effects", "diagnosis_staircase", "stabiliser")


def possible_figure_paths(out_html: str | os.PathLike[str], n_captures: int = 1) -> list[Path]:
    """Every side file a report on `n_captures` captures may write beside `out_html`, so that a
    command can claim them before its work (which of them are drawn depends on the data)."""
    out_html = Path(out_html)
    suffixes = [""] if n_captures <= 1 else [f"_{i + 1}" for i in range(n_captures)]
    names = [f"{n}{s}" for s in suffixes for n in CAPTURE_FIGURES] + list(REPORT_FIGURES)
    return [figure_path(out_html, n) for n in names]


def _figure_option(out_html: Path) -> str:
    return f"figure of {out_html.name}:"


def claim_report(outputs: Outputs, out_html: str | os.PathLike[str], *, n_captures: int = 1,
                 pdf: str | os.PathLike[str] | None = None) -> None:
    """Claim (before any work) the HTML, every figure a report on `n_captures` captures may draw
    beside it, and the PDF: a side file over an input, an existing one without --force or a
    symbolic link is refused as the HTML itself would be."""
    out_html = Path(out_html)
    outputs.claim("-o", out_html)
    for p in possible_figure_paths(out_html, n_captures):
        outputs.claim(_figure_option(out_html), p)
    if pdf is not None:
        outputs.claim("--pdf", pdf)


def _titles(d: ReportData) -> tuple[str, str]:
    title = f"AVR model validation report: {d.result.unit.name or 'unit not named'}"
    caps = ", ".join(a.loaded.path.name for a in d.captures)
    sub = (f"Capture(s) {caps}; result of {d.result.created_utc}; "
           f"report generated {d.generated_utc}; overall {d.verdict}")
    return title, sub


def render_report(result: IdentificationResult, out_html: str | os.PathLike[str], *,
                  diagnosis: Diagnosis | None = None,
                  pdf: str | os.PathLike[str] | None = None,
                  base_dir: str | os.PathLike[str] | None = None,
                  window_s: float = DEFAULT_EDGE_WINDOW_S,
                  noise_ratio_limit: float = chk.DEFAULT_NOISE_RATIO_LIMIT,
                  report_command: str = "", outputs: Outputs | None = None) -> list[Path]:
    """Write the report for `result` (schema bench-ctl/result/1) to `out_html`, each figure as
    `<stem>_<name>.png` beside it, and the PDF when `pdf` is given, every file through `outputs`
    (default: the captures protected, nothing existing replaced; see `bench_ctl.outputs`).

    Capture paths in the result are taken relative to `base_dir` (the folder of the result
    file), else as they are. Raises `ReportError` for a missing or implausible capture, a SHA-256
    / sample count / rate mismatch or a malformed result, `OutputRefused` for an output the
    guard refuses. Returns the written paths: the HTML first, then the PNGs, then the PDF.
    (`analyse` + `write_report` when the verdict is wanted too.)
    """
    data = analyse(result, diagnosis=diagnosis,
                   base_dir=None if base_dir is None else Path(base_dir),
                   window_s=window_s, noise_ratio_limit=noise_ratio_limit,
                   report_command=report_command)
    return write_report(data, out_html, pdf=pdf, outputs=outputs)


def write_report(data: ReportData, out_html: str | os.PathLike[str], *,
                 pdf: str | os.PathLike[str] | None = None, outputs: Outputs | None = None) -> list[Path]:
    """Write the HTML, the PNGs and (when asked) the PDF for analysed data; see render_report.
    Every file is claimed (`Outputs.claim`) before the first one is written."""
    out_html = Path(out_html)
    if outputs is None:
        outputs = Outputs([a.loaded.path for a in data.captures], make_folders=True)
    secs: list[Section] = build_sections(data, pdf=pdf is not None)
    title, sub = _titles(data)
    figs = [b for s in secs for b in s.blocks if isinstance(b, Fig)]
    outputs.claim("-o", out_html)
    for b in figs:
        outputs.claim(_figure_option(out_html), figure_path(out_html, b.name))
    if pdf is not None:
        outputs.claim("--pdf", pdf)
    pngs: dict[str, bytes] = {b.name: png_bytes(b.draw, b.size or FIGSIZE) for b in figs}
    pdf_data = pdf_bytes(title, sub, secs) if pdf is not None else None
    # a temporary file each, renamed: never half a page
    written = [outputs.write_text(out_html, render_html(title, sub, secs, pngs))]
    for name, png in pngs.items():
        written.append(outputs.write_bytes(figure_path(out_html, name), png))
    if pdf is not None and pdf_data is not None:
        written.append(outputs.write_bytes(pdf, pdf_data))
    log.info("report %s: %s, %d figure(s)%s", out_html, data.verdict, len(pngs),
             f", PDF {pdf}" if pdf is not None else "")
    return written
