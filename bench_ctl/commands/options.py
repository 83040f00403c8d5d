"""Click options shared by the commands that take a unit: --unit, --set, --effect."""
from __future__ import annotations

import math
from typing import Any, Sequence

import click

from bench_ctl.model.effects import effect
from bench_ctl.model.unit import Unit, UnitError, apply_overrides, load_unit


def unit_options(f):
    f = click.option("--effect", "effects", multiple=True, metavar="NAME:P=V[,P=V...]",
                     help="Switch an effect on, e.g. ceiling_limit:VRMAX=2.8,VRMIN=-1.0 (repeatable).")(f)
    f = click.option("--set", "overrides", multiple=True, metavar="NAME=VALUE",
                     help="Override one unit value: Td0p=6.0, TR=0.01, KAVR.min=20 (repeatable).")(f)
    f = click.option("--unit", "unit_path", type=click.Path(dir_okay=False), default=None,
                     help="Unit file (TOML); default: the built-in reference unit.")(f)
    return f


def parse_effect(text: str) -> tuple[str, dict[str, float]]:
    """'ceiling_limit:VRMAX=2.8,VRMIN=-1.0' -> ('ceiling_limit', {...})."""
    name, _, rest = text.partition(":")
    eff = effect(name.strip())
    params: dict[str, float] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, raw = item.partition("=")
        if not eq:
            raise UnitError(f"--effect {text!r}: expected PARAM=VALUE, got {item!r}")
        try:
            params[key.strip()] = float(raw)
        except ValueError:
            raise UnitError(f"--effect {text!r}: {raw!r} is not a number") from None
    if not params:
        raise UnitError(f"--effect {text!r}: give the effect's parameters, e.g. "
                        f"{name}:{','.join(p + '=...' for p in eff.params)}")
    return eff.name, params


def build_unit(unit_path: str | None, overrides: Sequence[str], effects: Sequence[str] = ()) -> Unit:
    unit = apply_overrides(load_unit(unit_path), overrides)
    parsed: dict[str, dict[str, float]] = {}
    for name, params in (parse_effect(e) for e in effects):  # repeated: the values add up
        parsed.setdefault(name, {}).update(params)
    try:
        return unit.with_effects(parsed) if parsed else unit
    except ValueError as exc:
        raise UnitError(str(exc)) from None


def fmt_value(v: Any, spec: str = ".4g") -> str:
    """A number for a summary table: '-' for missing, 'inf'/'nan' as such."""
    if v is None:
        return "-"
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    return format(v, spec)
