"""The engine's layout: the derived-parameter columns (`D_*`), the rows of a chunk's state and
readout arrays, the per-candidate block bits, and the engine's constants.

`derive` turns a parameter matrix into one row of derived factors per candidate; the compiled code
reads them transposed, `D[D_NAME, c]`. The columns are declared by the parts that read them, in
order: the excitation system and the effects (`EXCITER`), the machine on the grid (`GRID`), the
stabiliser (`STABILISER`); `D_NAME` (its first column) and `N_DERIVED` are generated from them,
so a column is added in one place. The parameter matrix's own columns are `P_NAME`.
"""
from __future__ import annotations

from bench_ctl.model.params import KERNEL_PARAMS, RECORD_PARAMS

#: (name, columns, meaning): the excitation system, the no-load generator and the effects
EXCITER: tuple[tuple[str, int, str], ...] = (
    ("KAVR", 1, "AVR gain"),
    ("R1", 1, "lead-lag 1: TA1 / TA2 (0 where the PI regulator replaces it)"),
    ("IT2", 1, "lead-lag 1: 1 / TA2 (0 where the PI regulator replaces it)"),
    ("R2", 1, "lead-lag 2: TA3 / TA4 (1 with the PID: bypassed)"),
    ("IT4", 1, "lead-lag 2: 1 / TA4 (the PID's derivative filter: 1 / TDR)"),
    ("ITE", 1, "regulator lag: 1 / TE"),
    ("ITR", 1, "transducer lag: 1 / TR, 0 without one"),
    ("ITD0P", 1, "generator: 1 / T'd0"),
    ("ITD0PP", 1, "generator: 1 / T''d0"),
    ("SATA", 1, "generator saturation B (x - A)^2: A"),
    ("SATB", 1, "generator saturation: B"),
    ("VRMAX", 1, "ceiling, upper"),
    ("VRMIN", 1, "ceiling, lower"),
    ("TD", 1, "dead time (s)"),
    ("RATE", 1, "slew limit of the regulator lag (pu/s)"),
    ("RAMP", 1, "setpoint ramp rate (pu/s)"),
    ("GAIN", 1, "recorder gain of efd"),
    ("SKEW", 1, "recorder skew of efd (s)"),
    ("VT0", 1, "terminal voltage at the steady state"),
    ("EFD0", 1, "regulator lag output at the steady state (clamped to the ceilings)"),
    ("E0", 1, "lead-lag states at the steady state: EFD0 / KAVR"),
    ("UREF0", 1, "voltage reference at the steady state"),
    ("VALID", 1, "1 when the parameters are valid, else 0 (failed at step 0)"),
    ("TRON", 1, "1 with a transducer lag"),
    ("TDON", 1, "1 with a dead time"),
    ("VRVT", 1, "1: the ceilings scale with Vt (bus-fed)"),
    ("KC", 1, "commutation: the upper ceiling less KC Ifd"),
    ("EDGE0", len(RECORD_PARAMS), "offset of setpoint edge `slot` (s): column D_EDGE0 + slot"),
    ("KFT", 1, "rate feedback: KF / TF"),
    ("ITF", 1, "rate feedback: 1 / TF"),
    ("ITEX", 1, "DC exciter: 1 / TEX"),
    ("DCON", 1, "1 with a DC exciter"),
    ("KE", 1, "DC exciter: KE"),
    ("SEA", 1, "DC exciter saturation B (Efd - A)^2: A"),
    ("SEB", 1, "DC exciter saturation: B"),
    ("LIMOUT", 1, "1: the ceilings clamp the output rather than the lag"),
    ("OUT0", 1, "the field voltage (the engine's output) at the steady state"),
    ("VRIN", 1, "1: the ST5B regulator, its output limited to [VRMIN, VRMAX] less KCIN Ifd drives the lag"),
    ("KCIN", 1, "ST5B: KC, the commutation drop at the regulator lag's input (0 elsewhere; D_KC is then 0)"),
    ("VR0", 1, "the regulator output KAVR y at the steady state (the dead time's history before the record)"),
    ("KPP", 1, "share of E'q in Vt (GENROU-like flux)"),
    ("SATVT", 1, "1: saturation on Vt rather than E'q (KPP > 0)"),
    ("KDA", 1, "damper coupling in the field current"),
    ("ST4", 1, "1 with the potential-source stage"),
    ("P1", 1, "PI regulator in place of lead-lag 1 (the potential-source stage's, or the PID's): KPI"),
    ("KI1", 1, "PI regulator: integral gain KII"),
    ("Y1MAX", 1, "PI regulator: upper limit (+inf without)"),
    ("Y1MIN", 1, "PI regulator: lower limit (-inf without)"),
    ("KPV", 1, "potential source: KP (1 without)"),
    ("VBMAX", 1, "potential source: VBMAX (+inf without)"),
    ("KPM", 1, "inner PI: proportional gain"),
    ("KIM", 1, "inner PI: integral gain"),
    ("VMMAX", 1, "inner PI: upper limit"),
    ("VMMIN", 1, "inner PI: lower limit"),
    ("KG", 1, "inner loop feedback gain KG"),
    ("XF0", 1, "the rate feedback's state (or the inner integrator's) at the steady state"),
    ("ACON", 1, "1 with an AC exciter: Efd = VE FEX(KCAC Ifd / VE), VFE = KE VE + SE(VE) + KD Ifd"),
    ("KD", 1, "AC exciter: KD, the demagnetising Ifd in VFE"),
    ("KCAC", 1, "AC exciter: KC of the rectifier's FEX (D_KC is then 0)"),
    ("XE0", 1, "the rotating exciter's state at the steady state: the DC exciter's Efd or the AC exciter's VE"),
    ("OUTK", 1, "the output's slope per the exciter state's: 1 (DC), FEX at the steady state (AC)"),
    ("PID", 1, "1: lead-lag 2's state is the PID's derivative filter (it follows the error at 1 / TDR)"),
    ("KDT", 1, "PID regulator: KDR / TDR, the derivative's gain on (error - its filtered value)"),
    ("X20", 1, "lead-lag 2's state at the steady state (E0), or the derivative filter's (0)"),
    ("BITS", 1, "what the candidate needs of the engine: the B_* bits (0 for an invalid candidate)"),
)

#: the machine on the grid (`machines.grid`): a GENROU or GENSAL through RE + j XE to an infinite bus
GRID: tuple[tuple[str, int, str], ...] = (
    ("GD1", 1, "(X''d - Xl) / (X'd - Xl)"),
    ("GQ1", 1, "(X''q - Xl) / (X'q - Xl) (0 for a GENSAL)"),
    ("GD2", 1, "(X'd - X''d) / (X'd - Xl)^2"),
    ("GQ2", 1, "(X'q - X''q) / (X'q - Xl)^2 (0 for a GENSAL)"),
    ("GQD", 1, "(Xq - Xl) / (Xd - Xl): the q-axis share of the saturation (0 for a GENSAL)"),
    ("XD", 1, "Xd"), ("XQ", 1, "Xq"), ("XDP", 1, "X'd"), ("XQP", 1, "X'q (Xq for a GENSAL)"),
    ("XDPP", 1, "X''d = X''q"), ("XL", 1, "Xl"),
    ("ITQ0P", 1, "1 / T'q0 (0 for a GENSAL)"), ("ITQ0PP", 1, "1 / T''q0"),
    ("IM", 1, "1 / (2 H)"), ("DAMP", 1, "speed damping D"), ("W0", 1, "2 pi fn"), ("RA", 1, "stator resistance"),
    ("GT", 1, "the path to the infinite bus as an admittance: conductance"), ("BT", 1, "its susceptance"),
    ("VINF", 1, "|infinite bus voltage|"), ("TM", 1, "mechanical power (pu)"),
    ("E1Q0", 1, "E'q at the operating point"), ("E2D0", 1, "psikd at the operating point"),
    ("E1D0", 1, "E'd at the operating point"), ("E2Q0", 1, "psikq at the operating point"),
    ("DELTA0", 1, "rotor angle at the operating point (the infinite bus at 0)"),
    ("GVALID", 1, "1 when the machine's data are in order (Xd > X'd > X''d > Xl, ...), else 0"),
    ("SAL", 1, "1: a GENSAL (salient pole: saturation on E'q, one q-axis circuit)"),
    ("KQ", 1, "the q-axis circuit's coupling: Xq - X''d (GENSAL) or X'q - Xl"),
)

#: the stabilisers: IEEEST on the rotor speed, without its notch filters (`stabilisers.ieeest`),
#: PSS2A / PSS2B on the speed and the electrical power (`stabilisers.pss2`); a candidate has the
#: columns of the one its PSS_MODEL picks, the other's gain 0
STABILISER: tuple[tuple[str, int, str], ...] = (
    ("PSS_KS", 1, "gain KS (0: no stabiliser)"),
    ("PSS_IT2", 1, "1 / T2"), ("PSS_R1", 1, "T1 / T2"),
    ("PSS_IT4", 1, "1 / T4"), ("PSS_R3", 1, "T3 / T4"),
    ("PSS_ITW", 1, "1 / TW (the washout)"),
    ("PSS_LIM", 1, "output limit +-LSMAX"),
    ("P2_KS1", 1, "PSS2A/PSS2B: gain KS1 (0: no such stabiliser)"),
    ("P2_KS2", 1, "KS2, input 2's gain"), ("P2_KS3", 1, "KS3, input 2's gain into the ramp-tracking filter"),
    ("P2_IW", 4, "1 / TW1 .. 1 / TW4, column D_P2_IW + i (0: that washout bypassed)"),
    ("P2_I6", 1, "1 / T6 (0 without that lag)"), ("P2_ON6", 1, "1 with the T6 lag"),
    ("P2_I7", 1, "1 / T7 (0 without that lag: the gain KS2 alone)"), ("P2_ON7", 1, "1 with the T7 lag"),
    ("P2_RA", 8, "ramp-tracking filter: state k's 1 / T9 (0 for k >= M N: unused), column D_P2_RA + k"),
    ("P2_RC", 8, "ramp-tracking filter: state k's weight in its output (1 - T8 / T9 for a section's last lag, "
                 "1 for the others, 0 unused: the input passes)"),
    ("P2_R", 3, "lead-lags T1/T2, T3/T4, T10/T11 (1: bypassed)"),
    ("P2_IT", 3, "lead-lags 1/T2, 1/T4, 1/T11 (0: bypassed)"),
    ("P2_V1MAX", 1, "input 1's upper limit (+inf: none)"), ("P2_V1MIN", 1, "input 1's lower limit (-inf: none)"),
    ("P2_V2MAX", 1, "input 2's upper limit (+inf: none)"), ("P2_V2MIN", 1, "input 2's lower limit (-inf: none)"),
    ("P2_U10", 1, "input 1 (limited) at the operating point"), ("P2_U20", 1, "input 2 (limited) there"),
    ("P2_VSTMAX", 1, "output upper limit"), ("P2_VSTMIN", 1, "output lower limit"),
)

COLUMNS = EXCITER + GRID + STABILISER


def _offsets(columns: tuple[tuple[str, int, str], ...]) -> tuple[dict[str, int], int]:
    offset: dict[str, int] = {}
    at = 0
    for name, width, _ in columns:
        if name in offset or width < 1:
            raise ValueError(f"engine layout: column {name!r} repeated or empty")
        offset[name] = at
        at += width
    return offset, at


#: first column of each entry of COLUMNS
OFFSET, N_DERIVED = _offsets(COLUMNS)
globals().update({f"D_{name}": at for name, at in OFFSET.items()})
#: the parameter matrix's columns (`params.KERNEL_PARAMS`), as constants of the compiled derivation
globals().update({f"P_{name}": at for at, name in enumerate(KERNEL_PARAMS)})
#: the first and the number of the machine's and the stabiliser's columns
G_FIRST, N_G = OFFSET["GD1"], len(GRID)
Z_FIRST, N_Z = OFFSET["PSS_KS"], len(STABILISER)

#: what a candidate needs of the engine (D_BITS): a block beyond the reference ones (rate feedback,
#: a rotating exciter, the output clamp, a PI / PID or the ST5B regulator), the potential-source
#: stage, one whose every block is that stage's (ESST4B), a slew limit or a finite ceiling, a dead
#: time, a recorder skew, a setpoint ramp, a GENROU-like no-load flux (KPP, KDA: not the no-load
#: reference structure's fast path)
B_FULL, B_ST4, B_ST4_ONLY, B_LIMITED, B_DELAY, B_SKEW, B_RAMP, B_FLUX = 1, 2, 4, 8, 16, 32, 64, 128

#: the excitation system's classes a variant compiles (`variants`): the reference blocks alone,
#: every block but the potential-source stage, every block with that stage selected per
#: candidate, that stage alone (the output VB VM; no DC exciter, the ceilings not on the lag)
X_REF, X_FULL, X_ST4, X_ST4_ONLY = 0, 1, 2, 3

#: rows of a chunk's readout array R: the field voltage, the stabiliser's output, then the
#: machine's algebra (Vt, Ifd and what else the machine carries from a step's end to the next
#: step's first stage)
R_FLD, R_VS, R_ALG = 0, 1, 2
#: the recorded signals, in the order of an engine run's traces, errors and weights: the field
#: voltage, Vt, P, Q, the stabiliser's output (R_VS: 0 without one, and at no load), Ifd
SIGNALS = ("efd", "vt", "p", "q", "vs", "ifd")
S_EFD, S_VT, S_P, S_Q, S_VS, S_IFD = range(6)
N_SIGNALS = 6
#: the signals an objective can score, the first N_SCORED of SIGNALS (ifd is recorded, not fitted)
N_SCORED = 5

#: tracking gain of the anti-windup of the ESST4B's PI regulators (ANDES' PITrackAW default, ks = 2)
PI_TRACK = 2.0
#: an edge instant within this many steps of a sample instant is taken to fall on it
EDGE_EPS = 1.0e-9
#: candidates per parallel chunk (see `run`)
CHUNK = 32
#: the loops over candidates run in vectors of this many (8 doubles: AVX-512; two of AVX2's 4) and
#: a scalar loop over the rest: a call of 6 or 7 candidates took 4.5 and 6.7 ms on a 15 s record,
#: one of 8 took 1.7 ms; `run` pads a call to a whole number of them
LANES = 8
#: a state magnitude beyond this marks the candidate failed (pu; physical values are < 20)
BLOWUP = 1.0e5
