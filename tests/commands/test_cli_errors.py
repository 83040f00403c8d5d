"""Errors are mapped to exit codes once, in `bench_ctl.cli.main`: bad input (`BadInput`, every
layer's input error derives from it) is one line and exit 2; anything else is a bug, said as such
(exit 70, one line; the traceback with -v), never passed off as bad input."""
from __future__ import annotations

import ast
import importlib
from pathlib import Path

from bench_ctl.cli import main
from bench_ctl.exitcodes import BadInput, ExitCode

ROOT = Path(__file__).resolve().parents[2]


def _boom(*_args, **_kwargs):
    raise ValueError("boom: a plain bug")


def test_a_plain_bug_in_a_command_is_reported_as_a_bug(monkeypatch, capsys):
    """`diagnose` once caught every ValueError as bad input (exit 2): a bug inside it now says it is
    one, in one line, with no traceback unless -v."""
    import bench_ctl.commands.diagnose as cmd

    monkeypatch.setattr(cmd, "read_capture", _boom)
    assert main(["diagnose", "cap.csv"]) == ExitCode.BUG == 70
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("internal error (a bug in bench-ctl, not in the input): ValueError: boom")
    assert "-v" in err[0] and "Traceback" not in err[0]


def test_a_bug_shows_its_traceback_with_v(monkeypatch, capsys):
    import bench_ctl.commands.models as cmd

    monkeypatch.setattr(cmd, "structure", _boom)
    assert main(["-v", "models", "SEXS"]) == ExitCode.BUG
    err = capsys.readouterr().err
    assert "internal error" in err and "Traceback (most recent call last)" in err and "_boom" in err


def test_bad_input_is_one_line_and_exit_2(monkeypatch, capsys):
    import bench_ctl.commands.models as cmd

    def refuse(name):
        raise BadInput(f"model {name!r}: no such structure")
    monkeypatch.setattr(cmd, "structure", refuse)
    assert main(["models", "NOPE"]) == ExitCode.ABORTED
    assert capsys.readouterr().err == "error: model 'NOPE': no such structure\n"
    # the real refusal takes the same road
    monkeypatch.undo()
    assert main(["models", "NOPE"]) == ExitCode.ABORTED
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1


def test_every_value_error_of_the_analysis_and_the_commands_is_bad_input():
    """An error class of bench_ctl that is a ValueError derives from BadInput: a plain ValueError
    is left to mean a bug."""
    found = []
    for path in sorted((ROOT / "bench_ctl").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        mod = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        for node in tree.body:
            if isinstance(node, ast.ClassDef) and node.name.endswith(("Error", "Refused", "Fitted", "Input")):
                cls = getattr(importlib.import_module(mod), node.name)
                if issubclass(cls, ValueError):
                    found.append(cls)
                    assert issubclass(cls, BadInput), f"{mod}.{node.name} is a ValueError but not a BadInput"
    # the layers' own: the unit file, captures, results and diagnoses, input files, outputs, ...
    assert len(found) >= 15, found


def test_commands_leave_the_mapping_to_main():
    """The commands return ABORTED themselves only where a run or a refusal of their own says so
    (a run's outcome, the simulated bench's options): at most 11 places (44 before issue 50)."""
    count = sum(p.read_text(encoding="utf-8").count("return ExitCode.ABORTED")
                for p in (ROOT / "bench_ctl" / "commands").glob("*.py"))
    assert count <= 11, count
