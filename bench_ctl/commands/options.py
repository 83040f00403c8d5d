"""Click options shared by the commands that take a unit: --unit, --model, --from-dyr, --set,
--effect."""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import click

from bench_ctl.exitcodes import BadInput
from bench_ctl.model.effects import effect
from bench_ctl.model.structures import STRUCTURES
from bench_ctl.units.overrides import apply_overrides, with_model
from bench_ctl.units.unit import Unit, UnitError, load_unit


def model_options(f):
    """--model NAME and --from-dyr FILE [--dyr-bus N --dyr-id ID --dyr-ignore MODEL]: the structure
    and the record a unit starts from (see `resolve_unit`)."""
    f = click.option("--dyr-ignore", "dyr_ignore", multiple=True, metavar="MODEL",
                     help="Leave the unit's MODEL record of --from-dyr out (repeatable): a stabiliser, limiter or "
                          "compensator bench-ctl does not model stops the command unless left out by name "
                          "(e.g. --dyr-ignore PSS2B when the test was made with the stabiliser off).")(f)
    f = click.option("--dyr-id", default=None, metavar="ID",
                     help="Machine ID of the records to take from --from-dyr (default: the only one).")(f)
    f = click.option("--dyr-bus", type=int, default=None, metavar="N",
                     help="Bus of the records to take from --from-dyr (default: the only one).")(f)
    f = click.option("--from-dyr", "from_dyr", type=click.Path(dir_okay=False), default=None, metavar="FILE",
                     help="Start from a PSS/E .dyr record: its exciter model and values, and the "
                          "GENROU/GENSAL record's T'd0, T''d0, S(1.0), S(1.2).")(f)
    f = click.option("--model", "model", default=None, metavar="NAME",
                     help=f"AVR / exciter structure ({', '.join(STRUCTURES)}; default: the unit "
                          "file's, else REFERENCE; `identify` also takes auto: every structure fitted, "
                          "checked and ranked). See `bench-ctl models`.")(f)
    return f


def model_args(kw: dict) -> list[str]:
    """The --model / --from-dyr options as given, for a result's command line."""
    out: list[str] = []
    for key, opt in (("model", "--model"), ("from_dyr", "--from-dyr"), ("dyr_bus", "--dyr-bus"),
                     ("dyr_id", "--dyr-id")):
        if kw.get(key) is not None:
            out += [opt, str(kw[key])]
    for m in kw.get("dyr_ignore") or ():
        out += ["--dyr-ignore", str(m)]
    return out


def resolve_unit(unit_path: str | None, overrides: Sequence[str], *, model: str | None = None,
                 from_dyr: str | None = None, dyr_bus: int | None = None, dyr_id: str | None = None,
                 effects: Sequence[str] = (), dyr_ignore: Sequence[str] = ()) -> Unit:
    """The unit file (or the reference unit), in the structure `model`, started from a .dyr
    record, then the --set overrides (standard names of the structure) and --effect's. What the
    record holds and is left out (or read under another model's name) is said on stderr."""
    unit = load_unit(unit_path)
    if model:
        try:
            unit = with_model(unit, model)
        except BadInput as exc:
            raise UnitError(f"--model {model}: {exc}") from None
    if dyr_ignore and not from_dyr:
        raise UnitError("--dyr-ignore leaves out a record of --from-dyr: give --from-dyr")
    if from_dyr:
        from bench_ctl.units.dyr_unit import unit_from_dyr
        notes: list[str] = []
        unit = unit_from_dyr(unit, from_dyr, bus=dyr_bus, ident=dyr_id, ignore=dyr_ignore, notes=notes)
        for note in notes:
            click.echo(f"note: --from-dyr: {note}", err=True)
        if model and unit.model != with_model(unit, model).model:
            raise UnitError(f"--model {model} differs from the record's model {unit.model} in {from_dyr}")
    unit = apply_overrides(unit, overrides)
    parsed: dict[str, dict[str, float]] = {}
    for name, params in (parse_effect(e) for e in effects):  # repeated: the values add up
        parsed.setdefault(name, {}).update(params)
    try:
        return unit.with_effects(parsed) if parsed else unit
    except BadInput as exc:
        raise UnitError(str(exc)) from None


def unit_options(f):
    f = model_options(f)
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


def build_unit(unit_path: str | None, overrides: Sequence[str], effects: Sequence[str] = (),
               **model: Any) -> Unit:
    return resolve_unit(unit_path, overrides, effects=effects, **model)


def fmt_value(v: Any, spec: str = ".4g") -> str:
    """A number for a summary table: '-' for missing, 'inf' as such (a fit that failed), 'n/a' for
    a figure that could not be computed (never 'nan': issue 49 item 7)."""
    if v is None:
        return "-"
    if isinstance(v, float) and math.isnan(v):
        return "n/a"
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    return format(v, spec)
