"""An on-line recorder export with P and Q in MW and Mvar (issue 27, item 2): `import --map p=...
--scale p=1/MVA` puts them on the machine base, and the capture is an on-line record whose operating
point is the unit's. The source is an ANDES on-line capture (tests/fixtures/andes_online) written out
as a vendor export on a 250 MVA base."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from andes_units import online_capture, online_unit
from bench_ctl.capture import read_capture
from bench_ctl.cli import main
from bench_ctl.engine.simulate import operating_point
from bench_ctl.identification.construction import make_problem

MVA = 250.0


def _export(folder: Path) -> tuple[Path, object]:
    cap = online_capture("sexs_xe02")
    cols = cap.columns()
    lines = ["t_s;Uref;Ufd;Ug;P_MW;Q_Mvar"]
    for k in range(cap.n):
        lines.append(";".join(repr(float(x)) for x in (cols["time"][k], cols["usetp"][k], cols["efd"][k],
                                                       cols["vt"][k], cols["p"][k] * MVA, cols["q"][k] * MVA)))
    path = folder / "online_export.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path, cap


def test_an_export_in_mw_and_mvar_is_put_on_the_machine_base(tmp_path):
    path, cap = _export(tmp_path)
    out = tmp_path / "cap.csv"
    assert main(["import", str(path), "-o", str(out), "--time-column", "t_s", "--delimiter", ";",
                 "--map", "usetp=Uref", "--map", "efd=Ufd", "--map", "vt=Ug", "--map", "p=P_MW",
                 "--map", "q=Q_Mvar", "--scale", f"p={1 / MVA!r}", "--scale", f"q={1 / MVA!r}"]) == 0
    got = read_capture(out)
    cols, ref = got.columns(), cap.columns()
    for name in ("p", "q"):
        np.testing.assert_allclose(cols[name], ref[name], rtol=0, atol=1e-12, err_msg=name)
    point = operating_point(cols["usetp"], cols["p"], cols["q"], cols["vt"], got.dt)
    assert point["P0"] == pytest.approx(0.8, abs=1e-6)                    # ANDES' P, on its base
    # an on-line record for identification: the machine runs from its operating point
    problem = make_problem([got], online_unit("sexs_xe02", true_values=False))
    assert problem.records[0].machine is not None
    assert set(problem.signals(problem.records[0])) >= {"efd", "q"}


def test_the_stabilisers_output_is_imported_as_vs_and_fitted_with_efd_and_q(tmp_path):
    """`--map vs=COLUMN` (issue 49, item 2): the PSS's output, recorded in volts (10 V = 1 pu here),
    becomes the capture's `vs` channel in pu, read back as written; identification scores it on
    the on-line record (less its pre-step level) at the default weight, and not with weight 0."""
    from bench_ctl.units.overrides import apply_overrides
    from bench_ctl.units.unit import VS_WEIGHT

    cap = online_capture("sexs_xe02")
    cols = cap.columns()
    t = cols["time"]
    vs_pu = 0.003 + 0.004 * np.sin(2 * np.pi * 1.5 * t) * (t > 1.0)   # an offset, then a swing
    lines = ["t_s;Uref;Ufd;Ug;P;Q;PSS_V"]
    for k in range(cap.n):
        lines.append(";".join(repr(float(x)) for x in (t[k], cols["usetp"][k], cols["efd"][k], cols["vt"][k],
                                                       cols["p"][k], cols["q"][k], 10.0 * vs_pu[k])))
    src = tmp_path / "export.csv"
    src.write_text("\n".join(lines) + "\n", encoding="utf-8")
    out = tmp_path / "cap.csv"
    assert main(["import", str(src), "-o", str(out), "--time-column", "t_s", "--delimiter", ";",
                 "--map", "usetp=Uref", "--map", "efd=Ufd", "--map", "vt=Ug", "--map", "p=P", "--map", "q=Q",
                 "--map", "vs=PSS_V", "--scale", "vs=0.1"]) == 0
    got = read_capture(out)
    np.testing.assert_allclose(got.channel("vs"), vs_pu, rtol=0, atol=1e-12)
    assert got.unit("vs") == "pu" and got.meta["units"]["vs"] == "pu"
    unit = online_unit("sexs_xe02", true_values=False)
    problem = make_problem([got], unit)
    r = problem.records[0]
    assert problem.signals(r) == ["efd", "q", "vs"] and problem.w_vs == VS_WEIGHT
    assert abs(float(np.mean(r.vs[:int(0.9 / got.dt)]))) < 1e-12          # its pre-step level taken off
    np.testing.assert_allclose(r.vs, vs_pu - 0.003, rtol=0, atol=1e-12)
    off = make_problem([got], apply_overrides(unit, ["weights.vs=0"]))
    assert off.signals(off.records[0]) == ["efd", "q"]
    plain = make_problem([cap], unit)                                     # the record without vs
    x = plain.x_start()[None, :]
    assert off.objective(x)[0] == plain.objective(x)[0]
    assert problem.objective(x)[0] > plain.objective(x)[0]
