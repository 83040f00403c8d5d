"""ESST1A, the IEEE 421.5 type ST1A static exciter (PSS/E ESST1A; ANDES `ESST1A`)."""
from . import declare
from .blocks import InputLimit, LeadLag, Param, RateFeedback, RegulatorLag, Transducer

_VI = "the input limiter acts only beyond |Verr| = VIMAX, far above a pulse test's 5-20 %"
_VA = "VA limits: not simulated; typical records leave them wide (the output limits act)"
_LR = "field current limiter: inactive at no load (Ifd below ILR)"

STRUCTURE = declare(
    name="ESST1A",
    title="IEEE 421.5 ST1A static exciter: two lead-lags, regulator lag, output limits Vt*VR - KC*Ifd",
    params=(
        Param(name="TR", unit="s", info="voltage transducer time constant", typical=0.01),
        Param(name="VIMAX", unit="pu", info="maximum voltage error", typical=0.8, note=_VI),
        Param(name="VIMIN", unit="pu", info="minimum voltage error", typical=-0.8, note=_VI),
        Param(name="TC", unit="s", info="lead time constant 1", typical=1.0, bounds=(0.05, 5.0), identify=True),
        Param(name="TB", unit="s", info="lag time constant 1", typical=10.0, bounds=(0.5, 50.0), identify=True),
        Param(name="TC1", unit="s", info="lead time constant 2", typical=0.5, bounds=(0.05, 5.0), identify=True),
        Param(name="TB1", unit="s", info="lag time constant 2", typical=0.2, bounds=(0.01, 2.0), identify=True),
        Param(name="KA", unit="pu/pu", info="regulator gain", typical=200.0, bounds=(20.0, 800.0), identify=True),
        Param(name="TA", unit="s", info="regulator time constant", typical=0.02, bounds=(0.002, 0.2), identify=True),
        Param(name="VAMAX", unit="pu", info="maximum regulator output", typical=999.0, note=_VA),
        Param(name="VAMIN", unit="pu", info="minimum regulator output", typical=-999.0, note=_VA),
        Param(name="VRMAX", unit="pu", info="maximum exciter output (times Vt)", typical=4.0),
        Param(name="VRMIN", unit="pu", info="minimum exciter output (times Vt)", typical=-3.0),
        Param(name="KC", unit="pu", info="rectifier loading factor (commutation drop KC*Ifd)", typical=0.1),
        Param(name="KF", unit="pu", info="rate feedback gain", typical=0.0),
        Param(name="TF", unit="s", info="rate feedback time constant", typical=1.0),
        Param(name="KLR", unit="pu", info="field current limiter gain", typical=0.0, note=_LR),
        Param(name="ILR", unit="pu", info="field current limit", typical=5.0, note=_LR),
    ),
    blocks=(
        Transducer(T="TR"),
        InputLimit(upper="VIMAX", lower="VIMIN"),
        LeadLag(lead="TC", lag="TB"),
        LeadLag(lead="TC1", lag="TB1"),
        RegulatorLag(gain="KA", T="TA", upper="VRMAX", lower="VRMIN", vt_scaled=True, output_clamp=True, kc="KC"),
        RateFeedback(K="KF", T="TF"),
    ),
    remarks=("UEL / PSS inputs: none in the test; VA limits VAMAX, VAMIN and the field current limiter "
             "KLR (Ifd - ILR): record only (inactive at no load)",),
    # 1/(1 + s TB1) and 1/(1 + s TA) commute below the ceilings: the fast one is the regulator's
    constraints=("TA <= TB1",),
    dyr_model="ESST1A",
    source="IEEE Std 421.5-2016 ST1A; PSS/E model library, ESST1A; ANDES andes/models/exciter/esst1a.py",
)
