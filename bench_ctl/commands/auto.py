"""`--model auto` of `identify` and `diagnose`: the options' unit handed to the candidates
(`bench_ctl.identification.candidates`), and the ranking as the console prints it
(`bench_ctl.identification.selection` ranks; docs/decisions/0016)."""
from __future__ import annotations

from bench_ctl.identification.candidates import candidate_units
from bench_ctl.identification.result_file import SelectionEntry
from bench_ctl.identification.selection import separation_text, where_left
from bench_ctl.units.unit import Unit

from .options import fmt_value as _fmt
from .options import resolve_unit

#: --model auto: every structure of the library identified, checked and ranked
AUTO = "auto"


def is_auto(model: str | None) -> bool:
    return model is not None and model.strip().lower() == AUTO


def auto_units(unit_path: str | None, overrides: tuple[str, ...], model_kw: dict
               ) -> tuple[dict[str, Unit], list[str]]:
    """--model auto: the unit the options name (`resolve_unit`, without --model) in every structure
    of the library (`candidates.candidate_units`: a --from-dyr record's or unit file's own
    structure at its values, the others with their limits fitted too). Returns the units and the
    notes on the --set overrides."""
    base = resolve_unit(unit_path, (), **{**model_kw, "model": None})
    return candidate_units(base, overrides, given_model=(model_kw.get("from_dyr") or unit_path) is not None)


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
