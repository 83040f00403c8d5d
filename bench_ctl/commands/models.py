"""`bench-ctl models [NAME]`: the AVR / exciter structures of the model library.

Without NAME: one line per structure (name, PSS/E record, what it is). With NAME: its block
diagram in words and every parameter with unit, typical value, default bounds, the kernel block
it drives and its meaning (`bench_ctl.model.structures`).
"""
from __future__ import annotations

import click

from bench_ctl.exitcodes import ExitCode
from bench_ctl.model.structures import STRUCTURES, StructureError, structure


@click.command("models")
@click.argument("name", required=False)
def models(name: str | None) -> int:
    """List the AVR / exciter structures, or show one with its block diagram."""
    if name is None:
        for s in STRUCTURES.values():
            ident = ", ".join(s.default_identified())
            click.echo(f"{s.name:<10} {s.dyr_model or '-':<7} {s.title}")
            click.echo(f"{'':<10} {'':<7} identified by default: {ident}")
        click.echo("\nChoose one with `[avr] model = \"NAME\"` in the unit file or --model NAME; "
                   "`bench-ctl models NAME` shows it.")
        return ExitCode.OK
    try:
        click.echo(structure(name).describe())
    except StructureError as exc:
        click.echo(f"error: {exc}", err=True)
        return ExitCode.ABORTED
    return ExitCode.OK
