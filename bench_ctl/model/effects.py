"""The diagnosis vocabulary: eight unmodelled effects, each an augmentation of the reference model.

Each effect names its parameters, their neutral values (the model without the effect), the
bounds a fit may search (physically sensible for a no-load pulse test of a static-excitation
unit), and any constraint between them. Names are fixed by docs/model.md ("The eight effects").
The record also carries what the diagnosis needs of the effect, so that nothing elsewhere is
keyed by its name: where its fits start (`starts`, from the feature tests' hints plus a small
grid), whether the order of the model's equivalent lags matters to it (`order_sensitive`), the
variants tried beside it (`variants`) and the test that tells it apart from a look-alike
(`separating`).
"""
from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from bench_ctl.exitcodes import BadInput

from .params import PARAMS


class EffectError(BadInput):
    """An effect or an effect's parameter that does not exist, or values that break its constraint."""

_SCALED = re.compile(r"^\s*(\w+)\s*(>=|<=)\s*([0-9.]+)\s*\*\s*(\w+)\s*$")  # "S12 >= 1.44*S10"


Hints = Mapping[str, float]


@dataclass(frozen=True)
class Variant:
    """Another form of an effect that the diagnosis fits beside the plain one (from the plain
    fit's values) and keeps when the BIC prefers it."""
    label: str
    #: option values the variant holds (VRVT = 1: the limits scale with Vt)
    fixed: Mapping[str, float]
    #: options it fits too, with their starting values (KC: the commutation drop)
    extra: Mapping[str, float] = field(default_factory=dict)
    #: a capture column it needs (the commutation drop needs the recorded field current)
    needs: str | None = None


@dataclass(frozen=True)
class Effect:
    name: str
    params: tuple[str, ...]
    bounds: dict[str, tuple[float, float]]
    description: str
    constraints: tuple[str, ...] = ()
    in_loop: bool = True  # False: acts on the record only (recorder_gain, time_skew)
    #: parameters of a variant: may be set (unit file, --effect), held by a fit unless it tries
    #: that variant (ceiling_limit: VRVT, the bus-fed ceilings; KC, the commutation drop)
    options: tuple[str, ...] = ()
    #: the diagnosis' starting values of the parameters from the feature tests' hints (top_level,
    #: delay_s, sat0, slope_up, gain, ...), before clipping to `bounds`
    grid: Callable[[Hints], list[dict[str, float]]] = lambda hints: []
    #: acts between the exciter lag and the record (a limit on the efd state): which of the linear
    #: model's equivalent lags sits in that slot matters, so the diagnosis tries each
    order_sensitive: bool = False
    #: the plain form's label and the variants the diagnosis tries beside it
    plain: str = ""
    variants: tuple[Variant, ...] = ()
    #: the test that separates this effect from another one (by its name) that explains a capture
    #: as well; one of the two effects holds it
    separating: Mapping[str, str] = field(default_factory=dict)
    #: where the diagnosis tries it: at no load, on line (the engine runs every effect on the grid;
    #: the dead time and the setpoint ramp are not tried there yet: the ramp's fits cost the Mostar
    #: on-line record's diagnosis about 2 s of its 18, and the dead time has no check on line
    #: against equations written apart)
    at_no_load: bool = True
    on_line: bool = True
    #: its parameters are the unit's [grid] values, fitted (not kernel parameters): a diagnosis
    #: effect only, never a unit file's [effects] section
    frees_grid: bool = False

    def starts(self, hints: Hints) -> list[dict[str, float]]:
        """Starting values of the parameters: from the feature tests plus a small grid, inside
        the fit bounds."""
        return [{p: self.clip(p, v) for p, v in s.items()} for s in self.grid(hints)]

    def clip(self, name: str, v: float) -> float:
        lo, hi = self.bounds[name]
        return float(min(max(v, lo), hi))

    def neutral(self) -> dict[str, float]:
        return {p: PARAMS[p].neutral for p in self.params}  # type: ignore[misc]

    def check(self, values: dict[str, float]) -> None:
        unknown = set(values) - set(self.params) - set(self.options)
        if unknown:
            raise EffectError(
                f"effect {self.name!r} has no parameter {sorted(unknown)}; it has "
                f"{list(self.params + self.options)}"
            )
        for name, value in values.items():
            PARAMS[name].check(float(value), where=f"effect {self.name}: ")

    def check_constraints(self, values: dict[str, float]) -> None:
        """The constraints between the effect's parameters, all of them given (`values`)."""
        for text in self.constraints:
            m = _SCALED.match(text)
            if m is None:  # only the "A >= k*B" form exists; a new form must be taught here
                raise EffectError(f"effect {self.name}: cannot read its constraint {text!r}")
            a, op, k, b = m.group(1), m.group(2), float(m.group(3)), m.group(4)
            lhs, rhs = float(values[a]), k * float(values[b])
            if not (lhs >= rhs if op == ">=" else lhs <= rhs):
                raise EffectError(f"effect {self.name}: {a} = {lhs:g} breaks {text} "
                                 f"({k:g}*{b} = {rhs:g}); give both parameters")


def _around(x: float, factors: tuple[float, ...], grid: list[float]) -> list[float]:
    """`grid`, led by `x` times each factor when the feature tests measured a positive `x`."""
    return [x * f for f in factors] + grid if math.isfinite(x) and x > 0 else grid


def _delay(p: str) -> Callable[[Hints], list[dict[str, float]]]:
    return lambda h: [{p: v} for v in _around(h.get("delay_s", math.nan), (1.0, 0.6, 1.5),
                                                [0.003, 0.01, 0.02, 0.04])]


def _saturation(h: Hints) -> list[dict[str, float]]:
    s = h.get("sat0", 0.0)
    s10s = ([s] if s > 0.005 else []) + [0.03, 0.1]
    return [{"S10": a, "S12": a * r} for a in s10s for r in (2.0, 4.0)]


def _rate(h: Hints) -> list[dict[str, float]]:
    s = max(h.get("slope_up", math.nan), h.get("slope_down", math.nan))
    return [{"RATE": v} for v in _around(s, (1.0, 0.8, 1.2), [3.0, 10.0, 30.0, 80.0])]


EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in [
        Effect("ceiling_limit", ("VRMAX", "VRMIN"),
               {"VRMAX": (1.5, 10.0), "VRMIN": (-10.0, 0.5), "VRVT": (0.0, 1.0), "KC": (0.0, 0.5)},
               "exciter output clamped by a non-windup limit; variants: the limits scale with Vt "
               "(VRVT = 1, a bus-fed static exciter), the upper one less KC*Ifd (commutation)",
               options=("VRVT", "KC"),
               # both limits where the measured efd turns flat: a limit that is not there moves
               # away (its gradient pushes it out), one started outside the record gets none
               grid=lambda h: [{"VRMAX": h["top_level"], "VRMIN": h["bottom_level"]}],
               order_sensitive=True, plain="fixed limits",
               variants=(Variant("bus-fed: VRMAX*Vt, VRMIN*Vt", {"VRVT": 1.0}),
                         Variant("bus-fed with commutation drop: VRMAX*Vt - KC*Ifd, VRMIN*Vt", {"VRVT": 1.0},
                                 {"KC": 0.05}, needs="ifd")),
               separating={"rate_limit": "repeat with a step of another size (e.g. half the amplitude): a "
                                         "ceiling caps the level at the same value, a slew limit caps the slope"}),
        Effect("dead_time", ("TD",), {"TD": (0.0, 0.1)},
               "pure delay in the control path (digital AVR + thyristor firing)",
               grid=_delay("TD"), on_line=False,
               separating={"time_skew": "record the AVR output or the field voltage at the exciter on a second "
                                        "channel (or efd and usetp on the same channel group): a recorder skew "
                                        "delays only the efd channel, a dead time delays the response"}),
        Effect("transducer_lag", ("TR",), {"TR": (0.0, 0.2)},
               "terminal-voltage measurement lag",
               grid=lambda h: [{"TR": v} for v in (0.01, 0.03, 0.06, 0.1, 0.15, 0.2)],
               separating={"dead_time": "record the transducer output (the AVR's measured voltage) beside Vt: "
                                        "a transducer lag shows there"}),
        Effect("saturation", ("S10", "S12"), {"S10": (0.0, 0.3), "S12": (0.0, 1.5)},
               "generator open-circuit saturation, Sat(x) = B (x - A)^2 for x > A",
               constraints=("S12 >= 1.44*S10",), grid=_saturation,
               separating={"recorder_gain": "repeat at another terminal voltage (e.g. Vt0 = 0.9 and 1.05 pu) or "
                                            "check the efd channel calibration: saturation grows with the "
                                            "voltage, a gain error scales every level alike"}),
        Effect("rate_limit", ("RATE",), {"RATE": (2.0, 500.0)},
               "slew limit on the exciter output", grid=_rate, order_sensitive=True),
        Effect("setpoint_ramp", ("RAMP",), {"RAMP": (0.01, 10.0)},
               "the device ramps setpoint changes instead of stepping",
               grid=lambda h: [{"RAMP": v} for v in (0.05, 0.1, 0.2, 0.4, 0.8, 2.0, 5.0)], on_line=False,
               separating={"rate_limit": "read the device's active setpoint during the test (a setpoint ramp "
                                         "shows there), or a step of another size: a ramp lengthens the rise "
                                         "in proportion to the step, a slew limit caps the efd slope",
                           "dead_time": "read the device's active setpoint during the test, or a step of "
                                        "another size: a ramp's duration scales with the step, a dead time "
                                        "does not"}),
        Effect("recorder_gain", ("GAIN",), {"GAIN": (0.8, 1.2)},
               "calibration error of the recorded efd channel", in_loop=False,
               grid=lambda h: [{"GAIN": h.get("gain", 1.0)}, {"GAIN": 1.0}]),
        Effect("time_skew", ("SKEW",), {"SKEW": (0.0, 0.05)},
               "efd channel recorded late relative to the usetp channel", in_loop=False,
               grid=_delay("SKEW")),
    ]
}

#: the diagnosis' effects on line that are not kernel parameters: the grid seen from the unit other
#: than the unit file says (its [grid] values fitted within the effect's bounds, from its own)
GRID_EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in [
        Effect("grid_reactance", ("XE",), {"XE": (0.02, 1.2)},
               "the grid's reactance to the infinite bus (step-up transformer + line) other than the unit's XE",
               grid=lambda h: [{"XE": h["xe"] * f} for f in (1.0, 0.6, 1.6, 0.35, 2.5)] if h.get("xe", 0) > 0
               else [{"XE": v} for v in (0.1, 0.2, 0.4, 0.7)],
               at_no_load=False, frees_grid=True,
               separating={"saturation": "a step at another operating point (P or Q): a wrong grid reactance "
                                         "changes the swing mode and Q's share of the step, saturation the "
                                         "field's level"}),
        Effect("pss", ("PSS_KS", "PSS_T1", "PSS_T2", "PSS_T3", "PSS_T4"),
               {"PSS_KS": (0.0, 150.0), "PSS_T1": (0.01, 2.0), "PSS_T2": (0.01, 2.0), "PSS_T3": (0.01, 2.0),
                "PSS_T4": (0.01, 2.0)},
               "an active power system stabiliser (speed input: gain, two lead-lags, washout PSS_TW) the unit "
               "file does not have",
               # two equal stages of a textbook range (lead 0.1 .. 0.5 s, lag 0.03 .. 0.1 s; no lead),
               # gains a decade apart: a stabiliser's usual lead is up to ~110 degrees at the swing
               grid=lambda h: [{"PSS_KS": k, "PSS_T1": t1, "PSS_T2": t2, "PSS_T3": t1, "PSS_T4": t2}
                               for k in (3.0, 10.0, 30.0)
                               for t1, t2 in ((0.3, 0.03), (0.1, 0.05), (0.5, 0.1), (0.1, 0.1))],
               at_no_load=False, frees_grid=True,
               separating={"grid_reactance": "the same step with the stabiliser switched off (or its output "
                                             "recorded): a stabiliser acts through the speed only",
                           "transducer_lag": "the same step with the stabiliser switched off (or its output "
                                             "recorded): a stabiliser acts through the speed only"}),
    ]
}

#: every effect the diagnosis knows, by name: the kernel's and the grid's
VOCABULARY: dict[str, Effect] = {**EFFECTS, **GRID_EFFECTS}


def vocabulary(on_line: bool, fitted_grid: tuple[str, ...] | frozenset[str] = ()) -> tuple[str, ...]:
    """The effects the diagnosis tries on a record at no load or on line (`on_line`); an effect
    whose [grid] values the unit already fits (`fitted_grid`) is no effect there."""
    return tuple(e.name for e in VOCABULARY.values()
                 if (e.on_line if on_line else e.at_no_load) and not set(e.params) & set(fitted_grid))


#: the test for two effects that explain a capture equally well when neither record names one
DEFAULT_TEST = "a step of another size and a record of the AVR input (the transducer output) beside efd"


def separating_test(a: str, b: str) -> str:
    """The test that would tell effects `a` and `b` apart (held by either record)."""
    return VOCABULARY[a].separating.get(b) or VOCABULARY[b].separating.get(a) or DEFAULT_TEST

EFFECT_NAMES = tuple(EFFECTS)


def effect(name: str) -> Effect:
    try:
        return EFFECTS[name]
    except KeyError:
        raise EffectError(f"unknown effect {name!r}; known effects: {', '.join(EFFECT_NAMES)}") from None
