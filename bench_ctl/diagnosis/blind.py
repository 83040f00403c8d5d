"""Blind suite: synthetic captures with one withheld effect, diagnosed and scored.

Each case is the reference unit with random AVR parameters (log-uniform within the unit's
bounds, satisfying its constraints, and giving a realistic pulse response: stable, efd peak
between 1.8 and 6 pu, trough above -4 pu, back near its initial value at the end of the record)
plus at most one effect at a random magnitude chosen so that it shows in the record but stays
physically plausible (see `draw_effect`), and visible: the base model refitted to the noise-free
record with the effect must miss it by at least `VISIBLE` (10 %) of the noise variance, else the
magnitude is drawn again (`visibility`; the count is kept in the case). Two captures are made
with the same unit: the main one (a 5 % pulse of 1 s) and a holdout with another pulse width
(0.5 s or 1.5 s), each with recorder noise 0.01 pu and 12-bit quantisation. The diagnosis sees
only the captures and the reference unit file; the scorer compares its verdict with the withheld effect.
"""
from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from bench_ctl.capture import Capture
from bench_ctl.engine.simulate import RecorderModel, pulse_usetp, simulate
from bench_ctl.identification.constraints import parse_constraints
from bench_ctl.identification.construction import make_problem
from bench_ctl.identification.localize import pulse_edges
from bench_ctl.identification.model_fits import coarse_factor
from bench_ctl.identification.options import PROFILE
from bench_ctl.identification.polish import polish
from bench_ctl.model.effects import EFFECT_NAMES
from bench_ctl.units.unit import Bound, Unit, load_unit

from .diagnosis_file import Diagnosis
from .search import fit, mean

log = logging.getLogger(__name__)

NONE = "none"


@dataclass(frozen=True)
class SuiteConfig:
    rate_hz: float = 1000.0
    duration_s: float = 10.0
    start_s: float = 1.0
    amplitude_pu: float = 0.05
    width_s: float = 1.0
    holdout_widths_s: tuple[float, ...] = (0.5, 1.5)
    noise_pu: float = 0.01


@dataclass(frozen=True, eq=False)
class Case:
    case_id: str
    effect: str                         # the withheld truth ("none" for effect-free)
    effect_params: dict[str, float]
    avr_params: dict[str, float]
    capture: Capture
    holdout: Capture | None             # None: no holdout (the check is the record's windows)
    visibility: float = 0.0             # excess MSE of the refitted base model / noise variance
    redraws: int = 0                    # magnitudes rejected as invisible
    unit: Unit | None = None            # what the diagnosis is told (None: the reference unit file)


def _draw_avr(unit: Unit, rng: np.random.Generator) -> dict[str, float]:
    names = unit.identified_names
    cons = parse_constraints(unit.constraints, names)
    for _ in range(10_000):
        x = {}
        for n, b in unit.identify.items():
            if b.min > 0 and b.max / b.min >= 10:
                x[n] = float(math.exp(rng.uniform(math.log(b.min), math.log(b.max))))
            else:
                x[n] = float(rng.uniform(b.min, b.max))
        v = np.array([x[n] for n in names])
        if all(c.satisfied(v) for c in cons):
            return x
    raise RuntimeError("could not draw AVR parameters satisfying the unit's constraints")


def _with_avr(unit: Unit, avr: Mapping[str, float]) -> Unit:
    return replace(unit, identify={n: Bound(avr[n], b.min, b.max) for n, b in unit.identify.items()})


def _realistic(efd: np.ndarray, fail: int, efd0: float, dt: float) -> bool:
    if fail >= 0 or not np.all(np.isfinite(efd)):
        return False
    peak, trough = float(efd.max()), float(efd.min())
    tail = efd[-int(0.5 / dt):]
    return 1.8 <= peak <= 6.0 and trough >= -4.0 and trough <= 0.4 and float(np.max(np.abs(tail - efd0))) < 0.1


def draw_effect(name: str, rng: np.random.Generator, free: dict[str, np.ndarray]) -> dict[str, float]:
    """Random effect magnitude, visible in the pulse response `free` (efd, dt, ...) yet plausible.

    ceiling_limit: VRMAX cuts 15-40 % off the free efd overshoot, VRMIN 15-40 % off the
    undershoot (each limit active); dead_time 5-50 ms; transducer_lag 20-150 ms; saturation
    S(1.0) 0.03-0.15 with S(1.2)/S(1.0) 2.5-5; rate_limit 15-60 % of the free response's
    steepest slope (2-500 pu/s); setpoint_ramp the 5 % step spread over 50-400 ms;
    recorder_gain 3-10 % high or low; time_skew 5-40 ms.
    """
    efd, dt = free["efd"], float(free["dt"])
    efd0 = float(efd[0])
    if name == "ceiling_limit":
        vrmax = efd0 + (1 - rng.uniform(0.15, 0.40)) * (efd.max() - efd0)
        vrmin = efd0 - (1 - rng.uniform(0.15, 0.40)) * (efd0 - efd.min())
        return {"VRMAX": float(max(vrmax, 1.5)), "VRMIN": float(min(vrmin, 0.5))}
    if name == "dead_time":
        return {"TD": float(rng.uniform(0.005, 0.05))}
    if name == "transducer_lag":
        return {"TR": float(rng.uniform(0.02, 0.15))}
    if name == "saturation":
        s10 = float(rng.uniform(0.03, 0.15))
        return {"S10": s10, "S12": float(s10 * rng.uniform(2.5, 5.0))}
    if name == "rate_limit":
        slope = float(np.max(np.abs(np.diff(efd))) / dt)
        return {"RATE": float(np.clip(rng.uniform(0.15, 0.6) * slope, 2.0, 500.0))}
    if name == "setpoint_ramp":
        return {"RAMP": float(np.clip(0.05 / rng.uniform(0.05, 0.4), 0.01, 10.0))}
    if name == "recorder_gain":
        return {"GAIN": float(1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(0.03, 0.10))}
    if name == "time_skew":
        return {"SKEW": float(rng.uniform(0.005, 0.04))}
    raise ValueError(f"unknown effect {name!r}")


#: an effect counts as visible when the base model refitted to the noise-free record with the
#: effect misses it by at least this share of the recorder noise variance
VISIBLE = 0.1


def visibility(unit: Unit, effect_unit: Unit, avr: Mapping[str, float], cfg: SuiteConfig, seed: int) -> float:
    """Excess MSE that remains when the base model (the unit without the effect, every AVR
    parameter free) is refitted to the noise-free main record with the effect, over the noise
    variance: what the effect adds beyond what the AVR parameters can absorb."""
    t, u = pulse_usetp(amplitude=cfg.amplitude_pu, width=cfg.width_s, start=cfg.start_s,
                       duration=cfg.duration_s, rate=cfg.rate_hz)
    dt = 1.0 / cfg.rate_hz
    efd, _vt, _fail = simulate(effect_unit.values(), u, dt)
    return record_visibility(unit, Capture(t, u, efd), avr, cfg, seed)


def record_visibility(unit: Unit, cap: Capture, avr: Mapping[str, float], cfg: SuiteConfig, seed: int) -> float:
    """Excess MSE of the base model refitted to a noise-free record `cap` (its setpoint edges on
    the samples), over the noise variance; the record may come from any plant."""
    u = cap.usetp
    dt = float(cap.dt)
    p = make_problem([cap], unit, fit_edges=False)   # the edges act on their samples
    edges = pulse_edges(u)
    q = coarse_factor(unit, dt, 0.004)
    coarse = p.decimated(q, n_max=(edges.trail_index or cap.n) + int(round(3.0 / dt)), offset=edges.lead.index)
    x0 = np.array([avr[n] for n in p.names])
    res = fit(coarse, x0=x0, evals=600, seed=seed, polish_evals=150, options=PROFILE)
    f = mean(p, polish(p, res.x, budget=100))
    if not math.isfinite(f):  # no feasible point: the search's own, as it is
        f = float(p.mean_objective(res.x[None])[0])
    return f / cfg.noise_pu ** 2


def _capture(unit: Unit, cfg: SuiteConfig, width: float, seed: int, label: str) -> Capture:
    t, u = pulse_usetp(amplitude=cfg.amplitude_pu, width=width, start=cfg.start_s,
                       duration=cfg.duration_s, rate=cfg.rate_hz)
    efd, vt, fail = simulate(unit.values(), u, 1.0 / cfg.rate_hz)
    if fail >= 0:
        raise RuntimeError(f"{label}: the simulated unit is unstable")
    rng = np.random.default_rng(seed)
    rec = RecorderModel(noise_pu=cfg.noise_pu)
    meta = {"test": {"kind": "pulse", "amplitude": cfg.amplitude_pu, "start": cfg.start_s, "width": width}}
    return Capture(t, u, rec.apply(efd, rng), rec.apply(vt, rng), meta=meta, source=label)


def make_case(effect: str, seed: int, cfg: SuiteConfig = SuiteConfig(), unit: Unit | None = None) -> Case:
    """One blind case: random AVR parameters + `effect` ("none" for none), main + holdout capture."""
    unit = unit or load_unit(None)
    rng = np.random.default_rng(seed)
    dt = 1.0 / cfg.rate_hz
    t, u = pulse_usetp(amplitude=cfg.amplitude_pu, width=cfg.width_s, start=cfg.start_s,
                       duration=cfg.duration_s, rate=cfg.rate_hz)
    redraws = 0
    for _ in range(1000):
        avr = _draw_avr(unit, rng)
        base_unit = _with_avr(unit, avr)
        efd, _vt, fail = simulate(base_unit.values(), u, dt)
        if not _realistic(efd, fail, float(efd[0]), dt):
            continue
        eff_params: dict[str, float] = {}
        cand, vis = base_unit, 0.0
        if effect != NONE:
            for _attempt in range(5):  # a magnitude the AVR parameters absorb is drawn again
                eff_params = draw_effect(effect, rng, {"efd": efd, "dt": dt})
                cand = base_unit.with_effects({effect: eff_params})
                vis = visibility(unit, cand, avr, cfg, seed)
                if vis >= VISIBLE:
                    break
                redraws += 1
            else:
                continue
        widths = cfg.holdout_widths_s
        w_hold = float(widths[int(rng.integers(len(widths)))])
        try:
            main = _capture(cand, cfg, cfg.width_s, seed * 2 + 1, f"blind-{effect}-{seed}")
            hold = _capture(cand, cfg, w_hold, seed * 2 + 2, f"blind-{effect}-{seed}-holdout")
        except RuntimeError:
            continue
        return Case(f"{effect}-{seed}", effect, eff_params, avr, main, hold, vis, redraws)
    raise RuntimeError(f"no realistic unit found for effect {effect} seed {seed}")


def make_suite(cases_per_effect: int, none_cases: int, seed: int = 0,
               effects: Sequence[str] = EFFECT_NAMES, cfg: SuiteConfig = SuiteConfig()) -> list[Case]:
    cases = []
    for i, name in enumerate(list(effects) + [NONE]):
        count = none_cases if name == NONE else cases_per_effect
        for j in range(count):
            cases.append(make_case(name, seed * 100_003 + i * 1009 + j, cfg))
    return cases


@dataclass
class CaseResult:
    case_id: str
    truth: str
    verdict: str
    gap_closed_holdout: float | None
    seconds: float
    cpu_seconds: float = 0.0
    ranking: list[str] = field(default_factory=list)
    ambiguous: list[list[str]] = field(default_factory=list)
    sequence: list[str] = field(default_factory=list)
    explained: list[str] = field(default_factory=list)   # explained_by names, in order


def run_suite(cases: Sequence[Case], diagnose_fn: Callable[..., Diagnosis], *, seed: int = 0,
              progress: Callable[[CaseResult], None] | None = None, **kwargs) -> list[CaseResult]:
    """Diagnose every case blind (the function sees the captures and the unit only: the case's
    when it has one, else the reference unit file)."""
    unit = load_unit(None)
    results = []
    for case in cases:
        t0, c0 = time.perf_counter(), time.process_time()
        diag = diagnose_fn(case.capture, case.unit or unit, holdout=case.holdout, seed=seed, **kwargs)
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
        gap = None
        if case.effect != NONE:
            for e in diag.effects:
                if e.name == case.effect:
                    gap = e.gap_closed_holdout
                    mse_h = e.mse_holdout
                    if gap is None and mse_h is not None and not math.isfinite(mse_h):
                        gap = -math.inf  # the true effect's fit failed on the holdout: it closed nothing
                    gap = e.gap_closed if gap is None else gap
                    if gap is not None and math.isnan(gap):
                        gap = -math.inf  # the base model failed there: no gap measured, a failure
                    break
        r = CaseResult(case.case_id, case.effect, diag.verdict, gap, dt, cpu,
                       [e.name for e in diag.effects],
                       [a.effects for a in diag.ambiguous],
                       [q.added for q in diag.sequence],
                       [q.name for q in diag.explained_by])
        results.append(r)
        if progress:
            progress(r)
    return results


def score(results: Sequence[CaseResult]) -> dict:
    """Confusion matrix (truth -> verdict counts), top-1 over the effect cases, none_correct,
    median holdout gap_closed of the true effect, seconds per capture."""
    labels = list(EFFECT_NAMES) + [NONE]
    confusion = {t: {p: 0 for p in labels} for t in labels}
    every = list(results)
    pairs = [r for r in results if "+" in r.truth]
    results = [r for r in results if "+" not in r.truth]
    for r in results:
        confusion[r.truth][r.verdict if r.verdict in labels else NONE] += 1
    eff = [r for r in results if r.truth != NONE]
    none = [r for r in results if r.truth == NONE]
    gaps = [r.gap_closed_holdout for r in eff if r.gap_closed_holdout is not None]
    return {
        "cases": len(results),
        "top1": (sum(r.verdict == r.truth for r in eff) / len(eff)) if eff else None,
        "top1_correct": sum(r.verdict == r.truth for r in eff),
        "effect_cases": len(eff),
        "none_correct": sum(r.verdict == NONE for r in none),
        "none_cases": len(none),
        "median_gap_closed": float(np.median(gaps)) if gaps else None,
        "seconds_per_capture": float(np.mean([r.seconds for r in every])) if every else None,
        "seconds_per_capture_median": float(np.median([r.seconds for r in every])) if every else None,
        "cpu_seconds_per_capture": float(np.mean([r.cpu_seconds for r in every])) if every else None,
        "extra_effects_in_sequence": sum(len(r.sequence) > 1 for r in results),
        "none_with_explained_by": sum(bool(r.explained) for r in results if r.truth == NONE),
        "pair_cases": len(pairs),
        "pair_both_explained": sum(set(r.truth.split("+")) <= set(r.explained) for r in pairs),
        "pair_by_kind": {k: [sum(set(r.truth.split("+")) <= set(r.explained) for r in pairs if r.truth == k),
                             sum(r.truth == k for r in pairs)] for k in sorted({r.truth for r in pairs})},
        "confusion": confusion,
    }
