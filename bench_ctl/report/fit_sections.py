"""The report's sections about the fit, as blocks (see `blocks`): summary, response figures,
error figures, acceptance, convergence, optimizer comparison, structure selection. The model's
parameters and constraints are in `parameter_sections`; the diagnosis, metadata and provenance
sections in `record_sections`; `outline` orders them all.
"""
from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np

from bench_ctl.engine.simulate import pre_step_mean, pre_trigger_mean, simulate
from bench_ctl.identification.construction import scored_vs
from bench_ctl.identification.result_file import CandidateEntry
from bench_ctl.identification.selection import separation_text, where_left
from bench_ctl.identification.timing import fitted_edge_plan
from bench_ctl.report import figures as F
from bench_ctl.report.analysis import CaptureAnalysis, ReportData
from bench_ctl.report.document import (
    NOT_AVAILABLE,
    Block,
    Fig,
    Heading,
    Num,
    Para,
    Section,
    Status,
    Table,
    Verdict,
    fmt,
    num,
    table,
)
from bench_ctl.report.inputs import ReportError, model_values
from bench_ctl.report.metrics import edge_times
from bench_ctl.signals.acceptance import SOURCE
from bench_ctl.signals.mode import electromechanical_mode


def summary(d: ReportData) -> Section:
    r = d.result
    counts = {s: sum(c.status == s for c in d.checks) for s in ("pass", "warn", "fail", "n/a")}
    text = (f"{counts['pass']} passed, {counts['warn']} warning(s), {counts['fail']} failed, "
            f"{counts['n/a']} not applicable")
    unit = r.unit
    opt = r.optimizer
    diag = d.diagnosis
    rows = [
        ("unit", unit.name, "", ""),
        ("captures", ", ".join(a.loaded.path.name for a in d.captures), "",
         "SHA-256 verified; see Metadata"),
        *([("fit window", f"{fmt(d.fit_window[0])} … {fmt(d.fit_window[1])}", "s",
            "identification fitted this part of each record; MSE and objective below are over it")]
          if d.fit_window else []),
        ("MSE (re-simulated)", Num(d.mse, "mse"), "pu²", "mean over captures of mean(r²)"),
        ("MSE (reported by identification)", Num(num(r.mse), "mse-reported"), "pu²", ""),
        ("objective (re-simulated)", Num(d.objective, "objective"), "pu² s",
         "trapezoidal integral of the weighted squared error"),
        ("objective (reported)", Num(num(r.objective), "objective-reported"), "pu² s", ""),
        ("noise floor", Num(d.noise_floor, "noise-floor"), "pu²", d.noise_source),
        ("optimizer", opt.name, "",
         f"seed {fmt(opt.seed)}, {fmt(r.evaluations)} evaluations"),
        *_single_capture_rows(d),
        ("diagnosis verdict", diag.verdict if diag else NOT_AVAILABLE,
         "", "see Diagnosis" if diag else "no diagnosis given"),
    ]
    return Section("summary", "Summary", (
        Verdict(d.verdict, text),
        table(("check", "status", "detail"),
              [(c.name, Status(c.status), c.detail) for c in d.checks], id="checks"),
        table(("quantity", "value", "unit", "note"), rows, id="key-figures"),
    ))


def _single_capture_rows(d: ReportData) -> list[tuple[str, Num, str, str]]:
    if len(d.captures) != 1:
        return []
    f = d.captures[0].figures
    return [("RMSE", Num(f.rmse), "pu", "√MSE"),
            ("NRMSE", Num(100.0 * f.nrmse, digits=4), "%", "RMSE / measured efd range"),
            ("peak error |r|", Num(f.peak_abs), "pu", f"at t = {fmt(f.peak_time_s, 5)} s")]


def _edge_text(a: CaptureAnalysis) -> str:
    lead, (lead_s, trail_s) = a.edges.lead, edge_times(a.edges)
    if lead is None or lead_s is None:
        return "No setpoint change found in usetp: no edge zooms, the whole record is one segment."
    trail = f", trailing edge at t = {trail_s:.4f} s" if trail_s is not None else \
        " (a step: no trailing edge)"
    cap = a.loaded.capture
    pre = pre_trigger_mean(np.asarray(cap.usetp, float), float(cap.time[1] - cap.time[0]))
    return (f"Setpoint change of {lead.jump_pu:+.4g} pu from {pre:.4g} pu; leading edge at "
            f"t = {lead_s:.4f} s{trail}. Edges are where usetp crosses half its largest "
            "excursion from the pre-trigger mean.")


def _edge_timing_table(a: CaptureAnalysis) -> Table | None:
    """The setpoint edge instants the fit estimated (result `captures[i].edges`), in ms."""
    entries = a.loaded.entry.edges
    if not entries:
        return None
    rows = []
    for i, e in enumerate(entries, 1):
        nominal, fitted, std = num(e.nominal_s), num(e.fitted_s), num(e.std_s)
        rows.append((str(i), Num(nominal, digits=7), Num(fitted, digits=7),
                     Num(None if fitted is None or nominal is None else 1e3 * (fitted - nominal), digits=3),
                     Num(None if std is None else 1e3 * std, digits=2),
                     e.how + ("" if e.fitted else " (not fitted)")))
    return table(("edge", "nominal (s)", "fitted (s)", "offset (ms)", "std (ms)", "setpoint"), rows,
                 id=f"edge-timing{a.suffix}",
                 caption="Setpoint edge instants: nominal = the first sample showing the change; fitted = "
                         "the instant the fit estimated inside its interval (the sample interval before a "
                         "recorded edge, +- the stated tolerance for a described test).")


def response(d: ReportData) -> Section:
    blocks: list[Block] = []
    for a in d.captures:
        cap = a.loaded.capture
        if len(d.captures) > 1:
            blocks.append(Heading(a.label))
        blocks.append(Fig(f"response{a.suffix}",
                          "Measured and simulated efd (top) and the recorded setpoint usetp (bottom); "
                          "dotted lines mark the setpoint edges.",
                          partial(F.draw_response, time=cap.time, usetp=cap.usetp, meas=cap.efd,
                                  sim=a.efd_sim, edges=a.edges,
                                  title=f"Measured vs simulated efd, {a.loaded.path.name}")))
        blocks.append(Fig(f"residual{a.suffix}",
                          "Residual r = measured − simulated efd; shading marks the segments, the "
                          "legend gives each segment's share of the residual energy Σr².",
                          partial(F.draw_residual, time=cap.time, residual=a.residual, figs=a.figures)))
        if a.edges.lead is not None:
            blocks.append(Fig(f"edges{a.suffix}",
                              f"Zooms on the setpoint edges ({F.ZOOM_BEFORE_S:g} s before to "
                              f"{F.ZOOM_AFTER_S:g} s after), usetp on the right axis.",
                              partial(F.draw_edges, time=cap.time, usetp=cap.usetp, meas=cap.efd,
                                      sim=a.efd_sim, edges=a.edges)))
        blocks.append(Para(_edge_text(a), "note"))
        timing = _edge_timing_table(a)
        if timing is not None:
            blocks.append(timing)
    return Section("response", "Measured vs simulated response", tuple(blocks))


def online(d: ReportData) -> Section | None:
    """An on-line record's P, Q, Vt and efd, measured vs simulated (and the stabiliser's output
    where a fit scores it: `scored_vs`, less its pre-step level as fitted), and the
    electromechanical mode in P after the first edge, measured vs simulated (`model.mode`). None
    without one."""
    blocks: list[Block] = []
    for a in d.captures:
        if a.online is None:
            continue
        cap = a.loaded.capture
        if len(d.captures) > 1:
            blocks.append(Heading(a.label))
        meas = {"efd": cap.efd, "vt": cap.vt, "p": cap.channel("p"), "q": cap.channel("q")}
        sim = {"efd": a.efd_sim, "vt": a.vt_sim, "p": a.online["p"], "q": a.online["q"]}
        vs = scored_vs(cap)
        caption = "On line: efd, terminal voltage, active and reactive power"
        if vs is not None:
            meas["vs"] = vs - pre_step_mean(cap.usetp, vs, cap.dt)
            sim["vs"] = a.online["vs"]
            caption += " and the stabiliser's output vs (less its pre-step level, as fitted)"
        blocks.append(Fig(f"online{a.suffix}", f"{caption}, measured and simulated; dotted lines mark the "
                          "setpoint edges.", partial(F.draw_online, time=cap.time, meas=meas, sim=sim, edges=a.edges),
                          size=(7.5, 8.0 if vs is None else 9.5)))
        rows = []
        for name, p in (("measured", meas["p"]), ("simulated", sim["p"])):
            lead_s = edge_times(a.edges)[0]
            m = None if lead_s is None else electromechanical_mode(cap.time, p, lead_s)
            key = f"mode-{name}{a.suffix}"
            rows.append((name, "n/a" if m is None else Num(m.frequency_hz, f"{key}-hz", 3),
                         "n/a" if m is None else Num(m.damping, f"{key}-zeta", 3),
                         "n/a" if m is None else Num(m.amplitude, None, 3)))
        blocks.append(Table(("P", "frequency (Hz)", "damping ratio", "swing amplitude (pu)"), tuple(rows),
                            caption="The electromechanical mode in P after the leading edge (a damped sinusoid "
                                    "beside a slow exponential, fitted over 4 s; n/a: no swing above three "
                                    "times the fit's residual)."))
    return Section("online", "On line: P, Q, Vt and efd", tuple(blocks)) if blocks else None


def errors(d: ReportData) -> Section:
    blocks: list[Block] = [Para(
        "r = efd measured − efd simulated, sample by sample. MSE = mean(r²) over all samples, as "
        "in the reference paper; RMSE = √MSE; NRMSE = RMSE normalised by the range (max − min) of "
        "the measured efd. Objective = trapezoidal integral of the weighted squared error "
        "(the identification's objective function). Segments: pre-trigger (start to the leading "
        f"edge), leading edge ({d.window_s:g} s from the leading edge), plateau (to the trailing "
        f"edge), trailing edge ({d.window_s:g} s from the trailing edge), recovery (to the end); "
        "share = Σr² in the segment / Σr² over the record.", "note")]
    for a in d.captures:
        f, s, e = a.figures, a.suffix, a.loaded.entry
        if len(d.captures) > 1:
            blocks.append(Heading(a.label))
        win = ""
        if d.fit_window:
            win = f" over the fit window {fmt(d.fit_window[0])} … {fmt(d.fit_window[1])} s"
        rows = [
            ("MSE (re-simulated)" + win, Num(a.fit_mse, f"mse{s}-capture"), "pu²", "mean(r²)"),
            ("MSE (reported)", Num(num(e.mse), f"mse{s}-capture-reported"), "pu²",
             "captures[].mse of the result"),
            *([("MSE over the whole record", Num(f.mse, f"mse{s}-record"), "pu²",
                "mean(r²), all samples")] if win else []),
            ("RMSE", Num(f.rmse, f"rmse{s}"), "pu", "√MSE"),
            ("NRMSE", Num(100.0 * f.nrmse, f"nrmse{s}", 4), "%",
             f"RMSE / measured efd range ({fmt(f.efd_range, 4)} pu)"),
            ("measured efd range", Num(f.efd_range, f"efd-range{s}"), "pu", "max − min"),
            ("peak error |r|", Num(f.peak_abs, f"peak{s}"), "pu",
             f"signed r = {fmt(f.peak_signed, 4)} pu"),
            ("time of peak error", Num(f.peak_time_s, f"peak-time{s}"), "s", ""),
            ("objective (re-simulated)" + win, Num(a.fit_objective, f"objective{s}-capture"),
             "pu² s", "trapezoidal ∫ w r² dt"),
            ("objective (reported)", Num(num(e.objective), f"objective{s}-capture-reported"),
             "pu² s", "captures[].objective of the result"),
            ("pre-trigger efd variance", Num(f.noise_floor, f"noise-pre{s}"), "pu²",
             f"{f.noise_samples} samples before the leading edge (noise estimate)"),
        ]
        blocks.append(table(("figure", "value", "unit", "definition"), rows, id=f"errors{s}"))
        seg_rows = [(g.name.replace("_", " "), Num(g.t0, digits=5), Num(g.t1, digits=5), Num(g.n),
                     Num(g.mse if g.n else None), Num(100.0 * g.share, f"share-{g.name}{s}", 4))
                    for g in f.segments]
        blocks.append(table(("segment", "from (s)", "to (s)", "samples", "MSE (pu²)",
                             "share of Σr² (%)"), seg_rows, id=f"segments{s}",
                            caption="Residual energy per segment of the response"))
    return Section("errors", "Error figures", tuple(blocks))


def acceptance(d: ReportData) -> Section:
    """The IEC 61400-27-2 table per capture: windows, figures against limits, pass / fail."""
    first = d.captures[0].acceptance if d.captures else None
    blocks: list[Block] = [Para(
        "d = (efd simulated − efd measured) / step size, where the step size is the largest "
        "deviation of the measured efd from its pre-trigger mean. Per window: MXE = max |d|, "
        "ME = |mean d|, MAE = mean |d|. Windows: before (start to the leading setpoint edge), "
        "during (leading to trailing edge), after (trailing edge to the end); "
        + (f"the first {fmt(first.exclusion_s * 1e3, 4)} ms after each edge is excluded. "
           if first else "") + "A window passes when every figure is at or below its limit.",
        "note"), Para(SOURCE, "note")]
    for a in d.captures:
        acc, s = a.acceptance, a.suffix
        if len(d.captures) > 1:
            blocks.append(Heading(a.label))
        rows = []
        for w in acc.windows:
            cells: list[Any] = [w.name, Num(w.t0, digits=5), Num(w.t1, digits=5), Num(w.n)]
            for f in ("MXE", "ME", "MAE"):
                cells += [Num(w.figures[f] if w.n else None, f"acc-{w.name}-{f.lower()}{s}", 4),
                          Num(w.limits[f], digits=4)]
            cells.append(Status("n/a" if w.ok is None else "pass" if w.ok else "fail"))
            rows.append(tuple(cells))
        blocks.append(table(("window", "from (s)", "to (s)", "samples", "MXE", "limit", "ME", "limit",
                             "MAE", "limit", "status"), rows, id=f"acceptance{s}",
                            caption=f"Step size {fmt(acc.step_pu, 4)} pu; figures in per unit of it"))
    return Section("acceptance", "Numeric acceptance", tuple(blocks))


def convergence(d: ReportData) -> Section:
    r = d.result
    opt = r.optimizer
    blocks: list[Block] = []
    # entries whose best is still null (no finite objective yet) or not positive are left out
    pts = [(float(p[0]), float(p[1])) for p in r.history
           if isinstance(p, list) and len(p) == 2 and num(p[0]) is not None
           and num(p[1]) is not None and p[1] > 0]
    h = np.asarray(pts, float).reshape(-1, 2)
    ok = h.shape[0] > 0
    if ok:
        name = opt.name
        left_out = len(r.history) - h.shape[0]
        blocks.append(Fig("convergence", "Best objective found vs number of objective "
                          "evaluations (log scale)." + (f" {left_out} history entries without a "
                                                        "finite positive objective are not drawn."
                                                        if left_out else ""),
                          partial(F.draw_convergence, history=h.tolist(), label=name)))
        best = float(h[:, 1].min())
        reached = int(h[int(np.argmax(h[:, 1] <= best)), 0])
    else:
        blocks.append(Para(f"Convergence history: {NOT_AVAILABLE}.", "na"))
        best, reached = None, None
    rows = [("optimizer", opt.name), ("seed", fmt(opt.seed)),
            ("evaluations", Num(num(r.evaluations), "evaluations")),
            ("best objective in history", Num(best)),
            ("best reached after (evaluations)", Num(reached, "best-reached")),
            ("optimizer wall time (s)", Num(num(r.wall_s), "wall-s", 4)),
            ("compile time (s), excluded", Num(num(r.compile_s), digits=4))]
    for key, value in opt.settings.items():
        rows.append((f"setting: {key}", fmt(value)))
    blocks.append(table(("item", "value"), rows, id="optimizer", kind="kv"))
    return Section("convergence", "Convergence", tuple(blocks))


def comparison(d: ReportData) -> Section:
    r = d.result
    comp = list(r.comparison or [])
    if not comp:
        return Section("comparison", "Optimizer comparison", (
            Para(f"Optimizer comparison: {NOT_AVAILABLE} (one optimizer was run).", "na"),))
    main = r.optimizer.name
    rows = [(c.optimizer + (" (this result)" if c.optimizer == main else ""),
             Num(num(c.mse)), Num(num(c.objective)), Num(num(c.evaluations)),
             Num(num(c.wall_s), digits=4),
             ", ".join(c.constraints_violated) or "none",
             f"failed: {c.message}" if c.failed else "")
            for c in comp]
    if not any(c.optimizer == main for c in comp):  # the chosen run is not listed: add it
        violated = [str(c.get("expr")) for c in d.constraints if c.get("satisfied") is not True]
        rows.insert(0, (main + " (this result)", Num(num(r.mse)),
                        Num(num(r.objective)), Num(num(r.evaluations)),
                        Num(num(r.wall_s), digits=4), ", ".join(violated) or "none", ""))
    return Section("comparison", "Optimizer comparison", (
        table(("optimizer", "MSE (pu²)", "objective (pu² s)", "evaluations", "wall time (s)",
               "constraints violated", "note"), rows, id="comparison",
              caption="Optimizers run on the same capture(s)"),))


def selection(d: ReportData) -> Section | None:
    """`identify --model auto`: the ranking of the structures and the residual of the best two
    (each re-simulated here from the values it stored), None for a result of one structure."""
    sel = d.result.selection
    if not sel:
        return None
    rows = []
    for c in sel.candidates:
        note = "fits as well, more parameters" if c.equivalent else (c.error or "")
        if c.constraints_violated:
            note = "constraint violated: " + ", ".join(c.constraints_violated)
        if c.inert:
            note = "; ".join(filter(None, [note, "not counted (moves nothing on this record): "
                                           + ", ".join(c.inert)]))
        if c.searches == 2:
            note = "; ".join(filter(None, [note, "searched twice (its first search ended on its bounds)"]))
        rows.append((Num(num(c.rank)), c.model + (" (this result)" if c.rank == 1 else ""),
                     Num(num(c.k)), Num(num(c.x_floor), digits=4),
                     Num(num(c.check_x_floor), digits=4), Num(num(c.score_difference), digits=5),
                     note))
    verdict = sel.verdict
    best = sel.candidates[0] if sel.candidates else None
    text = (f"{sel.chosen} explains the record: its fit is at the noise floor." if verdict == "explains"
            else f"{sel.chosen} fits best, but leaves {fmt(num(best.x_floor if best else None), 3)}x the noise "
                 "floor: no structure of the library explains the record.")
    if sel.equivalent:
        text += f" As good on this record: {', '.join(sel.equivalent)}."
    blocks: list[Block] = [Para(text)]
    for line in [*(where_left(sel) if verdict == "closest" else []), separation_text(sel)]:
        if line:
            blocks.append(Para(line.strip(), "note"))
    blocks += [
        table(("rank", "structure", "parameters counted", "fit × noise floor", "check × noise floor",
               "score − best", "note"), rows, id="selection",
              caption="Every structure identified on the record and ranked: " + sel.rule),
    ]
    for note in sel.notes:
        blocks.append(Para(note, "note"))
    two = [c for c in sel.candidates if c.kernel is not None][:2]
    for a in d.captures:
        residuals = []
        for c in two:
            r = _residual_of(a, c)
            if r is not None:
                residuals.append((c.model, r))
        if len(residuals) == 2:
            cap = a.loaded.capture
            blocks.append(Fig(f"selection-residual{a.suffix}",
                              f"Residual r = measured − simulated efd of the best two structures, {a.label}.",
                              partial(F.draw_residuals, time=cap.time, residuals=residuals)))
    return Section("selection", "Structure selection", tuple(blocks))


def _residual_of(a: CaptureAnalysis, c: CandidateEntry) -> np.ndarray | None:
    """The residual of a selection candidate on capture a, re-simulated from its stored values."""
    cap = a.loaded.capture
    edges = c.edges or []
    try:
        values = model_values({}, c.kernel or {}, f"selection candidate {c.model}")
        spec, offsets = fitted_edge_plan(edges[a.loaded.index] if a.loaded.index < len(edges) else None, cap.n)
        efd, _, fail = simulate({**values, **offsets}, cap.usetp, cap.dt, edges=spec)
    except (KeyError, TypeError, ValueError, ReportError):
        return None
    return None if fail >= 0 else cap.efd - efd
