"""ESST5B, the IEEE 421.5 type ST5B static exciter (PSS/E ESST5B; the Mostar hydro unit's in
ALSETLab/Mostar's OpenIPSL model)."""
from . import declare
from .blocks import LeadLag, LimitedRegulator, Param, Transducer

_EL = "OEL / UEL channel: wins its gate only when a limiter acts, never at no load"

STRUCTURE = declare(
    name="ESST5B",
    title="IEEE 421.5 ST5B static exciter: two limited lead-lags, gain KR limited to [VRMIN, VRMAX], "
          "firing lag T1 with bus-fed ceilings, commutation drop KC*Ifd",
    params=(
        Param(name="TR", unit="s", info="voltage transducer time constant", typical=0.0),
        Param(name="KR", unit="pu/pu", info="regulator gain", typical=200.0, bounds=(20.0, 1000.0), identify=True),
        Param(name="T1", unit="s", info="firing circuit time constant", typical=0.004, bounds=(0.001, 0.2),
              identify=True),
        Param(name="KC", unit="pu", info="rectifier regulation factor (commutation drop KC*Ifd)", typical=0.004),
        Param(name="VRMAX", unit="pu", info="maximum regulator output (the ceiling times Vt)", typical=5.0),
        Param(name="VRMIN", unit="pu", info="minimum regulator output (the floor times Vt)", typical=-4.0),
        Param(name="TC1", unit="s", info="lead time constant 1", typical=0.8, bounds=(0.01, 10.0), identify=True),
        Param(name="TB1", unit="s", info="lag time constant 1", typical=6.0, bounds=(0.01, 50.0), identify=True),
        Param(name="TC2", unit="s", info="lead time constant 2", typical=0.08, bounds=(0.005, 10.0), identify=True),
        Param(name="TB2", unit="s", info="lag time constant 2", typical=0.01, bounds=(0.005, 10.0), identify=True),
        *(Param(name=n, unit="s", info=f"{what} time constant {k} of the {chan}-excitation channel",
                typical=1.0, note=_EL)
          for chan, pre in (("over", "O"), ("under", "U")) for k in (1, 2)
          for n, what in ((f"T{pre}C{k}", "lead"), (f"T{pre}B{k}", "lag"))),
    ),
    blocks=(
        Transducer(T="TR"),
        LeadLag(lead="TC1", lag="TB1"),
        LeadLag(lead="TC2", lag="TB2"),
        LimitedRegulator(gain="KR", T="T1", upper="VRMAX", lower="VRMIN", kc="KC"),
    ),
    remarks=("the lead-lags' limits clamp their outputs; their states are not held at the limit "
             "(IEEE 421.5's non-windup lead-lag is not modelled), the firing lag T1 is held (non-windup); "
             "OEL / UEL channels: record only (inactive at no load)",),
    # the regulator's lags commute below the limits: the fast one is the firing circuit's
    constraints=("T1 <= TB1", "T1 <= TB2"),
    dyr_model="ESST5B",
    source="IEEE Std 421.5-2005 ST5B; PSS/E model library, ESST5B; OpenIPSL Electrical.Controls.PSSE.ES.ST5B "
           "(the limited lead-lags, the limiter ahead of the firing lag, KC*Ifd at its input)",
)
