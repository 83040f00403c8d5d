"""IEEEX1, the IEEE type 1 DC exciter (PSS/E IEEEX1, the ESDC1A family; ANDES `IEEEX1`)."""
from . import declare
from .blocks import DCExciter, LeadLag, Param, RateFeedback, RegulatorLag, Transducer

STRUCTURE = declare(
    name="IEEEX1",
    title="IEEE type 1 DC exciter: lead-lag, regulator with non-windup limits, DC exciter with "
          "saturation, rate feedback",
    params=(
        Param(name="TR", unit="s", info="voltage transducer time constant", typical=0.01),
        Param(name="KA", unit="pu/pu", info="regulator gain", typical=40.0, bounds=(5.0, 400.0), identify=True),
        Param(name="TA", unit="s", info="regulator time constant", typical=0.04, bounds=(0.002, 0.5), identify=True),
        Param(name="TB", unit="s", info="lag time constant", typical=1.0),
        Param(name="TC", unit="s", info="lead time constant", typical=1.0),
        Param(name="VRMAX", unit="pu", info="maximum regulator output", typical=7.3),
        Param(name="VRMIN", unit="pu", info="minimum regulator output", typical=-7.3),
        Param(name="KE", unit="pu", info="exciter self-excitation constant", typical=1.0),
        Param(name="TE", unit="s", info="exciter time constant", typical=0.5, bounds=(0.05, 3.0), identify=True),
        Param(name="KF", unit="pu", info="rate feedback gain", typical=0.03, bounds=(0.002, 0.3), identify=True),
        Param(name="TF1", unit="s", info="rate feedback time constant", typical=1.0),
        Param(name="SWITCH", unit="1", info="PSS/E's unused switch field", typical=0.0, note="kept at 0"),
        Param(name="E1", unit="pu", info="Efd of the first saturation point", typical=2.5),
        Param(name="SE1", unit="pu", info="exciter saturation at E1", typical=0.05),
        Param(name="E2", unit="pu", info="Efd of the second saturation point", typical=3.5),
        Param(name="SE2", unit="pu", info="exciter saturation at E2", typical=0.3),
    ),
    blocks=(
        Transducer(T="TR"),
        LeadLag(lead="TC", lag="TB"),
        RegulatorLag(gain="KA", T="TA", upper="VRMAX", lower="VRMIN", vt_scaled=False, output_clamp=False),
        DCExciter(T="TE", KE="KE", E1="E1", SE1="SE1", E2="E2", SE2="SE2"),
        RateFeedback(K="KF", T="TF1", source="Efd"),
    ),
    swaps=(("regulator lag TA <-> exciter time constant TE (the forward path KA/((1 + s TA)(KE + s TE)) "
            "is symmetric in them when KE = 1 and saturation is small)", ("TA", "TE")),),
    dyr_model="IEEEX1",
    source="PSS/E model library, IEEEX1 (IEEE 1968 type 1, 421.5 DC1A family); ANDES "
           "andes/models/exciter/ieeex1.py (ANDES scales VRMAX, VRMIN by Vt)",
)
