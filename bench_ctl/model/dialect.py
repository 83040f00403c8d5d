"""One dialect a user reads: a structure's own names at every boundary, the kernel's inside.

Inside bench-ctl a unit's values are kernel parameters (`bench_ctl.model.params`, the columns of
the kernel's matrix); a user reads and writes a standard structure's IEEE 421.5 / PSS/E names
(`bench_ctl.model.structures`): ESST1A's `KA`, `TA`, `TB1` are the kernel's `KAVR`, `TE`, `TA4`.
This module is the one place that translates, in each direction:

- kernel -> standard, at output: `std_name`, `namer`, `std_text`, `result_to_std`,
  `diagnosis_to_std`, `unit_to_std` (identification result, diagnosis, unit block; the kernel's
  own view goes under a `kernel` key, for debugging);
- standard -> kernel, at input: `kernel_text`, `kernel_sections` (the values a result gives,
  for the report's re-simulation, `export --dyr` and `diagnose --result`). Unit files and `--set`
  go through `bench_ctl.units.unit`, which refuses a kernel name with the standard one
  (`refusal`).

The REFERENCE structure's names are the kernel's (it is the paper's model): there both views are
the same and nothing is renamed. A result written before the standard names (no `kernel` key) is
read in the kernel's names (docs/formats.md).
"""
from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from typing import Any

from .effects import EFFECTS
from .params import GENERATOR_OPTIONAL, GENERATOR_PARAMS, PARAMS, RECORD_PARAMS
from .structures import DEFAULT, Structure, StructureError, structure

__all__ = ["std_name", "namer", "std_text", "kernel_text", "std_keys", "kernel_keys", "refusal",
           "unit_to_std", "result_to_std", "diagnosis_to_std", "kernel_sections", "structure_of",
           "hidden_kernel_names", "describe", "shared_names"]

_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _plain(st: Structure) -> bool:
    """The structure speaks the kernel's names (REFERENCE): nothing to translate."""
    return st.name == DEFAULT


# ---------------------------------------------------------------- kernel -> standard (output)
def std_name(st: Structure, kernel: str) -> str:
    """The standard name of a kernel parameter the structure drives; other names unchanged."""
    return kernel if _plain(st) else (st.std_name(kernel) or kernel)


def namer(st: Structure) -> Callable[[str], str]:
    """`std_name` bound to `st`, for code that formats names into text."""
    return lambda n: std_name(st, n)


def std_text(st: Structure, text: str) -> str:
    """A text in kernel names (a constraint, `TE <= TA4`) in the structure's (`TA <= TB1`); all
    names at once, so a swap (IEEEX1: kernel TE is TA, TEX is TE) cannot chain."""
    if _plain(st):
        return text
    return _WORD.sub(lambda m: st.std_name(m.group(0)) or m.group(0), text)


def std_keys(st: Structure, values: Mapping[str, Any]) -> dict[str, Any]:
    return {std_name(st, k): v for k, v in values.items()}


def describe(st: Structure, name: str) -> tuple[str, str, float | None] | None:
    """(unit, meaning, neutral value) of a name as the structure's user reads it: its own
    parameter, else the kernel catalogue's (generator, effects); None for an unknown name."""
    if not _plain(st) and name in st.names:
        p = st.param(name)
        return p.unit, p.info, None
    info = PARAMS.get(name)
    return (info.unit, info.info, info.neutral) if info else None


def hidden_kernel_names(st: Structure) -> tuple[str, ...]:
    """Kernel names a user of a standard structure `st` never reads: every kernel parameter that
    is neither one of its names nor a name all structures share (`shared_names`), e.g. the ones
    its parameters drive under another name, its settings and other structures' blocks."""
    shared = set(shared_names())
    own = {p.kernel for p in st.params if p.kernel} | set(st.settings)
    return tuple(sorted(n for n in PARAMS if n not in st.names and (n not in shared or n in own)))


def _std_fixed(st: Structure, kernel: Mapping[str, Any], std_values: Mapping[str, Any],
               skip: set[str]) -> dict[str, Any]:
    """A `fixed` table in the structure's names: its parameters not in `skip` (standard values),
    then the names all structures share (generator, effects, dead time, ...). Kernel names its
    parameters drive or its settings fix are left out (implied by the structure), so are other
    structures' blocks (neutral) and a shared name that is one of its standard names with
    another meaning (ESST4B's VRMAX is the kernel's VPMAX; the kernel's VRMAX, the diagnosis'
    ceiling, is under `unit.effects`)."""
    out = {p.name: std_values[p.name] for p in st.params if p.name not in skip and p.name in std_values}
    own = {p.kernel for p in st.params if p.kernel} | set(st.settings) | set(st.names)
    shared = set(shared_names())
    out.update({k: v for k, v in kernel.items() if k in shared and k not in own})
    return out


def unit_to_std(st: Structure, unit: Mapping[str, Any]) -> dict[str, Any]:
    """`Unit.to_dict()` in the structure's names; the kernel's identify, fixed and constraints
    under `kernel`."""
    if _plain(st):
        return dict(unit)
    out = dict(unit)
    ident = unit.get("identify") or {}
    out["identify"] = std_keys(st, ident)
    out["fixed"] = _std_fixed(st, unit.get("fixed") or {}, unit.get("model_values") or {},
                              {std_name(st, k) for k in ident})
    out["constraints"] = [std_text(st, c) for c in unit.get("constraints") or []]
    out["kernel"] = {k: unit.get(k) for k in ("identify", "fixed", "constraints")}
    return out


def _ident_to_std(st: Structure, ident: Mapping[str, Any]) -> dict[str, Any]:
    """The identifiability block's names (its texts are written with `namer` at the source)."""
    out = dict(ident)
    out["names"] = [std_name(st, n) for n in ident.get("names", [])]
    for key in ("sensitivity", "std", "rel_std", "determined", "reasons"):
        if isinstance(ident.get(key), Mapping):
            out[key] = std_keys(st, ident[key])
    out["equivalent_sets"] = [{**e, "params": std_keys(st, e.get("params") or {})}
                              if isinstance(e, Mapping) else e for e in ident.get("equivalent_sets", [])]
    return out


def _constraints_to_std(st: Structure, rows: Any) -> Any:
    return [{**c, "expr": std_text(st, c["expr"])} if isinstance(c, Mapping) and "expr" in c else c
            for c in rows or []]


def result_to_std(st: Structure, result: Mapping[str, Any]) -> dict[str, Any]:
    """An identification result in the structure's names (`params`, `bounds`, `fixed`,
    `constraints`, `identifiability`, `unit`, `comparison`); the kernel's view under `kernel`.
    `model` is already in standard names."""
    if _plain(st):
        return dict(result)
    out = dict(result)
    params = result.get("params") or {}
    std_values = (result.get("model") or {}).get("params") or {}
    out["params"] = std_keys(st, params)
    out["bounds"] = std_keys(st, result.get("bounds") or {})
    out["fixed"] = _std_fixed(st, result.get("fixed") or {}, std_values, set(out["params"]))
    out["constraints"] = _constraints_to_std(st, result.get("constraints"))
    if isinstance(result.get("identifiability"), Mapping):
        out["identifiability"] = _ident_to_std(st, result["identifiability"])
    if isinstance(result.get("unit"), Mapping):
        out["unit"] = unit_to_std(st, result["unit"])
    if "comparison" in result:
        out["comparison"] = [{**c, "params": std_keys(st, c.get("params") or {}),
                              "constraints_violated": [std_text(st, t) for t in c.get("constraints_violated", [])]}
                             for c in result["comparison"]]
    opt = result.get("optimizer")
    if isinstance(opt, Mapping) and isinstance(opt.get("settings"), Mapping):
        # the search space, the polishes and the swap restarts name parameters in keys and texts
        out["optimizer"] = {**opt, "settings": _deep_std(st, opt["settings"])}
    out["kernel"] = {k: result.get(k) for k in ("params", "bounds", "fixed", "constraints")}
    return out


def _deep_std(st: Structure, x: Any) -> Any:
    """`x` (nested dicts, lists, texts) with every name in a key or a text in the structure's."""
    if isinstance(x, Mapping):
        return {(std_text(st, k) if isinstance(k, str) else k): _deep_std(st, v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_deep_std(st, v) for v in x]
    return std_text(st, x) if isinstance(x, str) else x


def diagnosis_to_std(st: Structure, d: Mapping[str, Any]) -> dict[str, Any]:
    """A diagnosis in the structure's names: the base fit's and each effect's model parameters
    and the unit. An effect's own parameters keep the effect's names (docs/model.md, "The eight
    effects"): they sit under the effect. The kernel's view of the model parameters under
    `kernel`."""
    if _plain(st):
        return dict(d)
    out = dict(d)
    base = d.get("base") or {}
    out["base"] = {**base, "params": std_keys(st, base.get("params") or {})}
    out["effects"] = [{**e, "avr_params": std_keys(st, e.get("avr_params") or {})}
                      for e in d.get("effects") or []]
    out["explained_by"] = [{**s, "avr_params": std_keys(st, s["avr_params"])} if s.get("avr_params") else s
                           for s in d.get("explained_by") or []]
    if isinstance(d.get("unit"), Mapping):
        out["unit"] = unit_to_std(st, d["unit"])
    out["kernel"] = {"base_params": base.get("params"),
                     "avr_params": {e.get("name"): e.get("avr_params") for e in d.get("effects") or []},
                     "explained_by_avr_params": [s.get("avr_params") for s in d.get("explained_by") or []]}
    return out


# ---------------------------------------------------------------- standard -> kernel (input)
def kernel_text(st: Structure, text: str) -> str:
    """A text in the structure's names (`TA <= TB1`) in the kernel's (`TE <= TA4`)."""
    if _plain(st):
        return text
    return _WORD.sub(lambda m: (st.param(m.group(0)).kernel or m.group(0)) if m.group(0) in st.names
                     else m.group(0), text)


def kernel_keys(st: Structure, values: Mapping[str, Any]) -> dict[str, Any]:
    """Standard names -> kernel names; a parameter kept for the record only is left out."""
    if _plain(st):
        return dict(values)
    out = {}
    for k, v in values.items():
        if k in st.names:
            kern = st.param(k).kernel
            if kern is not None:
                out[kern] = v
        else:
            out[k] = v
    return out


def refusal(st: Structure, name: str) -> str | None:
    """Why `name` is not a name of `st` when it is a kernel name the structure hides (the message
    names the standard one); None for any other name."""
    if _plain(st) or name in st.names:
        return None
    drivers = [p.name for p in st.params if p.kernel == name]
    if drivers:
        return (f"{name} is the kernel's name; model {st.name} calls it {drivers[0]}: use "
                f"{drivers[0]}")
    if name in st.settings:
        return (f"{name} is a kernel setting that model {st.name} fixes at {st.settings[name]:g}; "
                f"its parameters are {', '.join(st.names)}")
    if name in PARAMS and name not in shared_names():
        return (f"{name} is a kernel parameter that model {st.name} does not have; its parameters are "
                f"{', '.join(st.names)}")
    return None


def shared_names() -> tuple[str, ...]:
    """Names every structure shares with the kernel: the generator's, the effects' (their options
    included; docs/model.md) and the record's edge offsets (`EDGE1`..: the fitted instant of a
    setpoint edge less its nominal sample, the same for every structure)."""
    return (*GENERATOR_PARAMS, *GENERATOR_OPTIONAL,
            *(p for e in EFFECTS.values() for p in (*e.params, *e.options)), *RECORD_PARAMS)


def structure_of(result: Mapping[str, Any]) -> Structure:
    """The structure a result or diagnosis names (`model.name`, else `unit.model`; REFERENCE)."""
    model = result.get("model") if isinstance(result.get("model"), Mapping) else {}
    unit = result.get("unit") if isinstance(result.get("unit"), Mapping) else {}
    return structure(model.get("name") or unit.get("model") or None)


def kernel_sections(result: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """`fixed` and `params` of an identification result in kernel names, values as written (null:
    an open limit): in a result of a standard structure every parameter of the structure becomes
    the kernel parameter it drives (one kept for the record only is left out), the structure's
    settings are added to `fixed`, and the unit's effects too (their names are the kernel's). A
    result without a `kernel` key was written in kernel names and is read as it is."""
    try:
        st = structure_of(result)
    except StructureError:
        st = structure(None)
    fixed = dict(result.get("fixed") or {})
    params = dict(result.get("params") or {})
    if _plain(st) or "kernel" not in result:
        return {"fixed": fixed, "params": params}
    kfixed: dict[str, Any] = dict(st.settings)
    kfixed.update(kernel_keys(st, fixed))
    unit = result.get("unit") if isinstance(result.get("unit"), Mapping) else {}
    for ps in (unit.get("effects") or {}).values():     # on top, as `Unit.values` has them
        if isinstance(ps, Mapping):
            kfixed.update(ps)
    kparams = kernel_keys(st, params)
    for lead, lag in st.lead_lags:      # a bypassed lead-lag (both 0 in the standard) is 1, 1
        merged = {**kfixed, **kparams}
        if merged.get(lead) == 0.0 and merged.get(lag) == 0.0:
            for n in (lead, lag):
                (kparams if n in kparams else kfixed)[n] = 1.0
    return {"fixed": {k: v for k, v in kfixed.items() if k not in kparams}, "params": kparams}
