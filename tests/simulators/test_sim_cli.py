"""`bench-ctl sim` as a process, driven by an outside client (mbpoll, Debian package): reads vt and
efd and writes the setpoint on TCP, reads the recorder's registers on the pseudo-terminal;
--effect, --fault and a clean SIGTERM shutdown."""
from __future__ import annotations

import os
import re
import select
import shutil
import signal
import subprocess
import sys
import time

import pytest

MBPOLL = shutil.which("mbpoll")
pytestmark = pytest.mark.skipif(MBPOLL is None, reason="mbpoll not installed (apt-get install mbpoll)")


def mbpoll(*args: str, timeout_s: str = "1") -> subprocess.CompletedProcess:
    return subprocess.run([MBPOLL, "-0", "-B", "-a", "1", "-1", "-o", timeout_s, *args],
                          capture_output=True, text=True, timeout=20)


def values(out: str) -> dict[int, str]:
    return {int(a): v.strip() for a, v in re.findall(r"^\[(\d+)\]:\s+(\S+)", out, re.M)}


def read_until_ready(proc: subprocess.Popen, timeout: float = 90.0) -> str:
    text = ""
    deadline = time.monotonic() + timeout
    fd = proc.stdout.fileno()
    while "ready" not in text:
        left = deadline - time.monotonic()
        assert left > 0 and proc.poll() is None, f"sim did not start: {text}"
        if select.select([fd], [], [], left)[0]:
            chunk = os.read(fd, 4096).decode()
            assert chunk, f"sim exited: {text}"
            text += chunk
    return text


@pytest.fixture()
def sim_process(tmp_path):
    cmd = [sys.executable, "-m", "bench_ctl.cli", "sim", "--tcp", "127.0.0.1:0",
           "--recorder-tcp", "127.0.0.1:0", "--heartbeat-timeout", "30",
           "--serial", str(tmp_path / "recorder-tty"),
           "--effect", "ceiling_limit:VRMAX=1.5,VRMIN=0.0",
           "--fault", "no_reply:device=exciter,count=1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        yield proc, read_until_ready(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_sim_command_with_mbpoll(sim_process):
    proc, banner = sim_process
    port = re.search(r"exciter\s+Modbus TCP\s+127\.0\.0\.1:(\d+)", banner).group(1)
    pty = re.search(r"recorder Modbus RTU\s+(/dev/pts/\d+) \(link (\S+)\)", banner).group(2)
    assert os.path.realpath(pty).startswith("/dev/pts/")            # --serial made the link
    assert "ceiling_limit" in banner and "fault armed: Fault(kind='no_reply'" in banner
    tcp = ["-m", "tcp", "-p", port]

    # the armed --fault swallows the first request, then the device answers
    first = mbpoll(*tcp, "-t", "3:float", "-r", "2", "-c", "2", "127.0.0.1", timeout_s="0.3")
    assert first.returncode != 0
    r = mbpoll(*tcp, "-t", "3:float", "-r", "2", "-c", "2", "127.0.0.1")        # vt, efd
    assert r.returncode == 0, r.stderr
    assert values(r.stdout) == {2: "1", 4: "1"}

    r = mbpoll(*tcp, "-t", "4:float", "-r", "0", "127.0.0.1", "1.05")            # local: refused
    assert r.returncode != 0
    assert mbpoll(*tcp, "-t", "4", "-r", "3", "127.0.0.1", "3").returncode == 0   # remote
    assert mbpoll(*tcp, "-t", "4:float", "-r", "0", "127.0.0.1", "1.05").returncode == 0
    status = mbpoll(*tcp, "-t", "3", "-r", "10", "127.0.0.1")
    efd = mbpoll(*tcp, "-t", "3:float", "-r", "4", "127.0.0.1")
    assert int(values(status.stdout)[10]) & 1                  # ceiling limit active
    assert float(values(efd.stdout)[4]) == pytest.approx(1.5)  # --effect ceiling_limit VRMAX=1.5
    r = mbpoll(*tcp, "-t", "4:float", "-r", "0", "-c", "1", "127.0.0.1")
    assert values(r.stdout) == {0: "1.05"}
    r = mbpoll(*tcp, "-t", "4:float", "-r", "0", "127.0.0.1", "1.5")             # out of range
    assert r.returncode != 0

    # the recorder on the pseudo-terminal: identity and configuration registers
    rtu = ["-m", "rtu", "-b", "19200", "-P", "none"]
    r = mbpoll(*rtu, "-t", "3:hex", "-r", "30", "-c", "2", pty)
    assert r.returncode == 0, r.stderr
    assert values(r.stdout) == {30: "0x5243", 31: "0x0100"}
    r = mbpoll(*rtu, "-t", "4", "-r", "0", "-c", "2", pty)
    assert values(r.stdout) == {0: "1000", 1: "1000"}

    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "stopping" in out.decode() and "stopped after" in out.decode()
    assert not os.path.lexists(pty)                                 # link removed on shutdown


def test_sim_command_refuses_bad_options():
    from bench_ctl.cli import main
    assert main(["sim", "--tcp", "127.0.0.1:0", "--fault", "explode"]) == 2
    assert main(["sim", "--tcp", "127.0.0.1:0", "--exciter-profile", "no-such"]) == 2
    assert main(["sim", "--tcp", "127.0.0.1:0", "--set", "KAVR=abc"]) == 2
