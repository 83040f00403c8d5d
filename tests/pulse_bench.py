"""The pulse test on the real-protocol simulators with a WireProxy in front of the exciter: the
bench config, the register words and the writes that reached the device, shared by the runner,
procedure and fault tests."""
from __future__ import annotations

import tomllib
from pathlib import Path

from bench_ctl.runner.config import config_from_dict
from simulators.bench import SimBench
from wire_proxy import WireProxy

ROOT = Path(__file__).resolve().parents[1]
SP_1_05 = [0x3F86, 0x6666]     # float32 1.05, high word first (sim profile setpoint)
SP_1_00 = [0x3F80, 0x0000]
SETPOINT_ADDR, MODE_ADDR, HEARTBEAT_ADDR = 0, 3, 2
# a short pulse test: the real 1 s width, short record
SHORT = {"pre_trigger_s": 0.3, "record_s": 2.0, "width_s": 1.0, "recovery_timeout_s": 5.0,
         "width_tolerance_s": 0.02}


def config_doc(**limits) -> dict:
    doc = tomllib.loads((ROOT / "benches" / "example.toml").read_text())
    doc["exciter"].update(timeout_s=0.3, heartbeat_period_s=0.1)
    doc["recorder"].update(timeout_s=0.2)
    doc["limits"].update({"restore_deadline_s": 3.0, **limits})
    return doc


def bench_config(proxy: WireProxy, sim: SimBench, *, exciter: dict | None = None, **limits):
    doc = config_doc(**limits)
    doc["exciter"].update(exciter or {})
    doc["exciter"]["url"] = proxy.url
    doc["recorder"]["url"] = sim.endpoints.recorder_serial   # the pty: the serial path
    return config_from_dict(doc, source="test-bench.toml")


def device_writes(proxy: WireProxy) -> list[tuple[int, list[int]]]:
    """Writes that reached the exciter, heartbeat left out."""
    return [w for w in proxy.writes() if w[0] != HEARTBEAT_ADDR]
