"""The Modbus TCP wire proxy the runner and procedure tests use (tests/wire_proxy.py)."""
from __future__ import annotations

import socket
import threading
import time

import pytest

from wire_proxy import WireProxy


@pytest.fixture
def echo_server():
    """A server that answers each chunk with the same bytes."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(4)
    stop = threading.Event()

    def serve() -> None:
        srv.settimeout(0.05)
        while not stop.is_set():
            try:
                conn, _ = srv.accept()
            except OSError:
                continue
            def echo(c: socket.socket = conn) -> None:
                while (d := c.recv(4096)):
                    c.sendall(d)
            threading.Thread(target=echo, daemon=True).start()

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    yield srv.getsockname()
    stop.set()
    t.join()
    srv.close()


def test_proxy_logs_requests_and_cuts(echo_server):
    proxy = WireProxy(echo_server)
    try:
        frame = bytes.fromhex("0001 0000 000b 01 10 0000 0002 04 3f86 6666")
        c = socket.create_connection(proxy.address)
        c.sendall(frame)
        assert c.recv(100) == frame
        assert proxy.writes() == [(0, [0x3F86, 0x6666])]
        proxy.cut(0.3)
        t0 = time.monotonic()
        assert c.recv(100) == b""          # the cut closed the connection
        with pytest.raises(ConnectionRefusedError):
            socket.create_connection(proxy.address)
        while True:                         # accepted again after the hold
            try:
                socket.create_connection(proxy.address).close()
                break
            except ConnectionRefusedError:
                assert time.monotonic() - t0 < 3
                time.sleep(0.01)
        assert time.monotonic() - t0 >= 0.29
    finally:
        proxy.close()
