"""`bench-ctl import` of a real recorder's export that lacks a setpoint channel and the model's
efd base: the test's edges found in the record (regulator output, else efd, else vt), their
uncertainty carried into every fit's edge search, an efd base found from the pre-step level with
the unit's saturation or given in volts / rated-field units, and the named channels (ifd, p, q,
vr). The exports are made here from the independent plant (tests/edge_exports.py)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench_ctl.capture import CaptureError, read_capture
from bench_ctl.capture.capture import write_capture
from bench_ctl.cli import main
from bench_ctl.identification.timing import record_edges
from edge_exports import CLOCK_ARGS, fine_response, sampled, write_export

RATED = 2.7      # 1 rated-field unit of the export = 2.7 pu of the model's efd
IFD_RATED = 2.0


def export(folder: Path, *, seed: int = 0, amplitude: float = 0.05, width: float | None = 1.5,
           s10: float = 0.0, s12: float = 0.0, channels=("UC", "IF", "UG", "UF"), efd_unit: float = 1 / RATED,
           name: str = "export.csv") -> tuple[Path, list[float]]:
    """A trending-recorder export (date, time, UC = vr, IF = ifd, UG = vt, UF = efd in rated-field
    units) of the plant's response; returns the path and the true edge instants."""
    t, ch, truth = sampled(fine_response(amplitude, width, s10, s12), seed=seed)
    cols = {"UC": ch["vr"], "IF": ch["ifd"] / IFD_RATED, "UG": ch["vt"], "UF": ch["efd"] * efd_unit}
    return write_export(folder / name, t, {k: cols[k] for k in channels}), truth


MAPS = ["--map", "efd=UF", "--map", "vt=UG", "--map", "vr=UC", "--map", "ifd=IF"]


def run_import(src: Path, out: Path, *args: str) -> int:
    return main(["import", str(src), "-o", str(out), *CLOCK_ARGS, "--resample", "200", *args])


@pytest.mark.parametrize("seed", range(4))
def test_edges_found_in_a_jittered_export_hold_the_true_instants(tmp_path, capsys, seed):
    src, truth = export(tmp_path, seed=seed)
    out = tmp_path / "cap.csv"
    assert run_import(src, out, *MAPS, "--test", "pulse:amplitude=0.05", "--efd-base", "auto") == 0
    printed = capsys.readouterr().out
    assert "edges found in vr (column 'UC'): leading" in printed and "efd base auto" in printed
    cap = read_capture(out)
    found = cap.meta["import"]["edges_found"]
    assert found["channel"] == "vr" and found["amplitude_check"]["ok"] is True
    for e, true_s in zip(found["edges"], truth):
        assert e["lo_s"] <= true_s <= e["hi_s"]
        assert e["uncertainty_s"] < 1.0 / 200
    # every fit searches each edge over an interval that holds the truth
    edges = record_edges(cap)
    assert [e.how for e in edges] == ["described", "described"]
    for e, true_s in zip(edges, truth):
        assert e.nominal_s + e.lo_s <= true_s <= e.nominal_s + e.hi_s
    test = cap.meta["test"]
    assert test["source"] == "found in the record" and test["kind"] == "pulse"
    assert test["width_s"] == pytest.approx(1.5, abs=0.01)
    assert test["edge_tolerance_s"] == found["tolerance_s"]
    # the efd base: no saturation in this unit, so the pre-step efd is Vt0 (the record's vt)
    base = cap.meta["import"]["efd_base"]
    assert base["mode"] == "auto" and base["vt0_from"] == "the record's pre-step vt"
    assert base["factor"] == pytest.approx(RATED * base["vt0_pu"], rel=2e-3)
    assert cap.unit("vr") == "pu" and cap.channel("ifd") is not None


def test_a_step_and_its_return_is_imported_as_a_pulse_from_efd_without_vr(tmp_path, capsys):
    src, truth = export(tmp_path, channels=("UG", "UF"))
    out = tmp_path / "cap.csv"
    assert run_import(src, out, "--map", "efd=UF", "--map", "vt=UG", "--test", "step:amplitude=0.05",
                      "--efd-scale", str(RATED)) == 0
    printed = capsys.readouterr().out
    assert "edges found in efd (column 'UF')" in printed and "a step and its return" in printed
    cap = read_capture(out)
    found = cap.meta["import"]["edges_found"]
    assert (found["described_as"], found["imported_as"]) == ("step", "pulse")
    assert [s["channel"] for s in found["searched"]] == ["efd"]
    assert all(e["lo_s"] <= t <= e["hi_s"] for e, t in zip(found["edges"], truth))
    assert cap.meta["test"]["kind"] == "pulse"
    assert np.isclose(cap.efd[0], 1.0, atol=0.05)


def test_a_step_found_in_vt_alone(tmp_path):
    """Only vt responds (the efd channel is someone else's flat signal): the edge comes from vt,
    wider, still holding the truth; the channels searched before are named."""
    src, truth = export(tmp_path, amplitude=0.05, width=None, channels=("UG", "UF"))
    text = src.read_text().splitlines()
    flat = [",".join(line.split(",")[:3] + ["0.37"]) for line in text[1:]]
    src.write_text("\n".join([text[0], *flat]) + "\n")
    out = tmp_path / "cap.csv"
    assert run_import(src, out, "--map", "efd=UF", "--map", "vt=UG", "--test", "step:amplitude=0.05") == 0
    found = read_capture(out).meta["import"]["edges_found"]
    assert found["channel"] == "vt" and found["searched"][0]["channel"] == "efd"
    assert "nothing departs" in found["searched"][0]["why_not"]
    e = found["edges"][0]
    assert e["lo_s"] <= truth[0] <= e["hi_s"]


def test_no_edge_of_the_stated_amplitude_is_refused(tmp_path, capsys):
    src, _ = export(tmp_path, channels=("UG", "UF"))
    lines = src.read_text().splitlines()
    rng = np.random.default_rng(1)
    noise = [",".join(line.split(",")[:2] + [f"{1.0 + rng.normal(0, 2e-4):.6f}", f"{0.37 + rng.normal(0, 0.004):.6f}"])
             for line in lines[1:]]
    flat = tmp_path / "flat.csv"
    flat.write_text("\n".join([lines[0], *noise]) + "\n")
    out = tmp_path / "cap.csv"
    assert run_import(flat, out, "--map", "efd=UF", "--map", "vt=UG", "--test", "pulse:amplitude=0.05") == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {flat}: no pulse of +0.05 pu found in the record: searched efd (column 'UF')")
    assert "vt (column 'UG'): nothing departs" in err and "Traceback" not in err
    assert not out.exists() and not out.with_suffix(".json").exists()
    # the record's own edge, but not the stated amplitude (vt moves 0.05) nor the stated width
    assert run_import(src, out, "--map", "efd=UF", "--map", "vt=UG", "--test", "pulse:amplitude=0.2") == 2
    assert "moves vt by +0.05" in capsys.readouterr().err
    assert run_import(src, out, "--map", "efd=UF", "--map", "vt=UG", "--test", "pulse:amplitude=0.05,width=0.5") == 2
    assert "not the stated width 0.5 s" in capsys.readouterr().err
    assert run_import(src, out, "--map", "efd=UF", "--test", "pulse:amplitude=-0.05") == 2
    assert "its first edge goes up (at t = " in capsys.readouterr().err
    assert not out.exists()


def test_efd_base_auto_takes_the_units_saturation(tmp_path, capsys):
    """The plant saturates (S10 0.08, S12 0.3): its pre-step efd is Vt0 + Sat(Vt0) = 1.08 pu. With
    the unit's saturation the auto base finds the export's 2.7; without it, 2.7 x 1/1.08."""
    src, truth = export(tmp_path, s10=0.08, s12=0.3)
    out = tmp_path / "cap.csv"
    assert run_import(src, out, *MAPS, "--test", "pulse:amplitude=0.05", "--efd-base", "auto",
                      "--scale", "ifd=auto", "--set", "S10=0.08", "--set", "S12=0.3") == 0
    printed = capsys.readouterr().out
    assert "S10 0.08, S12 0.3: factor" in printed and "ifd base auto" in printed
    cap = read_capture(out)
    base = cap.meta["import"]["efd_base"]
    assert base["factor"] == pytest.approx(RATED, rel=2e-3)
    assert base["sat_at_vt0_pu"] == pytest.approx(0.08, rel=0.02) and base["S12"] == 0.3
    assert cap.meta["import"]["ifd_base"]["factor"] == pytest.approx(IFD_RATED, rel=2e-3)
    assert np.mean(cap.efd[:100]) == pytest.approx(1.08, rel=2e-3)
    plain = tmp_path / "plain.csv"
    assert run_import(src, plain, *MAPS, "--test", "pulse:amplitude=0.05", "--efd-base", "auto") == 0
    assert read_capture(plain).meta["import"]["efd_base"]["factor"] == pytest.approx(RATED / 1.08, rel=2e-3)
    described = tmp_path / "described.csv"     # a described start: the pre-step part ends there
    assert run_import(src, described, *MAPS, "--test", f"pulse:start={truth[0]:.4f},amplitude=0.05,width=1.5",
                      "--efd-base", "auto", "--set", "S10=0.08", "--set", "S12=0.3") == 0
    cap = read_capture(described)
    assert "edges_found" not in cap.meta["import"] and cap.meta["test"]["source"] == "user description"
    assert cap.meta["import"]["efd_base"]["factor"] == pytest.approx(RATED, rel=2e-3)


def test_efd_base_in_volts_or_rated_field_units(tmp_path, capsys):
    src, _ = export(tmp_path, efd_unit=95.0, name="volts.csv")   # 95 V of the channel = 1 pu
    out = tmp_path / "v.csv"
    assert run_import(src, out, "--map", "efd=UF", "--map", "vt=UG", "--test", "pulse:amplitude=0.05",
                      "--efd-base", "95V") == 0
    assert "efd base 95V: factor 0.010526" in capsys.readouterr().out
    cap = read_capture(out)
    assert cap.meta["import"]["efd_base"]["pre_step_pu"] == pytest.approx(1.0, abs=0.01)
    src, _ = export(tmp_path, name="rated.csv")
    out = tmp_path / "rf.csv"
    assert run_import(src, out, "--map", "efd=UF", "--test", "pulse:amplitude=0.05",
                      "--efd-base", f"{1 / RATED!r}rf") == 0
    assert read_capture(out).meta["import"]["efd_base"]["factor"] == pytest.approx(RATED)
    for bad, why in (("2.7", "say what the efd channel records: 2.7V"), ("2.7kV", "unit 'kV'"),
                     ("-1V", "positive")):
        assert run_import(src, tmp_path / "x.csv", "--map", "efd=UF", "--test", "pulse:amplitude=0.05",
                          "--efd-base", bad) == 2
        assert why in capsys.readouterr().err
    assert run_import(src, tmp_path / "x.csv", "--map", "efd=UF", "--test", "pulse:amplitude=0.05",
                      "--efd-base", "auto", "--efd-scale", "2") == 2
    assert run_import(src, tmp_path / "x.csv", "--map", "efd=UF", "--map", "vt=UG", "--test",
                      "pulse:amplitude=0.05", "--scale", "vt=auto") == 2
    assert "auto and from: are for ifd only" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_auto_base_refused_when_the_pre_step_part_drifts(tmp_path, capsys):
    src, truth = export(tmp_path, channels=("UG", "UF"))
    lines = src.read_text().splitlines()
    out_lines = [lines[0]]
    for k, line in enumerate(lines[1:]):
        cells = line.split(",")
        drift = 0.2 * (k / len(lines))               # the field still settling: +4 % before the step
        cells[3] = f"{float(cells[3]) * (1 + drift):.9f}"
        out_lines.append(",".join(cells))
    src.write_text("\n".join(out_lines) + "\n")
    out = tmp_path / "cap.csv"
    assert run_import(src, out, "--map", "efd=UF", "--map", "vt=UG", "--test", "pulse:amplitude=0.05",
                      "--efd-base", "auto") == 2
    err = capsys.readouterr().err
    assert "the pre-step efd (column 'UF') is not steady: the means of its four quarters" in err
    assert "% of its level" in err and not out.exists()


def test_named_channels_arrive_with_their_unit(tmp_path):
    t = np.arange(2000) / 1000.0
    u = np.where((t >= 0.5) & (t < 1.0), 1.05, 1.0)
    cols = {"time": t, "usetp": u, "efd": u * 2 - 1, "ifd": u * 1.5, "p": np.zeros_like(t), "q": u * 0.1}
    write_capture(tmp_path / "c.csv", cols)
    cap = read_capture(tmp_path / "c.csv")
    assert [cap.unit(n) for n in ("ifd", "p", "q", "efd")] == ["pu"] * 4 and cap.unit("nope") is None
    assert np.array_equal(cap.channel("ifd"), u * 1.5) and cap.channel("vr") is None
    side = json.loads((tmp_path / "c.json").read_text())
    assert side["units"]["ifd"] == "pu"
    text = (tmp_path / "c.csv").read_text().splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join([text[0], text[1].rsplit(",", 3)[0] + ",x,0.0,0.1", *text[2:]]) + "\n")
    with pytest.raises(CaptureError, match=r"bad.csv, row 2, column 'ifd': not a number"):
        read_capture(bad)
    side["units"]["ifd"] = "A"
    (tmp_path / "c.json").write_text(json.dumps(side))
    with pytest.raises(CaptureError, match="unit 'A' for 'ifd': a capture holds ifd in pu"):
        read_capture(tmp_path / "c.csv")


def test_a_comtrade_record_without_setpoint_channel_and_its_field_current_in_amperes(tmp_path):
    """COMTRADE: the edges found in efd (sample numbers as rows), the field current in A mapped
    to ifd and put on the no-load base from its pre-step level (a unit without saturation)."""
    from bench_ctl.capture.field_base import NoLoad
    from bench_ctl.capture.importer import ImportSpec, TestDescription, import_export
    from test_capture_comtrade import Analog, write_comtrade_1999

    t, ch, truth = sampled(fine_response(0.05, 1.5), seed=5, rate_hz=1000.0, jitter=0.0)
    t = np.arange(t.size) / 1000.0                       # the record's own uniform time
    def counts(x: np.ndarray, a: float) -> np.ndarray:
        return np.round(x / a).astype(np.int64)
    analog = [Analog("EFD", "pu", 2e-4, 0.0, counts(ch["efd"], 2e-4)),
              Analog("IF", "A", 0.05, 0.0, counts(ch["ifd"] * 480.0, 0.05))]
    cfg = write_comtrade_1999(tmp_path, "rec", ft="BINARY", analog=analog, rate_hz=1000.0)
    no_load = NoLoad(vt0_pu=1.0, s10=0.0, s12=0.0, saturation=lambda x: 0.0, source="test")
    spec = ImportSpec(columns={"efd": "EFD", "ifd": "IF"}, ifd_auto=True, no_load=no_load,
                      test=TestDescription("pulse", amplitude_pu=0.05))
    cap = import_export(cfg, spec, tmp_path / "cap.csv")
    found = cap.meta["import"]["edges_found"]
    assert found["channel"] == "efd" and found["amplitude_check"]["channel"] is None
    for e, true_s in zip(found["edges"], truth):
        assert e["lo_s"] <= true_s <= e["hi_s"] and e["row"] == int(np.searchsorted(t, e["hi_s"])) + 1
    assert cap.meta["import"]["ifd_base"]["factor"] == pytest.approx(1 / 480.0, rel=1e-3)
    assert cap.unit("ifd") == "pu" and np.mean(cap.channel("ifd")[:300]) == pytest.approx(1.0, rel=1e-3)
