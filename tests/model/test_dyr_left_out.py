"""`--from-dyr` never replaces what it cannot read in silence (issue 48 item 9, issue 49 item 6),
`export --id` writes only what reads back (issue 48 item 10), and the identify header names the
unit the record made (issue 49 item 7)."""
from __future__ import annotations

import pytest

from bench_ctl.cli import main
from bench_ctl.commands.identify import unit_line
from bench_ctl.units.dyr import DyrError, DyrRecord, check_bus_id, format_record, read_dyr
from bench_ctl.units.dyr_unit import unit_from_dyr
from bench_ctl.units.unit import UnitError, reference_unit

GENROU = "  101 'GENROU' 1   8.0 0.03 0.4 0.05 6.5 0.0 1.8 1.7 0.3 0.55 0.25 0.2 {s10} {s12} /\n"
#: an IEEE type 1 DC exciter, as IEEEX1 writes it: TR KA TA TB TC VRMAX VRMIN KE TE KF TF1 SWITCH E1 SE1 E2 SE2
DC1 = "0.02 40 0.04 1.0 1.0 7.3 -7.3 1.0 0.5 0.03 1.0 0 2.5 0.05 3.5 0.3"


def _file(tmp_path, *records, name="plant.dyr", s10="0.0392", s12="0.2672"):
    path = tmp_path / name
    path.write_text("// a planning record\n" + GENROU.format(s10=s10, s12=s12) + "".join(records))
    return path


def test_esdc1a_and_ieeet1_are_read_as_ieeex1_and_said(tmp_path):
    x1 = unit_from_dyr(reference_unit(), _file(tmp_path, f"  101 'IEEEX1' 1 {DC1} /\n", name="x1.dyr"))
    notes: list[str] = []
    dc1a = unit_from_dyr(reference_unit(), _file(tmp_path, f"  101 'ESDC1A' 1 {DC1} /\n", name="dc1a.dyr"),
                         notes=notes)
    assert dc1a.model == "IEEEX1" and dc1a.values() == x1.values()
    assert len(notes) == 1 and "ESDC1A at " in notes[0] and "dc1a.dyr:3 is read as IEEEX1: the same equations" \
        in notes[0]
    # IEEET1: TR KA TA VRMAX VRMIN KE TE KF TF SWITCH E1 SE1 E2 SE2, no lead-lag
    t1 = "0.02 40 0.04 7.3 -7.3 1.0 0.5 0.03 1.0 0 2.5 0.05 3.5 0.3"
    notes = []
    ieeet1 = unit_from_dyr(reference_unit(), _file(tmp_path, f"  101 'IEEET1' 1 {t1} /\n", name="t1.dyr"),
                           notes=notes)
    std = ieeet1.standard_values()
    assert ieeet1.model == "IEEEX1" and std["TB"] == 0.0 and std["TC"] == 0.0 and std["TF1"] == 1.0
    assert "lead-lag bypassed (TB = TC = 0)" in notes[0]
    bypassed = DC1.replace("1.0 1.0 7.3", "0 0 7.3")
    no_ll = unit_from_dyr(reference_unit(), _file(tmp_path, f"  101 'IEEEX1' 1 {bypassed} /\n", name="x1b.dyr"))
    assert ieeet1.values() == no_ll.values()


@pytest.mark.parametrize("record, expect", [
    (f"  101 'ESDC2A' 1 {DC1} /\n", r"ESDC2A at .*plant.dyr:3: an exciter model bench-ctl does not have"),
    ("  101 'SCRX' 1 0.1 10 200 0.05 -5 5 0 0 /\n", r"SCRX at .*plant.dyr:3: an exciter model"),
])
def test_an_exciter_model_the_library_does_not_have_is_refused(tmp_path, record, expect):
    """It ran the REFERENCE structure (and was exported as ESST1A)."""
    with pytest.raises(UnitError, match=expect):
        unit_from_dyr(reference_unit(), _file(tmp_path, record))


def test_two_generator_or_exciter_records_for_one_machine_are_refused(tmp_path):
    path = _file(tmp_path, f"  101 'IEEEX1' 1 {DC1} /\n", GENROU.format(s10="0.05", s12="0.3"))
    with pytest.raises(UnitError, match=r"2 generator records for one machine \(bus 101, ID 1\): GENROU at "
                                        r".*plant.dyr:2, GENROU at .*plant.dyr:4"):
        unit_from_dyr(reference_unit(), path)
    path = _file(tmp_path, f"  101 'IEEEX1' 1 {DC1} /\n", f"  101 'ESDC1A' 1 {DC1} /\n", name="two_exc.dyr")
    with pytest.raises(UnitError, match=r"2 exciter records for one machine"):
        unit_from_dyr(reference_unit(), path)


@pytest.mark.parametrize("s10, s12, expect", [
    ("-0.05", "0.2", "a saturation factor cannot be negative"),
    ("0.05", "0.0", r"S\(1.2\) = 0 with S\(1.0\) = 0.05: no curve through them"),
    ("0.0", "0.2", r"S\(1.0\) = 0 with S\(1.2\) = 0.2: .* would drop S\(1.2\)"),
    ("0.3", "0.2", r"Sat\(1.2\) = 1.2 S\(1.2\) = 0.24 is not above Sat\(1.0\) = 0.3"),
])
def test_a_saturation_the_curve_cannot_hold_is_refused_naming_the_line(tmp_path, s10, s12, expect):
    """They ran without saturation."""
    path = _file(tmp_path, f"  101 'IEEEX1' 1 {DC1} /\n", s10=s10, s12=s12)
    with pytest.raises(UnitError, match=expect) as info:
        unit_from_dyr(reference_unit(), path)
    assert "plant.dyr:2: GENROU" in str(info.value)
    # no saturation at all (both 0) is the record's own value
    assert unit_from_dyr(reference_unit(), _file(tmp_path, f"  101 'IEEEX1' 1 {DC1} /\n", name="ok.dyr",
                                                  s10="0", s12="0")).values()["S10"] == 0.0


def test_a_stabiliser_or_limiter_it_cannot_model_stops_unless_left_out_by_name(tmp_path, capsys):
    """PSS3B: a stabiliser bench-ctl does not model (PSS2B is read since issue 49: test_dyr_pss2.py)."""
    path = _file(tmp_path, f"  101 'IEEEX1' 1 {DC1} /\n",
                 "  101 'PSS3B' 1  1 1 2 1  10 10 10 0 0.1 0.5 1 1 1 2 0.1 0.1 0.02 0.1 0.02 0.1 0.05 1 0 /\n",
                 "  101 'OEL1B' 1  1 2 3 4 5 6 /\n",
                 "  101 'HYGOV' 1  0.05 0.02 5 0.04 0.5 0.2 1 0 1.2 1 0.5 0.08 /\n",
                 "  101 'XYZ9' 1  1 2 /\n",
                 "  102 'PSS3B' 1  1 1 2 1 /\n")
    with pytest.raises(UnitError) as info:
        unit_from_dyr(reference_unit(), path)
    msg = str(info.value)
    assert "PSS3B (stabiliser) at " in msg and "plant.dyr:4" in msg and "OEL1B (limiter) at " in msg
    assert "--dyr-ignore PSS3B --dyr-ignore OEL1B" in msg and "HYGOV" not in msg
    notes: list[str] = []
    u = unit_from_dyr(reference_unit(), path, ignore=("PSS3B", "oel1b"), notes=notes)
    assert u.model == "IEEEX1" and "PSS_KS" not in u.grid
    said = "\n".join(notes)
    for what in ("PSS3B (stabiliser) at", "as --dyr-ignore PSS3B asks", "OEL1B (limiter)",
                 "HYGOV (governor or turbine) at", "XYZ9 (a model bench-ctl does not know)"):
        assert what in said, said
    assert "plant.dyr:9" not in said                       # another machine's record is not the unit's
    assert "left out: PSS3B (stabiliser)" in u.source and "HYGOV" in u.source
    assert u.name == "plant.dyr bus 101 ID 1 (GENROU + IEEEX1)"
    with pytest.raises(UnitError, match=r"--dyr-ignore PSS4B: no such record"):
        unit_from_dyr(reference_unit(), path, ignore=("PSS4B",))
    # the command line: refused (exit 2) without the option, the notes on stderr with it
    out = tmp_path / "c.csv"
    assert main(["simulate", "--from-dyr", str(path), "--model", "IEEEX1", "--duration", "4", "-o", str(out)]) == 2
    assert "--dyr-ignore PSS3B" in capsys.readouterr().err and not out.exists()
    assert main(["simulate", "--from-dyr", str(path), "--dyr-ignore", "PSS3B", "--dyr-ignore", "OEL1B",
                 "--duration", "4", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "note: --from-dyr: PSS3B (stabiliser) at" in err and "HYGOV (governor or turbine)" in err
    assert main(["simulate", "--dyr-ignore", "PSS3B", "-o", str(tmp_path / "d.csv")]) == 2


def test_the_ieeest_stays_accepted_and_a_unit_without_generator_record_says_so(tmp_path):
    path = tmp_path / "exc_only.dyr"
    path.write_text(f"  7 'IEEEX1' 1 {DC1} /\n  7 'IEEEST' 1   1 0  0 0 0 0 0 0  0.2 0.02 0.15 0.03 5 10  30  "
                    "0.1 -0.1  0 0 /\n")
    notes: list[str] = []
    u = unit_from_dyr(reference_unit(), path, notes=notes)
    assert u.grid["PSS_KS"] == 15.0 and u.name == "exc_only.dyr bus 7 ID 1 (IEEEX1)"
    assert notes == ["no generator record for bus 7, ID 1: the unit's own generator constants are kept "
                     "(T'd0 7.5 s, T''d0 0.05 s)"]


@pytest.mark.parametrize("bus, ident, expect", [
    (1, "", "an empty machine ID"),
    (1, "1 ", "PSS/E pads IDs with blanks"),
    (1, " ", "PSS/E pads IDs with blanks"),
    (1, "a/", "'/' cannot be in an ID"),
    (1, "'", "\"'\" cannot be in an ID"),
    (1, "A B", "' ' cannot be in an ID"),
    (1, "ABC", "one or two characters"),
    (0, "1", "bus 0: PSS/E's bus numbers are 1 .. 999997"),
    (-4, "1", "bus -4"),
])
def test_export_refuses_an_id_or_bus_that_does_not_read_back(bus, ident, expect):
    with pytest.raises(DyrError, match=expect):
        check_bus_id(bus, ident)
    rec = DyrRecord(bus, "SEXS", ident, {"TA/TB": 0.1, "TB": 10, "K": 200, "TE": 0.05, "EMIN": -3, "EMAX": 4})
    with pytest.raises(DyrError, match=expect):
        format_record(rec)


@pytest.mark.parametrize("ident", ["1", "G2", "&*", "1_"])
def test_every_id_export_writes_reads_back(tmp_path, ident):
    rec = DyrRecord(999997, "SEXS", ident, {"TA/TB": 0.1, "TB": 10.0, "K": 200.0, "TE": 0.05, "EMIN": -3.0,
                                             "EMAX": 4.0})
    path = tmp_path / "x.dyr"
    path.write_text(format_record(rec))
    back = read_dyr(path)
    assert len(back) == 1 and back[0].id == ident and back[0].bus == 999997 and back[0].values == rec.values


def test_a_quoted_id_is_read_without_its_padding_and_an_empty_one_refused(tmp_path):
    path = tmp_path / "q.dyr"
    path.write_text(f"  101 'IEEEX1' '1 ' {DC1} /\n")
    assert read_dyr(path)[0].id == "1"
    path.write_text(f"  101 'IEEEX1' '  ' {DC1} /\n")
    with pytest.raises(DyrError, match="q.dyr:1: an empty machine ID"):
        read_dyr(path)
    path.write_text(f"  0 'IEEEX1' 1 {DC1} /\n")
    with pytest.raises(DyrError, match="bus 0"):
        read_dyr(path)


def test_the_export_command_refuses_a_bad_id_before_writing(tmp_path, capsys):
    cap = tmp_path / "c.csv"
    assert main(["simulate", "--model", "SEXS", "-o", str(cap), "--duration", "3"]) == 0
    res = tmp_path / "r.json"
    assert main(["identify", str(cap), "--model", "SEXS", "--evals", "64", "--json", str(res),
                 "--no-progress"]) in (0, 1)
    capsys.readouterr()
    for args, expect in ((["--id", "1 "], "PSS/E pads IDs"), (["--id", "a/b"], "'/' cannot be"),
                         (["--id", ""], "an empty machine ID"), (["--bus", "0"], "bus 0")):
        out = tmp_path / "u.dyr"
        assert main(["export", str(res), "--dyr", str(out), *args]) == 2
        assert expect in capsys.readouterr().err and not out.exists()
    assert main(["export", str(res), "--dyr", str(tmp_path / "ok.dyr"), "--id", "G2", "--bus", "42"]) == 0
    assert read_dyr(tmp_path / "ok.dyr")[0].id == "G2"


def test_the_identify_header_names_the_unit_used():
    from types import SimpleNamespace as NS

    assert unit_line(NS(name="plant.dyr bus 101 ID 1 (GENSAL + ESST5B)", model=None), NS(name="ESST5B"), [True]) == \
        "unit: plant.dyr bus 101 ID 1 (GENSAL + ESST5B); structure ESST5B; on line (the captures hold P and Q)"
    ref = NS(name="reference unit (1500 MW hydro)", model=None)
    assert unit_line(ref, None, [False]).endswith("structure REFERENCE; at no load")
    assert "no load" not in reference_unit().name


def test_a_record_left_out_by_name_is_not_judged_by_its_layout(tmp_path):
    """A PSS2B record with one field too many (as a public study's file has it): refused with its
    line when the unit is to use it; read when the user leaves it out (--dyr-ignore PSS2B), its
    layout then not checked -- a record left out is not the unit's."""
    pss2b = ("  101 'PSS2B' 1  1 1 3 1 10 0 10 0 0 3 0.02 0.02 2 0.2 20 1 0 1 1 0.1 0.1 0.1 0.1 0.1 0.1 0.1 0.1 0.1 "
             "1 -1 /\n")
    path = _file(tmp_path, f"  101 'IEEEX1' 1 {DC1} /\n", pss2b)
    with pytest.raises(UnitError, match=r"plant.dyr:4: PSS2B: expected 6 ICONs and 23 CONs \(29 fields\), found 30"):
        unit_from_dyr(reference_unit(), path)
    notes: list[str] = []
    u = unit_from_dyr(reference_unit(), path, ignore=("PSS2B",), notes=notes)
    assert u.model == "IEEEX1" and "PSS_MODEL" not in u.grid
    assert any("as --dyr-ignore PSS2B asks" in n for n in notes), notes
    with pytest.raises(DyrError, match="found 30"):      # the reader itself checks what is not left out
        read_dyr(path)
