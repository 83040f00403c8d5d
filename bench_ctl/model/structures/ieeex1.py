"""IEEEX1, the IEEE type 1 DC exciter (PSS/E IEEEX1, the ESDC1A family; ANDES `IEEEX1`)."""
from . import StdParam, Structure

STRUCTURE = Structure(
    name="IEEEX1",
    title="IEEE type 1 DC exciter: lead-lag, regulator with non-windup limits, DC exciter with "
          "saturation, rate feedback",
    diagram=(
        "Vc = Vt / (1 + s TR)",
        "VR = KA/(1 + s TA) (1 + s TC)/(1 + s TB) (Vref - Vc - VF), non-windup VRMIN <= VR <= VRMAX",
        "TE dEfd/dt = VR - (KE + SE(Efd)) Efd,  SE(Efd) Efd = B (Efd - A)^2 through (E1, SE1), (E2, SE2)",
        "VF = s KF/(1 + s TF1) Efd",
    ),
    params=(
        StdParam("TR", "s", "voltage transducer time constant", 0.01, None, "TR"),
        StdParam("KA", "pu/pu", "regulator gain", 40.0, (5.0, 400.0), "KAVR", True),
        StdParam("TA", "s", "regulator time constant", 0.04, (0.002, 0.5), "TE", True),
        StdParam("TB", "s", "lag time constant", 1.0, None, "TA2"),
        StdParam("TC", "s", "lead time constant", 1.0, None, "TA1"),
        StdParam("VRMAX", "pu", "maximum regulator output", 7.3, None, "VRMAX"),
        StdParam("VRMIN", "pu", "minimum regulator output", -7.3, None, "VRMIN"),
        StdParam("KE", "pu", "exciter self-excitation constant", 1.0, None, "KE"),
        StdParam("TE", "s", "exciter time constant", 0.5, (0.05, 3.0), "TEX", True),
        StdParam("KF", "pu", "rate feedback gain", 0.03, (0.002, 0.3), "KF", True),
        StdParam("TF1", "s", "rate feedback time constant", 1.0, None, "TF"),
        StdParam("SWITCH", "1", "PSS/E's unused switch field", 0.0, None, None, note="kept at 0"),
        StdParam("E1", "pu", "Efd of the first saturation point", 2.5, None, "E1"),
        StdParam("SE1", "pu", "exciter saturation at E1", 0.05, None, "SE1"),
        StdParam("E2", "pu", "Efd of the second saturation point", 3.5, None, "E2"),
        StdParam("SE2", "pu", "exciter saturation at E2", 0.3, None, "SE2"),
    ),
    settings={"TA3": 1.0, "TA4": 1.0, "VRVT": 0.0, "KC": 0.0, "LIMOUT": 0.0},
    lead_lags=(("TA1", "TA2"),),
    swaps=(("regulator lag TA <-> exciter time constant TE (the forward path KA/((1 + s TA)(KE + s TE)) "
            "is symmetric in them when KE = 1 and saturation is small)", ("TA", "TE")),),
    dyr_model="IEEEX1",
    source="PSS/E model library, IEEEX1 (IEEE 1968 type 1, 421.5 DC1A family); ANDES "
           "andes/models/exciter/ieeex1.py (ANDES scales VRMAX, VRMIN by Vt)",
)
