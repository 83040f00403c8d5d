"""Import of recorder exports: date + clock time, jitter refused unless resampling is asked
for, efd base scaling, synthesised setpoint, vendor names, the sidecar's import record, CLI."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from bench_ctl.capture import CaptureError, read_capture
from bench_ctl.capture.importer import ImportSpec, TestDescription, import_export
from bench_ctl.cli import main

TENTH_MS = 1e-4  # clock resolution of the export (HH:MM:SS.ffff)
F_HZ = 0.7


def efd_rated(t: np.ndarray) -> np.ndarray:
    """The recorded signal on the rated-field base: smooth, so linear interpolation error is
    bounded by h^2/8 * max|f''| with max|f''| = 0.5 (2 pi F)^2."""
    return 2.0 + 0.5 * np.sin(2 * np.pi * F_HZ * t) + 0.2 * t


def usetp_true(t: np.ndarray) -> np.ndarray:
    return 1.0 + 0.05 * np.sin(2 * np.pi * 0.3 * t)


def _clock(ticks: int, start_s: int = 10 * 3600 + 31 * 60 + 7) -> str:
    """Clock text of `ticks` tenths of a millisecond after 10:31:07.0000."""
    whole, frac = divmod(ticks, 10_000)
    s = start_s + whole
    return f"{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d}.{frac:04d}"


def jittered_export(folder: Path, *, n: int = 800, seed: int = 3, sep: str = ";",
                    decimal: str = ",") -> tuple[Path, np.ndarray, np.ndarray]:
    """Vendor export: Date;Time;USETP;EFD_V;IFD_A;Status with 4.6..5.0 ms steps (4.8 nominal).
    Returns the path, the exact sample times (s) and the step sizes in clock ticks."""
    rng = np.random.default_rng(seed)
    steps = rng.integers(46, 51, size=n - 1)  # ticks of 0.1 ms: 4.6 .. 5.0 ms
    ticks = np.concatenate([[0], np.cumsum(steps)])
    t = ticks * TENTH_MS
    def num(x: float) -> str:
        return repr(float(x)).replace(".", decimal)
    lines = [sep.join(["Date", "Time", "USETP", "EFD_V", "IFD_A", "Status"])]
    for k in range(n):
        lines.append(sep.join(["2026-03-14", _clock(int(ticks[k]))
                               .replace(".", "," if decimal == "," else "."),
                               num(usetp_true(t[k])), num(efd_rated(t[k])),
                               num(400.0 + k), "OK"]))
    path = folder / "export.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path, t, steps


def uniform_export(folder: Path, *, n: int = 3000, step: float = 1e-3, name: str = "u.csv",
                   with_usetp: bool = False) -> tuple[Path, np.ndarray]:
    t = np.arange(n) * step
    header = ["Zeit_s", "EFD_V"] + (["USETP"] if with_usetp else [])
    lines = [",".join(header)]
    for k in range(n):
        row = [repr(float(t[k])), repr(float(efd_rated(t[k])))]
        if with_usetp:
            row.append(repr(float(usetp_true(t[k]))))
        lines.append(",".join(row))
    path = folder / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path, t


def _first_off_row(steps: np.ndarray) -> int:
    """The row check_time must name: the line of the sample ending the first step off the
    median by more than 1e-6 of it (header on line 1, sample k on line k + 2)."""
    d = steps * TENTH_MS
    med = np.median(d)
    i = int(np.flatnonzero(np.abs(d - med) > 1e-6 * med)[0])
    return i + 3


JITTER_SPEC = dict(columns={"usetp": "USETP", "efd": "EFD_V"}, date_column="Date",
                   clock_column="Time", delimiter=";", decimal=",", efd_base_scale=0.5)


def test_jittered_export_is_refused_without_resample(tmp_path: Path) -> None:
    src, _, steps = jittered_export(tmp_path)
    out = tmp_path / "cap.csv"
    with pytest.raises(CaptureError) as info:
        import_export(src, ImportSpec(**JITTER_SPEC), out)
    msg = str(info.value)
    assert msg.startswith(str(src)) and "non-uniform time step" in msg
    assert f"row {_first_off_row(steps)}," in msg and "column 'Time'" in msg
    assert not out.exists() and not out.with_suffix(".json").exists()


def test_jittered_export_resampled_matches_the_analytic_signal(tmp_path: Path) -> None:
    src, t_src, steps = jittered_export(tmp_path)
    out = tmp_path / "cap.csv"
    cap = import_export(src, ImportSpec(**JITTER_SPEC, resample_hz=1000.0), out)
    assert cap.rate_hz == pytest.approx(1000.0, rel=1e-9)
    assert cap.time[0] == 0.0 and cap.time[-1] <= t_src[-1] + 1e-12
    assert cap.time[-1] > t_src[-1] - 1e-3
    h = steps.max() * TENTH_MS
    bound = h**2 / 8 * 0.5 * (2 * np.pi * F_HZ) ** 2
    assert np.max(np.abs(cap.efd - 0.5 * efd_rated(cap.time))) <= 0.5 * bound
    assert np.max(np.abs(cap.usetp - usetp_true(cap.time))) <= h**2 / 8 * 0.05 * (2 * np.pi * 0.3) ** 2
    block = cap.meta["import"]
    assert block["resampled"]["to_rate_hz"] == 1000.0
    assert block["resampled"]["method"] == "linear interpolation"
    assert 0.0046 - 1e-12 <= block["resampled"]["from_step_s"]["min_s"] < 0.0048
    assert 0.0048 < block["resampled"]["from_step_s"]["max_s"] <= 0.0050 + 1e-12
    assert block["resampled"]["from_step_s"]["min_s"] == pytest.approx(steps.min() * TENTH_MS)
    assert block["resampled"]["from_step_s"]["max_s"] == pytest.approx(steps.max() * TENTH_MS)
    assert block["resampled"]["from_samples"] == len(t_src)
    assert block["resampled"]["to_samples"] == cap.n
    assert block["time"]["method"] == "date + clock columns"
    assert block["time"]["first_sample"] == "2026-03-14T10:31:07"
    assert block["efd_base_scale"] == 0.5 and block["scale"]["efd"] == 0.5
    assert block["columns"] == {"usetp": "USETP", "efd": "EFD_V"}
    assert block["usetp_synthesised"] is False
    assert block["source"]["sha256"] == hashlib.sha256(src.read_bytes()).hexdigest()
    assert block["source"]["path"] == str(src.resolve())
    assert block["source"]["delimiter"] == ";" and block["source"]["decimal"] == ","
    assert block["dropped_columns"] == ["IFD_A", "Status"]
    side = json.loads(out.with_suffix(".json").read_text(encoding="utf-8"))
    assert side["import"] == block and side["units"]["efd"] == "pu"


def test_uniform_export_is_accepted_scaled_and_vendor_names_mapped(tmp_path: Path) -> None:
    src, t = uniform_export(tmp_path, with_usetp=True)
    spec = ImportSpec(columns={"efd": "EFD_V", "usetp": "USETP"}, time_column="Zeit_s",
                      efd_base_scale=0.25)
    cap = import_export(src, spec, tmp_path / "cap.csv")
    assert np.array_equal(cap.time, t)
    assert np.array_equal(cap.efd, efd_rated(t) * 0.25)
    assert np.array_equal(cap.usetp, usetp_true(t))
    assert cap.meta["import"]["resampled"] is False
    assert cap.meta["import"]["time"] == {"method": "seconds column", "time_column": "Zeit_s",
                                          "unit": "s", "origin": "as in the source"}


def test_pulse_test_description_synthesises_usetp(tmp_path: Path) -> None:
    src, t = uniform_export(tmp_path)
    test = TestDescription("pulse", start_s=1.0, amplitude_pu=0.05, width_s=1.0)
    spec = ImportSpec(columns={"efd": "EFD_V"}, time_column="Zeit_s", test=test)
    cap = import_export(src, spec, tmp_path / "cap.csv")
    k = np.arange(len(t))  # 1 ms steps: the pulse covers samples 1000..1999
    assert np.array_equal(cap.usetp, np.where((k >= 1000) & (k < 2000), 1.05, 1.0))
    assert cap.meta["import"]["usetp_synthesised"] is True
    expected = {"kind": "pulse", "start_s": 1.0, "amplitude_pu": 0.05, "width_s": 1.0,
                "usetp0_pu": 1.0, "edge_tolerance_s": None, "source": "user description"}
    assert cap.meta["test"] == expected and cap.meta["import"]["test"] == expected


def test_step_test_description_with_other_initial_setpoint(tmp_path: Path) -> None:
    src, t = uniform_export(tmp_path)
    test = TestDescription("step", start_s=0.5, amplitude_pu=-0.02, usetp0_pu=0.98)
    cap = import_export(src, ImportSpec(columns={"efd": "EFD_V"}, time_column="Zeit_s",
                                        test=test), tmp_path / "cap.csv")
    k = np.arange(len(t))
    assert np.array_equal(cap.usetp, np.where(k >= 500, 0.96, 0.98))


def test_test_description_outside_the_record_is_refused(tmp_path: Path) -> None:
    src, _ = uniform_export(tmp_path)  # 0 .. 2.999 s
    test = TestDescription("pulse", start_s=2.5, amplitude_pu=0.05, width_s=1.0)
    with pytest.raises(CaptureError, match="end of the pulse at 3.5 s lies outside"):
        import_export(src, ImportSpec(columns={"efd": "EFD_V"}, time_column="Zeit_s",
                                      test=test), tmp_path / "cap.csv")


def test_spec_needs_usetp_or_a_test_and_valid_test_fields() -> None:
    with pytest.raises(ValueError, match="no usetp column mapped"):
        ImportSpec(columns={"efd": "EFD_V"}, time_column="t")
    with pytest.raises(ValueError, match="needs width_s"):
        TestDescription("pulse", start_s=1.0, amplitude_pu=0.05)
    with pytest.raises(ValueError, match="efd_base_scale"):
        ImportSpec(columns={"efd": "E", "usetp": "U"}, time_column="t", scale={"efd": 2.0})
    with pytest.raises(ValueError, match="decimal comma needs"):
        ImportSpec(columns={"efd": "E", "usetp": "U"}, time_column="t", decimal=",")


def test_missing_vendor_column_names_it_and_lists_the_header(tmp_path: Path) -> None:
    src, _ = uniform_export(tmp_path, with_usetp=True)
    with pytest.raises(CaptureError) as info:
        import_export(src, ImportSpec(columns={"efd": "EFD", "usetp": "USETP"},
                                      time_column="Zeit_s"), tmp_path / "cap.csv")
    msg = str(info.value)
    assert "row 1, column 'EFD'" in msg and "Zeit_s, EFD_V, USETP" in msg


def test_wrong_delimiter_and_unrequested_decimal_comma(tmp_path: Path) -> None:
    src, _, _ = jittered_export(tmp_path)
    spec = dict(JITTER_SPEC, delimiter=",", decimal=".")
    with pytest.raises(CaptureError, match="expected comma-separated values; the header looks "
                                           "semicolon-separated"):
        import_export(src, ImportSpec(**spec), tmp_path / "cap.csv")
    spec["delimiter"] = ";"
    with pytest.raises(CaptureError) as info:
        import_export(src, ImportSpec(**spec), tmp_path / "cap.csv")
    assert "row 2, column 'Time'" in str(info.value)  # '10:31:07,0000' needs decimal=','


def test_nan_in_vendor_column(tmp_path: Path) -> None:
    src, _ = uniform_export(tmp_path, with_usetp=True)
    lines = src.read_text(encoding="utf-8").splitlines()
    lines[41] = lines[41].split(",")[0] + ",NaN," + lines[41].split(",")[2]
    src.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(CaptureError, match=r"row 42, column 'EFD_V': value 'NaN' is not finite"):
        import_export(src, ImportSpec(columns={"efd": "EFD_V", "usetp": "USETP"},
                                      time_column="Zeit_s"), tmp_path / "cap.csv")


def test_dropout_is_not_interpolated_across(tmp_path: Path) -> None:
    src, _, _ = jittered_export(tmp_path)
    lines = src.read_text(encoding="utf-8").splitlines()
    del lines[100:110]  # ten samples lost: the next sample (was line 111) is now line 101
    src.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(CaptureError, match=r"row 101, column 'Time': gap of"):
        import_export(src, ImportSpec(**JITTER_SPEC, resample_hz=1000.0), tmp_path / "c.csv")


def test_midnight_crossing_with_date_is_continuous(tmp_path: Path) -> None:
    lines = ["Date,Time,EFD,U"]
    start = 23 * 3600 + 59 * 60 + 59  # 23:59:59.0000, 2 ms steps, 1000 samples
    for k in range(1000):
        ticks = k * 20
        day = "2026-03-14" if start + ticks // 10_000 < 86_400 else "2026-03-15"
        clock = _clock(ticks, start).replace("24:", "00:", 1)
        lines.append(f"{day},{clock},1.0,1.0")
    src = tmp_path / "mid.csv"
    src.write_text("\n".join(lines) + "\n", encoding="utf-8")
    spec = ImportSpec(columns={"efd": "EFD", "usetp": "U"}, date_column="Date",
                      clock_column="Time")
    cap = import_export(src, spec, tmp_path / "cap.csv")
    assert np.allclose(cap.time, np.arange(1000) * 0.002, rtol=0, atol=1e-12)
    with pytest.raises(CaptureError, match="row 502, column 'Time': decreasing time"):
        import_export(src, ImportSpec(columns={"efd": "EFD", "usetp": "U"},
                                      clock_column="Time"), tmp_path / "cap2.csv")


def test_kept_column_and_existing_output_is_not_overwritten(tmp_path: Path) -> None:
    src, _, _ = jittered_export(tmp_path)
    out = tmp_path / "cap.csv"
    cap = import_export(src, ImportSpec(**JITTER_SPEC, resample_hz=500.0,
                                        keep_columns=("IFD_A",)), out)
    assert cap.extra["IFD_A"][0] == 400.0 and cap.meta["import"]["kept_columns"] == ["IFD_A"]
    before = out.read_bytes()
    with pytest.raises(FileExistsError):
        import_export(src, ImportSpec(**JITTER_SPEC, resample_hz=1000.0), out)
    assert out.read_bytes() == before
    assert read_capture(out).rate_hz == pytest.approx(500.0, rel=1e-9)


def test_cli_import_ok_and_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src, _, _ = jittered_export(tmp_path)
    base = ["import", str(src), "--map", "efd=EFD_V", "--date-column", "Date",
            "--clock-column", "Time", "--delimiter", ";", "--decimal-comma",
            "--efd-scale", "0.5", "--test", "pulse:start=1.0,amplitude=0.05,width=1.0"]
    out = tmp_path / "cli.csv"
    assert main(base + ["-o", str(out), "--resample", "1000"]) == 0
    cap = read_capture(out)
    assert cap.meta["import"]["usetp_synthesised"] is True
    assert cap.meta["test"]["width_s"] == 1.0 and cap.rate_hz == pytest.approx(1000.0)
    assert main(base + ["-o", str(tmp_path / "cli2.csv")]) == 2  # jitter, no --resample: bad input
    err = capsys.readouterr().err
    assert err.startswith("error: " + str(src)) and "non-uniform time step" in err
    assert not (tmp_path / "cli2.csv").exists()
    assert main(base[:-1] + ["pulse:start=1.0,amp=0.05", "-o", str(tmp_path / "c3.csv")]) == 2


def test_preamble_lines_and_tab_delimiter(tmp_path: Path) -> None:
    t = np.arange(50) * 0.01
    lines = ["Recorder XY-7 export", "Channels: 2", "t\tEFD\tUSETP"]
    lines += [f"{float(x)!r}\t{float(efd_rated(x))!r}\t1.0" for x in t]
    src = tmp_path / "tab.txt"
    src.write_text("\n".join(lines) + "\n", encoding="utf-8")
    spec = ImportSpec(columns={"efd": "EFD", "usetp": "USETP"}, time_column="t",
                      delimiter="\t", header_line=3)
    cap = import_export(src, spec, tmp_path / "cap.csv")
    assert np.array_equal(cap.efd, efd_rated(t)) and cap.meta["import"]["source"]["header_line"] == 3
    lines[10] = lines[10].replace("\t1.0", "\tx")
    src.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(CaptureError, match=r"row 11, column 'USETP': not a number: 'x'"):
        import_export(src, spec, tmp_path / "cap2.csv")


def test_decimal_comma_file_refuses_a_dot_as_digit_separator(tmp_path: Path) -> None:
    """With a decimal comma, '1.234' is 1234 written with a thousands dot, or a mistake: refused,
    never read as 1.234."""
    src = tmp_path / "dots.csv"
    src.write_text("t;EFD;USETP\n0,000;1,5;1,0\n0,001;1.234;1,0\n0,002;2,0;1,0\n", encoding="utf-8")
    spec = ImportSpec(columns={"efd": "EFD", "usetp": "USETP"}, time_column="t", delimiter=";",
                      decimal=",")
    with pytest.raises(CaptureError) as info:
        import_export(src, spec, tmp_path / "cap.csv")
    assert "row 3" in str(info.value) and "'EFD'" in str(info.value)
    assert not (tmp_path / "cap.csv").exists()
