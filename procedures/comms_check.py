"""Communication check: read every register of both devices once; write nothing.

PURPOSE
    Before any test, prove that the host reaches the exciter and the recorder with the bench
    config's addresses, unit ids and profiles: every register of each profile is read once
    and decoded with the profile's type, word order and scale.

PRECONDITIONS
    None on the unit; safe at any operating point. No confirmation is asked because nothing is
    written (the runner refuses any write that has not been confirmed).

HAZARDS
    None: reads only.

PASS CRITERIA
    Every register of both profiles answered (no exception reply, no timeout). The values are
    in the audit file (`readings`) and printed.
"""
from __future__ import annotations

import logging

from bench_ctl.runner.context import Criterion, ProcedureResult, RunContext
from bench_ctl.runner.devices import CommError, DeviceError
from bench_ctl.runner.protocols import ProcedureBench

log = logging.getLogger(__name__)

#: reads only: the runner takes no bench lock for it (it may run beside a pulse test) and
#: refuses any write it would attempt
WRITES = False


def comms_check(bench: ProcedureBench, run: RunContext) -> ProcedureResult:
    """Read every register of both profiles once; see the module docstring."""
    criteria = []
    values: dict[str, dict[str, float | str]] = {}
    for dev in bench.devices:
        with run.step(f"read {dev.name}"):
            got: dict[str, float | str] = {}
            failed = []
            for name in dev.register_names():
                try:
                    got[name] = dev.read(name)
                except CommError:
                    raise  # the link is down: a comms error, not a register problem
                except DeviceError as exc:
                    got[name] = f"error: {exc.message}"
                    failed.append(name)
            values[dev.name] = got
            run.note("readings", device=dev.name, values=got)
        criteria.append(Criterion(f"{dev.name}: every register answered", not failed,
                                  failed or len(got), len(dev.register_names())))
    lines = [f"{dev}.{name} = {value}" for dev, regs in values.items()
             for name, value in regs.items()]
    return ProcedureResult(criteria=tuple(criteria),
                           summary=f"read {len(lines)} registers", data={"values": values})
