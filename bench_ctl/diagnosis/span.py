"""The part of an on-line record the diagnosis simulates: from PRE_STEP_S before the setpoint first changes to the end.

On line every model starts the machine from the operating point the record shows just before the
step (`engine.simulate.operating_point`: the means of P, Q and Vt over the OPERATING_POINT_S
before it) and holds it there until the step: the operation before that holds nothing a model
can follow, and a real export holds minutes of it (the Mostar on-line 5 % step: 86 s before the
step at 200 Hz), which every candidate of every fit simulated again. The diagnosis cuts such a
record to its test (`cut_to_test`), fits and checks every model there, takes its noise floor from
the PRE_STEP_S before the step (the pre-step operation's slow wander is no noise of the test), and
writes every instant in the whole record's seconds (`on_record`). A no-load record is the test
from its first sample (the machine starts from its own steady state there too, but the record's
start is where the user put it) and is never cut.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from bench_ctl.capture import Capture
from bench_ctl.engine.simulate import OPERATING_POINT_S
from bench_ctl.identification.result_file import Localization

from .diagnosis_file import Diagnosis, Span

__all__ = ["PRE_STEP_S", "cut_to_test", "on_record"]

#: the part of an on-line record before the step the diagnosis keeps (s): the operating point's
#: second and the noise floor's samples (1000 at 200 Hz)
PRE_STEP_S = 5.0
assert PRE_STEP_S >= OPERATING_POINT_S   # the operating point is the same on the cut record


def cut_to_test(capture: Capture | None) -> tuple[Capture | None, int]:
    """An on-line `capture` from PRE_STEP_S before its setpoint first changes to its end, and the
    first sample kept (0: the capture itself, at no load, with a shorter pre-step part or no
    setpoint change: the diagnosis refuses the last with its own words)."""
    if capture is None or not capture.on_line:
        return capture, 0
    u = np.asarray(capture.usetp, float)
    changed = np.flatnonzero(np.abs(u - u[0]) > 1e-9)
    if changed.size == 0:
        return capture, 0
    k0 = max(0, int(changed[0]) - int(round(PRE_STEP_S / capture.dt)))
    if k0 == 0:
        return capture, 0
    cut = Capture(time=capture.time[k0:], usetp=capture.usetp[k0:], efd=capture.efd[k0:],
                  vt=None if capture.vt is None else capture.vt[k0:],
                  extra={k: v[k0:] for k, v in capture.extra.items()}, meta=capture.meta, source=capture.source)
    return cut, k0


def _moved(loc: Localization, dt_s: float) -> Localization:
    return replace(loc, segments=tuple(replace(s, t0=s.t0 + dt_s, t1=s.t1 + dt_s) for s in loc.segments))


def on_record(d: Diagnosis, k0: int, dt: float, k0_holdout: int = 0, dt_holdout: float = 0.0) -> Diagnosis:
    """Diagnosis `d`, made on the parts of the capture (and holdout) from their samples k0 (and
    k0_holdout), with every instant and sample index in the whole records' terms: the edges, the
    fitted span (`validation.fit`), the check's windows, the noise floor's span, the localizations."""
    if k0 == 0 and k0_holdout == 0:
        return d
    s, s_h = k0 * dt, k0_holdout * dt_holdout

    def edge(e):  # noqa: ANN001, ANN202 - identification.timing.Edge
        k, ds = (k0_holdout, s_h) if e.capture == "holdout" else (k0, s)
        return replace(e, index=e.index + k, nominal_s=e.nominal_s + ds, fitted_s=e.fitted_s + ds)

    check = d.validation.check
    check = replace(check, windows=tuple(replace(w, t0=w.t0 + s, t1=w.t1 + s) for w in check.windows),
                    holdout=None if check.holdout is None else
                    replace(check.holdout, t0=check.holdout.t0 + s_h, t1=check.holdout.t1 + s_h))
    fit = d.validation.fit
    validation = replace(d.validation, fit=Span(fit.t0 + s, fit.t1 + s), check=check)
    nf = d.noise_floor_detail
    return replace(d, validation=validation, check=check, edges=tuple(edge(e) for e in d.edges),
                   noise_floor_detail=replace(nf, t0=nf.t0 + s, t1=nf.t1 + s), localization=_moved(d.localization, s),
                   left=replace(d.left, localization=_moved(d.left.localization, s)))
