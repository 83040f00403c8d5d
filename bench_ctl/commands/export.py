"""`bench-ctl export RESULT.json --dyr OUT.dyr [--bus N] [--id ID]`: the identified model as the
PSS/E dynamic data record the grid operator loads.

The record holds every field of the structure's PSS/E model in the standard order: identified
values, the unit's fixed values, and for fields bench-ctl does not simulate (input limiter,
field current limiter, ...) the unit's value or the library's default; a comment above the
record says which is which, and where the result came from. An existing file is never
overwritten without --force, never an input. The REFERENCE structure is written as ESST1A (the
same blocks). A limit the model leaves open is written as +-999 on its own side (what ANDES uses
for no limit; `--from-dyr` reads it back as open), every value in full precision, so that
`--from-dyr` on the export simulates what the result does. What the model has and the record
cannot hold (a dead time, a rate limit, ...) is named on the console and in the record's
comment. A unit with a power system stabiliser (its [grid] PSS_KS > 0, given or fitted on line)
gets its IEEEST record after the exciter's, at the same bus and ID; a unit whose PSS_MODEL is PSS2A
or PSS2B (PSS2_KS1 > 0) gets that record, in PSS/E's field order (`dyr_pss2`). The bus must be a PSS/E bus
number (1 .. 999997) and the ID one or two characters that read back the same (no blank, quote or
`/`, not empty): anything else is refused, as PSS/E would not read it. Exit codes: 0 written, 2 bad
input (file, key or value named) or an output refused.
"""
from __future__ import annotations

import math

import click

from bench_ctl.exitcodes import ExitCode

NO_LIMIT = 999.0


@click.command("export")
@click.argument("result_path", metavar="RESULT.json", type=click.Path(dir_okay=False))
@click.option("--dyr", "dyr_out", required=True, type=click.Path(dir_okay=False),
              help="PSS/E .dyr file to write (an existing one only with --force, never an input).")
@click.option("--bus", type=int, default=1, show_default=True, help="Bus number of the record (1 .. 999997).")
@click.option("--id", "machine_id", default="1", show_default=True,
              help="Machine ID of the record: one or two characters, no blank, quote or /.")
@click.option("--force", is_flag=True, help="Replace an existing .dyr (never an input).")
def export(result_path: str, dyr_out: str, bus: int, machine_id: str, force: bool = False) -> int:
    """Write the identified model of RESULT.json as a PSS/E dynamic data record."""
    from bench_ctl import outputs
    from bench_ctl.identification.result_file import read_result
    from bench_ctl.model.structures import StructureError
    from bench_ctl.units.dyr import DyrError, DyrRecord, check_bus_id, dyr_text
    from bench_ctl.units.dyr_export import dyr_fields, dyr_values_of, not_carried, pss_record

    try:   # what PSS/E reads back the same: refused before anything is read or written
        check_bus_id(bus, str(machine_id))
    except DyrError as exc:
        raise DyrError(f"--bus {bus} --id {machine_id!r}: {exc}") from None
    out = outputs.guard_outputs({"--dyr": dyr_out}, [result_path], force=force)
    result = read_result(result_path)
    try:   # a result that reads well but holds no record this structure can write
        st, std = dyr_values_of(result.to_json())
        fields = dyr_fields(st)
        values = st.dyr_values(std, fields)
        for k, v in values.items():
            if not math.isfinite(v):
                raise DyrError(f"field {k} = {v} is not finite")
        missing = not_carried(result.kernel_view(), st, std)
        pss = pss_record(result.unit.grid or {}, bus, str(machine_id))
    except (StructureError, DyrError) as exc:
        raise DyrError(f"{result_path}: {exc}") from None
    model = result.model
    identified = set(model.identified if model else ())
    if st.name == "ESST1A" and model is not None and model.name == "REFERENCE":
        identified = {st.std_name(k) for k in result.params} - {None}
    typical = st.typical()
    notes = []
    for f in fields:
        names = [f] if f in st.names else [n for n in ("TA", "TB") if f == "TA/TB"]
        if any(n in identified for n in names):
            how = "identified"
        elif all(n in typical and std.get(n) == typical[n] for n in names):
            how = "bench-ctl library default"
        elif any(abs(std.get(n, 0.0)) == NO_LIMIT for n in names):
            how = "no limit (open in the model)"
        else:
            how = "fixed (unit)"
        notes.append(f"{f} = {values[f]:.6G}: {how}")
    if missing:
        notes.append("NOT IN THIS RECORD (the model has them, the record cannot hold them): " + "; ".join(missing))
    header = (f"bench-ctl export of {result_path} (model {model.name if model else st.name} as PSS/E {st.dyr_model})\n"
              f"command: {result.command_line}\n"
              f"fit: mse {result.mse} pu^2 over {len(result.captures)} capture(s)")
    icons = {"UEL": 1, "VOS": 1} if st.dyr_model == "ESST1A" else {}
    rec = DyrRecord(bus, st.dyr_model, str(machine_id), values, icons)  # type: ignore[arg-type]
    records = [(rec, "\n".join(notes))]
    if pss is not None and pss.model == "IEEEST":
        records.append((pss, "the unit's power system stabiliser ([grid] PSS_*): speed input, no filter, "
                             "washout T5 = T6 = PSS_TW, no cut-off"))
    elif pss is not None:
        records.append((pss, f"the unit's power system stabiliser ([grid] PSS_MODEL {pss.model}, PSS2_*): input 1 "
                             "the speed (ICS1 1), input 2 the electrical power (ICS2 3), no remote bus; an open "
                             "input limit written as +-999"))
    with outputs.writing(dyr_out):
        out.write_text(dyr_out, dyr_text(records, header=header))
    click.echo(f"wrote {dyr_out}: {st.dyr_model} at bus {bus}, ID {machine_id} "
               f"({len(identified)} identified, {len(fields) - len(identified)} fixed or default)"
               + (f", and its stabiliser as {pss.model} (KS{'' if pss.model == 'IEEEST' else '1'} "
                  f"{pss.values.get('KS', pss.values.get('KS1')):g})" if pss is not None else ""))
    if missing:
        click.echo(f"warning: the {st.dyr_model} record does not hold: {'; '.join(missing)}; a simulation "
                   "from it differs from the result where these act", err=True)
    return ExitCode.OK
