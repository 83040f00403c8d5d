"""`--model auto` of `identify` and `diagnose`: the unit in every structure of the library, and the
ranking as the console prints it (bench_ctl.diagnosis.selection ranks; docs/decisions/0016)."""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from bench_ctl.capture import Capture
from bench_ctl.diagnosis.selection import Selection, free_limits, select_structure, separation_text, where_left
from bench_ctl.exitcodes import BadInput
from bench_ctl.identification.result_file import SelectionEntry
from bench_ctl.model.structures import DEFAULT as DEFAULT_MODEL
from bench_ctl.model.structures import STRUCTURES
from bench_ctl.units.overrides import apply_overrides, apply_own_overrides, with_model
from bench_ctl.units.unit import Unit

from .options import fmt_value as _fmt
from .options import resolve_unit

#: --model auto: every structure of the library identified, checked and ranked
AUTO = "auto"


def is_auto(model: str | None) -> bool:
    return model is not None and model.strip().lower() == AUTO


def auto_units(unit_path: str | None, overrides: tuple[str, ...], model_kw: dict
               ) -> tuple[dict[str, Unit], list[str]]:
    """--model auto: the unit in every structure of the library (a --from-dyr record's or unit
    file's own structure at its values, the others at their typical values with their limits
    fitted too: `selection.free_limits`; all on its generator), each with the --set overrides it
    has. Returns the units and a note per override a structure lacks; an
    override no structure takes is an error (UnitError)."""
    base = resolve_unit(unit_path, (), **{**model_kw, "model": None})
    given = {item.split("=", 1)[0].split(".", 1)[0].strip() for item in overrides}
    units: dict[str, Unit] = {}
    skipped: dict[str, list[str]] = {}
    for name in auto_models(base.model):
        u, lacking = apply_own_overrides(with_model(base, name), overrides)
        for item in lacking:
            skipped.setdefault(item, []).append(name)
        # the limits of the structure a unit file or planning record gives stay as given, as do
        # those --set names; the typical values of the others are only a start: fitted
        given_model = u.model == base.model and (model_kw.get("from_dyr") or unit_path) is not None
        units[name] = u if given_model else free_limits(u, keep=sorted(given))
    for item, names in skipped.items():
        if len(names) == len(units):   # no structure has it: the reference structure says why
            apply_overrides(with_model(base, DEFAULT_MODEL), [item])
    notes = [f"--set {item} not applied to {', '.join(names)} (not a parameter of theirs)"
             for item, names in skipped.items()]
    notes += twin_notes(list(units))
    return units, notes


def auto_models(given: str | None = None) -> list[str]:
    """The structures --model auto fits: the library, less one of each pair of pulse twins (the
    same equations on a pulse test, `Structure.pulse_twin`): the one that names its twin is left
    out, unless it is the unit's own (`given`)."""
    out = []
    for name, st in STRUCTURES.items():
        twin = st.pulse_twin
        if twin is not None and name != given:
            continue
        if any(o.pulse_twin == name and o.name == given for o in STRUCTURES.values()):
            continue
        out.append(name)
    return out


def twin_notes(fitted: Sequence[str]) -> list[str]:
    """What each fitted structure stands for beside itself (its pulse twins left out)."""
    out = []
    for name in fitted:
        st = STRUCTURES[name]
        pairs = [o.name for o in STRUCTURES.values() if o.pulse_twin == name and o.name not in fitted]
        if st.pulse_twin is not None and st.pulse_twin not in fitted:
            pairs.append(st.pulse_twin)
        for other in pairs:
            out.append(f"{name} stands for {other} too: on a pulse test they are the same equations, "
                       "their limits under other names (not fitted apart)")
    return out


def selection_summary(sel: SelectionEntry) -> str:
    """The ranking table of --model auto."""
    head = f"{'rank':<5}{'model':<11}{'k':>3}{'fit x floor':>13}{'check x floor':>15}{'score':>11}  note"
    lines = ["", f"structure selection ({len(sel.candidates)} candidates; score: BIC + the check's "
             "deviance, relative to the first)", head, "-" * len(head)]
    for c in sel.candidates:
        note = "fits as well (more parameters)" if c.equivalent else (c.error or "")
        if c.constraints_violated:
            note = "constraint violated: " + ", ".join(c.constraints_violated)
        if c.inert:
            note = "; ".join(filter(None, [note, f"not counted in k (moves nothing here): {', '.join(c.inert)}"]))
        if c.searches > 1:
            note = "; ".join(filter(None, [note, "searched twice (its first search ended on its bounds)"]))
        lines.append(f"{c.rank:<5}{c.model:<11}{c.k:>3}{_fmt(c.x_floor, '.3g'):>13}"
                     f"{_fmt(c.check_x_floor, '.3g'):>15}{_fmt(c.score_difference, '+.1f'):>11}  {note}")
    best = sel.candidates[0]
    if sel.verdict == "explains":
        lines.append(f"{sel.chosen} explains the record: its fit is at the noise floor "
                     f"({_fmt(best.x_floor, '.3g')}x)")
    elif sel.verdict == "closest":
        lines.append(f"{sel.chosen} fits best but leaves {_fmt(best.x_floor, '.3g')}x the noise floor: "
                     "no structure of the library explains the record (try `bench-ctl diagnose`)")
        lines += where_left(sel)
    else:
        lines.append("no structure could be fitted")
    if sel.equivalent:
        lines.append(f"as good on this record: {', '.join(sel.equivalent)} (more or as many parameters)")
    sep = separation_text(sel)
    if sep:
        lines.append(sep)
    for note in sel.notes:
        lines.append(f"note: {note}")
    return "\n".join(lines)



class NoStructureFitted(BadInput):
    """Every candidate failed; the message names each one's error."""


def rank_structures(captures: Sequence[Capture], units: Mapping[str, Unit], notes: Sequence[str], *,
                    seed: int, command_line: str, max_evals: int = 1000,
                    progress: Callable[[str, Any], None] | None = None) -> tuple[Selection, SelectionEntry]:
    """The selection of `identify` / `diagnose --model auto` and its record with the `--set` notes.
    Raises NoStructureFitted when no candidate could be fitted, DiagnosisError for a capture the
    check cannot use."""
    sel = select_structure(captures, units, max_evals=max_evals, seed=seed, command_line=command_line,
                           progress=progress)
    if sel.best.ident is None:
        raise NoStructureFitted("no structure could be fitted: " + "; ".join(
            f"{c.model}: {c.error}" for c in sel.candidates))
    return sel, sel.entry(notes)
