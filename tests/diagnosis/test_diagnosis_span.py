"""The diagnosis of an on-line record simulates its test, not the operation before it
(`bench_ctl.diagnosis.span`, issue 49: a real export held 86 s before the step, which every
candidate simulated): the record is cut PRE_STEP_S before the step, the machine starts there from
the same operating point, and the diagnosis writes its instants in the whole record's seconds."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from andes_units import online_capture, online_unit
from bench_ctl.capture import Capture
from bench_ctl.diagnosis.diagnose import diagnose
from bench_ctl.diagnosis.span import PRE_STEP_S, cut_to_test
from bench_ctl.identification.construction import make_problem

NOISE = {"noise": 0.01, "q_noise": 0.002, "vt_noise": 0.0005}
PAD_S = 20.0


def padded(cap: Capture, pad_s: float = PAD_S, seed: int = 5) -> Capture:
    """`cap` with `pad_s` more seconds of its pre-step operation in front (each channel's mean
    before the step plus recorder noise of the size its own pre-step part shows), as a real export
    holds it."""
    k = int(round(pad_s / cap.dt))
    rng = np.random.default_rng(seed)
    pre = int(np.flatnonzero(np.abs(cap.usetp - cap.usetp[0]) > 1e-9)[0])

    def front(x: np.ndarray) -> np.ndarray:
        level, sd = float(np.mean(x[:pre])), float(np.std(x[:pre]))
        return np.concatenate([level + (rng.normal(0.0, sd, k) if sd > 0 else np.zeros(k)), x])

    time = np.concatenate([cap.time[0] + (np.arange(k) - k) * cap.dt, cap.time])
    return Capture(time=time, usetp=np.concatenate([np.full(k, cap.usetp[0]), cap.usetp]), efd=front(cap.efd),
                   vt=front(cap.vt), extra={n: front(x) for n, x in cap.extra.items()}, source=cap.source)


def test_an_on_line_record_is_cut_to_its_test_and_a_no_load_one_never():
    cap = online_capture("sexs_xe02")
    long = padded(cap)
    part, k0 = cut_to_test(long)
    k_step = int(np.flatnonzero(np.abs(long.usetp - long.usetp[0]) > 1e-9)[0])
    assert k0 == k_step - int(round(PRE_STEP_S / long.dt)) and part.n == long.n - k0
    np.testing.assert_array_equal(part.efd, long.efd[k0:])
    np.testing.assert_array_equal(part.channel("q"), long.channel("q")[k0:])
    # its own 1 s before the step is shorter than PRE_STEP_S: kept whole; so is a no-load record
    assert cut_to_test(cap) == (cap, 0)
    at_no_load = replace(long, extra={})
    assert cut_to_test(at_no_load) == (at_no_load, 0)


def test_the_cut_record_starts_from_the_same_operating_point_and_responds_the_same():
    """The machine is initialised from the record's P, Q and Vt before the step, which the cut
    keeps: the model's response on the cut record is the whole record's from the cut on."""
    long = padded(online_capture("sexs_xe02", seed=1, **NOISE))
    part, k0 = cut_to_test(long)
    unit = online_unit("sexs_xe02")
    whole, cut = make_problem([long], unit), make_problem([part], unit)
    np.testing.assert_array_equal(whole.records[0].machine, cut.records[0].machine)
    assert whole.records[0].vt0 == cut.records[0].vt0
    a, b = whole.simulate(whole.x_start())[0], cut.simulate(cut.x_start())[0]
    for name in ("efd", "vt", "q"):
        np.testing.assert_allclose(b[name], a[name][k0:], rtol=0, atol=1e-9, err_msg=name)
    # and the model held steady over what was cut: nothing there to fit
    assert np.ptp(a["efd"][:k0]) < 1e-9


@pytest.mark.slow
def test_a_long_pre_step_operation_changes_neither_the_answer_nor_the_record_s_seconds():
    """A capture the model explains (`none`, tests/diagnosis/test_diagnosis_online.py) with 20 s
    more operation before its step: still `none`, its edges and fitted span in the long record's
    seconds."""
    cap = online_capture("sexs_xe02", seed=1, **NOISE)
    long = padded(cap)
    d = diagnose(long, online_unit("sexs_xe02"), seed=0)
    assert d.verdict == "none"
    k0 = cut_to_test(long)[1]
    assert d.validation.fit.t0 == pytest.approx(k0 * cap.dt)
    assert d.validation.fit.t1 == pytest.approx(float(long.time[-1] - long.time[0]))
    pad = long.n - cap.n
    for e, k in zip(d.edges, np.flatnonzero(np.diff(cap.usetp) != 0) + 1):
        assert e.index == k + pad and e.nominal_s == pytest.approx((k + pad) * cap.dt)
