"""Outputs never destroy inputs (issue 15 item 3): a capture, its sidecar, a result, a unit file;
an existing output is replaced only with --force, and always through a temporary file."""
from __future__ import annotations

import hashlib
import os
import subprocess
from pathlib import Path

import pytest

from bench_ctl.capture import write_capture
from bench_ctl.cli import main
from bench_ctl.identification.synthetic import synthetic_capture
from bench_ctl.outputs import OutputRefused, guard_outputs, write_json
from bench_ctl.units.unit import reference_unit


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    d = tmp_path_factory.mktemp("outputs")
    cap = synthetic_capture(reference_unit(), duration=3.0, rate=500.0, seed=2)
    csv, side = write_capture(d / "cap.csv", {"time": cap.time, "usetp": cap.usetp, "efd": cap.efd},
                              {"test": {"kind": "pulse"}})
    assert main(["identify", str(csv), "--json", str(d / "r.json"), "--evals", "64", "--no-progress"]) in (0, 1)
    return d, csv, side


@pytest.mark.parametrize("argv", [
    ["identify", "{csv}", "--json", "{side}", "--evals", "64", "--no-progress"],
    ["identify", "{csv}", "--json", "{csv}", "--evals", "64", "--no-progress", "--force"],
    ["report", "{d}/r.json", "-o", "{csv}", "--force"],
    ["report", "{d}/r.json", "-o", "{d}/r.json", "--force"],
    ["report", "{d}/r.json", "-o", "{d}/out.html", "--pdf", "{side}"],
    ["diagnose", "{csv}", "--json", "{side}", "--force"],
])
def test_an_output_on_an_input_is_refused_and_the_input_kept(made, argv, capsys):
    d, csv, side = made
    before = {p: _sha(p) for p in (csv, side, d / "r.json")}
    rc = main([a.format(d=d, csv=csv, side=side) for a in argv])
    assert rc == 2
    assert "would overwrite" in capsys.readouterr().err
    assert {p: _sha(p) for p in before} == before


def test_an_existing_output_needs_force(made, capsys):
    d, csv, _side = made
    out = d / "again.json"
    out.write_text("{}\n", encoding="utf-8")
    assert main(["identify", str(csv), "--json", str(out), "--evals", "64", "--no-progress"]) == 2
    assert "exists" in capsys.readouterr().err and out.read_text() == "{}\n"
    assert main(["identify", str(csv), "--json", str(out), "--evals", "64", "--no-progress", "--force"]) in (0, 1)
    assert '"schema"' in out.read_text()


def test_guard_names_the_option_and_refuses_a_missing_folder(tmp_path):
    with pytest.raises(OutputRefused, match="--json .*folder .* does not exist"):
        guard_outputs({"--json": tmp_path / "nope" / "r.json"}, [])
    with pytest.raises(OutputRefused, match="the same file"):
        guard_outputs({"-o": tmp_path / "a", "--pdf": tmp_path / "a"}, [])
    comtrade = tmp_path / "rec.cfg"
    with pytest.raises(OutputRefused, match="part of input"):
        guard_outputs({"--json": tmp_path / "rec.dat"}, [comtrade])


def test_write_json_leaves_no_temporary_file_and_refuses_nan(tmp_path):
    write_json(tmp_path / "x.json", {"a": 1})
    with pytest.raises(ValueError, match="not JSON compliant"):
        write_json(tmp_path / "x.json", {"a": float("nan")}, force=True)
    with pytest.raises(OutputRefused, match="exists"):
        write_json(tmp_path / "x.json", {"a": 2})
    assert (tmp_path / "x.json").read_text() == '{\n "a": 1\n}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.json"]


# ---- issue 24: one guard for every file, side files included (item 8), one permission policy
# (item 20), a folder that cannot be written is one line and exit 2 (item 15)

def _report_files(d: Path, stem: str) -> list[Path]:
    return [d / f"{stem}.html"] + [d / f"{stem}_{n}.png" for n in ("response", "residual", "edges", "convergence")]


def test_a_report_side_file_linked_to_an_input_is_refused_and_the_input_kept(made, capsys):
    """`ln -s cap.json evil_response.png; report r.json -o evil.html` overwrote the capture's
    sidecar with a PNG; now refused before anything is written, --force or not."""
    d, csv, side = made
    before = {p: _sha(p) for p in (csv, side, d / "r.json")}
    link = d / "evil_response.png"
    link.symlink_to(side.name)
    try:
        for force in ([], ["--force"]):
            assert main(["report", str(d / "r.json"), "-o", str(d / "evil.html"), *force]) == 2
            err = capsys.readouterr().err
            assert "evil_response.png" in err and "would overwrite" in err, err
            assert not (d / "evil.html").exists() and not (d / "evil_residual.png").exists()
        assert {p: _sha(p) for p in before} == before and link.is_symlink()
        # a link to anything else (not an input) is refused too: never written through
        link.unlink()
        other = d / "elsewhere.png"
        other.write_bytes(b"keep")
        link.symlink_to(other.name)
        assert main(["report", str(d / "r.json"), "-o", str(d / "evil.html"), "--force"]) == 2
        assert "symbolic link" in capsys.readouterr().err and other.read_bytes() == b"keep"
    finally:
        link.unlink()


def test_an_existing_side_file_needs_force_and_is_replaced_by_rename(made, capsys):
    d, _csv, _side = made
    png = d / "side_residual.png"
    keep = d / "keep.png"
    keep.write_bytes(b"not a figure")
    png.hardlink_to(keep)              # written in place, the other name would change too
    assert main(["report", str(d / "r.json"), "-o", str(d / "side.html")]) == 2
    err = capsys.readouterr().err
    assert "side_residual.png" in err and "exists" in err and not (d / "side.html").exists()
    assert main(["report", str(d / "r.json"), "-o", str(d / "side.html"), "--force"]) in (0, 1)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and keep.read_bytes() == b"not a figure"
    assert not [p for p in d.iterdir() if p.name.endswith(".tmp")]


def test_diagnose_report_side_files_are_claimed_before_the_diagnosis(made, capsys):
    d, csv, side = made
    before = _sha(side)
    link = d / "dg_edges.png"
    link.symlink_to(side.name)
    try:
        assert main(["diagnose", str(csv), "--json", str(d / "dg.json"), "--report", str(d / "dg.html"),
                     "--force"]) == 2
        err = capsys.readouterr().err
        assert "dg_edges.png" in err and "would overwrite" in err and not (d / "dg.json").exists()
        assert _sha(side) == before
    finally:
        link.unlink()


@pytest.mark.slow
def test_every_output_follows_the_umask(made, tmp_path):
    """One policy for results, captures, reports, figures, PDFs and records (issue 24 item 20:
    results were 0600, captures 0644): 0666 minus the umask, as any tool's."""
    d, csv, _side = made
    old = os.umask(0o022)
    try:
        out = tmp_path / "perm"
        out.mkdir()
        assert main(["simulate", "-o", str(out / "s.csv"), "--duration", "3", "--rate", "500"]) == 0
        assert main(["identify", str(csv), "--json", str(out / "r.json"), "--plot", str(out / "fit.png"),
                     "--evals", "64", "--no-progress"]) in (0, 1)
        assert main(["report", str(out / "r.json"), "-o", str(out / "rep.html"),   # the capture is the fixture's
                     "--pdf", str(out / "rep.pdf"), "--allow-outside"]) in (0, 1)
        assert main(["export", str(out / "r.json"), "--dyr", str(out / "r.dyr")]) == 0
        files = sorted(out.iterdir())
        assert {p.name for p in files} >= {"s.csv", "s.json", "r.json", "fit.png", "rep.html", "rep_response.png",
                                           "rep.pdf", "r.dyr"}
        assert {p.name: oct(p.stat().st_mode & 0o777) for p in files} == {p.name: "0o644" for p in files}
        os.umask(0o077)
        assert main(["export", str(out / "r.json"), "--dyr", str(out / "private.dyr")]) == 0
        assert (out / "private.dyr").stat().st_mode & 0o777 == 0o600
    finally:
        os.umask(old)


@pytest.fixture()
def readonly_dir(tmp_path):
    """A folder nothing can be written into: a read-only tmpfs mounted there when running as root
    (root ignores permission bits), else a folder without write permission."""
    ro = tmp_path / "ro"
    ro.mkdir()
    if os.geteuid() != 0:
        ro.chmod(0o555)
        yield ro
        ro.chmod(0o755)
        return
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a read-only file system here: {r.stderr.decode().strip()}")
    try:
        yield ro
    finally:
        subprocess.run(["umount", str(ro)], check=True)


def test_a_read_only_output_folder_is_one_line_and_exit_2(made, readonly_dir, capsys):
    """identify --json onto a read-only file system ended a whole fit in a traceback (issue 24
    item 15); every analysis command now refuses the folder before its work, in one line."""
    d, csv, _side = made
    ro = readonly_dir
    for argv in (["identify", str(csv), "--json", str(ro / "r.json"), "--evals", "64", "--no-progress"],
                 ["identify", str(csv), "--plot", str(ro / "fit.png"), "--evals", "64", "--no-progress"],
                 ["diagnose", str(csv), "--json", str(ro / "d.json")],
                 ["report", str(d / "r.json"), "-o", str(ro / "rep.html")],
                 ["export", str(d / "r.json"), "--dyr", str(ro / "r.dyr")],
                 ["simulate", "-o", str(ro / "s.csv"), "--duration", "3"],
                 ["import", str(csv), "-o", str(ro / "i.csv"), "--map", "efd=efd", "--map", "usetp=usetp",
                  "--time-column", "time"]):
        assert main(argv) == 2, argv
        printed = capsys.readouterr()
        err = printed.err
        assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err, err
        assert str(ro) in err and ("read-only" in err or "permission denied" in err), err
        assert printed.out == "", argv   # refused before the fit (its summary), not after it
    assert list(ro.iterdir()) == []
