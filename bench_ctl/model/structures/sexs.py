"""SEXS, the simplified excitation system (PSS/E SEXS; ANDES `SEXS`)."""
from . import StdParam, Structure

STRUCTURE = Structure(
    name="SEXS",
    title="simplified excitation system: lead-lag, gain with exciter lag, non-windup EMIN/EMAX",
    diagram=(
        "Verr = Vref - Vt",
        "VL = (1 + s TA)/(1 + s TB) Verr           (PSS/E gives TA as the ratio TA/TB)",
        "Efd = K/(1 + s TE) VL, non-windup limits EMIN <= Efd <= EMAX",
    ),
    params=(
        StdParam("K", "pu/pu", "gain", 200.0, (20.0, 800.0), "KAVR", True),
        StdParam("TA", "s", "lead time constant (the record holds TA/TB)", 1.0, (0.05, 5.0), "TA1", True),
        StdParam("TB", "s", "lag time constant", 10.0, (0.5, 50.0), "TA2", True),
        StdParam("TE", "s", "exciter time constant", 0.05, (0.002, 0.5), "TE", True),
        StdParam("EMIN", "pu", "minimum exciter output", -3.0, None, "VRMIN"),
        StdParam("EMAX", "pu", "maximum exciter output", 4.5, None, "VRMAX"),
    ),
    settings={"TA3": 1.0, "TA4": 1.0, "VRVT": 0.0, "KC": 0.0, "LIMOUT": 0.0, "TR": 0.0},
    lead_lags=(("TA1", "TA2"),),   # TA = TB = 0 (a record's TB = 0): no lead-lag
    dyr_model="SEXS",
    dyr_special={"TA/TB": (lambda v: v["TA"] / v["TB"], lambda f: ("TA", f["TA/TB"] * f["TB"]))},
    source="PSS/E model library, SEXS; ANDES andes/models/exciter/sexs.py",
)
