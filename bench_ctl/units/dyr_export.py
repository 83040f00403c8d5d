"""An identified result as PSS/E dynamic data records (issue 13): `export --dyr`.

The exciter record of the result's structure (`dyr_values_of`, `dyr_fields`), what the record
cannot carry back (`not_carried`) and the stabiliser's record (`pss_record`). A limit bench-ctl
leaves open (+-inf, null in a result) is written as +-NO_LIMIT with the sign of its side, as
`dyr_unit` reads it back (see there for what a record's values mean).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from bench_ctl.model.dialect import dialect_of
from bench_ctl.model.params import MACHINE_DEFAULTS, PARAMS
from bench_ctl.model.stabilisers import IEEEST
from bench_ctl.model.structures import Structure, structure

from .dyr import FIELDS, DyrError, DyrRecord
from .dyr_pss2 import pss2_record

#: the record written for "no limit" (PSS/E has no infinity; ANDES' own "no limit" defaults)
NO_LIMIT = 999.0


def pss_record(grid: Mapping[str, Any], bus: int, ident: str) -> DyrRecord | None:
    """The record of the stabiliser in a unit's [grid] (None without one: PSS_KS, or PSS2_KS1 for
    a PSS2A / PSS2B, 0 or absent): an IEEEST with speed input, no filter, T5 = T6 = TW, no cut-off,
    or the unit's PSS2A / PSS2B (`dyr_pss2.pss2_record`)."""
    g = {**MACHINE_DEFAULTS, **{k: float(x) for k, x in grid.items() if k.startswith("PSS")}}
    if g["PSS_MODEL"] != IEEEST:
        return pss2_record(grid, bus, ident)
    if g["PSS_KS"] == 0.0:
        return None
    values = dict.fromkeys(("A1", "A2", "A3", "A4", "A5", "A6"), 0.0)
    values.update(T1=g["PSS_T1"], T2=g["PSS_T2"], T3=g["PSS_T3"], T4=g["PSS_T4"], T5=g["PSS_TW"], T6=g["PSS_TW"],
                  KS=g["PSS_KS"], LSMAX=g["PSS_LSMAX"], LSMIN=-g["PSS_LSMAX"], VCU=NO_LIMIT, VCL=-NO_LIMIT)
    return DyrRecord(bus, "IEEEST", str(ident), values, {"MODE": 1, "BUSR": 0})


def _open_side(st: Structure, name: str) -> float:
    """The infinite value that means "no limit" for `name` (its kernel parameter's neutral; a
    record-only field by its name: ...MIN below, else above)."""
    p = st.param(name)
    info = PARAMS.get(p.kernel) if p.kernel else None
    if info is not None and info.neutral is not None and math.isinf(info.neutral):
        return info.neutral
    return -math.inf if name.upper().endswith("MIN") else math.inf


def _kernel_value(name: str, v: Any) -> float:
    """A result's kernel value; null is the parameter's neutral (an open limit: +-inf)."""
    if v is None:
        neutral = PARAMS[name].neutral if name in PARAMS else None
        if neutral is None:
            raise DyrError(f"{name} = null: only an open limit may be null")
        return float(neutral)
    return float(v)


def dyr_values_of(result: Mapping[str, Any]) -> tuple[Structure, dict[str, float]]:
    """(structure, its record's fields -> values) from an identification result; an open limit
    (null, +-inf) becomes +-NO_LIMIT on its own side."""
    model = result.get("model") or {}
    st = structure(model.get("name"))
    if st.name == "REFERENCE":      # the reference blocks under ESST1A's names, limits open
        st = structure("ESST1A")
        kern = {**(result.get("fixed") or {}), **(result.get("params") or {})}   # REFERENCE: kernel names
        base = {k: _kernel_value(k, v) for k, v in kern.items()}
        params = st.std_values(base, {"VRMAX": math.inf, "VRMIN": -math.inf, "KC": 0.0})
    else:
        params = {k: (_open_side(st, k) if v is None else float(v))
                  for k, v in (model.get("params") or {}).items()}
    for k, v in params.items():
        if math.isinf(v):
            params[k] = math.copysign(NO_LIMIT, v)
    return st, params


def dyr_fields(st: Structure) -> tuple[str, ...]:
    return FIELDS[st.dyr_model]  # type: ignore[index]


#: kernel parameters that are not the exciter's (the generator, the record's timing, the
#: recorder): a difference there is not the exciter record's to carry
_NOT_EXCITER = ("Td0p", "Td0pp", "Vt0", "KPP", "KDA", "SATEQ", "S10", "S12", "GAIN", "SKEW", "EDGE1", "EDGE2",
                "EDGE3", "EDGE4")


def not_carried(sections: Mapping[str, Mapping[str, Any]], st: Structure, std: Mapping[str, float]) -> list[str]:
    """What the result's model (its values in kernel names, `IdentificationResult.kernel_view`) has
    that the record `std` (of structure `st`, as `dyr_values_of` gives it) does not give back when
    read with `--from-dyr`: 'NAME = value (read back: value; what it is)'."""
    from bench_ctl.model.params import neutral_values

    have = dict(neutral_values())
    d = dialect_of(st)
    for section in ("fixed", "params"):
        for k, v in sections[section].items():
            if k in PARAMS:
                have[k] = _kernel_value(k, v)
    read = {k: (_open_side(st, k) if abs(v) == NO_LIMIT and st.param(k).kernel else v)
            for k, v in std.items()}
    back = {**neutral_values(), **st.kernel_values({k: v for k, v in read.items() if st.param(k).kernel})}
    open_limits = all(math.isinf(d.get(k, math.inf)) for d in (have, back) for k in ("VRMAX", "VRMIN"))
    skip = set(_NOT_EXCITER) | ({"VRVT", "LIMOUT", "KC"} if open_limits and not have.get("KPV") else set())
    out = []
    for k, a in have.items():
        if k in skip or k not in back:
            continue
        b = back[k]
        if a == b or (math.isfinite(a) and math.isfinite(b) and math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-15)):
            continue
        name = d.name(k)
        what = d.describe(name) or (PARAMS[k].unit, PARAMS[k].info, None)
        unit = "" if what[0] in ("", "1") else f" {what[0]}"
        out.append(f"{name} = {a:g}{unit} (read back: {b:g}; {what[1]})")
    return out
