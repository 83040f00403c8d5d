"""Every fault the simulated bench can inject, x N runs of the no-load pulse test (issue 24) and of
the on-line step (issue 48).

Each run is `bench-ctl run no_load_pulse --yes` (or `online_step`) in its own process, as an
operator starts it, against a fresh simulated bench in this process (the exciter's events and
state are read from the simulator itself, not from the run's own records). Faults (issue 24):

- link cut (the connection dropped instead of the reply) and exception reply (code 4) at each
  write of the test: take remote, pulse on, pulse off, give back remote, arm the recorder;
- late (0.5 s, past the 0.3 s request timeout) and lost replies to the pulse writes, late and
  lost replies and corrupt frames on recorder blocks (twice: retried; for good: the download
  fails), the link cut for 3 s during the pulse (longer than the device watchdog);
- the device's watchdog longer than the limit (20 s) and shorter than the heartbeat period,
  a second master holding remote, a second run started together with the first;
- SIGINT / SIGTERM / SIGHUP / SIGQUIT / SIGKILL at pre-test (the recorder arming), mid-pulse
  and recovery;
- disk full under --out: 12 KB free (the issue's case: the audit fills it while the recorder
  is armed, so the pulse, its restore and the release run on a full disk) and 56 KB free (the
  raw download is the first file that does not fit); a tmpfs of that size in its own mount
  namespace where `unshare -rm` works (ENOSPC), else RLIMIT_FSIZE of that size (EFBIG, per
  file); and a read-only --out (a read-only tmpfs, or a chmod 555 folder when not root).

Faults of issue 48 (group `issue48`): a slow exciter (replies 0.1-0.45 s late, or requests served
that late; and replies 0.02-0.1 s late, which the link's check accepts), a slow recorder (replies
0.1-0.45 s late), a loss of load, reverse power and a limiter acting 0.5 s into an on-line step,
three reads lost after the pulse or the step (and every q read lost after the step), and every
terminal signal during the on-line step (a 3 s hold under a 3.5 s cap, limits.step_hold_max_s).

Faults of issue 49 (group `issue49`): the stabiliser test `pss_step` (the step with the PSS off,
then on; a 4.5 s hold under a 5 s cap) on the simulated bench with the unit's stabiliser: every
terminal signal and a 3 s link cut during the PSS-off step, the reply to the PSS-off write lost,
the device refusing it (exception 4) or refusing the write that puts the PSS back, a loss of load
during the PSS-off step, a slow exciter. Beside the columns above: the PSS found as it was before
the run (% of runs; the device's own switch, read from the simulator) and the worst time the
switch stayed off after the fault hit (`pss_*` keys).

Per fault: setpoint restored (% of runs whose device setpoint is back at the pre-test value),
worst time to the pre-test setpoint after the fault hit (the signal sent, the cut, the faulty
reply; from the pulse on for faults without a moment: a full disk, a second run; 0 when the
setpoint never moved) and worst pulse length on the device, remote released
(% of runs after which this host does not hold remote), capture saved or its loss reported (%;
a silent loss is an exit 0 without a readable capture), within the cap or refused (% of runs whose
pulse or step the device held no longer than its cap, or that wrote nothing to the exciter),
records lost (the recorder triggered on the run's pulse or step and then no longer held the record,
or a run that was alive and had a writable folder saved no raw download of it; a SIGKILLed run's
record stays in the recorder), tracebacks, and the exit codes. Targets: 100 % restored; after a
signal, the pre-test setpoint within 50 ms (SIGKILL: the pulse within the width cap + the device
watchdog); 0 silent losses; issue 48: 100 % within the cap or refused, 100 % released, 0 records
lost, 0 tracebacks.

Usage: python benchmarks/fault_matrix.py [--runs 5] [--only NAME[,NAME]] [--group issue24|issue48] [--json OUT]
Prints a table; `--json` writes a flat object. Exits 0 when it ran (it reports, it does not judge).
"""
from __future__ import annotations

import argparse
import functools
import json
import logging
import os
import platform
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from bench_ctl.capture import read_capture  # noqa: E402
from cli_runs import audit_rows, bench_doc, run_argv, start_run, write_toml  # noqa: E402
from simulators.bench import SimBench  # noqa: E402
from simulators.faults import parse_fault  # noqa: E402
from wire_proxy import WireProxy  # noqa: E402

PARAMS = {"pre_trigger_s": 0.3, "record_s": 2.0, "width_s": 0.5, "recovery_timeout_s": 3.0,
          "width_tolerance_s": 0.02}
#: the on-line step: 3 s held (under a 3.5 s cap, below), 6 s recorded, 0.5 s steady before it
STEP_PARAMS = {"hold_s": 3.0, "pre_trigger_s": 0.5, "record_s": 6.0, "recovery_timeout_s": 5.0,
               "steady_timeout_s": 5.0}
STEP_CAP_S = 3.5
#: the stabiliser test: a 3 % step held 4.5 s (its mode is fitted over 4 s), 7 s recorded, under a 5 s cap
PSS_PARAMS = {"amplitude_pu": 0.03, "hold_s": 4.5, "pre_trigger_s": 0.5, "record_s": 7.0,
              "recovery_timeout_s": 5.0, "steady_timeout_s": 5.0}
PSS_CAP_S = 5.0
ONLINE_SIM = {"online": True, "recorder_profile": "sim-recorder-online"}
#: the example bench's host side: a 0.5 s request timeout, a beat every 0.25 s (cli_runs' 0.3 s and
#: 0.1 s would time out the slow devices' replies before any check)
SLOW_HOST = {"timeout_s": 0.5, "heartbeat_period_s": 0.25}
WIDTH_CAP_S = 1.5          # benches/example.toml limits.pulse_width_max_s
WATCHDOG_S = 2.0           # the simulated exciter's default watchdog
PRE_TEST_PU = 1.0
SIGNAL_TARGET_S = 0.050


@dataclass(frozen=True)
class Case:
    name: str
    faults: tuple[str, ...] = ()              # simulators.faults.parse_fault texts, armed at start
    sim: dict[str, Any] = field(default_factory=dict)
    exciter: dict[str, Any] = field(default_factory=dict)
    moment: str | None = None                 # pre-test | mid-pulse | recovery
    action: str | None = None                 # SIGINT.. | cut
    disk: str | None = None                   # full-12k | full-56k | read-only
    setup: str | None = None                  # second-master | second-run
    procedure: str = "no_load_pulse"          # or online_step / pss_step (the bench on line)
    recorder: dict[str, Any] = field(default_factory=dict)
    group: str = "issue24"

    @property
    def online(self) -> bool:
        return self.procedure in ("online_step", "pss_step")

    @property
    def pss(self) -> bool:
        return self.procedure == "pss_step"

    @property
    def cap_s(self) -> float:
        return PSS_CAP_S if self.pss else STEP_CAP_S if self.online else WIDTH_CAP_S

    @property
    def params(self) -> dict[str, Any]:
        return PSS_PARAMS if self.pss else STEP_PARAMS if self.online else PARAMS


def cases() -> list[Case]:
    out: list[Case] = []
    writes = {"take_remote": "device=exciter,op=write,register=mode,skip=0",
              "pulse_on": "device=exciter,op=write,register=setpoint,skip=0",
              "pulse_off": "device=exciter,op=write,register=setpoint,skip=1",
              "give_back": "device=exciter,op=write,register=mode,skip=1",
              "arm_recorder": "device=recorder,op=write,register=arm,skip=0"}
    for where, match in writes.items():
        out.append(Case(f"cut_at_{where}", (f"drop_connection:{match}",)))
    for where, match in writes.items():
        out.append(Case(f"exception_at_{where}", (f"exception:{match},code=4",)))
    for where in ("pulse_on", "pulse_off"):
        out.append(Case(f"late_reply_{where}", (f"late_reply:{writes[where]},delay_s=0.5",)))
        out.append(Case(f"lost_reply_{where}", (f"no_reply:{writes[where]}",)))
    block = "device=recorder,register=block,skip=5"
    out += [Case("late_reply_blocks", (f"late_reply:{block},count=2,delay_s=0.3",)),
            Case("lost_reply_blocks", (f"no_reply:{block},count=2",)),
            Case("corrupt_blocks_twice", (f"corrupt:{block},count=2",)),
            Case("corrupt_blocks_always", (f"corrupt:{block},count=inf",)),
            Case("link_cut_3s_mid_pulse", moment="mid-pulse", action="cut"),
            Case("watchdog_longer_20s", sim={"heartbeat_timeout_s": 20.0}),
            Case("watchdog_shorter_than_beat", sim={"heartbeat_timeout_s": 0.05}),
            Case("second_master", setup="second-master"),
            Case("second_run_together", setup="second-run")]
    for sig in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT", "SIGKILL"):
        for moment in ("pre-test", "mid-pulse", "recovery"):
            out.append(Case(f"{sig}_{moment.replace('-', '_')}", moment=moment, action=sig))
    out += [Case("disk_full_12k_free", disk="full-12k"), Case("disk_full_56k_free", disk="full-56k"),
            Case("read_only_out", disk="read-only")]
    return out + issue48_cases() + issue49_cases()


def issue48_cases() -> list[Case]:
    """A slow exciter or recorder, the unit's faults during the on-line step, reads lost after the
    test, the terminal's signals during the step (issue 48)."""
    step = {"procedure": "online_step", "sim": ONLINE_SIM, "group": "issue48"}
    at_step = "device=exciter,op=write,register=setpoint,count=1,delay_s=0.5"
    slow = "device=exciter,count=inf,delay_s=0.1,delay_max_s=0.45"
    after = "device=exciter,op=read,after=setpoint:2"
    out = [Case("slow_exciter_pulse", (f"late_reply:{slow}",), exciter=SLOW_HOST, group="issue48"),
           Case("slow_device_pulse", (f"slow:{slow}",), exciter=SLOW_HOST, group="issue48"),
           Case("slow_exciter_mild_pulse", ("late_reply:device=exciter,count=inf,delay_s=0.02,delay_max_s=0.1",),
                exciter=SLOW_HOST, group="issue48"),
           Case("slow_exciter_step", (f"late_reply:{slow}",), exciter=SLOW_HOST, **step),
           Case("slow_recorder_pulse", ("late_reply:device=recorder,count=inf,delay_s=0.1,delay_max_s=0.45",),
                recorder={"timeout_s": 0.5}, group="issue48"),
           Case("loss_of_load_step", (f"load:{at_step},mw=0",), **step),
           Case("reverse_power_step", (f"load:{at_step},mw=-15",), **step),
           Case("limiter_step", (f"limiter:{at_step},bit=ceiling_limit",), **step),
           Case("lost_reads_recovery_pulse", (f"no_reply:{after},count=3",), group="issue48"),
           Case("lost_reads_recovery_step", (f"no_reply:{after},count=3",), **step),
           Case("lost_q_reads_for_good_step", (f"no_reply:{after},register=q,count=inf",), **step)]
    for sig in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT", "SIGKILL"):
        out.append(Case(f"{sig}_mid_step", moment="mid-pulse", action=sig, **step))
    return out


def issue49_cases() -> list[Case]:
    """The stabiliser test with the unit's PSS: signals, a link cut, the switch's writes lost or
    refused, a loss of load, a slow exciter (issue 49)."""
    from procedures.pss_step import SIMULATED_BENCH

    pss = {"procedure": "pss_step", "sim": {**ONLINE_SIM, "unit_set": SIMULATED_BENCH["unit_set"]},
           "group": "issue49"}
    switch = "device=exciter,op=write,register=pss_on"
    out = [Case("pss_off_write_lost", (f"no_reply:{switch},skip=0",), **pss),
           Case("pss_off_write_refused", (f"exception:{switch},skip=0,code=4",), **pss),
           Case("pss_restore_write_refused", (f"exception:{switch},skip=1,code=4",), **pss),
           Case("pss_loss_of_load", ("load:device=exciter,op=write,register=setpoint,count=1,delay_s=0.3,mw=0",),
                **pss),
           Case("pss_slow_exciter", ("late_reply:device=exciter,count=inf,delay_s=0.02,delay_max_s=0.1",),
                exciter=SLOW_HOST, **pss),
           Case("pss_link_cut_3s_mid_step", moment="mid-pulse", action="cut", **pss)]
    for sig in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT", "SIGKILL"):
        out.append(Case(f"pss_{sig}_mid_step", moment="mid-pulse", action=sig, **pss))
    return out


@functools.cache
def userns_mounts() -> bool:
    if shutil.which("unshare") is None:
        return False
    probe = subprocess.run(["unshare", "-rm", "sh", "-c", "mount -t tmpfs -o size=4k none /mnt"],
                           capture_output=True)
    return probe.returncode == 0


def in_tmpfs(argv: list[str], mount_dir: Path, options: str) -> list[str]:
    return ["unshare", "-rm", "sh", "-c", 'mount -t tmpfs -o "$1" none "$2" && shift 2 && exec "$@"',
            "sh", options, str(mount_dir), *argv]


def _rlimit(limit: int) -> Callable[[], None]:
    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


def disk_argv(case: Case, argv_for: Callable[[Path], list[str]], work: Path) -> tuple[list[str], dict, bool]:
    """(argv, Popen extras, files visible from here) for a disk case."""
    mount = work / "mnt"
    mount.mkdir()
    size = {"full-12k": 12 * 1024, "full-56k": 56 * 1024}.get(case.disk or "", 0)
    if case.disk == "read-only":
        if userns_mounts():
            return in_tmpfs(argv_for(mount / "run"), mount, "ro,size=4k"), {}, False
        if os.geteuid() != 0:
            mount.chmod(0o555)
            return argv_for(mount / "run"), {}, True
        raise RuntimeError("no read-only folder to be had (root without mount namespaces)")
    if userns_mounts():
        return in_tmpfs(argv_for(mount / "run"), mount, f"size={size // 1024}k"), {}, False
    return argv_for(mount / "run"), {"preexec_fn": _rlimit(size)}, True


def online_bench_toml(path: Path, sim: SimBench, case: Case, url: str | None = None) -> Path:
    """bench_ctl/data/demo_bench_online.toml pointed at `sim` (the recorder on its pseudo-terminal;
    the exciter at `url` when given: a proxy), the hold capped at the case's cap, the steady state
    over 0.5 s."""
    import tomllib

    doc = tomllib.loads((ROOT / "bench_ctl" / "data" / "demo_bench_online.toml").read_text())
    ep = sim.endpoints
    doc["exciter"].update({"url": url or f"tcp://{ep.exciter_host}:{ep.exciter_port}", **case.exciter})
    doc["recorder"].update({"url": ep.recorder_serial, **case.recorder})
    doc["limits"].update(step_hold_max_s=case.cap_s, steady_time_s=0.5, restore_deadline_s=3.0)
    return write_toml(path, doc)


def poll_until(cond: Callable[[], bool], proc: subprocess.Popen, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        if proc.poll() is not None:
            return False
        time.sleep(0.0005)
    return False


def moment_reached(sim: SimBench, moment: str) -> Callable[[], bool]:
    ev = sim.exciter.events
    if moment == "pre-test":
        return lambda: sim.recorder.status in ("recording", "armed") and not ev
    if moment == "mid-pulse":
        return lambda: any(k == "setpoint" and v > PRE_TEST_PU + 1e-3 for _, k, v in ev)
    return lambda: (sum(k == "setpoint" for _, k, _ in ev) >= 2 and sim.recorder.status == "triggered")


class SecondMaster:
    """Another controller (another host address, 127.0.0.2) holding remote and keeping its
    heartbeat going until closed (sim profile: mode at holding 3, heartbeat at holding 2)."""

    def __init__(self, sim: SimBench) -> None:
        import threading

        from pymodbus.client import ModbusTcpClient

        self.client = ModbusTcpClient("127.0.0.1", port=sim.endpoints.exciter_port, timeout=1,
                                      retries=0, source_address=("127.0.0.2", 0))
        self.client.connect()
        self.client.write_register(3, 3, device_id=1)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, daemon=True)
        self._thread.start()

    def _beat(self) -> None:
        n = 0
        while not self._stop.wait(0.1):
            n = (n + 1) & 0xFFFF
            self.client.write_register(2, n, device_id=1)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.client.close()


def device_outcome(sim: SimBench, t_fault: float | None) -> dict[str, Any]:
    """From the simulator's event log: did the setpoint come back, how long after the fault,
    how long was the pulse on the device."""
    ev = list(sim.exciter.events)
    t_on = next((t for t, k, v in ev if k == "setpoint" and abs(v - PRE_TEST_PU) > 1e-6), None)
    back = None
    if t_on is not None:
        back = next((t for t, k, v in ev if t > t_on and k in ("setpoint", "watchdog")
                     and abs(v - PRE_TEST_PU) < 1e-6), None)
    restored = abs(sim.exciter.setpoint - PRE_TEST_PU) < 1e-6
    if t_on is None:
        return {"restored": restored, "moved": False, "restore_s": 0.0, "held_s": 0.0}
    if back is None:
        return {"restored": restored, "moved": True, "restore_s": float("inf"), "held_s": float("inf")}
    start = max(t_on, t_fault) if t_fault is not None else t_on
    return {"restored": restored, "moved": True, "restore_s": max(0.0, back - start),
            "held_s": back - t_on}


def pss_outcome(sim: SimBench, before: bool, t_fault: float | None) -> dict[str, Any]:
    """The PSS switch as found (the device's own, at the end) and how long it stayed off after
    the fault hit (from the switch's first move when no fault moment: a write lost or refused)."""
    # the watchdog puts the switch back as it was when remote was taken (the event holds the setpoint)
    ev = [(t, float(before) if k == "watchdog" else v) for t, k, v in sim.exciter.events
          if k in ("pss_on", "watchdog")]
    off = next((t for t, v in ev if v == 0.0), None)
    start = t_fault if t_fault is not None else off
    back = next((t for t, v in ev if start is not None and t >= start and v == 1.0), None) if off else None
    if off is None:
        off_s = 0.0
    elif back is None:
        off_s = float("inf")
    else:
        off_s = max(0.0, back - max(off, start))
    return {"pss_as_found": sim.exciter.pss_on == before, "pss_off_after_fault_s": off_s}


def settle(sim: SimBench, timeout_s: float) -> None:
    """Wait for the device to reach a state that will not change by itself (remote released
    by the watchdog after a killed run)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and sim.exciter.remote and sim.exciter._owner == "127.0.0.1":
        time.sleep(0.01)


def capture_state(out: Path, stdout: str, visible: bool) -> str:
    """saved | reported | silent"""
    if visible:
        try:   # capture.csv; the stabiliser test's capture_pss_off.csv (and capture_pss_on.csv)
            for path in sorted(out.glob("capture*.csv"))[:1] or [out / "capture.csv"]:
                read_capture(path)
            return "saved"
        except Exception:  # noqa: BLE001 - missing or unreadable: not saved
            pass
    elif "  capture: " in stdout:
        return "saved"
    return "silent"


def one_run(case: Case, work: Path) -> list[dict[str, Any]]:
    """One run of `case` (two for second-run); one result per run process."""
    sim = SimBench(**case.sim)
    sim.start()
    proxy = other = None
    try:
        for text in case.faults:
            sim.faults.add(parse_fault(text))
        if case.action == "cut":
            proxy = WireProxy(sim.endpoints.exciter_tcp)
        if case.setup == "second-master":
            other = SecondMaster(sim)
        if case.online:
            bench = online_bench_toml(work / "bench.toml", sim, case, proxy.url if proxy else None)
        else:
            doc = bench_doc(sim, exciter_url=proxy.url if proxy else None, exciter=case.exciter)
            doc["recorder"].update(case.recorder)
            bench = write_toml(work / "bench.toml", doc)
        params = case.params
        pss_before = sim.exciter.pss_on
        outs = [work / "run"] if case.setup != "second-run" else [work / "run0", work / "run1"]
        visible = True
        extras: dict[str, Any] = {}
        if case.disk:
            argv, extras, visible = disk_argv(case, lambda o: run_argv(bench, o, params=params), work)
            outs = [work / "mnt" / "run"]
            procs = [start_run(argv, **extras)]
        else:
            procs = [start_run(run_argv(bench, o, params=params, procedure=case.procedure)) for o in outs]
        t_fault = None
        if case.moment is not None:
            if poll_until(moment_reached(sim, case.moment), procs[0], 120):
                t_fault = time.monotonic()
                if case.action == "cut":
                    proxy.cut(3.0)
                else:
                    os.kill(procs[0].pid, getattr(signal, case.action))
        results = [(p, *p.communicate(timeout=180)) for p in procs]
        if t_fault is None and sim.faults.history:
            t_fault = sim.faults.history[0].time
        settle(sim, WATCHDOG_S + 1.0)
        dev = device_outcome(sim, t_fault)
        if case.pss:
            dev.update(pss_outcome(sim, pss_before, t_fault))
        released = not (sim.exciter.remote and sim.exciter._owner == "127.0.0.1")
        wrote = sum(n for (device, _), n in sim.faults.writes.items() if device == "exciter") > 0
        within = (not wrote) or dev["held_s"] <= case.cap_s
        triggered = sim.recorder.trigger_step is not None
        rows = []
        for (proc, stdout, stderr), out in zip(results, outs):
            lost = triggered and record_lost(case, out, visible)
            cap = capture_state(out, stdout, visible)
            code = proc.returncode
            if cap != "saved" and code != 0:
                cap = "reported"
            if case.disk and cap == "reported" and code != -9 and \
                    "NOT SAVED" not in stdout + stderr and "refused: --out" not in stderr:
                cap = "silent"
            said = next((ln for ln in (stdout + stderr).splitlines()
                         if ln.startswith((f"{case.procedure}: ", "refused: "))), "")
            lines = (stdout + stderr).splitlines()
            if said.startswith(f"{case.procedure}: ") and said in lines:
                at = lines.index(said)
                said += " | " + (lines[at + 1] if at + 1 < len(lines) else "")
            rows.append({**dev, "released": released, "capture": cap, "exit": code, "said": said,
                         "within_cap": within, "wrote": wrote, "record_lost": lost,
                         "traceback": "Traceback" in stdout + stderr,
                         "fault_hit": t_fault is not None or (not case.faults and case.moment is None)})
        return rows
    finally:
        if other is not None:
            other.close()
        if proxy is not None:
            proxy.close()
        sim.stop()


def record_lost(case: Case, out: Path, visible: bool) -> bool:
    """The record the recorder triggered on is lost to this run: the run armed it, was alive to the
    end (not SIGKILLed), had a folder it could write (not a disk case), and saved no raw download
    of it, without having tried and failed to download it (a download that fails for good is said:
    exit 3; the record is still in the recorder)."""
    if case.disk is not None or case.action == "SIGKILL" or not visible:
        return False
    rows = audit_rows(out / "audit.jsonl")
    armed = any(r.get("kind") == "write" and r.get("register") == "arm" and r.get("value") == 1 for r in rows)
    tried = any((r.get("kind") == "step_end" and r.get("step") == "download" and r.get("result") == "failed")
                or (r.get("kind") == "record_kept" and "failed" in r) for r in rows)
    return armed and not any(out.glob("recorder_raw*.bin")) and not tried   # the stabiliser test: one a step


def summarise(case: Case, rows: list[dict[str, Any]]) -> dict[str, Any]:
    n = len(rows)
    finite = [r["restore_s"] for r in rows]
    return {"runs": n,
            "restored_pct": 100.0 * sum(r["restored"] for r in rows) / n,
            "worst_restore_ms": max(finite) * 1e3,
            "worst_held_ms": max(r["held_s"] for r in rows) * 1e3,
            "remote_released_pct": 100.0 * sum(r["released"] for r in rows) / n,
            "capture_ok_pct": 100.0 * sum(r["capture"] != "silent" for r in rows) / n,
            "silent_losses": sum(r["capture"] == "silent" for r in rows),
            "tracebacks": sum(r["traceback"] for r in rows),
            "within_cap_or_refused_pct": 100.0 * sum(r["within_cap"] for r in rows) / n,
            "refused_before_write": sum(not r["wrote"] for r in rows),
            "records_lost": sum(r["record_lost"] for r in rows),
            "fault_missed": sum(not r["fault_hit"] for r in rows),
            "exit_codes": ",".join(str(c) for c in sorted({r["exit"] for r in rows})),
            **({"pss_as_found_pct": 100.0 * sum(r["pss_as_found"] for r in rows) / n,
                "pss_worst_off_after_fault_ms": max(r["pss_off_after_fault_s"] for r in rows) * 1e3}
               if case.pss else {})}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--only", default=None, help="comma-separated case names")
    ap.add_argument("--group", default=None, choices=("issue24", "issue48", "issue49"),
                    help="only the faults of one issue")
    ap.add_argument("--json", dest="json_out", default=None)
    ap.add_argument("-v", "--verbose", action="store_true",
                    help="print each run's exit code and the run's own outcome line")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    chosen = [c for c in cases() if (args.only is None or c.name in args.only.split(","))
              and (args.group is None or c.group == args.group)]
    result: dict[str, Any] = {"runs_per_fault": args.runs, "faults": len(chosen),
                              "pulse_width_s": PARAMS["width_s"], "width_cap_s": WIDTH_CAP_S,
                              "watchdog_s": WATCHDOG_S,
                              "disk_full_method": "tmpfs_12k_userns" if userns_mounts()
                              else "rlimit_fsize_12k"}
    head = (f"{'fault':30s} {'runs':>4s} {'restored':>8s} {'worst to':>9s} {'worst':>8s} {'cap':>5s} "
            f"{'in cap':>6s} {'remote':>8s} {'capture':>8s} {'silent':>6s} {'record':>6s}  exit")
    print(head + "\n" + f"{'':30s} {'':>4s} {'%':>8s} {'pre-test':>9s} {'pulse':>8s} {'s':>5s} "
          f"{'/ref %':>6s} {'released':>8s} {'ok %':>8s} {'losses':>6s} {'lost':>6s}  codes\n" + "-" * len(head))
    summaries = {}
    with tempfile.TemporaryDirectory(prefix="fault-matrix-") as tmp:
        for case in chosen:
            rows = []
            for i in range(args.runs):
                work = Path(tmp) / f"{case.name}-{i}"
                work.mkdir()
                try:
                    rows += one_run(case, work)
                finally:
                    for p in work.rglob("*"):      # a read-only folder made by chmod
                        if p.is_dir():
                            p.chmod(0o755)
            s = summarise(case, rows)
            summaries[case.name] = (case, s)
            for key, value in s.items():
                result[f"{case.name}_{key}"] = value
            print(f"{case.name:30s} {s['runs']:4d} {s['restored_pct']:8.0f} "
                  f"{s['worst_restore_ms']:8.1f}ms {s['worst_held_ms']:6.0f}ms {case.cap_s:5.1f} "
                  f"{s['within_cap_or_refused_pct']:6.0f} "
                  f"{s['remote_released_pct']:8.0f} {s['capture_ok_pct']:8.0f} "
                  f"{s['silent_losses']:6d} {s['records_lost']:6d}  {s['exit_codes']}"
                  + (f"  ({s['refused_before_write']} wrote nothing to the exciter)"
                     if s["refused_before_write"] else "")
                  + (f"  ({s['tracebacks']} tracebacks)" if s["tracebacks"] else "")
                  + (f"  (fault not reached in {s['fault_missed']})" if s["fault_missed"] else "")
                  + (f"  PSS as found {s['pss_as_found_pct']:.0f} %, off after the fault "
                     f"{s['pss_worst_off_after_fault_ms']:.0f} ms at worst" if case.pss else ""),
                  flush=True)
            if args.verbose:
                for r in rows:
                    print(f"    exit {r['exit']}: {r['said'][:300]}", flush=True)
    all_runs = sum(s["runs"] for _, s in summaries.values())
    new = [s for c, s in summaries.values() if c.group == "issue48"]
    restored = sum(s["restored_pct"] * s["runs"] / 100 for _, s in summaries.values())
    signal_mid = [s["worst_restore_ms"] for c, s in summaries.values()
                  if c.action not in (None, "cut", "SIGKILL") and c.moment == "mid-pulse"]
    kill_held = [s["worst_held_ms"] for c, s in summaries.values() if c.action == "SIGKILL" and not c.pss]
    pss = [s for c, s in summaries.values() if c.pss]
    result.update({
        "run_processes": all_runs,
        "restored_pct_all": 100.0 * restored / all_runs if all_runs else 0.0,
        "remote_released_pct_all": sum(s["remote_released_pct"] * s["runs"] / 100
                                       for _, s in summaries.values()) * 100.0 / max(all_runs, 1),
        "silent_losses_all": sum(s["silent_losses"] for _, s in summaries.values()),
        "tracebacks_all": sum(s["tracebacks"] for _, s in summaries.values()),
        "records_lost_all": sum(s["records_lost"] for _, s in summaries.values()),
        "issue48_within_cap_or_refused_pct": (sum(s["within_cap_or_refused_pct"] * s["runs"] / 100 for s in new)
                                              * 100.0 / max(sum(s["runs"] for s in new), 1)),
        "signal_mid_pulse_worst_restore_ms": max(signal_mid) if signal_mid else 0.0,
        "sigkill_worst_held_ms": max(kill_held) if kill_held else 0.0,
        "sigkill_bound_ms": (WIDTH_CAP_S + WATCHDOG_S) * 1e3,
        "pss_as_found_pct_all": (sum(s["pss_as_found_pct"] * s["runs"] / 100 for s in pss) * 100.0
                                 / max(sum(s["runs"] for s in pss), 1)),
        "pss_worst_off_after_fault_ms": max((s["pss_worst_off_after_fault_ms"] for s in pss), default=0.0),
        "machine": f"{platform.machine()} {os.cpu_count()} cpu, Python {platform.python_version()}",
    })
    print("-" * len(head))
    print(f"setpoint restored in {result['restored_pct_all']:.1f} % of {all_runs} run processes; "
          f"remote released in {result['remote_released_pct_all']:.1f} %; silent capture losses "
          f"{result['silent_losses_all']}; records lost {result['records_lost_all']}; tracebacks "
          f"{result['tracebacks_all']}")
    if new:
        print(f"issue 48 faults: pulses and steps within their caps (as the device held them) or refused "
              f"before any write in {result['issue48_within_cap_or_refused_pct']:.1f} % of "
              f"{sum(s['runs'] for s in new)} runs")
    if signal_mid:
        print(f"after SIGINT/TERM/HUP/QUIT mid-pulse: pre-test setpoint within "
              f"{result['signal_mid_pulse_worst_restore_ms']:.1f} ms at worst (target 50 ms)")
    if kill_held:
        print(f"SIGKILL: pulse on the device at most {result['sigkill_worst_held_ms']:.0f} ms "
              f"(bound: width cap + watchdog = {result['sigkill_bound_ms']:.0f} ms)")
    if pss:
        print(f"issue 49: the PSS as found in {result['pss_as_found_pct_all']:.1f} % of "
              f"{sum(s['runs'] for s in pss)} stabiliser-test runs; off after a fault "
              f"{result['pss_worst_off_after_fault_ms']:.0f} ms at worst")
    print(f"disk full made with: {result['disk_full_method']}")
    if args.json_out:
        Path(args.json_out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json_out).write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.json_out}")
    return 0


if __name__ == "__main__":
    t0 = time.monotonic()
    code = main()
    print(f"total {time.monotonic() - t0:.0f} s")
    sys.exit(code)
