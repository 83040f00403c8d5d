"""The diagnosis vocabulary: eight unmodelled effects, each an augmentation of the reference model.

Each effect names its parameters, their neutral values (the model without the effect), the
bounds a fit may search (physically sensible for a no-load pulse test of a static-excitation
unit), and any constraint between them. Names are fixed by docs/model.md ("The eight effects").
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from .params import PARAMS

_SCALED = re.compile(r"^\s*(\w+)\s*(>=|<=)\s*([0-9.]+)\s*\*\s*(\w+)\s*$")  # "S12 >= 1.44*S10"


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

    def neutral(self) -> dict[str, float]:
        return {p: PARAMS[p].neutral for p in self.params}  # type: ignore[misc]

    def check(self, values: dict[str, float]) -> None:
        unknown = set(values) - set(self.params) - set(self.options)
        if unknown:
            raise ValueError(
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
                raise ValueError(f"effect {self.name}: cannot read its constraint {text!r}")
            a, op, k, b = m.group(1), m.group(2), float(m.group(3)), m.group(4)
            lhs, rhs = float(values[a]), k * float(values[b])
            if not (lhs >= rhs if op == ">=" else lhs <= rhs):
                raise ValueError(f"effect {self.name}: {a} = {lhs:g} breaks {text} "
                                 f"({k:g}*{b} = {rhs:g}); give both parameters")


EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in [
        Effect("ceiling_limit", ("VRMAX", "VRMIN"),
               {"VRMAX": (1.5, 10.0), "VRMIN": (-10.0, 0.5), "VRVT": (0.0, 1.0), "KC": (0.0, 0.5)},
               "exciter output clamped by a non-windup limit; variants: the limits scale with Vt "
               "(VRVT = 1, a bus-fed static exciter), the upper one less KC*Ifd (commutation)",
               options=("VRVT", "KC")),
        Effect("dead_time", ("TD",), {"TD": (0.0, 0.1)},
               "pure delay in the control path (digital AVR + thyristor firing)"),
        Effect("transducer_lag", ("TR",), {"TR": (0.0, 0.2)},
               "terminal-voltage measurement lag"),
        Effect("saturation", ("S10", "S12"), {"S10": (0.0, 0.3), "S12": (0.0, 1.5)},
               "generator open-circuit saturation, Sat(x) = B (x - A)^2 for x > A",
               constraints=("S12 >= 1.44*S10",)),
        Effect("rate_limit", ("RATE",), {"RATE": (2.0, 500.0)},
               "slew limit on the exciter output"),
        Effect("setpoint_ramp", ("RAMP",), {"RAMP": (0.01, 10.0)},
               "the device ramps setpoint changes instead of stepping"),
        Effect("recorder_gain", ("GAIN",), {"GAIN": (0.8, 1.2)},
               "calibration error of the recorded efd channel", in_loop=False),
        Effect("time_skew", ("SKEW",), {"SKEW": (0.0, 0.05)},
               "efd channel recorded late relative to the usetp channel", in_loop=False),
    ]
}

EFFECT_NAMES = tuple(EFFECTS)


def effect(name: str) -> Effect:
    try:
        return EFFECTS[name]
    except KeyError:
        raise ValueError(f"unknown effect {name!r}; known effects: {', '.join(EFFECT_NAMES)}") from None
