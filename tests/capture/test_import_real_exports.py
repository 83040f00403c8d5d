"""Real on-line exports as they come (issue 49 item 4) and the import's data items of issue 48
(7: the efd base of an on-line record, 8: a second test in one export): the exports are made here
in the shape of the Mostar unit's (tests/online_exports.py), with synthetic numbers."""
from __future__ import annotations

import json

import numpy as np
import pytest

from bench_ctl.capture import read_capture
from bench_ctl.cli import main
from online_exports import CLOCK0_S, CLOCK_ARGS, MAPS, PQ_MAPS, RATE_HZ, STEP_S, Export, write

SAT = ["--set", "S10=0.1", "--set", "S12=0.48"]


def run(src, out, *args):
    return main(["import", str(src), "-o", str(out), *CLOCK_ARGS, *args])


# ---- issue 49 item 4: the amplitude check knows on line ------------------------------------------------

def test_an_on_line_field_current_step_is_checked_against_ifd(tmp_path, capsys):
    """A 10 % step of the field-current regulator on line moves vt by 0.07 of it (the grid holds
    it): it was refused ("0.07 times the stated amplitude"); the record's ifd moves the step."""
    src = write(tmp_path / "rr.csv", Export())
    out = tmp_path / "rr_cap.csv"
    assert run(src, out, "--resample", "200", *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1") == 0
    printed = capsys.readouterr().out
    assert "ifd (column 'SFS_Meas_IfRel') moves" in printed and "field-current (manual) regulator" in printed
    chk = read_capture(out).meta["import"]["edges_found"]["amplitude_check"]
    assert chk["on_line"] is True and chk["ratio"] == pytest.approx(0.07, abs=0.02)
    assert chk["reference"]["channel"] == "ifd" and chk["reference"]["ok"] is True
    assert chk["reference"]["ratio"] == pytest.approx(1.0, abs=0.05)


def test_an_on_line_step_nothing_else_measures_is_accepted_with_a_note(tmp_path, capsys):
    src = write(tmp_path / "avr.csv", Export(ifd_moves_step=False))
    out = tmp_path / "avr_cap.csv"
    assert run(src, out, "--resample", "200", *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1") == 0
    printed = capsys.readouterr().out
    assert "NOTE: on line vt moves 0.07 x the stated amplitude" in printed and "NOT checked" in printed
    chk = read_capture(out).meta["import"]["edges_found"]["amplitude_check"]
    assert chk["ok"] is True and "NOT checked" in chk["note"] and chk["reference"]["ok"] is False
    # the same record without P and Q is no on-line record: refused as before, saying how to map them
    assert run(src, tmp_path / "nl.csv", "--resample", "200", *MAPS, "--test", "step:amplitude=0.1") == 2
    err = capsys.readouterr().err
    assert "0.07 times the stated amplitude" in err and "--map p=" in err and not (tmp_path / "nl.csv").exists()
    # on line vt moving more than the step is still refused
    big = write(tmp_path / "big.csv", Export(vt_share=2.0, ifd_moves_step=False, seed=3))
    assert run(big, tmp_path / "big_cap.csv", "--resample", "200", *MAPS, *PQ_MAPS,
               "--test", "step:amplitude=0.1") == 2
    assert "no more than the step" in capsys.readouterr().err


# ---- issue 48 item 7: the efd base of an on-line record comes from the no-load step -------------------

def test_efd_base_auto_is_refused_on_line_and_taken_from_the_no_load_import(tmp_path, capsys):
    nl_src = write(tmp_path / "noload.csv", Export(on_line=False, duration_s=30.0, tests=((10.0, 6.0),), seed=5))
    nl = tmp_path / "noload_cap.csv"
    assert run(nl_src, nl, "--resample", "200", *MAPS, "--test", "step:amplitude=0.1", "--efd-base", "auto",
               "--scale", "ifd=auto", *SAT) == 0
    nl_base = read_capture(nl).meta["import"]
    capsys.readouterr()
    on_src = write(tmp_path / "online.csv", Export(ifd_moves_step=False, seed=6))
    on = tmp_path / "online_cap.csv"
    # auto on line: refused, naming why and the way (was: the no-load base on a loaded unit, exit 0)
    assert run(on_src, on, "--resample", "200", *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1",
               "--efd-base", "auto", *SAT) == 2
    err = capsys.readouterr().err
    assert "--efd-base auto: the record is of the unit on line" in err and "--efd-base from:NOLOAD.csv" in err
    assert not on.exists()
    assert run(on_src, on, "--resample", "200", *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1",
               "--scale", "ifd=auto", *SAT) == 2
    assert "--scale ifd=auto: the record is of the unit on line" in capsys.readouterr().err
    # from the no-load import: its factors, said where they came from
    assert run(on_src, on, "--resample", "200", *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1",
               "--efd-base", f"from:{nl}", "--scale", f"ifd=from:{nl}") == 0
    printed = capsys.readouterr().out
    imp = read_capture(on).meta["import"]
    assert imp["efd_base"]["factor"] == nl_base["efd_base"]["factor"]
    assert imp["ifd_base"]["factor"] == nl_base["ifd_base"]["factor"]
    assert imp["efd_base"]["from"]["mode"] == "auto" and imp["on_line"]["why"] == "P and Q recorded"
    assert "the auto base of the no-load import" in printed
    # an on-line capture cannot lend its base
    assert run(on_src, tmp_path / "again.csv", "--resample", "200", *MAPS, *PQ_MAPS,
               "--test", "step:amplitude=0.1", "--efd-base", f"from:{on}") == 2
    assert "that record is on line too" in capsys.readouterr().err


# ---- issue 48 item 8: a second test in one export ------------------------------------------------------

def test_a_second_test_in_one_export_is_said_and_each_window_imports(tmp_path, capsys):
    src = write(tmp_path / "two.csv", Export(on_line=False, duration_s=40.0, tests=((8.0, 4.0), (24.0, 4.0)),
                                            seed=7))
    assert run(src, tmp_path / "c.csv", "--resample", "200", *MAPS, "--test", "pulse:amplitude=0.1") == 2
    err = capsys.readouterr().err
    assert "shows 4 edges, more than one test" in err and not (tmp_path / "c.csv").exists()
    windows = [w.split(" ")[0] for w in err.split("--window ")[1:]]
    assert len(windows) == 2
    for i, w in enumerate(windows):
        out = tmp_path / f"c{i}.csv"
        assert run(src, out, "--resample", "200", *MAPS, "--test", "pulse:amplitude=0.1", "--window", w) == 0
        test = read_capture(out).meta["test"]
        assert test["start_s"] == pytest.approx((8.0, 24.0)[i], abs=0.02)
        assert test["width_s"] == pytest.approx(4.0, abs=0.02)


# ---- issue 49 item 4: --window, a pre-step part that is not steady -------------------------------------

def test_a_q_change_before_the_step_is_warned_of_with_a_window_that_leaves_it_out(tmp_path, capsys):
    src = write(tmp_path / "q.csv", Export(q_change=(5.0, 20.0, -0.3), seed=2))
    out = tmp_path / "q_cap.csv"
    assert run(src, out, "--resample", "200", *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1") == 0
    printed = capsys.readouterr().out
    assert "warning: the part before the test (t = 0.0 .. 34.9 s) is not steady" in printed
    steady = read_capture(out).meta["import"]["pre_step_steady"]
    assert steady["steady"] is False
    assert {r["channel"] for r in steady["channels"] if not r["steady"]} >= {"q", "vt", "efd"}
    assert 18.0 <= steady["steady_from_s"] <= 22.0            # the Q change ends at 20 s (1 s blocks)
    window = steady["suggested_window"]
    assert f"--window {window}" in printed
    out2 = tmp_path / "q_win.csv"
    assert run(src, out2, "--resample", "200", *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1",
               "--window", window) == 0
    printed = capsys.readouterr().out
    assert "not steady" not in printed and f"window {window}: t = " in printed
    cap = read_capture(out2)
    imp = cap.meta["import"]
    assert imp["pre_step_steady"]["steady"] is True and imp["window"]["given"] == window
    assert float(cap.time[0]) == pytest.approx(imp["window"]["start_s"], abs=1e-9)   # the export's axis
    assert cap.meta["test"]["start_s"] == pytest.approx(35.0, abs=0.02)
    # a steady record: no warning
    calm = write(tmp_path / "calm.csv", Export(seed=4))
    assert run(calm, tmp_path / "calm_cap.csv", "--resample", "200", *MAPS, *PQ_MAPS,
               "--test", "step:amplitude=0.1") == 0
    assert "not steady" not in capsys.readouterr().out


def test_a_window_in_clock_times_and_windows_outside_the_export(tmp_path, capsys):
    src = write(tmp_path / "w.csv", Export(seed=8))
    out = tmp_path / "w_cap.csv"

    def clock(s):
        x = CLOCK0_S + s
        return f"{int(x // 3600):02d}:{int(x // 60 % 60):02d}:{x % 60:06.3f}"

    assert run(src, out, "--resample", "200", *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1",
               "--window", f"{clock(28.0)}:{clock(48.0)}") == 0
    win = read_capture(out).meta["import"]["window"]
    assert win["start_s"] == pytest.approx(28.0, abs=STEP_S) and win["end_s"] == pytest.approx(48.0, abs=STEP_S)
    for bad, why in (("30:90", "outside the export"), ("40:30", "ends before it starts"),
                     ("10:10.05", "fewer than 20")):
        assert run(src, tmp_path / "x.csv", *MAPS, "--resample", "200", "--test", "step:amplitude=0.1",
                   "--window", bad) == 2
        assert why in capsys.readouterr().err, bad
    assert run(src, tmp_path / "x.csv", *MAPS, "--test", "step:amplitude=0.1", "--window", "1:2:3") == 2


# ---- issue 49 item 4: a clock column a spreadsheet shortened, --rate -----------------------------------

def test_a_shortened_clock_is_explained_and_rebuilt_from_the_rate(tmp_path, capsys):
    src = write(tmp_path / "short.csv", Export(short_clock=True, seed=9))
    assert run(src, tmp_path / "s.csv", *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1") == 2
    err = capsys.readouterr().err
    assert "row 2, column 'time'" in err and "is MM:SS.f, not HH:MM:SS.f" in err and "--rate HZ" in err
    assert "4.8" in err                                    # what the clock's own span gives a row
    out = tmp_path / "s_cap.csv"
    assert run(src, out, *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1", "--rate", repr(RATE_HZ)) == 0
    cap = read_capture(out)
    assert cap.rate_hz == pytest.approx(RATE_HZ, rel=1e-9)
    rebuilt = cap.meta["import"]["time"]["rebuilt"]
    assert rebuilt["checked_against"] == "shortened clock column" and rebuilt["resolution_s"] == pytest.approx(0.1)
    assert rebuilt["max_deviation_s"] <= 0.1 + 2 * STEP_S
    assert cap.meta["test"]["start_s"] == pytest.approx(35.0, abs=0.02)
    # a wrong rate, or rows missing (a gap), is refused at the row where the clock disagrees
    assert run(src, tmp_path / "r.csv", *MAPS, "--test", "step:amplitude=0.1", "--rate", "200") == 2
    assert "not evenly spaced at that rate" in capsys.readouterr().err
    gap = write(tmp_path / "gap.csv", Export(short_clock=True, drop_rows=(3000, 3060), seed=9))
    assert run(gap, tmp_path / "g.csv", *MAPS, "--test", "step:amplitude=0.1", "--rate", repr(RATE_HZ)) == 2
    err = capsys.readouterr().err
    assert "not evenly spaced" in err and "row " in err


def test_a_full_clock_rebuilt_from_the_rate_keeps_within_its_stamps(tmp_path):
    src = write(tmp_path / "full.csv", Export(seed=10))
    out = tmp_path / "f.csv"
    assert run(src, out, *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1", "--rate", repr(RATE_HZ)) == 0
    cap = read_capture(out)
    rebuilt = cap.meta["import"]["time"]["rebuilt"]
    assert rebuilt["max_deviation_s"] < 5e-4 and rebuilt["checked_against"] == "clock column"
    assert np.allclose(np.diff(cap.time), STEP_S, rtol=0, atol=1e-9)
    side = json.loads(out.with_suffix(".json").read_text())
    assert side["import"]["resampled"] is False


# ---- issue 49 item 4: a channel the recorder refreshes slower than it writes rows ---------------------

def test_a_field_voltage_refreshed_every_other_row_is_warned_of_and_a_quantised_q_is_not(tmp_path, capsys):
    """efd (forced at each edge, as a field voltage is) repeats the row before on every other row,
    also through the edges: held, warned of. Q rounded to 0.01 pu repeats on most rows where it is
    flat, never while it moves fast (its step is 0.12 pu): not held."""
    src = write(tmp_path / "h.csv", Export(held=("SFS_Meas_UfRel",), quantum={"SFS_Meas_QRel": 0.01}, efd_kick=1.0,
                                           seed=3))
    out = tmp_path / "h_cap.csv"
    assert run(src, out, "--resample", "200", *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1") == 0
    printed = capsys.readouterr().out
    held = read_capture(out).meta["import"]["held_samples"]
    rows = {r["channel"]: r for r in held["channels"]}
    assert held["held"] == ["efd"], held
    assert 0.4 < rows["efd"]["share_fast"] <= 0.6 and rows["efd"]["longest_run"] == 2
    assert rows["q"]["share"] > 0.5 and rows["q"]["held"] is False
    assert "warning: efd (column 'SFS_Meas_UfRel') repeats the row before" in printed
    assert "warning: q" not in printed and "warning: vt" not in printed
    assert "--held interpolate puts each repeated row between the fresh rows" in printed
    # interpolated: the note instead of the warning, efd changed on the held rows, q as written
    out2 = tmp_path / "h_interp.csv"
    assert run(src, out2, "--resample", "200", *MAPS, *PQ_MAPS, "--test", "step:amplitude=0.1",
               "--held", "interpolate") == 0
    printed = capsys.readouterr().out
    assert "note: efd (column 'SFS_Meas_UfRel') repeats the row before" in printed and "warning: efd" not in printed
    kept, interp = read_capture(out), read_capture(out2)
    assert interp.meta["import"]["held_samples"]["treatment"] == "interpolate"
    assert np.array_equal(kept.extra["q"], interp.extra["q"])
    moved = np.abs(kept.efd - interp.efd)
    assert np.count_nonzero(moved > 1e-6) > 0.2 * moved.size
    # the same export refreshed on every row: no warning
    calm = write(tmp_path / "calm.csv", Export(quantum={"SFS_Meas_QRel": 0.01}, efd_kick=1.0, seed=3))
    assert run(calm, tmp_path / "calm_cap.csv", "--resample", "200", *MAPS, *PQ_MAPS,
               "--test", "step:amplitude=0.1") == 0
    assert "repeats the row before" not in capsys.readouterr().out


def test_a_held_row_is_put_on_the_line_between_the_fresh_rows_around_it():
    from bench_ctl.capture.held import interpolated

    t = np.array([0.0, 1.0, 2.0, 3.0, 5.0, 6.0, 7.0])
    v = np.array([0.0, 0.0, 2.0, 2.0, 2.0, 8.0, 8.0])
    assert np.allclose(interpolated(t, v), [0.0, 1.0, 2.0, 3.5, 6.5, 8.0, 8.0])
