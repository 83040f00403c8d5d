"""`bench-ctl import`: turn a recorder export (vendor CSV or COMTRADE .cfg) into a capture.

Example:
  bench-ctl import rec.csv -o cap.csv --map efd=EFD_V --map usetp=USETP \\
      --date-column Date --clock-column Time --efd-scale 0.5 --resample 1000
  bench-ctl import rec.csv -o cap.csv --map efd=EFD_V --time-column t \\
      --test pulse:start=1.0,amplitude=0.05,width=1.0

The record must pass the checks identify makes on its values (a time axis in ms, a broken cell
such as 1e308, a test description that is not the record's are refused before anything is
written); whether it holds a test at all (a moving setpoint, a responding efd) is judged when it
is fitted.

Exit codes: 0 written; 2 the input was refused (message on stderr: file, row, column), the
output exists or cannot be written, or the options are malformed (2 is bad input).
"""
from __future__ import annotations

import logging
from pathlib import Path

import click

from bench_ctl import outputs

from bench_ctl.capture.errors import CaptureError
from bench_ctl.capture.importer import ImportSpec, TestDescription, import_export as run_import

log = logging.getLogger(__name__)

_TEST_KEYS = {"start": "start_s", "amplitude": "amplitude_pu", "width": "width_s",
              "usetp0": "usetp0_pu", "tolerance": "edge_tolerance_s"}


def _pairs(values: tuple[str, ...], option: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in values:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise click.BadParameter(f"expected NAME=VALUE, got {item!r}", param_hint=option)
        if name.strip() in out:
            raise click.BadParameter(f"{name.strip()!r} given twice", param_hint=option)
        out[name.strip()] = value.strip()
    return out


def _floats(pairs: dict[str, str], option: str) -> dict[str, float]:
    try:
        return {k: float(v) for k, v in pairs.items()}
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint=option) from None


def parse_test(text: str) -> TestDescription:
    """`pulse:start=1.0,amplitude=0.05,width=1.0[,usetp0=1.0][,tolerance=0.01]` or
    `step:start=..,amplitude=..`; `tolerance` (s): how far the real edges may lie from the stated
    instants (default one source sample); every fit searches them within it."""
    kind, sep, rest = text.partition(":")
    if not sep:
        raise click.BadParameter("expected KIND:key=value,...", param_hint="--test")
    values = _floats(_pairs(tuple(p for p in rest.split(",") if p), "--test"), "--test")
    unknown = set(values) - set(_TEST_KEYS)
    if unknown:
        raise click.BadParameter(f"unknown key(s) {sorted(unknown)}; known: "
                                 f"{', '.join(_TEST_KEYS)}", param_hint="--test")
    try:
        return TestDescription(kind=kind.strip(),  # type: ignore[arg-type]
                               **{_TEST_KEYS[k]: v for k, v in values.items()})
    except (TypeError, ValueError) as exc:
        raise click.BadParameter(str(exc), param_hint="--test") from None


@click.command("import")
@click.argument("src", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False),
              help="Capture CSV to write (its .json sidecar goes beside it); never overwritten.")
@click.option("--map", "maps", multiple=True, metavar="NAME=COLUMN",
              help="Capture column (efd, usetp, vt) = source column or COMTRADE channel.")
@click.option("--time-column", help="Source column holding time in seconds.")
@click.option("--date-column", help="Source column holding the date (see --date-format).")
@click.option("--clock-column", help="Source column holding HH:MM:SS.ffff clock time.")
@click.option("--date-format", default="%Y-%m-%d", show_default=True)
@click.option("--delimiter", default=",", show_default=True,
              help="Field separator of the source CSV; 'tab' for a tab.")
@click.option("--decimal-comma", is_flag=True, help="The source uses a decimal comma.")
@click.option("--header-line", type=int, default=1, show_default=True,
              help="1-based line of the header (lines before it are skipped).")
@click.option("--efd-scale", type=float, default=1.0, show_default=True,
              help="Multiply efd by this (rated-field base -> model base).")
@click.option("--scale", "scales", multiple=True, metavar="NAME=FACTOR",
              help="Factor for usetp or vt.")
@click.option("--resample", "resample_hz", type=float, default=None, metavar="HZ",
              help="Resample onto HZ by linear interpolation (otherwise jitter is refused).")
@click.option("--test", "test_text", default=None, metavar="KIND:key=value,...",
              help="e.g. pulse:start=1.0,amplitude=0.05,width=1.0 (synthesises usetp when "
                   "it is not mapped).")
@click.option("--keep", "keep", multiple=True, metavar="COLUMN",
              help="Keep this other source column in the capture.")
def import_export(src: str, out: str, maps: tuple[str, ...], time_column: str | None,
                  date_column: str | None, clock_column: str | None, date_format: str,
                  delimiter: str, decimal_comma: bool, header_line: int, efd_scale: float,
                  scales: tuple[str, ...], resample_hz: float | None, test_text: str | None,
                  keep: tuple[str, ...]) -> int:
    """Import a recorder export SRC (CSV or COMTRADE .cfg) as a capture."""
    test = parse_test(test_text) if test_text else None
    try:
        spec = ImportSpec(
            columns=_pairs(maps, "--map"), time_column=time_column, date_column=date_column,
            clock_column=clock_column, date_format=date_format,
            delimiter="\t" if delimiter.lower() == "tab" else delimiter,
            decimal="," if decimal_comma else ".", header_line=header_line,
            efd_base_scale=efd_scale, scale=_floats(_pairs(scales, "--scale"), "--scale"),
            resample_hz=resample_hz, test=test, keep_columns=keep)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    try:
        if not str(out).lower().endswith(".csv"):
            raise ValueError(f"-o {out}: a capture file name must end in .csv")
        outputs.guard_outputs({"-o": out, "-o (its sidecar)": Path(out).with_suffix(".json")}, [src],
                              replace_hint="captures are never overwritten: choose another name")
        capture = run_import(src, spec, out)
    except (CaptureError, FileExistsError, ValueError) as exc:
        click.echo(f"error: {exc}", err=True)
        return 2
    except OSError as exc:
        click.echo(f"error: {outputs.why_not_written(exc, out)}", err=True)
        return 2
    click.echo(f"wrote {capture.source} ({capture.n} samples at {capture.rate_hz:g} Hz)")
    return 0
