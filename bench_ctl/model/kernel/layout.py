"""The kernel's layout: the derived-parameter columns (`D_*`) and the kernel's constants.

`derive` turns a parameter matrix into one row of derived factors per candidate; the compiled
code reads them transposed, `D[D_NAME, c]`. `COLUMNS` is that layout, in order: each entry a
name, its width and what the column holds. The constants `D_NAME` (its first column) and
`N_DERIVED` are generated from it, so a column is added in one place.
"""
from __future__ import annotations

from ..params import RECORD_PARAMS

#: (name, columns, meaning), in the order of the derived matrix
COLUMNS: tuple[tuple[str, int, str], ...] = (
    # the reference blocks: AVR lead-lags, exciter lag, generator, the effects
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
    # the blocks of the standard structures
    ("KFT", 1, "rate feedback: KF / TF"),
    ("ITF", 1, "rate feedback: 1 / TF"),
    ("ITEX", 1, "DC exciter: 1 / TEX"),
    ("DCON", 1, "1 with a DC exciter"),
    ("KE", 1, "DC exciter: KE"),
    ("SEA", 1, "DC exciter saturation B (Efd - A)^2: A"),
    ("SEB", 1, "DC exciter saturation: B"),
    ("LIMOUT", 1, "1: the ceilings clamp the output rather than the lag"),
    ("OUT0", 1, "the field voltage (the kernel's output) at the steady state"),
    ("VRIN", 1, "1: the ST5B regulator, its output limited to [VRMIN, VRMAX] less KCIN Ifd drives the lag"),
    ("KCIN", 1, "ST5B: KC, the commutation drop at the regulator lag's input (0 elsewhere; D_KC is then 0)"),
    ("VR0", 1, "the regulator output KAVR y at the steady state (the dead time's history before the record)"),
    ("KPP", 1, "share of E'q in Vt (GENROU-like flux)"),
    ("SATVT", 1, "1: saturation on Vt rather than E'q (KPP > 0)"),
    ("KDA", 1, "damper coupling in the field current"),
    # the potential-source stage (ESST4B)
    ("ST4", 1, "1 with the potential-source stage"),
    ("P1", 1, "PI regulator in place of lead-lag 1 (the potential-source stage's, or the PID's): proportional "
              "gain KPI"),
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
    ("XF0", 1, "state 6 at the steady state (rate feedback, or the inner integrator)"),
    # the AC exciter (EXAC1): the DC exciter's state is VE
    ("ACON", 1, "1 with an AC exciter: Efd = VE FEX(KCAC Ifd / VE), VFE = KE VE + SE(VE) + KD Ifd"),
    ("KD", 1, "AC exciter: KD, the demagnetising Ifd in VFE"),
    ("KCAC", 1, "AC exciter: KC of the rectifier's FEX (D_KC is then 0)"),
    ("XE0", 1, "state 7 at the steady state: the DC exciter's Efd or the AC exciter's VE"),
    ("OUTK", 1, "the output's slope per the exciter state's: 1 (DC), FEX at the steady state (AC)"),
    # the PID regulator (AC8B): the PI in lead-lag 1's place with a derivative on lead-lag 2's state
    ("PID", 1, "1: state 2 is the PID's derivative filter (it follows the error at 1 / TDR, lead-lag 2 "
               "is bypassed), 0: lead-lag 2's state"),
    ("KDT", 1, "PID regulator: KDR / TDR, the derivative's gain on (error - its filtered value)"),
    ("X20", 1, "state 2 at the steady state: lead-lag 2's (E0), or the derivative filter's (0)"),
)


def _offsets(columns: tuple[tuple[str, int, str], ...]) -> tuple[dict[str, int], int]:
    offset: dict[str, int] = {}
    at = 0
    for name, width, _ in columns:
        if name in offset or width < 1:
            raise ValueError(f"kernel layout: column {name!r} repeated or empty")
        offset[name] = at
        at += width
    return offset, at


#: first column of each entry of COLUMNS
OFFSET, N_DERIVED = _offsets(COLUMNS)
globals().update({f"D_{name}": at for name, at in OFFSET.items()})

#: the potential-source stage in a chunk (`rhs`'s `st4`, a constant of each RK4 loop): no candidate
#: has it; some may (selected per candidate); every valid candidate has it (the output is VB VM,
#: no DC exciter, the ceilings not on the regulator lag: those blocks are left out)
ST4_NONE, ST4_SOME, ST4_ALL = 0, 1, 2
#: tracking gain of the anti-windup of the ESST4B's PI regulators (ANDES' PITrackAW default, ks = 2)
PI_TRACK = 2.0
#: an edge instant within this many steps of a sample instant is taken to fall on it
EDGE_EPS = 1.0e-9
#: candidates per parallel chunk (see run_kernel)
CHUNK = 32
#: a state magnitude beyond this marks the candidate failed (pu; physical values are < 20)
BLOWUP = 1.0e5
#: rows of the chunk's state array: xm, x1, x2, VR lag (efd of a static exciter), E'q, E''q, rate
#: feedback (or the inner PI's integrator), DC exciter Efd; the output's slope at step start, end
N_STATES = 8
N_STATE_ROWS = 10
