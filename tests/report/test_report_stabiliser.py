"""The report's stabiliser test section (issue 49 item 3): a result holding a PSS-off and a PSS-on
on-line capture (their sidecars' `test.pss_on`, as `pss_step` writes them) gets a table of the mode
in P measured and simulated, off vs on, and one figure; a result without such a pair gets none."""
from __future__ import annotations

import json
import re

from bench_ctl.cli import main
from procedures.pss_step import SIMULATED_BENCH

PSS = [a for s in SIMULATED_BENCH["unit_set"] for a in ("--set", s)]


def _capture(path, pss_on: bool) -> None:
    off = [] if pss_on else ["--set", "PSS_LSMAX=0"]      # the output held at 0, the states running
    assert main(["simulate", "--online", *PSS, *off, "--amplitude", "0.03", "--start", "1", "--width", "5",
                 "--duration", "7", "--noise", "0.002", "--seed", "3", "-o", str(path)]) == 0
    sidecar = path.with_suffix(".json")
    meta = json.loads(sidecar.read_text())
    meta["test"]["pss_on"] = pss_on
    sidecar.write_text(json.dumps(meta))


def test_a_result_with_both_captures_gets_the_stabiliser_section(tmp_path):
    off, on = tmp_path / "capture_pss_off.csv", tmp_path / "capture_pss_on.csv"
    _capture(off, False)
    _capture(on, True)
    res, html = tmp_path / "result.json", tmp_path / "report.html"
    assert main(["identify", str(off), str(on), *PSS, "--evals", "60", "--json", str(res)]) in (0, 1)
    assert main(["report", str(res), "-o", str(html)]) in (0, 1)
    text = html.read_text()
    assert 'id="sec-stabiliser"' in text and (tmp_path / "report_stabiliser.png").is_file()
    zeta = {k: float(v) for k, v in re.findall(r'id="(pss-(?:off|on)-(?:measured|simulated))-zeta" '
                                                r'data-value="([^"]+)"', text)}
    assert set(zeta) == {"pss-off-measured", "pss-on-measured", "pss-off-simulated", "pss-on-simulated"}, zeta
    assert zeta["pss-on-measured"] > zeta["pss-off-measured"] + 0.05, zeta
    assert zeta["pss-on-simulated"] > zeta["pss-off-simulated"] + 0.05, zeta
    print(zeta)


def test_a_result_without_the_pair_has_no_stabiliser_section(tmp_path):
    on = tmp_path / "capture_pss_on.csv"
    _capture(on, True)
    res, html = tmp_path / "result.json", tmp_path / "report.html"
    assert main(["identify", str(on), *PSS, "--evals", "32", "--json", str(res)]) in (0, 1)
    assert main(["report", str(res), "-o", str(html)]) in (0, 1)
    assert 'id="sec-stabiliser"' not in html.read_text()


def test_an_on_line_capture_with_the_stabilisers_output_shows_it_measured_and_simulated(tmp_path):
    """A capture with a `vs` channel (issue 49, item 2): the on-line figure gets a fifth panel, vs
    measured (less its pre-step level, as fitted) and simulated; without vs it keeps its four."""
    from matplotlib.figure import Figure

    from bench_ctl.capture import read_capture
    from bench_ctl.report import figures as F
    from bench_ctl.report.metrics import setpoint_edges
    from pss2_cases import make_case

    case = make_case(tmp_path, 0, with_vs=True)
    res, html = tmp_path / "result.json", tmp_path / "report.html"
    assert main(["identify", str(case.capture), "--unit", str(case.unit), "--evals", "32", "--json", str(res)]) \
        in (0, 1)
    assert main(["report", str(res), "-o", str(html)]) in (0, 1)
    text = html.read_text().replace("&#x27;", "'")
    assert "and the stabiliser's output vs (less its pre-step level, as fitted)" in text
    assert (tmp_path / "report_online.png").is_file()
    cap = read_capture(case.capture)
    meas = {name: cap.channel(name) for name in ("efd", "vt", "p", "q", "vs")}
    for with_vs, panels in ((True, 5), (False, 4)):
        shown = meas if with_vs else {k: v for k, v in meas.items() if k != "vs"}
        fig = Figure()
        F.draw_online(fig, cap.time, shown, shown, setpoint_edges(cap.time, cap.usetp))
        assert len(fig.axes) == panels
