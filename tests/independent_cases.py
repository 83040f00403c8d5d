"""Blind-suite cases drawn from the independent plant (tests/independent_plant.py).

The same shape as `bench_ctl.diagnosis.blind.make_case` (random AVR parameters, one withheld
effect at a visible but plausible magnitude or none, a main 5 %/1 s pulse and a holdout pulse of
another width), but every record comes from the independent plant, each setpoint edge at its own
random instant inside its sample interval (`edges="inside"`), a whole sample early (`"early"`) or
on the sample (`"on"`). With the effect the response must still settle (a slew limit can drive the
loop into a limit cycle: drawn again). Visibility is judged on a noise-free record with the edges on the samples,
so that it measures the effect and not the edge timing. Several effects may be withheld at once
(`effect="saturation+ceiling_limit"`). With `one_regime`, an effect's evidence lies in one regime of
the record (`independent_plant.draw_one_regime`: saturation seen on the plateau, a ceiling reached on
the leading edge only).
"""
from __future__ import annotations

import numpy as np

import independent_plant as ip
from bench_ctl.capture import Capture
from bench_ctl.diagnosis.blind import NONE, VISIBLE, Case, SuiteConfig, record_visibility
from bench_ctl.units.unit import Unit, load_unit


def _capture(rec: ip.Record, label: str, test: ip.Test) -> Capture:
    meta = {"test": {"kind": "pulse", "amplitude": test.amplitude_pu, "start": test.on_s, "width": test.width_s},
            "source": "independent plant (tests/independent_plant.py)"}
    return Capture(rec.time, rec.usetp, rec.efd, rec.vt, meta=meta, source=label)


def _settles(efd: np.ndarray, dt: float) -> bool:
    """A pulse response a commissioning test gives: within +-10 pu and back within 0.1 pu of its
    initial value in the last 0.5 s (as bench_ctl.diagnosis.blind's realistic responses)."""
    tail = efd[-int(0.5 / dt):]
    return bool(np.all(np.isfinite(efd)) and np.max(np.abs(efd)) <= 10.0 and np.max(np.abs(tail - efd[0])) < 0.1)


def independent_case(effect: str, seed: int, cfg: SuiteConfig = SuiteConfig(),  # noqa: B008 - frozen
                     edges: str = "inside",
                     unit: Unit | None = None, one_regime: bool = False) -> Case:
    """One blind case from the independent plant; `effect` is a name, "a+b" or "none"."""
    draw = ip.draw_one_regime if one_regime else ip.draw_effect
    unit = unit or load_unit(None)
    rng = np.random.default_rng([seed, 0x1DCA5E])
    dt = 1.0 / cfg.rate_hz
    rec_cfg = ip.Recorder(rate_hz=cfg.rate_hz, duration_s=cfg.duration_s, noise_pu=cfg.noise_pu, bits=12)
    clean_cfg = ip.Recorder(rate_hz=cfg.rate_hz, duration_s=cfg.duration_s, noise_pu=0.0, bits=0)
    nominal = ip.Test(on_s=cfg.start_s, amplitude_pu=cfg.amplitude_pu, width_s=cfg.width_s)
    names = [] if effect == NONE else effect.split("+")
    redraws = 0
    for _ in range(100):
        avr = ip.draw_avr(rng)
        free = ip.Plant(avr).run(nominal, clean_cfg).truth["efd_clean"]
        params: dict[str, float] = {}
        vis = 0.0
        if names:
            for _attempt in range(5):
                params = {}
                for name in names:
                    params.update(draw(name, rng, free, dt))
                clean = ip.Plant({**avr, **params}).run(nominal, clean_cfg)
                if not _settles(clean.efd, dt):   # e.g. a slew limit that drives the loop into a limit cycle
                    redraws += 1
                    continue
                vis = record_visibility(unit, Capture(clean.time, clean.usetp, clean.efd), avr, cfg, seed)
                if vis >= VISIBLE:
                    break
                redraws += 1
            else:
                continue
        w_hold = float(cfg.holdout_widths_s[int(rng.integers(len(cfg.holdout_widths_s)))])
        plant = ip.Plant({**avr, **params})
        t_main = ip.random_edges(rng, nominal, dt, edges)
        t_hold = ip.random_edges(rng, ip.Test(on_s=cfg.start_s, amplitude_pu=cfg.amplitude_pu, width_s=w_hold),
                                 dt, edges)
        label = f"independent-{effect}{'-one-regime' if one_regime else ''}-{seed}"
        main = _capture(plant.run(t_main, rec_cfg, seed=seed * 2 + 1), label, t_main)
        hold = _capture(plant.run(t_hold, rec_cfg, seed=seed * 2 + 2), label + "-holdout", t_hold)
        return Case(f"{effect}-{seed}", effect, params, avr, main, hold, vis, redraws)
    raise RuntimeError(f"no visible {effect} case found for seed {seed}")


def independent_suite(cases_per_effect: int, none_cases: int, seed: int = 0, effects=None,
                      cfg: SuiteConfig = SuiteConfig(),  # noqa: B008 - frozen
                      edges: str = "inside", one_regime: bool = False) -> list[Case]:
    from bench_ctl.model.effects import EFFECT_NAMES

    cases = []
    for i, name in enumerate(list(effects or EFFECT_NAMES) + [NONE]):
        for j in range(none_cases if name == NONE else cases_per_effect):
            cases.append(independent_case(name, seed * 100_003 + i * 1009 + j, cfg, edges,
                                          one_regime=one_regime and name != NONE))
    return cases
