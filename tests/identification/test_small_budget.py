"""`identify --evals N` runs for every N its help allows (issue 48 item 15: --evals 32..36 failed
with "max_evals=28 is smaller than the swarm" although the help says at least 32): the swap
restarts' and the edge polish's shares of the budget give way to MVMO's first generation."""
from __future__ import annotations

import json

import pytest

from bench_ctl.cli import main
from bench_ctl.commands.identify import MIN_EVALS


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    d = tmp_path_factory.mktemp("budget")
    assert main(["simulate", "-o", str(d / "c.csv"), "--duration", "3", "--rate", "500"]) == 0
    return d / "c.csv"


@pytest.mark.parametrize("evals", [MIN_EVALS, MIN_EVALS + 1, MIN_EVALS + 4, 40])
def test_every_budget_the_help_allows_runs_within_itself(capture, tmp_path, capsys, evals):
    out = tmp_path / "r.json"
    rc = main(["identify", str(capture), "--evals", str(evals), "--no-progress", "--json", str(out)])
    err = capsys.readouterr().err
    assert rc in (0, 1), err
    assert "smaller than the swarm" not in err
    assert json.loads(out.read_text())["evaluations"] <= evals


def test_the_help_and_the_check_agree(capsys):
    assert main(["identify", "--help"]) == 0
    assert f"at least {MIN_EVALS}" in " ".join(capsys.readouterr().out.split())
    assert main(["identify", "x.csv", "--evals", str(MIN_EVALS - 1)]) == 2
    assert f"{MIN_EVALS - 1} is not in the range x>={MIN_EVALS}" in capsys.readouterr().err
