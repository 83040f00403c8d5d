"""PSS/E dynamic data records: reading, writing, `export --dyr`, `--from-dyr`, and ANDES' own
reader loading what bench-ctl wrote (skipped when ANDES is absent; CI installs it)."""
from __future__ import annotations

import json

import pytest

from bench_ctl.cli import main
from bench_ctl.units.dyr import FIELDS, ICONS, DyrError, DyrRecord, find, format_record, parse_dyr, read_dyr, write_dyr
from bench_ctl.units.dyr_export import pss_record
from bench_ctl.units.dyr_unit import pss_from_record, unit_from_dyr
from bench_ctl.units.unit import UnitError, reference_unit

FILE = """// a plant: generator, exciter, and a governor bench-ctl does not model
@! comment line
  101 'GENROU' 1   8.000000  0.030000  0.400000  0.050000  6.500000  0.000000  1.800000
  1.700000  0.300000  0.550000  0.250000  0.200000  0.039200  0.267200  /  a comment after the slash
  101 'ESST1A' 1   1  1  0.01  99  -99  1  10  1  1  200  0.02  4  -4  4  -4  0.1  0  1  0  3  /
  101 'TGOV1' 1   1 2 3 4 /
"""


def test_a_realistic_file_parses_with_standard_field_names():
    recs = parse_dyr(FILE, "plant.dyr")
    assert [r.model for r in recs] == ["GENROU", "ESST1A", "TGOV1"]
    gen, exc, gov = recs
    assert gen.values["T'do"] == 8.0 and gen.values["S(1.2)"] == 0.2672 and gen.source == "plant.dyr:3"
    assert exc.icons == {"UEL": 1, "VOS": 1}
    assert (exc.values["TC"], exc.values["TB"], exc.values["KA"], exc.values["TA"]) == (1, 10, 200, 0.02)
    assert (exc.values["KC"], exc.values["ILR"]) == (0.1, 3)
    assert gov.values == {"CON1": 1.0, "CON2": 2.0, "CON3": 3.0, "CON4": 4.0}
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


#: an IEEEST on the rotor speed with no filter, the washout 5 s / (1 + 10 s): half its gain
IEEEST = "  101 'IEEEST' 1   1 0  0 0 0 0 0 0  0.2 0.02 0.15 0.03 5 10  30  0.1 -0.1  0 0 /\n"


def test_from_dyr_reads_the_stabiliser_into_the_grid(tmp_path):
    path = tmp_path / "plant.dyr"
    path.write_text(FILE + IEEEST)
    g = unit_from_dyr(reference_unit(), path).grid
    assert {k: g[k] for k in g if k.startswith("PSS_")} == {
        "PSS_KS": 15.0, "PSS_T1": 0.2, "PSS_T2": 0.02, "PSS_T3": 0.15, "PSS_T4": 0.03, "PSS_TW": 10.0,
        "PSS_LSMAX": 0.1}
    assert "PSS_KS" not in unit_from_dyr(reference_unit(), _plant(tmp_path, FILE)).grid
    # a lead-lag of 0 / 0 is bypassed (1 / 1)
    rec = parse_dyr(IEEEST.replace("0.2 0.02", "0 0"))[0]
    assert (pss_from_record(rec)["PSS_T1"], pss_from_record(rec)["PSS_T2"]) == (1.0, 1.0)


def _plant(tmp_path, text, name="p.dyr"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("change, expect", [
    (("1 0  0 0", "3 0  0 0"), "MODE = 3: .* rotor speed"),
    (("0 0 0 0 0 0  0.2", "0.01 0 0 0 0 0  0.2"), "A1 = 0.01: the stabiliser's filter is not simulated"),
    (("0.1 -0.1", "0.1 -0.05"), "LSMIN = -0.05: .* symmetric"),
    (("0.1 -0.1  0 0", "0.1 -0.1  0.95 0"), "VCU = 0.95, VCL = 0: the cut-off switches the stabiliser off"),
    (("0.2 0.02", "0.2 0"), "T2 = 0 with T1 = 0.2 s: a lead without a lag"),
    (("5 10  30", "5 0  30"), "T6 = 0 s: the washout needs its pole"),
    (("5 10  30", "5 10  500"), r"PSS_KS = 250.0 pu is outside its physical range"),
])
def test_a_stabiliser_bench_ctl_cannot_run_is_refused_naming_the_field(tmp_path, change, expect):
    path = _plant(tmp_path, FILE + IEEEST.replace(*change))
    with pytest.raises(UnitError, match=expect) as info:
        unit_from_dyr(reference_unit(), path)
    assert "p.dyr:" in str(info.value) and "IEEEST" in str(info.value)


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


def test_a_units_stabiliser_is_exported_as_ieeest_and_read_back(tmp_path, capsys):
    cap = tmp_path / "sexs.csv"
    assert main(["simulate", "--model", "SEXS", "-o", str(cap), "--duration", "3"]) == 0
    res = tmp_path / "r.json"
    pss = {"PSS_KS": 12.5, "PSS_T1": 0.25, "PSS_T2": 0.05, "PSS_T3": 1.0, "PSS_T4": 1.0, "PSS_TW": 7.0,
           "PSS_LSMAX": 0.08}
    assert main(["identify", str(cap), "--model", "SEXS", "--evals", "40", "--json", str(res), "--no-progress",
                 *[a for k, v in pss.items() for a in ("--set", f"{k}={v}")]]) in (0, 1)
    out = tmp_path / "unit.dyr"
    capsys.readouterr()
    assert main(["export", str(res), "--dyr", str(out), "--bus", "3"]) == 0
    assert "and its stabiliser as IEEEST (KS 12.5)" in capsys.readouterr().out
    exc, st = read_dyr(out)
    assert (exc.model, st.model, st.bus, st.id, st.icons) == ("SEXS", "IEEEST", 3, "1", {"MODE": 1, "BUSR": 0})
    assert st.values["T5"] == st.values["T6"] == 7.0 and st.values["LSMIN"] == -0.08
    g = unit_from_dyr(reference_unit(), out).grid
    assert {k: g[k] for k in pss} == pss
    # without a stabiliser, none is written
    res0 = tmp_path / "r0.json"
    assert main(["identify", str(cap), "--model", "SEXS", "--evals", "40", "--json", str(res0),
                 "--no-progress"]) in (0, 1)
    assert main(["export", str(res0), "--dyr", str(tmp_path / "u0.dyr")]) == 0
    assert [r.model for r in read_dyr(tmp_path / "u0.dyr")] == ["SEXS"]


def test_andes_reads_what_bench_ctl_writes(tmp_path, monkeypatch):
    """ANDES' own PSS/E reader loads the exported records beside a GENROU (needs ANDES)."""
    pytest.importorskip("yaml")
    # ANDES writes generated code under $HOME (~20 s, unless its package holds it: .ci/run makes it there)
    monkeypatch.setenv("HOME", str(tmp_path))
    andes = pytest.importorskip("andes")
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    import andes_captures as ac
    andes.config_logger(stream_level=50)
    vals_sexs = {"TA/TB": 0.1, "TB": 10.0, "K": 180.0, "TE": 0.04, "EMIN": -3.0, "EMAX": 4.5}
    for model, vals, names in (
            ("SEXS", vals_sexs, {"TA/TB": "TATB"}),
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
    # a unit's stabiliser as export writes it: ANDES puts the IEEEST on that exciter, speed input
    pss = pss_record({"PSS_KS": 12.0, "PSS_T1": 0.2, "PSS_T2": 0.02, "PSS_T3": 0.15, "PSS_T4": 0.03,
                      "PSS_TW": 8.0, "PSS_LSMAX": 0.08}, 1, "1")
    path = tmp_path / "pss.dyr"
    path.write_text(ac.generator_record() + format_record(DyrRecord(1, "SEXS", "1", vals_sexs))
                    + format_record(pss))
    ss = ac.system_from_dyr(andes, str(path))
    assert ss.IEEEST.n == 1 and int(ss.IEEEST.MODE.v[0]) == 1
    for k, v in pss.values.items():
        assert float(getattr(ss.IEEEST, k).v[0]) == pytest.approx(v), k


# ---- issue 24 items 6 and 7: every export reads back and simulates the same; a record's NaN,
# negative or zero time constants are refused or simulated as what they mean, never a typical value

STRUCTS = ("REFERENCE", "SEXS", "EXST1", "ESST1A", "IEEEX1", "ESST4B")


@pytest.mark.parametrize("model", STRUCTS)
def test_each_structures_export_reads_back_and_simulates_the_same(model, tmp_path):
    """identify -> export --dyr -> simulate --from-dyr on the export: the field voltage of the
    result and of the record read back agree to 1e-6 pu (the REFERENCE export wrote VRMIN = +999
    and the read-back model was 'unstable at t = 0')."""
    import numpy as np

    from bench_ctl.capture import read_capture
    from bench_ctl.engine.simulate import simulate
    from bench_ctl.model.dialect import kernel_sections
    from bench_ctl.report.inputs import model_values

    cap, res, dyr, back = (tmp_path / n for n in ("cap.csv", "r.json", "r.dyr", "back.csv"))
    assert main(["simulate", "--model", model, "-o", str(cap), "--duration", "3", "--rate", "500", "--seed", "1"]) == 0
    assert main(["identify", str(cap), "--model", model, "--evals", "64", "--json", str(res),
                 "--no-progress"]) in (0, 1)
    assert main(["export", str(res), "--dyr", str(dyr)]) == 0
    rec = read_dyr(dyr)[0]
    for k, v in rec.values.items():     # an open limit is +-999 on its own side, never flipped
        if abs(v) == 999.0:
            assert (v < 0) == k.endswith("MIN"), (k, v)
    assert main(["simulate", "--from-dyr", str(dyr), "-o", str(back), "--duration", "3", "--rate", "500",
                 "--noise", "0", "--lsb", "0"]) == 0
    kernel = kernel_sections(json.loads(res.read_text()))   # the result speaks the structure's names
    values = {k: v for k, v in model_values(kernel["params"], kernel["fixed"], "r.json").items()
              if not k.startswith("EDGE")}
    b = read_capture(back)
    efd, _vt, fail = simulate(values, b.usetp, b.dt)
    assert fail < 0 and float(np.max(np.abs(efd - b.efd))) <= 1e-6
    assert float(np.ptp(b.efd)) > 0.05     # the record does respond: not two flat lines agreeing


def _esst1a(**change):
    vals = dict(TR=0.01, VIMAX=0.8, VIMIN=-0.8, TC=1.0, TB=10.0, TC1=0.5, TB1=0.2, KA=200.0, TA=0.02,
                VAMAX=999.0, VAMIN=-999.0, VRMAX=4.0, VRMIN=-3.0, KC=0.1, KF=0.0, TF=1.0, KLR=0.0, ILR=5.0)
    vals.update(change)
    return vals


def _file(tmp_path, model, vals, name="x.dyr"):
    icons = {k: 1 for k in ICONS.get(model, ())}
    path = tmp_path / name
    path.write_text("// a record\n" + format_record(DyrRecord(5, model, "1", vals, icons)))
    return path


@pytest.mark.parametrize("change,expect", [
    ({"TB": "NaN"}, r"x.dyr:2: ESST1A TB = nan: not a number"),
    ({"TA": "-0.02"}, r"x.dyr:2: ESST1A TA = -0.02 s: a time constant cannot be negative"),
    ({"TC1": "-1"}, r"x.dyr:2: ESST1A TC1 = -1 s: a time constant cannot be negative"),
    ({"TA": "0"}, r"x.dyr:2: ESST1A TA = 0 \(no regulator lag\): bench-ctl's simulation kernel has no bypass"),
    ({"TB": "0"}, r"x.dyr:2: ESST1A TB = 0 with TC = 1 s: a lead without a lag"),
    ({"KF": "0.05", "TF": "0"}, r"x.dyr:2: ESST1A TF = 0 with rate feedback KF = 0.05: a derivative without a lag"),
])
def test_a_records_nan_negative_or_unsimulable_zero_is_refused_naming_line_field_value(tmp_path, change, expect):
    """--from-dyr replaced them silently with typical values (TC -> 1.0, TB -> 10, TA -> 0.02)."""
    vals = {k: str(v) for k, v in _esst1a().items()}
    vals.update(change)
    path = tmp_path / "x.dyr"
    path.write_text("// a record\n5 'ESST1A' 1 1 1 " + " ".join(vals[k] for k in FIELDS["ESST1A"]) + " /\n")
    with pytest.raises(UnitError, match=expect):
        unit_from_dyr(reference_unit(), path)
    assert main(["simulate", "--from-dyr", str(path), "-o", str(tmp_path / "s.csv")]) == 2


def test_a_bypassed_lead_lag_is_simulated_bypassed_and_zeros_stay_zero(tmp_path):
    """TC = TB = 0 is PSS/E's bypassed lead-lag (it became TC 1.0, TB 10: typical values); TC = 0
    under TB > 0 is a lag alone, KIR = 0 no integral; none is replaced by a typical value."""
    import numpy as np

    from bench_ctl.engine.simulate import simulate
    u = unit_from_dyr(reference_unit(), _file(tmp_path, "ESST1A", _esst1a(TC=0.0, TB=0.0, TC1=0.0, TB1=0.0)))
    v = u.values()
    assert v["TA1"] == v["TA2"] and v["TA3"] == v["TA4"]            # (1 + s T)/(1 + s T) = 1
    assert not {"TA1", "TA2", "TA3", "TA4"} & set(u.identify)        # not identified: the record has none
    lead_lags = ("TC", "TB", "TC1", "TB1")
    assert {k: u.standard_values()[k] for k in lead_lags} == dict.fromkeys(lead_lags, 0.0)
    # the same simulation as the structure without lead-lags: KA/(1 + s TA) alone
    t = np.arange(0, 3.0, 0.002)
    usetp = np.where((t >= 1.0) & (t < 2.0), 1.05, 1.0)
    efd, _, fail = simulate(v, usetp, 0.002)
    plain, _, _ = simulate({**v, "TA1": 3.3, "TA2": 3.3, "TA3": 0.7, "TA4": 0.7}, usetp, 0.002)
    assert fail < 0 and np.max(np.abs(efd - plain)) < 1e-12
    lag = unit_from_dyr(reference_unit(), _file(tmp_path, "ESST1A", _esst1a(TC=0.0), "lag.dyr"))
    assert lag.values()["TA1"] == 0.0 and lag.values()["TA2"] == 10.0
    st4 = dict(TR=0.01, KPR=3.0, KIR=0.0, VRMAX=1.0, VRMIN=-0.87, TA=0.02, KPM=1.0, KIM=0.0, VMMAX=1.0,
               VMMIN=-0.87, KG=0.0, KP=6.5, KI=0.0, VBMAX=8.41, KC=0.08, XL=0.0, THETAP=0.0)
    pi = unit_from_dyr(reference_unit(), _file(tmp_path, "ESST4B", st4, "st4.dyr"))
    assert pi.values()["KII"] == 0.0 and pi.identify["KII"].value == 0.0


def test_a_limit_of_999_reads_back_as_no_limit(tmp_path):
    """ANDES' and PSS/E's 'no limit' (+-999, +-99) is read as an open limit: a value beyond the
    kernel's physical range would otherwise refuse every --set on the unit."""
    path = _file(tmp_path, "ESST1A", _esst1a(VRMAX=999.0, VRMIN=-999.0))
    u = unit_from_dyr(reference_unit(), path)
    assert u.values()["VRMAX"] == float("inf") and u.values()["VRMIN"] == float("-inf")
    assert main(["simulate", "--from-dyr", str(path), "--set", "KA=150", "-o", str(tmp_path / "s.csv"),
                 "--duration", "3"]) == 0


def test_export_names_what_the_record_cannot_hold(tmp_path, capsys):
    """A dead time (or a non-windup ceiling where ESST1A clamps the output) is not in an ESST1A
    record: said on the console and in the record, so nobody takes the record for the model."""
    cap, res, dyr = tmp_path / "c.csv", tmp_path / "r.json", tmp_path / "r.dyr"
    assert main(["simulate", "-o", str(cap), "--duration", "3", "--rate", "500"]) == 0
    assert main(["identify", str(cap), "--set", "TD=0.01", "--evals", "64", "--no-progress",
                 "--json", str(res)]) in (0, 1)
    capsys.readouterr()
    assert main(["export", str(res), "--dyr", str(dyr)]) == 0
    err = capsys.readouterr().err
    assert "warning: the ESST1A record does not hold: TD = 0.01 s (read back: 0;" in err
    assert "NOT IN THIS RECORD" in dyr.read_text() and "TD = 0.01 s" in dyr.read_text()


def test_identify_from_a_record_starts_from_its_values(tmp_path):
    """`identify --from-dyr`: the record's values join the initial swarm, so even a short fit ends
    no worse than the record (here the unit that made the noisy capture; a swarm without it ends
    near 0.009 after 50 evaluations)."""
    rec = tmp_path / "rec.dyr"
    rec.write_text("1 'SEXS' 1 0.2 10.0 180.0 0.05 -5.0 5.0 /\n")
    cap = tmp_path / "rec.csv"
    assert main(["simulate", "--from-dyr", str(rec), "-o", str(cap), "--duration", "4"]) == 0
    res = tmp_path / "res.json"
    assert main(["identify", str(cap), "--from-dyr", str(rec), "--evals", "50", "--json", str(res),
                 "--no-progress"]) in (0, 1)
    mse = json.loads(res.read_text())["captures"][0]["mse"]
    assert mse < 1.5e-4   # the recorder's noise: 1e-4 pu^2
