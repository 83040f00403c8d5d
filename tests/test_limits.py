"""The one reader of input files (`bench_ctl.limits`): every refusal names the file first, then
what is wrong, and each loader (bench config, unit file, profile, manifest, result JSON) says the
same words through its own error type."""
from __future__ import annotations

import hashlib
import os

import pytest

from bench_ctl.limits import InputError, read_bounded, read_json, read_text, sha256_file


def test_a_device_a_folder_and_a_missing_file_are_refused_unread(tmp_path):
    for path, words in (("/dev/zero", "not a regular file"), (str(tmp_path), "not a regular file"),
                        (str(tmp_path / "none.toml"), "cannot read: No such file")):
        for read in (lambda p: read_bounded(p, "a unit file"), lambda p: read_text(p, "a unit file"),
                     lambda p: read_json(p, "a result JSON"), sha256_file):
            with pytest.raises(InputError) as info:
                read(path)
            assert str(info.value).startswith(f"{path}: ") and words in str(info.value)
            assert info.value.file == path and words in info.value.reason


def test_a_file_over_its_kinds_limit_is_refused_naming_the_limit(tmp_path):
    big = tmp_path / "big.toml"
    with open(big, "wb") as f:
        f.truncate((1 << 20) + 1)                   # sparse: one byte more than a page of TOML
    with pytest.raises(InputError, match=r"1048577 bytes, more than the 1048576 bytes a bench config may have"):
        read_text(big, "a bench config")
    assert read_bounded(big, "a capture") == bytes((1 << 20) + 1)    # a capture may be larger


def test_text_is_utf8_a_bom_is_dropped_and_a_bad_byte_is_named_with_its_line(tmp_path):
    f = tmp_path / "m.csv"
    f.write_bytes(b"\xef\xbb\xbfcapture\na.csv\n")
    assert read_text(f, "a manifest") == "capture\na.csv\n"
    f.write_bytes(b"capture\na\xff.csv\n")
    with pytest.raises(InputError, match=r"m.csv: not a UTF-8 text file \(byte 9, line 2\)"):
        read_text(f, "a manifest")


def test_json_errors_name_line_and_column(tmp_path):
    f = tmp_path / "r.json"
    f.write_text('{"params": {"KA": 1.0}}')
    assert read_json(f, "a result JSON") == {"params": {"KA": 1.0}}
    f.write_text('{\n  "params": ,\n}')
    with pytest.raises(InputError, match=r"r.json: invalid JSON: Expecting value \(line 2, column 13\)"):
        read_json(f, "a result JSON")


def test_sha256_file_is_the_hash_of_the_bytes(tmp_path):
    f = tmp_path / "c.csv"
    data = os.urandom(3 * (1 << 20) + 17)            # more than one chunk
    f.write_bytes(data)
    assert sha256_file(f) == hashlib.sha256(data).hexdigest()


def test_every_loader_refuses_a_device_with_the_same_words(tmp_path):
    """A bench config, a unit file, a profile and a manifest: each loader's own error type, the
    reader's words."""
    from bench_ctl.fleet.manifest import ManifestError, read_manifest
    from bench_ctl.runner.config import ConfigError, load_bench_config
    from bench_ctl.units.unit import UnitError, load_unit
    from drivers.profile import load_profile

    for load, error, kind in ((load_bench_config, ConfigError, "a bench config"),
                              (load_unit, UnitError, "a unit file"),
                              (load_profile, ValueError, "a profile"),
                              (read_manifest, ManifestError, "a manifest")):
        with pytest.raises(error) as info:
            load("/dev/zero")
        assert str(info.value) == ("/dev/zero: not a regular file (a device, pipe or folder): "
                                   f"{kind} is read from a file")
