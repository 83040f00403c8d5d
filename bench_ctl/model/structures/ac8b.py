"""AC8B, the IEEE 421.5 type AC8B exciter: a PID voltage regulator on a rotating AC exciter, the
usual digital retrofit of an older unit (PSS/E ESAC8B; ANDES `AC8B`)."""
from . import declare
from .blocks import ACExciter, Param, PIDRegulator, RegulatorLag, Transducer

_ESAC8B = "IEEE 421.5 AC8B and ANDES' AC8B; PSS/E's ESAC8B record has no field for it (read back as 0)"
_NOT_SIM = "not simulated (as in ANDES' AC8B): it acts far above a pulse test's exciter field"

STRUCTURE = declare(
    name="AC8B",
    title="IEEE 421.5 AC8B exciter: PID voltage regulator, regulator lag with non-windup limits, AC "
          "exciter with saturation, demagnetisation and rectifier regulation",
    params=(
        Param(name="TR", unit="s", info="voltage transducer time constant", typical=0.0),
        Param(name="KPR", unit="pu", info="proportional gain of the PID", typical=80.0, bounds=(1.0, 500.0),
              identify=True),
        Param(name="KIR", unit="pu/s", info="integral gain of the PID", typical=5.0, bounds=(0.0, 500.0),
              identify=True),
        Param(name="KDR", unit="pu s", info="derivative gain of the PID", typical=10.0, bounds=(0.0, 100.0),
              identify=True),
        Param(name="TDR", unit="s", info="derivative filter time constant of the PID", typical=0.1,
              bounds=(0.005, 1.0), identify=True),
        Param(name="KA", unit="pu/pu", info="regulator gain", typical=1.0),
        Param(name="TA", unit="s", info="regulator time constant", typical=0.01, bounds=(0.002, 0.5)),
        Param(name="VRMAX", unit="pu", info="maximum regulator output", typical=35.0),
        Param(name="VRMIN", unit="pu", info="minimum regulator output", typical=0.0),
        Param(name="TE", unit="s", info="exciter time constant", typical=1.2, bounds=(0.05, 3.0), identify=True),
        Param(name="KE", unit="pu", info="exciter constant (self-excited field)", typical=1.0),
        Param(name="E1", unit="pu", info="VE of the first saturation point", typical=6.5),
        Param(name="SE1", unit="pu", info="exciter saturation at E1", typical=0.3),
        Param(name="E2", unit="pu", info="VE of the second saturation point", typical=9.0),
        Param(name="SE2", unit="pu", info="exciter saturation at E2", typical=3.0),
        Param(name="KC", unit="pu", info="rectifier loading factor (commutating reactance); " + _ESAC8B,
              typical=0.0),
        Param(name="KD", unit="pu", info="demagnetising factor (armature reaction); " + _ESAC8B, typical=0.0),
        Param(name="VPIDMAX", unit="pu", info="maximum PID output (not in PSS/E's ESAC8B, which has "
                                              "none: typical the kernel's widest)", typical=20.0),
        Param(name="VPIDMIN", unit="pu", info="minimum PID output (not in PSS/E's ESAC8B, which has "
                                              "none: typical the kernel's widest)", typical=-20.0),
        Param(name="VFEMAX", unit="pu", info="exciter field current limit", typical=999.0, note=_NOT_SIM),
        Param(name="VEMIN", unit="pu", info="minimum exciter output voltage", typical=0.0, note=_NOT_SIM),
    ),
    blocks=(
        Transducer(T="TR"),
        PIDRegulator(KP="KPR", KI="KIR", KD="KDR", TD="TDR", upper="VPIDMAX", lower="VPIDMIN"),
        RegulatorLag(gain="KA", T="TA", upper="VRMAX", lower="VRMIN", vt_scaled=False, output_clamp=False,
                     kc_elsewhere=True),
        ACExciter(T="TE", KE="KE", KD="KD", KC="KC", E1="E1", SE1="SE1", E2="E2", SE2="SE2"),
    ),
    remarks=("KA multiplies the PID's gains: fit KPR, KIR, KDR with KA fixed",),
    dyr_model="ESAC8B",
    source="IEEE Std 421.5-2016 AC8B (sample data: KPR 80, KIR 5, KDR 10, TDR 0.1, TE 1.2, E1 6.5, SE1 0.3, "
           "E2 9, SE2 3); PSS/E model library, ESAC8B (15 fields, no KC, KD); ANDES "
           "andes/models/exciter/ac8b.py (PIDTrackAW, a washout as the derivative)",
)
