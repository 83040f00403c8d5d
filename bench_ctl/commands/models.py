"""`bench-ctl models [NAME]`: the AVR / exciter structures and the stabilisers of the model library.

Without NAME: one line per structure (name, PSS/E record, what it is), then one per stabiliser.
With NAME: its block diagram in words and every parameter with unit, typical value, default
bounds and its meaning, under the structure's own names (`bench_ctl.model.structures`); `--kernel`
adds the kernel parameter each one drives and the kernel settings the structure implies (for
debugging). A stabiliser's NAME (IEEEST, PSS2A, PSS2B) shows its diagram, its [grid] parameters
with unit, default, range and meaning, and where the sources differ (`bench_ctl.model.stabilisers`).
"""
from __future__ import annotations

import click

from bench_ctl.exitcodes import ExitCode
from bench_ctl.model.stabilisers import STABILISERS
from bench_ctl.model.structures import STRUCTURES, structure


@click.command("models")
@click.argument("name", required=False)
@click.option("--kernel", "show_kernel", is_flag=True,
              help="Also show the kernel parameter each one drives and the structure's kernel settings.")
def models(name: str | None, show_kernel: bool = False) -> int:
    """List the AVR / exciter structures and the stabilisers, or show one with its block diagram."""
    if name is not None and name.upper() in STABILISERS:
        click.echo(STABILISERS[name.upper()].describe())
        return ExitCode.OK
    if name is None:
        for s in STRUCTURES.values():
            ident = ", ".join(s.default_identified())
            click.echo(f"{s.name:<10} {s.dyr_model or '-':<7} {s.title}")
            click.echo(f"{'':<10} {'':<7} identified by default: {ident}")
        click.echo("\nChoose one with `[avr] model = \"NAME\"` in the unit file or --model NAME; "
                   "`bench-ctl models NAME` shows it.\n\nStabilisers (on line):")
        for st in STABILISERS.values():
            click.echo(f"{st.name:<10} {st.name:<7} {st.title}")
        click.echo("\nChoose one with `PSS_MODEL = \"NAME\"` under [grid] or --set PSS_MODEL=NAME; "
                   "`bench-ctl models NAME` shows it.")
        return ExitCode.OK
    click.echo(structure(name).describe(kernel=show_kernel))
    return ExitCode.OK
