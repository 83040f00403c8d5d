"""`report` reads only the captures of the result's own folder or the working folder unless told
(issue 48 item 12: it followed an absolute capture path to any file and printed its SHA-256), and
the batch's report of a row whose steps leave identify out uses the result an earlier batch left
(item 14)."""
from __future__ import annotations

import json

import pytest

from bench_ctl.cli import main
from bench_ctl.fleet.batch import _report_step
from bench_ctl.fleet.manifest import Entry, read_manifest
from bench_ctl.limits import sha256_file


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A capture in caps/, its result in results/ (the capture named as ../caps/c.csv)."""
    d = tmp_path_factory.mktemp("rep")
    (d / "caps").mkdir()
    (d / "results").mkdir()
    assert main(["simulate", "-o", str(d / "caps" / "c.csv"), "--duration", "3", "--rate", "500"]) == 0
    assert main(["identify", str(d / "caps" / "c.csv"), "--evals", "64", "--no-progress",
                 "--json", str(d / "results" / "r.json")]) in (0, 1)
    return d


def test_a_capture_path_leading_elsewhere_is_not_read(made, tmp_path, monkeypatch, capsys):
    secret = tmp_path / "secret" / "shadow"
    secret.parent.mkdir()
    secret.write_text("root:x:0:0\n")
    result = json.loads((made / "results" / "r.json").read_text())
    result["captures"][0]["path"] = str(secret)
    evil = tmp_path / "handed" / "evil.json"
    evil.parent.mkdir()
    evil.write_text(json.dumps(result))
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    capsys.readouterr()
    assert main(["report", str(evil), "-o", str(work / "r.html")]) == 2
    out = capsys.readouterr()
    assert "leads outside the result's folder and the working folder" in out.err and "--allow-outside" in out.err
    # allowed: read, and refused as not the file identified, without the file's own hash
    assert main(["report", str(evil), "-o", str(work / "r.html"), "--allow-outside"]) == 2
    out = capsys.readouterr()
    assert "is not the file identified" in out.err
    assert sha256_file(secret) not in out.out + out.err
    assert not (work / "r.html").exists()
    # a relative path that climbs out of both folders is refused the same way
    result["captures"][0]["path"] = "../secret/shadow"
    evil.write_text(json.dumps(result))
    assert main(["report", str(evil), "-o", str(work / "r.html")]) == 2
    assert "leads outside" in capsys.readouterr().err


def test_the_usual_layouts_report_and_say_what_they_read(made, monkeypatch, capsys):
    monkeypatch.chdir(made)               # results/r.json names ../caps/c.csv: inside the working folder
    assert main(["report", "results/r.json", "-o", "results/r.html"]) in (0, 1)
    assert f"read capture {made / 'results' / '..' / 'caps' / 'c.csv'}" in capsys.readouterr().out
    monkeypatch.chdir(made / "results")   # neither folder holds it: refused, allowed when asked
    assert main(["report", "r.json", "-o", "r2.html"]) == 2
    assert main(["report", "r.json", "-o", "r2.html", "--allow-outside"]) in (0, 1)


def test_a_batch_folder_never_takes_the_name_of_the_batchs_own_files(tmp_path):
    for name in ("index.html.csv", "Summary.csv.csv", "a.csv"):
        (tmp_path / name).write_text("time,usetp,efd\n")
    (tmp_path / "m.csv").write_text("capture\nindex.html.csv\nSummary.csv.csv\na.csv\n")
    names = [e.name for e in read_manifest(tmp_path / "m.csv")]
    assert names == ["index.html-2", "Summary.csv-2", "a"]


def test_a_report_only_row_uses_the_earlier_result(made, tmp_path):
    folder = tmp_path / "out" / "c"
    folder.mkdir(parents=True)
    entry = Entry(line=2, name="c", capture=made / "caps" / "c.csv", steps=("report",))
    row = _report_step(None, None, entry, str(folder), 64, 0)
    assert row["rc"] == 2 and "does not exist" in row["error"] and "identification failed" not in row["error"]
    result = json.loads((made / "results" / "r.json").read_text())
    result["captures"][0]["path"] = str((made / "caps" / "c.csv").resolve())
    (folder / "result.json").write_text(json.dumps(result))
    row = _report_step(None, None, entry, str(folder), 64, 0)
    assert row["rc"] in (0, 1), row
    assert (folder / "report.html").exists()
    # an earlier result of another capture is not reported as this row's
    other = Entry(line=3, name="c", capture=tmp_path / "x.csv", steps=("report",))
    row = _report_step(None, None, other, str(folder), 64, 0)
    assert row["rc"] == 2 and "was made from another capture" in row["error"]
