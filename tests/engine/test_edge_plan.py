"""A record's setpoint edges as the engine is given them (bench_ctl/engine/edge_plan.py): built and
checked, decimated with the record, cut at a window's end; the compiled `Edges` tuple itself."""
from __future__ import annotations

import numpy as np
import pytest

from bench_ctl.engine import edge_plan
from bench_ctl.engine.runner import Edges


def _plan() -> Edges:
    return edge_plan.build(np.array([5, 9, 30]), np.array([0.1, -0.1, 0.05]), np.array([0.0049, 0.0088, 0.03]),
                           np.array([0, 1, 2]))


def test_a_plan_is_the_engines_tuple_typed_as_the_compiled_code_takes_it():
    e = _plan()
    assert isinstance(e, Edges)
    assert [a.dtype for a in e] == [np.int64, np.float64, np.float64, np.int64, np.uint8]
    assert all(a.flags.c_contiguous for a in e) and e.window.size == 0   # `run` marks the window
    none = edge_plan.none()
    assert isinstance(none, Edges) and none.index.size == none.jump.size == none.slot.size == 0


@pytest.mark.parametrize(("args", "message"), [
    (([5, 9], [0.1], [0.005, 0.009], [0, 1]), "2 indices, 1 jumps"),
    (([5], [0.1], [0.005], [4]), r"slots must lie in 0..3, got \[4\]"),
    (([0], [0.1], [0.0], [0]), r"index >= 1\), got indices \[0\]"),
])
def test_a_plan_that_cannot_be_run_is_refused_naming_the_values(args, message):
    with pytest.raises(ValueError, match=message):
        edge_plan.build(*(np.asarray(a) for a in args))


def test_decimated_edges_show_at_the_first_kept_sample_and_keep_their_fine_instant():
    e = _plan()
    dt = 1e-3
    d = edge_plan.decimated(e, 4, 6, dt)              # keeps fine samples 2, 6, 10, ...
    # fine 5 -> kept 6 (index 1), fine 9 -> kept 10 (index 2), fine 30 -> kept 30 (index 7)
    assert d.index.tolist() == [1, 2, 7]
    assert d.nominal_s == pytest.approx(e.nominal_s - 2 * dt, abs=1e-15)
    assert d.jump.tolist() == e.jump.tolist() and d.slot.tolist() == e.slot.tolist()
    late = edge_plan.decimated(e, 8, 7, dt)           # keeps fine samples 7, 15, ...: the edge at 5 is before it
    assert late.index.tolist() == [1, 3] and late.slot.tolist() == [1, 2]
    assert edge_plan.decimated(e, 1, 0, dt) is e


def test_upto_keeps_the_edges_inside_the_first_samples():
    e = _plan()
    assert edge_plan.upto(e, 31) is e
    cut = edge_plan.upto(e, 10)
    assert cut.index.tolist() == [5, 9] and cut.nominal_s.tolist() == [0.0049, 0.0088]
