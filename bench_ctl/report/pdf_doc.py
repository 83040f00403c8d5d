"""The report as a PDF, made with matplotlib's PdfPages only (works wherever the pip packages do,
no browser needed): A4 text pages carrying every section's tables, then the figures two per page.
"""
from __future__ import annotations

import io
import textwrap
from collections.abc import Sequence
from pathlib import Path

from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine

import bench_ctl
from bench_ctl.report.document import Cell, Fig, Heading, Num, Para, Section, Status, Table, Verdict

A4 = (8.27, 11.69)  # inches, portrait
FONT = "DejaVu Sans Mono"
SIZE = 6.8          # pt
LINE_PT = SIZE * 1.32
MARGIN_IN = 0.5
WIDTH_CHARS = 120
CAPTION_CHARS = 130
FIG_RECT = (MARGIN_IN / 2 / A4[0], MARGIN_IN / A4[1], 1 - MARGIN_IN / A4[0], 1 - MARGIN_IN / A4[1])
LINES_PER_PAGE = int((A4[1] - 2 * MARGIN_IN) * 72 / LINE_PT) - 2

Line = tuple[str, str]  # (text, style: "h1" | "h2" | "h3" | "" | "note")


def _cell_text(c: Cell) -> str:
    if isinstance(c, Num):
        return c.text()
    if isinstance(c, Status):
        return c.status.upper()
    return "—" if c is None else str(c)


def _fit_widths(widths: list[int], total: int) -> list[int]:
    widths = list(widths)
    while sum(widths) + 3 * (len(widths) - 1) > total and max(widths) > 8:
        widths[widths.index(max(widths))] -= 1
    return widths


def table_lines(t: Table, width: int = WIDTH_CHARS) -> list[Line]:
    """A table as fixed-width text; long cells wrap inside their column (nothing is cut)."""
    cells = [list(t.headers)] + [[_cell_text(c) for c in row] for row in t.rows]
    natural = [max([len(r[i]) for r in cells[1:]] + [max(map(len, t.headers[i].split()), default=1)])
               for i in range(len(t.headers))]
    widths = _fit_widths(natural, width)
    out: list[Line] = [(t.caption, "h3")] if t.caption else []
    for k, row in enumerate(cells):
        wrapped = [textwrap.wrap(txt, w, break_long_words=True) or [""] for txt, w in zip(row, widths)]
        for j in range(max(len(w) for w in wrapped)):
            parts = [(w[j] if j < len(w) else "").ljust(widths[i]) for i, w in enumerate(wrapped)]
            out.append((" | ".join(parts).rstrip(), "th" if k == 0 else ""))
        if k == 0:
            out.append(("-+-".join("-" * w for w in widths), ""))
    out.append(("", ""))
    return out


def section_groups(sections: Sequence[Section]) -> list[list[Line]]:
    """The text of every section as groups of lines that should stay on one page (a table with
    its caption, a paragraph); a heading is kept with the group after it."""
    groups: list[list[Line]] = []
    pending: list[Line] = []
    for s in sections:
        pending += [("", ""), (s.title.upper(), "h2")]
        for b in s.blocks:
            if isinstance(b, Heading):
                pending.append((b.text, "h3"))
                continue
            if isinstance(b, Para):
                g = [(w, "note") for w in textwrap.wrap(b.text, WIDTH_CHARS)] + [("", "")]
            elif isinstance(b, Verdict):
                g = [(f"OVERALL: {b.verdict}  ({b.text})", "h2"), ("", "")]
            elif isinstance(b, Table):
                g = table_lines(b)
            elif isinstance(b, Fig):
                g = [(w, "note") for w in textwrap.wrap(
                    f"[figure '{b.name}' on the figure pages: {b.caption}]", WIDTH_CHARS)]
            else:
                continue
            groups.append(pending + g)
            pending = []
    if pending:
        groups.append(pending)
    return groups


def paginate(groups: Sequence[list[Line]], per_page: int = LINES_PER_PAGE,
             min_start: int = 8) -> list[list[Line]]:
    """Fill pages with groups; a group that does not fit goes to the next page, unless it is
    longer than a page and at least `min_start` lines are left, then it is split."""
    pages: list[list[Line]] = [[]]
    for g in groups:
        g = list(g)
        left = per_page - len(pages[-1])
        if len(g) > left and pages[-1] and (len(g) <= per_page or left < min_start):
            pages.append([])
        while g:
            left = per_page - len(pages[-1])
            if left <= 0:
                pages.append([])
                continue
            pages[-1] += g[:left]
            g = g[left:]
    return [p for p in pages if p]


_STYLE = {"h1": dict(fontsize=11, weight="bold"), "h2": dict(fontsize=8.5, weight="bold"),
          "h3": dict(fontsize=SIZE, weight="bold"), "th": dict(fontsize=SIZE, weight="bold"),
          "note": dict(fontsize=SIZE, style="italic"), "": dict(fontsize=SIZE)}


def _text_page(pdf: PdfPages, title: str, lines: Sequence[Line], page: int) -> None:
    fig = Figure(figsize=A4)
    top = 1.0 - MARGIN_IN / A4[1]
    step = LINE_PT / 72 / A4[1]
    fig.text(MARGIN_IN / A4[0], top, title, family=FONT, va="top", **_STYLE["h1"])
    for i, (text, style) in enumerate(lines):
        if text:
            fig.text(MARGIN_IN / A4[0], top - (i + 2) * step, text, family=FONT, va="top",
                     **_STYLE.get(style, _STYLE[""]))
    fig.text(0.5, MARGIN_IN / 2 / A4[1], f"page {page}", family=FONT, ha="center", fontsize=6)
    pdf.savefig(fig)


def pdf_bytes(title: str, subtitle: str, sections: Sequence[Section]) -> bytes:
    """The PDF's bytes (written to a file by the caller, through `bench_ctl.outputs`)."""
    buf = io.BytesIO()
    write_pdf(buf, title, subtitle, sections)
    return buf.getvalue()


def write_pdf(path: Path | io.BytesIO, title: str, subtitle: str, sections: Sequence[Section]) -> None:
    pages = paginate([[(subtitle, "")]] + section_groups(sections))
    figs = [b for s in sections for b in s.blocks if isinstance(b, Fig)]
    page = 0
    with PdfPages(path, metadata={"Title": title, "Creator": f"bench-ctl {bench_ctl.__version__}"}) as pdf:
        for lines in pages:
            page += 1
            _text_page(pdf, title, lines, page)
        for start in range(0, len(figs), 2):
            page += 1
            fig = Figure(figsize=A4)
            fig.set_layout_engine(ConstrainedLayoutEngine(rect=FIG_RECT))
            pair = figs[start:start + 2]
            subs = fig.subfigures(2, 1, hspace=0.04)
            for sub, f in zip(subs, pair):
                f.draw(sub)
                sub.suptitle(textwrap.fill(f"Figure '{f.name}': {f.caption}", CAPTION_CHARS),
                             fontsize=7, ha="left", x=0.02)
            fig.text(0.5, MARGIN_IN / 2 / A4[1], f"page {page}", ha="center", fontsize=6)
            pdf.savefig(fig)
