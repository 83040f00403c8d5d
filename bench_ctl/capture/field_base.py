"""The field quantities on the model's base (docs/formats.md, "The efd base").

A recorder gives the field voltage (and current) in its own unit: volts, or per unit of the rated
field (`UfRel`, `IfRel`). The model's efd is per unit of the field voltage that gives 1 pu terminal
voltage on the air-gap line at no load (docs/model.md), so at no load in steady state

    efd0 = ifd0 = Vt0 + Sat(Vt0) = Vt0 (1 + S(Vt0)),   S(Vt0) = Sat(Vt0) / Vt0

with the generator's saturation (S10, S12). `--efd-base` says how the recorded efd reaches that
base:

- `auto`: the factor that puts the mean of the pre-step efd on Vt0 + Sat(Vt0), with Vt0 the mean
  of the pre-step vt when the record has vt, else the unit's Vt0. Refused when the pre-step part
  is not steady (the means of its four quarters spread more than STEADY_REL_SPREAD of its level),
  too short (MIN_PRE_SAMPLES) or not positive.
- `<X>V`: the channel records volts and X volts are 1 pu of the model's efd (factor 1/X).
- `<X>rf`: the channel records per unit of the rated field voltage and X of it is 1 pu of the
  model's efd (factor 1/X).
- `from:NOLOAD.csv`: the factor an earlier import of the same unit's no-load step found (its
  sidecar's `import.efd_base`): what an on-line record needs, where the no-load relation above
  does not hold (a loaded unit's field is larger: armature reaction). `auto` on an on-line record
  is refused, naming this way.

`--scale ifd=auto` does the same for the field current (ifd0 = Vt0 + Sat(Vt0) at no load), and
`--scale ifd=from:NOLOAD.csv` takes the no-load import's `import.ifd_base`.
`NoLoad` carries Vt0 and Sat from the unit; the caller (the import command) builds it.
"""
from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from bench_ctl.capture.errors import CaptureError, SpecError

MIN_PRE_SAMPLES = 20
#: samples left out at the end of the pre-step part (the change may start there)
PRE_GUARD = 2
#: the means of the pre-step part's four quarters may spread at most this share of its level
STEADY_REL_SPREAD = 0.02
UNITS = {"v": ("volts", "V"), "rf": ("rated", "rated-field units")}
_SYNTAX = re.compile(r"([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*([A-Za-z]+)?")


@dataclass(frozen=True)
class EfdBase:
    """How the recorded efd reaches the model's base: `auto`, 1 pu of the model = `value` volts
    (`volts`) / rated-field units (`rated`), or the factor of a no-load import (`from`, its
    capture at `path`)."""

    mode: str
    value: float | None = None
    path: str | None = None

    def __post_init__(self) -> None:
        if self.mode not in ("auto", "volts", "rated", "from"):
            raise SpecError(f"efd base mode {self.mode!r}: expected auto, volts, rated or from")
        if self.mode == "from":
            if not self.path:
                raise SpecError("from: needs the no-load capture's path, e.g. from:noload.csv")
            return
        if self.mode != "auto" and not (isinstance(self.value, (int, float)) and math.isfinite(self.value)
                                        and self.value > 0):
            raise SpecError(f"efd base {self.value!r}: a positive finite number")

    def text(self) -> str:
        if self.mode == "auto":
            return "auto"
        if self.mode == "from":
            return f"from:{self.path}"
        return f"{self.value:g}{'V' if self.mode == 'volts' else 'rf'}"


def parse_efd_base(text: str) -> EfdBase:
    """`auto`, `95V` (volts), `0.34rf` (rated-field units) or `from:NOLOAD.csv` (an earlier no-load
    import's factor): what 1 pu of the model's efd is in the recorded channel's unit. A bare number
    is refused: it says neither."""
    t = text.strip()
    if t.lower() == "auto":
        return EfdBase("auto")
    if t.lower().startswith("from:"):
        return EfdBase("from", path=t[5:].strip())
    m = _SYNTAX.fullmatch(t)
    if m is None:
        raise SpecError(f"{text!r}: expected auto, <X>V or <X>rf (e.g. 95V, 0.34rf)")
    value, unit = float(m.group(1)), (m.group(2) or "").lower()
    if not unit:
        raise SpecError(f"{text!r}: say what the efd channel records: {t}V (it records volts, {t} V are "
                         f"1 pu of the model's efd) or {t}rf (it records rated-field units, {t} of them are "
                         "1 pu); a plain factor is --efd-scale")
    if unit not in UNITS:
        raise SpecError(f"{text!r}: unit {m.group(2)!r}: expected V (volts) or rf (rated-field units)")
    return EfdBase(UNITS[unit][0], value)


@dataclass(frozen=True)
class NoLoad:
    """The model's no-load field: efd0(vt) = ifd0(vt) = vt + Sat(vt)."""

    vt0_pu: float                            # the unit's Vt0
    s10: float
    s12: float
    saturation: Callable[[float], float]     # Sat(x) in pu (the kernel's quadratic)
    source: str                              # where the values came from (the unit)

    def efd0(self, vt: float) -> float:
        return vt + self.saturation(vt)


def pre_step(file: str, time: np.ndarray, x: np.ndarray, edge_lo_s: float, what: str) -> np.ndarray:
    """The samples of `x` before the first edge (less PRE_GUARD); refused when fewer than
    MIN_PRE_SAMPLES."""
    n = int(np.count_nonzero(np.asarray(time) < edge_lo_s)) - PRE_GUARD
    if n < MIN_PRE_SAMPLES:
        raise CaptureError(file, f"only {max(n, 0)} samples of {what} before the first edge at t = {edge_lo_s:.4f} s: "
                           f"at least {MIN_PRE_SAMPLES} are needed to put it on the model's base")
    return np.asarray(x[:n], float)


def quarter_spread(values: np.ndarray) -> float:
    """(max - min) of the means of the four quarters of `values`, over |their mean|."""
    means = [float(np.mean(q)) for q in np.array_split(np.asarray(values, float), 4)]
    level = float(np.mean(values))
    return (max(means) - min(means)) / abs(level) if level else math.inf


def auto_factor(file: str, what: str, column: str | None, time: np.ndarray, x: np.ndarray, edge_lo_s: float,
                no_load: NoLoad, vt_pre: float | None) -> tuple[float, dict[str, Any]]:
    """The factor that puts the pre-step mean of `x` (efd or ifd, source units) on the model's
    no-load value Vt0 + Sat(Vt0), and the sidecar block that says how."""
    pre = pre_step(file, time, x, edge_lo_s, what)
    level = float(np.mean(pre))
    where = f"column {column!r}" if column else what
    if not level > 0.0:
        raise CaptureError(file, f"the pre-step {what} ({where}) averages {level:.4g}: not a positive field "
                           "to put on the model's no-load base (a sign or an offset to correct first?)")
    spread = quarter_spread(pre)
    if spread > STEADY_REL_SPREAD:
        raise CaptureError(file, f"the pre-step {what} ({where}) is not steady: the means of its four quarters "
                           f"(t = {float(time[0]):.3f} .. {float(time[pre.size - 1]):.3f} s) spread "
                           f"{100 * spread:.2f} % of its level {level:.4g} (at most {100 * STEADY_REL_SPREAD:g} % "
                           f"for --efd-base auto); give the base instead")
    vt0 = no_load.vt0_pu if vt_pre is None else float(vt_pre)
    target = no_load.efd0(vt0)
    factor = target / level
    return factor, {
        "mode": "auto", "factor": factor, "channel": what, "column": column,
        "pre_step": {"t0_s": float(time[0]), "t1_s": float(time[pre.size - 1]), "samples": int(pre.size),
                     "mean_source_units": level, "quarter_spread_rel": spread},
        "vt0_pu": vt0, "vt0_from": "the record's pre-step vt" if vt_pre is not None else "the unit's Vt0",
        "unit_vt0_pu": no_load.vt0_pu,
        "S10": no_load.s10, "S12": no_load.s12, "sat_at_vt0_pu": no_load.saturation(vt0),
        "no_load_pu": target, "formula": "Vt0 + Sat(Vt0) = Vt0 (1 + S(Vt0))", "unit": no_load.source,
    }


def from_no_load(base: EfdBase, what: str, column: str | None) -> tuple[float, dict[str, Any]]:
    """The factor of `what` (efd or ifd) that the no-load import `base.path` found or was given, and
    the sidecar block that says so. Refused (ValueError naming the capture) when that capture is
    not an import, is itself on line, has no such factor, or took `what` from another column."""
    from bench_ctl.capture.capture import read_capture  # the capture layer's own reader

    path = str(base.path)
    try:
        cap = read_capture(path)
    except (CaptureError, OSError) as exc:
        raise SpecError(f"from:{path}: {exc}") from None
    imp = cap.meta.get("import") if isinstance(cap.meta.get("import"), dict) else None
    block = None if imp is None else imp.get(f"{what}_base")
    if not isinstance(block, dict) or not isinstance(block.get("factor"), (int, float)):
        raise SpecError(f"from:{path}: its sidecar has no import.{what}_base (import the unit's no-load step "
                         f"with --{'efd-base auto' if what == 'efd' else 'scale ifd=auto'} first)")
    if cap.on_line:
        raise SpecError(f"from:{path}: that record is on line too (it holds P and Q): the base comes from "
                         "the unit's no-load step")
    was = (imp.get("columns") or {}).get(what)
    if column is not None and was is not None and was != column:
        raise SpecError(f"from:{path}: its {what} came from column {was!r}, here it is {column!r}: another "
                         f"channel or unit; give the factor itself if they are the same "
                         f"({'--efd-scale' if what == 'efd' else '--scale ifd='}{block['factor']:.6g})")
    factor = float(block["factor"])
    return factor, {"mode": "from", "given": base.text(), "factor": factor, "column": column,
                    "from": {"path": str(cap.source), "sha256": cap.meta.get("csv_sha256"),
                             "mode": block.get("mode"), "column": was,
                             "source": (imp.get("source") or {}).get("path")}}


def explicit_block(base: EfdBase | None, factor: float, *, file: str, time: np.ndarray, x: np.ndarray,
                   edge_lo_s: float | None, no_load: NoLoad | None, vt_pre: float | None,
                   block: dict[str, Any] | None = None, on_line: bool = False) -> dict[str, Any]:
    """The sidecar block of a base the user gave (None: the plain factor of --efd-scale; `block`:
    one made already, `from_no_load`'s), with what the pre-step efd becomes on the model's base
    beside the model's no-load efd, when both are known (on line, `on_line`, a loaded unit's field
    is above the no-load one: said, not compared)."""
    if block is None:
        block = ({"mode": base.mode, "given": base.text(), "factor": factor} if base is not None
                 else {"mode": "scale", "given": f"{factor:g}", "factor": factor})
    block["on_line"] = on_line
    if edge_lo_s is None or (no_load is None and not on_line):
        return block
    try:
        pre = pre_step(file, time, x, edge_lo_s, "efd")
    except CaptureError:
        return block
    if on_line:   # a loaded unit's field: no no-load value to set beside it
        block.update(pre_step_pu=float(np.mean(pre)) * factor)
        return block
    vt0 = no_load.vt0_pu if vt_pre is None else float(vt_pre)
    block.update(pre_step_pu=float(np.mean(pre)) * factor, vt0_pu=vt0, no_load_pu=no_load.efd0(vt0),
                 unit=no_load.source)
    return block
