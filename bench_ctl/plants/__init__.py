"""The real-time plants the simulated devices share: the unit at no load (`Plant`) or on the grid
(`OnlinePlant`), one candidate of the engine stepped against the clock (`realtime`)."""
from .plant import FLAG_CEILING, FLAG_FAILED, FLAG_RAMP, FLAG_RATE, TURBINE_PU, OnlinePlant, Plant, warm_up
from .samples import (
    N_OUT,
    O_EFD,
    O_EFD_REC,
    O_EQP,
    O_FLAGS,
    O_IFD,
    O_P,
    O_Q,
    O_UREF,
    O_USETP,
    O_VT,
    Listener,
    PlantState,
    PlantTiming,
)

__all__ = ["FLAG_CEILING", "FLAG_FAILED", "FLAG_RAMP", "FLAG_RATE", "N_OUT", "O_EFD", "O_EFD_REC", "O_EQP", "O_FLAGS",
           "O_IFD", "O_P", "O_Q", "O_UREF", "O_USETP", "O_VT", "TURBINE_PU", "Listener", "OnlinePlant", "Plant",
           "PlantState", "PlantTiming", "warm_up"]
