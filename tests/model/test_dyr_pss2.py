"""PSS2A / PSS2B records (issue 49 item 1): PSS/E's field order pinned by hand-written records,
`--from-dyr` giving the unit its stabiliser, `export --dyr` writing it, read back the same, and the
inputs bench-ctl does not simulate refused naming file, line and field."""
from __future__ import annotations

import math

import pytest

from bench_ctl.cli import main
from bench_ctl.units.dyr import DyrError, dyr_text, parse_dyr, read_dyr
from bench_ctl.units.dyr_export import pss_record
from bench_ctl.units.dyr_unit import unit_from_dyr
from bench_ctl.units.unit import UnitError, reference_unit

PLANT = """// a salient-pole unit with its static exciter
  101 'GENSAL' 1   5.0  0.05  0.1  3.5  0.0  1.0  0.65  0.3  0.22  0.15  0.1  0.3 /
  101 'ESST1A' 1   1  1  0.01  99  -99  1  10  1  1  200  0.02  4  -4  4  -4  0.1  0  1  0  3  /
"""
#: PSS/E's order, written by hand: ICS1 IB1 ICS2 IB2 M N, TW1 TW2 T6 TW3 TW4 T7 KS2 KS3 T8 T9 KS1
#: T1 T2 T3 T4, then (PSS2B) T10 T11 VS1MAX VS1MIN VS2MAX VS2MIN, then VSTMAX VSTMIN
PSS2B = ("  101 'PSS2B' 1   {ics1} {ib1} {ics2} {ib2} 4 2\n"
         "    2.1 2.2 0.03 2.4 2.5 2.6 0.27 1.1 0.29 0.031\n"
         "    12.5 0.33 0.034 0.35 0.036 0.37 0.038 0.05 -0.06 1.2 0.4 0.11 -0.12 /\n")
PSS2A = ("  101 'PSS2A' 1   1 0 3 0 5 1\n"
         "    3.1 3.2 0.0 3.4 0.0 3.6 0.37 1.0 0.5 0.1 8.5 0.16 0.02 0.26 0.03 0.09 -0.08 /\n")


def _file(tmp_path, text, name="plant.dyr"):
    path = tmp_path / name
    path.write_text(PLANT + text)
    return path


def test_the_records_read_in_psse_field_order(tmp_path):
    path = _file(tmp_path, PSS2B.format(ics1=1, ib1=0, ics2=3, ib2=0))
    rec = read_dyr(path)[2]
    assert rec.icons == {"ICS1": 1, "IB1": 0, "ICS2": 3, "IB2": 0, "M": 4, "N": 2}
    assert (rec.values["TW1"], rec.values["T6"], rec.values["KS2"], rec.values["T9"], rec.values["KS1"]) == (
        2.1, 0.03, 0.27, 0.031, 12.5)
    assert (rec.values["T4"], rec.values["T10"], rec.values["T11"]) == (0.036, 0.37, 0.038)
    assert (rec.values["VS1MAX"], rec.values["VS1MIN"], rec.values["VS2MAX"], rec.values["VS2MIN"]) == (
        0.05, -0.06, 1.2, 0.4)
    assert (rec.values["VSTMAX"], rec.values["VSTMIN"]) == (0.11, -0.12)
    g = unit_from_dyr(reference_unit(), path).grid
    assert g["PSS_MODEL"] == 3.0 and (g["PSS2_M"], g["PSS2_N"]) == (4.0, 2.0)
    assert (g["PSS2_KS1"], g["PSS2_T8"], g["PSS2_T11"], g["PSS2_VS2MIN"]) == (12.5, 0.29, 0.038, 0.4)
    a = unit_from_dyr(reference_unit(), _file(tmp_path, PSS2A, "a.dyr"))
    assert a.grid["PSS_MODEL"] == 2.0 and a.grid["PSS2_KS1"] == 8.5 and a.grid["PSS2_VSTMIN"] == -0.08
    assert "PSS2_T10" not in a.grid and a.name == "a.dyr bus 101 ID 1 (GENSAL + ESST1A)"
    with pytest.raises(DyrError, match=r"PSS2A: expected 6 ICONs and 17 CONs \(23 fields\), found 22"):
        parse_dyr("1 'PSS2A' 1  1 0 3 0 5 1  " + "1 " * 16 + "/\n", "short.dyr")


def test_the_records_stabiliser_replaces_the_units_own(tmp_path):
    """A unit file's PSS2B must not hide the record's IEEEST (IEEEST is PSS_MODEL absent), nor its
    IEEEST the record's PSS2A."""
    from dataclasses import replace

    own = replace(reference_unit(), grid={**reference_unit().grid, "PSS_MODEL": 3.0, "PSS2_KS1": 4.0})
    ieeest = "  101 'IEEEST' 1   1 0  0 0 0 0 0 0  0.2 0.02 0.15 0.03 5 10  30  0.1 -0.1  0 0 /\n"
    g = unit_from_dyr(own, _file(tmp_path, ieeest)).grid
    assert "PSS_MODEL" not in g and g["PSS_KS"] == 15.0
    g = unit_from_dyr(replace(reference_unit(), grid={**reference_unit().grid, "PSS_KS": 9.0}),
                      _file(tmp_path, PSS2A, "a.dyr")).grid
    assert g["PSS_MODEL"] == 2.0 and g["PSS2_KS1"] == 8.5


@pytest.mark.parametrize("model", ["PSS2A", "PSS2B"])
def test_a_written_record_reads_back_the_same_values(tmp_path, model):
    grid = {"PSS_MODEL": {"PSS2A": 2.0, "PSS2B": 3.0}[model], "PSS2_KS1": 17.25, "PSS2_TW1": 4.5,
            "PSS2_TW2": 0.0, "PSS2_T6": 0.015, "PSS2_TW3": 3.5, "PSS2_TW4": 2.5, "PSS2_T7": 3.5, "PSS2_KS2": 0.4375,
            "PSS2_KS3": 1.25,
            "PSS2_T8": 0.45, "PSS2_T9": 0.09, "PSS2_M": 2.0, "PSS2_N": 3.0, "PSS2_T1": 0.21, "PSS2_T2": 0.023,
            "PSS2_T3": 0.3, "PSS2_T4": 0.6, "PSS2_VSTMAX": 0.085, "PSS2_VSTMIN": -0.075}
    if model == "PSS2B":   # one input limit open (written +-999, read back open), one closed
        grid.update(PSS2_T10=0.12, PSS2_T11=0.04, PSS2_VS1MAX=math.inf, PSS2_VS1MIN=-math.inf,
                    PSS2_VS2MAX=1.15, PSS2_VS2MIN=-0.05)
    rec = pss_record(grid, 101, "1")
    assert rec.model == model and rec.icons == {"ICS1": 1, "IB1": 0, "ICS2": 3, "IB2": 0, "M": 2, "N": 3}
    path = _file(tmp_path, dyr_text([(rec, "written by pss_record")]))
    if model == "PSS2B":
        written = read_dyr(path)[2].values
        assert [written[k] for k in ("VS1MAX", "VS1MIN", "VS2MAX", "VS2MIN")] == [999.0, -999.0, 1.15, -0.05]
    back = unit_from_dyr(reference_unit(), path).grid
    assert {k: back[k] for k in grid} == grid
    assert not {k for k in back if k.startswith("PSS2_")} - set(grid)   # nothing more than the record's


@pytest.mark.parametrize(("icons", "expect"), [
    ({"ics1": 2}, r"plant.dyr:4: PSS2B ICS1 = 2: bench-ctl's PSS2B reads the rotor speed deviation as input 1"),
    ({"ics2": 4}, r"plant.dyr:4: PSS2B ICS2 = 4: bench-ctl's PSS2B reads the electrical power as input 2"),
    ({"ics1": 3, "ics2": 1}, r"plant.dyr:4: PSS2B ICS1 = 3"),
    ({"ib1": 205}, r"plant.dyr:4: PSS2B IB1 = 205: a remote bus's signal is not simulated"),
    ({"ib2": 7}, r"plant.dyr:4: PSS2B IB2 = 7: a remote bus"),
])
def test_an_input_bench_ctl_does_not_simulate_is_refused_naming_line_and_field(tmp_path, icons, expect):
    """Run with the machine's own speed and power in their place, the record would be another
    stabiliser."""
    path = _file(tmp_path, PSS2B.format(**{"ics1": 1, "ib1": 0, "ics2": 3, "ib2": 0, **icons}))
    with pytest.raises(UnitError, match=expect):
        unit_from_dyr(reference_unit(), path)
    # and on the command line: exit 2, the field named, nothing written
    out = tmp_path / "s.csv"
    assert main(["simulate", "--from-dyr", str(path), "--duration", "2", "-o", str(out)]) == 2
    assert not out.exists()


def test_a_time_constant_or_filter_the_stabiliser_cannot_run_is_refused(tmp_path):
    bad = PSS2B.format(ics1=1, ib1=0, ics2=3, ib2=0).replace(" 0.29 ", " -0.29 ")
    with pytest.raises(UnitError, match=r"plant.dyr:4: PSS2B T8 = -0.29 s: a time constant cannot be negative"):
        unit_from_dyr(reference_unit(), _file(tmp_path, bad))
    many = PSS2B.format(ics1=1, ib1=0, ics2=3, ib2=0).replace(" 4 2\n", " 5 2\n")
    with pytest.raises(UnitError, match=r"PSS2_M = 5, PSS2_N = 2: M N = 10 lags, at most 8"):
        unit_from_dyr(reference_unit(), _file(tmp_path, many, "many.dyr"))


def test_export_writes_the_units_pss2b_and_from_dyr_reads_it_back(tmp_path, capsys):
    cap = tmp_path / "sexs.csv"
    assert main(["simulate", "--model", "SEXS", "-o", str(cap), "--duration", "3"]) == 0
    pss = {"PSS2_KS1": 9.5, "PSS2_T1": 0.18, "PSS2_T2": 0.03, "PSS2_T10": 0.2, "PSS2_T11": 0.05,
           "PSS2_VS2MAX": 1.1, "PSS2_VS2MIN": 0.0, "PSS2_M": 4.0, "PSS2_N": 1.0}
    res = tmp_path / "r.json"
    assert main(["identify", str(cap), "--model", "SEXS", "--evals", "40", "--json", str(res), "--no-progress",
                 "--set", "PSS_MODEL=PSS2B", *[a for k, v in pss.items() for a in ("--set", f"{k}={v}")]]) in (0, 1)
    out = tmp_path / "unit.dyr"
    capsys.readouterr()
    assert main(["export", str(res), "--dyr", str(out), "--bus", "3"]) == 0
    assert "and its stabiliser as PSS2B (KS1 9.5)" in capsys.readouterr().out
    exc, st = read_dyr(out)
    assert (exc.model, st.model, st.bus, st.id) == ("SEXS", "PSS2B", 3, "1")
    assert st.icons == {"ICS1": 1, "IB1": 0, "ICS2": 3, "IB2": 0, "M": 4, "N": 1}
    assert (st.values["VS1MAX"], st.values["VS1MIN"]) == (999.0, -999.0)   # open: the default
    g = unit_from_dyr(reference_unit(), out).grid
    assert g["PSS_MODEL"] == 3.0 and {k: g[k] for k in pss} == pss
