"""PSS/E dynamic data records: reading, writing, `export --dyr`, `--from-dyr`, and ANDES' own
reader loading what bench-ctl wrote (skipped when ANDES is absent; CI installs it)."""
from __future__ import annotations

import json

import pytest

from bench_ctl.cli import main
from bench_ctl.model.dyr import FIELDS, ICONS, DyrError, DyrRecord, find, format_record, parse_dyr, read_dyr, write_dyr
from bench_ctl.model.dyr_unit import unit_from_dyr
from bench_ctl.model.unit import UnitError, reference_unit

FILE = """// a plant: generator, exciter, and a stabiliser bench-ctl does not model
@! comment line
  101 'GENROU' 1   8.000000  0.030000  0.400000  0.050000  6.500000  0.000000  1.800000
  1.700000  0.300000  0.550000  0.250000  0.200000  0.039200  0.267200  /  a comment after the slash
  101 'ESST1A' 1   1  1  0.01  99  -99  1  10  1  1  200  0.02  4  -4  4  -4  0.1  0  1  0  3  /
  101 'IEEEST' 1   1 2 3 4 /
"""


def test_a_realistic_file_parses_with_standard_field_names():
    recs = parse_dyr(FILE, "plant.dyr")
    assert [r.model for r in recs] == ["GENROU", "ESST1A", "IEEEST"]
    gen, exc, pss = recs
    assert gen.values["T'do"] == 8.0 and gen.values["S(1.2)"] == 0.2672 and gen.source == "plant.dyr:3"
    assert exc.icons == {"UEL": 1, "VOS": 1}
    assert (exc.values["TC"], exc.values["TB"], exc.values["KA"], exc.values["TA"]) == (1, 10, 200, 0.02)
    assert (exc.values["KC"], exc.values["ILR"]) == (0.1, 3)
    assert pss.values == {"CON1": 1.0, "CON2": 2.0, "CON3": 3.0, "CON4": 4.0}
    assert find(recs, {"ESST1A", "SEXS"}) is exc
    with pytest.raises(DyrError, match="no SEXS record at bus 7"):
        find(recs, "SEXS", bus=7)


@pytest.mark.parametrize("model", sorted(FIELDS))
def test_every_known_model_round_trips(model, tmp_path):
    vals = {k: round(0.1 + 0.37 * i, 6) for i, k in enumerate(FIELDS[model])}
    rec = DyrRecord(42, model, "G2", vals, {k: 1 for k in ICONS.get(model, ())})
    path = tmp_path / "out.dyr"
    write_dyr(path, [(rec, "written by a test")], header="header line")
    back = read_dyr(path)
    assert len(back) == 1 and back[0].values == vals and back[0].bus == 42 and back[0].id == "G2"
    assert back[0].icons == rec.icons
    text = path.read_text()
    assert text.startswith("// header line\n// written by a test\n") and text.rstrip().endswith("/")


def test_bad_records_are_refused_naming_file_and_line():
    with pytest.raises(DyrError, match=r"x.dyr:2: SEXS: expected 0 ICONs and 6 CONs \(6 fields\), found 5"):
        parse_dyr("// c\n1 'SEXS' 1 0.1 10 200 0.05 -3 /\n", "x.dyr")
    with pytest.raises(DyrError, match=r"x.dyr:1: SEXS TE: 'abc' is not a number"):
        parse_dyr("1 'SEXS' 1 0.1 10 200 abc -3 4 /\n", "x.dyr")
    with pytest.raises(DyrError, match="not terminated"):
        parse_dyr("1 'SEXS' 1 0.1 10 200 0.05 -3 4\n", "x.dyr")
    with pytest.raises(DyrError, match="no value for TE"):
        format_record(DyrRecord(1, "SEXS", "1", {"TA/TB": 0.1, "TB": 10, "K": 200, "EMIN": -3, "EMAX": 4}))


def test_never_overwrites(tmp_path):
    path = tmp_path / "a.dyr"
    path.write_text("keep me")
    rec = DyrRecord(1, "SEXS", "1", {"TA/TB": 0.1, "TB": 10, "K": 200, "TE": 0.05, "EMIN": -3, "EMAX": 4})
    with pytest.raises(FileExistsError, match="never overwritten"):
        write_dyr(path, [(rec, None)])
    assert path.read_text() == "keep me"


def test_from_dyr_takes_the_exciter_and_the_generator(tmp_path):
    path = tmp_path / "plant.dyr"
    path.write_text(FILE)
    u = unit_from_dyr(reference_unit(), path)
    assert u.model == "ESST1A"
    v = u.values()
    assert v["Td0p"] == 8.0 and v["Td0pp"] == 0.03
    assert v["KPP"] == pytest.approx((0.25 - 0.2) / (0.3 - 0.2))
    assert v["KDA"] == pytest.approx((1.8 - 0.3) * (0.3 - 0.25) / (0.3 - 0.2) ** 2)
    assert v["S10"] == 0.0392 and v["S12"] == pytest.approx(1.2 * 0.2672)   # PSS/E's relative S(1.2)
    assert u.identify["KAVR"].value == 200 and u.identify["TE"].value == 0.02
    assert v["KC"] == 0.1 and v["VRMAX"] == 4 and u.standard_values()["ILR"] == 3
    two = tmp_path / "two.dyr"
    two.write_text(FILE + FILE.replace("101 ", "102 "))
    with pytest.raises(UnitError, match="several records match.*--dyr-bus"):
        unit_from_dyr(reference_unit(), two)
    assert unit_from_dyr(reference_unit(), two, bus=102).model == "ESST1A"


def test_identify_export_and_start_again_from_the_record(tmp_path, capsys):
    cap = tmp_path / "sexs.csv"
    assert main(["simulate", "--model", "SEXS", "--set", "K=150", "-o", str(cap), "--duration", "4"]) == 0
    res = tmp_path / "sexs.result.json"
    assert main(["identify", str(cap), "--model", "SEXS", "--evals", "300", "--json", str(res),
                 "--no-progress"]) in (0, 1)
    r = json.loads(res.read_text())
    assert r["model"]["name"] == "SEXS" and set(r["model"]["identified"]) == {"K", "TA", "TB", "TE"}
    out = tmp_path / "unit.dyr"
    capsys.readouterr()
    assert main(["export", str(res), "--dyr", str(out), "--bus", "7", "--id", "2"]) == 0
    rec = read_dyr(out)[0]
    p = r["model"]["params"]
    assert (rec.bus, rec.model, rec.id) == (7, "SEXS", "2")
    assert rec.values["K"] == pytest.approx(p["K"], rel=1e-5)
    assert rec.values["TA/TB"] == pytest.approx(p["TA"] / p["TB"], rel=1e-5)
    text = out.read_text()
    assert "K = " in text and "identified" in text and "EMAX" in text
    # never over an existing file
    assert main(["export", str(res), "--dyr", str(out)]) == 2
    assert "exists; refusing to replace it" in capsys.readouterr().err
    # the record is a starting point again
    res2 = tmp_path / "again.result.json"
    assert main(["identify", str(cap), "--from-dyr", str(out), "--evals", "50", "--json", str(res2),
                 "--no-progress"]) in (0, 1)
    r2 = json.loads(res2.read_text())
    assert r2["model"]["name"] == "SEXS" and "--from-dyr" in r2["command_line"]
    assert r2["unit"]["model_values"]["EMAX"] == pytest.approx(rec.values["EMAX"])


def test_andes_reads_what_bench_ctl_writes(tmp_path, monkeypatch):
    """ANDES' own PSS/E reader loads the exported records beside a GENROU (needs ANDES)."""
    pytest.importorskip("yaml")
    monkeypatch.setenv("HOME", str(tmp_path))           # ANDES writes generated code under $HOME
    andes = pytest.importorskip("andes")
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import andes_captures as ac
    andes.config_logger(stream_level=50)
    for model, vals, names in (
            ("SEXS", {"TA/TB": 0.1, "TB": 10.0, "K": 180.0, "TE": 0.04, "EMIN": -3.0, "EMAX": 4.5},
             {"TA/TB": "TATB"}),
            ("EXST1", dict(TR=0.01, VIMAX=0.8, VIMIN=-0.8, TC=1.0, TB=10.0, KA=200.0, TA=0.02, VRMAX=4.0,
                           VRMIN=-3.0, KC=0.05, KF=0.0, TF=1.0), {}),
            ("IEEEX1", dict(TR=0.01, KA=40.0, TA=0.04, TB=1.0, TC=1.0, VRMAX=7.3, VRMIN=-7.3, KE=1.0, TE=0.5,
                            KF=0.03, TF1=1.0, SWITCH=0.0, E1=2.5, SE1=0.05, E2=3.5, SE2=0.3), {"KF": "KF1"})):
        path = tmp_path / f"{model}.dyr"
        path.write_text(ac.generator_record() + format_record(DyrRecord(1, model, "1", vals)))
        ss = ac.system_from_dyr(andes, str(path))
        exc = getattr(ss, model)
        for k, v in vals.items():
            an = names.get(k, k)
            if hasattr(exc, an):
                assert float(getattr(exc, an).v[0]) == pytest.approx(v), (model, k)
