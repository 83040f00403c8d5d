"""`bench-ctl sim` on bad profiles, and a quiet stop while clients are connected (issue 24 item 20).

- `--exciter-profile /dev/zero` is not "no such file": it is not a regular file, refused unread
  (reading it would never end), and a profile too large to be one is refused too;
- stopping the simulated bench while clients keep sending requests leaves no asyncio "Task was
  destroyed but it is pending" and no "coroutine ... was never awaited" behind (before: 13 of 15
  stops logged them).
"""
from __future__ import annotations

import gc
import logging
import threading
import warnings

import pytest
from pymodbus.client import ModbusTcpClient

from bench_ctl.cli import main
from drivers.profile import load_profile
from simulators.bench import SimBench


def test_a_profile_that_is_not_a_regular_file_is_refused_unread(tmp_path, capsys):
    assert main(["sim", "--tcp", "127.0.0.1:0", "--exciter-profile", "/dev/zero"]) == 2
    err = capsys.readouterr().err
    assert "/dev/zero: not a regular file" in err and "a profile is read from a file" in err \
        and "no such file" not in err
    assert main(["sim", "--tcp", "127.0.0.1:0", "--recorder-profile", str(tmp_path)]) == 2
    assert "not a regular file" in capsys.readouterr().err
    big = tmp_path / "big.toml"
    big.write_text("# " + "x" * (1 << 20))
    with pytest.raises(ValueError, match="more than the 1048576 bytes a profile may have"):
        load_profile(big)
    with pytest.raises(FileNotFoundError, match="no such file"):
        load_profile(tmp_path / "missing.toml")


def test_stopping_while_clients_send_leaves_no_asyncio_noise(caplog):
    caplog.set_level(logging.ERROR, logger="asyncio")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(5):
            bench = SimBench(serial=False)
            bench.start()
            port = bench.endpoints.exciter_port
            stop = threading.Event()
            started = threading.Barrier(5)

            def hammer(port: int = port, started: threading.Barrier = started,
                       stop: threading.Event = stop) -> None:
                c = ModbusTcpClient("127.0.0.1", port=port, timeout=0.2, retries=0)
                c.connect()
                started.wait()
                while not stop.is_set():
                    try:
                        c.read_input_registers(0, count=2, device_id=1)
                    except Exception:  # noqa: BLE001 - the server goes away under it
                        pass
                c.close()

            threads = [threading.Thread(target=hammer) for _ in range(4)]
            for t in threads:
                t.start()
            started.wait()
            seen = bench.plant.step
            while bench.plant.step < seen + 50:        # let them send for a while
                stop.wait(0.01)
            bench.stop()
            stop.set()
            for t in threads:
                t.join()
            gc.collect()                                # destroyed tasks are reported here
    noise = [r.getMessage() for r in caplog.records if r.name == "asyncio"]
    noise += [str(w.message) for w in caught if "never awaited" in str(w.message)]
    assert noise == []


def test_a_failed_start_shuts_down_cleanly(monkeypatch):
    """A port in use: start() raises OSError, and the bench's thread ends its shutdown instead of
    dying in it ('Event loop stopped before Future completed', seen 1 start in 3)."""
    import socket

    errors = []
    monkeypatch.setattr(threading, "excepthook", lambda args: errors.append(args.exc_value))
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    try:
        for _ in range(10):
            bench = SimBench(serial=False, tcp=busy.getsockname())
            with pytest.raises(OSError, match="cannot listen on"):
                bench.start()
    finally:
        busy.close()
    assert errors == []
