"""The parameter catalogue of the reference unit and its effects (docs/model.md).

Names follow IEEE 421.5 / the reference paper. Every parameter the kernel knows has a fixed
column in the kernel's parameter matrix (`KERNEL_PARAMS` order); a `ParamInfo` carries its unit,
meaning and physically sensible range, like ANDES' `NumParam(info=..., vrange=...)`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from bench_ctl.exitcodes import BadInput


class ParamError(BadInput):
    """A parameter value outside its physical range; the message names it, its unit and range."""


@dataclass(frozen=True)
class ParamInfo:
    name: str
    unit: str
    info: str
    lo: float
    hi: float
    neutral: float | None = None  # the value that switches an effect off

    def check(self, value: float, where: str = "") -> None:
        if not (self.lo <= value <= self.hi) and not (self.neutral is not None and value == self.neutral):
            raise ParamError(
                f"{where}{self.name} = {value!r} {self.unit} is outside its physical range "
                f"[{self.lo}, {self.hi}] ({self.info})"
            )


INF = math.inf

_CATALOGUE = [
    # AVR (the paper's six)
    ParamInfo("KAVR", "pu/pu", "AVR proportional gain (AC8B's KA after a PID may be below 1)", 0.01, 5000.0),
    ParamInfo("TA1", "s", "AVR lead time constant 1", 0.0, 100.0),
    ParamInfo("TA2", "s", "AVR lag time constant 1", 0.0, 100.0),
    ParamInfo("TA3", "s", "AVR lead time constant 2", 0.0, 100.0),
    ParamInfo("TA4", "s", "AVR lag time constant 2", 0.0, 500.0),
    ParamInfo("TE", "s", "exciter / bridge time constant", 0.0, 5.0),
    # generator and steady state
    ParamInfo("Td0p", "s", "open-circuit d-axis transient time constant T'd0", 0.1, 30.0),
    ParamInfo("Td0pp", "s", "open-circuit d-axis subtransient time constant T''d0", 0.001, 1.0),
    ParamInfo("Vt0", "pu", "initial terminal voltage", 0.5, 1.3),
    ParamInfo("KPP", "1", "share of E'q in Vt at no load, (X''d - Xl)/(X'd - Xl) of a GENROU/GENSAL; "
                          "0: Vt = E''q (the reference model); > 0 also saturates on Vt = psi''",
              0.0, 1.0, 0.0),
    ParamInfo("KDA", "1", "damper coupling in the no-load field current, Ifd = E'q + KDA (E'q - E''q) + Sat; "
                          "(Xd - X'd)(X'd - X''d)/(X'd - Xl)^2 of a GENROU; 0 in the reference model",
              0.0, 50.0, 0.0),
    ParamInfo("SATEQ", "1", "1: saturation on E'q even with KPP > 0 (a GENSAL: its saturation is a function of "
                            "E'q, a GENROU's of psi'' = Vt at no load); 0 otherwise", 0.0, 1.0, 0.0),
    # effects (neutral value = effect off)
    ParamInfo("VRMAX", "pu", "exciter ceiling, upper (ceiling_limit)", 1.05, 50.0, INF),
    ParamInfo("VRMIN", "pu", "exciter ceiling, lower (ceiling_limit; a rotating exciter's regulator may stop above 0)",
              -20.0, 10.0, -INF),
    ParamInfo("VRVT", "1", "ceilings scale with terminal voltage, VRMAX*Vt and VRMIN*Vt (bus-fed static "
                           "exciter; ceiling_limit variant): 1 on, 0 off", 0.0, 1.0, 0.0),
    ParamInfo("KC", "pu", "rectifier loading factor: the upper ceiling drops by KC*Ifd (commutation; "
                          "ceiling_limit variant)", 0.0, 1.0, 0.0),
    ParamInfo("TD", "s", "dead time in the control path (dead_time)", 0.0, 0.2, 0.0),
    ParamInfo("TR", "s", "terminal-voltage transducer lag (transducer_lag)", 0.0, 0.5, 0.0),
    ParamInfo("S10", "pu", "open-circuit saturation at 1.0 pu (saturation)", 0.0, 0.5, 0.0),
    ParamInfo("S12", "pu", "open-circuit saturation at 1.2 pu (saturation)", 0.0, 2.0, 0.0),
    ParamInfo("RATE", "pu/s", "slew limit on the exciter output (rate_limit)", 1.0, 1.0e4, INF),
    ParamInfo("RAMP", "pu/s", "setpoint ramp rate of the device (setpoint_ramp)", 0.005, 100.0, INF),
    ParamInfo("GAIN", "1", "efd recorder channel gain (recorder_gain)", 0.5, 1.5, 1.0),
    ParamInfo("SKEW", "s", "efd channel recorded late vs usetp (time_skew)", 0.0, 0.2, 0.0),
    # blocks of the standard structures (bench_ctl.model.structures); neutral = block absent
    ParamInfo("KF", "pu", "rate-feedback gain: KF s/(1 + s TF) from the regulator (ST) or exciter (DC) "
                          "output to the summing junction", 0.0, 1.0, 0.0),
    ParamInfo("TF", "s", "rate-feedback time constant", 0.01, 20.0, 1.0),
    ParamInfo("TEX", "s", "DC exciter time constant: TEX dEfd/dt = VR - (KE + SE(Efd)) Efd; 0 = no DC "
                          "exciter (the regulator output is Efd)", 0.0, 10.0, 0.0),
    ParamInfo("KE", "pu", "DC exciter self-excitation constant", -1.0, 2.0, 1.0),
    ParamInfo("E1", "pu", "DC exciter saturation: first Efd point", 0.0, 20.0, 0.0),
    ParamInfo("SE1", "pu", "DC exciter saturation SE(E1)", 0.0, 5.0, 0.0),
    ParamInfo("E2", "pu", "DC exciter saturation: second Efd point", 0.0, 20.0, 0.0),
    ParamInfo("SE2", "pu", "DC exciter saturation SE(E2)", 0.0, 5.0, 0.0),
    ParamInfo("ACEX", "1", "AC exciter (1, with TEX > 0): that exciter's state is VE, the field voltage "
                           "VE FEX(KC Ifd / VE) (IEEE 421.5 rectifier regulation, KC then not on the ceiling), "
                           "its feedback VFE = KE VE + SE(VE) VE + KD Ifd, which the rate feedback takes; "
                           "0: a DC exciter", 0.0, 1.0, 0.0),
    ParamInfo("KD", "pu", "AC exciter demagnetising factor: KD Ifd in VFE", 0.0, 5.0, 0.0),
    ParamInfo("LIMOUT", "1", "ceilings clamp the output (1: the regulator lag itself is not limited, as "
                             "ESST1A/EXST1) instead of a non-windup limit on the lag (0)", 0.0, 1.0, 0.0),
    ParamInfo("VRIN", "1", "the ST5B regulator (1): its output KAVR y limited to [VRMIN, VRMAX], less KC*Ifd, is "
                           "the regulator lag's input (whose non-windup ceilings carry no KC), and the first "
                           "lead-lag's output is limited to [VRMIN, VRMAX]/KAVR; 0: off", 0.0, 1.0, 0.0),
    # the potential-source static exciter (ESST4B): a PI regulator in place of the first lead-lag,
    # an inner field-voltage PI with feedback KG, and the output VB * VM, VB = KPV Vt FEX(KC Ifd /
    # (KPV Vt)) (IEEE 421.5 rectifier regulation); KPV = 0: no such stage (the blocks above)
    ParamInfo("KPV", "pu", "potential-source gain KP: the output is VB VM with VB = KP Vt FEX(IN) "
                           "(ESST4B); 0 = no potential-source stage", 0.0, 20.0, 0.0),
    ParamInfo("VBMAX", "pu", "upper limit of VB (ESST4B)", 0.1, 100.0, INF),
    ParamInfo("KPI", "pu", "proportional gain of the PI regulator that replaces the first lead-lag "
                           "when KPV > 0 (ESST4B KPR) or when it, KII or KDR is > 0 (AC8B KPR)", 0.0, 1000.0, 0.0),
    ParamInfo("KII", "pu/s", "integral gain of that PI regulator (ESST4B KIR)", 0.0, 1000.0, 0.0),
    ParamInfo("VPMAX", "pu", "upper limit of that PI regulator (ESST4B VRMAX)", -20.0, 20.0, INF),
    ParamInfo("VPMIN", "pu", "lower limit of that PI regulator (ESST4B VRMIN)", -20.0, 20.0, -INF),
    ParamInfo("KPM", "pu", "proportional gain of the inner field-voltage PI (ESST4B)", 0.0, 100.0, 1.0),
    ParamInfo("KIM", "pu/s", "integral gain of the inner field-voltage PI (ESST4B; 0: its integrator "
                             "holds the steady-state share)", 0.0, 100.0, 0.0),
    ParamInfo("VMMAX", "pu", "upper limit of the inner PI (ESST4B)", -20.0, 20.0, INF),
    ParamInfo("VMMIN", "pu", "lower limit of the inner PI (ESST4B)", -20.0, 20.0, -INF),
    ParamInfo("KG", "pu", "feedback gain of the field voltage into the inner PI (ESST4B)", 0.0, 1.1, 0.0),
    # the derivative of the PID regulator (AC8B): the PI above without the potential-source stage,
    # plus KDR s/(1 + s TDR) of the error inside its limits
    ParamInfo("KDR", "pu s", "derivative gain of the PID regulator, KDR s/(1 + s TDR) of the error added to the "
                             "PI's sum (AC8B); 0 = no derivative", 0.0, 1000.0, 0.0),
    ParamInfo("TDR", "s", "time constant of the PID regulator's derivative filter (AC8B)", 0.001, 10.0, 1.0),
    # record timing, not the model: fitted instant of setpoint edge N minus the sample where the
    # record first shows it (bench_ctl.signals.edges); 0 = the kernel's zero-order hold
    *(ParamInfo(f"EDGE{i}", "s", f"setpoint edge {i}: fitted instant minus its nominal sample (record timing)",
                -1.0, 1.0, 0.0) for i in range(1, 5)),
]

PARAMS: dict[str, ParamInfo] = {p.name: p for p in _CATALOGUE}

#: Column order of the kernel's parameter matrix.
KERNEL_PARAMS: tuple[str, ...] = tuple(p.name for p in _CATALOGUE)
COL: dict[str, int] = {name: i for i, name in enumerate(KERNEL_PARAMS)}

AVR_PARAMS = ("KAVR", "TA1", "TA2", "TA3", "TA4", "TE")
GENERATOR_PARAMS = ("Td0p", "Td0pp", "Vt0")
#: generator constants a unit file may give (neutral when absent)
GENERATOR_OPTIONAL = ("KPP", "KDA", "SATEQ")
#: blocks of the standard structures beyond the reference one (neutral: the block is absent)
STRUCTURE_PARAMS = ("KPP", "KDA", "SATEQ", "KF", "TF", "TEX", "KE", "E1", "SE1", "E2", "SE2", "ACEX", "KD",
                    "LIMOUT", "VRIN",
                    "KPV", "VBMAX", "KPI", "KII", "VPMAX", "VPMIN", "KPM", "KIM", "VMMAX", "VMMIN", "KG",
                    "KDR", "TDR")
#: parameters of the record's timing rather than of the unit (never in a unit file or a .dyr)
RECORD_PARAMS = ("EDGE1", "EDGE2", "EDGE3", "EDGE4")

#: the machine on the grid (the engine's grid machine; a unit's [grid]): its data beside the kernel's
#: T'd0, T''d0, S(1.0), S(1.2), Vt0, the grid to the infinite bus and the operating point
MACHINE_CATALOGUE: tuple[ParamInfo, ...] = (
    ParamInfo("XD", "pu", "d-axis synchronous reactance Xd", 0.2, 4.0),
    ParamInfo("XQ", "pu", "q-axis synchronous reactance Xq", 0.2, 4.0),
    ParamInfo("XDP", "pu", "d-axis transient reactance X'd", 0.05, 1.5),
    ParamInfo("XQP", "pu", "q-axis transient reactance X'q", 0.05, 4.0),
    ParamInfo("XDPP", "pu", "subtransient reactance X''d = X''q", 0.02, 1.0),
    ParamInfo("XLS", "pu", "stator leakage reactance Xl (PSS/E's Xl; XL is ESST4B's)", 0.0, 0.5),
    ParamInfo("Tq0p", "s", "open-circuit q-axis transient time constant T'q0", 0.01, 10.0),
    ParamInfo("Tq0pp", "s", "open-circuit q-axis subtransient time constant T''q0", 0.001, 1.0),
    ParamInfo("H", "s", "inertia constant (machine base)", 0.1, 20.0),
    ParamInfo("DAMP", "pu", "speed damping D of the swing equation", 0.0, 50.0),
    ParamInfo("RA", "pu", "stator resistance", 0.0, 0.05),
    ParamInfo("XE", "pu", "grid reactance to the infinite bus (step-up transformer + line, machine base)", 0.0, 2.0),
    ParamInfo("RE", "pu", "grid resistance to the infinite bus (machine base)", 0.0, 0.5),
    ParamInfo("P0", "pu", "active power before the test (machine base)", -0.2, 1.2),
    ParamInfo("Q0", "pu", "reactive power before the test (machine base)", -1.0, 1.0),
    ParamInfo("FN", "Hz", "nominal frequency", 45.0, 65.0),
    # the unit's power system stabiliser on line (IEEEST on the rotor speed, without its filters)
    ParamInfo("PSS_KS", "pu", "stabiliser gain KS on the speed deviation (0: no stabiliser)", 0.0, 200.0),
    ParamInfo("PSS_T1", "s", "stabiliser first lead-lag, lead T1", 0.0, 10.0),
    ParamInfo("PSS_T2", "s", "stabiliser first lead-lag, lag T2", 0.001, 10.0),
    ParamInfo("PSS_T3", "s", "stabiliser second lead-lag, lead T3", 0.0, 10.0),
    ParamInfo("PSS_T4", "s", "stabiliser second lead-lag, lag T4", 0.001, 10.0),
    ParamInfo("PSS_TW", "s", "stabiliser washout T5 = T6", 0.1, 60.0),
    ParamInfo("PSS_LSMAX", "pu", "stabiliser output limit, +-LSMAX", 0.0, 0.5),
    # which stabiliser the unit carries (bench_ctl.model.stabilisers: `bench-ctl models PSS2B`); a
    # unit file or --set may give its name
    ParamInfo("PSS_MODEL", "1", "the stabiliser's model: 1 IEEEST (the PSS_* values), 2 PSS2A, 3 PSS2B "
                                "(the PSS2_* values)", 1.0, 3.0),
    # PSS2A / PSS2B: input 1 the rotor speed deviation, input 2 the electrical power (PSS/E's names)
    ParamInfo("PSS2_KS1", "pu", "PSS2A/PSS2B gain KS1 (0: no stabiliser)", 0.0, 200.0),
    ParamInfo("PSS2_TW1", "s", "PSS2A/PSS2B input 1 (speed), first washout TW1 (0: bypassed)", 0.0, 60.0),
    ParamInfo("PSS2_TW2", "s", "PSS2A/PSS2B input 1 (speed), second washout TW2 (0: bypassed)", 0.0, 60.0),
    ParamInfo("PSS2_T6", "s", "PSS2A/PSS2B input 1 (speed), transducer lag T6 (0: none)", 0.0, 10.0),
    ParamInfo("PSS2_TW3", "s", "PSS2A/PSS2B input 2 (power), first washout TW3 (0: bypassed)", 0.0, 60.0),
    ParamInfo("PSS2_TW4", "s", "PSS2A/PSS2B input 2 (power), second washout TW4 (0: bypassed)", 0.0, 60.0),
    ParamInfo("PSS2_T7", "s", "PSS2A/PSS2B input 2 (power), integrator lag T7 (0: the gain KS2 alone)", 0.0, 20.0),
    ParamInfo("PSS2_KS2", "pu", "PSS2A/PSS2B input 2 gain KS2 (typically T7 / 2H)", 0.0, 20.0),
    ParamInfo("PSS2_KS3", "pu", "PSS2A/PSS2B gain KS3 of input 2 into the ramp-tracking filter", 0.0, 20.0),
    ParamInfo("PSS2_T8", "s", "PSS2A/PSS2B ramp-tracking filter [(1 + s T8)/(1 + s T9)^M]^N: lead T8", 0.0, 10.0),
    ParamInfo("PSS2_T9", "s", "PSS2A/PSS2B ramp-tracking filter: lag T9 (> 0 when M N > 0)", 0.0, 10.0),
    ParamInfo("PSS2_M", "1", "PSS2A/PSS2B ramp-tracking filter: lags per section M (an integer, M N <= 8; "
                             "M = 0 or N = 0: no filter)", 0.0, 8.0),
    ParamInfo("PSS2_N", "1", "PSS2A/PSS2B ramp-tracking filter: sections N (an integer, M N <= 8)", 0.0, 8.0),
    ParamInfo("PSS2_T1", "s", "PSS2A/PSS2B first lead-lag, lead T1", 0.0, 10.0),
    ParamInfo("PSS2_T2", "s", "PSS2A/PSS2B first lead-lag, lag T2 (0 with T1 = 0: bypassed)", 0.0, 10.0),
    ParamInfo("PSS2_T3", "s", "PSS2A/PSS2B second lead-lag, lead T3", 0.0, 10.0),
    ParamInfo("PSS2_T4", "s", "PSS2A/PSS2B second lead-lag, lag T4 (0 with T3 = 0: bypassed)", 0.0, 10.0),
    ParamInfo("PSS2_T10", "s", "PSS2B third lead-lag, lead T10", 0.0, 10.0),
    ParamInfo("PSS2_T11", "s", "PSS2B third lead-lag, lag T11 (0 with T10 = 0: bypassed, as PSS2A)", 0.0, 10.0),
    ParamInfo("PSS2_VS1MAX", "pu", "PSS2B input 1 upper limit VS1MAX (on the speed deviation)", -1000.0, 1000.0,
              INF),
    ParamInfo("PSS2_VS1MIN", "pu", "PSS2B input 1 lower limit VS1MIN", -1000.0, 1000.0, -INF),
    ParamInfo("PSS2_VS2MAX", "pu", "PSS2B input 2 upper limit VS2MAX (on the electrical power itself)", -1000.0,
              1000.0, INF),
    ParamInfo("PSS2_VS2MIN", "pu", "PSS2B input 2 lower limit VS2MIN", -1000.0, 1000.0, -INF),
    ParamInfo("PSS2_VSTMAX", "pu", "PSS2A/PSS2B output upper limit VSTMAX", 0.0, 1.0),
    ParamInfo("PSS2_VSTMIN", "pu", "PSS2A/PSS2B output lower limit VSTMIN", -1.0, 0.0),
)
MACHINE_PARAMS: tuple[str, ...] = tuple(p.name for p in MACHINE_CATALOGUE)
MCOL: dict[str, int] = {name: i for i, name in enumerate(MACHINE_PARAMS)}

#: what a machine on the grid takes when not given
MACHINE_DEFAULTS: dict[str, float] = {"RA": 0.0, "RE": 0.0, "DAMP": 0.0, "FN": 50.0, "PSS_KS": 0.0,
                                      "PSS_T1": 1.0, "PSS_T2": 1.0, "PSS_T3": 1.0, "PSS_T4": 1.0, "PSS_TW": 10.0,
                                      "PSS_LSMAX": 0.1, "PSS_MODEL": 1.0,
                                      # PSS2A/PSS2B: off (KS1 0); the rest typical values (OpenIPSL's
                                      # PSS2B defaults but KS2 1 and T10 = T11 = 0), no input limits
                                      "PSS2_KS1": 0.0, "PSS2_TW1": 10.0, "PSS2_TW2": 10.0, "PSS2_T6": 0.0,
                                      "PSS2_TW3": 10.0, "PSS2_TW4": 0.0, "PSS2_T7": 10.0, "PSS2_KS2": 1.0,
                                      "PSS2_KS3": 1.0, "PSS2_T8": 0.5, "PSS2_T9": 0.1, "PSS2_M": 5.0, "PSS2_N": 1.0,
                                      "PSS2_T1": 0.15, "PSS2_T2": 0.025, "PSS2_T3": 0.15, "PSS2_T4": 0.025,
                                      "PSS2_T10": 0.0, "PSS2_T11": 0.0, "PSS2_VS1MAX": INF, "PSS2_VS1MIN": -INF,
                                      "PSS2_VS2MAX": INF, "PSS2_VS2MIN": -INF, "PSS2_VSTMAX": 0.1,
                                      "PSS2_VSTMIN": -0.1}
#: what a unit needs in [grid] (or a .dyr generator record, --set) to run on line, beside P0, Q0 of the record
MACHINE_DATA = ("XD", "XQ", "XDP", "XQP", "XDPP", "XLS", "Tq0p", "Tq0pp", "H")

#: Reference values of the simulated unit (docs/model.md).
REFERENCE_VALUES: dict[str, float] = {
    "KAVR": 200.0, "TA1": 1.0, "TA2": 0.2, "TA3": 0.5, "TA4": 10.0, "TE": 0.02,
    "Td0p": 7.5, "Td0pp": 0.05, "Vt0": 1.0,
}

#: Suggested identification bounds (docs/model.md).
REFERENCE_BOUNDS: dict[str, tuple[float, float]] = {
    "KAVR": (50.0, 800.0), "TA1": (0.05, 5.0), "TA2": (0.01, 2.0),
    "TA3": (0.05, 5.0), "TA4": (1.0, 50.0), "TE": (0.002, 0.2),
}

REFERENCE_CONSTRAINTS = ("TA2 <= TA1", "TA4 >= TA2")


def neutral_values() -> dict[str, float]:
    """Every effect parameter at its neutral value (the model without effects)."""
    return {p.name: p.neutral for p in _CATALOGUE if p.neutral is not None}
