"""Capture CSV + JSON sidecar: round trip, refusal to overwrite, SHA-256 pinning, and one test
per kind of malformed file, each checking that the message names file, row and column."""
from __future__ import annotations

import datetime as dt
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

import bench_ctl
from bench_ctl.capture import Capture, CaptureError, read_capture, write_capture
from bench_ctl.capture.capture import SCHEMA


def _pulse_capture(n: int = 2000, rate_hz: float = 1000.0, seed: int = 1) -> Capture:
    rng = np.random.default_rng(seed)
    time = np.arange(n) / rate_hz
    usetp = np.where((time >= 0.5) & (time < 1.5), 1.05, 1.0)
    efd = 1.0 + rng.normal(0.0, 0.3, n)
    vt = 1.0 + rng.normal(0.0, 1e-3, n)
    extra = {"ifd_a": rng.normal(500.0, 10.0, n), "note": np.array(["ok"] * (n - 1) + ["a,b"])}
    return Capture(time=time, usetp=usetp, efd=efd, vt=vt, extra=extra)


def _lines(n: int = 6, step: float = 0.001) -> list[str]:
    """A valid capture as text lines: header + n rows (line k + 2 holds sample k)."""
    return ["time,usetp,efd,vt"] + [f"{k * step!r},1.0,{1.0 + 0.1 * k!r},1.0" for k in range(n)]


def _write(tmp_path: Path, lines: list[str], name: str = "cap.csv") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _refused(path: Path, row: int | None = None, column: str | None = None) -> CaptureError:
    with pytest.raises(CaptureError) as info:
        read_capture(path)
    exc = info.value
    msg = str(exc)
    assert msg.startswith(str(path)), msg
    if row is not None:
        assert f"row {row}" in msg and exc.row == row, msg
    if column is not None:
        assert f"column {column!r}" in msg and exc.column == column, msg
    return exc


# --- round trip ---------------------------------------------------------------------------

def test_roundtrip_is_exact_and_sidecar_has_the_computed_keys(tmp_path: Path) -> None:
    cap = _pulse_capture()
    csv_path, json_path = write_capture(tmp_path / "p1.csv", cap, {"operator": "A. Engineer",
                                                                   "test": {"kind": "pulse"}})
    assert (csv_path, json_path) == (tmp_path / "p1.csv", tmp_path / "p1.json")
    back = read_capture(csv_path)
    for name in ("time", "usetp", "efd", "vt"):
        assert np.array_equal(getattr(back, name), getattr(cap, name)), name
    assert np.array_equal(back.extra["ifd_a"], cap.extra["ifd_a"])
    assert list(back.extra["note"]) == list(cap.extra["note"])
    assert back.n == 2000 and back.dt == pytest.approx(1e-3, rel=1e-12)
    assert back.rate_hz == pytest.approx(1000.0, rel=1e-12)
    assert back.source == str(csv_path)
    side = json.loads(json_path.read_text(encoding="utf-8"))
    assert back.meta == side
    assert side["schema"] == SCHEMA == "bench-ctl/capture/1"
    assert side["software_version"] == bench_ctl.__version__
    assert side["csv_sha256"] == hashlib.sha256(csv_path.read_bytes()).hexdigest()
    created = dt.datetime.fromisoformat(side["created_utc"])
    assert abs(dt.datetime.now(dt.UTC) - created) < dt.timedelta(minutes=5)
    assert side["operator"] == "A. Engineer" and side["test"] == {"kind": "pulse"}
    assert side["columns"] == ["time", "usetp", "efd", "vt", "ifd_a", "note"]


def test_write_from_plain_arrays_and_read_without_sidecar(tmp_path: Path) -> None:
    time = np.arange(11) * 0.1
    write_capture(tmp_path / "a.csv", {"time": time, "usetp": np.ones(11), "efd": time * 2})
    (tmp_path / "a.json").unlink()
    back = read_capture(tmp_path / "a.csv")
    assert back.meta == {} and back.vt is None and back.extra == {}
    assert np.array_equal(back.efd, time * 2)


def test_capture_arrays_are_read_only() -> None:
    cap = _pulse_capture(n=10)
    with pytest.raises(ValueError):
        cap.efd[0] = 5.0


def test_rewriting_a_read_capture_recomputes_the_sha(tmp_path: Path) -> None:
    cap = _pulse_capture(n=50)
    write_capture(tmp_path / "a.csv", cap, {"operator": "x"})
    back = read_capture(tmp_path / "a.csv")
    write_capture(tmp_path / "b.csv", back)
    again = read_capture(tmp_path / "b.csv")
    assert again.meta["operator"] == "x"
    assert again.meta["csv_sha256"] == hashlib.sha256((tmp_path / "b.csv").read_bytes()).hexdigest()


# --- never overwrite -----------------------------------------------------------------------

def test_refuses_to_overwrite_csv_and_leaves_it_untouched(tmp_path: Path) -> None:
    cap = _pulse_capture(n=20)
    csv_path, json_path = write_capture(tmp_path / "p.csv", cap)
    before = csv_path.read_bytes(), json_path.read_bytes()
    other = _pulse_capture(n=20, seed=2)
    with pytest.raises(FileExistsError) as info:
        write_capture(tmp_path / "p.csv", other)
    assert str(csv_path) in str(info.value)
    assert (csv_path.read_bytes(), json_path.read_bytes()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.csv", "p.json"]  # no temp left


def test_refuses_when_only_the_sidecar_exists(tmp_path: Path) -> None:
    (tmp_path / "q.json").write_text("{}", encoding="utf-8")
    with pytest.raises(FileExistsError) as info:
        write_capture(tmp_path / "q.csv", _pulse_capture(n=20))
    assert str(tmp_path / "q.json") in str(info.value)
    assert not (tmp_path / "q.csv").exists()


def test_overwrite_flag_replaces(tmp_path: Path) -> None:
    write_capture(tmp_path / "p.csv", _pulse_capture(n=20))
    other = _pulse_capture(n=30, seed=3)
    write_capture(tmp_path / "p.csv", other, overwrite=True)
    assert np.array_equal(read_capture(tmp_path / "p.csv").efd, other.efd)


def test_write_refuses_bad_data_before_writing(tmp_path: Path) -> None:
    time = np.arange(10) * 0.01
    efd = np.ones(10)
    efd[4] = np.nan
    with pytest.raises(CaptureError) as info:
        write_capture(tmp_path / "bad.csv", {"time": time, "usetp": np.ones(10), "efd": efd})
    assert "row 6" in str(info.value) and "column 'efd'" in str(info.value)  # line of sample 4
    time[7] += 0.003
    with pytest.raises(CaptureError, match="non-uniform"):
        write_capture(tmp_path / "bad.csv", {"time": time, "usetp": np.ones(10), "efd": np.ones(10)})
    assert list(tmp_path.iterdir()) == []


# --- SHA-256 --------------------------------------------------------------------------------

def test_sha_mismatch_is_refused(tmp_path: Path) -> None:
    csv_path, _ = write_capture(tmp_path / "s.csv", _pulse_capture(n=20))
    text = csv_path.read_text(encoding="utf-8").splitlines()
    cells = text[5].split(",")
    cells[2] = "9.5"  # still a valid file, but not the one the sidecar pins
    text[5] = ",".join(cells)
    csv_path.write_text("\n".join(text) + "\n", encoding="utf-8")
    exc = _refused(csv_path)
    assert "SHA-256" in str(exc) and "s.json" in str(exc)


# --- malformed files: one test per case ---------------------------------------------------

@pytest.mark.parametrize("missing", ["time", "usetp", "efd"])
def test_missing_required_column(tmp_path: Path, missing: str) -> None:
    lines = _lines()
    header = lines[0].split(",")
    idx = header.index(missing)
    lines = [",".join(c for i, c in enumerate(line.split(",")) if i != idx) for line in lines]
    exc = _refused(_write(tmp_path, lines), row=1, column=missing)
    assert "missing required column" in str(exc)


@pytest.mark.parametrize("cell", ["nan", "NaN", "inf", "-inf"])
def test_non_finite_cell(tmp_path: Path, cell: str) -> None:
    lines = _lines()
    i = 4  # list index i is file line i + 1
    lines[i] = lines[i].rsplit(",", 2)[0] + f",{cell},1.0"
    exc = _refused(_write(tmp_path, lines), row=i + 1, column="efd")
    assert "not finite" in str(exc)


def test_non_numeric_cell(tmp_path: Path) -> None:
    lines = _lines()
    i = 3
    lines[i] = lines[i].split(",", 1)[0] + ",1.0x,1.1,1.0"
    exc = _refused(_write(tmp_path, lines), row=i + 1, column="usetp")
    assert "not a number: '1.0x'" in str(exc)


def test_empty_cell(tmp_path: Path) -> None:
    lines = _lines()
    i = 6
    lines[i] = lines[i].rsplit(",", 1)[0] + ","  # vt empty
    exc = _refused(_write(tmp_path, lines), row=i + 1, column="vt")
    assert "empty cell" in str(exc)


def test_empty_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.csv"
    path.write_bytes(b"")
    assert "empty file" in str(_refused(path))


def test_header_only(tmp_path: Path) -> None:
    exc = _refused(_write(tmp_path, _lines()[:1]))
    assert "no data rows" in str(exc)


@pytest.mark.parametrize("sep, name", [(";", "semicolon"), ("\t", "tab")])
def test_wrong_delimiter(tmp_path: Path, sep: str, name: str) -> None:
    lines = [line.replace(",", sep) for line in _lines()]
    exc = _refused(_write(tmp_path, lines), row=1)
    assert "expected comma-separated" in str(exc) and name in str(exc)


def test_row_with_wrong_field_count(tmp_path: Path) -> None:
    lines = _lines()
    i = 5
    lines[i] += ",7"
    exc = _refused(_write(tmp_path, lines), row=i + 1)
    assert "5 fields, the header has 4" in str(exc)


def test_decreasing_time(tmp_path: Path) -> None:
    lines = _lines()
    i = 4
    lines[i], lines[i + 1] = lines[i + 1], lines[i]  # list index i + 1 (line i + 2) goes back
    exc = _refused(_write(tmp_path, lines), row=i + 2, column="time")
    assert "decreasing time" in str(exc)


def test_repeated_time(tmp_path: Path) -> None:
    lines = _lines()
    i = 4
    lines[i] = lines[i - 1].split(",", 1)[0] + "," + lines[i].split(",", 1)[1]
    exc = _refused(_write(tmp_path, lines), row=i + 1, column="time")
    assert "repeated time" in str(exc)


def test_non_uniform_step_names_row_and_steps(tmp_path: Path) -> None:
    step = 0.001
    times = [k * step for k in range(8)]
    times[5:] = [t + 0.0005 for t in times[5:]]  # one long step into sample 5 (line 7)
    lines = ["time,usetp,efd"] + [f"{t!r},1.0,1.0" for t in times]
    exc = _refused(_write(tmp_path, lines), row=7, column="time")
    msg = str(exc)
    assert "non-uniform time step" in msg
    assert f"{0.0015:.9g} s" in msg and f"expected {step:.9g} s" in msg


def test_jitter_below_tolerance_is_accepted_above_is_refused(tmp_path: Path) -> None:
    step = 1e-3
    base = np.arange(50) * step
    ok = base.copy()
    ok[20] += 0.5e-6 * step  # relative jitter below 1e-6 of the step
    path = _write(tmp_path, ["time,usetp,efd"] + [f"{t!r},1.0,1.0" for t in ok.tolist()],
                  "ok.csv")
    assert read_capture(path).n == 50
    bad = base.copy()
    bad[20] += 3e-6 * step
    path = _write(tmp_path, ["time,usetp,efd"] + [f"{t!r},1.0,1.0" for t in bad.tolist()],
                  "bad.csv")
    _refused(path, row=20 + 2, column="time")  # sample 20 is on line 22


def test_single_row_is_too_few(tmp_path: Path) -> None:
    exc = _refused(_write(tmp_path, _lines(n=1)))
    assert "at least 2" in str(exc)


def test_blank_line_between_rows(tmp_path: Path) -> None:
    lines = _lines()
    lines.insert(3, "")
    exc = _refused(_write(tmp_path, lines), row=4)
    assert "blank line" in str(exc)


def test_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "latin.csv"
    path.write_bytes(("\n".join(_lines()) + "\n").encode() + "0.006,1.0,1.0,1.0 \xb5\n".encode("latin-1"))
    exc = _refused(path, row=8)
    assert "UTF-8" in str(exc)


def test_bad_sidecar_json_names_sidecar_and_line(tmp_path: Path) -> None:
    path = _write(tmp_path, _lines())
    (tmp_path / "cap.json").write_text('{\n  "operator": "x",\n  oops\n}\n', encoding="utf-8")
    with pytest.raises(CaptureError) as info:
        read_capture(path)
    assert str(tmp_path / "cap.json") in str(info.value) and "row 3" in str(info.value)


def test_sidecar_rate_must_agree_with_csv(tmp_path: Path) -> None:
    path = _write(tmp_path, _lines())
    (tmp_path / "cap.json").write_text('{"rate_hz": 500.0}', encoding="utf-8")
    with pytest.raises(CaptureError, match="rate_hz 500.0 disagrees"):
        read_capture(path)


def test_other_columns_are_kept(tmp_path: Path) -> None:
    lines = ["time,usetp,efd,ifd,status"] + [f"{k * 0.01!r},1.0,1.0,{k * 2},{'on' if k else 'off'}"
                                              for k in range(5)]
    cap = read_capture(_write(tmp_path, lines))
    assert np.array_equal(cap.extra["ifd"], [0.0, 2.0, 4.0, 6.0, 8.0])
    assert list(cap.extra["status"]) == ["off", "on", "on", "on", "on"]
    assert cap.vt is None


def test_units_are_written_and_wrong_units_refused(tmp_path: Path) -> None:
    cap = _pulse_capture(n=20)
    _, json_path = write_capture(tmp_path / "u.csv", cap, {"units": {"ifd_a": "A"}})
    units = json.loads(json_path.read_text(encoding="utf-8"))["units"]
    assert units == {"time": "s", "usetp": "pu", "efd": "pu", "vt": "pu", "ifd_a": "A"}
    with pytest.raises(CaptureError, match=r"key 'units.efd': unit 'V'"):
        write_capture(tmp_path / "v.csv", cap, {"units": {"efd": "V"}})
    assert not (tmp_path / "v.csv").exists()
    path = _write(tmp_path, _lines())
    (tmp_path / "cap.json").write_text('{"units": {"time": "ms"}}', encoding="utf-8")
    with pytest.raises(CaptureError) as info:
        read_capture(path)
    assert str(info.value).startswith(str(tmp_path / "cap.json"))
    assert "key 'units.time'" in str(info.value)
