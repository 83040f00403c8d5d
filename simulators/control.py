"""A line-based control port for a running `bench-ctl sim` (run-time fault switching).

One command per line, one reply line (``ok ...`` or ``error ...``)::

    fault no_reply device=exciter count=1      arm a fault (keys as simulators.faults.Fault)
    fault late_reply device=exciter count=inf delay_s=0.1 delay_max_s=0.45    a slow exciter
    fault load device=exciter op=write register=setpoint mw=0 delay_s=0.5    loss of load in a step
    fault limiter device=exciter op=write register=setpoint bit=ceiling_limit delay_s=0.5
    fault no_reply device=exciter op=read register=q after=setpoint:2        a lost read in recovery
    clear [KIND]                               disarm all faults (or those of one kind; a limiter's
                                               forced status bit ends with it)
    list                                       the armed faults
    load 12.5                                  set the exciter's active power (MW; on line the
                                               turbine's power, which P follows)
    state                                      plant step, vt, efd, p, q, setpoint, recorder status

e.g. ``printf 'fault late_reply device=recorder delay_s=0.4\\n' | socat - TCP:127.0.0.1:5029``.
Binds to loopback by default; it is a test aid, not an operator interface.
"""
from __future__ import annotations

import asyncio
import logging
from typing import Any, Protocol

from .faults import FaultSet, parse_fault

log = logging.getLogger(__name__)


class Controllable(Protocol):
    """What the control port needs of a running simulated bench (simulators.bench.SimBench has it):
    its armed faults, the exciter (`set_load_mw`, `remote`), the plant (`state()`: step, vt, efd,
    usetp) and the recorder (`status`)."""

    faults: FaultSet
    exciter: Any
    plant: Any
    recorder: Any


def execute(bench: Controllable, line: str) -> str:
    """Run one control command; returns the reply line."""
    words = line.split()
    if not words:
        return "error empty command"
    cmd, args = words[0], words[1:]
    try:
        if cmd == "fault" and args:
            fault = parse_fault(args[0] + (":" + ",".join(args[1:]) if args[1:] else ""))
            bench.faults.add(fault)
            return f"ok {fault}"
        if cmd == "clear":
            kind = args[0] if args else None
            if kind in (None, "limiter"):
                bench.exciter.clear_forced_bits()
            return f"ok cleared {bench.faults.clear(kind=kind)}"
        if cmd == "list":
            return "ok " + "; ".join(str(f) for f in bench.faults.active())
        if cmd == "load" and len(args) == 1:
            bench.exciter.set_load_mw(float(args[0]))
            return f"ok load {float(args[0])} MW"
        if cmd == "state":
            st = bench.plant.state()
            power = (f"p={st.p * bench.plant.mva:.3f} q={st.q * bench.plant.mva:.3f} "
                     if bench.plant.on_line else f"p={bench.exciter.load_mw:.3f} ")
            return (f"ok step={st.step} vt={st.vt:.6f} efd={st.efd:.6f} {power}usetp={st.usetp:.6f} "
                    f"remote={bench.exciter.remote} recorder={bench.recorder.status}")
    except ValueError as exc:
        return f"error {exc}"
    return f"error unknown command {line.strip()!r} (fault, clear, list, load, state)"


async def start_control(bench: Controllable, address: tuple[str, int]) -> asyncio.AbstractServer:
    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while line := await reader.readline():
                reply = execute(bench, line.decode("utf-8", "replace"))
                log.info("control: %s -> %s", line.strip(), reply)
                writer.write(reply.encode() + b"\n")
                await writer.drain()
        except ConnectionError:
            pass
        finally:
            writer.close()

    return await asyncio.start_server(handle, *address)
