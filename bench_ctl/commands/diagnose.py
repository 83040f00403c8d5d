"""`bench-ctl diagnose`: where the model misses a capture, which unmodelled effect, how far it shrinks.

Example:
  bench-ctl diagnose pulse1s.csv --holdout pulse05s.csv --json diag.json --report diag.html
  bench-ctl diagnose pulse1s.csv --unit unit.toml --set Td0p=6.8 --result result.json

Every model is fitted on the whole capture and checked where it was not fitted: the leading
edge, the plateau and the trailing edge each left out in turn, the recorded Vt when the fit did
not use it, and --holdout when given (see `bench_ctl.diagnosis.diagnose`). --result warm-starts
the base fit from an identification result's parameters.

Exit codes: 0 the base model fits the capture to its noise floor (verdict none); 1 an unmodelled
effect was found (the verdict names it); 2 bad input (capture, unit file, --set, option) or the
output could not be written.
"""
from __future__ import annotations

import logging
import math
import os
import shlex
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import click
import numpy as np

from bench_ctl import outputs
from bench_ctl.capture import Capture, read_capture
from bench_ctl.capture.plausible import check_plausible
from bench_ctl.diagnosis.diagnosis_file import Diagnosis
from bench_ctl.engine.simulate import simulate
from bench_ctl.exitcodes import BadInput, ExitCode
from bench_ctl.identification.constraints import parse_constraints
from bench_ctl.identification.localize import where_lines
from bench_ctl.identification.result_file import (
    RESULT_SCHEMA,
    CaptureEntry,
    ConstraintEntry,
    IdentificationResult,
    OptimizerEntry,
    read_result,
    written,
)
from bench_ctl.identification.selection import rank_structures
from bench_ctl.identification.timing import fitted_edge_plan
from bench_ctl.model.params import KERNEL_PARAMS, RECORD_PARAMS
from bench_ctl.records import plain
from bench_ctl.units.unit import Unit, UnitError

from .auto import auto_units, is_auto, selection_summary
from .options import fmt_value as _fmt
from .options import model_args, model_options, resolve_unit

log = logging.getLogger(__name__)


def summary(d: Diagnosis) -> str:
    """Human-readable summary of a diagnosis."""
    b = d.base
    lines = [f"capture: {d.capture.path}   holdout: {d.holdout.path if d.holdout else 'none'} "
             f"(check: {d.validation.kind})",
             f"noise floor {_fmt(d.noise_floor)} pu^2   base model mse {_fmt(b.mse)}, on the check "
             f"record {_fmt(b.mse_holdout)}   at the noise floor: {b.at_noise_floor}", "",
             "where the base model misses (share of the residual energy):"]
    lines.append("  " + "  ".join(f"{s.name} {s.share:.2f}" for s in d.localization.segments))
    lines.append("  " + "  ".join(f"{s.name} ({s.f0_hz:g}-{s.f1_hz:g} Hz) {s.share:.2f}"
                                  for s in d.localization.bands))
    lines += ["", "features:"]
    for f in d.features:
        lines.append(f"  [{'x' if f.detected else ' '}] {f.name}: {f.evidence}")
    lines += ["", f"{'effect':<16}{'mse':>11}{'mse check':>11}{'gap closed':>12}{'score':>11}  params"]
    if b.at_noise_floor:
        lines.append("  (gap closed: n/a, the base model is already at the noise floor)")
    for e in d.effects:
        params = ", ".join(f"{k}={_fmt(v, '.4g')}" for k, v in e.params.items())
        lines.append(f"{e.name:<16}{_fmt(e.mse):>11}{_fmt(e.mse_holdout):>11}"
                     f"{_fmt(e.gap_closed, '.3f'):>12}{_fmt(e.score, '.1f'):>11}  {params}"
                     + ("" if e.significant else "  (not significant)"))
    for a in d.ambiguous:
        lines.append(f"ambiguous: {' / '.join(a.effects)}: {a.separating_test}")
    not_tried = d.vocabulary.not_tried if d.vocabulary else {}
    if not_tried:
        lines.append(f"not tried{' on line' if d.vocabulary and d.vocabulary.on_line else ''}: "
                     + "; ".join(f"{k} ({v})" for k, v in not_tried.items()))
    if d.explained_by:
        lines += ["", "explained by (each step re-fitted jointly; error over the noise floor):",
                  f"  base model {_ratio(b.mse, d.noise_floor)}x"]
        for s in d.explained_by:
            params = ", ".join(f"{k}={_fmt(v, '.4g')}" for k, v in s.params.items())
            lines.append(f"  + {s.name:<15} {_fmt(s.mse_over_floor, '.2f')}x   {params}"
                         + (f"   (dropped {', '.join(s.dropped)})" if s.dropped else ""))
        last = d.explained_by[-1].avr_params
        if last:
            lines.append("  the model after the last step: "
                         + ", ".join(f"{k}={_fmt(v, '.4g')}" for k, v in last.items()))
    lines.append(f"left: {d.left.note}")
    if (d.left.mse_over_floor or 0.0) > 1.0:
        lines += where_lines(d.left.localization, d.noise_floor)
    lines += ["", f"verdict: {d.verdict}   ({d.wall_s:.1f} s)"]
    return "\n".join(lines)


def _ratio(a: float | None, b: float | None) -> str:
    return f"{a / b:.2f}" if a is not None and b else "n/a"


def for_file(d: Diagnosis, path: str | Path) -> Diagnosis:
    """The diagnosis as written to `path`: the capture and holdout paths relative to its folder
    (as a result's, issue 24 item 14)."""
    moved = {}
    for key in ("capture", "holdout"):
        ref = getattr(d, key)
        if ref is not None and ref.path:
            moved[key] = replace(ref, path=outputs.path_from(path, ref.path))
    return replace(d, **moved)


def base_result(d: Diagnosis, capture: Capture, unit: Unit) -> IdentificationResult:
    """The diagnosis' base fit as an identification result (schema bench-ctl/result/1), so that
    the report can re-simulate and show it next to the diagnosis."""
    from bench_ctl.identification.identify import model_entry

    base_params = {k: float(v) for k, v in d.kernel_base_params().items() if v is not None}
    # [grid] values fitted on line (XE) go to the unit's [grid], as an identification's do
    grid = {k: base_params.pop(k) for k in list(base_params) if k in unit.grid_identify}
    entry = unit.entry()
    entry = replace(entry, grid={**(entry.grid or {}), **grid}) if grid else entry
    values = unit.values()
    values.update(base_params)
    edges = tuple(replace(e, capture=None) for e in d.edges if e.capture == "capture")
    spec, offsets = fitted_edge_plan(edges, capture.n)
    efd, _vt, _fail = simulate({**values, **offsets}, capture.usetp, capture.dt, edges=spec)
    t1 = d.validation.fit.t1
    k1 = min(capture.n, int(round(t1 / capture.dt)) + 1)  # t1 included (the whole capture today)
    r = capture.efd[:k1] - efd[:k1]
    objective = float(capture.dt * (np.sum(r * r) - 0.5 * (r[0] ** 2 + r[-1] ** 2)))
    mse = float(np.mean(r * r))  # a result's mse is the plain mean (the diagnosis' the trapezoidal one)
    names = list(unit.identified_names)
    x = np.array([base_params[n] for n in names])
    cons = tuple(ConstraintEntry(c.expr, c.satisfied(x), float(c.rhs - c.coef @ x))
                 for c in parse_constraints(unit.constraints, names))
    result = IdentificationResult(
        schema=RESULT_SCHEMA, software_version=d.software_version,
        command_line=d.command_line, created_utc=d.created_utc, unit=entry,
        captures=(CaptureEntry(path=os.path.abspath(capture.source) if capture.source else d.capture.path,
                               sha256=d.capture.sha256, n=capture.n, rate_hz=capture.rate_hz,
                               meta=plain(dict(capture.meta)), mse=mse, objective=objective, weight=1.0,
                               edges=edges),),
        params=dict(base_params),
        fixed={k: (v if math.isfinite(v) else None) for k, v in values.items()
               if k in KERNEL_PARAMS and k not in base_params and k not in RECORD_PARAMS},
        bounds={n: [b.min, b.max] for n, b in unit.identify.items()},
        constraints=cons, objective=objective, mse=mse,
        evaluations=d.base.evaluations, wall_s=d.wall_s, compile_s=0.0,
        optimizer=OptimizerEntry(name="mvmo + least squares (diagnosis base fit)", settings={}, seed=None),
        history=[], fit_window=None if k1 >= capture.n else [0.0, t1],
        model=model_entry(unit, values, names, {}),
    )
    return replace(written(result, unit.structure), selection=d.selection)


def _command_line(capture: str, holdout: str | None, unit_path: str | None, overrides: Sequence[str], model_kw: dict,
                  result: str | None, seed: int, json_out: str | None, report_out: str | None) -> str:
    args = ["bench-ctl", "diagnose", capture]
    if holdout:
        args += ["--holdout", holdout]
    if unit_path:
        args += ["--unit", unit_path]
    args += model_args(model_kw or {})
    for o in overrides:
        args += ["--set", o]
    if result:
        args += ["--result", result]
    if seed:
        args += ["--seed", str(seed)]
    if json_out:
        args += ["--json", json_out]
    if report_out:
        args += ["--report", report_out]
    return shlex.join(args)


@click.command("diagnose")
@click.argument("capture_path", metavar="CAPTURE", type=click.Path(dir_okay=False))
@click.option("--holdout", "holdout_path", metavar="CAPTURE2", type=click.Path(dir_okay=False), default=None,
              help="A second capture of the same unit (e.g. another pulse width) to check the fits on.")
@click.option("--unit", "unit_path", type=click.Path(dir_okay=False), default=None,
              help="Unit file (TOML); default: the built-in reference unit.")
@model_options
@click.option("--set", "overrides", multiple=True, metavar="NAME=VALUE",
              help="Override one unit value: Td0p=6.0, KAVR.min=20 (repeatable).")
@click.option("--result", "result_path", metavar="RESULT.json", type=click.Path(dir_okay=False), default=None,
              help="Warm-start the base fit from this identification result's params.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None,
              help="Write the diagnosis JSON (bench-ctl/diagnosis/1) here.")
@click.option("--force", is_flag=True, help="Replace an existing --json / --report output (never an input).")
@click.option("--report", "report_out", type=click.Path(dir_okay=False), default=None,
              help="Write the HTML report of the base fit with the diagnosis section here.")
def diagnose(capture_path: str, holdout_path: str | None, unit_path: str | None, model: str | None,
             from_dyr: str | None, dyr_bus: int | None, dyr_id: str | None, overrides: tuple[str, ...],
             result_path: str | None, seed: int, json_out: str | None, report_out: str | None,
             force: bool = False, dyr_ignore: tuple[str, ...] = ()) -> int:
    """Diagnose the gap between the unit's model and CAPTURE (a pulse or step test)."""
    from bench_ctl.diagnosis import diagnose as run

    model_kw = dict(model=model, from_dyr=from_dyr, dyr_bus=dyr_bus, dyr_id=dyr_id, dyr_ignore=dyr_ignore)
    auto = is_auto(model)
    if auto and result_path:
        raise BadInput("--model auto starts each structure from its own fit; --result is for one structure")

    if auto:
        units, notes = auto_units(unit_path, overrides, model_kw)
        unit = next(iter(units.values()))
    else:
        unit = resolve_unit(unit_path, overrides, **model_kw)
    capture = read_capture(capture_path)
    holdout = read_capture(holdout_path) if holdout_path else None
    for c in (capture, holdout):
        if c is not None:
            check_plausible(c)
    base_params = None
    if result_path:
        previous = read_result(result_path)
        for k, v in previous.params.items():   # refused under the name the file gives it
            if not math.isfinite(v):
                raise UnitError(f"{result_path}: params.{k} = {v!r} is not a finite number")
        params = previous.kernel_view()["params"]      # the result's names -> the kernel's
        base_params = {k: float(v) for k, v in params.items() if k in unit.identify}
        if not base_params:
            raise UnitError(f"{result_path}: no 'params' of the unit's identified parameters")
    out = outputs.Outputs([capture_path, holdout_path, unit_path, result_path, from_dyr], force=force)
    out.claim("--json", json_out)
    if report_out:
        from bench_ctl.report import claim_report
        claim_report(out, report_out)   # the HTML and every figure it may draw beside it
    command_line = _command_line(capture_path, holdout_path, unit_path, overrides, model_kw, result_path, seed,
                                 json_out, report_out)
    selection = None
    if auto:   # the structures ranked first; the first one is diagnosed from its fit
        sel, selection = rank_structures([capture], units, notes, seed=seed, command_line=command_line)
        click.echo(selection_summary(selection))
        click.echo(f"\ndiagnosing {sel.best.model}, the first of the ranking\n")
        unit = units[sel.best.model]
        fitted = sel.best.ident.problem.params(sel.best.ident.best.x)
        base_params = {k: v for k, v in fitted.items() if k in unit.identify}
    d = run(capture, unit, holdout=holdout, seed=seed, base_params=base_params, command_line=command_line)
    if selection is not None:
        d = replace(d, selection=selection)
    click.echo(summary(d))
    if json_out:
        with outputs.writing(json_out):
            out.write_json(json_out, for_file(d, json_out).to_json())
        click.echo(f"diagnosis written to {json_out}")
    if report_out:
        from bench_ctl.report import ReportError, render_report
        try:
            with outputs.writing(report_out):
                written = render_report(base_result(d, capture, unit), report_out,
                                        diagnosis=Diagnosis.from_json(d.to_json(), "the diagnosis"),
                                        report_command=command_line, outputs=out)
        except ReportError as exc:
            raise ReportError(f"report not written: {exc}") from None
        click.echo(f"report written to {written[0]}")
    return ExitCode.OK if d.verdict == "none" else ExitCode.FAILED  # FAILED: an effect found
