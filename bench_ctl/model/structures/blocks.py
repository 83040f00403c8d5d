"""The records a structure is declared with, the ANDES way (`andes/models/exciter/esst1a.py`).

A structure lists its parameters (`Param`, keyword-only: name, unit, info, typical, bounds,
identify) and its blocks in diagram order, each block naming the parameters it uses. From the
blocks `declare` generates what used to be written by hand beside them, so that it cannot drift:
the kernel parameter each standard name drives (the column mapping), the kernel settings the
structure implies (a lead-lag it lacks: TA3 = TA4 = 1; a regulator whose ceilings scale with Vt:
VRVT = 1; ...), the lead-lags a record may bypass (both time constants 0) and the block diagram
`bench-ctl models NAME` prints.

The kernel's blocks (docs/model.md, "The standard structures"): a transducer, two lead-lags, a
regulator lag whose ceilings clamp the lag (non-windup) or its output (scaled by Vt, less KC*Ifd),
or (ESST5B) a regulator limited ahead of its lag with the commutation drop at the lag's input,
rate feedback, a DC exciter with saturation (or an AC exciter with its rectifier), ESST4B's
potential-source stage with two PI regulators and the output VB VM, and AC8B's PID regulator.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, kw_only=True)
class Param:
    """One parameter of a structure under its standard name."""
    name: str
    unit: str
    info: str
    typical: float
    #: default identification bounds (the typical range); None: not identified by default
    bounds: tuple[float, float] | None = None
    identify: bool = False
    #: why a parameter no block uses is kept (for the .dyr record, not simulated)
    note: str = ""


class Block:
    """A block of the diagram: the parameters it uses (standard name -> kernel parameter), the
    kernel settings it implies and its line of the diagram."""

    kind = ""

    def wiring(self) -> dict[str, str]:
        return {}

    def settings(self) -> dict[str, float]:
        return {}

    def line(self) -> str:
        raise NotImplementedError


@dataclass(frozen=True, kw_only=True)
class Transducer(Block):
    T: str
    kind = "transducer"

    def wiring(self) -> dict[str, str]:
        return {self.T: "TR"}

    def line(self) -> str:
        return f"Vc = Vt / (1 + s {self.T})"


@dataclass(frozen=True, kw_only=True)
class InputLimit(Block):
    """The error limiter of the ST exciters: part of the record, not simulated (it acts far
    above a pulse test's error)."""
    upper: str
    lower: str
    feedback: bool = True
    kind = "input limiter"

    def line(self) -> str:
        vf = " - VF" if self.feedback else ""
        return f"Vi = Vref - Vc{vf}, limited to [{self.lower}, {self.upper}] (record only)"


@dataclass(frozen=True, kw_only=True)
class LeadLag(Block):
    """(1 + s lead)/(1 + s lag); the first one declared is the kernel's TA1/TA2, the second
    TA3/TA4. `bypass`: both time constants 0 (a record's way of saying "none") is run as 1, 1."""
    lead: str
    lag: str
    bypass: bool = True
    slot: int = 0          # set by `declare`
    kind = "lead-lag"

    def kernel_pair(self) -> tuple[str, str]:
        return ("TA1", "TA2") if self.slot == 0 else ("TA3", "TA4")

    def wiring(self) -> dict[str, str]:
        a, b = self.kernel_pair()
        return {self.lead: a, self.lag: b}

    def line(self) -> str:
        return f"(1 + s {self.lead})/(1 + s {self.lag})"


@dataclass(frozen=True, kw_only=True)
class RegulatorLag(Block):
    """gain/(1 + s T) with its ceilings: a non-windup limit on the lag, or (output_clamp) a clamp
    of its output; the ceilings scaled by Vt (vt_scaled, a bus-fed exciter) and the upper one less
    kc*Ifd. None leaves the kernel's setting to the effects (the reference structure's ceiling is
    the diagnosis' ceiling_limit)."""
    gain: str | None
    T: str
    upper: str | None = None
    lower: str | None = None
    vt_scaled: bool | None = None
    output_clamp: bool | None = None
    kc: str | None = None
    #: the kernel's KC belongs to another block (an AC exciter's rectifier): no commutation drop
    #: here, and KC not set to 0 either
    kc_elsewhere: bool = False
    kind = "regulator lag"

    def wiring(self) -> dict[str, str]:
        out = {self.T: "TE"}
        if self.gain:
            out[self.gain] = "KAVR"
        if self.upper:
            out[self.upper] = "VRMAX"
        if self.lower:
            out[self.lower] = "VRMIN"
        if self.kc:
            out[self.kc] = "KC"
        return out

    def settings(self) -> dict[str, float]:
        out: dict[str, float] = {}
        if self.gain is None:
            out["KAVR"] = 1.0
        if self.vt_scaled is not None:
            out["VRVT"] = float(self.vt_scaled)
        if self.output_clamp is not None:
            out["LIMOUT"] = float(self.output_clamp)
        if self.upper is not None and self.kc is None and not self.kc_elsewhere:
            out["KC"] = 0.0
        return out

    def line(self) -> str:
        gain = f"{self.gain}/" if self.gain else "1/"
        head = f"VR = {gain}(1 + s {self.T})"
        if self.upper is None:
            return head + ", no ceiling of its own"
        vt = "Vt " if self.vt_scaled else ""
        drop = f" - {self.kc} Ifd" if self.kc else ""
        if self.output_clamp:
            return (f"{head}; Efd = VR clamped to [{vt}{self.lower}, {vt}{self.upper}{drop}] "
                    "(the lag itself is not limited)")
        return f"{head}, non-windup {vt}{self.lower} <= VR <= {vt}{self.upper}{drop}"


@dataclass(frozen=True, kw_only=True)
class LimitedRegulator(Block):
    """The ST5B regulator: the gain's output limited to [lower, upper], less kc*Ifd (the
    commutation drop at the lag's input, not on the ceiling), drives the lag, whose non-windup
    ceilings are Vt*lower, Vt*upper; the first lead-lag's output is limited to [lower, upper]/gain."""
    gain: str
    T: str
    upper: str
    lower: str
    kc: str
    kind = "regulator lag"

    def wiring(self) -> dict[str, str]:
        return {self.gain: "KAVR", self.T: "TE", self.upper: "VRMAX", self.lower: "VRMIN", self.kc: "KC"}

    def settings(self) -> dict[str, float]:
        return {"VRIN": 1.0, "VRVT": 1.0, "LIMOUT": 0.0}

    def line(self) -> str:
        return (f"VR = {self.gain} y limited to [{self.lower}, {self.upper}] (y: the second lead-lag's "
                f"output; the first's limited to [{self.lower}, {self.upper}]/{self.gain}); "
                f"Efd = (VR - {self.kc} Ifd)/(1 + s {self.T}), non-windup Vt {self.lower} <= Efd <= "
                f"Vt {self.upper}")


@dataclass(frozen=True, kw_only=True)
class RateFeedback(Block):
    K: str
    T: str
    source: str = "VA"
    kind = "rate feedback"

    def wiring(self) -> dict[str, str]:
        return {self.K: "KF", self.T: "TF"}

    def line(self) -> str:
        return f"VF = s {self.K}/(1 + s {self.T}) {self.source}"


@dataclass(frozen=True, kw_only=True)
class DCExciter(Block):
    T: str
    KE: str
    E1: str
    SE1: str
    E2: str
    SE2: str
    kind = "DC exciter"

    def wiring(self) -> dict[str, str]:
        return {self.T: "TEX", self.KE: "KE", self.E1: "E1", self.SE1: "SE1", self.E2: "E2", self.SE2: "SE2"}

    def line(self) -> str:
        return (f"{self.T} dEfd/dt = VR - ({self.KE} + SE(Efd)) Efd,  SE(Efd) Efd = B (Efd - A)^2 through "
                f"({self.E1}, {self.SE1}), ({self.E2}, {self.SE2})")


@dataclass(frozen=True, kw_only=True)
class ACExciter(Block):
    """A rotating AC exciter with a diode rectifier (IEEE 421.5 AC1A family): the DC exciter's
    integrator on VE with the demagnetising KD Ifd in its feedback, and the rectifier's
    regulation FEX(KC Ifd / VE) on its output."""
    T: str
    KE: str
    KD: str
    KC: str
    E1: str
    SE1: str
    E2: str
    SE2: str
    kind = "AC exciter"

    def wiring(self) -> dict[str, str]:
        return {self.T: "TEX", self.KE: "KE", self.KD: "KD", self.KC: "KC", self.E1: "E1", self.SE1: "SE1",
                self.E2: "E2", self.SE2: "SE2"}

    def settings(self) -> dict[str, float]:
        return {"ACEX": 1.0}

    def line(self) -> str:
        return (f"{self.T} dVE/dt = VR - VFE,  VFE = {self.KE} VE + SE(VE) VE + {self.KD} Ifd,  SE(VE) VE = "
                f"B (VE - A)^2 through ({self.E1}, {self.SE1}), ({self.E2}, {self.SE2});  Efd = VE FEX(IN), "
                f"IN = {self.KC} Ifd / VE (FEX: 1 - 0.577 IN to 0.433, sqrt(0.75 - IN^2) to 0.75, "
                "1.732 (1 - IN) to 1)")


@dataclass(frozen=True, kw_only=True)
class PIRegulator(Block):
    """The voltage regulator of a potential-source exciter: a PI in the first lead-lag's place."""
    KP: str
    KI: str
    upper: str
    lower: str
    kind = "PI regulator"

    def wiring(self) -> dict[str, str]:
        return {self.KP: "KPI", self.KI: "KII", self.upper: "VPMAX", self.lower: "VPMIN"}

    def line(self) -> str:
        return (f"VR = ({self.KP} + {self.KI}/s)(Vref - Vc), limited to [{self.lower}, {self.upper}] "
                "(anti-windup by tracking)")


@dataclass(frozen=True, kw_only=True)
class PIDRegulator(Block):
    """The AC8B voltage regulator: a PID in the first lead-lag's place, its derivative filtered by
    TD (the kernel's second state then holds that filter: a structure with a PID has no second
    lead-lag)."""
    KP: str
    KI: str
    KD: str
    TD: str
    upper: str | None = None
    lower: str | None = None
    kind = "PID regulator"

    def wiring(self) -> dict[str, str]:
        out = {self.KP: "KPI", self.KI: "KII", self.KD: "KDR", self.TD: "TDR"}
        if self.upper:
            out[self.upper] = "VPMAX"
        if self.lower:
            out[self.lower] = "VPMIN"
        return out

    def line(self) -> str:
        lim = (f", limited to [{self.lower}, {self.upper}] (anti-windup by tracking)" if self.upper
               else " (no limits of its own)")
        return f"VPID = ({self.KP} + {self.KI}/s + s {self.KD}/(1 + s {self.TD}))(Vref - Vc){lim}"


@dataclass(frozen=True, kw_only=True)
class FieldVoltagePI(Block):
    KP: str
    KI: str
    upper: str
    lower: str
    KG: str
    kind = "field-voltage PI"

    def wiring(self) -> dict[str, str]:
        return {self.KP: "KPM", self.KI: "KIM", self.upper: "VMMAX", self.lower: "VMMIN", self.KG: "KG"}

    def line(self) -> str:
        return (f"VM = ({self.KP} + {self.KI}/s)(VA - {self.KG} Efd), limited to [{self.lower}, {self.upper}] "
                "(anti-windup by tracking)")


@dataclass(frozen=True, kw_only=True)
class PotentialSource(Block):
    """Output VB VM, VB = KP Vt FEX(KC Ifd / (KP Vt)) at most VBMAX (at no load)."""
    KP: str
    VBMAX: str
    KC: str
    kind = "potential source"

    def wiring(self) -> dict[str, str]:
        return {self.KP: "KPV", self.VBMAX: "VBMAX", self.KC: "KC"}

    def line(self) -> str:
        return (f"Efd = VB VM, VB = VE FEX(IN) <= {self.VBMAX}, VE = {self.KP} Vt (no load), "
                f"IN = {self.KC} Ifd / VE; FEX = 1 - 0.577 IN (IN <= 0.433), sqrt(0.75 - IN^2) (<= 0.75), "
                "1.732 (1 - IN) (<= 1), 0")


def generate(blocks: tuple[Block, ...]) -> tuple[tuple[Block, ...], dict[str, str], dict[str, float],
                                                 tuple[tuple[str, str], ...], tuple[str, ...]]:
    """(blocks with their lead-lag slots, standard name -> kernel parameter, kernel settings,
    bypassable lead-lag pairs, diagram lines) of `blocks` in diagram order."""
    placed: list[Block] = []
    slot = 0
    for b in blocks:
        if isinstance(b, LeadLag):
            if slot > 1:
                raise ValueError("the kernel has two lead-lags")
            b = LeadLag(lead=b.lead, lag=b.lag, bypass=b.bypass, slot=slot)
            slot += 1
        placed.append(b)
    wiring: dict[str, str] = {}
    settings: dict[str, float] = {}
    for b in placed:
        for name, kern in b.wiring().items():
            if name in wiring or kern in wiring.values():
                raise ValueError(f"{name} -> {kern}: a standard name or kernel parameter wired twice")
            wiring[name] = kern
        settings.update(b.settings())
    if any(isinstance(b, PIDRegulator) for b in placed) and slot:
        raise ValueError("a PID regulator takes both lead-lags' states: no lead-lag beside it")
    for pair in (("TA1", "TA2"), ("TA3", "TA4"))[slot:]:     # the lead-lags it lacks: 1, 1
        settings.update(dict.fromkeys(pair, 1.0))
    if not any(isinstance(b, Transducer) for b in placed):
        settings["TR"] = 0.0
    clash = set(settings) & set(wiring.values())
    if clash:
        raise ValueError(f"kernel parameter(s) {sorted(clash)} both wired and set")
    lead_lags = tuple(b.kernel_pair() for b in placed if isinstance(b, LeadLag) and b.bypass)
    lines = tuple(f"{b.kind + ':':<18}{b.line()}" for b in placed)
    return tuple(placed), wiring, settings, lead_lags, lines
