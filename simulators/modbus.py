"""Modbus glue: a device model + profile served by pymodbus 3.16, with reply faults on the wire.

pymodbus 3.16 serves dynamic registers through `SimDevice(action=...)`: the action sees every
request on a device before pymodbus answers it; here it asks the fault set, then fills the
registers from (or hands the written words to) the device's `RegisterImage`. Reply faults
(no / late reply, dropped connection, corrupted bytes) need the connection, so the servers use
a request-handler subclass whose `server_send` reads the fault the action chose for this
request (a context variable: each request is handled in its own asyncio task).
"""
from __future__ import annotations

import asyncio
import contextvars
import logging

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType
from pymodbus.pdu.device import ModbusDeviceIdentification
from pymodbus.server import ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import DataType, SimData, SimDevice

from .faults import Fault, FaultSet
from .regmap import CLIENT, DeviceModel, RegisterImage

log = logging.getLogger(__name__)

_READ_FC = {3: "holding", 4: "input"}
_WRITE_FC = {6: "holding", 16: "holding", 23: "holding"}
_REPLY_FAULT: contextvars.ContextVar[Fault | None] = contextvars.ContextVar("reply_fault",
                                                                            default=None)
#: the delay drawn for this request's late_reply fault
_REPLY_DELAY: contextvars.ContextVar[float] = contextvars.ContextVar("reply_delay", default=0.0)


def build_simdevice(device: DeviceModel, unit_id: int, faults: FaultSet) -> SimDevice:
    """A pymodbus SimDevice whose registers come from `device` through its profile."""
    image = RegisterImage(device)
    ends = {t: max(1, image.table_end(t)) for t in ("holding", "input")}

    async def action(function_code: int, start_address: int, address: int, count: int,
                     registers: list[int], set_values) -> ExcCodes | None:
        second_half = False
        if set_values is not None and function_code in _WRITE_FC:
            op, table = "write", _WRITE_FC[function_code]
        elif function_code == 6:
            return None     # the reply of FC06 echoes the words written (pymodbus stored them)
        elif function_code == 23:
            op, table, second_half = "read", "holding", True   # read half of FC23
        elif function_code in _READ_FC:
            op, table = "read", _READ_FC[function_code]
        else:
            return ExcCodes.ILLEGAL_FUNCTION
        names = image.names(table, address, count)
        fault = None if second_half else faults.take(device.kind, op, names)
        if not second_half:
            for event in faults.take_events(device.kind, op, names):
                _schedule(device, event)
        if fault is not None:
            if fault.kind == "exception":
                return ExcCodes(fault.code)
            if fault.kind == "slow":   # the device serves the request that late
                delay = faults.delay_for(fault)
                log.info("fault: request served %.3f s late", delay)
                await asyncio.sleep(delay)
            else:
                _REPLY_FAULT.set(fault)
                _REPLY_DELAY.set(faults.delay_for(fault) if fault.kind == "late_reply" else 0.0)
        if op == "write":
            return image.write(table, address, [int(v) for v in set_values])
        words = image.read(table, address, count)
        if isinstance(words, ExcCodes):
            return words
        off = address - start_address
        registers[off:off + count] = words
        return None

    return SimDevice(id=unit_id, simdata=_blocks(ends["holding"], ends["input"]), action=action)


def _schedule(device: DeviceModel, event: Fault) -> None:
    """Set off a plant event (`load`, `limiter`) `delay_s` after this request."""
    apply = getattr(device, "plant_event", None)
    if apply is None:
        log.warning("fault %s: the %s has no plant", event.kind, device.kind)
        return
    asyncio.get_running_loop().call_later(event.delay_s, apply, event)


def _blocks(holding: int, inputs: int) -> tuple:
    bits = [SimData(0, values=[False] * 16, datatype=DataType.BITS)]
    return (bits, list(bits), [SimData(0, count=holding, datatype=DataType.REGISTERS)],
            [SimData(0, count=inputs, datatype=DataType.REGISTERS)])


_SILENT = Fault("no_reply", count=None)


def other_unit_ids() -> SimDevice:
    """Catch-all for unit ids the bench does not serve: no reply, as on a real RTU line."""

    async def action(function_code: int, start_address: int, address: int, count: int,
                     registers: list[int], set_values) -> ExcCodes | None:
        _REPLY_FAULT.set(_SILENT)
        return ExcCodes.ILLEGAL_FUNCTION

    return SimDevice(id=0, simdata=_blocks(0xFFFF, 0xFFFF), action=action)


def identity_of(device: DeviceModel) -> ModbusDeviceIdentification:
    ident = device.profile.identity
    return ModbusDeviceIdentification(info_name={
        "VendorName": str(ident.get("vendor", "")),
        "ProductCode": str(ident.get("model", "")),
        "ModelName": str(ident.get("model", "")),
        "MajorMinorRevision": str(ident.get("firmware", "")),
        "ProductName": device.profile.description or device.profile.name,
    })


def corrupt_frame(packet: bytes, mode: str) -> bytes:
    """Damage a reply frame the way a noisy line would (deterministic, so tests can check it)."""
    if not packet:
        return packet
    if mode == "truncate":
        return packet[: max(1, len(packet) // 2)]
    if mode == "garbage":
        return b"\xff\x00\xa5" + packet
    i = min(len(packet) - 1, max(2, len(packet) // 2))
    return packet[:i] + bytes([packet[i] ^ 0xFF]) + packet[i + 1:]


class _FaultHandler(ServerRequestHandler):
    """Request handler (one per client connection) that applies the reply fault chosen for the
    current request and tells the device model which master a request came from (`CLIENT`: the
    peer's address, as a device that tracks its master by IP address sees it)."""

    async def handle_request(self):  # noqa: D102 - each request runs in its own task
        peer = self.transport.get_extra_info("peername") if self.transport is not None else None
        CLIENT.set(peer[0] if peer else None)
        await super().handle_request()

    def server_send(self, pdu, addr):  # noqa: ANN001 (pymodbus signature)
        fault = _REPLY_FAULT.get()
        if fault is None or not pdu:
            return super().server_send(pdu, addr)
        _REPLY_FAULT.set(None)
        if fault.kind == "no_reply":
            log.info("fault: reply suppressed")
            return None
        if fault.kind == "drop_connection":
            log.info("fault: connection dropped instead of replying")
            if self.transport is not None:
                self.transport.close()
            return None
        if fault.kind == "late_reply":
            delay = _REPLY_DELAY.get()
            log.info("fault: reply delayed by %.3f s", delay)
            self.loop.call_later(delay, self._send_late, pdu, addr)
            return None
        if fault.kind == "corrupt":
            packet = self.framer.buildFrame(pdu)
            bad = corrupt_frame(packet, fault.mode)
            log.info("fault: reply corrupted (%s) %s -> %s", fault.mode, packet.hex(), bad.hex())
            self.low_level_send(bad, addr=addr)
            return None
        return super().server_send(pdu, addr)

    def _send_late(self, pdu, addr) -> None:  # noqa: ANN001
        if self.transport is not None and not self.transport.is_closing():
            super().server_send(pdu, addr)


class FaultTcpServer(ModbusTcpServer):
    """ModbusTcpServer (socket or RTU framing) whose connections apply reply faults."""

    def callback_new_connection(self):
        return _FaultHandler(self, self.trace_packet, self.trace_pdu, self.trace_connect)

    def bound_address(self) -> tuple[str, int]:
        """The (host, port) actually listened on (port 0 resolved)."""
        sock = self.transport.sockets[0]  # type: ignore[union-attr]
        host, port = sock.getsockname()[:2]
        return host, port


async def start_server(device: DeviceModel, unit_id: int, faults: FaultSet,
                       address: tuple[str, int], rtu: bool) -> FaultTcpServer:
    """Create and start listening (returns once the socket listens)."""
    devices = [build_simdevice(device, unit_id, faults)]
    if unit_id != 0:
        devices.append(other_unit_ids())
    server = FaultTcpServer(devices,
                            framer=FramerType.RTU if rtu else FramerType.SOCKET,
                            identity=identity_of(device), address=address)
    try:
        await server.serve_forever(background=True)
    except RuntimeError as exc:  # pymodbus 3.16: "Could not start listen, please check address."
        raise OSError(f"cannot listen on {address[0]}:{address[1]} for the simulated {device.kind} "
                      f"(port in use, or not an address of this host): {exc}") from None
    host, port = server.bound_address()
    log.info("%s listening on %s:%d (%s)", device.kind, host, port, "RTU" if rtu else "TCP")
    return server
