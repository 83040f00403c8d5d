"""The register-map codec (drivers/profile.py): encodings pinned by hand-computed words."""
from __future__ import annotations

import struct
from pathlib import Path

import pytest

from drivers.profile import PROFILE_DIR, Register, load_profile, profile_from_dict


def reg(**kw) -> Register:
    base = dict(name="x", table="holding", address=0, type="uint16", access="rw")
    base.update(kw)
    return Register(**base)


# ---------------------------------------------------------------- encode / decode
def test_float32_abcd_and_cdab_words():
    # 1.05 as IEEE-754 single is 0x3F866666 (hand-checked: 1.05 = 1.00001100110011... b)
    assert reg(type="float32").encode(1.05) == [0x3F86, 0x6666]
    assert reg(type="float32", word_order="CDAB").encode(1.05) == [0x6666, 0x3F86]
    assert reg(type="float32").decode([0x3F80, 0x0000]) == 1.0
    assert reg(type="float32", word_order="CDAB").decode([0x0000, 0x3F80]) == 1.0
    assert reg(type="float32").decode([0xC080, 0x0000]) == -4.0


def test_scaled_integers():
    r = reg(type="uint16", scale=0.0001, unit="pu")
    assert r.encode(1.05) == [10500]           # 1.05 / 0.0001 = 10500.000000000002 -> whole count
    assert r.decode([10500]) == pytest.approx(1.05, abs=1e-15)
    s = reg(type="int16", scale=0.01)
    assert s.encode(-1.5) == [0xFFFF - 150 + 1]    # two's complement of -150
    assert s.decode([0xFF6A]) == pytest.approx(-1.5)
    i32 = reg(type="int32", word_order="CDAB", scale=0.001)
    # -100000 counts = 0xFFFE7960 -> low word first
    assert i32.encode(-100.0) == [0x7960, 0xFFFE]
    assert i32.decode([0x7960, 0xFFFE]) == pytest.approx(-100.0)
    u32 = reg(type="uint32", scale=0.001)
    assert u32.encode(70.0) == [0x0001, 0x1170]    # 70000 = 0x00011170
    assert u32.decode([0x0001, 0x1170]) == pytest.approx(70.0)


def test_word_count():
    assert reg(type="int16").count == 1
    assert reg(type="float32").count == 2
    assert reg(type="uint32").count == 2


def test_encode_refuses_out_of_range_naming_register_and_value():
    r = reg(name="setpoint", type="float32", min=0.9, max=1.1)
    with pytest.raises(ValueError, match=r"setpoint.*1\.2.*above max 1\.1"):
        r.encode(1.2)
    with pytest.raises(ValueError, match=r"setpoint.*0\.5.*below min"):
        r.encode(0.5)
    with pytest.raises(ValueError, match="not finite"):
        r.encode(float("nan"))


def test_encode_refuses_unrepresentable_instead_of_clipping():
    with pytest.raises(ValueError, match=r"x.*uint16 range"):
        reg(type="uint16").encode(70000)
    with pytest.raises(ValueError, match=r"x.*-1"):
        reg(type="uint16").encode(-1)
    with pytest.raises(ValueError, match="not a multiple of the scale"):
        reg(type="uint16", scale=0.0001).encode(1.05123)
    with pytest.raises(ValueError, match="overflows float32"):
        reg(type="float32").encode(1e39)


def test_decode_checks_word_count_and_width():
    with pytest.raises(ValueError, match="expected 2 word"):
        reg(type="float32").decode([1])
    with pytest.raises(ValueError, match="16-bit"):
        reg(type="uint16").decode([70000])


def test_roundtrip_random_values():
    import random
    rnd = random.Random(4)
    for typ, scale in (("int16", 0.001), ("uint16", 0.5), ("int32", 1e-4), ("uint32", 1.0)):
        for order in ("ABCD", "CDAB"):
            r = reg(type=typ, scale=scale, word_order=order)
            lo, hi = {"int16": (-32768, 32767), "uint16": (0, 65535),
                      "int32": (-2**31, 2**31 - 1), "uint32": (0, 2**32 - 1)}[typ]
            for _ in range(50):
                count = rnd.randint(lo, hi)
                assert r.decode(r.encode(count * scale)) == pytest.approx(count * scale)
    f = reg(type="float32", word_order="CDAB")
    for _ in range(50):
        v = rnd.uniform(-1e6, 1e6)
        assert f.decode(f.encode(v)) == struct.unpack(">f", struct.pack(">f", v))[0]


# ---------------------------------------------------------------- files
def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "p.toml"
    p.write_text(text)
    return p


HEAD = '[profile]\nname = "t"\ndevice = "exciter"\n'


def test_unknown_key_names_file_and_key(tmp_path):
    p = _write(tmp_path, HEAD + '[registers.a]\ntable="holding"\naddress=0\ntype="uint16"\nwordorder="ABCD"\n')
    with pytest.raises(ValueError, match=r"p\.toml.*registers\.a\.'wordorder'"):
        load_profile(p)
    p = _write(tmp_path, HEAD + 'colour = 1\n[registers.a]\ntable="holding"\naddress=0\ntype="uint16"\n')
    with pytest.raises(ValueError, match=r"p\.toml.*profile\.'colour'"):
        load_profile(p)


def test_overlapping_registers_refused(tmp_path):
    p = _write(tmp_path, HEAD + '[registers.a]\ntable="holding"\naddress=0\ntype="float32"\n'
                                '[registers.b]\ntable="holding"\naddress=1\ntype="uint16"\n')
    with pytest.raises(ValueError, match=r"'a' \(0\.\.1\) and 'b' \(1\.\.1\) overlap"):
        load_profile(p)
    # same address in different tables is fine
    p = _write(tmp_path, HEAD + '[registers.a]\ntable="holding"\naddress=0\ntype="float32"\n'
                                '[registers.b]\ntable="input"\naddress=1\ntype="uint16"\n')
    assert set(load_profile(p).registers) == {"a", "b"}


def test_bad_values_refused(tmp_path):
    for body, pattern in (('table="coil"', "table 'coil'"), ('type="float64"', "type 'float64'"),
                          ('access="w"', "access 'w'")):
        text = HEAD + '[registers.a]\naddress=0\n' + ('table="holding"\n' if "table" not in body else "") \
            + ('type="uint16"\n' if "type=" not in body else "") + body + "\n"
        with pytest.raises(ValueError, match=pattern):
            load_profile(_write(tmp_path, text))
    text = HEAD + '[registers.a]\ntable="input"\naddress=0\ntype="uint16"\naccess="rw"\n'
    with pytest.raises(ValueError, match="read-only"):
        load_profile(_write(tmp_path, text))


def test_data_window_must_not_overlap_registers():
    doc = {"profile": {"name": "r", "device": "recorder"},
           "settings": {"block_data_address": 10, "block_words": 120},
           "registers": {"status": {"table": "input", "address": 50, "type": "uint16"}}}
    with pytest.raises(ValueError, match="block data window"):
        profile_from_dict(doc)


def test_bare_name_resolves_to_profiles_dir():
    p = load_profile("sim-exciter")
    assert Path(p.path) == PROFILE_DIR / "sim-exciter.toml"
    assert p.device == "exciter"
    assert p["setpoint"].writable and p["setpoint"].min == 0.9 and p["setpoint"].max == 1.1
    with pytest.raises(FileNotFoundError):
        load_profile("no-such-profile")


def test_shipped_profiles_match_the_documented_map():
    """Addresses as written in docs/devices.md (hand-copied, not read from the TOML)."""
    e = load_profile("sim-exciter")
    expect = {"setpoint": ("holding", 0, "float32"), "heartbeat": ("holding", 2, "uint16"),
              "mode": ("holding", 3, "uint16"), "active_setpoint": ("input", 0, "float32"),
              "vt": ("input", 2, "float32"), "efd": ("input", 4, "float32"),
              "ifd": ("input", 6, "float32"), "p": ("input", 8, "float32"),
              "status": ("input", 10, "uint16")}
    for name, (table, addr, typ) in expect.items():
        r = e[name]
        assert (r.table, r.address, r.type) == (table, addr, typ), name
    assert dict(e["mode"].bits) == {"auto": 0, "remote": 1}
    r = load_profile("sim-recorder")
    expect = {"sample_rate": ("holding", 0), "pre_trigger": ("holding", 1),
              "record_length": ("holding", 2), "trigger_mode": ("holding", 4),
              "trigger_threshold": ("holding", 5), "arm": ("holding", 7), "trigger": ("holding", 8),
              "block_index": ("holding", 9), "status": ("input", 0), "sample_count": ("input", 1),
              "block_count": ("input", 4), "record_crc": ("input", 5),
              "trigger_sample": ("input", 7), "block_echo": ("input", 100)}
    for name, (table, addr) in expect.items():
        assert (r[name].table, r[name].address) == (table, addr), name
    assert r.data_window_spans() == [("block data window", "input", 101, 221)]
    assert dict(r["status"].values) == {"idle": 0, "recording": 1, "armed": 2, "triggered": 3,
                                        "done": 4}
