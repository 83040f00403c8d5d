"""What the engineer reads on the console of a run, and the inputs a run refuses in one line
(issue 24 items 13 (procedure parameters), 18, 19; issue 48 item 16).

- The plan (setpoint from -> to, width, limits, the watchdog found on the device) is printed on
  every run, also with --yes and --dry-run; a live readout (setpoint, vt, efd, time left) runs
  during the pulse on a terminal; values in engineering format (no `5.0e-06 pu`, no `-0.0`),
  no raw register words outside -vv.
- Every parameter of the pulse test is bounded; a bench config whose exciter profile is a
  recorder's, or that is not a file, is refused before anything is opened.
"""
from __future__ import annotations

import inspect
import io
import logging
import os
import re
import subprocess
import sys

import pytest

from bench_ctl.cli import main
from bench_ctl.commands.run import print_outcome
from bench_ctl.plants import Plant
from bench_ctl.runner.config import ConfigError, config_from_dict
from bench_ctl.runner.runner import run_procedure
from cli_runs import FAST_PARAMS, ROOT, bench_toml, run_argv, run_env, start_run
from drivers.profile import load_profile
from procedures import no_load_pulse as pulse_module
from pulse_bench import bench_config, config_doc
from simulators.bench import SimBench
from simulators.exciter import ExciterDevice
from simulators.recorder import RecorderDevice
from wire_proxy import WireProxy

PLAN_LINES = ("no_load_pulse on the exciter tcp://127.0.0.1:",
              "  setpoint  1.0000 pu -> 1.0500 pu for 0.300 s, then back to 1.0000 pu",
              "  limits    |amplitude| <= 0.0600 pu, width <= 1.500 s, setpoints 0.9500..1.0800 pu",
              "  watchdog  2.000 s (read from the device, register watchdog_timeout (input 11)); limit 3.000 s")


def fast_args() -> list[str]:
    args = []
    for key, value in FAST_PARAMS.items():
        args += ["--param", f"{key}={value}"]
    return args


def assert_engineering(text: str) -> None:
    assert not re.search(r"\d[eE][-+]?\d", text), text          # no 5.0e-06
    assert not re.search(r"-0\.0+\b(?!\d)", text), text           # no -0.0 / -0.000
    assert not re.search(r"\[\d+, \d+\]", text), text           # no register words
    assert "last frames on the link" not in text


def test_the_plan_is_printed_with_yes_and_the_criteria_in_engineering_format(tmp_path, capsys):
    with SimBench() as sim:
        bench = bench_toml(tmp_path / "bench.toml", sim)
        rc = main(["run", "no_load_pulse", "--bench", str(bench), "--yes", "--out",
                   str(tmp_path / "run"), *fast_args()])
    out = capsys.readouterr()
    assert rc in (0, 1), out.out + out.err
    for line in PLAN_LINES:
        assert line in out.out, out.out
    assert "(--yes given: not asked)" in out.out
    crit = [ln for ln in out.out.splitlines() if ln.startswith("  [PASS]") or ln.startswith("  [FAIL]")]
    assert len(crit) == 5
    assert re.search(r"pulse width error: [-+]?\d+\.\d ms \(limit ±20\.0 ms\)", crit[0]), crit[0]
    assert re.search(r"pulse amplitude error: [-+]?\d\.\d{4} pu \(limit ±0\.0010 pu\)", crit[1]), crit[1]
    assert_engineering(out.out)


def test_the_plan_is_printed_on_a_dry_run(tmp_path, capsys):
    rc = main(["run", "no_load_pulse", "--bench", str(ROOT / "benches" / "example.toml"),
               "--dry-run", "--out", str(tmp_path / "run"), *fast_args()])
    out = capsys.readouterr().out
    assert rc in (0, 1), out
    for line in PLAN_LINES:
        assert line in out, out
    assert "(dry run against the simulated bench: not asked)" in out


def test_a_live_readout_runs_during_the_pulse_on_a_terminal(tmp_path, monkeypatch):
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    tty = Tty()
    monkeypatch.setattr("sys.stderr", tty)
    with SimBench() as sim:
        proxy = WireProxy(sim.endpoints.exciter_tcp)
        try:
            out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                                params={**FAST_PARAMS, "width_s": 0.8, "record_s": 2.0},
                                progress=True)
        finally:
            proxy.close()
    shown = tty.getvalue()
    assert out.exit_code in (0, 1), out.message
    readouts = re.findall(r"pulse: setpoint (\d\.\d{4}) pu, vt \d\.\d{4} pu, efd -?\d+\.\d{3} pu, "
                          r"(\d\.\d\d) s left", shown)
    assert len(readouts) >= 3, shown[-800:]
    assert {sp for sp, _ in readouts} == {"1.0500"}                   # the device's setpoint
    left = [float(t) for _, t in readouts]
    assert left == sorted(left, reverse=True) and left[0] <= 0.8
    assert out.data["commanded_width_s"] - 0.8 < 0.005                # the readout kept off the deadline


def test_a_refused_write_says_register_and_value_not_words(tmp_path):
    with SimBench() as sim:
        proxy = WireProxy(sim.endpoints.exciter_tcp)
        try:
            sim.faults.set("exception", device="exciter", op="write", register="setpoint", code=4)
            out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                                params=FAST_PARAMS)
        finally:
            proxy.close()
    assert out.exit_code == 2
    assert ("exciter: writing 2 holding register(s) at 0: device replied with exception 4 (server "
            "device failure) (register setpoint (holding 0), value 1.05)") in out.message
    assert_engineering(out.message)


@pytest.mark.parametrize("param, value, message", [
    ("width_s", 0.0001, "width_s = 0.0001 s outside 0.1..10 s"),
    ("width_tolerance_s", 10, "width_tolerance_s = 10 s outside 0.0005..0.1 s"),
    ("recovery_timeout_s", -5, "recovery_timeout_s = -5 s outside 0..600 s"),
    ("width_tolerance_s", 0.05, "width_tolerance_s = 0.05 s above 10 % of width_s = 0.3 s"),
    ("rate_hz", 20, "width_s = 0.3 s is 6 samples at rate_hz = 20 Hz"),
    ("amplitude_pu", 0.001, "|amplitude_pu| = 0.001 pu below 0.005 pu"),
    ("record_s", 0.5, "record_s = 0.5 s must exceed pre_trigger_s + width_s = 0.5 s"),
])
def test_every_pulse_parameter_is_bounded(tmp_path, capsys, param, value, message):
    bench = ROOT / "benches" / "example.toml"
    with pytest.raises(ConfigError, match=re.escape(message)):
        run_procedure("no_load_pulse", bench, tmp_path / "a", params={**FAST_PARAMS, param: value})
    assert not (tmp_path / "a").exists()                              # nothing opened
    rc = main(["run", "no_load_pulse", "--bench", str(bench), "--dry-run", "--out",
               str(tmp_path / "b"), *fast_args(), "--param", f"{param}={value}"])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and len(err.strip().splitlines()) == 1


def test_the_bounds_cover_every_parameter():
    kwargs = [p.name for p in inspect.signature(pulse_module.no_load_pulse).parameters.values()
              if p.kind is inspect.Parameter.KEYWORD_ONLY]
    assert sorted(kwargs) == sorted(pulse_module.PARAMETERS)
    defaults = {p.name: p.default for p in inspect.signature(pulse_module.no_load_pulse).parameters.values()
                if p.kind is inspect.Parameter.KEYWORD_ONLY}
    assert pulse_module.check_parameters(defaults) == []


@pytest.mark.parametrize("device, other", [("exciter", "sim-recorder"), ("recorder", "sim-exciter")])
def test_a_profile_of_the_wrong_device_kind_is_refused_in_one_line(tmp_path, capsys, device, other):
    doc = config_doc()
    doc[device]["profile"] = other
    kind = "recorder" if device == "exciter" else "exciter"
    with pytest.raises(ConfigError, match=f"{device}.profile = '{other}' describes an? {kind} "
                                          f"\\(profile '{other}'\\), not an? {device}"):
        run_procedure("comms_check", config_from_dict(doc, source="wrong.toml"), tmp_path / "a")
    assert not (tmp_path / "a").exists()
    text = (ROOT / "benches" / "example.toml").read_text().replace(
        f'profile = "sim-{device}"', f'profile = "{other}"')
    (tmp_path / "wrong.toml").write_text(text)
    rc = main(["run", "no_load_pulse", "--bench", str(tmp_path / "wrong.toml"), "--dry-run",
               "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err
    assert rc == 2 and "describes a" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "b").exists()


def test_a_bench_config_that_is_not_a_file_is_refused_unread(tmp_path, capsys):
    rc = main(["run", "comms_check", "--bench", "/dev/zero", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert rc == 2 and "/dev/zero: not a regular file" in err and len(err.strip().splitlines()) == 1
    big = tmp_path / "big.toml"
    big.write_text("# " + "x" * (1 << 20) + "\n")
    rc = main(["run", "comms_check", "--bench", str(big), "--out", str(tmp_path / "y")])
    assert rc == 2 and "more than the 1048576 bytes a bench config may have" in capsys.readouterr().err


# ------------------------------------------------------------------ issue 48 item 16
def test_a_run_with_stderr_closed_says_its_outcome_on_stdout(tmp_path):
    """`2>&-`: the run used to abort before any write with AttributeError ... isatty and say
    nothing; now it runs, and a refusal's reason reaches stdout."""
    bench = ROOT / "benches" / "example.toml"
    for name, params, code in (("refused", {**FAST_PARAMS, "amplitude_pu": 0.08}, 2), ("run", FAST_PARAMS, None)):
        argv = run_argv(bench, tmp_path / name, params=params, extra=("--dry-run",))
        proc = subprocess.run(argv, stdout=subprocess.PIPE, text=True, env=run_env(), cwd=ROOT, timeout=600,
                              preexec_fn=lambda: os.close(2))   # as `2>&-` leaves it
        assert "Traceback" not in proc.stdout and "AttributeError" not in proc.stdout, proc.stdout
        if code is not None:
            assert proc.returncode == code
            assert "|amplitude_pu| = 0.08 pu above the cap" in proc.stdout, proc.stdout
        else:
            assert proc.returncode in (0, 1), proc.stdout
            assert "no_load_pulse: " in proc.stdout and (tmp_path / name / "capture.csv").exists()


def test_library_log_lines_stay_off_the_console_and_go_to_the_run_log(tmp_path):
    """A lost reply read again: pymodbus logs an ERROR for it; the console shows none of it, the
    run's log file keeps it."""
    with SimBench() as sim:
        sim.faults.set("no_reply", device="exciter", op="read", register="vt", count=1)
        bench = bench_toml(tmp_path / "bench.toml", sim)
        proc = start_run(run_argv(bench, tmp_path / "run"))
        out, err = proc.communicate(timeout=300)
    assert proc.returncode in (0, 1), out + err
    assert sim.faults.history                                       # the reply was lost
    assert "pymodbus" not in out + err and "No response received" not in out + err, out + err
    assert "pymodbus.logging: No response received" in (tmp_path / "run" / "run.log").read_text()


def test_a_refusal_before_any_write_does_not_say_a_capture_was_lost(tmp_path, capsys):
    with SimBench() as sim:
        proxy = WireProxy(sim.endpoints.exciter_tcp)
        try:
            out = run_procedure("no_load_pulse", bench_config(proxy, sim), tmp_path, yes=True,
                                params={**FAST_PARAMS, "amplitude_pu": 0.08})
        finally:
            proxy.close()
    assert out.exit_code == 2 and not out.started
    print_outcome(out)
    printed = capsys.readouterr()
    assert "refused before any write" in printed.err and "NOT SAVED" not in printed.out + printed.err


def test_a_profile_of_the_wrong_kind_is_named_with_its_article():
    plant = Plant(None, rt_priority=None)
    with pytest.raises(ValueError, match="is for an exciter, not a recorder"):
        RecorderDevice(plant, load_profile("sim-exciter"))
    with pytest.raises(ValueError, match="is for a recorder, not an exciter"):
        ExciterDevice(plant, load_profile("sim-recorder"))


def test_dask_info_lines_stay_off_the_console():
    """Dask's own console handler (it does not propagate) prints INFO lines; bench-ctl sets it to
    warnings unless -vv."""
    code = ("import logging; from bench_ctl.cli import main; main(['models']); import distributed; "
            "print(logging.getLogger('distributed').getEffectiveLevel())")
    for flags, level in (("", logging.WARNING), ("'-vv', ", logging.INFO)):
        run = subprocess.run([sys.executable, "-c", code.replace("['models']", f"[{flags}'models']")],
                             capture_output=True, text=True, env={k: v for k, v in run_env().items()
                                                                  if not k.startswith("DASK_")},
                             cwd=ROOT, timeout=300)
        assert run.returncode == 0, run.stderr
        assert run.stdout.strip().splitlines()[-1] == str(level), run.stdout
