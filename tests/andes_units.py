"""Units for the ANDES fixtures (tests/fixtures/andes): each capture's exciter structure with the
values it was made with, and the kernel's generator from the GENROU data in the manifest.

Shared by tests/model/test_structures.py and benchmarks/model_library.py. The GENROU -> kernel
conversion is written out here from the GENROU equations (not taken from bench_ctl's own
`generator_from_record`, which a test checks against it)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from bench_ctl.capture import Capture
from bench_ctl.capture.capture import read_capture
from bench_ctl.engine import edge_plan
from bench_ctl.engine.runner import Edges
from bench_ctl.signals.edges import find_setpoint_edges
from bench_ctl.units.overrides import apply_overrides, with_model
from bench_ctl.units.unit import Unit, reference_unit

FOLDER = Path(__file__).resolve().parent / "fixtures" / "andes"


def manifest() -> dict:
    return json.loads((FOLDER / "manifest.json").read_text("utf-8"))


def generator_values(gen: dict) -> dict[str, float]:
    """GENROU at no load (Id = Iq = 0): psi''d = g E'q + (1 - g) psi1d with g = (X''d - Xl)/(X'd -
    Xl); field current E'q + (Xd - X'd)(X'd - X''d)/(X'd - Xl)^2 (E'q - psi1d) + B (psi'' - A)^2,
    the saturation through Se(1.0) 1.0 = S10 and Se(1.2) 1.2 = 1.2 S12."""
    xd, xd1, xd2, xl = gen["xd"], gen["xd1"], gen["xd2"], gen["xl"]
    return {"Td0p": gen["Td10"], "Td0pp": gen["Td20"], "KPP": (xd2 - xl) / (xd1 - xl),
            "KDA": (xd - xd1) * (xd1 - xd2) / (xd1 - xl) ** 2, "S10": gen["S10"], "S12": 1.2 * gen["S12"]}


def standard_params(entry: dict) -> dict[str, float]:
    """The capture's exciter values under bench-ctl's standard names (ANDES names a few apart)."""
    p = dict(entry["exciter_params"])
    if entry["exciter"] == "SEXS":
        p["TA"] = p.pop("TATB") * p["TB"]
    if entry["exciter"] == "IEEEX1":
        p["KF"] = p.pop("KF1")
    if entry["exciter"] == "AC8B":
        for a, b in (("kP", "KPR"), ("kI", "KIR"), ("kD", "KDR"), ("Td", "TDR"), ("VPMAX", "VPIDMAX"),
                     ("VPMIN", "VPIDMIN")):
            p[b] = p.pop(a)
        for k in ("VPIDMAX", "VPIDMIN"):    # ANDES' +-999: no limit (the structure's typical)
            if abs(p[k]) >= 999.0:
                del p[k]
    return p


def fixture_unit(name: str, *, true_values: bool = True) -> Unit:
    """The structure of capture `name` with the ANDES generator; its exciter values when
    `true_values`, else the structure's typical values (the start of an identification)."""
    m = manifest()
    entry = m["captures"][name]
    g = generator_values(m["generator_params"])
    unit = with_model(reference_unit(), entry["exciter"])
    sets = [f"{k}={g[k]}" for k in ("Td0p", "Td0pp", "KPP", "KDA")]
    if true_values:
        st = unit.structure
        p = standard_params(entry)
        ident = set(st.default_identified())
        sets += [f"{k}={v}" for k, v in p.items() if k in st.names and k not in ident]
        sets += [f"{k}={v}" for k, v in p.items() if k in ident]
    else:  # known: everything but the identified parameters (the unit's data sheet)
        st = unit.structure
        p = standard_params(entry)
        sets += [f"{k}={v}" for k, v in p.items() if k in st.names and k not in st.default_identified()]
    unit = apply_overrides(unit, sets)
    return unit.with_effects({"saturation": {"S10": g["S10"], "S12": g["S12"]}})


def read_fixture(name: str) -> Capture:
    return read_capture(FOLDER / manifest()["captures"][name]["file"])


def fixture_column(name: str, column: str) -> np.ndarray:
    """One column of a fixture by its header name (the capture reader keeps only its own)."""
    path = FOLDER / manifest()["captures"][name]["file"]
    header = path.read_text("utf-8").splitlines()[0].split(",")
    return np.loadtxt(path, delimiter=",", skiprows=1, usecols=header.index(column))


def open_loop_efd(name: str, unit, cap: Capture) -> np.ndarray:
    """The unit's excitation system alone fed the fixture's Vt and Ifd, setpoint edges at their
    true instants (bench_ctl.engine.open_loop)."""
    from bench_ctl.engine.open_loop import run_open_loop
    spec, off = true_edges(name, cap)
    times = [spec.nominal_s[i] + off[f"EDGE{i + 1}"] for i in range(spec.index.size)]
    return run_open_loop(unit.values(), cap.time, cap.vt, fixture_column(name, "ifd"), times, spec.jump)


def true_edges(name: str, cap: Capture) -> tuple[Edges, dict[str, float]]:
    """The capture's setpoint edges and the EDGE offsets of their true instants (the manifest)."""
    return _true_edges(manifest()["captures"][name], cap)


def _true_edges(entry: dict, cap: Capture) -> tuple[Edges, dict[str, float]]:
    k = find_setpoint_edges(cap.usetp)
    spec = edge_plan.build(k, cap.usetp[k] - cap.usetp[k - 1], cap.time[k], np.arange(len(k)))
    offsets = {f"EDGE{i + 1}": t - n for i, (n, t) in enumerate(zip(entry["edges_nominal_s"], entry["edges_true_s"]))}
    return spec, offsets


# ---- the on-line captures (tests/fixtures/andes_online, benchmarks/andes_online.py) -----------

ONLINE = Path(__file__).resolve().parent / "fixtures" / "andes_online"


def online_manifest() -> dict:
    return json.loads((ONLINE / "manifest.json").read_text("utf-8"))


def machine_values(gen: dict, xe: float) -> dict[str, float]:
    """The GENROU of the manifest as the on-line machine's [grid] values (H = M / 2)."""
    return {"XD": gen["xd"], "XQ": gen["xq"], "XDP": gen["xd1"], "XQP": gen["xq1"], "XDPP": gen["xd2"],
            "XLS": gen["xl"], "Tq0p": gen["Tq10"], "Tq0pp": gen["Tq20"], "H": gen["M"] / 2.0, "DAMP": gen["D"],
            "RA": gen["ra"], "FN": gen["fn"], "XE": xe}


def online_entry(name: str) -> dict:
    """The manifest's entry of on-line capture `name`: among `captures`, or `pss_captures` (the
    unit with ANDES' IEEEST stabiliser, which the unit here does not have)."""
    m = online_manifest()
    return m["captures"].get(name) or m["pss_captures"][name]


def online_unit(name: str, *, true_values: bool = True) -> Unit:
    """The structure of on-line capture `name` on the manifest's GENROU and XE, its exciter values
    when `true_values`, else the structure's typical values for the identified ones."""
    m = online_manifest()
    entry = online_entry(name)
    gen = m["generator_params"]
    g = generator_values(gen)
    unit = with_model(reference_unit(), entry["exciter"])
    st = unit.structure
    p = standard_params(entry)
    ident = set(st.default_identified())
    sets = [f"{k}={g[k]}" for k in ("Td0p", "Td0pp", "KPP", "KDA")]
    sets += [f"{k}={v}" for k, v in p.items() if k in st.names and (true_values or k not in ident)]
    sets += [f"{k}={v}" for k, v in machine_values(gen, entry["xe_pu"]).items()]
    unit = apply_overrides(unit, sets)
    return unit.with_effects({"saturation": {"S10": g["S10"], "S12": g["S12"]}})


def online_capture(name: str, noise: float = 0.0, seed: int = 0, *, q_noise: float = 0.0,
                   vt_noise: float = 0.0) -> Capture:
    """On-line capture `name` (efd, vt, p, q, ifd), with seeded Gaussian noise of `noise` pu on efd
    (and of `q_noise`, `vt_noise` on q and vt, from the next draws of the same generator)."""
    path = ONLINE / online_entry(name)["file"]
    d = np.genfromtxt(path, delimiter=",", names=True)
    rng = np.random.default_rng(seed)
    efd = d["efd"] + rng.normal(0.0, noise, d.size) if noise > 0 else d["efd"]
    extra = {k: d[k] for k in ("p", "q", "ifd")}
    if q_noise > 0:
        extra["q"] = extra["q"] + rng.normal(0.0, q_noise, d.size)
    vt = d["vt"] + rng.normal(0.0, vt_noise, d.size) if vt_noise > 0 else d["vt"]
    return Capture(time=d["time"], usetp=d["usetp"], efd=efd, vt=vt, extra=extra, source=str(path))


def online_true_edges(name: str, cap: Capture) -> tuple[Edges, dict[str, float]]:
    """The on-line capture's setpoint edges and the EDGE offsets of their true instants."""
    return _true_edges(online_entry(name), cap)
