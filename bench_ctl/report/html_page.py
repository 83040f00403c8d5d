"""The report as one self-contained HTML page: inline CSS (screen and print), figures as base64
PNG data URIs, no script, no external reference of any kind. Every text taken from a file is
escaped with `html.escape`.
"""
from __future__ import annotations

import base64
import html
from collections.abc import Mapping, Sequence

from bench_ctl.report.checks import verdict_class
from bench_ctl.report.document import Cell, Fig, Heading, Num, Para, Section, Status, Table, Verdict

CSS = """
:root { --pass: #1e7e34; --fail: #c5221f; --warn: #b26a00; --na: #666; }
* { box-sizing: border-box; }
body { font-family: "DejaVu Sans", "Liberation Sans", Arial, Helvetica, sans-serif;
       color: #222; background: #fff; max-width: 1100px; margin: 0 auto; padding: 16px;
       font-size: 14px; line-height: 1.4; }
h1 { font-size: 22px; margin: 0 0 4px 0; }
h2 { font-size: 18px; border-bottom: 2px solid #444; padding-bottom: 2px; margin-top: 28px; }
h3 { font-size: 15px; margin: 16px 0 6px 0; }
p.sub { margin: 0 0 10px 0; color: #444; }
p.note { color: #444; font-size: 13px; }
p.na { color: var(--na); font-style: italic; }
.verdict { border: 3px solid; border-radius: 6px; padding: 10px 14px; margin: 10px 0;
           font-size: 16px; }
.verdict b { font-size: 22px; margin-right: 12px; }
.verdict.PASS { border-color: var(--pass); background: #e8f5ec; }
.verdict.FAIL { border-color: var(--fail); background: #fdecea; }
.verdict.WARN { border-color: var(--warn); background: #fff4e0; }
.tw { overflow-x: auto; }
table { border-collapse: collapse; margin: 8px 0 14px 0; font-size: 13px; }
caption { caption-side: top; text-align: left; font-weight: bold; padding: 2px 0 4px 0; }
th, td { border: 1px solid #bbb; padding: 3px 7px; text-align: left; vertical-align: top;
         overflow-wrap: break-word; }
table.kv td { overflow-wrap: anywhere; }
th { background: #eee; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
table.kv td.num { text-align: left; }
td.mono { font-family: "DejaVu Sans Mono", monospace; font-size: 12px; }
.st { font-weight: bold; text-transform: uppercase; white-space: nowrap; }
.st.pass { color: var(--pass); } .st.fail { color: var(--fail); }
.st.warn { color: var(--warn); } .st.na { color: var(--na); }
figure { margin: 12px 0 18px 0; break-inside: avoid; page-break-inside: avoid; }
figure img { display: block; max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption { font-size: 13px; color: #444; margin-top: 4px; }
@page { size: A4; margin: 12mm; }
@media print {
  body { max-width: none; padding: 0; font-size: 10pt; }
  section { break-before: page; page-break-before: always; }
  section:first-of-type { break-before: auto; page-break-before: auto; }
  h2 { margin-top: 0; }
  .tw { overflow: visible; }
  table { font-size: 8.5pt; }
  thead { display: table-header-group; }
  tr, figure { break-inside: avoid; page-break-inside: avoid; }
  figure img { max-height: 120mm; width: auto; max-width: 100%; }
  .verdict { -webkit-print-color-adjust: exact; print-color-adjust: exact; }
}
"""

_STATUS_CLASS = {"pass": "pass", "fail": "fail", "warn": "warn", "n/a": "na"}


def esc(text: object) -> str:
    return html.escape(str(text), quote=True)


def _cell(c: Cell) -> str:
    if isinstance(c, Num):
        attrs = ' class="num"'
        if c.key:
            attrs += f' id="{esc(c.key)}"'
        if c.value is not None:
            attrs += f' data-value="{esc(repr(c.value))}"'
        return f"<td{attrs}>{esc(c.text())}</td>"
    if isinstance(c, Status):
        cls = _STATUS_CLASS.get(c.status, "na")
        return f'<td><span class="st {cls}">{esc(c.status)}</span></td>'
    return f"<td>{esc('—' if c is None else c)}</td>"


def _table(t: Table) -> str:
    ident = f' id="{esc(t.id)}"' if t.id else ""
    ident += f' class="{esc(t.kind)}"' if t.kind else ""
    cap = f"<caption>{esc(t.caption)}</caption>" if t.caption else ""
    head = "".join(f"<th>{esc(h)}</th>" for h in t.headers)
    body = "\n".join("<tr>" + "".join(_cell(c) for c in row) + "</tr>" for row in t.rows)
    return (f'<div class="tw"><table{ident}>{cap}<thead><tr>{head}</tr></thead>'
            f"<tbody>\n{body}\n</tbody></table></div>")


def _figure(f: Fig, png: bytes) -> str:
    data = base64.b64encode(png).decode("ascii")
    return (f'<figure id="fig-{esc(f.name)}"><img alt="{esc(f.caption)}" '
            f'src="data:image/png;base64,{data}"><figcaption>{esc(f.caption)}</figcaption></figure>')


def render_html(title: str, subtitle: str, sections: Sequence[Section],
                pngs: Mapping[str, bytes]) -> str:
    parts = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             f"<title>{esc(title)}</title>", f"<style>{CSS}</style>", "</head>", "<body>",
             f"<header><h1>{esc(title)}</h1><p class=\"sub\">{esc(subtitle)}</p></header>"]
    for s in sections:
        parts.append(f'<section id="sec-{esc(s.id)}"><h2>{esc(s.title)}</h2>')
        for b in s.blocks:
            if isinstance(b, Heading):
                parts.append(f"<h3>{esc(b.text)}</h3>")
            elif isinstance(b, Para):
                cls = f' class="{esc(b.cls)}"' if b.cls else ""
                parts.append(f"<p{cls}>{esc(b.text)}</p>")
            elif isinstance(b, Table):
                parts.append(_table(b))
            elif isinstance(b, Verdict):
                parts.append(f'<div class="verdict {esc(verdict_class(b.verdict))}" id="verdict"><b>'
                             f"{esc(b.verdict)}</b>{esc(b.text)}</div>")
            elif isinstance(b, Fig):
                parts.append(_figure(b, pngs[b.name]))
        parts.append("</section>")
    parts += ["</body>", "</html>", ""]
    return "\n".join(parts)
