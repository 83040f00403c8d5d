"""`bench-ctl identify`: fit the unit's AVR parameters to captures (MVMO or a peer method).

Example:
  bench-ctl identify cap1.csv cap2.csv --unit unit.toml --set TA4.max=30 \\
      --optimizer mvmo --evals 1000 --seed 0 --json result.json --plot fit.png
  bench-ctl identify cap.csv --compare          # mvmo, de, local and open-loop side by side

Prints a summary (parameters with bounds, std and whether the capture determines them; MSE;
constraints; equivalent parameter sets; the comparison when several optimizers ran).
Exit codes: 0 fitted, every constraint satisfied and every value inside its bounds; 1 a
constraint is violated, a value lies outside its bounds (`local` ignores them) or the fit
failed; 2 bad input (capture, unit file, --set, option), with the file / key named (raised as
`BadInput`, mapped by `bench_ctl.cli.main`).
"""
from __future__ import annotations

import logging
import shlex
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import click

from bench_ctl import outputs
from bench_ctl.capture import read_capture
from bench_ctl.capture.plausible import check_plausible
from bench_ctl.exitcodes import BadInput, ExitCode
from bench_ctl.identification.constraints import ConstraintError
from bench_ctl.identification.construction import ProblemError, make_problem
from bench_ctl.identification.identify import Identification, result_for_file, run_identification
from bench_ctl.identification.options import IDENTIFY
from bench_ctl.identification.peers import OPTIMIZERS
from bench_ctl.identification.result_file import (  # noqa: F401 (the summary's input)
    IdentificationResult,
    ModelEntry,
    written,
)
from bench_ctl.identification.selection import NoStructureFitted, rank_structures
from bench_ctl.model.unit_record import UnitEntry

from .auto import auto_units, is_auto, selection_summary
from .options import fmt_value as _fmt
from .options import model_args, model_options, resolve_unit

log = logging.getLogger(__name__)

#: the smallest --evals: MVMO evaluates its whole swarm in the first generation
MIN_EVALS = int(IDENTIFY["particles"])
#: differential evolution's population: this many candidates per identified parameter (peers._run_de)
DE_POPSIZE = 5


def unit_line(unit: UnitEntry, model: ModelEntry | None, on_line: list[bool]) -> str:
    """The header's unit: its name (a --from-dyr unit's is the record's: file, bus, ID, generator
    and exciter models), the structure that ran, and whether the captures are on line or at no
    load (issue 49 item 7)."""
    st = (model.name if model else None) or unit.model or "REFERENCE"
    where = ("on line (the captures hold P and Q)" if all(on_line) else "at no load" if not any(on_line)
             else f"{sum(on_line)} of {len(on_line)} captures on line")
    return f"unit: {unit.name}; structure {st}; {where}"


def summary(ident: Identification) -> str:
    """The human-readable summary table of a result."""
    r = ident.result
    idn = r.identifiability
    lines = [unit_line(r.unit, r.model, [c.on_line for c in ident.problem.captures]),
             f"optimizer: {r.optimizer.name} (seed {r.optimizer.seed})   evaluations: {r.evaluations}   "
             f"wall: {r.wall_s:.2f} s (compile {r.compile_s:.2f} s)", ""]
    head = f"{'param':<7}{'value':>12}{'min':>10}{'max':>10}{'std':>11}{'rel std':>9}  determined"
    lines += [head, "-" * len(head)]
    if r.model_name != "REFERENCE":
        lines.insert(1, f"model: {r.model_name} ({r.model.title if r.model else ''})")
    # [grid] values fitted on line (the unit's grid, its bounds in grid_identify) after the model's
    fitted_grid = {n: ((r.unit.grid or {})[n], b.min, b.max) for n, b in (r.unit.grid_identify or {}).items()}
    rows = [(n, v, *r.bounds[n]) for n, v in r.params.items()] + [(n, *vb) for n, vb in fitted_grid.items()]
    for n, v, lo, hi in rows:
        rel = idn.rel_std.get(n) if idn else None
        det = idn.determined.get(n) if idn else None
        why = "; ".join((idn.reasons or {}).get(n, [])) if idn else ""
        lines.append(f"{n:<7}{_fmt(v, '.6g'):>12}{_fmt(lo, '.4g'):>10}{_fmt(hi, '.4g'):>10}"
                     f"{_fmt(idn.std.get(n) if idn else None, '.3g'):>11}"
                     f"{(_fmt(100 * rel, '.1f') + ' %') if rel is not None else '-':>9}  "
                     f"{'yes' if det else 'NO'}{('  (' + why + ')') if why else ''}")
    lines.append("")
    for c in r.captures:
        lines.append(f"capture {c.path or '<memory>'}: n {c.n}, {c.rate_hz:g} Hz, "
                     f"mse {_fmt(c.mse, '.4g')}, objective {_fmt(c.objective, '.4g')}")
    lines.append(f"mse {_fmt(r.mse, '.4g')}   objective {_fmt(r.objective, '.4g')}")
    lines.append("constraints: " + ", ".join(
        f"{c.expr} {'ok' if c.satisfied else 'VIOLATED'}" for c in r.constraints) if r.constraints
        else "constraints: none")
    for e in (idn.equivalent_sets if idn else ()):
        # the values the exchange moved (the result's names: the structure's)
        vals = ", ".join(f"{k}={_fmt(v, '.4g')}" for k, v in e.params.items()
                         if k in r.params and v != r.params[k])
        lines.append(f"equivalent set? {e.note}: {vals}; mse {_fmt(e.mse, '.4g')}: {e.verdict}")
    for note in (idn.notes if idn else ()):
        lines.append(f"note: {note}")
    if r.comparison is not None:
        lines += ["", f"{'optimizer':<11}{'mse':>12}{'objective':>12}{'evals':>7}{'wall s':>8}  violated"]
        for c in r.comparison:
            lines.append(f"{c.optimizer:<11}{_fmt(c.mse, '.5g'):>12}{_fmt(c.objective, '.5g'):>12}"
                         f"{c.evaluations:>7}{c.wall_s:>8.2f}  {', '.join(c.constraints_violated) or '-'}")
    if r.failed:
        lines.append(f"FIT FAILED: {r.message or ''}")
    return "\n".join(lines)


def write_json(path: str | Path, data: dict[str, Any], *, force: bool = False) -> None:
    """Write `data` as JSON through the output guard (atomic; an existing file only with force)."""
    outputs.write_json(path, data, force=force)


def min_evals(optimizer: str, n_params: int) -> int:
    """The smallest budget `optimizer` can run on `n_params` parameters."""
    if optimizer == "de":
        return DE_POPSIZE * n_params
    return MIN_EVALS if optimizer == "mvmo" else 1


def plot_fit(ident: Identification, path: str | Path, out: outputs.Outputs | None = None) -> None:
    """Measured vs simulated efd (and usetp) per capture, PNG via matplotlib's Agg backend,
    written through `out` (default: the guard of `bench_ctl.outputs`, nothing replaced)."""
    import io

    from matplotlib.figure import Figure

    prob, x = ident.problem, ident.best.x
    sims = prob.simulate(x)
    mses = prob.mse(x)
    n = len(prob.captures)
    fig = Figure(figsize=(9, 3.2 * n))
    axes = fig.subplots(n, 1, squeeze=False)
    for ax, cap, sim, m in zip(axes[:, 0], prob.captures, sims, mses):
        t = cap.time - cap.time[0]
        ax.plot(t, cap.efd, color="0.6", lw=0.8, label="efd measured")
        ax.plot(t, sim["efd"], color="C0", lw=1.2, label=f"efd simulated ({ident.best.method})")
        ax.set_ylabel("efd (pu)")
        ax.set_xlabel("time (s)")
        ax.set_title(f"{Path(cap.source).name if cap.source else 'capture'}: mse {m:.3g}")
        ax2 = ax.twinx()
        ax2.plot(t, cap.usetp, color="C3", lw=0.8, label="usetp")
        ax2.set_ylabel("usetp (pu)", color="C3")
        h1, l1 = ax.get_legend_handles_labels()
        h2, l2 = ax2.get_legend_handles_labels()
        ax.legend(h1 + h2, l1 + l2, loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    (out or outputs.Outputs()).write_bytes(path, buf.getvalue())


@click.command("identify")
@click.argument("captures", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--unit", "unit_path", type=click.Path(dir_okay=False), default=None,
              help="Unit file (TOML); default: the built-in reference unit.")
@model_options
@click.option("--set", "overrides", multiple=True, metavar="NAME=VALUE",
              help="Override a unit value, bound (KAVR.min=20), weight or effect parameter.")
@click.option("--optimizer", "optimizers", multiple=True, type=click.Choice(OPTIMIZERS),
              help="Optimizer (repeat to compare several; the first gives the result). Default mvmo.")
@click.option("--compare", is_flag=True, help="Also run every other optimizer and fill 'comparison'.")
@click.option("--evals", type=click.IntRange(min=MIN_EVALS), default=1000, show_default=True,
              help=f"Evaluation budget of each optimizer: at least {MIN_EVALS} (MVMO's swarm: one "
                   "generation); de needs one population, 5 x the number of identified parameters.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None,
              help="Write the result JSON (bench-ctl/result/1) here.")
@click.option("--force", is_flag=True, help="Replace an existing --json / --plot output (never an input).")
@click.option("--plot", "plot_out", type=click.Path(dir_okay=False), default=None,
              help="Write a PNG of measured vs simulated efd here.")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
def identify(captures: tuple[str, ...], unit_path: str | None, model: str | None, from_dyr: str | None,
             dyr_bus: int | None, dyr_id: str | None, overrides: tuple[str, ...],
             optimizers: tuple[str, ...], compare: bool, evals: int, seed: int,
             json_out: str | None, plot_out: str | None, no_progress: bool, force: bool = False,
             dyr_ignore: tuple[str, ...] = ()) -> int:
    """Identify the AVR parameters from CAPTURE files (CSV + sidecar) by simulation in the loop."""
    model_kw = dict(model=model, from_dyr=from_dyr, dyr_bus=dyr_bus, dyr_id=dyr_id, dyr_ignore=dyr_ignore)
    if is_auto(model):
        return _identify_auto(captures, unit_path, overrides, model_kw, optimizers, compare, evals, seed,
                              json_out, plot_out, force)
    unit = resolve_unit(unit_path, overrides, **model_kw)
    caps = [read_capture(p) for p in captures]
    for c in caps:
        check_plausible(c)
    try:
        problem = make_problem(caps, unit)
    except (ProblemError, ConstraintError) as exc:   # said in the kernel's names: in the structure's
        raise written(exc, unit.structure) from None
    out = outputs.guard_outputs({"--json": json_out, "--plot": plot_out},
                                [*captures, unit_path, from_dyr], force=force)
    chosen = list(dict.fromkeys(optimizers or ("mvmo",)))
    others = chosen[1:] + ([n for n in OPTIMIZERS if n not in chosen] if compare else [])
    short = [f"{n} needs at least {min_evals(n, problem.d)}" for n in chosen + others
             if evals < min_evals(n, problem.d)]
    if short:
        raise BadInput(f"--evals {evals}: {'; '.join(short)} evaluations ({problem.d} parameters)")

    bars: list[Any] = []

    def factory(name: str):
        for b in bars:  # the previous optimizer's bar is done
            b.close()
        if no_progress:
            return None
        from tqdm import tqdm
        # disable=None: no bar when stderr is not a terminal (logs, tests)
        bar = tqdm(total=evals, desc=f"{name:<9}", unit="ev", file=sys.stderr, disable=None,
                   dynamic_ncols=True)
        bars.append(bar)

        def cb(nfev: int, best: float) -> None:
            bar.set_postfix_str(f"best {best:.4g}", refresh=False)
            bar.update(min(nfev, evals) - bar.n)
        return cb

    command_line = _command_line(captures, unit_path, overrides, model_kw, chosen, compare, evals, seed,
                                 json_out, plot_out)
    try:
        # a planning record's values are the unit's own: they join the initial swarm (as structure
        # selection's typical values and the diagnosis' base fit do)
        ident = run_identification(caps, unit, optimizer=chosen[0], compare=others, max_evals=evals,
                                   seed=seed, command_line=command_line, problem=problem,
                                   x0=problem.x_start() if from_dyr else None, progress_factory=factory)
    finally:
        for b in bars:
            b.close()
    click.echo(summary(ident))
    return _write_and_judge(ident, out, json_out, plot_out)


def _write_and_judge(ident: Identification, out: outputs.Outputs, json_out: str | None,
                     plot_out: str | None) -> int:
    """Write --json / --plot, then the exit code: 0 fitted within its constraints and bounds, 1
    not (said on stderr); an output that could not be written is an `OutputRefused` (exit 2)."""
    if json_out:
        with outputs.writing(json_out):
            out.write_json(json_out, result_for_file(ident.result, json_out).to_json())
        click.echo(f"result written to {json_out}")
    if plot_out:
        with outputs.writing(plot_out):
            plot_fit(ident, plot_out, out)
        click.echo(f"plot written to {plot_out}")
    if not ident.ok:
        bad = ident.result.constraints_violated
        why = [f"constraint(s) violated: {', '.join(bad)}"] if bad else []
        if ident.outside_bounds:
            why.append(f"outside its bounds: {', '.join(ident.outside_bounds)}")
        click.echo("criteria failed: " + ("fit failed" if not ident.best.success else "; ".join(why)),
                   err=True)
        return ExitCode.FAILED
    return ExitCode.OK


def _command_line(captures: tuple[str, ...], unit_path: str | None, overrides: tuple[str, ...], model_kw: dict,
                  chosen: list[str], compare: bool, evals: int, seed: int, json_out: str | None,
                  plot_out: str | None) -> str:
    """The command as run, rebuilt from the parsed options (canonical order, shell-quoted)."""
    args = ["bench-ctl", "identify", *captures]
    if unit_path:
        args += ["--unit", unit_path]
    args += model_args(model_kw or {})
    for o in overrides:
        args += ["--set", o]
    for name in chosen:
        args += ["--optimizer", name]
    if compare:
        args.append("--compare")
    args += ["--evals", str(evals), "--seed", str(seed)]
    if json_out:
        args += ["--json", json_out]
    if plot_out:
        args += ["--plot", plot_out]
    return " ".join(shlex.quote(a) for a in args)


def _identify_auto(captures: tuple[str, ...], unit_path: str | None, overrides: tuple[str, ...], model_kw: dict,
                   optimizers: tuple[str, ...], compare: bool, evals: int, seed: int, json_out: str | None,
                   plot_out: str | None, force: bool) -> int:
    """`identify --model auto` (module docstring)."""

    if compare or any(o != "mvmo" for o in optimizers):
        raise BadInput("--model auto identifies every structure with mvmo; --optimizer / --compare "
                       "are for one structure")
    units, notes = auto_units(unit_path, overrides, model_kw)
    caps = [read_capture(p) for p in captures]
    for c in caps:
        check_plausible(c)
    out = outputs.guard_outputs({"--json": json_out, "--plot": plot_out},
                                [*captures, unit_path, model_kw.get("from_dyr")], force=force)
    command_line = _command_line(captures, unit_path, overrides, model_kw, ["mvmo"], False, evals, seed,
                                 json_out, plot_out)

    def said(name: str, c: Any) -> None:
        click.echo(f"{name}: {'failed: ' + c.error if c.error else f'mse {c.mse:.4g}'} ({c.wall_s:.1f} s)",
                   err=True)
    try:
        sel, chosen = rank_structures(caps, units, notes, seed=seed, command_line=command_line, max_evals=evals,
                                      progress=said)
    except NoStructureFitted as exc:   # the work was done, and no fit came of it
        click.echo(f"error: {exc}", err=True)
        return ExitCode.FAILED
    ident = sel.best.ident
    ident = replace(ident, result=replace(ident.result, selection=chosen))
    click.echo(summary(ident))
    click.echo(selection_summary(chosen))
    return _write_and_judge(ident, out, json_out, plot_out)
