"""Dry runs: start the embedded simulated bench and point the bench config at it.

The drivers are unchanged; only the addresses in the config change (docs/style.md: a simulated
device is a different address, never an `if simulated:` branch). The simulators serve the
profiles the bench config names, so a vendor-profile bench dry-runs against a simulator
speaking that vendor's register map. The recorder is reached on its pseudo-terminal, the same
serial path a real recorder uses.

The simulated bench (`simulators.bench.SimBench`) runs in a child process, as a real device
is a separate box: in the same interpreter its threads and garbage collections stalled the
host's timed restore write, which is the simulator's cost, not the procedure's
(docs/decisions/0005).
"""
from __future__ import annotations

import contextlib
import dataclasses
import gc
import json
import logging
import os
import pickle
import select
import subprocess
import sys
import time
import traceback
from collections.abc import Iterator
from typing import Any

from bench_ctl.runner.config import BenchConfig

log = logging.getLogger(__name__)

START_TIMEOUT_S = 600.0   # the plant is compiled before the child starts: a start takes seconds


def _child() -> None:
    """`python -m bench_ctl.runner.dryrun`: read pickled SimBench options on stdin, start the
    bench, print its endpoints as one JSON line, run until stdin closes. The bench stopped (its
    servers, serial line and plant), what exists is kept out of the interpreter's last garbage
    collections (`gc.freeze`): with numba's compiled code loaded they took ~0.5 s, which every dry
    run's end waited for; the exit is otherwise the usual one (exit handlers, flushed streams)."""
    try:
        options = pickle.load(sys.stdin.buffer)
        from simulators.bench import SimBench  # the runner wires simulators in; drivers never

        with SimBench(**options) as sim:
            print(json.dumps({"ok": True, **dataclasses.asdict(sim.endpoints)}), flush=True)
            sys.stdin.buffer.read()             # until the parent closes the pipe
    except BaseException:  # noqa: BLE001 - report any start failure to the parent
        print(json.dumps({"ok": False, "error": traceback.format_exc()}), flush=True)
    else:
        gc.freeze()


def _read_line(proc: subprocess.Popen, timeout_s: float) -> str:
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout_s
    buf = b""
    while not buf.endswith(b"\n"):
        left = deadline - time.monotonic()
        if left <= 0:
            raise RuntimeError(f"the simulated bench did not start within {timeout_s:g} s")
        ready, _, _ = select.select([proc.stdout], [], [], left)
        if ready:
            chunk = os.read(proc.stdout.fileno(), 4096)
            if not chunk:
                raise RuntimeError(f"the simulated bench exited (code {proc.wait()}) "
                                   "before it started")
            buf += chunk
    return buf.decode()


@contextlib.contextmanager
def simulated_bench(config: BenchConfig, *, recorder_link: str = "serial",
                    **sim_options: Any) -> Iterator[tuple[BenchConfig, dict[str, Any]]]:
    """Yield (config pointed at a fresh simulated bench, its endpoints as a dict).

    `recorder_link` "serial" uses the pty, "url" the RTU-over-TCP socket (rtu+tcp://); `sim_options` go to
    `SimBench` (e.g. `unit=`, `load_mw=`; they must be picklable).
    """
    options = {"exciter_profile": config.exciter.profile,
               "recorder_profile": config.recorder.profile, **sim_options}
    from simulators.bench import warm_plant  # the runner wires simulators in; drivers never

    warm_plant(**options)   # a first run compiles here, where the console says so, not in the child
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    proc = subprocess.Popen([sys.executable, "-m", "bench_ctl.runner.dryrun"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env,
                            # its own session, as a real device does not share the operator's
                            # terminal: a Ctrl-C, Ctrl-\ or hang-up reaches the run only, which
                            # then restores against a living simulator (docs/decisions/0014)
                            start_new_session=True)
    assert proc.stdin is not None
    try:
        proc.stdin.write(pickle.dumps(options))
        proc.stdin.flush()
        reply = json.loads(_read_line(proc, START_TIMEOUT_S))
        if not reply.pop("ok"):
            raise RuntimeError(f"the simulated bench failed to start:\n{reply['error']}")
        ep = reply
        recorder = (ep["recorder_serial"] if recorder_link == "serial"
                    else f"rtu+tcp://{ep['recorder_host']}:{ep['recorder_port']}")
        if recorder is None:
            raise RuntimeError("the simulated bench has no serial line (serial=False)")
        pointed = config.with_endpoints(
            exciter_url=f"tcp://{ep['exciter_host']}:{ep['exciter_port']}",
            recorder_url=recorder, exciter_unit_id=ep["exciter_unit_id"],
            recorder_unit_id=ep["recorder_unit_id"])
        log.info("dry run: simulated exciter at %s, recorder at %s (process %d)",
                 pointed.exciter.url, pointed.recorder.url, proc.pid)
        yield pointed, ep
    finally:
        with contextlib.suppress(OSError):
            proc.stdin.close()                  # the child stops its bench and exits
        try:
            proc.wait(10.0)
        except subprocess.TimeoutExpired:
            proc.terminate()
            proc.wait(5.0)
        if proc.stdout is not None:
            proc.stdout.close()


if __name__ == "__main__":
    _child()
