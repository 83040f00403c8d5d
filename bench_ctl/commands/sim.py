"""`bench-ctl sim`: run the simulated bench (exciter on Modbus TCP, recorder on Modbus RTU).

Example:
  bench-ctl sim --tcp 127.0.0.1:5020 --serial /tmp/recorder --effect ceiling_limit:VRMAX=2.8
  bench-ctl sim --fault late_reply:device=recorder,delay_s=0.3,count=inf --control 127.0.0.1:5029

Prints the endpoints, then runs until Ctrl-C or SIGTERM and shuts down cleanly (exit 0).
Faults are armed at start with --fault, and at run time through the optional line-based
control port (`fault KIND key=value ...`, `clear`, `list`, `load MW`; see simulators/control.py).
Exit codes: 0 stopped cleanly; 2 bad option / unit / profile; 3 cannot bind or open a port.
"""
from __future__ import annotations

import logging
import signal
import threading

import click

from bench_ctl.exitcodes import ExitCode
from bench_ctl.units.unit import UnitError

from .options import build_unit, unit_options

log = logging.getLogger(__name__)


def _hostport(text: str, option: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise click.BadParameter(f"expected HOST:PORT, got {text!r}", param_hint=option)
    try:
        number = int(port)
    except ValueError:
        raise click.BadParameter(f"port {port!r} is not a number", param_hint=option) from None
    if not 0 <= number <= 65535:
        raise click.BadParameter(f"port {number} outside 0..65535", param_hint=option)
    return host, number


@click.command()
@unit_options
@click.option("--tcp", default="127.0.0.1:5020", show_default=True, metavar="HOST:PORT",
              help="Exciter Modbus TCP address (port 0: any free port).")
@click.option("--recorder-tcp", default="127.0.0.1:5021", show_default=True, metavar="HOST:PORT",
              help="Recorder RTU-over-TCP address (bench config url rtu+tcp://HOST:PORT; "
                   "pyserial clients: socket://HOST:PORT).")
@click.option("--serial", "serial_link", default=None, metavar="PATH",
              help="Also make PATH a symlink to the recorder's pseudo-terminal.")
@click.option("--no-serial", is_flag=True, help="Do not open a pseudo-terminal for the recorder.")
@click.option("--exciter-profile", default="sim-exciter", show_default=True,
              help="Exciter profile name (drivers/profiles/NAME.toml) or path.")
@click.option("--recorder-profile", default=None,
              help="Recorder profile name or path [default: sim-recorder; with --online sim-recorder-online].")
@click.option("--exciter-unit-id", type=int, default=1, show_default=True)
@click.option("--recorder-unit-id", type=int, default=1, show_default=True)
@click.option("--heartbeat-timeout", type=float, default=None,
              help="Exciter watchdog period (s), served in the profile's watchdog register (what a "
                   "run reads and checks); default from the profile.")
@click.option("--load-mw", type=float, default=None,
              help="Simulated active power (MW) [default: 0, no load]; with --online the turbine's mechanical "
                   "power [default: the unit's [grid] P0].")
@click.option("--online", is_flag=True,
              help="The unit synchronised through XE to an infinite bus (its [grid] data, --set XE=..., or a "
                   "GENROU / GENSAL record via --from-dyr): P follows the turbine (register mech_power), Q the "
                   "excitation; the recorder records p, q and ifd too.")
@click.option("--mva", type=float, default=100.0, show_default=True,
              help="The machine base (MVA) of --online: P and Q in MW and Mvar on the exciter's registers.")
@click.option("--noise", type=float, default=0.01, show_default=True,
              help="Recorder noise sigma on efd and vt (pu).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--fault", "faults", multiple=True, metavar="KIND[:k=v,...]",
              help="Arm a fault at start, e.g. no_reply:device=exciter,count=1 (repeatable).")
@click.option("--control", default=None, metavar="HOST:PORT",
              help="Open a line-based control port for run-time faults.")
def sim(unit_path, model, from_dyr, dyr_bus, dyr_id, overrides, effects, tcp, recorder_tcp, serial_link, no_serial,
        exciter_profile, recorder_profile, exciter_unit_id, recorder_unit_id, heartbeat_timeout,
        load_mw, online, mva, noise, seed, faults, control, dyr_ignore=()) -> int:
    """Run the simulated exciter and recorder around one real-time plant until Ctrl-C."""
    from simulators.bench import SimBench
    from simulators.faults import parse_fault

    tcp_addr = _hostport(tcp, "--tcp")
    rec_addr = _hostport(recorder_tcp, "--recorder-tcp")
    control_addr = _hostport(control, "--control") if control else None
    try:
        unit = build_unit(unit_path, overrides, effects, model=model, from_dyr=from_dyr,
                          dyr_bus=dyr_bus, dyr_id=dyr_id, dyr_ignore=dyr_ignore)
        if unit.model != "REFERENCE" and not online:   # the no-load plant steps the reference blocks only
            raise UnitError(f"the simulated bench at no load runs the REFERENCE structure only, not {unit.model} "
                            "(on line, --online, it runs any); use `bench-ctl simulate` for a capture of another "
                            "structure")
        if recorder_profile is None:
            recorder_profile = "sim-recorder-online" if online else "sim-recorder"
        armed = [parse_fault(f) for f in faults]
        bench = SimBench(unit, tcp=tcp_addr, recorder_tcp=rec_addr,
                         serial=False if no_serial else (serial_link or True),
                         exciter_profile=exciter_profile, recorder_profile=recorder_profile,
                         exciter_unit_id=exciter_unit_id, recorder_unit_id=recorder_unit_id,
                         heartbeat_timeout_s=heartbeat_timeout, load_mw=0.0, noise_pu=noise,
                         seed=seed, faults=armed, control=control_addr, online=online, mva=mva)
        if load_mw is not None:
            bench.exciter.set_load_mw(load_mw)
    except (UnitError, ValueError, FileNotFoundError) as exc:
        click.echo(f"error: {exc}", err=True)
        return ExitCode.ABORTED
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            endpoints = bench.start()
        except OSError as exc:
            click.echo(f"error: cannot open the simulated devices' ports: {exc}", err=True)
            return ExitCode.COMMS
        click.echo(f"simulated bench: unit {unit.name!r}, effects "
                   f"{', '.join(unit.effects) or 'none'}")
        if online:
            st = bench.plant.state()
            click.echo(f"on line through XE {unit.grid['XE']:g} pu: P {st.p * mva:.1f} MW, Q {st.q * mva:.1f} Mvar, "
                       f"Vt {st.vt:.4f} pu ({mva:g} MVA base)")
        click.echo(endpoints.describe())
        if bench.control_address:
            click.echo(f"control  line protocol   {bench.control_address[0]}:{bench.control_address[1]}")
        for fault in armed:
            click.echo(f"fault armed: {fault}")
        click.echo("ready (Ctrl-C or SIGTERM to stop)", nl=True)
        while not stop.wait(0.5):
            pass
        click.echo("stopping")
    finally:
        bench.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    timing = bench.plant.timing()
    click.echo(f"stopped after {timing.elapsed_s:.1f} s: plant lag max {timing.lag_max_s * 1e3:.2f} ms, "
               f"behind max {timing.behind_max_s * 1e3:.2f} ms, stalls > 1 ms {timing.stalls_over_1ms}")
    return ExitCode.OK
