"""The reference paper's structure (docs/model.md): two lead-lags, gain, bridge lag.

The default structure; its parameters are the kernel's own names. It has no PSS/E record of its
own (`export --dyr` writes it as ESST1A without limits: the same blocks under ESST1A's names)."""
from . import StdParam, Structure

STRUCTURE = Structure(
    name="REFERENCE",
    title="the reference paper's AVR: KAVR (1+sTA1)/(1+sTA2) (1+sTA3)/(1+sTA4), bridge 1/(1+sTE)",
    diagram=(
        "Vm = Vt / (1 + s TR)                      (TR = 0: Vm = Vt)",
        "VR = KAVR (1 + s TA1)/(1 + s TA2) (1 + s TA3)/(1 + s TA4) (uref - Vm)",
        "Efd = VR / (1 + s TE)                     (ceilings: the ceiling_limit effect)",
    ),
    params=(
        StdParam("KAVR", "pu/pu", "AVR proportional gain", 200.0, (50.0, 800.0), "KAVR", True),
        StdParam("TA1", "s", "lead time constant 1", 1.0, (0.05, 5.0), "TA1", True),
        StdParam("TA2", "s", "lag time constant 1", 0.2, (0.01, 2.0), "TA2", True),
        StdParam("TA3", "s", "lead time constant 2", 0.5, (0.05, 5.0), "TA3", True),
        StdParam("TA4", "s", "lag time constant 2", 10.0, (1.0, 50.0), "TA4", True),
        StdParam("TE", "s", "exciter / bridge time constant", 0.02, (0.002, 0.2), "TE", True),
        StdParam("TR", "s", "voltage transducer time constant", 0.0, None, "TR"),
    ),
    constraints=("TA2 <= TA1", "TA4 >= TA2"),
    swaps=(("lag TA2 <-> bridge lag TE (the forward path's lags 1/((1 + s TA2)(1 + s TA4)(1 + s TE)) trade places)",
            ("TA2", "TE")),
           ("lag TA4 <-> bridge lag TE (the forward path's lags 1/((1 + s TA2)(1 + s TA4)(1 + s TE)) trade places)",
            ("TA4", "TE"))),
    dyr_model="ESST1A",
    source="the reference paper (docs/model.md)",
)
