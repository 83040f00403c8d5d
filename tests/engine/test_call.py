"""The Python side of an engine call: how chunks share the threads, and the edge window."""
from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from bench_ctl import engine
from bench_ctl.engine import edge_plan
from bench_ctl.engine.layout import D_EDGE0, N_DERIVED
from bench_ctl.engine.runner import Edges


def test_the_calling_thread_works_the_chunks_beside_the_pool():
    """Every span runs once; the calling thread runs some of them itself (it does not only wait),
    and no more threads than asked for take part."""
    done: list[tuple[int, int]] = []
    who: set[int] = set()
    lock = threading.Lock()
    gate = threading.Barrier(2, timeout=10)   # both threads hold a span at once: two really work

    def work(lo: int, hi: int) -> None:
        with lock:
            done.append((lo, hi))
            who.add(threading.get_ident())
        if lo < 32:
            gate.wait()

    spans = [(lo, lo + 16) for lo in range(0, 160, 16)]
    engine._share(spans, work, 2)
    assert sorted(done) == spans
    assert threading.get_ident() in who and len(who) == 2


def test_a_helper_s_error_reaches_the_caller():
    caller = threading.get_ident()
    helped = threading.Event()

    def work(lo: int, hi: int) -> None:
        if threading.get_ident() != caller:
            helped.set()
            raise RuntimeError(f"chunk {lo}..{hi} failed")
        assert helped.wait(timeout=10)   # the caller holds its first span until the helper has one

    with pytest.raises(RuntimeError, match="failed"):
        engine._share([(0, 16), (16, 32), (32, 48)], work, 2)


def test_a_call_from_a_pool_thread_does_not_wait_for_a_free_one():
    """The helpers' pool busy with the calling call itself: the caller works every span and the
    helper that never started is cancelled (no dead lock)."""
    done: list[tuple[int, int]] = []
    inner = lambda: engine._share([(0, 16), (16, 32)], lambda lo, hi: done.append((lo, hi)), 2)  # noqa: E731
    engine._pool(1).submit(inner).result(timeout=30)
    assert sorted(done) == [(0, 16), (16, 32)]


def _window_one_edge_at_a_time(D: np.ndarray, edges: Edges, dt: float, T: int) -> np.ndarray:
    """The definition: around each edge, the steps between its nominal sample and every
    candidate's fitted instant, one step either side."""
    win = np.zeros(T, dtype=np.uint8)
    for j in range(edges.index.size):
        ke = [(float(edges.nominal_s[j]) + float(D[c, D_EDGE0 + edges.slot[j]])) / dt for c in range(D.shape[0])]
        lo = math.floor(min(min(ke), float(edges.index[j]))) - 1
        hi = math.ceil(max(max(ke), float(edges.index[j]))) + 1
        win[max(0, lo): max(0, min(T, hi + 1))] = 1
    return win


@pytest.mark.parametrize("seed", range(4))
def test_the_edge_window_marks_the_steps_between_nominal_and_fitted_instants(seed):
    rng = np.random.default_rng(seed)
    dt, T = 1e-3, 400
    D = np.zeros((9, N_DERIVED))
    D[:, D_EDGE0:D_EDGE0 + 3] = rng.uniform(-0.004, 0.003, (9, 3))
    index = np.array([3, 150, 398])   # one near each end of the record: the window is clipped there
    edges = edge_plan.build(index, np.array([0.05, -0.05, 0.02]), index * dt - rng.uniform(0, dt, 3),
                            np.array([0, 2, 1]))
    win = engine.edge_window(D, edges, dt, T)
    assert np.array_equal(win, _window_one_edge_at_a_time(D, edges, dt, T))
    assert win[0] == 1 and win[-1] == 1 and win[60:90].sum() == 0
    assert not engine.edge_window(D, edge_plan.none(), dt, T).any()
