"""ESST4B, the IEEE 421.5 type ST4B potential-source static exciter (PSS/E ESST4B; ANDES `ESST4B`)."""
from . import declare
from .blocks import FieldVoltagePI, Param, PIRegulator, PotentialSource, RegulatorLag, Transducer

_NL = "no load: the generator carries no current, so VE = |KP e^(j THETAP) Vt| = KP Vt"
_VG = "VG = KG Efd reaches VGMAX only far above a pulse test's field voltage (ANDES only, not in the .dyr)"

STRUCTURE = declare(
    name="ESST4B",
    title="IEEE 421.5 ST4B potential-source static exciter: PI regulator, lag, inner field-voltage PI, "
          "output VB VM with the rectifier regulation FEX",
    params=(
        Param(name="TR", unit="s", info="voltage transducer time constant", typical=0.01),
        Param(name="KPR", unit="pu", info="proportional gain of the voltage regulator", typical=3.15,
              bounds=(0.3, 30.0), identify=True),
        Param(name="KIR", unit="pu/s", info="integral gain of the voltage regulator", typical=3.15,
              bounds=(0.0, 30.0), identify=True),
        Param(name="VRMAX", unit="pu", info="maximum voltage regulator output", typical=1.0),
        Param(name="VRMIN", unit="pu", info="minimum voltage regulator output", typical=-0.87),
        Param(name="TA", unit="s", info="voltage regulator time constant", typical=0.02, bounds=(0.002, 0.5),
              identify=True),
        Param(name="KPM", unit="pu", info="proportional gain of the field-voltage regulator", typical=1.0),
        Param(name="KIM", unit="pu/s", info="integral gain of the field-voltage regulator", typical=0.0),
        Param(name="VMMAX", unit="pu", info="maximum field-voltage regulator output", typical=1.0),
        Param(name="VMMIN", unit="pu", info="minimum field-voltage regulator output", typical=-0.87),
        Param(name="KG", unit="pu", info="feedback gain of the field-voltage regulator", typical=0.0,
              bounds=(0.0, 1.0), identify=True),
        Param(name="KP", unit="pu", info="potential circuit gain", typical=6.5),
        Param(name="KI", unit="pu", info="compound circuit (current) gain", typical=0.0, note=_NL),
        Param(name="VBMAX", unit="pu", info="maximum available exciter voltage", typical=8.41),
        Param(name="KC", unit="pu", info="rectifier loading factor (commutating reactance)", typical=0.08),
        Param(name="XL", unit="pu", info="reactance of the potential source", typical=0.0, note=_NL),
        Param(name="THETAP", unit="deg", info="potential circuit phase angle", typical=0.0, note=_NL),
    ),
    # the PI takes the kernel's first lead-lag's place, the regulator lag TA carries no ceiling of
    # its own (the kernel's ceilings, which only the diagnosis' ceiling_limit sets, bound Efd = VB VM
    # through VM, not the lag)
    blocks=(
        Transducer(T="TR"),
        PIRegulator(KP="KPR", KI="KIR", upper="VRMAX", lower="VRMIN"),
        RegulatorLag(gain=None, T="TA", vt_scaled=False, output_clamp=True),
        FieldVoltagePI(KP="KPM", KI="KIM", upper="VMMAX", lower="VMMIN", KG="KG"),
        PotentialSource(KP="KP", VBMAX="VBMAX", KC="KC"),
    ),
    swaps=(("regulator limit VRMAX <-> field-voltage regulator limit VMMAX (with KPM = 1, KIM = 0 and KG = 0 "
            "VM = VR, and whichever is lower clips; KG Efd only shifts VM's)", ("VRMAX", "VMMAX")),),
    remarks=("the loop through KG is solved in closed form; KI, XL, THETAP: record only (no load)",),
    dyr_model="ESST4B",
    source="IEEE Std 421.5-2016 ST4B; PSS/E model library, ESST4B; ANDES andes/models/exciter/esst4b.py "
           "(PI regulators with tracking anti-windup, gain 2; " + _VG + ")",
)
