"""EXST1, the IEEE type ST1 static exciter (PSS/E EXST1; ANDES `EXST1`)."""
from . import StdParam, Structure

_VI = "the input limiter acts only beyond |Verr| = VIMAX, far above a pulse test's 5-20 %"

STRUCTURE = Structure(
    name="EXST1",
    title="IEEE ST1 static exciter: transducer, lead-lag, regulator lag, output limits Vt*VR - KC*Ifd",
    diagram=(
        "Vc = Vt / (1 + s TR)",
        "Vi = Vref - Vc - VF, limited to [VIMIN, VIMAX]",
        "VA = KA/(1 + s TA) (1 + s TC)/(1 + s TB) Vi",
        "Efd = VA clamped to [Vt VRMIN, Vt VRMAX - KC Ifd] (the lag itself is not limited)",
        "VF = s KF/(1 + s TF) VA",
    ),
    params=(
        StdParam("TR", "s", "voltage transducer time constant", 0.01, None, "TR"),
        StdParam("VIMAX", "pu", "maximum voltage error", 0.8, None, None, note=_VI),
        StdParam("VIMIN", "pu", "minimum voltage error", -0.8, None, None, note=_VI),
        StdParam("TC", "s", "lead time constant", 1.0, (0.05, 5.0), "TA1", True),
        StdParam("TB", "s", "lag time constant", 10.0, (0.5, 50.0), "TA2", True),
        StdParam("KA", "pu/pu", "regulator gain", 200.0, (20.0, 800.0), "KAVR", True),
        StdParam("TA", "s", "regulator time constant", 0.02, (0.002, 0.2), "TE", True),
        StdParam("VRMAX", "pu", "maximum regulator output (times Vt)", 4.0, None, "VRMAX"),
        StdParam("VRMIN", "pu", "minimum regulator output (times Vt)", -3.0, None, "VRMIN"),
        StdParam("KC", "pu", "rectifier loading factor (commutation drop KC*Ifd)", 0.05, None, "KC"),
        StdParam("KF", "pu", "rate feedback gain", 0.0, None, "KF"),
        StdParam("TF", "s", "rate feedback time constant", 1.0, None, "TF"),
    ),
    settings={"TA3": 1.0, "TA4": 1.0, "VRVT": 1.0, "LIMOUT": 1.0},
    lead_lags=(("TA1", "TA2"),),
    dyr_model="EXST1",
    source="PSS/E model library, EXST1 (IEEE 421.5-1992 ST1); ANDES andes/models/exciter/exst1.py "
           "(ANDES limits VRMAX - KC*Ifd and VRMIN - KC*Ifd without Vt)",
)
