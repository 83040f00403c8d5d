"""A full disk or a read-only output folder never decides the safe state (issue 24 items 3, 15).

The run reports what it could not save and exits 2 (3 if the safe state was not confirmed);
an output folder that cannot be written at all is refused before anything is sent.

How the disk is made full, and why: the exact moment is injected in-process (the audit's file
raising ENOSPC from the pulse on, the capture or raw writer raising ENOSPC at the download), so
each case is deterministic; the real thing runs `bench-ctl run` as a process whose files the
kernel refuses - RLIMIT_FSIZE (any POSIX system, root included: EFBIG once a file passes 12 KB)
and, where unprivileged mount namespaces exist, a real 12 KB tmpfs under --out (ENOSPC, the
issue's case) and a read-only tmpfs (EROFS). A folder made read-only with chmod is used when
not root (root writes through it).
"""
from __future__ import annotations

import errno
import functools
import os
import resource
import shutil
import subprocess

import pytest

from bench_ctl.cli import main
from bench_ctl.runner.audit import read_audit
from bench_ctl.runner.runner import OutputUnusable, run_procedure
from cli_runs import FAST_PARAMS, ROOT, bench_toml, run_argv, start_run
from pulse_bench import bench_config
from simulators.bench import SimBench

ENOSPC = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


class FullDisk:
    """A file object whose writes fail as on a full disk (flush too: buffered bytes go nowhere)."""

    def __init__(self, fh):
        self._fh = fh

    def write(self, text):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    flush = write

    def fileno(self):
        return self._fh.fileno()

    def close(self):
        self._fh.close()


def device_kinds(sim):
    return [(k, round(v, 4)) for _, k, v in sim.exciter.events]


FULL_SEQUENCE = [("remote", 1.0), ("setpoint", 1.05), ("setpoint", 1.0), ("local", 1.0)]


def test_audit_full_from_the_pulse_on_still_restores_and_releases(bench, tmp_path):
    sim, proxy = bench

    def disk_fills(run):
        run.audit._fh = FullDisk(run.audit._fh)

    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                        params=FAST_PARAMS, hooks={"pulse_applied": disk_fills})
    assert out.exit_code == 2 and out.safe
    assert out.message.startswith(str(out.audit_path) + ": NOT SAVED: ")
    assert "lines lost ([Errno 28] No space left on device); run ended with: recorded width" \
        in out.message
    assert out.not_saved and "audit.jsonl" in out.not_saved[0]
    assert device_kinds(sim) == FULL_SEQUENCE                 # restored, remote given back
    assert not sim.exciter.remote and not sim.exciter.watchdog_tripped
    assert sim.recorder.status in ("done", "idle")
    rows = read_audit(out.audit_path)                         # what was written stays readable
    assert rows[-1]["kind"] == "hook" and rows[-1]["name"] == "pulse_applied"


def test_capture_not_saved_at_the_download_is_said_with_exit_2(bench, tmp_path, monkeypatch):
    sim, proxy = bench

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp_path / "capture.csv"))

    monkeypatch.setattr("bench_ctl.runner.context.write_capture", full)
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                        params=FAST_PARAMS)
    assert out.exit_code == 2 and out.safe
    assert "capture.csv and its sidecar: NOT SAVED ([Errno 28] No space left on device); the " \
           "capture is not on disk" in out.message
    assert out.raw_path is not None and out.raw_path.exists()     # the raw download was kept
    assert out.capture_path is None and not (tmp_path / "capture.csv").exists()
    end = read_audit(out.audit_path)[-1]
    assert end["kind"] == "run_end" and end["exit_code"] == 2 and end["not_saved"]
    assert device_kinds(sim) == FULL_SEQUENCE


def test_raw_download_not_saved_leaves_no_half_file(bench, tmp_path, monkeypatch):
    sim, proxy = bench
    import drivers.recorder as recorder

    real = recorder._write_whole
    calls = []

    def write_whole(target, payload):      # the disk fills half-way through the raw download
        calls.append(target)
        tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
        with open(tmp, "xb") as fh:
            fh.write(payload[: len(payload) // 2])
        tmp.unlink()
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(recorder, "_write_whole", write_whole)
    out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                        params=FAST_PARAMS)
    assert real is not write_whole and len(calls) == 1
    assert out.exit_code == 2
    assert "recorder_raw.bin: NOT SAVED ([Errno 28] No space left on device); the recorder " \
           "download, 9000 bytes, is not on disk" in out.message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["audit.jsonl", "run.log"]


def _rlimit(limit_bytes: int):
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))


@functools.cache
def _userns_mounts() -> bool:
    """`unshare -rm` can mount a tmpfs here (a user and mount namespace)."""
    if shutil.which("unshare") is None:
        return False
    probe = subprocess.run(["unshare", "-rm", "sh", "-c", "mount -t tmpfs -o size=4k none /mnt"],
                           capture_output=True)
    return probe.returncode == 0


def in_tmpfs(argv: list[str], mount_dir, options: str) -> list[str]:
    """`argv` run with a tmpfs (`options`) mounted on `mount_dir`, in its own mount namespace."""
    return ["unshare", "-rm", "sh", "-c", 'mount -t tmpfs -o "$1" none "$2" && shift 2 && exec "$@"',
            "sh", options, str(mount_dir), *argv]


@pytest.mark.parametrize("how", ["rlimit_fsize_12k", "tmpfs_12k"])
def test_a_real_full_disk_under_out(tmp_path, how):
    """The issue's case: 12 KB free under --out. The setpoint comes back AND remote is given
    back (no watchdog trip), the run says what it lost, exit 2, no traceback."""
    if how == "tmpfs_12k" and not _userns_mounts():
        pytest.skip("no unprivileged mount namespace here (unshare -rm)")
    out_dir = tmp_path / "full"
    out_dir.mkdir()
    with SimBench() as sim:
        bench = bench_toml(tmp_path / "bench.toml", sim)
        argv = run_argv(bench, out_dir / "run")
        if how == "tmpfs_12k":
            proc = start_run(in_tmpfs(argv, out_dir, "size=12k"))
        else:
            proc = start_run(argv, preexec_fn=lambda: _rlimit(12 * 1024))
        stdout, stderr = proc.communicate(timeout=120)
        text = stdout + stderr
        assert proc.returncode == 2, text
        assert "NOT SAVED" in text and "Traceback" not in text
        assert ("No space left on device" if how == "tmpfs_12k" else "File too large") in text
        assert "SAFE STATE NOT CONFIRMED" not in text
        assert "safe state exciter: setpoint" in text
        assert device_kinds(sim)[-1] == ("local", 1.0)          # remote given back by the host
        assert not sim.exciter.remote and not sim.exciter.watchdog_tripped
        assert sim.exciter.setpoint == pytest.approx(1.0)
    if how == "rlimit_fsize_12k":
        assert (out_dir / "run" / "audit.jsonl").stat().st_size <= 12 * 1024


def _read_only_out(tmp_path, argv_for):
    """(argv, cleanup) running `argv_for(out)` with `out` on something read-only, or skip."""
    if os.geteuid() != 0:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        return argv_for(ro / "run"), lambda: ro.chmod(0o755)
    if _userns_mounts():
        ro = tmp_path / "ro"
        ro.mkdir()
        return in_tmpfs(argv_for(ro / "run"), ro, "ro,size=4k"), lambda: None
    pytest.skip("root without mount namespaces: no read-only folder to be had")


def test_run_onto_a_read_only_folder_is_one_line_and_touches_nothing(tmp_path):
    with SimBench() as sim:
        bench = bench_toml(tmp_path / "bench.toml", sim)
        argv, cleanup = _read_only_out(tmp_path, lambda out: run_argv(bench, out))
        try:
            proc = start_run(argv)
            stdout, stderr = proc.communicate(timeout=120)
        finally:
            cleanup()
        assert proc.returncode == 2, stdout + stderr
        assert "Traceback" not in stdout + stderr
        lines = [ln for ln in stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("refused: --out ")
        assert ("Read-only file system" in lines[0] or "Permission denied" in lines[0])
        assert "nothing was sent to a device" in lines[0]
        assert sim.exciter.events == []


def test_demo_onto_a_read_only_folder_is_one_line(tmp_path):
    import sys

    argv, cleanup = _read_only_out(
        tmp_path, lambda out: [sys.executable, "-m", "bench_ctl.cli", "demo", "--out", str(out)])
    try:
        proc = start_run(argv)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        cleanup()
    assert proc.returncode == 2 and "Traceback" not in stdout + stderr
    # the demo claims its outputs before the pulse (53c6b6b): refused there, nothing sent
    assert stderr.startswith("refused: ") and "read-only file system" in stderr
    assert len(stderr.strip().splitlines()) == 1 and "pulse test" not in stdout


def test_an_out_folder_that_cannot_be_made_is_refused_before_anything(tmp_path, capsys):
    """In-process: --out under a file (ENOTDIR)."""
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputUnusable, match="cannot make the folder"):
        run_procedure("comms_check", ROOT / "benches" / "example.toml", tmp_path / "file" / "run")
    rc = main(["run", "comms_check", "--bench", str(ROOT / "benches" / "example.toml"),
               "--out", str(tmp_path / "file" / "run")])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("refused: --out ") and "Traceback" not in err
