"""`bench-ctl import`: turn a recorder export (vendor CSV or COMTRADE .cfg) into a capture.

Example:
  bench-ctl import rec.csv -o cap.csv --map efd=EFD_V --map usetp=USETP \\
      --date-column Date --clock-column Time --efd-scale 0.5 --resample 1000
  bench-ctl import rec.csv -o cap.csv --map efd=EFD_V --time-column t \\
      --test pulse:start=1.0,amplitude=0.05,width=1.0
  bench-ctl import export.csv -o cap.csv --date-column date --clock-column time \\
      --date-format %d.%m.%Y --resample 200 --map efd=SFS_Meas_UfRel --map vt=SFS_Meas_UgRel \\
      --map vr=SFS_Reg_Uc --map ifd=SFS_Meas_IfRel --scale ifd=auto \\
      --test step:amplitude=0.1 --efd-base auto --set S10=0.1 --set S12=0.4
  bench-ctl import online.csv -o cap.csv --time-column t --map usetp=UREF --map efd=EFD --map vt=UG \\
      --map p=P --map q=Q --map vs=PSS_OUT --scale vs=0.1 --efd-base from:noload.csv

On line with the PSS on, `--map vs=COLUMN` records the stabiliser's output (pu; `--scale vs=K` from
volts): identify and diagnose then fit it with efd, Vt and Q (docs/formats.md).

Without a start, `--test` has its edges found in the record (the regulator output `vr`, else efd,
else vt: bench_ctl/capture/found_test.py); `--efd-base auto` puts the pre-step efd on the model's
no-load base Vt0 + Sat(Vt0) with the unit's saturation (--unit, --set, --from-dyr as elsewhere:
bench_ctl/capture/field_base.py); on an on-line record (P and Q mapped) it is refused, and
`--efd-base from:NOLOAD.csv` takes the factor the unit's no-load import found. `--window START:END`
takes the test out of a long export, `--rate HZ` rebuilds the time base from the recorder's rate
(a clock column a spreadsheet shortened to MM:SS.f needs it). What was found and the factors used
are printed and stored in the sidecar's `import` block (docs/formats.md); a pre-step part that is
not steady is warned of, with a window that leaves it out.

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
from typing import Any

import click

from bench_ctl import outputs
from bench_ctl.capture import held
from bench_ctl.capture.capture import Capture
from bench_ctl.capture.errors import SpecError
from bench_ctl.capture.field_base import NoLoad, parse_efd_base
from bench_ctl.capture.importer import ImportSpec, TestDescription
from bench_ctl.capture.importer import import_export as run_import
from bench_ctl.capture.steady import warning_lines
from bench_ctl.capture.window import parse_window
from bench_ctl.exitcodes import ExitCode
from bench_ctl.units.unit import Unit

from .options import resolve_unit, unit_options

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
    instants (default one source sample); every fit searches them within it. Without `start` (and
    a pulse's `width`) the edges are found in the record."""
    kind, sep, rest = text.partition(":")
    if not sep:
        raise click.BadParameter("expected KIND:key=value,...", param_hint="--test")
    values = _floats(_pairs(tuple(p for p in rest.split(",") if p), "--test"), "--test")
    unknown = set(values) - set(_TEST_KEYS)
    if unknown:
        raise click.BadParameter(f"unknown key(s) {sorted(unknown)}; known: "
                                 f"{', '.join(_TEST_KEYS)}", param_hint="--test")
    if "amplitude" not in values:
        raise click.BadParameter("give the amplitude (pu), e.g. step:amplitude=0.1", param_hint="--test")
    try:
        return TestDescription(kind=kind.strip(),  # type: ignore[arg-type]
                               **{_TEST_KEYS[k]: v for k, v in values.items()})
    except SpecError as exc:
        raise click.BadParameter(str(exc), param_hint="--test") from None


def _scales(values: tuple[str, ...]) -> tuple[dict[str, float], bool, str | None]:
    """--scale NAME=FACTOR pairs, whether ifd=auto was asked for, and ifd=from:NOLOAD.csv's path."""
    pairs = _pairs(values, "--scale")
    ifd_auto = pairs.get("ifd", "").lower() == "auto"
    ifd_from = None
    if ifd_auto:
        del pairs["ifd"]
    elif pairs.get("ifd", "").lower().startswith("from:"):
        ifd_from = pairs.pop("ifd")[5:].strip()
        if not ifd_from:
            raise click.BadParameter("ifd=from: needs the no-load import's capture, e.g. ifd=from:noload.csv",
                                     param_hint="--scale")
    bad = [k for k, v in pairs.items() if v.lower() == "auto" or v.lower().startswith("from:")]
    if bad:
        raise click.BadParameter(f"auto and from: are for ifd only (the field current on the no-load base), "
                                 f"not {bad[0]!r}", param_hint="--scale")
    return _floats(pairs, "--scale"), ifd_auto, ifd_from


def _no_load(unit: Unit) -> NoLoad:
    """The unit's no-load field for an auto base: Vt0 and the model's saturation Sat(x)."""
    from bench_ctl.engine.simulate import generator_saturation  # numba: loaded only for an auto base

    values = unit.values()
    s10, s12 = float(values["S10"]), float(values["S12"])
    return NoLoad(vt0_pu=float(unit.generator["Vt0"]), s10=s10, s12=s12,
                  saturation=generator_saturation(s10, s12), source=f"{unit.name} ({unit.source})")


def _fmt(v: Any, spec: str = ".4g") -> str:
    return "-" if v is None else format(v, spec)


def summary(capture: Capture) -> list[str]:
    """What the import found and used, for the console (from the sidecar's import block)."""
    imp = capture.meta.get("import", {})
    lines = []
    win = imp.get("window")
    if win:
        lines.append(f"window {win['given']}: t = {win['start_s']:.3f} .. {win['end_s']:.3f} s of the export "
                     f"(rows {win['first_row']}..{win['last_row']}, {win['samples']} of {win['export_samples']} "
                     "samples)")
    rebuilt = (imp.get("time") or {}).get("rebuilt")
    if rebuilt:
        lines.append(f"time rebuilt as k / {rebuilt['rate_hz']:g} Hz: within {rebuilt['max_deviation_s']:.4g} s of "
                     f"the {rebuilt['checked_against']} (resolution {rebuilt['resolution_s']:g} s, "
                     f"tolerance {rebuilt['tolerance_s']:.3g} s)")
    found = imp.get("edges_found")
    if found:
        edges = ", ".join(f"{e['edge']} {e['instant_s']:.4f} s +- {e['uncertainty_s']:.4f} s"
                          for e in found["edges"])
        lines.append(f"edges found in {found['channel']} (column {found['column']!r}): {edges}; "
                     f"every fit searches each within +- {found['tolerance_s']:.4f} s")
        if found.get("note"):
            lines.append(f"  {found['note']}")
        chk = found["amplitude_check"]
        if chk.get("ratio") is not None:
            lines.append(f"  amplitude: vt moves {chk['change_pu']:+.4f} pu over the edge, "
                         f"{chk['ratio']:.3f} x the stated {chk['stated_pu']:+g} pu")
            if chk.get("note"):
                lines.append(f"  {'note' if (chk.get('reference') or {}).get('ok') else 'NOTE'}: {chk['note']}")
        else:
            lines.append(f"  amplitude: {chk.get('note')}")
        for s in found["searched"]:
            if not s["found"]:
                lines.append(f"  not in {s['channel']} (column {s['column']!r}): {s['why_not']}")
    for key, what in (("efd_base", "efd"), ("ifd_base", "ifd")):
        b = imp.get(key)
        if not b:
            continue
        if b["mode"] == "auto":
            pre = b["pre_step"]
            lines.append(
                f"{what} base auto: pre-step {what} {pre['mean_source_units']:.5g} (column {b['column']!r}, "
                f"t = {pre['t0_s']:.3f} .. {pre['t1_s']:.3f} s, quarter means within "
                f"{100 * pre['quarter_spread_rel']:.2f} %) = Vt0 + Sat(Vt0) = {b['no_load_pu']:.5g} pu at "
                f"Vt0 {b['vt0_pu']:.5g} ({b['vt0_from']}), S10 {_fmt(b['S10'])}, S12 {_fmt(b['S12'])}: "
                f"factor {b['factor']:.5g}")
            if what == "efd" and abs(b["vt0_pu"] - b["unit_vt0_pu"]) > 5e-4:
                lines.append(f"  the unit's Vt0 is {b['unit_vt0_pu']:g} pu: fit with --set Vt0={b['vt0_pu']:.4f} "
                             "so that the model starts where the record does")
        elif b["mode"] != "scale" or b["factor"] != 1.0:
            tail = ""
            if b.get("pre_step_pu") is not None and b.get("on_line"):
                tail = (f"; pre-step efd {b['pre_step_pu']:.4g} pu on the model's base (the loaded unit's field, "
                        "above its no-load value)")
            elif b.get("pre_step_pu") is not None:
                tail = (f"; pre-step efd {b['pre_step_pu']:.4g} pu on the model's base (its no-load efd at "
                        f"Vt0 {b['vt0_pu']:.4g}: {b['no_load_pu']:.4g} pu)")
            src = b.get("from")
            if src:
                tail = f" (the {src['mode']} base of the no-load import {src['path']}){tail}"
            lines.append(f"{what} base {b['given']}: factor {b['factor']:.5g}{tail}")
    on = imp.get("on_line")
    if on:
        lines.append(f"on line ({on['why']}): every fit starts the machine from the record's operating point")
    steady = imp.get("pre_step_steady")
    if steady:
        lines += warning_lines(steady)
    lines += held.warning_lines(imp.get("held_samples") or {})
    return lines


@click.command("import")
@click.argument("src", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False),
              help="Capture CSV to write (its .json sidecar goes beside it); never overwritten.")
@click.option("--map", "maps", multiple=True, metavar="NAME=COLUMN",
              help="Capture column (efd, usetp, vt) or named channel (ifd, p, q, vr: the regulator "
                   "output, vs: the stabiliser's (PSS) output in pu, fitted on line) = source column or "
                   "COMTRADE channel.")
@click.option("--time-column", help="Source column holding time in seconds.")
@click.option("--date-column", help="Source column holding the date (see --date-format).")
@click.option("--clock-column", help="Source column holding HH:MM:SS.ffff clock time.")
@click.option("--date-format", default="%Y-%m-%d", show_default=True)
@click.option("--delimiter", default=",", show_default=True,
              help="Field separator of the source CSV; 'tab' for a tab.")
@click.option("--decimal-comma", is_flag=True, help="The source uses a decimal comma.")
@click.option("--header-line", type=int, default=1, show_default=True,
              help="1-based line of the header (lines before it are skipped).")
@click.option("--efd-scale", type=float, default=None,
              help="Multiply efd by this (rated-field base -> model base); default 1.")
@click.option("--efd-base", "efd_base", default=None, metavar="auto|<X>V|<X>rf|from:NOLOAD.csv",
              help="efd's base: auto (no load only: the pre-step efd = Vt0 + Sat(Vt0) with the unit's saturation), "
                   "<X>V (the channel records volts, X V = 1 pu), <X>rf (rated-field units, X of them = 1 pu) or "
                   "from:NOLOAD.csv (the factor the unit's no-load import found: for an on-line record).")
@click.option("--scale", "scales", multiple=True, metavar="NAME=FACTOR",
              help="Factor for usetp, vt, ifd, p, q, vr or vs; ifd=auto puts the field current on the no-load base "
                   "(no load only), ifd=from:NOLOAD.csv takes the no-load import's.")
@click.option("--resample", "resample_hz", type=float, default=None, metavar="HZ",
              help="Resample onto HZ by linear interpolation (otherwise jitter is refused).")
@click.option("--rate", "rate_hz", type=float, default=None, metavar="HZ",
              help="The recorder's rate: time rebuilt as k / HZ where the samples are evenly spaced, checked "
                   "against the file's own time (needed for a clock column a spreadsheet shortened to MM:SS.f).")
@click.option("--window", "window_text", default=None, metavar="START:END",
              help="Take the test out of a long export: seconds from its first sample (120:150, 120:) or clock "
                   "times (12:53:58.5:12:54:30).")
@click.option("--held", "held_rows", type=click.Choice(held.HELD_TREATMENTS), default="keep", show_default=True,
              help="A channel the recorder refreshes slower than it writes rows (its rows repeat the one before, also "
                   "at an edge): keep its rows as written (with a warning), or interpolate each repeated row between "
                   "the fresh rows around it.")
@click.option("--test", "test_text", default=None, metavar="KIND:key=value,...",
              help="e.g. pulse:start=1.0,amplitude=0.05,width=1.0 (synthesises usetp when it is not "
                   "mapped); step:amplitude=0.1 without a start: the edges are found in the record.")
@click.option("--keep", "keep", multiple=True, metavar="COLUMN",
              help="Keep this other source column in the capture.")
@unit_options
def import_export(src: str, out: str, maps: tuple[str, ...], time_column: str | None,
                  date_column: str | None, clock_column: str | None, date_format: str,
                  delimiter: str, decimal_comma: bool, header_line: int, efd_scale: float | None,
                  efd_base: str | None, scales: tuple[str, ...], resample_hz: float | None,
                  rate_hz: float | None, window_text: str | None, held_rows: str,
                  test_text: str | None, keep: tuple[str, ...], unit_path: str | None, overrides: tuple[str, ...],
                  effects: tuple[str, ...], model: str | None, from_dyr: str | None, dyr_bus: int | None,
                  dyr_id: str | None, dyr_ignore: tuple[str, ...] = ()) -> int:
    """Import a recorder export SRC (CSV or COMTRADE .cfg) as a capture."""
    test = parse_test(test_text) if test_text else None
    factors, ifd_auto, ifd_from = _scales(scales)
    try:
        window = parse_window(window_text) if window_text is not None else None
    except SpecError as exc:
        raise click.BadParameter(str(exc), param_hint="--window") from None
    if efd_base is not None and efd_scale is not None:
        raise click.UsageError("give --efd-base or --efd-scale, not both")
    try:
        base = parse_efd_base(efd_base) if efd_base is not None else None
    except SpecError as exc:
        raise click.BadParameter(str(exc), param_hint="--efd-base") from None
    no_load = None
    # the unit is read for what needs it: an auto base, and what an explicit one becomes
    if ifd_auto or base is not None or efd_scale is not None or unit_path or overrides or effects \
            or model or from_dyr or dyr_ignore:
        no_load = _no_load(resolve_unit(unit_path, overrides, model=model, from_dyr=from_dyr,
                                        dyr_bus=dyr_bus, dyr_id=dyr_id, effects=effects,
                                        dyr_ignore=dyr_ignore))
    try:
        spec = ImportSpec(
            columns=_pairs(maps, "--map"), time_column=time_column, date_column=date_column,
            clock_column=clock_column, date_format=date_format,
            delimiter="\t" if delimiter.lower() == "tab" else delimiter,
            decimal="," if decimal_comma else ".", header_line=header_line,
            efd_base_scale=1.0 if efd_scale is None else efd_scale, efd_base=base, scale=factors,
            ifd_auto=ifd_auto, no_load=no_load, resample_hz=resample_hz, test=test, keep_columns=keep,
            window=window, rate_hz=rate_hz, ifd_from=ifd_from, held=held_rows)
    except SpecError as exc:
        raise click.UsageError(str(exc)) from None
    if not str(out).lower().endswith(".csv"):
        raise SpecError(f"-o {out}: a capture file name must end in .csv")
    outputs.guard_outputs({"-o": out, "-o (its sidecar)": Path(out).with_suffix(".json")},
                          [src, unit_path, from_dyr, base.path if base is not None and base.mode == "from"
                           else None, ifd_from],
                          replace_hint="captures are never overwritten: choose another name")
    try:
        with outputs.writing(out):
            capture = run_import(src, spec, out)
    except FileExistsError as exc:   # (a name taken meanwhile: the guard refused the ones there before)
        raise outputs.OutputRefused(str(exc)) from None
    for line in summary(capture):
        click.echo(line)
    click.echo(f"wrote {capture.source} ({capture.n} samples at {capture.rate_hz:g} Hz)")
    return ExitCode.OK
