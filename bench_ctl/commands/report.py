"""`bench-ctl report`: the validation report for an identification result.

Example:
  bench-ctl report result.json --diagnosis diag.json -o report.html --pdf report.pdf

Writes one self-contained HTML page (figures embedded, nothing fetched), each figure as
`<stem>_<name>.png` beside it, and the PDF (matplotlib PdfPages) when asked. Capture paths in
the result are relative to the result file's folder (absolute ones used as written); a path that
leads outside the result's folder and the working folder is refused before the file is opened,
unless --allow-outside (a result is a file anyone can hand over: its paths must not make the
report read and hash any file). The captures read are named on the console. Every file
goes through the output guard (`bench_ctl.outputs`): the PNGs too are never an input, never an
existing file without --force, never written through a symbolic link. A diagnosis of another
capture is shown, with a warning on the console, and its noise floor is not used.

Exit codes: 0 report written, no check failed (PASS, or PASS WITH WARNINGS: a fit well above
the noise floor, undetermined parameters, a value on a bound); 1 report written, a check failed (constraint
violated, reported MSE not reproduced, model blew up); 2 nothing written: the result, the
diagnosis or a capture was refused (missing file, SHA-256 mismatch, malformed JSON, a record
that is not a plausible setpoint test) or an output was refused or could not be written.
"""
from __future__ import annotations

import logging
import shlex
from pathlib import Path

import click

from bench_ctl import outputs
from bench_ctl.exitcodes import ExitCode
from bench_ctl.report import analyse, claim_report, load_diagnosis, load_result, write_report
from bench_ctl.report.checks import DEFAULT_NOISE_RATIO_LIMIT, FAIL
from bench_ctl.report.inputs import resolve_capture_path
from bench_ctl.report.metrics import DEFAULT_EDGE_WINDOW_S

log = logging.getLogger(__name__)


def _command_line(result_json: str, diagnosis_json: str | None, out: str, pdf: str | None,
                  edge_window: float, noise_ratio_limit: float) -> str:
    args = ["bench-ctl", "report", result_json]
    if diagnosis_json:
        args += ["--diagnosis", diagnosis_json]
    args += ["-o", out]
    if pdf:
        args += ["--pdf", pdf]
    if edge_window != DEFAULT_EDGE_WINDOW_S:
        args += ["--edge-window", repr(edge_window)]
    if noise_ratio_limit != DEFAULT_NOISE_RATIO_LIMIT:
        args += ["--noise-ratio-limit", repr(noise_ratio_limit)]
    return shlex.join(args)


@click.command("report")
@click.argument("result_json", metavar="RESULT.json", type=click.Path(dir_okay=False))
@click.option("--diagnosis", "diagnosis_json", metavar="DIAG.json", default=None,
              type=click.Path(dir_okay=False), help="Diagnosis JSON to include.")
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False),
              help="HTML file to write (an existing one only with --force); PNGs go beside it.")
@click.option("--pdf", default=None, type=click.Path(dir_okay=False),
              help="Also write a PDF (matplotlib PdfPages, A4).")
@click.option("--force", is_flag=True, help="Replace an existing report (never an input).")
@click.option("--edge-window", type=click.FloatRange(min=0.0, min_open=True),
              default=DEFAULT_EDGE_WINDOW_S, show_default=True,
              help="Length (s) of the leading / trailing edge segments.")
@click.option("--noise-ratio-limit", type=click.FloatRange(min=1.0),
              default=DEFAULT_NOISE_RATIO_LIMIT, show_default=True,
              help="Warn when MSE exceeds this multiple of the noise floor.")
@click.option("--allow-outside", is_flag=True,
              help="Read captures the result names outside its folder and the working folder (refused by default).")
def report(result_json: str, diagnosis_json: str | None, out: str, pdf: str | None,
           edge_window: float, noise_ratio_limit: float, force: bool = False, allow_outside: bool = False) -> int:
    """Write the validation report for RESULT.json (from `bench-ctl identify --json`)."""
    result = load_result(result_json)
    # the captures the result names (and their sidecars) are inputs too
    named = [c.path for c in result.captures]
    base = Path(result_json).resolve().parent
    caps = [str(resolve_capture_path(p, base)) for p in named if p]
    out_set = outputs.Outputs([result_json, diagnosis_json, *caps], force=force, make_folders=True)
    claim_report(out_set, out, n_captures=max(1, len(named)), pdf=pdf)
    diagnosis = load_diagnosis(diagnosis_json) if diagnosis_json else None
    data = analyse(result, diagnosis=diagnosis, base_dir=base,
                   where=result_json, window_s=edge_window,
                   noise_ratio_limit=noise_ratio_limit,
                   report_command=_command_line(result_json, diagnosis_json, out, pdf,
                                                edge_window, noise_ratio_limit),
                   confine=None if allow_outside else [base, Path.cwd()])
    for c in data.captures:
        click.echo(f"read capture {c.loaded.path} (SHA-256 as in the result)")
    for c in data.checks:
        if c.name == "diagnosis of this record" and c.status == "warn":
            click.echo(f"WARNING: --diagnosis {diagnosis_json}: {c.detail}", err=True)
    with outputs.writing(out, "the report was not written: "):
        written = write_report(data, out, pdf=pdf, outputs=out_set)
    for path in written:
        click.echo(f"wrote {path}")
    for c in data.checks:
        if c.status in ("fail", "warn"):
            click.echo(f"{c.status.upper()}: {c.name}: {c.detail}")
    click.echo(f"overall: {data.verdict}")
    return ExitCode.FAILED if data.verdict == FAIL else ExitCode.OK
