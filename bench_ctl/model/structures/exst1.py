"""EXST1, the IEEE type ST1 static exciter (PSS/E EXST1; ANDES `EXST1`)."""
from . import declare
from .blocks import InputLimit, LeadLag, Param, RateFeedback, RegulatorLag, Transducer

_VI = "the input limiter acts only beyond |Verr| = VIMAX, far above a pulse test's 5-20 %"

STRUCTURE = declare(
    name="EXST1",
    title="IEEE ST1 static exciter: transducer, lead-lag, regulator lag, output limits Vt*VR - KC*Ifd",
    params=(
        Param(name="TR", unit="s", info="voltage transducer time constant", typical=0.01),
        Param(name="VIMAX", unit="pu", info="maximum voltage error", typical=0.8, note=_VI),
        Param(name="VIMIN", unit="pu", info="minimum voltage error", typical=-0.8, note=_VI),
        Param(name="TC", unit="s", info="lead time constant", typical=1.0, bounds=(0.05, 5.0), identify=True),
        Param(name="TB", unit="s", info="lag time constant", typical=10.0, bounds=(0.5, 50.0), identify=True),
        Param(name="KA", unit="pu/pu", info="regulator gain", typical=200.0, bounds=(20.0, 800.0), identify=True),
        Param(name="TA", unit="s", info="regulator time constant", typical=0.02, bounds=(0.002, 0.2), identify=True),
        Param(name="VRMAX", unit="pu", info="maximum regulator output (times Vt)", typical=4.0),
        Param(name="VRMIN", unit="pu", info="minimum regulator output (times Vt)", typical=-3.0),
        Param(name="KC", unit="pu", info="rectifier loading factor (commutation drop KC*Ifd)", typical=0.05),
        Param(name="KF", unit="pu", info="rate feedback gain", typical=0.0),
        Param(name="TF", unit="s", info="rate feedback time constant", typical=1.0),
    ),
    blocks=(
        Transducer(T="TR"),
        InputLimit(upper="VIMAX", lower="VIMIN"),
        LeadLag(lead="TC", lag="TB"),
        RegulatorLag(gain="KA", T="TA", upper="VRMAX", lower="VRMIN", vt_scaled=True, output_clamp=True, kc="KC"),
        RateFeedback(K="KF", T="TF"),
    ),
    dyr_model="EXST1",
    source="PSS/E model library, EXST1 (IEEE 421.5-1992 ST1); ANDES andes/models/exciter/exst1.py "
           "(ANDES limits VRMAX - KC*Ifd and VRMIN - KC*Ifd without Vt)",
)
