"""Bad requests end in one line and exit 2 (bad input) or 3 (a port that cannot be opened),
never a traceback (issue 15 item 6)."""
from __future__ import annotations

import socket

import pytest

from bench_ctl.cli import main


def _run(argv, capsys):
    rc = main(argv)
    out = capsys.readouterr()
    assert "Traceback" not in out.err + out.out
    return rc, out.err


@pytest.fixture(scope="module")
def cap(tmp_path_factory):
    d = tmp_path_factory.mktemp("refusals")
    assert main(["simulate", "-o", str(d / "cap.csv"), "--duration", "3"]) == 0
    return d / "cap.csv"


def test_simulate_refuses_a_non_csv_name_and_an_absurd_duration(tmp_path, capsys):
    rc, err = _run(["simulate", "-o", str(tmp_path / "x.txt"), "--duration", "4"], capsys)
    assert rc == 2 and "must end in .csv" in err
    rc, err = _run(["simulate", "-o", str(tmp_path / "x.csv"), "--duration", "1e9"], capsys)
    assert rc == 2 and "samples, more than" in err


def test_import_into_a_missing_folder(cap, tmp_path, capsys):
    rc, err = _run(["import", str(cap), "-o", str(tmp_path / "nope" / "out.csv"), "--map", "efd=efd",
                    "--map", "usetp=usetp", "--time-column", "time"], capsys)
    assert rc == 2 and "does not exist" in err


def test_demo_refuses_before_the_pulse(tmp_path, capsys):
    (tmp_path / "result.json").write_text("{}")
    rc, err = _run(["demo", "--out", str(tmp_path)], capsys)
    assert rc == 2 and "result.json: exists" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["result.json"]  # no pulse was run
    rc, err = _run(["demo", "--out", str(tmp_path / "d"), "--evals", "0"], capsys)
    assert rc == 2 and "--evals" in err and not (tmp_path / "d").exists()


def test_sim_on_a_busy_port_exits_3_naming_it(capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        rc, err = _run(["sim", "--tcp", f"127.0.0.1:{port}", "--no-serial"], capsys)
    assert rc == 3 and f"cannot listen on 127.0.0.1:{port}" in err


def test_contradictory_constraints_are_refused_before_the_fit(cap, tmp_path, capsys):
    from importlib import resources

    text = resources.files("bench_ctl.data").joinpath("reference_unit.toml").read_text("utf-8")
    bad = text.replace('constraints = ["TA2 <= TA1", "TA4 >= TA2"]',
                       'constraints = ["TA2 <= TA1", "TA4 >= TA2", "TA1 <= 0.5*TA2"]')
    assert bad != text
    (tmp_path / "u.toml").write_text(bad)
    rc, err = _run(["identify", str(cap), "--unit", str(tmp_path / "u.toml"), "--evals", "64",
                    "--no-progress"], capsys)
    assert rc == 2 and "contradict each other" in err


@pytest.mark.timeout(60)
def test_every_text_input_is_bounded_before_it_is_read(cap, tmp_path, capsys):
    """Issue 24 item 17: `batch /dev/zero` read without end. Each kind of input has its own limit,
    stated in the refusal, and a device is refused before a byte is read."""
    zero = tmp_path / "zero.json"
    zero.symlink_to("/dev/zero")
    for argv in (["export", str(zero), "--dyr", str(tmp_path / "x.dyr")],
                 ["report", str(zero), "-o", str(tmp_path / "x.html")],
                 ["diagnose", str(cap), "--result", str(zero)],
                 ["simulate", "--from-dyr", str(zero), "-o", str(tmp_path / "x.csv")],
                 ["identify", str(cap), "--unit", str(zero), "--no-progress"]):
        rc, err = _run(argv, capsys)
        assert rc == 2 and ("not a regular file" in err or "not a unit file" in err), (argv, err)
    big = tmp_path / "big.dyr"
    with open(big, "wb") as f:
        f.truncate(65 << 20)                       # sparse: more than a .dyr may have
    rc, err = _run(["simulate", "--from-dyr", str(big), "-o", str(tmp_path / "y.csv")], capsys)
    assert rc == 2 and "more than the 67108864 bytes a .dyr file may have" in err
    res = tmp_path / "big.json"
    with open(res, "wb") as f:
        f.truncate(65 << 20)
    rc, err = _run(["export", str(res), "--dyr", str(tmp_path / "z.dyr")], capsys)
    assert rc == 2 and "more than the 67108864 bytes a result JSON may have" in err


def test_identify_evals_help_states_the_swarm_and_refuses_below_it(cap, capsys):
    """Issue 24 item 20: the help said x >= 1; the minimum is MVMO's swarm (32), de's one population."""
    from click.testing import CliRunner

    from bench_ctl.cli import cli
    help_text = CliRunner().invoke(cli, ["identify", "--help"]).output
    assert "x>=32" in help_text and "at least 32 (MVMO's swarm" in " ".join(help_text.split())
    rc, err = _run(["identify", str(cap), "--evals", "10", "--no-progress"], capsys)
    assert rc == 2 and "x>=32" in err
    rc, err = _run(["identify", str(cap), "--evals", "32", "--optimizer", "de", "--no-progress"], capsys)
    assert rc == 2 and "de needs at least" in err and "evaluations" in err


def test_diagnose_refuses_a_result_value_that_is_not_finite_under_the_files_name(cap, tmp_path, capsys):
    """A --result of IEEEX1 whose TE (the kernel's TEX) is Infinity is refused naming params.TE, the
    key as the file writes it, not the kernel's TEX."""
    import json

    from records import model_json, result_json

    res = tmp_path / "inf.json"
    data = result_json(params={"KA": 400.0, "TE": float("inf")}, model=model_json(name="IEEEX1"),
                       kernel={"params": {}, "bounds": {}, "fixed": {}, "constraints": []})
    res.write_text(json.dumps(data))          # json writes the float as Infinity, which it reads back
    rc, err = _run(["diagnose", str(cap), "--model", "IEEEX1", "--result", str(res)], capsys)
    assert rc == 2 and "params.TE = inf is not a finite number" in err and "TEX" not in err, err


def test_a_refused_problem_is_said_in_the_structures_names_by_identify_and_diagnose(cap, tmp_path, capsys):
    """IEEEX1's TA is the kernel's TE and its TE the kernel's TEX: constraints that contradict
    each other are refused in the names the unit file wrote, by both commands (diagnose once said
    the kernel's 'TEX <= 0.5*TE')."""
    unit = tmp_path / "x1.toml"
    unit.write_text('constraints = ["TE <= 0.5*TA", "TA <= 0.5*TE"]\n[avr]\nmodel = "IEEEX1"\n'
                    "[generator]\nTd0p = 7.5\nTd0pp = 0.05\nVt0 = 1.0\n")
    for argv in (["identify", str(cap), "--unit", str(unit), "--evals", "64", "--no-progress"],
                 ["diagnose", str(cap), "--unit", str(unit)]):
        rc, err = _run(argv, capsys)
        assert rc == 2 and "contradict each other" in err, (argv, err)
        assert "'TE <= 0.5*TA', 'TA <= 0.5*TE'" in err and "KA in [" in err, (argv, err)
        assert "TEX" not in err and "KAVR" not in err, (argv, err)


def test_warm_up_refuses_an_unknown_variant_and_all_with_a_list_before_compiling(tmp_path, capsys):
    listed = tmp_path / "variants.txt"
    listed.write_text("# the suite's\nnoload_ref_none\ngrid_full_pss3\n")
    rc, err = _run(["warm-up", "--variants", str(listed)], capsys)
    assert rc == 2 and "unknown engine variant 'grid_full_pss3'" in err
    rc, err = _run(["warm-up", "--all", "--variants", str(listed)], capsys)
    assert rc == 2 and "--all or --variants, not both" in err
