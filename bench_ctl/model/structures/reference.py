"""The reference paper's structure (docs/model.md): two lead-lags, gain, bridge lag.

The default structure; its parameters are the kernel's own names. It has no PSS/E record of its
own (`export --dyr` writes it as ESST1A without limits: the same blocks under ESST1A's names)."""
from . import declare
from .blocks import LeadLag, Param, RegulatorLag, Transducer

STRUCTURE = declare(
    name="REFERENCE",
    title="the reference paper's AVR: KAVR (1+sTA1)/(1+sTA2) (1+sTA3)/(1+sTA4), bridge 1/(1+sTE)",
    params=(
        Param(name="KAVR", unit="pu/pu", info="AVR proportional gain", typical=200.0, bounds=(50.0, 800.0),
              identify=True),
        Param(name="TA1", unit="s", info="lead time constant 1", typical=1.0, bounds=(0.05, 5.0), identify=True),
        Param(name="TA2", unit="s", info="lag time constant 1", typical=0.2, bounds=(0.01, 2.0), identify=True),
        Param(name="TA3", unit="s", info="lead time constant 2", typical=0.5, bounds=(0.05, 5.0), identify=True),
        Param(name="TA4", unit="s", info="lag time constant 2", typical=10.0, bounds=(1.0, 50.0), identify=True),
        Param(name="TE", unit="s", info="exciter / bridge time constant", typical=0.02, bounds=(0.002, 0.2),
              identify=True),
        Param(name="TR", unit="s", info="voltage transducer time constant", typical=0.0),
    ),
    blocks=(
        Transducer(T="TR"),
        LeadLag(lead="TA1", lag="TA2", bypass=False),
        LeadLag(lead="TA3", lag="TA4", bypass=False),
        RegulatorLag(gain="KAVR", T="TE"),    # ceilings: the diagnosis' ceiling_limit effect
    ),
    remarks=("Efd = VR (the bridge lag TE is the regulator lag); TR = 0: Vc = Vt",),
    constraints=("TA2 <= TA1", "TA4 >= TA2"),
    swaps=(("lag TA2 <-> bridge lag TE (the forward path's lags 1/((1 + s TA2)(1 + s TA4)(1 + s TE)) trade places)",
            ("TA2", "TE")),
           ("lag TA4 <-> bridge lag TE (the forward path's lags 1/((1 + s TA2)(1 + s TA4)(1 + s TE)) trade places)",
            ("TA4", "TE"))),
    dyr_model="ESST1A",
    source="the reference paper (docs/model.md)",
)
