"""Unit files: the built-in reference unit, strict keys, --set overrides, effects."""
from __future__ import annotations

import math
import re

import pytest

from bench_ctl.model.effects import EFFECTS
from bench_ctl.model.params import PARAMS
from bench_ctl.units.overrides import apply_overrides
from bench_ctl.units.unit import UnitError, load_unit, reference_unit


def test_reference_unit_matches_design():
    u = reference_unit()
    assert u.generator == {"Td0p": 7.5, "Td0pp": 0.05, "Vt0": 1.0}
    assert {k: b.value for k, b in u.identify.items()} == {
        "KAVR": 200.0, "TA1": 1.0, "TA2": 0.2, "TA3": 0.5, "TA4": 10.0, "TE": 0.02}
    assert (u.identify["KAVR"].min, u.identify["KAVR"].max) == (50.0, 800.0)
    assert u.constraints == ("TA2 <= TA1", "TA4 >= TA2")
    assert u.effects == {}


def test_every_effect_has_named_params_neutral_and_bounds_inside_physical_range():
    assert set(EFFECTS) == {"ceiling_limit", "dead_time", "transducer_lag", "saturation", "rate_limit",
                            "setpoint_ramp", "recorder_gain", "time_skew"}
    for eff in EFFECTS.values():
        for p in eff.params:
            info = PARAMS[p]
            assert info.neutral is not None
            lo, hi = eff.bounds[p]
            assert info.lo <= lo < hi <= info.hi


def test_unknown_keys_are_errors(tmp_path):
    f = tmp_path / "u.toml"
    f.write_text('name = "x"\ncolour = "red"\n[generator]\nTd0p = 7.5\nTd0pp = 0.05\nVt0 = 1.0\n')
    with pytest.raises(UnitError, match=r"u.toml.*colour"):
        load_unit(f)
    f.write_text('[generator]\nTd0p = 7.5\nTd0pp = 0.05\nVt0 = 1.0\nXd = 1.0\n')
    with pytest.raises(UnitError, match="Xd"):
        load_unit(f)
    f.write_text('[generator]\nTd0p = 7.5\nTd0pp = 0.05\nVt0 = 1.0\n[effects.backlash]\nB = 1\n')
    with pytest.raises(UnitError, match="backlash"):
        load_unit(f)


def test_unit_file_with_effects(tmp_path):
    f = tmp_path / "u.toml"
    f.write_text('constraints = ["TA2 <= TA1"]\n[generator]\nTd0p = 6.0\nTd0pp = 0.04\nVt0 = 1.0\n'
                 '[identify.KAVR]\nmin = 50\nmax = 500\nvalue = 150\n[fixed]\nTA1 = 1.0\n'
                 'TA2 = 0.2\nTA3 = 0.5\nTA4 = 10.0\nTE = 0.02\n'
                 '[effects.ceiling_limit]\nVRMAX = 2.8\nVRMIN = -1.0\n')
    u = load_unit(f)
    v = u.values()
    assert v["VRMAX"] == 2.8 and v["Td0p"] == 6.0 and v["KAVR"] == 150 and v["TA1"] == 1.0
    assert math.isinf(v["RATE"])


GEN = '[generator]\nTd0p = 6.0\nTd0pp = 0.04\nVt0 = 1.0\n'
AVR_FIXED = 'TA1 = 1.0\nTA2 = 0.2\nTA3 = 0.5\nTA4 = 10.0\nTE = 0.02\n'


@pytest.mark.parametrize("text, msg", [
    (GEN + '[identify.KAVR]\nmin = 50\nmax = 500\n[fixed]\nTA1 = 1.0\n',
     "AVR parameter TA2 is neither under"),
    (GEN + '[identify.KAVR]\nmin = 50\nmax = 500\nvalue = 900\n[fixed]\n' + AVR_FIXED,
     r"identify.KAVR.value = 900.0 is outside its bounds \[50.0, 500.0\]"),
    (GEN + '[identify.KAVR]\nmin = -inf\nmax = 500\n[fixed]\n' + AVR_FIXED,
     "identify.KAVR.min = -inf must be finite"),
    (GEN + '[fixed]\nKAVR = 200\n' + AVR_FIXED + 'TR = 5.0\n', "TR = 5.0 s is outside its physical range"),
    (GEN + '[fixed]\nKAVR = 200\nTd0p = 0.0\n' + AVR_FIXED, "fixed.Td0p: a generator constant"),
    ('generator = 3\n', r"generator must be a table \(\[generator\]\)"),
    (GEN + '[fixed]\nKAVR = 200\n' + AVR_FIXED + '[effects]\nceiling_limit = 3\n',
     "effects.ceiling_limit must be a table"),
    (GEN + '[fixed]\nKAVR = 200\n' + AVR_FIXED + '[effects.saturation]\nS10 = 0.3\nS12 = 0.1\n',
     r"S12 = 0.1 breaks S12 >= 1.44\*S10"),
])
def test_unit_file_refusals_name_the_file_and_key(tmp_path, text, msg):
    f = tmp_path / "u.toml"
    f.write_text(text)
    with pytest.raises(UnitError, match=msg) as info:
        load_unit(f)
    assert str(f) in str(info.value)


def test_unit_file_not_utf8_is_refused_with_its_name(tmp_path):
    f = tmp_path / "u.toml"
    f.write_bytes(b"name = '\xff\xfe'\n")
    with pytest.raises(UnitError, match="not a UTF-8 text file"):
        load_unit(f)


def test_overrides_are_checked_once_all_are_in():
    u = apply_overrides(reference_unit(), ["KAVR.max=100", "KAVR=80"])   # fine in that order
    assert u.identify["KAVR"].value == 80
    with pytest.raises(UnitError, match=r"KAVR.value = 200.0 is outside its bounds \[50.0, 100.0\]"):
        apply_overrides(reference_unit(), ["KAVR.max=100"])
    with pytest.raises(UnitError, match="must be finite"):
        apply_overrides(reference_unit(), ["KAVR=inf"])
    with pytest.raises(UnitError, match=r"breaks S12 >= 1.44\*S10"):
        apply_overrides(reference_unit(), ["S10=0.1"])
    u = apply_overrides(reference_unit(), ["S10=0.1", "S12=0.3"])  # one at a time, then checked
    assert u.effects["saturation"] == {"S10": 0.1, "S12": 0.3}


def test_set_overrides():
    u = apply_overrides(reference_unit(), ["Td0p=6.0", "KAVR.min=20", "KAVR=250", "TR=0.01", "VRMAX=2.8",
                                           "weights.vt=0.5"])
    assert u.generator["Td0p"] == 6.0
    assert u.identify["KAVR"].min == 20 and u.identify["KAVR"].value == 250
    assert u.fixed["TR"] == 0.01
    assert u.effects["ceiling_limit"]["VRMAX"] == 2.8 and u.effects["ceiling_limit"]["VRMIN"] == -math.inf
    assert u.weights["vt"] == 0.5


@pytest.mark.parametrize("bad, msg", [("Xd=1", "unknown name 'Xd'"), ("KAVR.min=900", "below max"),
                                      ("Td0p=abc", "not a number"), ("Td0p", "NAME=VALUE"),
                                      ("Td0p=-1", "outside its physical range")])
def test_bad_overrides(bad, msg):
    with pytest.raises(UnitError, match=msg):
        apply_overrides(reference_unit(), [bad])


def test_grid_table_set_and_dyr_give_the_machine_on_the_grid(tmp_path):
    """[grid] (issue 27): the machine's on-line data and the grid, from the unit file, --set (kept
    across --model) and a GENROU record; a key outside the machine's names, or out of range, is named."""
    from bench_ctl.units.overrides import with_model

    ref = tmp_path / "ref.toml"
    text = resources_reference_text()
    ref.write_text(text + "\n[grid]\nXE = 0.25\nH = 4.0\n")
    unit = load_unit(ref)
    assert unit.grid == {"XE": 0.25, "H": 4.0}
    unit = apply_overrides(unit, ["XE=0.3", "P0=0.8"])
    assert with_model(unit, "SEXS").grid == {"XE": 0.3, "H": 4.0, "P0": 0.8}
    assert unit.entry().grid["XE"] == 0.3
    for bad, msg in (("XE = 9.0", "grid.XE = 9.0 pu is outside"), ("XX = 1.0", "[grid] unknown key(s) ['XX']")):
        ref.write_text(text + f"\n[grid]\n{bad}\n")
        with pytest.raises(UnitError) as e:
            load_unit(ref)
        assert msg in str(e.value)
    with pytest.raises(UnitError, match="XE = -1.0 pu is outside"):
        apply_overrides(reference_unit(), ["XE=-1"])


def test_genrou_record_gives_the_machine_data(tmp_path):
    from bench_ctl.units.dyr import read_dyr
    from bench_ctl.units.dyr_unit import machine_from_record

    dyr = tmp_path / "u.dyr"
    dyr.write_text("1 'GENROU' 1 7.5 0.05 0.4 0.05 3.0 0.0 1.8 1.7 0.3 0.55 0.25 0.15 0.05 0.2 /\n")
    rec = read_dyr(dyr)[0]
    assert machine_from_record(rec) == {"XD": 1.8, "XQ": 1.7, "XDP": 0.3, "XQP": 0.55, "XDPP": 0.25, "XLS": 0.15,
                                        "Tq0p": 0.4, "Tq0pp": 0.05, "H": 3.0, "DAMP": 0.0}


def resources_reference_text(grid: bool = False) -> str:
    """The built-in reference unit's file, without its [grid] table unless `grid`."""
    from importlib import resources
    text = resources.files("bench_ctl.data").joinpath("reference_unit.toml").read_text("utf-8")
    return text if grid else re.sub(r"\n\[grid\]\n(?:\w+ = .*\n)+", "\n", text)


def test_the_units_stabiliser_is_picked_by_name_in_grid_and_by_set(tmp_path, capsys):
    """[grid] PSS_MODEL (issue 49): a stabiliser's name or code in the unit file and with --set, its
    PSS2_* values beside it, values that do not go together refused with the name; without it the
    IEEEST of the PSS_* values, as before; `models PSS2B` lists its parameters."""
    from bench_ctl.cli import main
    from bench_ctl.units.overrides import GRID_FITTABLE

    ref = tmp_path / "ref.toml"
    text = resources_reference_text()
    ref.write_text(text + '\n[grid]\nXE = 0.25\nPSS_MODEL = "PSS2B"\nPSS2_KS1 = 12.0\nPSS2_M = 2\nPSS2_N = 4\n')
    unit = load_unit(ref)
    assert unit.grid == {"XE": 0.25, "PSS_MODEL": 3.0, "PSS2_KS1": 12.0, "PSS2_M": 2.0, "PSS2_N": 4.0}
    assert apply_overrides(unit, ["PSS_MODEL=pss2a"]).grid["PSS_MODEL"] == 2.0
    assert apply_overrides(unit, ["PSS_MODEL=1"]).grid["PSS_MODEL"] == 1.0
    for bad, msg in (('PSS_MODEL = "PSS4B"', "unknown stabiliser 'PSS4B'"),
                     ('PSS_MODEL = "PSS2A"\nPSS2_M = 3\nPSS2_N = 3', "grid.PSS2_M = 3, PSS2_N = 3: M N = 9 lags"),
                     ('PSS_MODEL = 3\nPSS2_T9 = 0', "grid.PSS2_T9 = 0"),
                     ("PSS2_VSTMAX = 2.0", "PSS2_VSTMAX = 2.0 pu is outside")):
        ref.write_text(text + f"\n[grid]\n{bad}\n")
        with pytest.raises(UnitError, match=re.escape(msg)):
            load_unit(ref)
    with pytest.raises(UnitError, match="M N = 12 lags"):
        apply_overrides(unit, ["PSS2_M=3"])
    with pytest.raises(UnitError, match="unknown stabiliser"):
        apply_overrides(unit, ["PSS_MODEL=ST2CUT"])
    assert "PSS2_KS1" in GRID_FITTABLE and not {"PSS_MODEL", "PSS2_M", "PSS2_N"} & set(GRID_FITTABLE)
    assert "PSS_MODEL" not in reference_unit().grid   # IEEEST when absent: the PSS_* values, unchanged
    assert main(["models", "PSS2B"]) == 0
    out = capsys.readouterr().out
    for words in ("PSS2_KS1", "PSS2_VS2MAX", "PSS2_T11", "[(1 + s T8)/(1 + s T9)^M]^N", "OpenIPSL"):
        assert words in out
    assert main(["models", "PSS2A"]) == 0
    assert "PSS2_T10" not in capsys.readouterr().out
    assert main(["models"]) == 0
    assert "PSS2B" in capsys.readouterr().out
    # export: an IEEEST record for an IEEEST, a PSS2B record for a PSS2B (tests/model/test_dyr_pss2.py)
    from bench_ctl.units.dyr_export import pss_record

    assert pss_record({"PSS_MODEL": 3.0, "PSS_KS": 10.0}, 1, "1") is None   # KS1 0: no stabiliser
    assert pss_record({"PSS_MODEL": 3.0, "PSS2_KS1": 10.0}, 1, "1").model == "PSS2B"
    assert pss_record({"PSS_KS": 10.0}, 1, "1").model == "IEEEST"
