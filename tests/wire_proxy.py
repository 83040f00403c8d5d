"""A Modbus TCP wire proxy for the runner, procedure and fault tests (its own tests:
tests/runner/test_runner_wire.py).

`WireProxy` sits between the driver and a simulated device: it records every request frame
the device is sent (independently of the driver's own frame log, so a test can assert what
really reached the device and in which order) and can cut the link - close every connection
and refuse new ones for a while - at a moment the test chooses.
"""
from __future__ import annotations

import select
import socket
import struct
import threading
import time


class WireProxy:
    """TCP proxy to `target` on an ephemeral loopback port (see the module docstring)."""

    def __init__(self, target: tuple[str, int]) -> None:
        self.target = target
        self.requests: list[tuple[float, bytes]] = []   # (monotonic time, Modbus TCP ADU)
        self.connections = 0
        self.cuts = 0
        self._lock = threading.Lock()
        self._socks: list[socket.socket] = []
        self._refuse_until = 0.0
        self._stop = threading.Event()
        self._listener = self._listen(0)
        self.address = self._listener.getsockname()
        self._thread = threading.Thread(target=self._accept_loop, daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"tcp://{self.address[0]}:{self.address[1]}"

    def _listen(self, port: int) -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))
        s.listen(8)
        return s

    # -- control -----------------------------------------------------------------------------
    def cut(self, hold_s: float) -> None:
        """Drop every connection now and refuse new ones for `hold_s` seconds."""
        with self._lock:
            self.cuts += 1
            self._refuse_until = time.monotonic() + hold_s
            if self._listener is not None:
                try:  # stop listening now, even while the accept thread selects on it
                    self._listener.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                self._listener.close()
                self._listener = None
            for s in self._socks:
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                s.close()
            self._socks.clear()

    def close(self) -> None:
        self._stop.set()
        self.cut(0.0)
        self._thread.join(timeout=5)

    # -- what reached the device ---------------------------------------------------------------
    def writes(self) -> list[tuple[int, list[int]]]:
        """(address, words) of every write-multiple-registers request, in order."""
        out = []
        for _, adu in list(self.requests):
            if adu[7] == 0x10:
                address, qty, nbytes = struct.unpack(">HHB", adu[8:13])
                out.append((address, list(struct.unpack(f">{qty}H", adu[13:13 + nbytes]))))
        return out

    # -- plumbing ----------------------------------------------------------------------------
    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                listener = self._listener
                if listener is None and time.monotonic() >= self._refuse_until \
                        and not self._stop.is_set():
                    self._listener = listener = self._listen(self.address[1])
            if listener is None:
                time.sleep(0.005)
                continue
            try:
                ready, _, _ = select.select([listener], [], [], 0.02)
                if not ready:
                    continue
                client, _ = listener.accept()
            except (OSError, ValueError):
                continue
            try:
                upstream = socket.create_connection(self.target, timeout=2)
            except OSError:
                client.close()
                continue
            with self._lock:
                self._socks += [client, upstream]
                self.connections += 1
            threading.Thread(target=self._pump, args=(client, upstream, True), daemon=True).start()
            threading.Thread(target=self._pump, args=(upstream, client, False),
                             daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket, requests: bool) -> None:
        buf = b""
        while True:
            try:
                data = src.recv(4096)
            except OSError:
                data = b""
            if not data:
                break
            if requests:
                buf += data
                while len(buf) >= 6 and len(buf) >= 6 + int.from_bytes(buf[4:6], "big"):
                    n = 6 + int.from_bytes(buf[4:6], "big")
                    self.requests.append((time.monotonic(), buf[:n]))
                    buf = buf[n:]
            try:
                dst.sendall(data)
            except OSError:
                break
        for s in (src, dst):
            try:
                s.close()
            except OSError:
                pass
