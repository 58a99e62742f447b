"""A sample rejected (or lost) *before* the backtrack: block feeding and one sample per call
agree.

The rejected sample leaves a double interval in the buffer the backtrack re-runs. Its end
or its midpoint can land exactly on a threshold: a coarse or fine update (the clock in the
update interval reaching the period less half the interval), the backtrack itself (the
time since the first sample reaching ``backtrack_time``), or an interval boundary of the
sway-velocity analysis that picks the fine pass's noise. The per-sample path sums stamp
differences, the block path multiples of its rounded uniform interval; the two clocks
differ by rounding, so on main such a tie went one way in one path and the other way in
the other (the attitude then differed by 0.01-1.7 rad after the backtrack on this ship
sway). Every such clock now counts a tie as reached (``fast_path.reached``).

Fed one sample per call (align_node), in blocks of 100 and 777 samples (fast path), as one
array (replay's summary) and through ``update_states`` (replay --output): the attitude to
1e-9 rad, the covariance to 1e-9 relative, the aligned flag and the rejection counters
equal after every second (every sample for update_states).
"""
from __future__ import annotations

import numpy as np
import pytest

from sins_align.estimators.quasi_static.aligner import AlignConfig, Aligner
from sins_align.sim.simulator import simulate

RATE = 100


@pytest.fixture(scope="module")
def sway():
    return simulate(20.0, rate=RATE, sway="ship", seed=4)


def _bad(s, kind, k):
    t, w, f = s.t.copy(), s.gyro.copy(), s.accel.copy()
    if kind == "nan":
        w[k, 0] = np.nan
    elif kind == "spike":                   # a rate spike above max_angular_rate
        w[k, 2] = 5.0
    else:                                   # the sample lost: the same double interval
        keep = np.arange(len(t)) != k
        t, w, f = t[keep], w[keep], f[keep]
    return t, w, f


def _read(al):
    return al.dcm.copy(), al.covariance.copy(), al.aligned, dict(al.rejected)


def _same(a, b, where):
    assert np.abs(a[0] - b[0]).max() <= 1e-9, where
    np.testing.assert_allclose(a[1], b[1], rtol=1e-9, atol=1e-9 * np.abs(b[1]).max(),
                               err_msg=where)
    assert a[2] == b[2] and a[3] == b[3], where


@pytest.mark.parametrize("kind,k", [
    ("nan", 400),      # the double interval's midpoint on a 1 s boundary (sway analysis)
    ("spike", 400),
    ("nan", 398),      # its end on a coarse and a fine update (0.1 s, 1 s less half of it)
    ("spike", 998),    # its end on the backtrack (10 s less half of it)
    ("drop", 998),     # a lost sample leaves the same double interval
])
def test_rejection_before_backtrack_blocks_equal_one_by_one(sway, kind, k):
    t, w, f = _bad(sway, kind, k)
    cfg = AlignConfig(latitude_deg=34.0, backtrack_time=10.0)
    one = Aligner(cfg)
    ref = []                                # after every sample, one sample per call
    for i in range(len(t)):
        one.update(float(t[i]), w[i], f[i])
        ref.append(_read(one))
    reason = {"nan": {"nonfinite": 1}, "spike": {"rate_too_high": 1}, "drop": {}}[kind]
    assert one.rejected == reason and one.stage == "fine"
    for size in (100, 777):
        al = Aligner(cfg)
        for a in range(0, len(t), size):
            b = min(len(t), a + size)
            al.update(t[a:b], w[a:b], f[a:b])
            _same(_read(al), ref[b - 1], f"blocks of {size}, after sample {b - 1}")
    whole = Aligner(cfg)
    whole.update(t, w, f)
    _same(_read(whole), ref[-1], "one array")
    st = Aligner(cfg).update_states(t, w, f)
    assert st.accepted.sum() == len(t) - len(reason) and (kind == "drop" or not st.accepted[k])
    for i in range(len(t)):
        assert np.abs(st.dcm[i] - ref[i][0]).max() <= 1e-9, i
        np.testing.assert_allclose(st.covariance[i], ref[i][1], rtol=1e-9,
                                   atol=1e-9 * np.abs(ref[i][1]).max(), err_msg=str(i))
    assert list(st.aligned) == [r[2] for r in ref]
