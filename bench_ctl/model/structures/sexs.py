"""SEXS, the simplified excitation system (PSS/E SEXS; ANDES `SEXS`)."""
from . import declare
from .blocks import LeadLag, Param, RegulatorLag

STRUCTURE = declare(
    name="SEXS",
    title="simplified excitation system: lead-lag, gain with exciter lag, non-windup EMIN/EMAX",
    params=(
        Param(name="K", unit="pu/pu", info="gain", typical=200.0, bounds=(20.0, 800.0), identify=True),
        Param(name="TA", unit="s", info="lead time constant (the record holds TA/TB)", typical=1.0,
              bounds=(0.05, 5.0), identify=True),
        Param(name="TB", unit="s", info="lag time constant", typical=10.0, bounds=(0.5, 50.0), identify=True),
        Param(name="TE", unit="s", info="exciter time constant", typical=0.05, bounds=(0.002, 0.5), identify=True),
        Param(name="EMIN", unit="pu", info="minimum exciter output", typical=-3.0),
        Param(name="EMAX", unit="pu", info="maximum exciter output", typical=4.5),
    ),
    blocks=(
        LeadLag(lead="TA", lag="TB"),     # TA = TB = 0 (a record's TB = 0): no lead-lag
        RegulatorLag(gain="K", T="TE", upper="EMAX", lower="EMIN", vt_scaled=False, output_clamp=False),
    ),
    remarks=("input Verr = Vref - Vt (no transducer); PSS/E gives TA as the ratio TA/TB",),
    dyr_model="SEXS",
    dyr_special={"TA/TB": (lambda v: v["TA"] / v["TB"], lambda f: ("TA", f["TA/TB"] * f["TB"]))},
    source="PSS/E model library, SEXS; ANDES andes/models/exciter/sexs.py",
)
