"""The one edge finder (bench_ctl.signals.edges.find_edges): a recorded setpoint's edges, and a
test's edges in the channels that respond to it (regulator output, efd, Vt) on records the
independent plant made, sampled with jitter and noise, the edges at known sub-sample instants.
The found interval must contain the true instant, over seeds; the views built on it (the report's
PulseEdges, the plausibility checks) keep their meaning."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bench_ctl.capture.plausible import setpoint_edges
from bench_ctl.engine.simulate import pulse_usetp
from bench_ctl.records import FormatError
from bench_ctl.report.metrics import edge_times
from bench_ctl.signals.edges import EXCITER, SETPOINT, VOLTAGE, Edge, find_edges, find_setpoint_edges
from edge_exports import fine_response, sampled

SEEDS = range(12)


def test_a_recorded_setpoint_pulse_step_and_flat_record():
    t, u = pulse_usetp(amplitude=0.05, width=1.0, start=1.5, duration=5.0, rate=200.0)
    s = find_edges(t, u, kind=SETPOINT)
    assert [e.index for e in s.edges] == [300, 500] == find_setpoint_edges(u).tolist()
    lead, trail = s.pulse()
    assert (lead.sign, trail.sign) == (1, -1)
    assert lead.jump_pu == pytest.approx(0.05) and trail.jump_pu == pytest.approx(-0.05)
    # a recorded jump happened in (t[k-1], t[k]]: the interval is that sample interval
    assert (lead.earliest_s, lead.latest_s) == (t[299], t[300])
    step = np.where(t >= 2.0, 0.98, 1.0)
    lead, trail = find_edges(t, step, kind=SETPOINT).pulse()
    assert lead.index == 400 and lead.sign == -1 and trail is None
    assert find_edges(t, np.ones_like(t)).edges == ()
    # one type for an edge: the finder's writes as a result's edge, its levels held in memory only
    written = s.edges[0].to_json()
    assert list(written) == ["index", "jump_pu", "nominal_s", "fitted_s", "offset_s", "std_s", "lo_s", "hi_s",
                             "how", "fitted"]
    assert written["how"] == "found" and written["hi_s"] == 0.0 and written["nominal_s"] == t[300]
    back = Edge.from_json(written)
    assert back.index == 300 and back.sign == 1 and math.isnan(back.level_before)
    with pytest.raises(FormatError, match="unknown key.*'departure'"):
        Edge.from_json({**written, "departure": 0.05})
    assert find_edges(t[:5], u[:5]).edges == ()


def test_a_noisy_recorded_setpoint_and_its_one_sample_blip():
    rng = np.random.default_rng(0)
    t, u = pulse_usetp(amplitude=0.05, width=0.5, start=1.0, duration=3.0, rate=1000.0)
    noisy = u + rng.normal(0.0, 1e-4, u.size)
    noisy[200] += 0.05   # one bad sample is no edge
    assert [e.index for e in find_edges(t, noisy, kind=SETPOINT).edges] == [1000, 1500]


def test_the_views_on_it_keep_their_meaning():
    t, u = pulse_usetp(amplitude=-0.02, width=0.3, start=0.5, duration=2.0, rate=1000.0)
    e = find_edges(t, u, kind=SETPOINT)     # as the report finds them
    assert (e.lead.index, e.trail_index, *edge_times(e)) == (500, 800, 0.5, 0.8)
    assert e.lead.jump_pu == pytest.approx(-0.02)
    assert setpoint_edges(u).tolist() == [500, 800]
    ramp = u.copy()
    ramp[500:503] = [0.995, 0.99, 0.985]     # a change spread over adjacent samples is one edge
    assert setpoint_edges(ramp).tolist() == [500, 800]


@pytest.mark.parametrize("channel, kind, rate_hz, samples", [
    ("vr", EXCITER, 208.0, 0.6), ("efd", EXCITER, 208.0, 1.3), ("vt", VOLTAGE, 208.0, 10.0),
    ("vr", EXCITER, 1000.0, 0.6), ("efd", EXCITER, 1000.0, 2.0), ("vt", VOLTAGE, 1000.0, 40.0)])
def test_the_found_interval_holds_the_true_instant(channel, kind, rate_hz, samples):
    """A pulse of the independent plant, sampled with 4 % jitter (none at 1 kHz) and noise, its
    edges anywhere in a sample interval: each found interval holds the true instant, and is
    about a sample wide for the exciter's channels (Vt lags: wider, as honest)."""
    fine = fine_response(0.05, 1.5)
    for seed in SEEDS:
        t, ch, truth = sampled(fine, seed=seed, rate_hz=rate_hz, jitter=0.04 if rate_hz < 500 else 0.0)
        s = find_edges(t, ch[channel], kind=kind, channel=channel)
        assert len(s.edges) == 2, (seed, s.edges)
        lead, trail = s.pulse(1)
        for e, true_s in zip((lead, trail), truth):
            assert e.earliest_s <= true_s <= e.latest_s, (seed, e, true_s)
            assert e.uncertainty_s <= samples / rate_hz, (seed, e.uncertainty_s * rate_hz)


@pytest.mark.parametrize("channel, kind", [("vr", EXCITER), ("efd", EXCITER), ("vt", VOLTAGE)])
def test_a_step_down_and_a_pulse_into_the_ceiling(channel, kind):
    """A negative step (no return) and a pulse that drives the exciter into its ceiling and floor
    (held there for 0.2 s): the channel coming off its limit is no edge."""
    down = fine_response(-0.05, None)
    ceiling = fine_response(0.1, 1.0, vrmax=3.0, vrmin=-1.0)
    for seed in SEEDS:
        t, ch, truth = sampled(down, seed=seed)
        s = find_edges(t, ch[channel], kind=kind)
        assert [e.sign for e in s.edges] == [-1] and s.edges[0].earliest_s <= truth[0] <= s.edges[0].latest_s
        t, ch, truth = sampled(ceiling, seed=seed)
        s = find_edges(t, ch[channel], kind=kind)
        assert [e.sign for e in s.edges] == [1, -1], (seed, s.edges)
        assert all(e.earliest_s <= true_s <= e.latest_s for e, true_s in zip(s.edges, truth))


def test_noise_alone_has_no_edge_and_the_search_says_how():
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.0046, 0.005, 3000))
    s = find_edges(t, 0.37 + rng.normal(0.0, 0.006, t.size), kind=EXCITER, channel="efd")
    assert s.edges == ()
    assert s.noise == pytest.approx(0.006, rel=0.15) and s.threshold == pytest.approx(5 * s.noise)
    assert "steady samples" in s.method() and "limit" in s.method()
    with pytest.raises(ValueError, match="channel kind"):
        find_edges(t, t, kind="power")
