"""The power system stabilisers a unit on the grid can carry (docs/model.md, "The stabilisers";
docs/decisions/0024): IEEEST on the speed, and PSS2A and PSS2B on the speed and the electrical
power. A unit's [grid] picks one with `PSS_MODEL` (its name or code; IEEEST when absent) and
gives its values under the catalogue's names (`params.MACHINE_CATALOGUE`: PSS_* for the IEEEST,
PSS2_* for PSS2A and PSS2B, PSS/E's names after the prefix); `bench-ctl models PSS2B` shows one.

The engine runs IEEEST in `bench_ctl/engine/stabilisers/ieeest.py` and PSS2A and PSS2B in
`bench_ctl/engine/stabilisers/pss2.py` (PSS2A is PSS2B without its third lead-lag and its input
limits). This module is the user's side: each stabiliser's block diagram in words, its
parameters, what the sources say differently, and the checks a set of values must pass.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from .params import MACHINE_CATALOGUE, MACHINE_DEFAULTS


@dataclass(frozen=True)
class Stabiliser:
    """One stabiliser: its name (the PSS/E record's), its PSS_MODEL code, its parameters under the
    catalogue's names (PSS_*, PSS2_*), its block diagram and remarks in words."""
    name: str
    code: int
    title: str
    params: tuple[str, ...]
    diagram: tuple[str, ...]
    remarks: tuple[str, ...] = ()
    #: the time constants of its lead-lags in series with nothing between them: two leads (or two
    #: lags) exchanged give the same stabiliser (the identifiability analysis examines each pair)
    leads: tuple[str, ...] = ()
    lags: tuple[str, ...] = ()

    def exchanges(self) -> list[tuple[str, str]]:
        """Every pair of leads, then every pair of lags, whose exchange gives the same stabiliser."""
        return [(a, b) for group in (self.leads, self.lags) for i, a in enumerate(group) for b in group[i + 1:]]

    def describe(self) -> str:
        """The block diagram, every parameter (unit, default, range, meaning) and the remarks."""
        info = {p.name: p for p in MACHINE_CATALOGUE}
        lines = [f"{self.name}: {self.title}", "", "Block diagram:"]
        lines += [f"  {d}" for d in self.diagram]
        lines += ["", f"Parameters ([grid] of the unit file, or --set NAME=VALUE; PSS_MODEL = \"{self.name}\" "
                      "selects this stabiliser):",
                  f"  {'name':<12} {'unit':<5} {'default':>8}  {'range':<16} meaning"]
        for name in self.params:
            p = info[name]
            default = MACHINE_DEFAULTS.get(name, math.nan)
            span = f"[{p.lo:g}, {p.hi:g}]"
            lines.append(f"  {name:<12} {p.unit:<5} {default:>8g}  {span:<16} {p.info}")
        if self.remarks:
            lines += ["", "Remarks:"] + [f"  - {r}" for r in self.remarks]
        return "\n".join(lines)


_IEEEST = Stabiliser(
    "IEEEST", 1, "IEEE ST stabiliser on the rotor speed, without its notch filters (PSS/E IEEEST, MODE 1)",
    ("PSS_KS", "PSS_T1", "PSS_T2", "PSS_T3", "PSS_T4", "PSS_TW", "PSS_LSMAX"),
    ("vs = clamp(KS (1 + s T1)/(1 + s T2) (1 + s T3)/(1 + s T4) s TW/(1 + s TW) (omega - 1), -LSMAX, LSMAX)",
     "added to the voltage reference; KS = 0: no stabiliser"),
    leads=("PSS_T1", "PSS_T3"), lags=("PSS_T2", "PSS_T4"))

_PSS2_DIAGRAM = (
    "u1 = omega - 1 (PSS/E ICS1 = 1, rotor speed deviation)        u2 = Pe (ICS2 = 3, electrical power)",
    "V1 = 1/(1 + s T6) s TW2/(1 + s TW2) s TW1/(1 + s TW1) u1",
    "V2 = KS2/(1 + s T7) s TW4/(1 + s TW4) s TW3/(1 + s TW3) u2",
    "V3 = [(1 + s T8)/(1 + s T9)^M]^N (V1 + KS3 V2) - V2              (the ramp-tracking filter)",
    "vs = clamp(KS1 (1 + s T1)/(1 + s T2) (1 + s T3)/(1 + s T4) V3, VSTMIN, VSTMAX)",
    "added to the voltage reference; KS1 = 0: no stabiliser. A washout with TW = 0, a lag T6 = 0, a",
    "lead-lag with both time constants 0 are bypassed; T7 = 0 leaves the gain KS2; M = 0 or N = 0: no filter")
_PSS2_PARAMS = ("PSS2_KS1", "PSS2_TW1", "PSS2_TW2", "PSS2_T6", "PSS2_TW3", "PSS2_TW4", "PSS2_T7", "PSS2_KS2",
                "PSS2_KS3", "PSS2_T8", "PSS2_T9", "PSS2_M", "PSS2_N", "PSS2_T1", "PSS2_T2", "PSS2_T3", "PSS2_T4")
_PSS2_REMARKS = (
    "Sources: IEEE Std 421.5-2016 (PSS2B), PSS/E's PSS2A and PSS2B records, OpenIPSL's PSS2A.mo and PSS2B.mo, "
    "PowerSimulationsDynamics.jl's PSS2A/PSS2B (checked there against PSS/E); docs/decisions/0024.",
    "Input 2 is the machine's electrical power as the engine's seam gives it, the air-gap power P + RA |I|^2 "
    "(P with RA = 0); PowerSimulationsDynamics multiplies its electrical torque by the speed (a 1e-3 relative "
    "difference at most).",
    "The ramp-tracking filter is [(1 + s T8)/(1 + s T9)^M]^N, M N lags in all (IEEE 421.5, PSS/E, "
    "PowerSimulationsDynamics). OpenIPSL's RampTrackingFilter chains N lead-lags (1 + s T8)/(1 + s T9) and M "
    "lags: (1 + s T8)^N/(1 + s T9)^(M+N), one lag more than the others for M = 5, N = 1.",
    "M and N are integers of the unit (read per candidate, not fixed per compiled variant): the filter has "
    "the eight states the largest M N = 8 needs; those beyond M N stay at 0.",
    "A washout with TW = 0 is bypassed (OpenIPSL's DerivativeLag; PowerSimulationsDynamics bypasses TW2 and TW4 "
    "only, PowerSystems.jl warns on TW1 or TW3 = 0). T7 = 0 leaves the gain KS2 (OpenIPSL's SimpleLag); "
    "PowerSimulationsDynamics then drops KS2 and the V2 subtracted after the filter.",
    "The states start at the operating point's steady state: every washout holds its input there, so the "
    "output starts at 0 (with both washouts of an input bypassed, that input's deviation from the operating "
    "point enters).")
_PSS2B_PARAMS = ("PSS2_T10", "PSS2_T11", "PSS2_VS1MIN", "PSS2_VS1MAX", "PSS2_VS2MIN", "PSS2_VS2MAX")

_PSS2A = Stabiliser(
    "PSS2A", 2, "IEEE dual-input stabiliser PSS2A (IEEE 421.5-2005; PSS/E PSS2A): speed and electrical power",
    _PSS2_PARAMS + ("PSS2_VSTMAX", "PSS2_VSTMIN"), _PSS2_DIAGRAM, _PSS2_REMARKS,
    leads=("PSS2_T1", "PSS2_T3"), lags=("PSS2_T2", "PSS2_T4"))
_PSS2B = Stabiliser(
    "PSS2B", 3, "IEEE dual-input stabiliser PSS2B (IEEE 421.5-2016; PSS/E PSS2B): PSS2A with a third lead-lag "
                "and input limits",
    _PSS2_PARAMS + _PSS2B_PARAMS + ("PSS2_VSTMAX", "PSS2_VSTMIN"),
    ("u1 = clamp(omega - 1, VS1MIN, VS1MAX)    u2 = clamp(Pe, VS2MIN, VS2MAX)    (the input limits, before the "
     "washouts)",) + _PSS2_DIAGRAM[1:4]
    + ("vs = clamp(KS1 (1 + s T1)/(1 + s T2) (1 + s T3)/(1 + s T4) (1 + s T10)/(1 + s T11) V3, VSTMIN, VSTMAX)",)
    + _PSS2_DIAGRAM[5:],
    _PSS2_REMARKS + ("The input limits act on the signals themselves: VS2MIN, VS2MAX bound the electrical power, "
                     "not its deviation (OpenIPSL, PowerSimulationsDynamics).",),
    leads=("PSS2_T1", "PSS2_T3", "PSS2_T10"), lags=("PSS2_T2", "PSS2_T4", "PSS2_T11"))

#: the stabilisers by name
STABILISERS: dict[str, Stabiliser] = {s.name: s for s in (_IEEEST, _PSS2A, _PSS2B)}
#: PSS_MODEL codes
IEEEST, PSS2A, PSS2B = 1, 2, 3
_BY_CODE = {s.code: s for s in STABILISERS.values()}


def stabiliser(name_or_code: str | float) -> Stabiliser:
    """The stabiliser of a name (any case) or a PSS_MODEL code (a number, or its text: --set
    PSS_MODEL=3); ValueError naming the known ones."""
    found = STABILISERS.get(name_or_code.strip().upper()) if isinstance(name_or_code, str) else None
    if found is None:
        try:
            code = float(name_or_code)
        except ValueError:
            code = math.nan
        found = _BY_CODE.get(int(code)) if code.is_integer() else None
    if found is None:
        raise ValueError(f"unknown stabiliser {name_or_code!r}; known: "
                         + ", ".join(f"{s.name} ({s.code})" for s in STABILISERS.values()))
    return found


def model_code(value: object) -> float:
    """PSS_MODEL's value from a unit file or --set: a stabiliser's name or its code."""
    if isinstance(value, bool) or not isinstance(value, (str, int, float)):
        raise ValueError(f"PSS_MODEL: expected a stabiliser's name or code, got {value!r}")
    return float(stabiliser(value).code)


def check_stabiliser(values: Mapping[str, float], where: str = "") -> None:
    """What the stabiliser of a set of [grid] values (MACHINE_DEFAULTS where absent) needs beyond
    each value's range: PSS_MODEL a known code; for PSS2A / PSS2B, M and N integers with M N <= 8
    and T9 > 0 when they filter, each lead-lag's lag > 0 unless both its time constants are 0,
    each lower limit below its upper one. A ValueError names the value."""
    v = {**MACHINE_DEFAULTS, **values}
    st = stabiliser(v["PSS_MODEL"])
    if st.code == IEEEST:
        return
    m, n = v["PSS2_M"], v["PSS2_N"]
    if not (float(m).is_integer() and float(n).is_integer()):
        raise ValueError(f"{where}PSS2_M = {m:g}, PSS2_N = {n:g}: the ramp-tracking filter's M and N are integers")
    if m * n > 8:
        raise ValueError(f"{where}PSS2_M = {m:g}, PSS2_N = {n:g}: M N = {m * n:g} lags, at most 8 (PSS/E's limit)")
    if m * n > 0 and not v["PSS2_T9"] > 0:
        raise ValueError(f"{where}PSS2_T9 = {v['PSS2_T9']:g}: the ramp-tracking filter (M N = {m * n:g}) needs "
                         "T9 > 0 (M = 0 or N = 0 switches it off)")
    pairs = (("PSS2_T1", "PSS2_T2"), ("PSS2_T3", "PSS2_T4")) + ((("PSS2_T10", "PSS2_T11"),) if st.code == PSS2B
                                                              else ())
    for lead, lag in pairs:
        if v[lag] == 0 and v[lead] != 0:
            raise ValueError(f"{where}{lag} = 0 with {lead} = {v[lead]:g}: a lead-lag needs its lag > 0 "
                             f"({lead} = {lag} = 0 bypasses it)")
    limits = (("PSS2_VSTMIN", "PSS2_VSTMAX"),) + ((("PSS2_VS1MIN", "PSS2_VS1MAX"), ("PSS2_VS2MIN", "PSS2_VS2MAX"))
                                                 if st.code == PSS2B else ())
    for lo, hi in limits:
        if not v[lo] < v[hi]:
            raise ValueError(f"{where}{lo} = {v[lo]:g} must be below {hi} = {v[hi]:g}")
