"""`bench-ctl warm-up`: compile the engine ahead of its first use (a newcomer's machine, CI, an
offline laptop before a site visit, a Dask worker): the variants a unit's records run (no load, and
on the grid when the unit has the machine's data) and its plant's real-time loop, or `--all` of
them (or those a file names, `--variants`: what CI's tests run), side by side in child processes,
into numba's disk cache."""
from __future__ import annotations

import time
from pathlib import Path

import click

from bench_ctl.exitcodes import ExitCode
from bench_ctl.units.overrides import apply_overrides
from bench_ctl.units.unit import Unit, UnitError

from .options import build_unit, unit_options

#: the on-line plants `--all` compiles the real-time loop of, as `--set` values on the unit: the
#: unit alone (`online_step`'s simulated bench), and with an IEEEST (`pss_step`'s)
ONLINE_BENCH_SETS: tuple[tuple[str, ...], ...] = ((), ("PSS_MODEL=IEEEST", "PSS_KS=5"))


def unit_keys(unit: Unit) -> list:
    """The engine variants `unit`'s records run: at no load, and on the grid when the unit has the
    machine's data."""
    from bench_ctl.engine import Key, classify, derive, grid_key
    from bench_ctl.engine.machines import grid
    from bench_ctl.engine.simulate import param_matrix

    P = param_matrix(unit.values())
    keys = [Key("noload", classify(derive(P)))]
    try:
        M = grid.machine_matrix(grid.unit_machine(unit))
    except ValueError:   # no machine data: the unit runs at no load only
        return keys
    D = grid.derive_grid(P, M)
    return keys + [grid_key(D)]


def read_variants(path: str | Path) -> list:
    """The engine variants a file names (`Key.name`, e.g. grid_full_pss2), one a line; `#` starts a
    comment. ValueError names an unknown one."""
    from bench_ctl.engine.warm import key_named

    names = [line.split("#", 1)[0].strip() for line in Path(path).read_text(encoding="utf-8").splitlines()]
    return [key_named(name) for name in names if name]


@click.command("warm-up")
@click.option("--all", "everything", is_flag=True,
              help="Every variant of the engine (each machine under each class of blocks, with and without a "
                   "stabiliser: what `identify --model auto` may run), and the simulated bench's real-time loops, no "
                   "load and on line.")
@click.option("--variants", "variants_file", type=click.Path(exists=True, dir_okay=False), default=None,
              metavar="FILE",
              help="The variants FILE names (one a line, `#` comments; names as `--all` compiles them, e.g. "
                   "grid_full_pss2) instead of all of them, with the same real-time loops as --all: what "
                   "`make test` compiles ahead (tests/engine_variants.txt).")
@unit_options
def warm_up(everything: bool, variants_file: str | None, unit_path: str | None, overrides: tuple[str, ...],
            effects: tuple[str, ...], **model: str | None) -> int:
    """Compile the engine's variants (and the plant's real-time loop) a unit needs, or --all of them,
    or those a file names (--variants); nothing when numba's cache holds them already."""
    from bench_ctl.engine import warm
    from bench_ctl.plants import warm_up as plant_warm_up
    from bench_ctl.plants.realtime import timer_jitter

    try:
        unit = build_unit(unit_path, overrides, effects, **model)
    except UnitError as exc:
        click.secho(f"refused: {exc}", fg="red", err=True)
        return ExitCode.ABORTED
    if everything and variants_file:
        click.secho("refused: --all or --variants, not both", fg="red", err=True)
        return ExitCode.ABORTED
    if variants_file:
        try:
            keys = tuple(read_variants(variants_file))
        except ValueError as exc:   # an unknown name
            click.secho(f"refused: {variants_file}: {exc}", fg="red", err=True)
            return ExitCode.ABORTED
    else:
        keys = tuple(warm.ALL) if everything else tuple(unit_keys(unit))
    t0 = time.perf_counter()
    todo = warm.missing(keys)
    click.echo(f"{len(keys)} engine variant(s): {len(keys) - len(todo)} in the cache, {len(todo)} to compile")
    warm.warm(todo, report=lambda key, s: click.echo(f"  compiled the {key.words()} in {s:.0f} s"))
    plant_warm_up(unit)
    if everything or variants_file:   # the simulated bench's plants on line: alone, with pss_step's IEEEST
        for extra in ONLINE_BENCH_SETS:
            plant_warm_up(apply_overrides(unit, list(extra)) if extra else unit, online=True)
        timer_jitter(0.002, rt_priority=None)   # and the host's timer probe (sim_latency.py; a test runs it)
    elif len(keys) > 1 and keys[1].machine == "grid":
        plant_warm_up(unit, online=True)
    click.echo(f"the engine is ready ({time.perf_counter() - t0:.0f} s)")
    return ExitCode.OK
