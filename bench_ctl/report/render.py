"""`render_report`: a result (+ optional diagnosis) -> the HTML report, one PNG per figure beside
it, and optionally a PDF. See `bench_ctl.report` for what the report contains.
"""
from __future__ import annotations

import logging
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from bench_ctl.outputs import write_text
from bench_ctl.report import checks as chk
from bench_ctl.report.analysis import ReportData, analyse
from bench_ctl.report.blocks import Fig, Section
from bench_ctl.report.outline import sections as build_sections
from bench_ctl.report.figures import FIGSIZE, png_bytes
from bench_ctl.report.html_page import render_html
from bench_ctl.report.metrics import DEFAULT_EDGE_WINDOW_S
from bench_ctl.report.pdf_doc import write_pdf

log = logging.getLogger(__name__)


def figure_path(out_html: Path, name: str) -> Path:
    """Where figure `name` is written: `<html stem>_<name>.png` beside the HTML
    (`report_response.png` for `report.html`)."""
    return out_html.with_name(f"{out_html.stem}_{name}.png")


def _titles(d: ReportData) -> tuple[str, str]:
    unit = d.result.get("unit") if isinstance(d.result.get("unit"), Mapping) else {}
    title = f"AVR model validation report: {unit.get('name', 'unit not named')}"
    caps = ", ".join(a.loaded.path.name for a in d.captures)
    sub = (f"Capture(s) {caps}; result of {d.result.get('created_utc', 'unknown date')}; "
           f"report generated {d.generated_utc}; overall {d.verdict}")
    return title, sub


def render_report(result: Mapping[str, Any], out_html: str | os.PathLike[str], *,
                  diagnosis: Mapping[str, Any] | None = None,
                  pdf: str | os.PathLike[str] | None = None,
                  base_dir: str | os.PathLike[str] | None = None,
                  window_s: float = DEFAULT_EDGE_WINDOW_S,
                  noise_ratio_limit: float = chk.DEFAULT_NOISE_RATIO_LIMIT,
                  report_command: str = "") -> list[Path]:
    """Write the report for `result` (schema bench-ctl/result/1) to `out_html`, each figure as
    `<stem>_<name>.png` beside it, and the PDF when `pdf` is given (existing files are replaced).

    Capture paths in the result are taken as they are, else relative to `base_dir` (the folder
    of the result file). Raises `ReportError` for a missing capture, a SHA-256 / sample count /
    rate mismatch or a malformed result. Returns the written paths: the HTML first, then the
    PNGs, then the PDF. (`analyse` + `write_report` when the verdict is wanted too.)
    """
    data = analyse(result, diagnosis=diagnosis,
                   base_dir=None if base_dir is None else Path(base_dir),
                   window_s=window_s, noise_ratio_limit=noise_ratio_limit,
                   report_command=report_command)
    return write_report(data, out_html, pdf=pdf)


def write_report(data: ReportData, out_html: str | os.PathLike[str], *,
                 pdf: str | os.PathLike[str] | None = None) -> list[Path]:
    """Write the HTML, the PNGs and (when asked) the PDF for analysed data; see render_report."""
    out_html = Path(out_html)
    secs: list[Section] = build_sections(data, pdf=pdf is not None)
    title, sub = _titles(data)
    pngs: dict[str, bytes] = {}
    for s in secs:
        for b in s.blocks:
            if isinstance(b, Fig):
                pngs[b.name] = png_bytes(b.draw, b.size or FIGSIZE)
    out_html.parent.mkdir(parents=True, exist_ok=True)
    write_text(out_html, render_html(title, sub, secs, pngs))  # a temporary file, renamed: never half a page
    written = [out_html]
    for name, png in pngs.items():
        p = figure_path(out_html, name)
        p.write_bytes(png)
        written.append(p)
    if pdf is not None:
        pdf_path = Path(pdf)
        pdf_path.parent.mkdir(parents=True, exist_ok=True)
        write_pdf(pdf_path, title, sub, secs)
        written.append(pdf_path)
    log.info("report %s: %s, %d figure(s)%s", out_html, data.verdict, len(pngs),
             f", PDF {pdf}" if pdf is not None else "")
    return written
