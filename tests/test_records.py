"""The typed result and diagnosis (docs/formats.md): every key checked on reading and named when
wrong, the schema version, the same JSON written back, and the format page kept current."""
from __future__ import annotations

import dataclasses
import json
import re
import typing
from pathlib import Path

import pytest

from bench_ctl.cli import main
from bench_ctl.diagnosis.diagnosis_file import BaseFit, Diagnosis, EffectEntry, Step, read_diagnosis
from bench_ctl.identification.result_file import CaptureEntry, IdentificationResult, read_result
from bench_ctl.records import FormatError, Record, plain
from records import (
    assert_round_trip,
    diagnosis_json,
    edge_json,
    effect_json,
    ident_json,
    model_json,
    result_json,
    step_json,
)

ROOT = Path(__file__).resolve().parents[1]

CAPTURE = {"path": "pulse.csv", "sha256": "ab" * 32, "n": 5001, "rate_hz": 1000.0, "meta": {"test": {"kind": "pulse"}},
           "mse": 1.2e-4, "objective": 0.6, "weight": 1.0,
           "edges": [edge_json(fitted_s=0.9995, offset_s=-0.0005, fitted=True)]}


def _result() -> dict:
    return result_json(captures=[json.loads(json.dumps(CAPTURE))], params={"KAVR": 201.5, "TA1": 1},
                       fixed={"VRMAX": None, "Td0p": 7.5},
                       bounds={"KAVR": [50, 500]}, mse=1.2e-4, objective=0.6, evaluations=1000,
                       history=[[32, None], [64, 0.7]],
                       identifiability=ident_json(["KAVR"], std={"KAVR": 1.5}),
                       failed=False, message="", model=model_json())


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
    """The keys of `cls` (its fields but those held in memory only)."""
    return [f.name for f in dataclasses.fields(cls) if f.name not in cls.IN_MEMORY]


def _nested(cls: type) -> dict[str, list[type]]:
    """Each key of `cls` that holds records -> the record classes it holds, its own nested ones
    included (read from the annotations: every typed part of a file is named in its key's row)."""
    hints = typing.get_type_hints(cls)

    def records(tp: object) -> list[type]:
        if isinstance(tp, type) and issubclass(tp, Record):
            return [tp] + [r for f in dataclasses.fields(tp) for r in records(typing.get_type_hints(tp)[f.name])]
        return [r for arg in typing.get_args(tp) for r in records(arg)]
    return {f.name: found for f in dataclasses.fields(cls) if (found := records(hints[f.name]))}


@pytest.mark.parametrize(("section", "cls"), [("Result JSON", IdentificationResult), ("Diagnosis JSON", Diagnosis)])
def test_the_format_page_names_every_key_of_the_classes(section, cls):
    rows = _table(section)
    assert list(rows) == _fields(cls)        # the same keys, in the order they are written
    for key in cls.OMITTED_WHEN_NONE:
        assert "optional" in rows[key], key
    for key in set(_fields(cls)) - set(cls.OMITTED_WHEN_NONE):
        assert not rows[key].startswith("optional"), key
    nested = _nested(cls)
    assert {"captures", "unit", "identifiability", "model", "selection"} <= set(nested) or cls is Diagnosis
    for key, inner_classes in nested.items():
        if key in ("unit", "selection") and cls is Diagnosis:   # "as in a result", named there
            continue
        named = set(re.findall(r"`([a-z_0-9]+)`", rows[key]))
        for inner in inner_classes:
            assert set(_fields(inner)) <= named, (key, inner.__name__, set(_fields(inner)) - named)
            for opt in inner.OMITTED_WHEN_NONE:
                assert re.search(rf"`{opt}`[^|`]*optional", rows[key]), (key, inner.__name__, opt)


# --- the files bench-ctl writes read back the same ---------------------------------------------

#: result and diagnosis files as `identify` / `diagnose` wrote them, one of each shape: the reference
#: structure, a standard one (its `kernel` key) with `--compare`, two captures, on line (a [grid]
#: value fitted), `--model auto` (`selection`), a holdout, `diagnose --result`
STORED = sorted((ROOT / "tests" / "fixtures" / "records").glob("*.json"))


@pytest.mark.parametrize("path", STORED, ids=lambda p: p.name)
def test_every_stored_file_reads_back_the_same(path):
    """Read into its typed record (every nested part typed: unit, identifiability, model,
    selection, the diagnosis' check, localization, ...), written again: the same JSON, key order
    included."""
    assert_round_trip(path)


def test_the_stored_files_cover_each_shape():
    names = {p.name for p in STORED}
    assert {"result_reference.json", "result_esst1a_compare.json", "result_auto.json", "result_online.json",
            "diagnosis_reference_holdout.json", "diagnosis_esst1a.json", "diagnosis_auto.json",
            "diagnosis_online.json"} <= names
    shapes = {p.name: json.loads(p.read_text(encoding="utf-8")) for p in STORED}
    assert "kernel" in shapes["result_esst1a_compare.json"] and "comparison" in shapes["result_esst1a_compare.json"]
    assert "selection" in shapes["result_auto.json"] and "selection" in shapes["diagnosis_auto.json"]
    assert shapes["result_online.json"]["unit"]["grid_identify"]
    assert shapes["diagnosis_reference_holdout.json"]["holdout"] is not None


def test_no_result_or_diagnosis_record_holds_an_untyped_object():
    """No `dict[str, Any]` (or `Any`) field in the result's and the diagnosis' records: every part
    is a record or a table of numbers, texts or flags; a capture's sidecar and an optimizer's
    settings, copied as they are, are `JSON`."""
    seen, todo, loose = set(), [IdentificationResult, Diagnosis], []
    while todo:
        cls = todo.pop()
        if cls in seen:
            continue
        seen.add(cls)
        for name, tp in typing.get_type_hints(cls).items():
            if name == "OMITTED_WHEN_NONE":
                continue
            text = repr(tp)
            if "typing.Any" in text:
                loose.append(f"{cls.__name__}.{name}: {text}")
            todo += [t for t in _records_in(tp)]
    assert loose == []
    assert len(seen) >= 30, sorted(c.__name__ for c in seen)


def _records_in(tp: object) -> list[type]:
    if isinstance(tp, type) and issubclass(tp, Record):
        return [tp]
    return [r for arg in typing.get_args(tp) for r in _records_in(arg)]
