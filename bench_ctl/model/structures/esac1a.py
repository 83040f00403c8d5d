"""ESAC1A, the IEEE 421.5 type AC1A rotating exciter with a diode rectifier (PSS/E ESAC1A; ANDES
`ESAC1A`): EXAC1's parameters and blocks (`exac1.ac1_params`, `ac1_blocks`) with the VA limits
on the regulator lag and the VR clamp kept for the record."""
from . import declare
from .blocks import Param
from .exac1 import ac1_blocks, ac1_params

_VR = ("VR = VA limited to [VRMIN, VRMAX] after the under- / over-excitation gates: not simulated (as in "
       "ANDES' ESAC1A); it acts only when VA passes it, far above a pulse test's field voltage")

STRUCTURE = declare(
    name="ESAC1A",
    title="IEEE 421.5 AC1A exciter: lead-lag, regulator with non-windup VA limits, AC exciter with "
          "saturation, demagnetisation and rectifier regulation, rate feedback from VFE",
    params=ac1_params(Param(name="VAMAX", unit="pu", info="maximum regulator output VA", typical=14.5),
                      Param(name="VAMIN", unit="pu", info="minimum regulator output VA", typical=-14.5)) + (
        Param(name="VRMAX", unit="pu", info="maximum exciter field voltage VR", typical=6.03, note=_VR),
        Param(name="VRMIN", unit="pu", info="minimum exciter field voltage VR", typical=-5.43, note=_VR),
    ),
    blocks=ac1_blocks("VAMAX", "VAMIN"),
    remarks=("on a pulse test the same equations as EXAC1, its VA limits in the place of EXAC1's VR limits",),
    dyr_model="ESAC1A",
    pulse_twin="EXAC1",
    source="IEEE Std 421.5-2016 AC1A; PSS/E model library, ESAC1A; ANDES andes/models/exciter/esac1a.py",
)
