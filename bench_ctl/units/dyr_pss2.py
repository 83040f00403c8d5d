"""A unit's PSS2A / PSS2B from and to its PSS/E record (issue 49 item 1; docs/decisions/0024).

The record's fields (`dyr.FIELDS`, PSS/E's order) become the unit's [grid] values under the
catalogue's names: `PSS_MODEL` the record's model, `PSS2_` and PSS/E's name for every CON, and
`PSS2_M`, `PSS2_N` from the ICONs M and N. bench-ctl's PSS2A / PSS2B reads the machine's own rotor
speed deviation as input 1 and its own electrical power as input 2: a record with another input
code (ICS1 other than 1, ICS2 other than 3) or a remote bus (IB1, IB2 not 0) is refused naming
the file, line and field. PSS/E has no infinity: an input limit of PSS2B at +-999 or beyond (what
ANDES and the export write for no limit) is read as open, and an open one is written as +-999.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from bench_ctl.model.params import MACHINE_DEFAULTS
from bench_ctl.model.stabilisers import IEEEST, stabiliser

from .dyr import FIELDS, DyrRecord
from .unit import UnitError, grid_values

#: the record models read and written here
PSS2_MODELS = ("PSS2A", "PSS2B")
#: PSS/E's input codes bench-ctl's PSS2A / PSS2B runs: input 1 the rotor speed deviation, input 2
#: the electrical power
INPUT_CODES = {"ICS1": (1, "the rotor speed deviation"), "ICS2": (3, "the electrical power")}
#: PSS/E has no infinity: a limit at this magnitude or beyond is no limit
NO_LIMIT = 999.0
#: the time constants of the records (a negative one is refused)
_TIMES = {"TW1", "TW2", "T6", "TW3", "TW4", "T7", "T8", "T9", "T1", "T2", "T3", "T4", "T10", "T11"}
_INPUT_LIMITS = ("VS1MAX", "VS1MIN", "VS2MAX", "VS2MIN")


def pss2_from_record(rec: DyrRecord) -> dict[str, float]:
    """The unit's [grid] PSS_MODEL and PSS2_* from a PSS2A or PSS2B record; what bench-ctl's
    stabiliser cannot run (another input, a remote bus, a negative time constant, a value outside
    its range) is refused naming the record, the field and the value (UnitError)."""
    where = f"{rec.source}: {rec.model}" if rec.source else rec.model
    for k, x in rec.values.items():
        if not math.isfinite(x):
            raise UnitError(f"{where} {k} = {x}: not a number a record can hold")
        if k in _TIMES and x < 0.0:
            raise UnitError(f"{where} {k} = {x:g} s: a time constant cannot be negative")
    for k, (code, what) in INPUT_CODES.items():
        if rec.icons[k] != code:
            raise UnitError(f"{where} {k} = {rec.icons[k]}: bench-ctl's {rec.model} reads {what} as input "
                            f"{k[-1]} ({k} = {code}) only; PSS/E's other input codes are not simulated")
    for k in ("IB1", "IB2"):
        if rec.icons[k] != 0:
            raise UnitError(f"{where} {k} = {rec.icons[k]}: a remote bus's signal is not simulated (bench-ctl's "
                            "stabiliser reads its own machine: IB 0)")
    out: dict[str, Any] = {"PSS_MODEL": rec.model, "PSS2_M": float(rec.icons["M"]),
                           "PSS2_N": float(rec.icons["N"])}
    for k, x in rec.values.items():
        if k in _INPUT_LIMITS and abs(x) >= NO_LIMIT:
            x = math.copysign(math.inf, x)
        out[f"PSS2_{k}"] = x
    return grid_values(out, where)


def pss2_record(grid: Mapping[str, Any], bus: int, ident: str) -> DyrRecord | None:
    """The PSS2A / PSS2B record of the stabiliser in a unit's [grid] (`PSS_MODEL`; MACHINE_DEFAULTS
    where a value is absent), None when KS1 is 0 (no stabiliser); input 1 the speed, input 2 the
    electrical power, both of the machine itself. ValueError for a unit whose stabiliser is the
    IEEEST (`dyr_export.pss_record` writes that one)."""
    g = {**MACHINE_DEFAULTS, **{k: float(x) for k, x in grid.items() if k.startswith("PSS")}}
    st = stabiliser(g["PSS_MODEL"])
    if st.code == IEEEST:
        raise ValueError("the unit's stabiliser is an IEEEST: not a PSS2A / PSS2B record")
    if g["PSS2_KS1"] == 0.0:
        return None
    values = {}
    for k in FIELDS[st.name]:
        x = g[f"PSS2_{k}"]
        values[k] = math.copysign(NO_LIMIT, x) if math.isinf(x) else x
    icons = {"ICS1": 1, "IB1": 0, "ICS2": 3, "IB2": 0, "M": int(g["PSS2_M"]), "N": int(g["PSS2_N"])}
    return DyrRecord(bus, st.name, str(ident), values, icons)
