"""One dialect a user reads (issue 25 section 4): every surface of a standard structure speaks its
own IEEE 421.5 / PSS/E names; kernel names only under a `kernel` key; input refuses them."""
from __future__ import annotations

import json
import re

import pytest

from bench_ctl.cli import main
from bench_ctl.identification.result_file import IdentificationResult
from bench_ctl.model.dialect import dialect_of, kernel_sections
from bench_ctl.model.effects import EFFECTS, separating_test
from bench_ctl.model.structures import STRUCTURES, structure
from bench_ctl.units.overrides import apply_overrides, with_model
from bench_ctl.units.unit import UnitError, reference_unit, unit_from_dict
from records import model_json, result_json

STANDARD = [n for n in STRUCTURES if n != "REFERENCE"]

#: the column mapping and settings as they were written by hand before the blocks generated them
#: (the kernel calls must not change): standard name -> kernel parameter, and the settings
MAPPING = {
    "REFERENCE": ({"KAVR": "KAVR", "TA1": "TA1", "TA2": "TA2", "TA3": "TA3", "TA4": "TA4", "TE": "TE", "TR": "TR"},
                  {}),
    "SEXS": ({"K": "KAVR", "TA": "TA1", "TB": "TA2", "TE": "TE", "EMIN": "VRMIN", "EMAX": "VRMAX"},
             {"TA3": 1.0, "TA4": 1.0, "VRVT": 0.0, "KC": 0.0, "LIMOUT": 0.0, "TR": 0.0}),
    "EXST1": ({"TR": "TR", "TC": "TA1", "TB": "TA2", "KA": "KAVR", "TA": "TE", "VRMAX": "VRMAX",
               "VRMIN": "VRMIN", "KC": "KC", "KF": "KF", "TF": "TF"},
              {"TA3": 1.0, "TA4": 1.0, "VRVT": 1.0, "LIMOUT": 1.0}),
    "ESST1A": ({"TR": "TR", "TC": "TA1", "TB": "TA2", "TC1": "TA3", "TB1": "TA4", "KA": "KAVR", "TA": "TE",
                "VRMAX": "VRMAX", "VRMIN": "VRMIN", "KC": "KC", "KF": "KF", "TF": "TF"},
               {"VRVT": 1.0, "LIMOUT": 1.0}),
    "IEEEX1": ({"TR": "TR", "KA": "KAVR", "TA": "TE", "TB": "TA2", "TC": "TA1", "VRMAX": "VRMAX",
                "VRMIN": "VRMIN", "KE": "KE", "TE": "TEX", "KF": "KF", "TF1": "TF", "E1": "E1", "SE1": "SE1",
                "E2": "E2", "SE2": "SE2"},
               {"TA3": 1.0, "TA4": 1.0, "VRVT": 0.0, "KC": 0.0, "LIMOUT": 0.0}),
    "ESST4B": ({"TR": "TR", "KPR": "KPI", "KIR": "KII", "VRMAX": "VPMAX", "VRMIN": "VPMIN", "TA": "TE",
                "KPM": "KPM", "KIM": "KIM", "VMMAX": "VMMAX", "VMMIN": "VMMIN", "KG": "KG", "KP": "KPV",
                "VBMAX": "VBMAX", "KC": "KC"},
               {"KAVR": 1.0, "TA1": 1.0, "TA2": 1.0, "TA3": 1.0, "TA4": 1.0, "VRVT": 0.0, "LIMOUT": 1.0}),
    # added with its block (no hand-written mapping before it)
    "ESST5B": ({"TR": "TR", "KR": "KAVR", "T1": "TE", "KC": "KC", "VRMAX": "VRMAX", "VRMIN": "VRMIN",
                "TC1": "TA1", "TB1": "TA2", "TC2": "TA3", "TB2": "TA4"},
               {"VRIN": 1.0, "VRVT": 1.0, "LIMOUT": 0.0}),
    "EXAC1": ({"TR": "TR", "TB": "TA2", "TC": "TA1", "KA": "KAVR", "TA": "TE", "VRMAX": "VRMAX", "VRMIN": "VRMIN",
               "TE": "TEX", "KF": "KF", "TF": "TF", "KC": "KC", "KD": "KD", "KE": "KE", "E1": "E1", "SE1": "SE1",
               "E2": "E2", "SE2": "SE2"},
              {"TA3": 1.0, "TA4": 1.0, "VRVT": 0.0, "LIMOUT": 0.0, "ACEX": 1.0}),
    "ESAC1A": ({"TR": "TR", "TB": "TA2", "TC": "TA1", "KA": "KAVR", "TA": "TE", "VAMAX": "VRMAX", "VAMIN": "VRMIN",
                "TE": "TEX", "KF": "KF", "TF": "TF", "KC": "KC", "KD": "KD", "KE": "KE", "E1": "E1", "SE1": "SE1",
                "E2": "E2", "SE2": "SE2"},
               {"TA3": 1.0, "TA4": 1.0, "VRVT": 0.0, "LIMOUT": 0.0, "ACEX": 1.0}),
    "AC8B": ({"TR": "TR", "KPR": "KPI", "KIR": "KII", "KDR": "KDR", "TDR": "TDR", "VPIDMAX": "VPMAX",
              "VPIDMIN": "VPMIN", "KA": "KAVR", "TA": "TE", "VRMAX": "VRMAX", "VRMIN": "VRMIN", "TE": "TEX",
              "KE": "KE", "E1": "E1", "SE1": "SE1", "E2": "E2", "SE2": "SE2", "KC": "KC", "KD": "KD"},
             {"TA1": 1.0, "TA2": 1.0, "TA3": 1.0, "TA4": 1.0, "VRVT": 0.0, "LIMOUT": 0.0, "ACEX": 1.0}),
}


@pytest.mark.parametrize("name", list(STRUCTURES))
def test_blocks_generate_the_same_kernel_mapping_and_settings(name):
    st = structure(name)
    mapping, settings = MAPPING[name]
    assert {p.name: p.kernel for p in st.params if p.kernel} == mapping
    assert dict(st.settings) == settings
    # the diagram is the blocks', in their order, in the structure's names
    assert len(st.diagram) >= len(st.blocks)
    for line in st.diagram:
        assert not set(re.findall(r"[A-Za-z_]\w*", line)) & set(dialect_of(st).hidden_kernel_names()), line


def test_texts_translate_at_once_both_ways():
    x1 = dialect_of(structure("IEEEX1"))     # kernel TE is its TA, kernel TEX its TE: no chaining
    assert x1.text("TE <= TEX") == "TA <= TE" and x1.kernel_text("TA <= TE") == "TE <= TEX"
    st = dialect_of(structure("ESST1A"))
    assert st.text("TE <= TA4") == "TA <= TB1" and st.kernel_text("TA <= TB1") == "TE <= TA4"


@pytest.mark.parametrize("name", STANDARD)
def test_set_and_unit_files_refuse_kernel_names_naming_the_standard_one(name):
    st = structure(name)
    unit = with_model(reference_unit(), name)
    for kern in dialect_of(st).hidden_kernel_names():
        drivers = [p.name for p in st.params if p.kernel == kern]
        with pytest.raises(UnitError) as exc:
            apply_overrides(unit, [f"{kern}=1.0"])
        if drivers:
            assert f"calls it {drivers[0]}" in str(exc.value)
        with pytest.raises(UnitError) as exc:
            unit_from_dict({"avr": {"model": name}, "generator": {"Td0p": 7.5, "Td0pp": 0.05, "Vt0": 1.0},
                            "fixed": {kern: 1.0}}, "u.toml")
        assert "u.toml" in str(exc.value) and kern in str(exc.value)
        if drivers:
            assert drivers[0] in str(exc.value)
    # the standard names are accepted
    ident = st.default_identified()[0]
    b = unit.identify[st.kernel_name(ident)]
    assert apply_overrides(unit, [f"{ident}={b.value}", f"{ident}.max={b.max}"]).identify[st.kernel_name(ident)]


def test_a_unit_file_constraint_in_kernel_names_is_refused():
    with pytest.raises(UnitError, match="calls it TA"):
        unit_from_dict({"avr": {"model": "ESST1A"}, "generator": {"Td0p": 7.5, "Td0pp": 0.05, "Vt0": 1.0},
                        "constraints": ["TE <= TA4"]}, "u.toml")


def test_effects_carry_their_starts_variants_and_separating_tests():
    hints = {"top_level": 3.0, "bottom_level": -1.0, "delay_s": 0.02, "sat0": 0.05, "slope_up": 40.0,
             "slope_down": 30.0, "gain": 1.05}
    for e in EFFECTS.values():
        starts = e.starts(hints)
        assert starts, e.name
        for s in starts:
            assert set(s) == set(e.params)
            assert all(e.bounds[p][0] <= v <= e.bounds[p][1] for p, v in s.items())
    assert EFFECTS["dead_time"].starts(hints)[0] == {"TD": 0.02}
    assert [v.label for v in EFFECTS["ceiling_limit"].variants][0].startswith("bus-fed")
    assert separating_test("time_skew", "dead_time") == separating_test("dead_time", "time_skew")
    assert "second channel" in separating_test("time_skew", "dead_time")


def test_an_old_result_in_kernel_names_is_still_read():
    old = IdentificationResult.from_json(result_json(
        model=model_json(name="ESST1A"), params={"KAVR": 210.0, "TE": 0.03}, fixed={"TA1": 1.0},
        bounds={"KAVR": [20, 800], "TE": [0.002, 0.2]}))
    assert old.kernel_view()["params"] == {"KAVR": 210.0, "TE": 0.03}
    new = old.renamed(dialect_of(structure("ESST1A")))
    assert new.params == {"KA": 210.0, "TA": 0.03} and new.kernel is not None
    assert new.kernel_view()["params"] == {"KAVR": 210.0, "TE": 0.03}


def _words(text: str) -> set[str]:
    return set(re.findall(r"(?<![\w.-])[A-Za-z_][A-Za-z0-9_]*(?![\w-])", text))


def _without_kernel_key(x):
    if isinstance(x, dict):
        return {k: _without_kernel_key(v) for k, v in x.items() if k != "kernel"}
    if isinstance(x, list):
        return [_without_kernel_key(v) for v in x]
    return x


@pytest.mark.parametrize("name", STANDARD)
def test_no_kernel_name_on_any_surface_of_a_standard_structure(name, tmp_path, capsys):
    """Result JSON (params, bounds, fixed, constraints, identifiability, unit), the identify
    console table, the report's HTML and the .dyr comments: none names a kernel parameter that
    the structure calls otherwise."""
    st = structure(name)
    hidden = set(dialect_of(st).hidden_kernel_names())
    cap, res, html, dyr = (tmp_path / f for f in ("cap.csv", "r.json", "r.html", "u.dyr"))
    assert main(["simulate", "--model", name, "-o", str(cap), "--duration", "4", "--seed", "3"]) == 0
    capsys.readouterr()
    assert main(["identify", str(cap), "--model", name, "--evals", "60", "--json", str(res)]) in (0, 1)
    console = capsys.readouterr().out
    result = json.loads(res.read_text())
    assert "kernel" in result and set(result["kernel"]["params"]) <= set(hidden) | set(st.names)
    user = _without_kernel_key(result)
    for key in ("params", "bounds", "fixed", "constraints", "identifiability", "unit", "model", "optimizer"):
        seen = _words(json.dumps(user[key]))
        assert not seen & hidden, (key, seen & hidden)
    assert set(user["params"]) == set(st.default_identified())
    assert not _words(console) & hidden, _words(console) & hidden
    assert main(["report", str(res), "-o", str(html)]) in (0, 1)
    page = re.sub(r"<[^>]+>", " ", html.read_text(encoding="utf-8"))
    page = re.sub(r"data:image/[^\"' ]+", " ", page)
    assert not _words(page) & hidden, _words(page) & hidden
    if st.dyr_model:
        assert main(["export", str(res), "--dyr", str(dyr)]) == 0
        text = dyr.read_text()     # its comments say how each field was obtained
        assert not _words(text) & hidden, _words(text) & hidden


@pytest.mark.parametrize("name", list(STRUCTURES))
@pytest.mark.parametrize("effects", [{}, {"ceiling_limit": {"VRMAX": 2.5, "VRMIN": -1.0}, "dead_time": {"TD": 0.01}}])
def test_a_result_in_standard_names_reads_back_to_the_kernel_values_it_was_made_of(name, effects):
    """kernel -> standard at output, standard -> kernel at input: the same kernel values (the
    report re-simulates, export and diagnose --result read them)."""
    import math

    from bench_ctl.model.params import KERNEL_PARAMS, RECORD_PARAMS, neutral_values

    unit = with_model(reference_unit(), name).with_effects(effects)
    values = unit.values()
    none = lambda v: v if math.isfinite(v) else None  # noqa: E731
    kernel = IdentificationResult.from_json(result_json(
        model=model_json(name=name, params={k: none(v) for k, v in unit.standard_values().items()}),
        unit=unit.entry().to_json(),
        params={k: values[k] for k in unit.identify},
        fixed={k: none(v) for k, v in values.items() if k not in unit.identify and k not in RECORD_PARAMS},
        bounds={k: [b.min, b.max] for k, b in unit.identify.items()}))
    std = kernel.renamed(dialect_of(unit.structure)).to_json()
    back = kernel_sections(json.loads(json.dumps(std)))
    got = dict(neutral_values())
    for section in ("fixed", "params"):
        got.update({k: (neutral_values()[k] if v is None else v) for k, v in back[section].items()})
    for k in KERNEL_PARAMS:
        if k not in RECORD_PARAMS:
            assert got[k] == values[k], (k, got[k], values[k])
    if name != "REFERENCE":
        assert not set(std["fixed"]) & set(dialect_of(unit.structure).hidden_kernel_names())


@pytest.mark.parametrize("name", ["ESST1A", "IEEEX1", "ESST4B"])
def test_a_unit_file_in_the_structures_names_reads_and_writes_back_the_same(name):
    """The unit file is read in the structure's names and the record written of it (`Unit.entry`
    through the dialect) says the same names, bounds, values and constraints (IEEEX1: the kernel's
    TE is the standard TA, its TEX the standard TE, a swap that must not chain)."""
    st = structure(name)
    typical = {p.name: p.typical for p in st.params}
    ident = {n: {"value": typical[n], "min": st.param(n).bounds[0], "max": st.param(n).bounds[1]}
             for n in st.default_identified()}
    fixed = {p.name: p.typical for p in st.params if p.name not in ident and p.kernel is not None}
    data = {"avr": {"model": name}, "generator": {"Td0p": 7.5, "Td0pp": 0.05, "Vt0": 1.0},
            "identify": ident, "fixed": fixed, "constraints": list(st.constraints)}
    unit = unit_from_dict(data, "u.toml")
    assert not set(unit.identify) & (set(ident) - {st.kernel_name(n) for n in ident})   # kernel names inside
    written = dialect_of(st).unit(unit.entry())
    assert {k: (b.value, b.min, b.max) for k, b in written.identify.items()} == \
        {k: (b["value"], b["min"], b["max"]) for k, b in ident.items()}
    assert {k: written.fixed[k] for k in fixed} == fixed
    assert written.constraints == list(st.constraints)
    again = unit_from_dict({**data, "identify": {k: {"value": b.value, "min": b.min, "max": b.max}
                                                 for k, b in written.identify.items()},
                            "fixed": {k: written.fixed[k] for k in fixed}}, "again.toml")
    assert again.identify == unit.identify and again.fixed == unit.fixed


def test_set_reads_the_structures_names_and_its_messages_say_what_was_typed():
    """`--set` on an IEEEX1 unit: TE is the standard exciter constant (the kernel's TEX), TA the
    regulator's lag (the kernel's TE), TB a fixed lag (the kernel's TA2); a refusal names the name
    the user typed and lists the identified ones as the structure calls them, never the kernel's."""
    unit = with_model(reference_unit(), "IEEEX1")
    st = unit.structure
    assert [st.kernel_name(n) for n in ("TE", "TA", "TB")] == ["TEX", "TE", "TA2"]
    assert {"TEX", "TE"} <= set(unit.identify) and "TA2" in unit.fixed
    set_ = apply_overrides(unit, ["TE=0.9", "TA.max=0.5", "TB=2"])
    assert set_.identify["TEX"].value == 0.9 and set_.identify["TE"].max == 0.5 and set_.fixed["TA2"] == 2.0
    assert set_.standard_values()["TE"] == 0.9 and set_.standard_values()["TB"] == 2.0
    with pytest.raises(UnitError) as exc:
        apply_overrides(unit, ["TB.max=2"])
    assert "'TB' is not an identified parameter" in str(exc.value)
    assert f"(identified: {', '.join(st.std_name(k) for k in unit.identify)})" in str(exc.value)
    assert "TA2" not in str(exc.value) and "TEX" not in str(exc.value)
    with pytest.raises(UnitError) as exc:
        apply_overrides(unit, ["TB=-1"])
    assert "TB" in str(exc.value) and "TA2" not in str(exc.value)


def test_a_note_says_its_names_and_leaves_its_prose():
    """A `Note` translates only the names it carries (IEEEX1: kernel TE is TA, TEX is TE, no
    chaining); its prose, even where it holds a kernel name, and a note without names stay as
    they are; the reference structure says the kernel's text."""
    from bench_ctl.model.dialect import Note

    x1 = dialect_of(structure("IEEEX1"))
    note = Note("{} and {} trade places; constraint {} (TE is prose here)", "TE", "TEX", "TE <= TEX")
    assert note == "TE and TEX trade places; constraint TE <= TEX (TE is prose here)"   # the kernel's
    assert x1.say(note) == "TA and TE trade places; constraint TA <= TE (TE is prose here)"
    assert x1.say(Note("exchangeable ({}) here", Note("lag TA <-> TE"))) == "exchangeable (lag TA <-> TE) here"
    assert x1.deep({"swap": Note("lag TA <-> TE"), "k": "TEX"}) == {"swap": "lag TA <-> TE", "k": "TE"}
    assert dialect_of(structure("REFERENCE")).say(note) == str(note)
    import pickle
    again = pickle.loads(pickle.dumps(note))
    assert x1.say(again) == x1.say(note)


def test_model_auto_applies_the_overrides_a_structure_names_and_says_the_others():
    """`--model auto`'s --set parse: IEEEX1 takes its TE (the kernel's TEX), a weight and the
    generator's constants, not the kernel's KAVR (its KA); the reference takes KAVR, not SEXS's K."""
    from bench_ctl.units.overrides import apply_own_overrides

    x1 = with_model(reference_unit(), "IEEEX1")
    u, lacking = apply_own_overrides(x1, ["TE=0.9", "KAVR=200", "weights.vt=0.5", "Td0p=6.0"])
    assert lacking == ["KAVR=200"]
    te = u.identify["TEX"].value if "TEX" in u.identify else u.fixed["TEX"]
    assert te == 0.9 and u.weights["vt"] == 0.5 and u.generator["Td0p"] == 6.0
    r, lacking = apply_own_overrides(reference_unit(), ["KAVR=200", "K.max=900"])
    assert lacking == ["K.max=900"] and r.identify["KAVR"].value == 200
    with pytest.raises(UnitError, match="not a number"):       # one it takes is still checked
        apply_own_overrides(x1, ["TE=abc"])


def test_a_result_describes_a_parameter_in_its_structures_names():
    """The report's parameter table: IEEEX1's TE is its exciter time constant (the kernel's TEX),
    not the kernel's TE (its TA); a structure this version lacks reads the kernel's."""
    from bench_ctl.model.params import PARAMS
    from records import result_of

    te = structure("IEEEX1").param("TE")
    x1 = result_of(model=model_json(name="IEEEX1"))
    assert x1.describe("TE") == (te.unit, te.info, None) and te.info != PARAMS["TE"].info
    assert x1.describe("NOPE") is None
    other = result_of(model=model_json(name="NO_SUCH_MODEL"))
    assert other.describe("TE") == (PARAMS["TE"].unit, PARAMS["TE"].info, PARAMS["TE"].neutral)


def test_a_refused_problem_says_its_names_in_the_structures_and_its_capture_path_as_it_is(tmp_path, capsys):
    """A refusal of the problem is a `Note`: the names it carries are said in the structure's, its
    prose is not. A capture under a folder named TE (IEEEX1 calls the kernel's TE its TA) keeps
    its path in the message of `identify` and `diagnose` (a regex over the whole message once
    said .../TA/cap.csv, a file that does not exist)."""
    folder = tmp_path / "TE"
    folder.mkdir()
    cap = folder / "cap.csv"
    assert main(["simulate", "--online", "-o", str(cap), "--duration", "3", "--seed", "3"]) == 0
    unit = tmp_path / "x1.toml"      # no [grid]: an on-line record is refused naming the capture
    unit.write_text('[avr]\nmodel = "IEEEX1"\n[generator]\nTd0p = 7.5\nTd0pp = 0.05\nVt0 = 1.0\n')
    capsys.readouterr()
    for argv in (["identify", str(cap), "--unit", str(unit), "--evals", "64", "--no-progress"],
                 ["diagnose", str(cap), "--unit", str(unit)]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert f"{cap} is an on-line record" in err, (argv, err)


def test_a_candidates_inert_parameters_are_written_in_its_structures_names():
    """`--model auto` scores in the kernel's names; the candidate's entry says its inert ones in
    its structure's (SEXS's EMAX is the kernel's VRMAX)."""
    from types import SimpleNamespace as Fit

    from bench_ctl.identification.selection import Candidate, Selection

    unit = with_model(reference_unit(), "SEXS")
    result = Fit(params={"K": 200.0}, captures=(), constraints_violated=[], failed=False)
    ident = Fit(result=result, best=Fit(x=None), problem=Fit(unit=unit, values=lambda x: unit.values()))
    sel = Selection((Candidate("SEXS", ident, 4, 100, 1e-4, (), 1.0, 0.0, 0.1, inert=("VRMAX", "TE")),), 1e-4, 0.1, ())
    assert sel.entry().candidates[0].inert == ["EMAX", "TE"]


def test_the_dialect_is_taken_at_five_boundaries_at_most():
    """Issue 50: the dialect is applied where an input is parsed or a record written, not along
    the way: calls of `dialect_of` / `Dialect` outside bench_ctl/model/dialect.py stay at most 5
    (the unit's input, the one writer, a result read back, the .dyr export), and none under an
    alias."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    sites, aliases = [], []
    for path in sorted((root / "bench_ctl").rglob("*.py")):
        if path == root / "bench_ctl" / "model" / "dialect.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            where = f"{path.relative_to(root)}:{getattr(node, 'lineno', 0)}"
            if isinstance(node, ast.Call):
                f = node.func
                name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
                if name in ("dialect_of", "Dialect", "_dialect"):
                    sites.append(where)
            elif isinstance(node, ast.ImportFrom) and (node.module or "").endswith("dialect"):
                aliases += [where for a in node.names if a.asname and a.name in ("dialect_of", "Dialect")]
    assert len(sites) <= 5, sites
    assert not aliases, aliases
