"""A pseudo-terminal serial line for the recorder: pty master <-> the RTU-over-TCP server.

`os.openpty()` gives a master fd (ours) and a slave device (`/dev/pts/N`) that a serial client
opens like a real port (baud and parity are ignored by a pty). The slave is put in raw mode so
the line discipline passes RTU bytes unchanged; we keep a slave fd open so the master never
sees EIO/hang-up while no client has the port open. Bytes from the master are relayed to the
recorder's RTU-over-TCP server and the replies back, so one server (and one fault set) serves
both the URL and the serial line. An optional symlink (`link`) gives the port a stable name,
like socat's `link=`.
"""
from __future__ import annotations

import asyncio
import errno
import logging
import os
import tty
from pathlib import Path

log = logging.getLogger(__name__)


class PtyBridge:
    """Relay between a pty master and a TCP endpoint (host, port); runs on an asyncio loop."""

    def __init__(self, target: tuple[str, int], link: str | Path | None = None) -> None:
        self.target = target
        self.link = Path(link) if link else None
        self.slave_path = ""
        self._master = -1
        self._slave = -1
        self._writer: asyncio.StreamWriter | None = None
        self._task: asyncio.Task | None = None
        self._out = bytearray()
        self._closing = False
        self._connected = asyncio.Event()

    async def start(self) -> str:
        """Open the pty pair, connect to the target; returns the slave path."""
        loop = asyncio.get_running_loop()
        if self.link is not None and (self.link.exists() or self.link.is_symlink()):
            if not self.link.is_symlink():
                raise FileExistsError(f"serial link {self.link} exists and is not a symlink")
            self.link.unlink()
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        tty.setraw(self._master)
        os.set_blocking(self._master, False)
        self.slave_path = os.ttyname(self._slave)
        if self.link is not None:
            self.link.symlink_to(self.slave_path)
        loop.add_reader(self._master, self._on_pty)
        self._task = asyncio.create_task(self._pump(), name="pty bridge")
        await asyncio.wait_for(self._connected.wait(), timeout=5.0)
        log.info("recorder serial line on %s%s", self.slave_path,
                 f" (link {self.link})" if self.link else "")
        return self.slave_path

    async def _pump(self) -> None:
        """Keep a connection to the target; relay its bytes to the pty; reconnect when dropped."""
        while not self._closing:
            try:
                reader, self._writer = await asyncio.open_connection(*self.target)
            except OSError as exc:
                log.warning("pty bridge: cannot reach %s:%d (%s); retrying", *self.target, exc)
                await asyncio.sleep(0.1)
                continue
            self._connected.set()
            try:
                while True:
                    data = await reader.read(4096)
                    if not data:
                        break
                    self._to_pty(data)
            except (ConnectionError, OSError) as exc:
                log.info("pty bridge: link to server lost (%s)", exc)
            finally:
                self._writer.close()
                self._writer = None
            if not self._closing:
                log.info("pty bridge: server closed the link; reconnecting")

    def _on_pty(self) -> None:
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:    # no slave open (cannot happen while we hold one)
                return
            raise
        if data and self._writer is not None:
            self._writer.write(data)
        elif data:
            log.info("pty bridge: %d byte(s) dropped while reconnecting", len(data))

    def _to_pty(self, data: bytes) -> None:
        self._out += data
        self._flush()

    def _flush(self) -> None:
        loop = asyncio.get_running_loop()
        while self._out:
            try:
                n = os.write(self._master, self._out)
            except BlockingIOError:
                loop.add_writer(self._master, self._flush)
                return
            del self._out[:n]
        loop.remove_writer(self._master)

    async def stop(self) -> None:
        self._closing = True
        loop = asyncio.get_running_loop()
        if self._master >= 0:
            loop.remove_reader(self._master)
            loop.remove_writer(self._master)
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except (asyncio.CancelledError, Exception):
                pass
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1
        if self.link is not None and self.link.is_symlink():
            self.link.unlink()
