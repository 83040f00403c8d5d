"""`bench-ctl simulate`: a synthetic pulse capture of a unit, with effects, noise and quantisation; at
no load, or on the grid (`--online`: the unit synchronised through XE, P, Q and Ifd recorded too)."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import click

from bench_ctl import __version__, outputs
from bench_ctl.capture import write_capture
from bench_ctl.engine.simulate import RecorderModel, pulse_usetp, synthetic_record
from bench_ctl.exitcodes import ExitCode
from bench_ctl.identification.result_file import written
from bench_ctl.units.unit import UnitError

from .options import build_unit, unit_options

#: the longest simulated capture (samples): an hour at 1 kHz is 3.6e6
MAX_SAMPLES = 1.0e7


@click.command()
@unit_options
@click.option("--amplitude", type=float, default=0.05, show_default=True, help="Pulse height (pu).")
@click.option("--width", type=float, default=1.0, show_default=True, help="Pulse width (s).")
@click.option("--start", type=float, default=1.0, show_default=True, help="Pulse start (s).")
@click.option("--duration", type=float, default=10.0, show_default=True, help="Record length (s).")
@click.option("--rate", type=float, default=1000.0, show_default=True, help="Sample rate (Hz).")
@click.option("--noise", type=float, default=0.01, show_default=True, help="Recorder noise sigma on efd and vt (pu).")
@click.option("--lsb", type=float, default=20.0 / 4096, show_default=True,
              help="Recorder quantisation step (pu); default 12 bit over +-10 pu.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--online", is_flag=True,
              help="The unit on the grid: a GENROU through XE to an infinite bus at the operating point P0, Q0, "
                   "Vt0 (the unit's [grid], --set, or a GENROU record via --from-dyr); P, Q and Ifd recorded too.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Capture CSV to write.")
def simulate(unit_path, model, from_dyr, dyr_bus, dyr_id, overrides, effects, amplitude, width, start, duration,
             rate, noise, lsb, seed, online, output, dyr_ignore=()):
    """Write a synthetic pulse capture (CSV + JSON sidecar) of the unit."""
    unit = build_unit(unit_path, overrides, effects, model=model, from_dyr=from_dyr,
                      dyr_bus=dyr_bus, dyr_id=dyr_id, dyr_ignore=dyr_ignore)
    for opt, v in (("--amplitude", amplitude), ("--width", width), ("--start", start),
                   ("--duration", duration), ("--rate", rate), ("--noise", noise), ("--lsb", lsb)):
        if not math.isfinite(v):
            raise UnitError(f"{opt} {v!r} must be a finite number")
    if noise < 0 or lsb < 0:
        raise UnitError("--noise and --lsb must not be negative")
    if not str(output).lower().endswith(".csv"):
        raise UnitError(f"-o {output}: a capture file name must end in .csv")
    if rate * duration > MAX_SAMPLES:
        raise UnitError(f"--rate {rate:g} Hz over --duration {duration:g} s is {rate * duration:.3g} samples, "
                        f"more than the {MAX_SAMPLES:.0e} a simulated capture may have")
    if rate * duration < 2:
        raise UnitError(f"--rate {rate:g} Hz over --duration {duration:g} s gives fewer than 2 samples")
    if start < 0 or width <= 0 or start + width >= duration:
        raise UnitError(f"pulse start {start} s + width {width} s must lie inside the record of {duration} s")
    # the capture and its sidecar, before the simulation: never an input, never an existing
    # file, never through a link, a folder that can be written
    outputs.guard_outputs({"-o": output, "-o (its sidecar)": Path(output).with_suffix(".json")},
                          [unit_path, from_dyr], make_folders=True,
                          replace_hint="captures are never overwritten: choose another name")
    t, usetp = pulse_usetp(amplitude=amplitude, width=width, start=start, duration=duration, rate=rate,
                           usetp0=unit.generator["Vt0"])
    rec = synthetic_record(unit, t, usetp, RecorderModel(noise, lsb), seed, online=online)
    entry = unit.entry()
    meta = {
        "test": {"kind": "pulse", "amplitude_pu": amplitude, "start_s": start, "width_s": width,
                 **({"online": True} if online else {})},
        "source": "simulation",
        "unit": written(entry, unit.structure).to_json(),   # the structure's names
        "recorder": {"noise_pu": noise, "lsb_pu": lsb, "seed": seed,
                     "usetp": "the AVR's digital setpoint, recorded exactly",
                     **{name: "measured: noise + quantisation" for name in rec if name not in ("time", "usetp")}},
        "effects": entry.effects,  # JSON has no infinity: neutral limits as null
        "software_version": __version__,
        "command_line": " ".join(["bench-ctl"] + sys.argv[1:]),
    }
    try:
        Path(output).parent.mkdir(parents=True, exist_ok=True)
        with outputs.writing(output):
            csv_path, json_path = write_capture(Path(output), rec, meta)
    except FileExistsError as exc:   # (a name taken meanwhile: the guard refused the ones there before)
        raise outputs.OutputRefused(f"{exc} (captures are never overwritten)") from None
    click.echo(f"capture: {csv_path}")
    click.echo(f"sidecar: {json_path}")
    return ExitCode.OK
