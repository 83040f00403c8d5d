"""Bench config (strict keys), audit log and the limit checks - no devices needed."""
from __future__ import annotations

import json
import os
import signal
import tomllib
from pathlib import Path

import pytest

from bench_ctl.runner.audit import AuditLog, read_audit
from bench_ctl.runner.config import ConfigError, config_from_dict, load_bench_config
from bench_ctl.runner.safety import CtrlC, LimitViolation, PreconditionFailed, check_no_load, check_pulse

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "benches" / "example.toml"
SIM_EXCITER = ROOT / "drivers" / "profiles" / "sim-exciter.toml"
SIM_RECORDER = ROOT / "drivers" / "profiles" / "sim-recorder.toml"


def example_doc() -> dict:
    return tomllib.loads(EXAMPLE.read_text())


def test_example_configs_load():
    cfg = load_bench_config(EXAMPLE)
    assert cfg.exciter.url == "tcp://192.0.2.10:502" and cfg.exciter.profile == "sim-exciter"
    assert cfg.recorder.url == "/dev/ttyUSB0" and cfg.recorder.download_attempts == 3
    assert cfg.limits.pulse_amplitude_max_pu == 0.06
    assert cfg.procedure_params("no_load_pulse")["amplitude_pu"] == 0.05
    sim = load_bench_config(ROOT / "benches" / "sim.toml")
    assert sim.exciter.url == "tcp://127.0.0.1:5020"
    assert json.loads(json.dumps(cfg.to_dict()))["limits"]["setpoint_max_pu"] == 1.08


@pytest.mark.parametrize("section, key, value, message", [
    ("limits", "pulse_amplitude_max", 0.06, "unknown key limits.pulse_amplitude_max"),
    ("exciter", "adress", "x", "unknown key exciter.adress"),
    ("limits", "pulse_width_max_s", "1.5", "limits.pulse_width_max_s = '1.5' must be a float"),
    ("limits", "setpoint_min_pu", 1.2, "setpoint_min_pu 1.2 must be below"),
    ("exciter", "url", "/dev/ttyS0", "expected tcp://HOST:PORT"),
    ("exciter", "url", "tcp://host", "expected tcp://HOST:PORT"),
    ("recorder", "parity", "X", "must be N, E or O"),
    ("recorder", "stopbits", 3, "recorder.stopbits = 3 must be 1 or 2"),
    ("exciter", "heartbeat_period_s", 0, "must be > 0"),
    ("limits", "no_load_p_max_mw", True, "must be a float"),
])
def test_bad_keys_and_values_are_refused_naming_the_key(section, key, value, message):
    doc = example_doc()
    doc[section][key] = value
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        config_from_dict(doc, source="bench.toml")


def test_a_bench_config_that_is_not_text_is_refused_with_its_name(tmp_path):
    f = tmp_path / "bench.toml"
    f.write_bytes(b"[bench]\nname = '\xff'\n")
    with pytest.raises(ConfigError, match="not a UTF-8 text file") as info:
        load_bench_config(f)
    assert str(f) in str(info.value)


def test_missing_required_limit_and_unknown_table():
    doc = example_doc()
    del doc["limits"]["no_load_p_max_mw"]
    with pytest.raises(ConfigError, match="missing key limits.no_load_p_max_mw"):
        config_from_dict(doc, source="bench.toml")
    doc = example_doc()
    doc["limit"] = {}
    with pytest.raises(ConfigError, match="unknown table or key 'limit'"):
        config_from_dict(doc, source="bench.toml")


def test_profile_paths_are_relative_to_the_config(tmp_path):
    text = EXAMPLE.read_text().replace('profile = "sim-exciter"',
                                       'profile = "profiles/mine.toml"')
    (tmp_path / "b.toml").write_text(text)
    (tmp_path / "profiles").mkdir()
    (tmp_path / "profiles" / "mine.toml").write_text(SIM_EXCITER.read_text())
    cfg = load_bench_config(tmp_path / "b.toml")
    assert cfg.exciter.profile == str(tmp_path / "profiles" / "mine.toml")
    assert cfg.recorder.profile == "sim-recorder"


def test_with_endpoints_changes_addresses_only():
    cfg = load_bench_config(EXAMPLE)
    moved = cfg.with_endpoints(exciter_url="tcp://127.0.0.1:1502", recorder_url="/dev/pts/9")
    assert moved.exciter.url == "tcp://127.0.0.1:1502" and moved.recorder.url == "/dev/pts/9"
    assert moved.limits == cfg.limits and moved.exciter.profile == cfg.exciter.profile


def test_audit_lines_are_durable_json_and_never_overwritten(tmp_path):
    path = tmp_path / "audit.jsonl"
    with AuditLog(path) as audit:
        audit.step = "pulse"
        audit.event("write", register="setpoint", raw=[1, 2], value=float("inf"))
        assert len(read_audit(path)) == 1        # on disk before close
    rows = read_audit(path)
    assert rows[0]["kind"] == "write" and rows[0]["step"] == "pulse"
    assert rows[0]["value"] == "inf" and rows[0]["raw"] == [1, 2]
    assert {"t_utc", "t_mono_s"} <= set(rows[0])
    with pytest.raises(FileExistsError):
        AuditLog(path).open()


def test_pulse_limits_refuse_and_list_every_violation():
    lim = load_bench_config(EXAMPLE).limits   # cap 0.06 pu, 1.5 s, band 0.95..1.08
    plan = check_pulse(lim, setpoint_pu=1.0, amplitude_pu=0.05, width_s=1.0)
    assert plan.pulse_setpoint_pu == pytest.approx(1.05)
    with pytest.raises(LimitViolation) as err:
        check_pulse(lim, setpoint_pu=1.05, amplitude_pu=0.07, width_s=2.0)
    text = str(err.value)
    assert "0.07 pu above the cap limits.pulse_amplitude_max_pu = 0.06" in text
    assert "width_s = 2 s above the cap limits.pulse_width_max_s = 1.5" in text
    assert "pulse setpoint 1.12 pu outside the band" in text
    with pytest.raises(LimitViolation, match="pre-test setpoint 0.9 pu outside"):
        check_pulse(lim, setpoint_pu=0.9, amplitude_pu=0.05, width_s=1.0)
    with pytest.raises(LimitViolation, match="not a finite number"):
        check_pulse(lim, setpoint_pu=1.0, amplitude_pu=float("nan"), width_s=1.0)
    # exactly at the cap is allowed; a negative pulse is checked by magnitude
    check_pulse(lim, setpoint_pu=1.0, amplitude_pu=-0.04, width_s=1.5)


def test_no_load_precondition():
    lim = load_bench_config(EXAMPLE).limits   # |p| < 2 MW
    check_no_load(lim, 0.5)
    check_no_load(lim, -1.9)
    with pytest.raises(PreconditionFailed, match="p = 2 MW, must be below"):
        check_no_load(lim, 2.0)
    with pytest.raises(PreconditionFailed):
        check_no_load(lim, float("nan"))


def test_ctrl_c_policy_first_raises_then_ignored():
    before = signal.getsignal(signal.SIGINT)
    policy = CtrlC()
    with policy.installed():
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)       # during the safe state: ignored
        os.kill(os.getpid(), signal.SIGINT)
    assert policy.ignored == 2 and not policy.armed
    assert signal.getsignal(signal.SIGINT) is before


def test_bench_safe_state_never_raises_and_reaches_every_device():
    """Whatever escapes one device's safe state (here a full disk under the audit log) ends as
    a failed report, and the next device still gets its safe state."""
    from bench_ctl.runner.bench import Bench
    from drivers.device import SafeStateReport

    class Raising:
        name = "exciter"

        def safe_state(self, reason, *, reconnect=False):
            raise OSError("No space left on device")

    class Fine:
        name = "recorder"

        def safe_state(self, reason, *, reconnect=False):
            return SafeStateReport("recorder", True, "disarmed", reason=reason)

    bench = Bench.__new__(Bench)  # the devices only; no config, no I/O
    bench.exciter, bench.recorder = Raising(), Fine()
    reports = bench.safe_state("test")
    assert [(r.device, r.ok) for r in reports] == [("exciter", False), ("recorder", True)]
    assert "OSError: No space left on device" in reports[0].detail


def _register_block(text: str, name: str) -> str:
    """The [registers.NAME] table of a profile's text, up to the next table."""
    start = text.index(f"[registers.{name}]")
    end = text.find("\n[", start + 1)
    return text[start:] if end < 0 else text[start:end + 1]


def _edited(text: str, name: str, old: str, new: str) -> str:
    block = _register_block(text, name)
    assert old in block, (name, old)
    return text.replace(block, block.replace(old, new))


@pytest.mark.parametrize("device, edit, message", [
    ("exciter", lambda t: t.replace(_register_block(t, "p"), ""),
     "role p: missing (active power: the no-load precondition)"),
    ("exciter", lambda t: _edited(t, "setpoint", 'access = "rw"', 'access = "r"'),
     "role setpoint: access 'r' (holding register), the host writes it: needs 'rw'"),
    ("exciter", lambda t: _edited(t, "p", 'unit = "MW"', 'unit = "kW"'),
     "role p: unit 'kW', the drivers compute in 'MW'"),
    ("exciter", lambda t: _edited(t, "watchdog_timeout", 'unit = "s"', 'unit = "ms"'),
     "role watchdog (register watchdog_timeout): unit 'ms', the drivers compute in 's'"),
    ("exciter", lambda t: t.replace('watchdog_register = "watchdog_timeout"', 'watchdog_register = "wd"'),
     "role watchdog: settings.watchdog_register = 'wd' is not a register of the profile"),
    ("recorder", lambda t: _edited(t, "status", "triggered = 3, ", ""),
     "role status: no named value triggered (has idle, recording, armed, done)"),
    ("recorder", lambda t: t.replace(_register_block(t, "efd_scale"), ""),
     "role efd_scale: missing (per unit per count of each recorded channel)"),
])
def test_a_profile_that_does_not_fit_its_driver_is_refused_at_load_in_one_line(tmp_path, device, edit, message):
    """The drivers declare the roles a procedure needs (drivers.roles); the bench config checks
    its profiles against them when it is loaded: one line naming the config, the profile, the
    role and what is wrong."""
    shipped = SIM_EXCITER if device == "exciter" else SIM_RECORDER
    (tmp_path / "mine.toml").write_text(edit(shipped.read_text()))
    (tmp_path / "b.toml").write_text(EXAMPLE.read_text().replace(
        f'profile = "sim-{device}"', 'profile = "mine.toml"'))
    with pytest.raises(ConfigError) as info:
        load_bench_config(tmp_path / "b.toml")
    text = str(info.value)
    assert text.startswith(f"{tmp_path / 'b.toml'}: {device}.profile = '{tmp_path / 'mine.toml'}' "
                           f"(profile 'sim-{device}') does not fit the {device} driver: ")
    assert text.endswith(message) and "\n" not in text


def test_every_problem_of_a_profile_is_in_its_one_line(tmp_path):
    text = _edited(SIM_EXCITER.read_text(), "setpoint", 'access = "rw"', 'access = "r"')
    (tmp_path / "mine.toml").write_text(text.replace(_register_block(text, "vt"), ""))
    doc = example_doc()
    doc["exciter"]["profile"] = str(tmp_path / "mine.toml")
    with pytest.raises(ConfigError, match=r"role setpoint: access 'r' .*; role vt: missing"):
        config_from_dict(doc, source="bench.toml")


def test_the_shipped_profiles_play_every_role():
    from drivers.profile import load_profile
    from drivers.roles import role_problems

    for name in ("sim-exciter", "vendor-exciter", "sim-recorder"):
        assert role_problems(load_profile(name)) == [], name


def test_a_run_on_a_profile_without_a_role_opens_nothing(tmp_path, capsys):
    """`bench-ctl run` refuses before the output folder, the audit or a link is opened."""
    from bench_ctl.cli import main

    (tmp_path / "mine.toml").write_text(SIM_EXCITER.read_text().replace(
        _register_block(SIM_EXCITER.read_text(), "heartbeat"), ""))
    (tmp_path / "b.toml").write_text(EXAMPLE.read_text().replace('profile = "sim-exciter"',
                                                                 'profile = "mine.toml"'))
    rc = main(["run", "no_load_pulse", "--bench", str(tmp_path / "b.toml"), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "role heartbeat: missing" in err, err
    assert not (tmp_path / "out").exists()
