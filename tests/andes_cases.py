"""Blind-suite cases from another simulator: the ANDES captures (tests/fixtures/andes).

The plant dynamics are ANDES' (a no-load GENROU with saturation S(1.0) 0.05, S(1.2) 0.2 and a
standard exciter, benchmarks/andes_captures.py); bench_ctl's model made none of these records.
Each case is diagnosed with the capture's own structure as a commissioning engineer would have it
from the data sheets (`andes_units.fixture_unit(true_values=False)`: the generator and every
exciter value but the identified ones; the identified ones start at the structure's typical
values) and is told nothing else. What is withheld:

* ``none``: nothing; the unit knows the generator's saturation. Every fixture in turn. (EXST1's
  ceilings are opened in every case: ANDES 2.0's EXST1 clamps another signal, so they never act
  in its records, as the data sheet of what ANDES simulated would say.)
* ``saturation``: the unit is given no saturation (ANDES' is in every record). Every fixture.
* ``ceiling_limit``: the unit's own ceilings opened wide (VRMAX / VRMIN, and ESST4B's VMMAX /
  VMMIN at +-20 pu), on the captures whose efd rides a limit in ANDES (manifest `ceiling_ms` /
  `floor_ms` > 0; EXST1 excepted: ANDES 2.0's EXST1 clamps another signal, its ceilings never act).
* ``recorder_gain`` and ``time_skew``: the recorder's, applied to ANDES' efd channel as a recorder
  does (efd scaled by GAIN 3-10 % high or low; efd read SKEW 5-30 ms late, interpolated in ANDES'
  1 kHz record), magnitudes drawn as the independent plant draws them. Every fixture.

Every record gets recorder noise (0.01 pu on efd, 0.002 pu on Vt) with its own seed, and keeps
ANDES' field current (`ifd`) so the ceiling is also tried with the commutation drop. There is no
holdout: the fixtures of one exciter differ a little in their values, so the check is the windows
of the record. The j-th case of an effect takes the (j mod n)-th eligible fixture, with a fresh
noise seed (and magnitude) each time round.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

import independent_plant as ip
from andes_units import fixture_column, fixture_unit, manifest, read_fixture
from bench_ctl.capture import Capture
from bench_ctl.diagnosis.blind import NONE, Case
from bench_ctl.units.overrides import apply_overrides

#: the effects an ANDES record can carry without editing ANDES' models
EFFECTS = ("saturation", "ceiling_limit", "recorder_gain", "time_skew")
WIDE = 20.0   # the physical range of the limit parameters (bench_ctl.model.params)


#: the exciters of the fixtures the suite was measured on (EXAC1's joined the fixtures later: with
#: them the j-th case of an effect would draw another fixture, and the figures would not compare)
SUITE_EXCITERS = ("ESST1A", "ESST4B", "EXST1", "IEEEX1", "SEXS")


def eligible(effect: str) -> list[str]:
    """The fixtures a case of `effect` can be drawn from."""
    caps = manifest()["captures"]
    names = sorted(n for n in caps if caps[n]["exciter"] in SUITE_EXCITERS)
    if effect == "ceiling_limit":
        return [n for n in names if caps[n]["exciter"] != "EXST1"
                and caps[n]["ceiling_ms"] + caps[n]["floor_ms"] > 0]
    if effect in (NONE,) + EFFECTS:
        return names
    raise ValueError(f"the ANDES source cannot carry {effect!r}; it has {', '.join(EFFECTS)} and none")


def andes_case(effect: str, j: int, seed: int = 0) -> Case:
    """The j-th case of `effect` ("none" for none) drawn from the ANDES fixtures."""
    names = eligible(effect)
    name = names[j % len(names)]
    rng = np.random.default_rng([seed, j, 0xA11D])
    base = read_fixture(name)
    unit = fixture_unit(name, true_values=False)
    if unit.model == "EXST1":
        # what ANDES simulated: its EXST1 clamps another signal, its ceilings never act (the
        # reproduction in benchmarks/model_library.py opens them the same way)
        unit = apply_overrides(unit, [f"VRMAX={WIDE}", f"VRMIN={-WIDE}"])
    efd = base.efd.copy()
    params: dict[str, float] = {}
    if effect == "saturation":
        unit = replace(unit, effects={k: v for k, v in unit.effects.items() if k != "saturation"})
        g = manifest()["generator_params"]
        params = {"S10": float(g["S10"]), "S12": float(1.2 * g["S12"])}
    elif effect == "ceiling_limit":
        st = unit.structure
        wide = [f"{k}={WIDE}" for k in ("VRMAX", "VMMAX") if k in st.names]
        wide += [f"{k}={-WIDE}" for k in ("VRMIN", "VMMIN") if k in st.names]
        params = {k: float(v) for k, v in manifest()["captures"][name]["exciter_params"].items()
                  if k in ("VRMAX", "VRMIN", "VMMAX", "VMMIN")}
        unit = apply_overrides(unit, wide)
    elif effect == "recorder_gain":
        params = ip.draw_effect("recorder_gain", rng, efd, 1e-3)
        efd = params["GAIN"] * efd
    elif effect == "time_skew":
        params = ip.draw_effect("time_skew", rng, efd, 1e-3)
        efd = np.interp(base.time - params["SKEW"], base.time, efd, left=efd[0])
    noise = rng.normal(0.0, 0.01, base.n)
    noise_vt = rng.normal(0.0, 0.002, base.n)
    label = f"andes-{effect}-{name}-{j}"
    cap = Capture(base.time, base.usetp, efd + noise, base.vt + noise_vt,
                  extra={"ifd": fixture_column(name, "ifd")}, source=label,
                  meta={"source": f"ANDES fixture {name} (tests/fixtures/andes)"})
    return Case(f"{effect}-{name}-{j}", effect, params, {}, cap, None, unit=unit)


def andes_suite(cases_per_effect: int, none_cases: int, seed: int = 0, effects=None) -> list[Case]:
    effects = [e for e in (effects or EFFECTS)]
    for e in effects:
        if "+" in e or e not in EFFECTS:
            raise ValueError(f"the ANDES source cannot carry {e!r}; it has {', '.join(EFFECTS)} and none")
    cases = []
    for name in effects + [NONE]:
        for j in range(none_cases if name == NONE else cases_per_effect):
            cases.append(andes_case(name, j, seed))
    return cases
