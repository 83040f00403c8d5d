"""ESST4B, the IEEE 421.5 type ST4B potential-source static exciter (PSS/E ESST4B; ANDES `ESST4B`)."""
from . import StdParam, Structure

_NL = "no load: the generator carries no current, so VE = |KP e^(j THETAP) Vt| = KP Vt"
_VG = "VG = KG Efd reaches VGMAX only far above a pulse test's field voltage (ANDES only, not in the .dyr)"

STRUCTURE = Structure(
    name="ESST4B",
    title="IEEE 421.5 ST4B potential-source static exciter: PI regulator, lag, inner field-voltage PI, "
          "output VB VM with the rectifier regulation FEX",
    diagram=(
        "Vc = Vt / (1 + s TR)",
        "VR = (KPR + KIR/s)(Vref - Vc), limited to [VRMIN, VRMAX] (anti-windup by tracking)",
        "VA = VR / (1 + s TA)",
        "VM = (KPM + KIM/s)(VA - KG Efd), limited to [VMMIN, VMMAX] (anti-windup by tracking)",
        "VB = VE FEX(IN), VE = KP Vt (no load), IN = KC Ifd / VE, VB <= VBMAX",
        "FEX = 1 - 0.577 IN (IN <= 0.433), sqrt(0.75 - IN^2) (<= 0.75), 1.732 (1 - IN) (<= 1), 0",
        "Efd = VB VM  (the loop through KG solved in closed form)",
    ),
    params=(
        StdParam("TR", "s", "voltage transducer time constant", 0.01, None, "TR"),
        StdParam("KPR", "pu", "proportional gain of the voltage regulator", 3.15, (0.3, 30.0), "KPI", True),
        StdParam("KIR", "pu/s", "integral gain of the voltage regulator", 3.15, (0.0, 30.0), "KII", True),
        StdParam("VRMAX", "pu", "maximum voltage regulator output", 1.0, None, "VPMAX"),
        StdParam("VRMIN", "pu", "minimum voltage regulator output", -0.87, None, "VPMIN"),
        StdParam("TA", "s", "voltage regulator time constant", 0.02, (0.002, 0.5), "TE", True),
        StdParam("KPM", "pu", "proportional gain of the field-voltage regulator", 1.0, None, "KPM"),
        StdParam("KIM", "pu/s", "integral gain of the field-voltage regulator", 0.0, None, "KIM"),
        StdParam("VMMAX", "pu", "maximum field-voltage regulator output", 1.0, None, "VMMAX"),
        StdParam("VMMIN", "pu", "minimum field-voltage regulator output", -0.87, None, "VMMIN"),
        StdParam("KG", "pu", "feedback gain of the field-voltage regulator", 0.0, None, "KG"),
        StdParam("KP", "pu", "potential circuit gain", 6.5, None, "KPV"),
        StdParam("KI", "pu", "compound circuit (current) gain", 0.0, None, None, note=_NL),
        StdParam("VBMAX", "pu", "maximum available exciter voltage", 8.41, None, "VBMAX"),
        StdParam("KC", "pu", "rectifier loading factor (commutating reactance)", 0.08, None, "KC"),
        StdParam("XL", "pu", "reactance of the potential source", 0.0, None, None, note=_NL),
        StdParam("THETAP", "deg", "potential circuit phase angle", 0.0, None, None, note=_NL),
    ),
    # the kernel's first lead-lag becomes the PI (KPV > 0), the second is bypassed, the regulator
    # lag is TA and carries no ceiling of its own (LIMOUT 1: the kernel's ceilings, which only the
    # diagnosis' ceiling_limit sets, bound Efd = VB VM through VM, not the lag)
    settings={"KAVR": 1.0, "TA1": 1.0, "TA2": 1.0, "TA3": 1.0, "TA4": 1.0, "VRVT": 0.0, "LIMOUT": 1.0},
    dyr_model="ESST4B",
    source="IEEE Std 421.5-2016 ST4B; PSS/E model library, ESST4B; ANDES andes/models/exciter/esst4b.py "
           "(PI regulators with tracking anti-windup, gain 2; " + _VG + ")",
)
