"""Simulated bench figures: request latency on both devices, plant timing over a run, and the
delay from a setpoint write to its appearance in the recorded usetp channel.

    python benchmarks/sim_latency.py [--seconds 60] [--requests 500] [--trials 20] [--probe-seconds 20]
                                     [--online] [--json OUT]

Latency is measured with minimal raw-frame clients (what the simulator itself costs) and with
pymodbus 3.16 sync clients (what a driver sees; its serial client polls the port every 1 ms and
waits for a quiet line, and over a socket:// URL pyserial reports only 0/1 bytes waiting, which
makes it much slower; `recorder_rtu_tcp` is the same socket through the TCP client with the RTU
framer, the drivers' rtu+tcp:// endpoint). The timing run keeps a procedure-like load on the bench: a 20 Hz poll of
the exciter with heartbeats, and a 10 s recording downloaded over the pseudo-terminal (its
download time is reported too). Before the bench starts, `machine_timer_*` is the host's own
wake-up lateness for a bare 1 kHz sleeper with the plant's clock calls and priority
(`bench_ctl.plants.realtime.timer_jitter`): on a virtual machine that floor, not the plant, is what
sets the plant's late steps. `--online`: the same on the bench on line (the unit on the grid, stepped
by a Python-timed loop, docs/decisions/0018). Exits 0 when it ran; it reports, it does not judge.
"""
from __future__ import annotations

import argparse
import json
import math
import random
import socket
import struct
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import serial

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pymodbus.client import ModbusSerialClient, ModbusTcpClient  # noqa: E402
from pymodbus.framer import FramerRTU, FramerType  # noqa: E402

from bench_ctl.plants.realtime import timer_jitter  # noqa: E402
from simulators.bench import SimBench  # noqa: E402


def crc16(data: bytes) -> bytes:
    """Modbus RTU CRC, bytes in wire order (pymodbus returns it as a big-endian int)."""
    return FramerRTU.compute_CRC(data).to_bytes(2, "big")


def stats_ms(xs: list[float]) -> tuple[float, float]:
    a = np.asarray(xs) * 1e3
    return float(np.median(a)), float(np.percentile(a, 99))


# ------------------------------------------------------------------ latency
def raw_tcp_latency(ep, n: int) -> list[float]:
    out = []
    with socket.create_connection(ep.exciter_tcp, timeout=2.0) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for i in range(n):
            req = struct.pack(">HHHBBHH", i & 0xFFFF, 0, 6, 1, 4, 2, 4)    # vt, efd
            t = time.perf_counter()
            s.sendall(req)
            got = b""
            while len(got) < 17:
                got += s.recv(64)
            out.append(time.perf_counter() - t)
    return out


def raw_rtu_latency(send, recv, n: int) -> list[float]:
    req = bytes.fromhex("010400000012")          # 18 input registers (status .. samples_stored)
    req += crc16(req)
    out = []
    for _ in range(n):
        t = time.perf_counter()
        send(req)
        got = recv(5 + 36)
        out.append(time.perf_counter() - t)
        assert len(got) == 41 and crc16(got[:-2]) == got[-2:], got
    return out


def pymodbus_latency(call, n: int) -> list[float]:
    out = []
    for _ in range(n):
        t = time.perf_counter()
        r = call()
        out.append(time.perf_counter() - t)
        assert not r.isError(), r
    return out


def latency(bench: SimBench, n: int) -> dict[str, float]:
    ep = bench.endpoints
    res: dict[str, list[float]] = {}
    res["exciter_tcp_raw"] = raw_tcp_latency(ep, n)
    c = ModbusTcpClient(ep.exciter_host, port=ep.exciter_port, timeout=1.0, retries=0)
    c.connect()
    res["exciter_tcp_pymodbus"] = pymodbus_latency(
        lambda: c.read_input_registers(2, count=4, device_id=1), n)
    c.close()
    with serial.Serial(ep.recorder_serial, 115200, timeout=1.0) as p:
        res["recorder_pty_raw"] = raw_rtu_latency(p.write, p.read, n)
    with socket.create_connection((ep.recorder_host, ep.recorder_port), timeout=2.0) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

        def recv(k: int) -> bytes:
            got = b""
            while len(got) < k:
                got += s.recv(k - len(got))
            return got
        res["recorder_url_raw"] = raw_rtu_latency(s.sendall, recv, n)
    for name, port, count in (("recorder_pty_pymodbus", ep.recorder_serial, n),
                              ("recorder_url_pymodbus", ep.recorder_url, max(20, n // 10))):
        r = ModbusSerialClient(port, timeout=1.0, retries=0, baudrate=115200)
        r.connect()
        res[name] = pymodbus_latency(lambda r=r: r.read_input_registers(0, count=18, device_id=1), count)
        r.close()
    # the same socket as drivers reach it (rtu+tcp://): the TCP client with the RTU framer
    r = ModbusTcpClient(ep.recorder_host, port=ep.recorder_port, framer=FramerType.RTU, timeout=1.0, retries=0)
    r.connect()
    res["recorder_rtu_tcp_pymodbus"] = pymodbus_latency(
        lambda: r.read_input_registers(0, count=18, device_id=1), n)
    r.close()
    out: dict[str, float] = {}
    for name, xs in res.items():
        med, p99 = stats_ms(xs)
        out[f"{name}_median_ms"] = med
        out[f"{name}_p99_ms"] = p99
        out[f"{name}_n"] = len(xs)
    return out


# ------------------------------------------------------------------ recorder helpers
def u32(w) -> int:
    return (w[0] << 16) | w[1]


def wait_status(r, want: int, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while r.read_input_registers(0, count=1, device_id=1).registers[0] != want:
        if time.monotonic() > deadline:
            raise TimeoutError(f"recorder never reached status {want}")
        time.sleep(0.005)


def download(r) -> tuple[np.ndarray, dict]:
    head = r.read_input_registers(0, count=20, device_id=1).registers
    n, nch, nblk, crc = u32(head[1:3]), head[3], head[4], u32(head[5:7])
    words: list[int] = []
    for b in range(nblk):
        if r.write_register(9, b, device_id=1).isError():
            raise RuntimeError(f"block {b} refused")
        win = r.read_input_registers(100, count=121, device_id=1)
        if win.isError() or win.registers[0] != b:
            raise RuntimeError(f"block {b}: {win}")
        words.extend(win.registers[1:])
    words = words[: nch * n]
    if zlib.crc32(struct.pack(f">{len(words)}H", *words)) != crc:
        raise RuntimeError("record CRC mismatch")
    frames = np.array(words, dtype=np.uint16).view(np.int16).reshape(n, nch)
    return frames, {"trigger_sample": u32(head[7:9]), "rate": head[15],
                    "trigger_time_s": u32(head[18:20]) * 1e-3}


def configure(r, pre_ms: int, length_ms: int, mode: int) -> None:
    for reg, val in ((0, 1000), (1, pre_ms), (4, mode)):
        assert not r.write_register(reg, val, device_id=1).isError()
    assert not r.write_registers(2, [length_ms >> 16, length_ms & 0xFFFF], device_id=1).isError()
    assert not r.write_registers(5, list(struct.unpack(">HH", struct.pack(">f", 0.005))),
                                 device_id=1).isError()


def f32w(x: float) -> list[int]:
    return list(struct.unpack(">HH", struct.pack(">f", x)))


# ------------------------------------------------------------------ setpoint -> record
def setpoint_delay(bench: SimBench, trials: int, seed: int = 0) -> dict[str, float]:
    ep = bench.endpoints
    rnd = random.Random(seed)
    e = ModbusTcpClient(ep.exciter_host, port=ep.exciter_port, timeout=1.0, retries=0)
    e.connect()
    r = ModbusSerialClient(ep.recorder_serial, timeout=1.0, retries=0, baudrate=115200)
    r.connect()
    configure(r, pre_ms=20, length_ms=60, mode=1)
    assert not e.write_register(3, 3, device_id=1).isError()
    delays, acks = [], []
    value = 1.0
    hb = 0
    for _ in range(trials):
        assert not r.write_register(7, 1, device_id=1).isError()
        wait_status(r, 2, 2.0)
        time.sleep(rnd.uniform(0.0, 0.002))            # random phase against the 1 ms steps
        value = 1.02 if value == 1.0 else 1.0
        t_send = time.monotonic()
        assert not e.write_registers(0, f32w(value), device_id=1).isError()
        t_ack = time.monotonic()
        hb += 1
        e.write_register(2, hb, device_id=1)
        wait_status(r, 4, 2.0)
        frames, meta = download(r)
        u = frames[:, 0]
        changed = np.flatnonzero(u != u[0])
        i = int(changed[0])
        t_sample = bench.plant.t0 + meta["trigger_time_s"] + (i - meta["trigger_sample"]) / meta["rate"]
        delays.append(t_sample - t_send)
        acks.append(t_sample - t_ack)
    e.write_registers(0, f32w(1.0), device_id=1)
    e.write_register(3, 1, device_id=1)
    e.close()
    r.close()
    d = np.asarray(delays) * 1e3
    a = np.asarray(acks) * 1e3
    return {"setpoint_to_record_median_ms": float(np.median(d)),
            "setpoint_to_record_p99_ms": float(np.percentile(d, 99)),
            "setpoint_to_record_min_ms": float(d.min()), "setpoint_to_record_max_ms": float(d.max()),
            "setpoint_ack_to_record_median_ms": float(np.median(a)),
            "setpoint_ack_to_record_max_ms": float(a.max()), "setpoint_trials": trials}


# ------------------------------------------------------------------ plant timing under load
def plant_timing(bench: SimBench, seconds: float) -> dict[str, float]:
    ep = bench.endpoints
    e = ModbusTcpClient(ep.exciter_host, port=ep.exciter_port, timeout=1.0, retries=0)
    e.connect()
    r = ModbusSerialClient(ep.recorder_serial, timeout=1.0, retries=0, baudrate=115200)
    r.connect()
    record_s = min(10.0, max(1.0, seconds / 2))
    configure(r, pre_ms=0, length_ms=int(record_s * 1000), mode=0)
    e.write_register(3, 3, device_id=1)
    bench.plant.reset_timing()
    t_start = time.monotonic()
    step_start = bench.plant.step
    r.write_register(7, 1, device_id=1)
    wait_status(r, 2, 2.0)
    r.write_register(8, 1, device_id=1)
    hb = 0
    download_s = math.nan
    downloaded = False
    polls = 0
    while time.monotonic() - t_start < seconds:
        hb += 1
        e.write_register(2, hb & 0xFFFF, device_id=1)
        e.read_input_registers(0, count=11, device_id=1)
        polls += 1
        if not downloaded and r.read_input_registers(0, count=1, device_id=1).registers[0] == 4:
            t = time.monotonic()
            frames, _ = download(r)
            download_s = time.monotonic() - t
            downloaded = True
            assert frames.shape[0] == int(record_s * 1000)
        time.sleep(0.05)
    t_end = time.monotonic()
    step_end = bench.plant.step
    timing = bench.plant.timing()
    e.write_register(3, 1, device_id=1)
    e.close()
    r.close()
    elapsed = t_end - t_start
    return {"plant_seconds": elapsed, "plant_steps": step_end - step_start,
            "plant_wall_minus_plant_end_ms": ((t_end - bench.plant.t0) - step_end * bench.plant.dt) * 1e3,
            "plant_steps_minus_expected": (step_end - step_start) - elapsed / bench.plant.dt,
            "plant_lag_mean_ms": timing.lag_mean_s * 1e3, "plant_lag_p99_ms": timing.lag_p99_s * 1e3,
            "plant_lag_max_ms": timing.lag_max_s * 1e3,
            "plant_behind_p99_ms": timing.behind_p99_s * 1e3,
            "plant_behind_max_ms": timing.behind_max_s * 1e3,
            "plant_stalls_over_1ms": timing.stalls_over_1ms, "plant_late_bursts": timing.late_bursts,
            "plant_max_burst_steps": timing.max_burst, "plant_drift_ms": timing.drift_s * 1e3,
            "plant_rt_priority": bench.plant.rt_active, "exciter_polls": polls,
            "record_seconds": record_s, "record_download_s": download_s}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0, help="plant timing run (s)")
    ap.add_argument("--requests", type=int, default=500, help="requests per latency series")
    ap.add_argument("--trials", type=int, default=20, help="setpoint-to-record trials")
    ap.add_argument("--probe-seconds", type=float, default=20.0,
                    help="machine timer-jitter baseline before the bench starts (s; 0: skip)")
    ap.add_argument("--online", action="store_true",
                    help="the bench on line (the unit on the grid, its Python-timed plant loop; the recorder "
                         "records six channels)")
    ap.add_argument("--json", type=Path, default=None, help="write the figures as flat JSON")
    args = ap.parse_args(argv)
    baseline: dict[str, float] = {}
    if args.probe_seconds > 0:  # what this host allows a 1 kHz sleeper at best: read the plant figures against it
        probe = timer_jitter(args.probe_seconds)
        baseline = {f"machine_timer_{k}": v for k, v in probe.items()}
        baseline["machine_timer_seconds"] = args.probe_seconds
    t0 = time.monotonic()
    on_line = {"online": True, "recorder_profile": "sim-recorder-online"} if args.online else {}
    with SimBench(heartbeat_timeout_s=5.0, **on_line) as bench:
        start_s = time.monotonic() - t0
        figures: dict[str, float] = {**baseline, "online": args.online, "bench_start_s": start_s}
        figures.update(latency(bench, args.requests))
        figures.update(setpoint_delay(bench, args.trials))
        figures.update(plant_timing(bench, args.seconds))
    print(f"{'figure':44s} value")
    for k, v in figures.items():
        print(f"{k:44s} {v:.4g}" if isinstance(v, float) else f"{k:44s} {v}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2))
        print(f"written {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
