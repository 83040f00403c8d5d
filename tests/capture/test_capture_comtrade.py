"""COMTRADE records read as captures. The fixtures are written here, byte by byte, from the
IEEE C37.111-1999 layout (not by the `comtrade` package that the reader uses)."""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bench_ctl.capture import CaptureError, read_capture
from bench_ctl.capture.comtrade_io import read_comtrade
from bench_ctl.capture.importer import ImportSpec, TestDescription, import_export

RATE_HZ = 1000.0
N = 600


@dataclass(frozen=True)
class Analog:
    name: str
    unit: str
    a: float
    b: float
    raw: np.ndarray  # int16 counts; the value is a * raw + b
    skew_us: float = 0.0


def write_comtrade_1999(folder: Path, name: str, *, ft: str, analog: list[Analog],
                        status: list[tuple[str, np.ndarray]] = (), rate_hz: float = RATE_HZ,
                        timestamps_us: np.ndarray | None = None,
                        declared_samples: int | None = None,
                        ascii_override: dict[int, str] | None = None) -> Path:
    """Write NAME.cfg + NAME.dat (1999 revision, ASCII or BINARY). With `timestamps_us`
    the .cfg declares no sample rate (nrates 0) and time comes from the timestamps."""
    n = len(analog[0].raw)
    ts = (np.round(np.arange(n) / rate_hz * 1e6).astype(np.int64)
          if timestamps_us is None else timestamps_us)
    lines = ["Test station,AVR-REC-1,1999",
             f"{len(analog) + len(status)},{len(analog)}A,{len(status)}D"]
    for k, ch in enumerate(analog, start=1):
        lines.append(f"{k},{ch.name},,,{ch.unit},{ch.a!r},{ch.b!r},{ch.skew_us},-32767,32767,"
                     "1,1,P")
    for k, (sname, _) in enumerate(status, start=len(analog) + 1):
        lines.append(f"{k},{sname},,,0")
    lines.append("50")
    if timestamps_us is None:
        lines += ["1", f"{rate_hz!r},{declared_samples or n}"]
    else:
        lines += ["0", f"0,{declared_samples or n}"]
    lines += ["14/03/2026,10:31:07.000000", "14/03/2026,10:31:07.100000", ft, "1"]
    (folder / f"{name}.cfg").write_text("\r\n".join(lines) + "\r\n", encoding="utf-8")
    words = math.ceil(len(status) / 16)
    if ft == "ASCII":
        rows = []
        for i in range(n):
            fields = [str(i + 1), str(ts[i])] + [str(int(ch.raw[i])) for ch in analog]
            fields += [str(int(v[i])) for _, v in status]
            rows.append(",".join(fields))
        for i, text in (ascii_override or {}).items():
            rows[i] = text
        (folder / f"{name}.dat").write_text("\r\n".join(rows) + "\r\n", encoding="utf-8")
    else:
        fmt = "<II" + "h" * len(analog) + "H" * words
        out = bytearray()
        for i in range(n):
            packed = [0] * words
            for j, (_, v) in enumerate(status):
                packed[j // 16] |= int(v[i]) << (j % 16)
            out += struct.pack(fmt, i + 1, int(ts[i]), *(int(ch.raw[i]) for ch in analog),
                               *packed)
        (folder / f"{name}.dat").write_bytes(bytes(out))
    return folder / f"{name}.cfg"


def _signals(seed: int = 7) -> dict[str, Analog]:
    rng = np.random.default_rng(seed)
    t = np.arange(N) / RATE_HZ
    usetp = np.where((t >= 0.1) & (t < 0.3), 1.05, 1.0)
    efd = 1.0 + 2.0 * np.exp(-(t - 0.1) / 0.05) * (t >= 0.1) + rng.normal(0, 0.01, N)
    vt = 1.0 + 0.02 * (t >= 0.15)
    ifd = 400.0 + 50.0 * np.sin(2 * np.pi * 5 * t)
    def counts(x: np.ndarray, a: float, b: float) -> np.ndarray:
        return np.round((x - b) / a).astype(np.int64)
    return {
        "USETP": Analog("USETP", "pu", 1e-4, 0.0, counts(usetp, 1e-4, 0.0)),
        "EFD": Analog("EFD", "pu", 2e-4, -1.0, counts(efd, 2e-4, -1.0)),
        "VT": Analog("VT", "kV", 1e-3, 0.0, counts(vt * 18.0, 1e-3, 0.0)),
        "IFD": Analog("IFD", "A", 0.05, 0.0, counts(ifd, 0.05, 0.0)),
    }


MAP = {"usetp": "USETP", "efd": "EFD", "vt": "VT"}


@pytest.mark.parametrize("ft", ["ASCII", "BINARY"])
def test_read_ascii_and_binary(tmp_path: Path, ft: str) -> None:
    sig = _signals()
    trip = np.zeros(N, dtype=np.int64)
    trip[300:] = 1
    cfg = write_comtrade_1999(tmp_path, "rec", ft=ft, analog=list(sig.values()),
                              status=[("TRIP", trip)])
    cap = read_comtrade(cfg, MAP, scale={"vt": 1 / 18.0})
    assert cap.n == N and cap.rate_hz == pytest.approx(RATE_HZ, rel=1e-9)
    assert np.allclose(cap.time, np.arange(N) / RATE_HZ, rtol=0, atol=1e-12)
    for our, ch in (("usetp", "USETP"), ("efd", "EFD")):
        a, b, raw = sig[ch].a, sig[ch].b, sig[ch].raw
        assert np.allclose(getattr(cap, our), a * raw + b, rtol=0, atol=1e-12), our
    assert np.allclose(cap.vt, sig["VT"].a * sig["VT"].raw / 18.0, rtol=0, atol=1e-12)
    assert np.allclose(cap.extra["IFD"], 0.05 * sig["IFD"].raw, rtol=0, atol=1e-9)
    assert np.array_equal(cap.extra["TRIP"], trip.astype(float))
    assert cap.source == str(cfg)
    assert cap.meta["comtrade"]["ft"] == ft and cap.meta["comtrade"]["rev_year"] == "1999"
    assert cap.meta["channels"]["vt"]["unit"] == "kV"
    assert cap.meta["channels"]["vt"]["scale"] == pytest.approx(1 / 18.0)
    assert cap.meta["comtrade"]["trigger_time_s"] == pytest.approx(0.1)


def test_comtrade_capture_can_be_written_and_read_back(tmp_path: Path) -> None:
    from bench_ctl.capture import write_capture

    cfg = write_comtrade_1999(tmp_path, "rec", ft="BINARY", analog=list(_signals().values()))
    cap = read_comtrade(cfg, {"usetp": "USETP", "efd": "EFD"})
    write_capture(tmp_path / "cap.csv", cap)
    back = read_capture(tmp_path / "cap.csv")
    assert np.array_equal(back.efd, cap.efd) and back.meta["comtrade"]["dat_sha256"]
    assert back.meta["units"] == {"time": "s", "usetp": "pu", "efd": "pu", "VT": "kV",
                                  "IFD": "A"}


def test_the_stabilisers_output_maps_to_the_vs_channel(tmp_path: Path) -> None:
    """A PSS output channel mapped to `vs` is a named channel in pu, written and read back."""
    from bench_ctl.capture import write_capture

    sig = _signals()
    vs = 0.01 * np.sin(2 * np.pi * 2.0 * np.arange(N) / RATE_HZ)
    pss = Analog("PSS_OUT", "V", 1e-4, 0.0, np.round(vs * 10.0 / 1e-4).astype(np.int64))   # 10 V = 1 pu
    cfg = write_comtrade_1999(tmp_path, "rec", ft="BINARY", analog=[*sig.values(), pss])
    cap = read_comtrade(cfg, {**MAP, "vs": "PSS_OUT"}, scale={"vt": 1 / 18.0, "vs": 0.1})
    assert np.allclose(cap.channel("vs"), vs, rtol=0, atol=1e-5) and "PSS_OUT" not in cap.extra
    write_capture(tmp_path / "cap.csv", cap)
    back = read_capture(tmp_path / "cap.csv")
    assert np.array_equal(back.channel("vs"), cap.channel("vs")) and back.meta["units"]["vs"] == "pu"


def test_unknown_channel_names_file_channel_and_available(tmp_path: Path) -> None:
    cfg = write_comtrade_1999(tmp_path, "rec", ft="ASCII", analog=list(_signals().values()))
    with pytest.raises(CaptureError) as info:
        read_comtrade(cfg, {"usetp": "USETP", "efd": "Efd"})
    msg = str(info.value)
    assert msg.startswith(str(cfg)) and "channel 'Efd'" in msg
    assert "available: USETP, EFD, VT, IFD" in msg and "did you mean 'EFD'" in msg


def test_non_pu_unit_needs_a_scale(tmp_path: Path) -> None:
    cfg = write_comtrade_1999(tmp_path, "rec", ft="ASCII", analog=list(_signals().values()))
    with pytest.raises(CaptureError, match=r"channel 'VT': unit 'kV' is not per-unit"):
        read_comtrade(cfg, MAP)


@pytest.mark.parametrize("ft, missing, where", [("ASCII", 99999, "row 51"),
                                                ("BINARY", -32768, "sample 51")])
def test_missing_value_names_row_and_channel(tmp_path: Path, ft: str, missing: int,
                                             where: str) -> None:
    sig = _signals()
    raw = sig["EFD"].raw.copy()
    raw[50] = missing
    analog = [sig["USETP"], Analog("EFD", "pu", 2e-4, -1.0, raw)]
    cfg = write_comtrade_1999(tmp_path, "rec", ft=ft, analog=analog)
    with pytest.raises(CaptureError) as info:
        read_comtrade(cfg, {"usetp": "USETP", "efd": "EFD"})
    msg = str(info.value)
    assert msg.startswith(str(tmp_path / "rec.dat")) and where in msg and "channel 'EFD'" in msg


def test_ascii_non_numeric_field(tmp_path: Path) -> None:
    sig = _signals()
    cfg = write_comtrade_1999(tmp_path, "rec", ft="ASCII", analog=[sig["USETP"], sig["EFD"]],
                              ascii_override={9: "10,9000,10000,x12"})
    with pytest.raises(CaptureError) as info:
        read_comtrade(cfg, {"usetp": "USETP", "efd": "EFD"})
    assert "row 10" in str(info.value) and "channel 'EFD'" in str(info.value)


@pytest.mark.parametrize("ft", ["ASCII", "BINARY"])
def test_dat_shorter_than_declared(tmp_path: Path, ft: str) -> None:
    sig = _signals()
    cfg = write_comtrade_1999(tmp_path, "rec", ft=ft, analog=[sig["USETP"], sig["EFD"]],
                              declared_samples=N + 5)
    with pytest.raises(CaptureError) as info:
        read_comtrade(cfg, {"usetp": "USETP", "efd": "EFD"})
    assert str(info.value).startswith(str(tmp_path / "rec.dat"))
    assert f"declares {N + 5}" in str(info.value)


def test_channel_skew_is_refused(tmp_path: Path) -> None:
    sig = _signals()
    efd = Analog("EFD", "pu", 2e-4, -1.0, sig["EFD"].raw, skew_us=120.0)
    cfg = write_comtrade_1999(tmp_path, "rec", ft="ASCII", analog=[sig["USETP"], efd])
    with pytest.raises(CaptureError, match="channel 'EFD': time skew 120"):
        read_comtrade(cfg, {"usetp": "USETP", "efd": "EFD"})


def test_timestamp_time_uniform_accepted_jittered_refused(tmp_path: Path) -> None:
    sig = _signals()
    analog = [sig["USETP"], sig["EFD"]]
    ts = np.arange(N, dtype=np.int64) * 500  # 2 kHz in microsecond timestamps
    cap = read_comtrade(write_comtrade_1999(tmp_path, "ok", ft="BINARY", analog=analog,
                                            timestamps_us=ts), {"usetp": "USETP", "efd": "EFD"})
    assert cap.rate_hz == pytest.approx(2000.0, rel=1e-9)
    ts = ts.copy()
    ts[200:] += 40
    with pytest.raises(CaptureError) as info:
        read_comtrade(write_comtrade_1999(tmp_path, "jit", ft="BINARY", analog=analog,
                                          timestamps_us=ts), {"usetp": "USETP", "efd": "EFD"})
    assert "sample 201" in str(info.value) and "non-uniform" in str(info.value)


def test_import_comtrade_without_setpoint_channel(tmp_path: Path) -> None:
    sig = _signals()
    cfg = write_comtrade_1999(tmp_path, "rec", ft="BINARY", analog=[sig["EFD"], sig["IFD"]])
    spec = ImportSpec(columns={"efd": "EFD"}, efd_base_scale=0.5,
                      test=TestDescription("pulse", start_s=0.1, amplitude_pu=0.05,
                                           width_s=0.2))
    cap = import_export(cfg, spec, tmp_path / "cap.csv")
    k = np.arange(N)
    assert np.array_equal(cap.usetp, np.where((k >= 100) & (k < 300), 1.05, 1.0))
    assert np.allclose(cap.efd, 0.5 * (2e-4 * sig["EFD"].raw - 1.0), rtol=0, atol=1e-12)
    block = cap.meta["import"]
    assert block["source"]["format"] == "comtrade" and block["usetp_synthesised"] is True
    assert block["dropped_columns"] == ["IFD"]


def test_padded_missing_value_is_refused_not_read_as_data(tmp_path: Path) -> None:
    """Fixed-width writers pad fields; ' 99999' is still the 1999 'no data' marker."""
    sig = _signals()
    cfg = write_comtrade_1999(tmp_path, "rec", ft="ASCII", analog=[sig["USETP"], sig["EFD"]],
                              ascii_override={50: f"51,50000, {int(sig['USETP'].raw[50])}, 99999"})
    with pytest.raises(CaptureError) as info:
        read_comtrade(cfg, {"usetp": "USETP", "efd": "EFD"})
    assert "row 51" in str(info.value) and "channel 'EFD'" in str(info.value)
    assert "missing value" in str(info.value)


def test_blank_unit_is_not_taken_for_per_unit(tmp_path: Path) -> None:
    sig = _signals()
    efd = Analog("EFD", "", 2e-4, -1.0, sig["EFD"].raw)
    cfg = write_comtrade_1999(tmp_path, "rec", ft="ASCII", analog=[sig["USETP"], efd])
    with pytest.raises(CaptureError, match=r"channel 'EFD': unit '' is not per-unit"):
        read_comtrade(cfg, {"usetp": "USETP", "efd": "EFD"})
    cap = read_comtrade(cfg, {"usetp": "USETP", "efd": "EFD"}, scale={"efd": 1.0})  # said: it is pu
    assert cap.n == N


def test_jittered_comtrade_imports_when_resampling_is_asked_for(tmp_path: Path) -> None:
    sig = _signals()
    ts = np.arange(N, dtype=np.int64) * 1000
    ts[1:-1] += np.where(np.arange(1, N - 1) % 2 == 0, 30, -30)  # +-30 us around 1 ms
    cfg = write_comtrade_1999(tmp_path, "jit", ft="BINARY", analog=[sig["USETP"], sig["EFD"]],
                              timestamps_us=ts)
    spec = ImportSpec(columns={"usetp": "USETP", "efd": "EFD"}, resample_hz=1000.0)
    cap = import_export(cfg, spec, tmp_path / "cap.csv")
    assert cap.n == N and cap.meta["import"]["resampled"]["to_rate_hz"] == 1000.0
    with pytest.raises(CaptureError, match="non-uniform"):  # not asked: refused, as before
        import_export(cfg, ImportSpec(columns={"usetp": "USETP", "efd": "EFD"}), tmp_path / "c2.csv")
