"""Fits side by side (`bench_ctl.identification.threads`): the order of the results, errors, the
thread count, and the engine's entry points that let two fits overlap."""
from __future__ import annotations

import threading

import pytest

from bench_ctl.engine import runner
from bench_ctl.identification import threads
from bench_ctl.identification.threads import ENV, fit_threads, map_fits, set_fit_threads


@pytest.fixture
def two(monkeypatch):
    monkeypatch.delenv(ENV, raising=False)
    set_fit_threads(2)
    yield
    set_fit_threads(None)


def test_results_keep_their_place_and_each_runs_in_order_on_the_caller(two):
    started = threading.Barrier(2, timeout=30)   # both fits run at once, or this times out
    seen = []

    def fn(x):
        if x < 2:
            started.wait()
        return x * x

    out = map_fits(fn, range(6), lambda x, r: seen.append((x, r, threading.current_thread().name)))
    assert out == [0, 1, 4, 9, 16, 25]
    assert [(x, r) for x, r, _ in seen] == [(x, x * x) for x in range(6)]
    assert {name for *_, name in seen} == {threading.current_thread().name}


def test_the_first_error_is_raised(two):
    def fn(x):
        if x in (1, 3):
            raise ValueError(f"candidate {x} cannot be fitted")
        return x

    with pytest.raises(ValueError, match="candidate 1"):
        map_fits(fn, range(8))


def test_one_thread_runs_in_the_callers_thread(monkeypatch):
    monkeypatch.setenv(ENV, "1")
    names = map_fits(lambda _: threading.current_thread().name, range(3))
    assert names == [threading.current_thread().name] * 3


def test_thread_count_from_the_environment_the_setting_or_the_cores(monkeypatch):
    monkeypatch.setenv(ENV, "3")
    assert fit_threads() == 3
    monkeypatch.setenv(ENV, "two")
    with pytest.raises(ValueError, match=f"{ENV}='two'"):
        fit_threads()
    monkeypatch.delenv(ENV)
    set_fit_threads(1)
    try:
        assert fit_threads() == 1
    finally:
        set_fit_threads(None)
    assert 1 <= fit_threads() <= threads.MAX_THREADS
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="fit threads"):
            set_fit_threads(bad)


def test_the_engine_entry_points_release_the_gil():
    # without it two fits' engine calls (and a call's chunks, which run on threads) would take
    # turns like the rest of their Python
    for dispatcher in (runner.new_work, runner.advance):
        assert dispatcher.targetoptions.get("nogil") is True, dispatcher
