"""ESAC1A, the IEEE 421.5 type AC1A rotating exciter with a diode rectifier (PSS/E ESAC1A; ANDES `ESAC1A`)."""
from . import declare
from .blocks import ACExciter, LeadLag, Param, RateFeedback, RegulatorLag, Transducer

_VR = ("VR = VA limited to [VRMIN, VRMAX] after the under- / over-excitation gates: not simulated (as in "
       "ANDES' ESAC1A); it acts only when VA passes it, far above a pulse test's field voltage")

STRUCTURE = declare(
    name="ESAC1A",
    title="IEEE 421.5 AC1A exciter: lead-lag, regulator with non-windup VA limits, AC exciter with "
          "saturation, demagnetisation and rectifier regulation, rate feedback from VFE",
    params=(
        Param(name="TR", unit="s", info="voltage transducer time constant", typical=0.0),
        Param(name="TB", unit="s", info="lag time constant (typical 1 = TC: no lead-lag, as the sample's 0, 0)",
              typical=1.0, bounds=(0.5, 50.0), identify=True),
        Param(name="TC", unit="s", info="lead time constant (typical 1 = TB: no lead-lag, as the sample's 0, 0)",
              typical=1.0, bounds=(0.05, 5.0), identify=True),
        Param(name="KA", unit="pu/pu", info="regulator gain", typical=400.0, bounds=(20.0, 1000.0), identify=True),
        Param(name="TA", unit="s", info="regulator time constant", typical=0.02, bounds=(0.002, 0.5), identify=True),
        Param(name="VAMAX", unit="pu", info="maximum regulator output VA", typical=14.5),
        Param(name="VAMIN", unit="pu", info="minimum regulator output VA", typical=-14.5),
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
        Param(name="VRMAX", unit="pu", info="maximum exciter field voltage VR", typical=6.03, note=_VR),
        Param(name="VRMIN", unit="pu", info="minimum exciter field voltage VR", typical=-5.43, note=_VR),
    ),
    blocks=(
        Transducer(T="TR"),
        LeadLag(lead="TC", lag="TB"),     # TB = TC = 0 (a record's "none") or TB = TC: no lead-lag
        RegulatorLag(gain="KA", T="TA", upper="VAMAX", lower="VAMIN", vt_scaled=False, output_clamp=False,
                     kc_elsewhere=True),
        ACExciter(T="TE", KE="KE", KD="KD", KC="KC", E1="E1", SE1="SE1", E2="E2", SE2="SE2"),
        RateFeedback(K="KF", T="TF", source="VFE"),
    ),
    remarks=("on a pulse test the same equations as EXAC1, its VA limits in the place of EXAC1's VR limits",),
    dyr_model="ESAC1A",
    pulse_twin="EXAC1",
    source="IEEE Std 421.5-2016 AC1A; PSS/E model library, ESAC1A; ANDES andes/models/exciter/esac1a.py",
)
