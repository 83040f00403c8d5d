"""EXAC1, the IEEE type AC1 rotating exciter with a diode rectifier (PSS/E EXAC1; ANDES `EXAC1`).
Its parameters and blocks are also ESAC1A's (`ac1_params`, `ac1_blocks`), with other limits."""
from . import declare
from .blocks import ACExciter, Block, LeadLag, Param, RateFeedback, RegulatorLag, Transducer

_NO_LEAD_LAG = "typical 1 = {other}: no lead-lag, as the sample's 0, 0"


def ac1_params(upper: Param, lower: Param) -> tuple[Param, ...]:
    """The AC1 exciter's parameters (IEEE 421.5 sample values), its regulator's limits `upper`,
    `lower` in their place."""
    return (
        Param(name="TR", unit="s", info="voltage transducer time constant", typical=0.0),
        Param(name="TB", unit="s", info=f"lag time constant ({_NO_LEAD_LAG.format(other='TC')})",
              typical=1.0, bounds=(0.5, 50.0), identify=True),
        Param(name="TC", unit="s", info=f"lead time constant ({_NO_LEAD_LAG.format(other='TB')})",
              typical=1.0, bounds=(0.05, 5.0), identify=True),
        Param(name="KA", unit="pu/pu", info="regulator gain", typical=400.0, bounds=(20.0, 1000.0), identify=True),
        Param(name="TA", unit="s", info="regulator time constant", typical=0.02, bounds=(0.002, 0.5), identify=True),
        upper,
        lower,
        Param(name="TE", unit="s", info="exciter time constant", typical=0.8, bounds=(0.05, 3.0), identify=True),
        Param(name="KF", unit="pu", info="rate feedback gain", typical=0.03, bounds=(0.0, 0.3), identify=True),
        Param(name="TF", unit="s", info="rate feedback time constant", typical=1.0),
        Param(name="KC", unit="pu", info="rectifier loading factor (commutating reactance)", typical=0.2),
        Param(name="KD", unit="pu", info="demagnetising factor (armature reaction)", typical=0.38),
        Param(name="KE", unit="pu", info="exciter constant (self-excited field)", typical=1.0),
        Param(name="E1", unit="pu", info="VE of the first saturation point", typical=3.14),
        Param(name="SE1", unit="pu", info="exciter saturation at E1", typical=0.03),
        Param(name="E2", unit="pu", info="VE of the second saturation point", typical=4.18),
        Param(name="SE2", unit="pu", info="exciter saturation at E2", typical=0.1),
    )


def ac1_blocks(upper: str, lower: str) -> tuple[Block, ...]:
    """The AC1 exciter's blocks, its regulator lag's non-windup limits named `upper`, `lower`."""
    return (
        Transducer(T="TR"),
        LeadLag(lead="TC", lag="TB"),     # TB = TC = 0 (a record's "none") or TB = TC: no lead-lag
        RegulatorLag(gain="KA", T="TA", upper=upper, lower=lower, vt_scaled=False, output_clamp=False,
                     kc_elsewhere=True),
        ACExciter(T="TE", KE="KE", KD="KD", KC="KC", E1="E1", SE1="SE1", E2="E2", SE2="SE2"),
        RateFeedback(K="KF", T="TF", source="VFE"),
    )


STRUCTURE = declare(
    name="EXAC1",
    title="IEEE type AC1 exciter: lead-lag, regulator with non-windup limits, AC exciter with "
          "saturation, demagnetisation and rectifier regulation, rate feedback from VFE",
    params=ac1_params(Param(name="VRMAX", unit="pu", info="maximum regulator output", typical=6.03),
                      Param(name="VRMIN", unit="pu", info="minimum regulator output", typical=-5.43)),
    blocks=ac1_blocks("VRMAX", "VRMIN"),
    dyr_model="EXAC1",
    source="PSS/E model library, EXAC1 (IEEE 421.5 AC1A without the VA limits); ANDES "
           "andes/models/exciter/exac1.py",
)
