"""ESST1A, the IEEE 421.5 type ST1A static exciter (PSS/E ESST1A; ANDES `ESST1A`)."""
from . import StdParam, Structure

_VI = "the input limiter acts only beyond |Verr| = VIMAX, far above a pulse test's 5-20 %"
_VA = "VA limits: not simulated; typical records leave them wide (the output limits act)"
_LR = "field current limiter: inactive at no load (Ifd below ILR)"

STRUCTURE = Structure(
    name="ESST1A",
    title="IEEE 421.5 ST1A static exciter: two lead-lags, regulator lag, output limits Vt*VR - KC*Ifd",
    diagram=(
        "Vc = Vt / (1 + s TR)",
        "Vi = Vref - Vc - VF, limited to [VIMAX, VIMIN]  (UEL/PSS inputs: none in the test)",
        "VA = KA/(1 + s TA) (1 + s TC1)/(1 + s TB1) (1 + s TC)/(1 + s TB) Vi",
        "Efd = VA clamped to [Vt VRMIN, Vt VRMAX - KC Ifd] (the lag itself is not limited)",
        "VF = s KF/(1 + s TF) VA; field current limiter KLR (Ifd - ILR): inactive at no load",
    ),
    params=(
        StdParam("TR", "s", "voltage transducer time constant", 0.01, None, "TR"),
        StdParam("VIMAX", "pu", "maximum voltage error", 0.8, None, None, note=_VI),
        StdParam("VIMIN", "pu", "minimum voltage error", -0.8, None, None, note=_VI),
        StdParam("TC", "s", "lead time constant 1", 1.0, (0.05, 5.0), "TA1", True),
        StdParam("TB", "s", "lag time constant 1", 10.0, (0.5, 50.0), "TA2", True),
        StdParam("TC1", "s", "lead time constant 2", 0.5, (0.05, 5.0), "TA3", True),
        StdParam("TB1", "s", "lag time constant 2", 0.2, (0.01, 2.0), "TA4", True),
        StdParam("KA", "pu/pu", "regulator gain", 200.0, (20.0, 800.0), "KAVR", True),
        StdParam("TA", "s", "regulator time constant", 0.02, (0.002, 0.2), "TE", True),
        StdParam("VAMAX", "pu", "maximum regulator output", 999.0, None, None, note=_VA),
        StdParam("VAMIN", "pu", "minimum regulator output", -999.0, None, None, note=_VA),
        StdParam("VRMAX", "pu", "maximum exciter output (times Vt)", 4.0, None, "VRMAX"),
        StdParam("VRMIN", "pu", "minimum exciter output (times Vt)", -3.0, None, "VRMIN"),
        StdParam("KC", "pu", "rectifier loading factor (commutation drop KC*Ifd)", 0.1, None, "KC"),
        StdParam("KF", "pu", "rate feedback gain", 0.0, None, "KF"),
        StdParam("TF", "s", "rate feedback time constant", 1.0, None, "TF"),
        StdParam("KLR", "pu", "field current limiter gain", 0.0, None, None, note=_LR),
        StdParam("ILR", "pu", "field current limit", 5.0, None, None, note=_LR),
    ),
    settings={"VRVT": 1.0, "LIMOUT": 1.0},
    # 1/(1 + s TB1) and 1/(1 + s TA) commute below the ceilings: the fast one is the regulator's
    constraints=("TA <= TB1",),
    lead_lags=(("TA1", "TA2"), ("TA3", "TA4")),
    dyr_model="ESST1A",
    source="IEEE Std 421.5-2016 ST1A; PSS/E model library, ESST1A; ANDES andes/models/exciter/esst1a.py",
)
