"""Units from and to PSS/E dynamic data records (issue 13): `--from-dyr` and `export --dyr`.

`unit_from_dyr` starts a unit from an existing record: the exciter record picks the structure and
gives its values (the starting point of identification; bounds widened to hold them), the
generator record (GENROU / GENSAL) gives T'd0, T''d0, the saturation S(1.0), S(1.2) and the
no-load flux shares of the kernel's generator (KPP, KDA, see `generator_from_record`).
`dyr_record_of` turns an identified result back into a record.

Saturation convention: PSS/E's S(1.2) is relative (the field current's excess over the air-gap
line at 1.2 pu, divided by the air-gap current there, Sat(1.2) = 1.2 S(1.2)); the kernel's S12 is
the absolute excess Sat(1.2). The conversion is here, in both directions.
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping

from .dyr import DyrError, DyrRecord, FIELDS, find, read_dyr
from .structures import STRUCTURES, Structure, structure
from .unit import Bound, Unit, UnitError, with_model

GENERATORS = ("GENROU", "GENSAL")


def generator_from_record(rec: DyrRecord) -> dict[str, float]:
    """Kernel generator values from a GENROU / GENSAL record: Td0p, Td0pp; KPP = (X''d - Xl)/(X'd
    - Xl), the share of E'q in psi''d; KDA = (Xd - X'd)(X'd - X''d)/(X'd - Xl)^2, the damper's
    part in the field current at no load; S10 = S(1.0), S12 = 1.2 S(1.2) (absolute)."""
    v = _values(rec)
    xd, xdp, xdpp, xl = v["Xd"], v["X'd"], v["X''d"], v["Xl"]
    where = f"{rec.source}: {rec.model}"
    if not (xd > xdp > xdpp > xl >= 0.0):
        raise UnitError(f"{where}: needs Xd > X'd > X''d > Xl >= 0, got {xd}, {xdp}, {xdpp}, {xl}")
    out = {"Td0p": v["T'do"], "Td0pp": v["T''do"],
           "KPP": (xdpp - xl) / (xdp - xl), "KDA": (xd - xdp) * (xdp - xdpp) / (xdp - xl) ** 2}
    s10, s12 = v.get("S(1.0)", 0.0), v.get("S(1.2)", 0.0)
    if s10 > 0.0 and s12 > 0.0:
        out["S10"], out["S12"] = s10, 1.2 * s12
    return out


def _values(rec: DyrRecord) -> dict[str, float]:
    """A record's values by the names used here (the dyr module's names, normalised)."""
    out = {}
    for k, x in rec.values.items():
        key = k.replace("’", "'").replace("′", "'")
        out[key] = float(x)
        alias = {"Tdo'": "T'do", "Tdo''": "T''do", "Xd'": "X'd", "Xd''": "X''d", "S10": "S(1.0)",
                 "S12": "S(1.2)", "SE1": "SE(E1)", "SE2": "SE(E2)"}.get(key)
        if alias:
            out[alias] = float(x)
    return out


def unit_from_dyr(unit: Unit, path: str | Path, *, bus: int | None = None, ident: str | None = None) -> Unit:
    """`unit` (its generator constants, weights, effects) started from the records in `path`."""
    try:
        records = read_dyr(path)
    except (DyrError, OSError) as exc_:
        raise UnitError(f"--from-dyr {path}: {exc_}") from None
    exciters = {s.dyr_model for s in STRUCTURES.values() if s.name != "REFERENCE"}
    if not any(r.model in exciters for r in records):   # a generator record only: the unit's structure
        try:
            gen = find(records, set(GENERATORS), bus=bus, id=ident)
        except DyrError as exc_:
            raise UnitError(f"--from-dyr {path}: neither an exciter record ({', '.join(sorted(exciters))}) "
                            f"nor a usable generator record: {exc_}") from None
        return _with_generator(replace(unit, source=f"{unit.source} with --from-dyr {path}"), gen)
    try:
        exc = find(records, exciters, bus=bus, id=ident)
    except DyrError as exc_:
        raise UnitError(f"--from-dyr {path}: {exc_}") from None
    st = structure(exc.model)
    new = with_model(unit, st.name)
    std = st.from_dyr(_values(exc))
    identify = dict(new.identify)
    fixed_std = {}
    for name, value in std.items():
        p = st.param(name)
        if p.kernel is not None and p.kernel in identify:
            b = identify[p.kernel]
            if value > 0.0:   # the record's value is the start; bounds widened to hold it
                identify[p.kernel] = Bound(value, min(b.min, value), max(b.max, value))
            # a zero (a bypassed block in the record) cannot start a fit of it: typical kept
        else:
            fixed_std[name] = value
    fixed = dict(new.fixed)
    fixed.update(st.kernel_values({k: v for k, v in fixed_std.items()}))
    for k in identify:
        fixed.pop(k, None)
    new = replace(new, identify=identify, fixed=fixed, model_values={**new.model_values, **std},
                  source=f"{unit.source} with --from-dyr {path}")
    try:
        gen = find(records, set(GENERATORS), bus=exc.bus, id=exc.id)
    except DyrError:
        gen = None
    return _with_generator(new, gen) if gen is not None else new


def _with_generator(unit: Unit, gen: DyrRecord) -> Unit:
    g = generator_from_record(gen)
    generator = dict(unit.generator)
    generator.update({k: g[k] for k in ("Td0p", "Td0pp", "KPP", "KDA")})
    unit = replace(unit, generator=generator)
    if "S10" in g:
        unit = unit.with_effects({"saturation": {"S10": g["S10"], "S12": g["S12"]}})
    return unit


def dyr_values_of(result: Mapping[str, Any]) -> tuple[Structure, dict[str, float]]:
    """(structure, its record's fields -> values) from an identification result."""
    model = result.get("model") or {}
    st = structure(model.get("name"))
    params = {k: (math.inf if v is None else float(v)) for k, v in (model.get("params") or {}).items()}
    if st.name == "REFERENCE":      # the reference blocks under ESST1A's names, limits wide
        esst1a = structure("ESST1A")
        kern = {**(result.get("fixed") or {}), **(result.get("params") or {})}
        base = {k: (math.inf if v is None else float(v)) for k, v in kern.items()}
        vals = esst1a.std_values(base, {"VRMAX": 999.0, "VRMIN": -999.0, "KC": 0.0})
        for k in ("VRMAX", "VRMIN"):
            if not math.isfinite(vals[k]):
                vals[k] = math.copysign(999.0, vals[k])
        return esst1a, vals
    for k, v in params.items():
        if not math.isfinite(v):
            params[k] = math.copysign(999.0, v)
    return st, params


def dyr_fields(st: Structure) -> tuple[str, ...]:
    return FIELDS[st.dyr_model]  # type: ignore[index]
