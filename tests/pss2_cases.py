"""Independent on-line records with a PSS2B, written as a user has them (issue 49: identify with
the stabiliser on): a capture (CSV + sidecar, with P, Q and Vt, and the stabiliser's output vs when
asked) made by tests/independent_online.py outside the engine, and the unit file that names the
PSS2B and its values. Used by benchmarks/pss2_identify.py, tests/identification/test_pss2_identify.py
and tests/identification/test_pss2_vs.py.

Per seed: the exciter's values drawn around its typical ones, the PSS2B's gain KS1 drawn, the
reference step's instant between two samples; drawn again until the closed loop settles. The unit file holds
the machine, the grid and the PSS2B's time constants as a planning record gives them (true), and
KS1 at its planning value `KS1_PLANNED` (not the truth): `pss_sets` fits it (and T1, T3 if asked)
on the record."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from independent_online import ESST1A, GEN, SEXS, OnlineRecorder, OnlineStep, online_record

#: the PSS2B of tests/engine/test_pss2.py (tuned for this machine: KS2 = T7 / 2H), output limits +-0.1 pu
PSS2B = dict(MODEL="PSS2B", KS1=10.0, TW1=2.0, TW2=2.0, T6=0.02, TW3=2.0, TW4=0.0, T7=2.0, KS2=2.0 / 6.0, KS3=1.0,
             T8=0.3, T9=0.06, M=5, N=1, T1=0.3, T2=0.05, T3=0.2, T4=0.05, T10=0.15, T11=0.05, VS1MAX=1.0,
             VS1MIN=-1.0, VS2MAX=2.0, VS2MIN=-2.0, VSTMAX=0.1, VSTMIN=-0.1)
KS1_PLANNED = 10.0
#: the PSS2B values a fit may take from the record: (min, max, start); the start is the planning
#: value (KS1) or the catalogue's typical one (T1, T3), never the truth
PSS_FIT = {"KS1": (1.0, 50.0, KS1_PLANNED), "T1": (0.05, 1.0, 0.15), "T3": (0.05, 1.0, 0.15)}
#: the exciters' drawn values: (low, high), log-uniform; the others their typical values
DRAWN = {"SEXS": {"K": (100.0, 400.0), "TA": (0.5, 2.0), "TB": (5.0, 15.0), "TE": (0.02, 0.1)},
         "ESST1A": {"KA": (100.0, 400.0), "TC": (0.5, 2.0), "TB": (5.0, 15.0), "TC1": (0.2, 1.0),
                    "TB1": (0.05, 0.3), "TA": (0.01, 0.05)}}
TYPICAL = {"SEXS": SEXS, "ESST1A": ESST1A}
#: values fixed in the unit file (the structure's others are its typical ones, the same as here)
FIXED = {"SEXS": ("EMIN", "EMAX"), "ESST1A": ("TR", "VRMAX", "VRMIN", "KC")}
AMPLITUDE_PU, STEP_S = 0.02, 1.0
MAX_DRAWS = 10


@dataclass(frozen=True)
class Pss2Case:
    seed: int
    exciter: str
    values: dict          # the exciter's true values (PSS/E names)
    pss: dict             # the PSS2B's true values
    step_s: float         # the step's instant (between samples)
    capture: Path
    unit: Path             # the unit file with the PSS2B (KS1 at its planning value)
    unit_without_pss: Path  # the same unit with the stabiliser left out
    noise_efd_var: float  # the noise actually in efd: mean square of recorded - clean
    redrawn: int          # how many draws of the seed were refused (their closed loop did not settle)
    noise_vs_var: float = 0.0   # the same of vs (recorded or not)


def draw(exciter: str, seed: int, attempt: int = 0) -> tuple[dict, dict, float]:
    """(the exciter's values, the PSS2B's, the step instant) of `seed` (`attempt` > 0: drawn again)."""
    rng = np.random.default_rng([seed, 0x9552B, 1 if exciter == "ESST1A" else 0] + ([attempt] if attempt else []))
    values = dict(TYPICAL[exciter])
    for name, (lo, hi) in DRAWN[exciter].items():
        values[name] = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    pss = {**PSS2B, "KS1": float(rng.uniform(5.0, 20.0))}
    step_s = STEP_S - float(rng.uniform(0.02, 0.98)) * 1e-3   # inside the sample interval before 1 s
    return values, pss, step_s


def settled(clean: dict[str, np.ndarray], rate_hz: float, last_s: float = 2.0) -> bool:
    """Whether the closed loop settled: over the record's last `last_s` the stabiliser's output
    moves less than 1e-3 pu and efd's fast part (its second difference) stays below 1e-4 pu. A
    unit with its exciter and PSS2B in a sustained oscillation (a fast exciter, a high KS1) is no
    commissioning record: drawn again, as tests/independent_plant.py's `draw_avr` does."""
    k = int(round(last_s * rate_hz))
    efd, vs = clean["efd"][-k:], clean["vs"][-k:]
    return bool(np.ptp(vs) < 1e-3 and np.abs(np.diff(efd, 2)).max() < 1e-4)


def _grid(pss: dict | None) -> dict:
    g = GEN
    out = {"XD": g["xd"], "XQ": g["xq"], "XDP": g["xd1"], "XQP": g["xq1"], "XDPP": g["xd2"], "XLS": g["xl"],
           "Tq0p": g["Tq10"], "Tq0pp": g["Tq20"], "H": g["H"], "DAMP": g["D"], "XE": 0.4, "P0": 0.8, "Q0": 0.2,
           "FN": g["fn"]}
    if pss:
        out["PSS_MODEL"] = pss["MODEL"]
        out.update({f"PSS2_{k}": v for k, v in pss.items() if k != "MODEL"})
        out["PSS2_KS1"] = KS1_PLANNED
    return out


def _toml(value) -> str:
    return f'"{value}"' if isinstance(value, str) else repr(float(value))


def unit_text(exciter: str, values: dict, pss: dict | None) -> str:
    """The unit file: the machine (GEN of tests/independent_online.py), the grid, the exciter's
    structure with its fixed values, and the PSS2B (KS1 at its planning value) when `pss`."""
    g = GEN
    kpp = (g["xd2"] - g["xl"]) / (g["xd1"] - g["xl"])
    kda = (g["xd"] - g["xd1"]) * (g["xd1"] - g["xd2"]) / (g["xd1"] - g["xl"]) ** 2
    lines = [f'name = "independent on-line unit, {exciter}' + (f', {pss["MODEL"]}"' if pss else '"'), "",
             "[generator]", f"Td0p = {g['Td10']!r}", f"Td0pp = {g['Td20']!r}", "Vt0 = 1.0", f"KPP = {kpp!r}",
             f"KDA = {kda!r}", "SATEQ = 0", "", "[avr]", f'model = "{exciter}"', "", "[fixed]"]
    lines += [f"{k} = {_toml(values[k])}" for k in FIXED[exciter]]
    lines += ["", "[effects.saturation]", f"S10 = {g['S10']!r}", f"S12 = {1.2 * g['S12']!r}", "", "[grid]"]
    lines += [f"{k} = {_toml(v)}" for k, v in _grid(pss).items()]
    return "\n".join(lines) + "\n"


def pss_sets(names: tuple[str, ...] = ("KS1",)) -> list[str]:
    """The `--set` arguments that fit the PSS2B's `names` (of `PSS_FIT`) within their bounds from
    their start values."""
    out: list[str] = []
    for name in names:
        lo, hi, start = PSS_FIT[name]
        out += ["--set", f"PSS2_{name}.min={lo}", "--set", f"PSS2_{name}.max={hi}", "--set",
                f"PSS2_{name}.value={start}"]
    return out


def pss_errors(true: dict, fitted: dict, names: tuple[str, ...]) -> dict[str, float]:
    """|fitted / true - 1| of each PSS2B value `names` (of `PSS_FIT`; `fitted` keyed `PSS2_NAME`).
    T1 and T3 fitted together are a pair: with T2 = T4 their lead-lags commute, the same transfer
    function either way round, so each is compared with the truth of the closer assignment."""
    err = {n: abs(fitted[f"PSS2_{n}"] / true[n] - 1.0) for n in names}
    if {"T1", "T3"} <= set(names):
        swapped = {"T1": abs(fitted["PSS2_T3"] / true["T1"] - 1.0), "T3": abs(fitted["PSS2_T1"] / true["T3"] - 1.0)}
        if max(swapped.values()) < max(err["T1"], err["T3"]):
            err.update(swapped)
    return err


def make_case(folder: Path, seed: int, exciter: str = "SEXS", recorder: OnlineRecorder | None = None,
              with_vs: bool = False) -> Pss2Case:
    """Make seed's record (the PSS2B on), write it as a capture (`with_vs`: with the stabiliser's
    output; the other channels the same either way) and the unit files (with the PSS2B; without
    it, the unit that leaves the stabiliser out)."""
    from bench_ctl.capture import write_capture

    recorder = recorder or OnlineRecorder()
    for attempt in range(MAX_DRAWS):
        values, pss, step_s = draw(exciter, seed, attempt)
        case = OnlineStep(exciter, values, pss, step_s=step_s, amplitude_pu=AMPLITUDE_PU)
        rec = online_record(case, recorder, seed=30_000 + seed)
        if settled(rec["truth"]["clean"], recorder.rate_hz):
            break
    else:
        raise RuntimeError(f"{exciter} seed {seed}: no draw of {MAX_DRAWS} settles")
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"pss2b_{exciter.lower()}_seed{seed}" + ("_vs" if with_vs else "")
    cap = folder / f"{stem}.csv"
    cols = {k: rec[k] for k in ("time", "usetp", "efd", "vt", "p", "q") + (("vs",) if with_vs else ())}
    meta = {"source": "tests/independent_online.py", "exciter": exciter, "seed": seed, "step_s": step_s}
    write_capture(cap, cols, meta, overwrite=True)
    unit, bare = folder / f"{stem}.toml", folder / f"{stem}_no_pss.toml"
    unit.write_text(unit_text(exciter, values, pss), encoding="utf-8")
    bare.write_text(unit_text(exciter, values, None), encoding="utf-8")
    return Pss2Case(seed, exciter, values, pss, step_s, cap, unit, bare, rec["truth"]["noise_efd_var"], attempt,
                    rec["truth"]["noise_vs_var"])
