"""The stabiliser test: the on-line voltage-reference step with the PSS off, then the same step with
it on, the electromechanical mode in P compared (the PSS must damp it).

PURPOSE
    Show that the unit's power system stabiliser damps the rotor's swing against the grid: two
    records of the same reference step (procedures/online_step.py), the first with the PSS's output
    switched off, the second with it on; the mode in P (frequency, damping ratio) of each.

PARAMETERS
    Those of online_step (the same names, bounds and defaults; see PARAMETERS there), the same for
    both steps, hold_s at least MODE_SPAN_S (4 s: the mode is fitted over that long after the step,
    while it is held, as the report fits it); min_damping_gain 0..1 (how much the damping ratio
    must rise with the PSS on).

PRECONDITIONS
    Everything online_step checks, before each step (the unit steady again after the first: the
    second waits for it up to steady_timeout_s, and is refused otherwise); and the exciter's profile
    has the PSS switch (register `pss_on`), read before anything is written.

SEQUENCE
    1. Record the step with the PSS OFF: online_step's sequence, with the PSS switch written off
       (once, read back and compared) right after remote is taken and before the steady state is
       awaited; at its end the release puts the pre-test switch back (the safe state restores what
       the run changed: the setpoint, then the PSS switch, then remote). The record is saved
       (capture_pss_off.csv, raw download first) before anything else happens.
    2. Record the same step with the PSS ON (the switch written on only where it was found off; the
       release puts it back), saved as capture_pss_on.csv.
    3. The mode in P of each record over MODE_SPAN_S after the step's edge (bench_ctl.signals.mode), from
       the converted record once it is saved.

HAZARDS
    Those of online_step, and the unit without its stabiliser during the first step: a poorly
    damped swing after the step. The P swing limit (limits.p_swing_max_mw) and the bands end the
    step at once, and a step ended early puts the PSS switch back as found at once, right after
    the setpoint (not when the record ends); whatever ends the test (an abort, an error, a lost
    link, Ctrl-C, SIGTERM, a refusal after the switch was written) the runner's safe state
    restores the setpoint and the PSS switch as found. A host that dies leaves the device to its
    watchdog (the simulated one puts the switch back with the setpoint).

PASS CRITERIA
    - Each step passes online_step's criteria (named "PSS off: ...", "PSS on: ...").
    - The mode found in P in both records, and its damping ratio with the PSS on at least
      min_damping_gain above the one with it off.
    - The PSS switch read back as found before the test.
"""
from __future__ import annotations

import math
from typing import Any

from bench_ctl.runner.context import Criterion, ProcedureResult, RunContext
from bench_ctl.runner.protocols import ProcedureBench
from bench_ctl.runner.safety import PreconditionFailed
from bench_ctl.signals.mode import electromechanical_mode
from procedures import online_step as online
from procedures.online_step import PARAMETERS as STEP_PARAMETERS
from procedures.online_step import StepPart, step_on_line

#: the run leaves captures (two: capture_pss_off.csv, capture_pss_on.csv)
CAPTURES = True
#: the simulated bench of a dry run: the unit on the grid with an IEEEST that damps its swing
#: (gain 5 on the speed, two lead-lags 0.2 / 0.05 s, washout 5 s; the mode's damping ratio
#: about 0.07 with its output off, 0.24 on, stepped offline), recorded with 0.002 pu of noise (at
#: the bench's default 0.01 pu the swing of a 2 % step, about 0.02 pu of P, is lost in it)
SIMULATED_BENCH = {"online": True, "noise_pu": 0.002,
                   "unit_set": ("PSS_MODEL=IEEEST", "PSS_KS=5", "PSS_T1=0.2", "PSS_T2=0.05", "PSS_T3=0.2",
                                "PSS_T4=0.05", "PSS_TW=5", "PSS_LSMAX=0.1")}
PARAMETERS: dict[str, tuple[float, float, str]] = {**STEP_PARAMETERS, "min_damping_gain": (0.0, 1.0, "")}
#: how long after the step the mode in P is fitted (s; the report's on-line section fits 4 s too)
MODE_SPAN_S = 4.0
#: the parts, in order: (name, the PSS switch during the step)
PARTS = (("pss_off", False), ("pss_on", True))


def check_parameters(params: dict[str, Any]) -> list[str]:
    """Every problem with the test's parameters (empty when fine): online_step's, and a hold long
    enough for the mode's span."""
    problems = online.check_parameters({k: v for k, v in params.items() if k in STEP_PARAMETERS})
    if not 0.0 <= params["min_damping_gain"] <= 1.0:
        problems.append(f"min_damping_gain = {params['min_damping_gain']:g} outside 0..1")
    if not problems and params["hold_s"] < MODE_SPAN_S:
        problems.append(f"hold_s = {params['hold_s']:g} s shorter than the {MODE_SPAN_S:g} s the mode is fitted over "
                        "after the step (it is measured while the step is held, before the step back)")
    return problems


def pss_step(bench: ProcedureBench, run: RunContext, *, amplitude_pu: float = 0.02, hold_s: float = 10.0,
             pre_trigger_s: float = 2.0, record_s: float = 20.0, rate_hz: int = 200,
             hold_tolerance_s: float = 0.02, amplitude_tolerance_pu: float = 0.001,
             recovery_tolerance_pu: float = 0.01, recovery_timeout_s: float = 30.0,
             vt_margin_pu: float = 0.005, q_margin: float = 0.1, poll_s: float = 0.05,
             steady_timeout_s: float = 30.0, min_damping_gain: float = 0.02) -> ProcedureResult:
    """The stabiliser test; see the module docstring (the test sheet)."""
    given = locals()
    params = {name: given[name] for name in STEP_PARAMETERS}
    ex = bench.exciter
    with run.step("pss switch"):
        found = ex.read_pss()
        run.note("pss_switch", found=found)
        if found is None:
            raise PreconditionFailed("refused before any write: the exciter's profile has no PSS switch "
                                     "(register pss_on): the stabiliser test switches the PSS's output")
    results: list[ProcedureResult] = []
    modes: list[dict[str, float] | None] = []
    for i, (name, on) in enumerate(PARTS):
        def switch(on: bool = on, name: str = name) -> None:
            if ex.read_pss() != on:
                ex.write_pss(on, purpose=f"PSS {'on' if on else 'off'} for the step ({name})")

        def undo(why: str, on: bool = on, name: str = name) -> None:
            if on != found and ex.read_pss() != found:   # at once, not at the record's end
                ex.write_pss(found, purpose=f"abort ({why}): PSS back {'on' if found else 'off'} at once ({name})")

        def saved(data: dict[str, Any], test: dict[str, Any], name: str = name) -> None:
            modes.append(_mode(run, name, data, float(test["start_s"]), MODE_SPAN_S))

        plan = (f"  PSS       step {i + 1} of 2 with the PSS {'ON' if on else 'OFF'}"
                + ("; then the same step with it on, the switch as found at the end" if i == 0 else ""))
        part = StepPart(name, switch, {"pss_on": on, "pss_test": {"part": i + 1, "of": len(PARTS)}}, plan,
                        confirm=i == 0, saved=saved, on_abort=undo)
        result = step_on_line(bench, run, params, part)
        results.append(result)
        if result.data.get("aborted") or result.comms_error is not None:
            break     # the first step ended early or lost the link after it: no second step
    run.part = ""
    return _verdict(ex.read_pss(), found, results, modes, min_damping_gain, run)


def _mode(run: RunContext, name: str, data: dict[str, Any], t_edge: float, span_s: float) -> dict[str, float] | None:
    """The mode in P of a part's record over span_s after the step's edge (None: none found)."""
    mode = electromechanical_mode(data["time"], data["p"], data["time"][0] + t_edge, span_s)
    found = None if mode is None else {"frequency_hz": mode.frequency_hz, "damping": mode.damping}
    run.note("mode", part=name, mode=found, span_s=span_s)
    return found


def _verdict(now: bool | None, found: bool, results: list[ProcedureResult], modes: list[dict[str, float] | None],
             min_damping_gain: float, run: RunContext) -> ProcedureResult:
    """Both steps' criteria, the damping compared, the switch as found."""
    criteria = [Criterion(f"{label}: {c.name}", c.passed, c.value, c.limit, c.unit, shown=c.shown)
                for label, r in zip(("PSS off", "PSS on"), results) for c in r.criteria]
    off, on = (modes + [None, None])[:2]
    if off is not None and on is not None:
        gain = on["damping"] - off["damping"]
        criteria.append(Criterion("damping ratio higher with the PSS on", gain >= min_damping_gain, gain,
                                  min_damping_gain, "",
                                  shown=f"{off['damping']:.3f} off ({off['frequency_hz']:.2f} Hz) -> "
                                        f"{on['damping']:.3f} on ({on['frequency_hz']:.2f} Hz), "
                                        f"{gain:+.3f} (at least +{min_damping_gain:.3f})"))
    else:
        missing = [label for label, m in zip(("PSS off", "PSS on"), (off, on)) if m is None]
        criteria.append(Criterion("damping ratio higher with the PSS on", False, math.nan, min_damping_gain, "",
                                  shown=f"no mode found in P with the {' and the '.join(missing)}"
                                        + (" (step not made)" if len(results) < len(PARTS) else "")))
    criteria.append(Criterion("PSS switch as found", now == found, now, found, "",
                              shown=f"{'on' if now else 'off'}, found {'on' if found else 'off'}"))
    run.note("criteria", criteria=[c.to_dict() for c in criteria])
    summary = "; ".join(f"{label}: {r.summary}" for label, r in zip(("PSS off", "PSS on"), results))
    if off is not None and on is not None:
        summary += (f"; mode in P {off['frequency_hz']:.2f} Hz damping {off['damping']:.3f} off, "
                    f"{on['frequency_hz']:.2f} Hz damping {on['damping']:.3f} on")
    carried = next((r.comms_error for r in results if r.comms_error is not None), None)
    return ProcedureResult(criteria=tuple(criteria), summary=summary, comms_error=carried,
                           data={"modes": {"pss_off": off, "pss_on": on},
                                 "captures": [str(p) for p in run.captures],
                                 "parts": [r.data for r in results]})
