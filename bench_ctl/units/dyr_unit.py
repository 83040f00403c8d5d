"""Units from PSS/E dynamic data records (issue 13): `--from-dyr`; `dyr_export` writes them back.

`unit_from_dyr` starts a unit from an existing record: the exciter record picks the structure and
gives its values (the starting point of identification; bounds widened to hold them), the
generator record (GENROU / GENSAL) gives T'd0, T''d0, the saturation S(1.0), S(1.2) and the
no-load flux shares of the kernel's generator (KPP, KDA, see `generator_from_record`).
An identified result goes back into a record in `dyr_export` (`export --dyr`).

What a record's values mean, read and written the same way (issue 24 items 6 and 7):

- no limit: a limit bench-ctl leaves open (+-inf, null in a result) is written as +-999 with the
  sign of its side (PSS/E has no infinity; ANDES' own "no limit" defaults are +-999, e.g. ESST1A
  VAMAX/VAMIN, and +-99, SEXS EMAX/EMIN), and a limit read beyond the kernel's physical range on
  its open side (99, 999, 9999: never reached in a no-load test) is read back as no limit;
- a NaN or infinite value, or a negative time constant, in the exciter or generator record is
  refused naming the record (file:line), the field and the value;
- TC = TB = 0 is PSS/E's bypassed lead-lag: simulated bypassed (the kernel's 1/1) and not
  identified; a zero lag under a non-zero lead (TB = 0, TC > 0) is refused, not guessed;
- a zero lead (TC = 0), a zero transducer lag (TR = 0), no rate feedback (KF = 0), no integral
  (KIR = 0) are those values, never a typical one; a zero regulator lag (TA, SEXS TE) or a zero
  DC exciter time constant with KE != 1 or saturation is refused: the kernel has no bypass for
  them yet (it needs them > 0).

What the unit's records hold and bench-ctl does not model is never replaced in silence (issue 48
item 9, issue 49 item 6; the unit's records are those at the exciter's bus and machine ID):

- an exciter model the library does not have is refused (file:line and why), except ESDC1A and
  IEEET1, read as IEEEX1 (the same equations; IEEET1 without the lead-lag, TB = TC = 0) and said;
- two generator (or exciter, or stabiliser) records for one machine are refused, naming both;
- a GENROU / GENSAL saturation bench-ctl's curve cannot hold is refused: S(1.0) or S(1.2) < 0,
  S(1.2) = 0 with S(1.0) > 0, S(1.0) = 0 with S(1.2) > 0, Sat(1.2) = 1.2 S(1.2) not above S(1.0);
- every other record of the unit is named (`notes`); a stabiliser, limiter, compensator, exciter
  or generator record bench-ctl does not model stops the command unless it is left out by name
  (`ignore`, the CLI's `--dyr-ignore MODEL`: `dyr_kinds`); a unit without a generator record keeps
  its own generator constants, said too. The unit's name becomes the record's (file, bus, ID,
  generator and exciter models) and its `source` lists what was left out.

A stabiliser record (IEEEST, PSS2A or PSS2B, at the exciter's bus and ID) gives the machine on the
grid its PSS (`[grid]` PSS_* or PSS_MODEL and PSS2_*: `pss_from_record`, `dyr_pss2`), and `export
--dyr` writes one when the result's unit has a PSS (`dyr_export.pss_record`). The IEEEST is run on the rotor
speed without its filter: a
record with another input (MODE), a filter (A1..A6 not 0), limits that are not symmetric or a
cut-off that switches it off at 1 pu is refused, naming the field. The washout T5 s/(1 + T6 s)
is KS T5/T6 times the unity washout of TW = T6; VCU, VCL (the cut-off by the terminal voltage
outside a band around 1 pu) are not simulated.

Saturation convention: PSS/E's S(1.2) is relative (the field current's excess over the air-gap
line at 1.2 pu, divided by the air-gap current there, Sat(1.2) = 1.2 S(1.2)); the kernel's S12 is
the absolute excess Sat(1.2). The conversion is here, in both directions.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from bench_ctl.model.params import GENERATOR_OPTIONAL, PARAMS
from bench_ctl.model.structures import STRUCTURES, Structure, structure
from bench_ctl.units import dyr_kinds

from .dyr import DyrError, DyrRecord, find, read_dyr
from .dyr_pss2 import PSS2_MODELS, pss2_from_record
from .overrides import with_model
from .unit import Bound, Unit, UnitError, grid_values

GENERATORS = ("GENROU", "GENSAL")
STABILISERS = ("IEEEST", *PSS2_MODELS)
#: exciter models read as a structure of the library with the same equations: model -> (the
#: structure's record model, values from the record, why)
ALIASES: dict[str, tuple[str, Any, str]] = {
    "ESDC1A": ("IEEEX1", lambda v: dict(v),
               "the same equations (IEEE 421.5 DC1A is the IEEE type 1 DC exciter with its lead-lag) and the same "
               "PSS/E fields"),
    "IEEET1": ("IEEEX1", lambda v: {**{k: x for k, x in v.items() if k != "TF"}, "TB": 0.0, "TC": 0.0,
                                    "TF1": v["TF"]},
               "the same equations with its lead-lag bypassed (TB = TC = 0): the IEEE 1968 type 1 DC exciter has "
               "none"),
}


#: generator record fields that are time constants (s)
_GEN_TIMES = ("T'do", "T''do", "T'qo", "T''qo")


def _where(rec: DyrRecord) -> str:
    return f"{rec.source}: {rec.model}" if rec.source else rec.model


def check_record(rec: DyrRecord, times: set[str]) -> None:
    """Refuse (UnitError naming record, field and value) a non-finite value anywhere in `rec`
    and a negative value of a time-constant field in `times`."""
    for k, x in rec.values.items():
        if not math.isfinite(x):
            raise UnitError(f"{_where(rec)} {k} = {x}: not a number a record can hold (a value is "
                            "never guessed: give the record's value)")
        if k in times and x < 0.0:
            raise UnitError(f"{_where(rec)} {k} = {x:g} s: a time constant cannot be negative")


def generator_from_record(rec: DyrRecord) -> dict[str, float]:
    """Kernel generator values from a GENROU / GENSAL record: Td0p, Td0pp; KPP = (X''d - Xl)/(X'd
    - Xl), the share of E'q in psi''d; KDA = (Xd - X'd)(X'd - X''d)/(X'd - Xl)^2, the damper's
    part in the field current at no load; SATEQ = 1 for a GENSAL (its saturation acts on E'q, a
    GENROU's on psi''); S10 = S(1.0), S12 = 1.2 S(1.2) (absolute)."""
    check_record(rec, set(_GEN_TIMES) & set(rec.values))
    v = _values(rec)
    xd, xdp, xdpp, xl = v["Xd"], v["X'd"], v["X''d"], v["Xl"]
    where = _where(rec)
    for k in ("T'do", "T''do"):
        if v[k] <= 0.0:
            raise UnitError(f"{where} {k} = {v[k]:g} s: the no-load generator needs {k} > 0")
    if not (xd > xdp > xdpp > xl >= 0.0):
        raise UnitError(f"{where}: needs Xd > X'd > X''d > Xl >= 0, got {xd}, {xdp}, {xdpp}, {xl}")
    out = {"Td0p": v["T'do"], "Td0pp": v["T''do"],
           "KPP": (xdpp - xl) / (xdp - xl), "KDA": (xd - xdp) * (xdp - xdpp) / (xdp - xl) ** 2,
           "SATEQ": 1.0 if rec.model == "GENSAL" else 0.0}
    s10, s12 = v.get("S(1.0)", 0.0), v.get("S(1.2)", 0.0)
    _check_saturation(where, s10, s12)
    if s10 > 0.0 and s12 > 0.0:
        out["S10"], out["S12"] = s10, 1.2 * s12
    return out


def _check_saturation(where: str, s10: float, s12: float) -> None:
    """Refuse a saturation bench-ctl's curve (the kernel's quadratic through S(1.0) and
    Sat(1.2) = 1.2 S(1.2), docs/model.md) would not hold as the record gives it."""
    if s10 < 0.0 or s12 < 0.0:
        raise UnitError(f"{where} S(1.0) = {s10:g}, S(1.2) = {s12:g}: a saturation factor cannot be negative")
    if s10 == 0.0 and s12 == 0.0:
        return
    if s12 == 0.0:
        raise UnitError(f"{where} S(1.2) = 0 with S(1.0) = {s10:g}: no curve through them (saturation grows with "
                        "the flux); give S(1.2) > S(1.0) / 1.2, or S(1.0) = S(1.2) = 0 for none")
    if s10 == 0.0:
        raise UnitError(f"{where} S(1.0) = 0 with S(1.2) = {s12:g}: bench-ctl's saturation curve passes through "
                        "S(1.0) > 0 (it would drop S(1.2) and run without saturation); give S(1.0) > 0, or both 0")
    if 1.2 * s12 <= s10:
        raise UnitError(f"{where} S(1.0) = {s10:g}, S(1.2) = {s12:g}: Sat(1.2) = 1.2 S(1.2) = {1.2 * s12:g} is not "
                        f"above Sat(1.0) = {s10:g} (saturation grows with the flux): bench-ctl's curve would drop "
                        "them")


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


def _exciter_std(st: Structure, rec: DyrRecord) -> tuple[dict[str, float], set[str]]:
    """The structure's standard values from the exciter record, checked (see the module
    docstring), limits beyond the kernel's range read as open; and the names of its bypassed
    lead-lags (both time constants 0)."""
    times = {p.name for p in st.params if p.unit == "s"} | {f for f in rec.values if "/" in f}
    check_record(rec, times & set(rec.values))
    std = st.from_dyr(_values(rec))
    where = _where(rec)
    for name, v in list(std.items()):
        p = st.param(name)
        info = PARAMS.get(p.kernel) if p.kernel else None
        if info is not None and info.neutral is not None and math.isinf(info.neutral):
            if (info.neutral > 0 and v > info.hi) or (info.neutral < 0 and v < info.lo):
                std[name] = info.neutral      # 99, 999, 9999: no limit
    bypassed: set[str] = set()
    for lead, lag in st.lead_lags:
        nl, ng = st.std_name(lead), st.std_name(lag)
        if nl is None or ng is None:
            continue
        if std.get(nl) == 0.0 and std.get(ng) == 0.0:
            bypassed |= {nl, ng}
        elif std.get(ng) == 0.0:
            raise UnitError(f"{where} {ng} = 0 with {nl} = {std[nl]:g} s: a lead without a lag cannot "
                            f"be simulated (ANDES bypasses such a block, PSS/E's meaning is not "
                            f"documented for it); give {ng} > 0, or {nl} = {ng} = 0 for no lead-lag")
    for name, v in std.items():
        p = st.param(name)
        if v != 0.0 or p.kernel is None or name in bypassed:
            continue
        if p.kernel == "TE":
            raise UnitError(f"{where} {name} = 0 (no regulator lag): bench-ctl's simulation kernel has "
                            f"no bypass for a zero regulator lag yet (it needs {name} > 0), and a zero "
                            "is never replaced by a typical value")
        if p.kernel in ("TA2", "TA4"):
            raise UnitError(f"{where} {name} = 0: a lag of zero needs its lead at zero too (bypassed)")
        if p.kernel == "TEX" and (std.get("KE", 1.0) != 1.0
                                  or (std.get("SE1", 0.0) > 0.0 and std.get("SE2", 0.0) > 0.0)):
            raise UnitError(f"{where} {name} = 0 with KE = {std.get('KE', 1.0):g} or saturation: bench-ctl's "
                            "kernel drops a DC exciter of zero time constant entirely (Efd = VR), which is "
                            f"only right for KE = 1 without saturation; it needs {name} > 0")
        if p.kernel == "TF" and std.get(_kf_name(st), 0.0) > 0.0:
            raise UnitError(f"{where} {name} = 0 with rate feedback {_kf_name(st)} = "
                            f"{std[_kf_name(st)]:g}: a derivative without a lag cannot be simulated; "
                            f"give {name} > 0, or {_kf_name(st)} = 0 for no rate feedback")
    for name, v in std.items():
        p = st.param(name)
        info = PARAMS.get(p.kernel) if p.kernel else None
        if info is None or name in bypassed or v == info.neutral or _unused(st, std, name):
            continue
        if not info.lo <= v <= info.hi:
            raise UnitError(f"{where} {name} = {v:g} {p.unit}: outside what bench-ctl's kernel simulates "
                            f"for it, [{info.lo:g}, {info.hi:g}] ({info.info})")
    return std, bypassed


def _unused(st: Structure, std: Mapping[str, float], name: str) -> bool:
    """A value the simulation does not use: the rate feedback's lag without rate feedback."""
    return st.param(name).kernel == "TF" and std.get(_kf_name(st), 0.0) == 0.0


def _kf_name(st: Structure) -> str:
    return st.std_name("KF") or "KF"


def _one(records: Sequence[DyrRecord], models: set[str], bus: int | None, ident: str | None, what: str,
         path: str | Path) -> DyrRecord | None:
    """The one record of `models` (at `bus`, `ident` when given); None when there is none. Two for
    one machine (the same bus and ID) are refused naming both; several machines ask for
    --dyr-bus / --dyr-id."""
    hits = [r for r in records if r.model in models and (bus is None or r.bus == bus)
            and (ident is None or r.id == str(ident))]
    if len(hits) <= 1:
        return hits[0] if hits else None
    if len({(r.bus, r.id) for r in hits}) == 1:
        raise UnitError(f"--from-dyr {path}: {len(hits)} {what} records for one machine (bus {hits[0].bus}, ID "
                        f"{hits[0].id}): " + ", ".join(f"{r.model} at {r.source}" for r in hits)
                        + "; a machine has one: remove the others")
    try:
        return find(records, models, bus=bus, id=ident)
    except DyrError as exc_:
        raise UnitError(f"--from-dyr {path}: {exc_}") from None


def _aliased(rec: DyrRecord, notes: list[str]) -> DyrRecord:
    """An exciter record of a model the library has under another name (`ALIASES`), as that
    model's record; said in `notes`."""
    model, values, why = ALIASES[rec.model]
    notes.append(f"{rec.model} at {rec.source} is read as {model}: {why}; `export --dyr` writes it back as {model}")
    return replace(rec, model=model, values=values(rec.values))


def _left_out(records: Sequence[DyrRecord], bus: int, ident: str, used: Sequence[DyrRecord],
              ignore: set[str], path: str | Path, notes: list[str]) -> list[str]:
    """Name every record of the machine (bus, ident) not in `used` (`notes`); refuse one that
    changes the excitation system's response unless its model is in `ignore`. Returns the
    'MODEL (kind) at file:line' of each left out."""
    out, stop = [], []
    for r in records:
        if r.bus != bus or r.id != ident or any(r is u for u in used):
            continue
        kind = dyr_kinds.kind_of(r.model)
        what = f"{r.model} ({kind}) at {r.source}"
        if r.model in ignore:
            notes.append(f"{what}: left out, as --dyr-ignore {r.model} asks")
        elif dyr_kinds.stops(r.model):
            stop.append(what)
            continue
        else:
            notes.append(f"{what}: not modelled by bench-ctl, left out")
        out.append(what)
    if stop:
        raise UnitError(f"--from-dyr {path}: the unit (bus {bus}, ID {ident}) has records bench-ctl cannot model: "
                        + "; ".join(stop) + ". They change the excitation system's response in a test: fitted "
                        "without them the model would stand in for them. Leave each out by name if the test was "
                        "made without it (e.g. the stabiliser switched off): "
                        + " ".join(f"--dyr-ignore {m}" for m in dict.fromkeys(w.split(" ")[0] for w in stop)))
    return out


def unit_from_dyr(unit: Unit, path: str | Path, *, bus: int | None = None, ident: str | None = None,
                  ignore: Sequence[str] = (), notes: list[str] | None = None) -> Unit:
    """`unit` (its generator constants, weights, effects) started from the records in `path`;
    `ignore`: models of the unit's records to leave out (`--dyr-ignore`); `notes` (when given)
    receives a line for each record aliased or left out (see the module docstring)."""
    notes = [] if notes is None else notes
    skip = {m.strip().upper() for m in ignore}
    try:
        records = read_dyr(path, skip)   # a record left out is not judged (its layout)
    except (DyrError, OSError) as exc_:
        raise UnitError(f"--from-dyr {path}: {exc_}") from None
    absent = sorted(skip - {r.model for r in records})
    if absent:
        raise UnitError(f"--dyr-ignore {', '.join(absent)}: no such record in {path}")
    kept = [r for r in records if r.model not in skip]
    exciter_models = {s.dyr_model for s in STRUCTURES.values() if s.name != "REFERENCE"}
    exciter_like = (exciter_models | set(ALIASES) | dyr_kinds.EXCITERS) - skip
    exc = _one(kept, exciter_like, bus, ident, "exciter", path)
    if exc is None:   # a generator record only: the unit's structure
        gen = _one(kept, set(GENERATORS), bus, ident, "generator", path)
        if gen is None:
            other = _one(kept, set(dyr_kinds.GENERATORS), bus, ident, "generator", path)
            if other is not None:
                raise UnitError(f"--from-dyr {path}: {other.model} at {other.source}: a generator model bench-ctl "
                                f"does not read (it reads {' and '.join(GENERATORS)})")
            raise UnitError(f"--from-dyr {path}: neither an exciter record ({', '.join(sorted(exciter_models))}) "
                            f"nor a generator record ({', '.join(GENERATORS)})"
                            + (f" at bus {bus}" if bus is not None else "") + (f" with ID {ident}" if ident else ""))
        notes.append(f"no exciter record for bus {gen.bus}, ID {gen.id}: the unit's own structure {unit.model} runs "
                     f"with its own values")
        new = _with_generator(replace(unit, source=f"{unit.source} with --from-dyr {path}"), gen)
        new = _with_stabiliser(new, kept, gen.bus, gen.id)
        return _named(new, path, gen, None, _left_out(records, gen.bus, gen.id, [gen, *_pss_of(kept, gen)], skip,
                                                        path, notes))
    used = [exc]
    if exc.model not in exciter_models:
        if exc.model not in ALIASES:
            raise UnitError(f"--from-dyr {path}: {exc.model} at {exc.source}: an exciter model bench-ctl does not "
                            f"have (its library: {', '.join(sorted(exciter_models))}; ESDC1A and IEEET1 are read as "
                            "IEEEX1). Another structure's equations are never run in its place: choose one with "
                            "--model and give its values with --set, without --from-dyr")
        exc = _aliased(exc, notes)
    st = structure(exc.model)
    new = with_model(unit, st.name)
    std, bypassed = _exciter_std(st, exc)
    identify = dict(new.identify)
    fixed_std = {}
    for name, value in std.items():
        p = st.param(name)
        if p.kernel is not None and p.kernel in identify and name not in bypassed:
            b = identify[p.kernel]   # the record's value is the start; bounds widened to hold it
            identify[p.kernel] = Bound(value, min(b.min, value), max(b.max, value))
        else:
            fixed_std[name] = value
            identify.pop(p.kernel or "", None)   # a bypassed lead-lag is not identified
    fixed = dict(new.fixed)
    fixed.update(st.kernel_values({k: v for k, v in fixed_std.items()}))
    for name in fixed_std:
        if _unused(st, std, name):   # held at its neutral value, the record keeps its own
            kernel = st.param(name).kernel or ""
            fixed[kernel] = float(PARAMS[kernel].neutral)  # type: ignore[arg-type]
    for k in identify:
        fixed.pop(k, None)
    for k in [k for k, v in fixed.items() if math.isinf(v) and v == PARAMS[k].neutral]:
        del fixed[k]   # an open limit: the parameter's neutral value (JSON holds no infinity)
    new = replace(new, identify=identify, fixed=fixed, model_values={**new.model_values, **std},
                  source=f"{unit.source} with --from-dyr {path}")
    gen = _one(kept, set(GENERATORS), exc.bus, exc.id, "generator", path)
    if gen is not None:
        used.append(gen)
        new = _with_generator(new, gen)
    elif _one(kept, set(dyr_kinds.GENERATORS), exc.bus, exc.id, "generator", path) is None:
        notes.append(f"no generator record for bus {exc.bus}, ID {exc.id}: the unit's own generator constants are "
                     f"kept (T'd0 {unit.generator.get('Td0p')} s, T''d0 {unit.generator.get('Td0pp')} s)")
    new = _with_stabiliser(new, kept, exc.bus, exc.id)
    used += _pss_of(kept, exc)
    return _named(new, path, gen, exc, _left_out(records, exc.bus, exc.id, used, skip, path, notes))


def _pss_of(records: Sequence[DyrRecord], rec: DyrRecord) -> list[DyrRecord]:
    return [r for r in records if r.model in STABILISERS and r.bus == rec.bus and r.id == rec.id]


def _named(unit: Unit, path: str | Path, gen: DyrRecord | None, exc: DyrRecord | None, left: list[str]) -> Unit:
    """The unit named after the records it was made from, its source listing what was left out."""
    at = gen or exc
    assert at is not None
    parts = [m for m in ((gen.model if gen else None), (exc.model if exc else None)) if m]
    name = f"{Path(path).name} bus {at.bus} ID {at.id} ({' + '.join(parts)})"
    source = unit.source + (f"; left out: {'; '.join(left)}" if left else "")
    return replace(unit, name=name, source=source)


def machine_from_record(rec: DyrRecord) -> dict[str, float]:
    """The machine's on-line data (a unit's [grid], `params.MACHINE_PARAMS`) from a GENROU or
    GENSAL record: reactances, q-axis time constants, H and D (a GENSAL has no X'q, T'q0)."""
    v = _values(rec)
    names = {"XD": "Xd", "XQ": "Xq", "XDP": "X'd", "XQP": "X'q", "XDPP": "X''d", "XLS": "Xl",
             "Tq0p": "T'qo", "Tq0pp": "T''qo", "H": "H", "DAMP": "D"}
    return {k: v[src] for k, src in names.items() if src in v}


def pss_from_record(rec: DyrRecord) -> dict[str, float]:
    """The unit's [grid] PSS_* from an IEEEST record (see the module docstring); what bench-ctl's
    stabiliser cannot run is refused naming the record, the field and the value."""
    where = _where(rec)
    check_record(rec, {"A1", "A2", "A3", "A4", "A5", "A6", "T1", "T2", "T3", "T4", "T5", "T6"})
    v = rec.values
    mode = rec.icons.get("MODE", 1)
    if mode != 1:
        raise UnitError(f"{where} MODE = {mode}: bench-ctl's stabiliser reads the rotor speed deviation "
                        "(MODE 1) only")
    filt = [f"{k} = {v[k]:g}" for k in ("A1", "A2", "A3", "A4", "A5", "A6") if v[k] != 0.0]
    if filt:
        raise UnitError(f"{where} {', '.join(filt)}: the stabiliser's filter is not simulated (bench-ctl runs "
                        "the IEEEST without it; A1..A6 = 0 is no filter)")
    if v["LSMIN"] != -v["LSMAX"]:
        raise UnitError(f"{where} LSMAX = {v['LSMAX']:g}, LSMIN = {v['LSMIN']:g}: bench-ctl's stabiliser "
                        "limit is symmetric (LSMIN = -LSMAX)")
    vcu, vcl = v["VCU"], v["VCL"]
    if (vcu != 0.0 and vcu <= 1.0) or (vcl != 0.0 and vcl >= 1.0):
        raise UnitError(f"{where} VCU = {vcu:g}, VCL = {vcl:g}: the cut-off switches the stabiliser off at "
                        "1 pu terminal voltage; bench-ctl does not simulate the cut-off")
    out = {"PSS_LSMAX": v["LSMAX"]}
    for lead, lag, a, b in (("T1", "T2", "PSS_T1", "PSS_T2"), ("T3", "T4", "PSS_T3", "PSS_T4")):
        if v[lead] == 0.0 and v[lag] == 0.0:     # bypassed: the kernel's 1/1
            out[a] = out[b] = 1.0
        elif v[lag] == 0.0:
            raise UnitError(f"{where} {lag} = 0 with {lead} = {v[lead]:g} s: a lead without a lag cannot be "
                            f"simulated; give {lag} > 0, or {lead} = {lag} = 0 for no lead-lag")
        else:
            out[a], out[b] = v[lead], v[lag]
    if v["T6"] <= 0.0:
        raise UnitError(f"{where} T6 = {v['T6']:g} s: the washout needs its pole T6 > 0")
    out["PSS_TW"] = v["T6"]
    out["PSS_KS"] = v["KS"] * v["T5"] / v["T6"]
    return grid_values(out, where)


def _with_stabiliser(unit: Unit, records: Sequence[DyrRecord], bus: int, ident: str) -> Unit:
    """`unit` with the PSS of the stabiliser record at `bus`, machine `ident` (unchanged without one)."""
    hits = [r for r in records if r.model in STABILISERS and r.bus == bus and r.id == ident]
    if not hits:
        return unit
    if len(hits) > 1:
        raise UnitError(f"several stabiliser records at bus {bus} ID {ident}: "
                        f"{', '.join(r.source for r in hits)}")
    rec = hits[0]
    if rec.model in PSS2_MODELS:
        return replace(unit, grid={**unit.grid, **pss2_from_record(rec)})
    # an IEEEST record: the unit's own PSS_MODEL (a PSS2A / PSS2B of its file) would hide it
    grid = {k: v for k, v in unit.grid.items() if k != "PSS_MODEL"}
    return replace(unit, grid={**grid, **pss_from_record(rec)})


def _with_generator(unit: Unit, gen: DyrRecord) -> Unit:
    g = generator_from_record(gen)
    generator = dict(unit.generator)
    generator.update({k: g[k] for k in ("Td0p", "Td0pp", *GENERATOR_OPTIONAL)})
    unit = replace(unit, generator=generator, grid={**unit.grid, **machine_from_record(gen)})
    if "S10" in g:
        unit = unit.with_effects({"saturation": {"S10": g["S10"], "S12": g["S12"]}})
    return unit
