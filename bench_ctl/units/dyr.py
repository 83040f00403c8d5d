"""PSS/E dynamic data records (.dyr): read and write the records bench-ctl knows.

A record is `BUS 'MODEL' ID [ICONs] CONs /`, whitespace-separated over one or more lines; text after
the `/` is a comment, as are lines starting with `//` or `@!`. Field orders (PSS/E model library,
cross-checked with ANDES' andes/io/psse-dyr.yaml, the InterPSS reader and published .dyr files):

- GENROU: T'do T''do T'qo T''qo H D Xd Xq X'd X'q X''d Xl S(1.0) S(1.2)
- GENSAL: T'do T''do T''qo H D Xd Xq X'd X''d Xl S(1.0) S(1.2)
- SEXS:   TA/TB TB K TE EMIN EMAX
- EXST1:  TR VIMAX VIMIN TC TB KA TA VRMAX VRMIN KC KF TF
- ESST1A: ICONs UEL VOS; TR VIMAX VIMIN TC TB TC1 TB1 KA TA VAMAX VAMIN VRMAX VRMIN KC KF TF KLR ILR
  (ANDES 2.0's psse-dyr.yaml lists TB before TC and KLR, ILR, KC elsewhere: it misreads ESST1A)
- IEEEX1: TR KA TA TB TC VRMAX VRMIN KE TE KF TF1 SWITCH E1 SE(E1) E2 SE(E2)
- ESDC1A: the same fields (PSS/E's IEEE 421.5 DC1A; `--from-dyr` reads it as IEEEX1: the same
  equations, said on the console)
- IEEET1: TR KA TA VRMAX VRMIN KE TE KF TF SWITCH E1 SE(E1) E2 SE(E2) (the IEEE 1968 type 1 without
  the lead-lag; `--from-dyr` reads it as IEEEX1 with TB = TC = 0, said on the console)
- ESST4B: TR KPR KIR VRMAX VRMIN TA KPM KIM VMMAX VMMIN KG KP KI VBMAX KC XL THETAP
- ESST5B: TR KR T1 KC VRMAX VRMIN TC1 TB1 TC2 TB2 TOC1 TOB1 TOC2 TOB2 TUC1 TUB1 TUC2 TUB2
  (IEEE 421.5 lists the under-excitation channel first; PSS/E's record and the InterPSS reader
  put the over-excitation one first)
- ESAC1A: TR TB TC KA TA VAMAX VAMIN TE KF TF KC KD KE E1 SE(E1) E2 SE(E2) VRMAX VRMIN
  (ANDES 2.0's psse-dyr.yaml puts VAMAX VAMIN before KA and VRMAX VRMIN before TE: it misreads
  ESAC1A records as PSS/E writes them)
- ESAC8B: TR KPR KIR KDR TDR KA TA VRMAX VRMIN TE KE E1 SE(E1) E2 SE(E2) (15 fields: no KC, KD,
  no PID limits; ANDES reads its own AC8B record instead, 21 fields)
- IEEEST: ICONs MODE BUSR; A1 A2 A3 A4 A5 A6 T1 T2 T3 T4 T5 T6 KS LSMAX LSMIN VCU VCL (the IEEE ST
  stabiliser: MODE 1 the rotor speed deviation; filter (1 + A5 s + A6 s^2)/((1 + A1 s + A2 s^2)
  (1 + A3 s + A4 s^2)), two lead-lags, KS, washout T5 s/(1 + T6 s), output limits, cut-off by Vt)
- PSS2A:  ICONs ICS1 IB1 ICS2 IB2 M N; TW1 TW2 T6 TW3 TW4 T7 KS2 KS3 T8 T9 KS1 T1 T2 T3 T4 VSTMAX VSTMIN
- PSS2B:  the same ICONs; TW1 .. T4 as PSS2A, then T10 T11 VS1MAX VS1MIN VS2MAX VS2MIN VSTMAX VSTMIN
  (ICS the input's code, 1 the rotor speed deviation, 3 the electrical power; IB a remote bus, 0
  the machine's own; M N the ramp-tracking filter's orders. Confirmed in docs/decisions/0024.)

Records of other models are kept with positional names (CON1..), never refused here: real files
hold hundreds of governors and stabilisers (`--from-dyr` names those of the unit it leaves out:
`dyr_kinds`). The bus is a PSS/E bus number (1 .. 999997) and the machine ID one or two
characters (letters, digits, `_ & * # . + -`); a quoted ID is read without its padding blanks
(`'1 '` is machine 1, as PSS/E reads it); an ID that cannot be written so that it reads back the
same (empty, a blank, a quote, a `/` that ends a record, more than two characters) is refused.
Written by hand (no maintained PyPI reader of .dyr files exists; ANDES' reader builds an ANDES
system, it is a benchmark extra): docs/decisions/0009.
"""
from __future__ import annotations

import math
import os
import re
from collections.abc import Collection, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from bench_ctl.exitcodes import BadInput

#: PSS2A's and PSS2B's CONs up to the second lead-lag (the same in both records)
_PSS2 = ("TW1", "TW2", "T6", "TW3", "TW4", "T7", "KS2", "KS3", "T8", "T9", "KS1", "T1", "T2", "T3", "T4")
FIELDS: dict[str, tuple[str, ...]] = {
    "GENROU": ("T'do", "T''do", "T'qo", "T''qo", "H", "D", "Xd", "Xq", "X'd", "X'q", "X''d", "Xl",
               "S(1.0)", "S(1.2)"),
    "GENSAL": ("T'do", "T''do", "T''qo", "H", "D", "Xd", "Xq", "X'd", "X''d", "Xl", "S(1.0)", "S(1.2)"),
    "SEXS": ("TA/TB", "TB", "K", "TE", "EMIN", "EMAX"),
    "EXST1": ("TR", "VIMAX", "VIMIN", "TC", "TB", "KA", "TA", "VRMAX", "VRMIN", "KC", "KF", "TF"),
    "ESST1A": ("TR", "VIMAX", "VIMIN", "TC", "TB", "TC1", "TB1", "KA", "TA", "VAMAX", "VAMIN", "VRMAX",
               "VRMIN", "KC", "KF", "TF", "KLR", "ILR"),
    "IEEEX1": ("TR", "KA", "TA", "TB", "TC", "VRMAX", "VRMIN", "KE", "TE", "KF", "TF1", "SWITCH", "E1",
               "SE1", "E2", "SE2"),
    "ESDC1A": ("TR", "KA", "TA", "TB", "TC", "VRMAX", "VRMIN", "KE", "TE", "KF", "TF1", "SWITCH", "E1",
               "SE1", "E2", "SE2"),
    "IEEET1": ("TR", "KA", "TA", "VRMAX", "VRMIN", "KE", "TE", "KF", "TF", "SWITCH", "E1", "SE1", "E2", "SE2"),
    "ESST4B": ("TR", "KPR", "KIR", "VRMAX", "VRMIN", "TA", "KPM", "KIM", "VMMAX", "VMMIN", "KG", "KP", "KI",
               "VBMAX", "KC", "XL", "THETAP"),
    "ESST5B": ("TR", "KR", "T1", "KC", "VRMAX", "VRMIN", "TC1", "TB1", "TC2", "TB2", "TOC1", "TOB1", "TOC2",
               "TOB2", "TUC1", "TUB1", "TUC2", "TUB2"),
    "EXAC1": ("TR", "TB", "TC", "KA", "TA", "VRMAX", "VRMIN", "TE", "KF", "TF", "KC", "KD", "KE", "E1", "SE1", "E2",
              "SE2"),
    "ESAC1A": ("TR", "TB", "TC", "KA", "TA", "VAMAX", "VAMIN", "TE", "KF", "TF", "KC", "KD", "KE", "E1", "SE1", "E2",
               "SE2", "VRMAX", "VRMIN"),
    "ESAC8B": ("TR", "KPR", "KIR", "KDR", "TDR", "KA", "TA", "VRMAX", "VRMIN", "TE", "KE", "E1", "SE1", "E2", "SE2"),
    "IEEEST": ("A1", "A2", "A3", "A4", "A5", "A6", "T1", "T2", "T3", "T4", "T5", "T6", "KS", "LSMAX", "LSMIN", "VCU",
               "VCL"),
    "PSS2A": _PSS2 + ("VSTMAX", "VSTMIN"),
    "PSS2B": _PSS2 + ("T10", "T11", "VS1MAX", "VS1MIN", "VS2MAX", "VS2MIN", "VSTMAX", "VSTMIN"),
}
ICONS: dict[str, tuple[str, ...]] = {"ESST1A": ("UEL", "VOS"), "IEEEST": ("MODE", "BUSR"),
                                     "PSS2A": ("ICS1", "IB1", "ICS2", "IB2", "M", "N"),
                                     "PSS2B": ("ICS1", "IB1", "ICS2", "IB2", "M", "N")}
DESCRIPTION = {
    "GENROU": "round-rotor generator", "GENSAL": "salient-pole generator",
    "SEXS": "simplified excitation system", "EXST1": "IEEE ST1 static exciter",
    "ESST1A": "IEEE 421.5 ST1A static exciter", "IEEEX1": "IEEE type 1 DC exciter",
    "ESDC1A": "IEEE 421.5 DC1A exciter", "IEEET1": "IEEE 1968 type 1 exciter",
    "ESST4B": "IEEE 421.5 ST4B potential-source static exciter",
    "ESST5B": "IEEE 421.5 ST5B static exciter",
    "EXAC1": "IEEE type AC1 rotating exciter",
    "ESAC1A": "IEEE 421.5 AC1A rotating exciter",
    "ESAC8B": "IEEE 421.5 AC8B exciter (PID regulator)",
    "IEEEST": "IEEE ST power system stabiliser",
    "PSS2A": "IEEE dual-input power system stabiliser PSS2A",
    "PSS2B": "IEEE dual-input power system stabiliser PSS2B",
}

_TOKEN = re.compile(r"'[^']*'|\"[^\"]*\"|[^\s']+")
#: a machine ID that writes and reads back the same (PSS/E: one or two characters)
_ID = re.compile(r"[A-Za-z0-9_&*#.+-]{1,2}")
#: PSS/E's bus numbers
BUS_MIN, BUS_MAX = 1, 999_997


class DyrError(BadInput):
    """A record that cannot be read or written; the message names the file and line."""


def check_bus_id(bus: int, ident: str, where: str = "") -> None:
    """Refuse (DyrError) a bus number PSS/E does not accept and a machine ID that cannot be
    written so that it reads back the same (see the module docstring)."""
    at = f"{where}: " if where else ""
    if isinstance(bus, bool) or not isinstance(bus, int) or not BUS_MIN <= bus <= BUS_MAX:
        raise DyrError(f"{at}bus {bus!r}: PSS/E's bus numbers are {BUS_MIN} .. {BUS_MAX}")
    if not ident:
        raise DyrError(f"{at}an empty machine ID: PSS/E needs one or two characters (e.g. 1)")
    if ident != ident.strip():
        raise DyrError(f"{at}machine ID {ident!r}: PSS/E pads IDs with blanks ({ident.strip()!r} is the same "
                       f"machine): give {ident.strip()!r}")
    bad = [c for c in ident if c in "'\"/" or c.isspace()]
    if bad:
        raise DyrError(f"{at}machine ID {ident!r}: {bad[0]!r} cannot be in an ID (a quote delimits it, a / ends "
                       "the record, a blank separates fields)")
    if not _ID.fullmatch(ident):
        raise DyrError(f"{at}machine ID {ident!r}: PSS/E's IDs are one or two characters, letters, digits or "
                       "_ & * # . + -")


@dataclass(frozen=True)
class DyrRecord:
    bus: int
    model: str
    id: str
    values: dict[str, float]
    icons: dict[str, int] = field(default_factory=dict)
    source: str = ""


def _number(text: str, where: str) -> float:
    try:
        return float(text.replace("D", "E").replace("d", "e"))
    except ValueError:
        raise DyrError(f"{where}: {text!r} is not a number") from None


def _records(text: str, name: str) -> Iterable[tuple[int, list[str]]]:
    """(line of its first field, tokens) per record; comments dropped."""
    tokens: list[str] = []
    start = 0
    for n, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("//") or s.startswith("@!"):
            continue
        body, slash, _ = line.partition("/")
        found = _TOKEN.findall(body)
        if found and not tokens:
            start = n
        tokens += found
        if slash:
            if tokens:
                yield start, tokens
            tokens = []
    if tokens:
        raise DyrError(f"{name}:{start}: record not terminated by '/'")


def parse_dyr(text: str, name: str = "<dyr>", ignore: Collection[str] = ()) -> list[DyrRecord]:
    """The records of a .dyr text; a record of a model in `ignore` (upper case: the user's
    `--dyr-ignore`) is read as plain CONs, its layout not checked: a record left out is not judged."""
    out = []
    for line, tok in _records(text, name):
        where = f"{name}:{line}"
        if len(tok) < 3:
            raise DyrError(f"{where}: a record needs at least BUS 'MODEL' ID, got {' '.join(tok)!r}")
        try:
            bus = int(tok[0])
        except ValueError:
            raise DyrError(f"{where}: bus {tok[0]!r} is not an integer") from None
        model = tok[1].strip("'\"").upper()
        ident = tok[2].strip("'\"").strip()
        if not ident:
            raise DyrError(f"{where}: an empty machine ID ({tok[2]}): PSS/E needs one or two characters")
        if bus < BUS_MIN:
            raise DyrError(f"{where}: bus {bus}: PSS/E's bus numbers start at {BUS_MIN}")
        rest = tok[3:]
        where = f"{where}: {model}"
        icon_names = () if model in ignore else ICONS.get(model, ())
        names = None if model in ignore else FIELDS.get(model)
        if names is not None and len(rest) != len(icon_names) + len(names):
            raise DyrError(f"{where}: expected {len(icon_names)} ICONs and {len(names)} CONs "
                           f"({len(icon_names) + len(names)} fields), found {len(rest)}")
        icons = {}
        for k, text_ in zip(icon_names, rest):
            v = _number(text_, f"{where} {k}")
            if v != int(v):
                raise DyrError(f"{where}: ICON {k} = {text_!r} is not an integer")
            icons[k] = int(v)
        cons = rest[len(icon_names):]
        names = names or tuple(f"CON{i + 1}" for i in range(len(cons)))
        values = {k: _number(t, f"{where} {k}") for k, t in zip(names, cons)}
        out.append(DyrRecord(bus, model, ident, values, icons, where.split(": ")[0]))
    return out


def read_dyr(path: str | os.PathLike[str], ignore: Collection[str] = ()) -> list[DyrRecord]:
    """The records of a .dyr file (a regular file within the limit of `bench_ctl.limits`; UTF-8,
    else Latin-1 as older PSS/E files are written); `ignore`: models read without their layout
    checked (`parse_dyr`)."""
    from bench_ctl.limits import InputError, read_bounded

    p = Path(path)
    try:
        data = read_bounded(p, "a .dyr file")
    except InputError as exc:
        raise DyrError(str(exc)) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    return parse_dyr(text, str(p), ignore)


def format_record(rec: DyrRecord, comment: str | None = None, per_line: int = 5) -> str:
    names = FIELDS.get(rec.model)
    if names is None:
        raise DyrError(f"{rec.model}: no field order known; known: {', '.join(FIELDS)}")
    missing = [k for k in names if k not in rec.values] + [k for k in ICONS.get(rec.model, ()) if k not in rec.icons]
    if missing:
        raise DyrError(f"{rec.model} at bus {rec.bus}: no value for {', '.join(missing)}")
    check_bus_id(rec.bus, rec.id, rec.model)
    bad = [f"{k} = {rec.values[k]}" for k in names if not math.isfinite(float(rec.values[k]))]
    if bad:
        raise DyrError(f"{rec.model} at bus {rec.bus}: {', '.join(bad)} cannot be written (a record holds numbers)")
    items = [str(int(rec.icons[k])) for k in ICONS.get(rec.model, ())]
    # the shortest text that reads back as the same float: a record read back simulates the same
    items += [repr(float(rec.values[k])).upper() for k in names]
    lines = [f"// {c}" for c in (comment.splitlines() if comment else [])]
    head = f"{rec.bus} '{rec.model}' {rec.id}"
    chunks = [items[i:i + per_line] for i in range(0, len(items), per_line)] or [[]]
    lines.append(f"{head}  " + "  ".join(chunks[0]))
    lines += ["    " + "  ".join(c) for c in chunks[1:]]
    lines[-1] += "  /"
    return "\n".join(lines) + "\n"


def dyr_text(records: Iterable[tuple[DyrRecord, str | None]], header: str | None = None) -> str:
    """The text of a .dyr file: `header` as comment lines, then each record with its comment."""
    text = "".join(f"// {h}\n" for h in (header.splitlines() if header else []))
    return text + "".join(format_record(r, c) for r, c in records)


def write_dyr(path: str | os.PathLike[str], records: Iterable[tuple[DyrRecord, str | None]], *,
              header: str | None = None, overwrite: bool = False) -> None:
    """Write `records` (each with its comment) to `path` through `bench_ctl.outputs`: never over an
    existing file unless `overwrite`, never through a symbolic link, a temporary file in the same
    folder linked (or renamed) into place."""
    from bench_ctl import outputs

    p = Path(path)
    if os.path.lexists(p) and not overwrite:
        raise FileExistsError(f"{p}: exists; the .dyr is never overwritten (choose another name)")
    text = dyr_text(records, header)
    try:
        outputs.write_text(p, text, force=overwrite)
    except outputs.OutputRefused as exc:
        raise FileExistsError(f"{exc}; the .dyr is never overwritten (choose another name)") from None


def find(records: Iterable[DyrRecord], models: set[str] | str, bus: int | None = None,
         id: str | None = None) -> DyrRecord:
    """The one record of `models` (at `bus`, machine `id` when given)."""
    wanted = {models} if isinstance(models, str) else set(models)
    hits = [r for r in records if r.model in wanted and (bus is None or r.bus == bus)
            and (id is None or r.id == str(id))]
    if not hits:
        raise DyrError(f"no {'/'.join(sorted(wanted))} record" + (f" at bus {bus}" if bus is not None else "")
                       + (f" with ID {id}" if id is not None else ""))
    if len(hits) > 1:
        where = ", ".join(f"{r.model} bus {r.bus} ID {r.id} ({r.source})" for r in hits)
        raise DyrError(f"several records match ({where}); choose with --dyr-bus / --dyr-id")
    return hits[0]
