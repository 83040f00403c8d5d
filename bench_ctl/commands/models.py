"""`bench-ctl models [NAME]`: the AVR / exciter structures of the model library.

Without NAME: one line per structure (name, PSS/E record, what it is). With NAME: its block
diagram in words and every parameter with unit, typical value, default bounds and its meaning,
under the structure's own names (`bench_ctl.model.structures`); `--kernel` adds the kernel
parameter each one drives and the kernel settings the structure implies (for debugging).
"""
from __future__ import annotations

import click

from bench_ctl.exitcodes import ExitCode
from bench_ctl.model.structures import STRUCTURES, structure


@click.command("models")
@click.argument("name", required=False)
@click.option("--kernel", "show_kernel", is_flag=True,
              help="Also show the kernel parameter each one drives and the structure's kernel settings.")
def models(name: str | None, show_kernel: bool = False) -> int:
    """List the AVR / exciter structures, or show one with its block diagram."""
    if name is None:
        for s in STRUCTURES.values():
            ident = ", ".join(s.default_identified())
            click.echo(f"{s.name:<10} {s.dyr_model or '-':<7} {s.title}")
            click.echo(f"{'':<10} {'':<7} identified by default: {ident}")
        click.echo("\nChoose one with `[avr] model = \"NAME\"` in the unit file or --model NAME; "
                   "`bench-ctl models NAME` shows it.")
        return ExitCode.OK
    click.echo(structure(name).describe(kernel=show_kernel))
    return ExitCode.OK
