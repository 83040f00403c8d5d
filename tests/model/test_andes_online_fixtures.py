"""On-line captures made by another simulator (ANDES, benchmarks/andes_online.py) kept as fixtures:
every file is the one its manifest names, has the documented columns on a uniform 1 kHz grid, and
starts in the power-flow steady state (P0 = 0.8, Vt0 as the manifest says) flat up to the first
edge, which lies between samples where the manifest says; the captures with ANDES' IEEEST
stabiliser (`pss_captures`) differ from theirs without it only by the PSS, which damps the swing.
Read with numpy alone: no ANDES, no bench-ctl reader."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "andes_online"
MANIFEST = json.loads((FIXTURES / "manifest.json").read_text(encoding="utf-8"))
CAPTURES = MANIFEST["captures"]
PSS_CAPTURES = MANIFEST["pss_captures"]
COLUMNS = ["time", "usetp", "efd", "vt", "p", "q", "ifd", "delta", "omega"]


def _read(path: Path) -> dict[str, np.ndarray]:
    header = path.read_text(encoding="utf-8").split("\n", 1)[0].split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    return {c: data[:, i] for i, c in enumerate(header)}


def test_the_fixture_set_covers_both_exciters_and_both_lines():
    assert sorted(CAPTURES) == ["esst1a_xe02", "esst1a_xe04", "sexs_xe02", "sexs_xe04"]
    assert {(c["exciter"], c["xe_pu"]) for c in CAPTURES.values()} == {
        ("SEXS", 0.2), ("SEXS", 0.4), ("ESST1A", 0.2), ("ESST1A", 0.4)}
    assert MANIFEST["record"]["columns"] == COLUMNS
    for c in CAPTURES.values():
        assert c["mode"]["frequency_hz"] > 0 and "damping" in c["mode"]


def test_the_pss_captures_differ_from_theirs_only_by_the_pss():
    assert sorted(PSS_CAPTURES) == ["esst1a_xe02_pss", "sexs_xe02_pss"]
    for c in PSS_CAPTURES.values():
        base = CAPTURES[c["without_pss"]]
        for key in ("exciter", "exciter_params", "xe_pu", "operating_point", "initial_values", "edges_true_s",
                    "usetp_step_pu"):
            assert c[key] == base[key], key
        assert c["pss_model"] == "IEEEST" and c["pss_params"]["MODE"] == 1
        assert c["mode_without_pss"] == base["mode"]
        assert c["mode"]["damping"] >= 0.25 > 0.1 > base["mode"]["damping"]   # the PSS is active
        out = c["pss_output"]
        assert not out["limits_reached"] and 0.001 < out["max_excursion_pu"] < out["limits_pu"][1]


@pytest.mark.parametrize("name", sorted(CAPTURES) + sorted(PSS_CAPTURES))
def test_fixture_matches_its_manifest_and_starts_flat(name):
    entry = CAPTURES.get(name) or PSS_CAPTURES[name]
    path = FIXTURES / entry["file"]
    assert path.is_file()
    assert hashlib.sha256(path.read_bytes()).hexdigest() == entry["sha256"]
    d = _read(path)
    assert list(d) == COLUMNS
    n = int(round(MANIFEST["record"]["duration_s"] * 1000)) + 1
    assert d["time"].size == n
    assert np.allclose(np.diff(d["time"]), 1e-3, atol=1e-9) and d["time"][0] == 0.0
    # the reference: two edges, up then down, between the samples the manifest names
    k = np.flatnonzero(np.diff(d["usetp"]) != 0) + 1
    assert np.allclose(d["time"][k], entry["edges_nominal_s"])
    for kk, true in zip(k, entry["edges_true_s"]):
        assert d["time"][kk - 1] < true < d["time"][kk]
    assert np.max(d["usetp"]) - 1.0 == pytest.approx(entry["usetp_step_pu"], abs=1e-6)
    assert d["usetp"][0] == d["usetp"][-1] == 1.0
    # before the first edge: the power-flow operating point, flat
    before = d["time"] < entry["edges_true_s"][0]
    for col in ("efd", "vt", "p", "q", "ifd", "delta", "omega"):
        x = d[col][before]
        assert np.max(np.abs(x - x[0])) < 1e-5, col
    op = entry["operating_point"]
    assert np.max(np.abs(d["p"][before] - 0.8)) < 1e-3
    assert np.max(np.abs(d["vt"][before] - op["Vt0_pu"])) < 1e-5
    assert np.max(np.abs(d["q"][before] - op["Q0_pu"])) < 1e-5
    assert np.max(np.abs(d["omega"][before] - 1.0)) < 1e-5
    # after it the unit answers: efd and vt move, the rotor swings
    assert np.max(np.abs(d["vt"] - op["Vt0_pu"])) > 0.5 * entry["usetp_step_pu"]
    assert np.ptp(d["delta"][~before]) > 1e-3
