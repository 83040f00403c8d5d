"""Numeric acceptance after IEC 61400-27-2 (issue 13): windows, figures per unit of the step size,
exclusion zones after the edges, limits from the unit file."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bench_ctl.signals.acceptance import DEFAULT_LIMITS, AcceptanceError, acceptance_limits, evaluate
from bench_ctl.units.unit import UnitError, load_unit

RATE = 1000.0


def _pulse_response(offset_during: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A measured efd stepping from 1.0 to 3.0 between 1 s and 2 s, and a 'simulated' one equal to
    it plus `offset_during` inside the pulse."""
    t = np.arange(0, 4.0, 1.0 / RATE)
    meas = np.where((t >= 1.0) & (t < 2.0), 3.0, 1.0)
    sim = meas + np.where((t >= 1.0) & (t < 2.0), offset_during, 0.0)
    return t, meas, sim


def test_a_constant_offset_gives_equal_mxe_me_mae_in_units_of_the_step() -> None:
    t, meas, sim = _pulse_response(offset_during=0.08)
    acc = evaluate(t, meas, sim, 1.0, 2.0)
    assert acc.step_pu == pytest.approx(2.0)
    by = {w.name: w for w in acc.windows}
    assert [w.name for w in acc.windows] == ["before", "during", "after"]
    for fig in ("MXE", "ME", "MAE"):
        assert by["during"].figures[fig] == pytest.approx(0.04)  # 0.08 pu of a 2 pu step
        assert by["before"].figures[fig] == 0.0 and by["after"].figures[fig] == 0.0
    # 0.04 is within 0.08 / 0.05 / 0.07: passes; the samples exclude 20 ms after the edge
    assert by["during"].ok and acc.ok
    assert by["during"].n == 1000 - 20 and by["after"].n == 2000 - 20 and by["before"].n == 1000
    # a larger offset fails ME (0.06 > 0.05) but not MXE (0.06 <= 0.08)
    acc = evaluate(t, meas, meas + np.where((t >= 1.0) & (t < 2.0), 0.12, 0.0), 1.0, 2.0)
    during = {w.name: w for w in acc.windows}["during"]
    assert during.passed == {"MXE": True, "ME": False, "MAE": True} and not acc.ok


def test_a_spike_inside_the_exclusion_zone_is_ignored_outside_it_counts() -> None:
    t, meas, sim = _pulse_response()
    spike = sim.copy()
    spike[int(1.010 * RATE)] += 1.0  # 10 ms after the leading edge: excluded
    assert evaluate(t, meas, spike, 1.0, 2.0).ok
    spike[int(1.030 * RATE)] += 1.0  # 30 ms after: 0.5 of the step, fails MXE
    acc = evaluate(t, meas, spike, 1.0, 2.0)
    during = {w.name: w for w in acc.windows}["during"]
    assert during.figures["MXE"] == pytest.approx(0.5) and not during.passed["MXE"] and not acc.ok
    # with no exclusion zone the first spike counts too (it is the same size)
    acc = evaluate(t, meas, spike, 1.0, 2.0, {"exclusion_s": 0.0})
    assert {w.name: w for w in acc.windows}["during"].n == 1000


def test_a_step_test_has_two_windows_and_no_edge_one() -> None:
    t, meas, _ = _pulse_response()
    meas = np.where(t >= 1.0, 3.0, 1.0)
    acc = evaluate(t, meas, meas + 0.01, 1.0, None)
    assert [w.name for w in acc.windows] == ["before", "after"]
    assert acc.ok and acc.windows[1].figures["ME"] == pytest.approx(0.005)
    acc = evaluate(t, meas, meas, None, None)
    assert [w.name for w in acc.windows] == ["before"] and acc.ok


def test_limits_merge_over_the_defaults_and_bad_ones_are_refused() -> None:
    lim = acceptance_limits({"during": {"MXE": 0.1}, "exclusion_s": 0.05}, "u.toml")
    assert lim["during"] == {**DEFAULT_LIMITS["during"], "MXE": 0.1} and lim["exclusion_s"] == 0.05
    assert lim["before"] == DEFAULT_LIMITS["before"]
    for raw, named in [({"during": {"MXE": -0.1}}, "acceptance.during.MXE = -0.1"),
                       ({"during": {"RMSE": 0.1}}, "acceptance.during.RMSE: unknown figure"),
                       ({"plateau": {"MXE": 0.1}}, "acceptance.plateau: unknown"),
                       ({"during": 0.1}, "acceptance.during must be a table"),
                       ({"exclusion_s": math.nan}, "acceptance.exclusion_s = nan"),
                       ({"after": {"ME": True}}, "acceptance.after.ME = True")]:
        with pytest.raises(AcceptanceError, match="u.toml: " + named.replace(".", r"\.").replace("(", r"\(")):
            acceptance_limits(raw, "u.toml")


def test_the_unit_file_carries_its_limits_into_the_result(tmp_path: Path) -> None:
    base = Path(__file__).resolve().parents[2] / "bench_ctl" / "data" / "reference_unit.toml"
    text = base.read_text(encoding="utf-8")
    good = tmp_path / "good.toml"
    good.write_text(text + "\n[acceptance]\nexclusion_s = 0.03\n[acceptance.during]\nMXE = 0.1\n",
                    encoding="utf-8")
    unit = load_unit(good)
    acc = unit.entry().acceptance.to_json()
    assert acc["during"]["MXE"] == 0.1 and acc["exclusion_s"] == 0.03 and acc["after"] == DEFAULT_LIMITS["after"]
    assert load_unit(None).entry().acceptance.during == DEFAULT_LIMITS["during"]
    bad = tmp_path / "bad.toml"
    bad.write_text(text + "\n[acceptance.during]\nMAE = \"small\"\n", encoding="utf-8")
    with pytest.raises(UnitError, match=r"bad\.toml: acceptance\.during\.MAE = 'small'"):
        load_unit(bad)
