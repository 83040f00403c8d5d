"""The drivers and the runner's bench satisfy the protocols procedures are typed against
(`bench_ctl.runner.protocols`): every member exists, and every method takes the protocol's
parameters by the same names and kinds. Built without I/O (no device needed)."""
from __future__ import annotations

import inspect
import tomllib
from pathlib import Path

import pytest

from bench_ctl.runner import protocols as P
from bench_ctl.runner.bench import Bench
from bench_ctl.runner.config import config_from_dict
from drivers.exciter import Exciter
from drivers.recorder import Recorder

ROOT = Path(__file__).resolve().parents[2]


def members(proto: type) -> dict[str, object]:
    out = {}
    for klass in reversed(proto.__mro__):
        if klass in (object,) or not getattr(klass, "_is_protocol", False) or klass.__name__ == "Protocol":
            continue
        out.update({k: v for k, v in vars(klass).items() if not k.startswith("_")})
        out.update({k: None for k in getattr(klass, "__annotations__", {})})
    return out


@pytest.mark.parametrize("proto, klass", [(P.ExcitationSystem, Exciter), (P.Recorder, Recorder)])
def test_each_driver_takes_every_protocol_method_as_declared(proto, klass):
    for name, member in members(proto).items():
        assert hasattr(klass, name) or name == "name", f"{klass.__name__} has no {name}"
        if not inspect.isfunction(member):
            continue
        want = inspect.signature(member).parameters
        have = inspect.signature(getattr(klass, name)).parameters
        for pname, p in want.items():
            assert pname in have, f"{klass.__name__}.{name} takes no {pname}"
            assert have[pname].kind == p.kind, f"{klass.__name__}.{name}({pname}): {have[pname].kind} != {p.kind}"


def test_the_runners_bench_is_a_procedure_bench():
    doc = tomllib.loads((ROOT / "benches" / "example.toml").read_text())
    bench = Bench(config_from_dict(doc, source="example.toml"))   # no I/O before connect()
    assert isinstance(bench, P.ProcedureBench)
    assert isinstance(bench.exciter, P.ExcitationSystem) and isinstance(bench.recorder, P.Recorder)
    assert all(isinstance(d, P.Device) for d in bench.devices)
    ex = bench.exciter
    assert (ex.endpoint_url, ex.unit_id, ex.request_timeout_s) == ("tcp://192.0.2.10:502", 1, 0.5)
    assert ex.has("efd") and ex.has("q") and not ex.has("pss_output")
    assert ex.register_names()[:4] == ("setpoint", "heartbeat", "mode", "mech_power")
    assert ex.decode("setpoint", [0x3F86, 0x6666]) == pytest.approx(1.05)
    assert ex.heartbeat_stats() == P.HeartbeatStats(0, 0, 0.0)
