"""The typed result and diagnosis (docs/formats.md): every key checked on reading and named when
wrong, the schema version, the same JSON written back, and the format page kept current."""
from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import pytest

from bench_ctl.cli import main
from bench_ctl.diagnosis.diagnosis_file import BaseFit, Diagnosis, EffectEntry, Step, read_diagnosis
from bench_ctl.identification.result_file import CaptureEntry, IdentificationResult, read_result
from bench_ctl.records import FormatError, plain
from records import diagnosis_json, effect_json, result_json, step_json

ROOT = Path(__file__).resolve().parents[1]

CAPTURE = {"path": "pulse.csv", "sha256": "ab" * 32, "n": 5001, "rate_hz": 1000.0, "meta": {"test": {"kind": "pulse"}},
           "mse": 1.2e-4, "objective": 0.6, "weight": 1.0,
           "edges": [{"index": 1000, "jump_pu": 0.05, "fitted_s": 0.9995, "std_s": None}]}


def _result() -> dict:
    return result_json(captures=[json.loads(json.dumps(CAPTURE))], params={"KAVR": 201.5, "TA1": 1},
                       fixed={"VRMAX": None, "Td0p": 7.5},
                       bounds={"KAVR": [50, 500]}, mse=1.2e-4, objective=0.6, evaluations=1000,
                       history=[[32, None], [64, 0.7]], identifiability={"names": ["KAVR"], "std": {"KAVR": 1.5}},
                       failed=False, message="", model={"name": "REFERENCE"})


def _diagnosis() -> dict:
    return diagnosis_json(noise_floor=1e-4, verdict="ceiling_limit",
                          effects=[effect_json("ceiling_limit", params={"VRMAX": 2.8}, score=-40.0, k=2,
                                               variant="fixed limits", significant=True),
                                   effect_json("dead_time", params={"TD": 0.004}, score=None)],
                          explained_by=[step_json("ceiling_limit", params={"VRMAX": 2.8}, mse=1.1e-4)])


def test_a_result_and_a_diagnosis_read_into_their_classes_and_write_the_same_json():
    for cls, data in ((IdentificationResult, _result()), (Diagnosis, _diagnosis())):
        record = cls.from_json(json.loads(json.dumps(data)), "x.json")
        assert json.dumps(record.to_json()) == json.dumps(data)   # keys in order, 1 stays 1, 500 stays 500
    r = IdentificationResult.from_json(_result())
    assert isinstance(r.captures[0], CaptureEntry) and r.captures[0].n == 5001 and r.params["TA1"] == 1
    assert r.fixed["VRMAX"] is None and r.comparison is None and "comparison" not in r.to_json()
    d = Diagnosis.from_json(_diagnosis())
    assert isinstance(d.base, BaseFit) and all(isinstance(e, EffectEntry) for e in d.effects)
    assert isinstance(d.explained_by[0], Step) and d.effect("ceiling_limit").variant == "fixed limits"
    assert d.effect("dead_time").variant is None and "variant" not in d.to_json()["effects"][1]
    assert d.effect("saturation") is None


def test_a_figure_not_finite_in_memory_is_written_as_null():
    d = Diagnosis.from_json(plain(_diagnosis() | {"noise_floor": float("nan")}))
    effects = [e | {"score": float("inf")} for e in _diagnosis()["effects"]]
    d = dataclasses.replace(d, effects=tuple(EffectEntry.from_json(e) for e in effects))
    out = d.to_json()
    assert out["noise_floor"] is None and [e["score"] for e in out["effects"]] == [None, None]
    json.dumps(out, allow_nan=False)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda r: r.pop("mse"), "x.json: key 'mse' is missing (a number or null)"),
    (lambda r: r["captures"][0].pop("sha256"), "key 'captures[0].sha256' is missing"),
    (lambda r: r.update(mse="0.1"), "key 'mse' must be a number or null, got '0.1'"),
    (lambda r: r.update(evaluations=10.5), "key 'evaluations' must be an integer, got 10.5"),
    (lambda r: r.update(evaluations=True), "key 'evaluations' must be an integer, got True"),
    (lambda r: r["captures"][0].update(n="5001"), "key 'captures[0].n' must be an integer"),
    (lambda r: r["params"].update(KAVR=None), "key 'params.KAVR' must be a number, got None"),
    (lambda r: r.update(captures={}), "key 'captures' must be a list of an object"),
    (lambda r: r.update(failed="no"), "key 'failed' must be true or false or null"),
    (lambda r: r.update(extra=1), "unknown key(s) 'extra' in the file"),
    (lambda r: r["captures"][0].update(extra=1), "unknown key(s) 'captures[0].extra' in 'captures[0]'"),
    (lambda r: r.update(schema="bench-ctl/result/2"), "this bench-ctl reads result files of version 1, the file is "
                                                      "version 2"),
    (lambda r: r.update(schema="bench-ctl/diagnosis/1"), "expected 'bench-ctl/result/1' (not a result file)"),
])
def test_a_result_key_missing_or_wrong_is_named(edit, message):
    data = _result()
    edit(data)
    with pytest.raises(FormatError) as exc:
        IdentificationResult.from_json(data, "x.json")
    assert message in str(exc.value) and str(exc.value).startswith("x.json: ")


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["effects"][1].pop("score"), "key 'effects[1].score' is missing"),
    (lambda d: d["effects"][0].update(significant=1), "key 'effects[0].significant' must be true or false, got 1"),
    (lambda d: d["explained_by"][0].update(dropped="TD"), "key 'explained_by[0].dropped' must be a list of a string"),
    (lambda d: d["base"].pop("at_noise_floor"), "key 'base.at_noise_floor' is missing"),
    (lambda d: d.update(verdict=None), "key 'verdict' must be a string, got None"),
    (lambda d: d.update(schema="bench-ctl/diagnosis/0"), "the file is version 0"),
])
def test_a_diagnosis_key_missing_or_wrong_is_named(edit, message):
    data = _diagnosis()
    edit(data)
    with pytest.raises(FormatError, match=re.escape(message)):
        Diagnosis.from_json(data, "d.json")


def test_a_file_without_schema_is_read_as_version_1():
    old = {k: v for k, v in _result().items() if k != "schema"}
    r = IdentificationResult.from_json(old, "old.json")
    assert r.schema == "bench-ctl/result/1" and r.to_json() == _result()
    del old["history"]
    with pytest.raises(FormatError, match=r"old.json: key 'history' is missing .*no 'schema' key: read as "
                                          r"bench-ctl/result/1"):
        IdentificationResult.from_json(old, "old.json")
    d = {k: v for k, v in _diagnosis().items() if k != "schema"}
    assert Diagnosis.from_json(d).schema == "bench-ctl/diagnosis/1"
    with pytest.raises(FormatError, match="expected a JSON object, got list"):
        Diagnosis.from_json([1, 2], "d.json")


def test_read_names_the_file(tmp_path):
    path = tmp_path / "r.json"
    path.write_text(json.dumps(_result()), encoding="utf-8")
    assert read_result(path).mse == 1.2e-4
    path.write_text(json.dumps({**_result(), "mse": []}), encoding="utf-8")
    with pytest.raises(FormatError, match=f"{re.escape(str(path))}: key 'mse' must be a number or null"):
        read_result(path)
    dpath = tmp_path / "d.json"
    dpath.write_text(json.dumps(_diagnosis()), encoding="utf-8")
    assert read_diagnosis(dpath).verdict == "ceiling_limit"


def test_commands_refuse_a_bad_result_or_diagnosis_naming_the_key(tmp_path, capsys):
    """Exit code 2 and one line naming the file and the key, never a traceback."""
    bad = _result()
    del bad["captures"][0]["sha256"]
    res = tmp_path / "r.json"
    res.write_text(json.dumps(bad), encoding="utf-8")
    assert main(["report", str(res), "-o", str(tmp_path / "r.html")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and f"{res}: key 'captures[0].sha256' is missing" in err
    assert main(["export", str(res), "--dyr", str(tmp_path / "r.dyr")]) == 2
    assert "key 'captures[0].sha256' is missing" in capsys.readouterr().err
    good = tmp_path / "good.json"
    good.write_text(json.dumps(_result()), encoding="utf-8")
    diag = tmp_path / "d.json"
    diag.write_text(json.dumps({**_diagnosis(), "effects": [{"name": "dead_time"}]}), encoding="utf-8")
    assert main(["report", str(good), "--diagnosis", str(diag), "-o", str(tmp_path / "r2.html")]) == 2
    assert f"{diag}: key 'effects[0].params' is missing" in capsys.readouterr().err
    assert not (tmp_path / "r.html").exists() and not (tmp_path / "r2.html").exists()


# --- docs/formats.md describes the classes ---------------------------------------------------

def _table(section: str) -> dict[str, str]:
    """The key table of a section of docs/formats.md: each key named in a row's first cell -> the row."""
    text = (ROOT / "docs" / "formats.md").read_text(encoding="utf-8")
    body = text.split(f"## {section}", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in body.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 2 or not line.startswith("| `"):
            continue
        for key in re.findall(r"`([a-z_0-9]+)`", cells[0]):
            rows[key] = " | ".join(cells[1:])
    return rows


def _fields(cls) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)]


@pytest.mark.parametrize(("section", "cls", "nested"), [
    ("Result JSON", IdentificationResult, {"captures": CaptureEntry}),
    ("Diagnosis JSON", Diagnosis, {"base": BaseFit, "effects": EffectEntry, "explained_by": Step}),
])
def test_the_format_page_names_every_key_of_the_classes(section, cls, nested):
    rows = _table(section)
    assert list(rows) == _fields(cls)        # the same keys, in the order they are written
    for key in cls.OMITTED_WHEN_NONE:
        assert "optional" in rows[key], key
    for key in set(_fields(cls)) - set(cls.OMITTED_WHEN_NONE):
        assert not rows[key].startswith("optional"), key
    for key, inner in nested.items():
        named = set(re.findall(r"`([a-z_0-9]+)`", rows[key]))
        assert set(_fields(inner)) <= named, (key, set(_fields(inner)) - named)
        for opt in inner.OMITTED_WHEN_NONE:
            assert re.search(rf"`{opt}`[^|`]*optional", rows[key]), (key, opt)
