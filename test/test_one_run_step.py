"""The one-run step (N = 1, the node's and replay's per-sample path) keeps the velocity and
its interval sum on floats; the N-run step computes them with numpy on stacked arrays. Both
must give the same state (the C products differ in rounding only: 2-D against stacked)."""
import numpy as np
import pytest

from sins_align.estimators.quasi_static.aligner import AlignConfig, AlignmentFilter
from sins_align.core.rotation import dcm_from_rpy, so3_exp
from sins_align.sim.simulator import simulate
from sins_align.core.specs import DEG


def test_one_run_step_equals_stacked_runs():
    s = simulate(75.0, 100.0, 34.0, specs="navigation", seed=3)
    cfg = AlignConfig(latitude_deg=34.0, backtrack_time=30.0)
    C0 = s.C0 @ dcm_from_rpy(np.array([2.0, -3.0, 20.0]) * DEG).T
    one = AlignmentFilter(cfg, C0[None], fast_backtrack=False)
    two = AlignmentFilter(cfg, np.stack([C0, C0]), fast_backtrack=False)
    v_one, v_two, vs_one, vs_two = [], [], [], []
    for k in range(len(s.t) - 1):
        gap = 0.02 if k in (500, 4000) else 0.0          # holes in both passes
        hole = (1e-10, 1e-8) if gap else (0.0, 0.0)
        for fl in (one, two):
            n = fl.n
            fl.step(0.01, np.repeat(s.gyro[k][None], n, 0), np.repeat(s.accel[k][None], n, 0),
                    gap, hole=hole)
        v_one.append(one.v[0].copy())
        v_two.append(two.v[1].copy())
        vs_one.append(one.v_sum[0].copy())
        vs_two.append(two.v_sum[1].copy())
        np.testing.assert_allclose(one.C[0], two.C[1], rtol=0, atol=1e-12)
    assert one.backtracked and two.backtracked and one.fine and one.updates > 30
    np.testing.assert_allclose(np.array(v_one), np.array(v_two), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.array(vs_one), np.array(vs_two), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(one.P[0], two.P[-1], rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize("model", ["constant", "conventional"])
def test_step_one_is_step_bit_for_bit(model):
    """AlignmentFilter.step_one (the Aligner's ordinary sample) against step, the reference,
    over the coarse pass, the backtrack and the fine pass: the same numbers exactly."""
    s = simulate(45.0, 100.0, 34.0, specs="navigation", seed=5)
    cfg = AlignConfig(latitude_deg=34.0, model=model, backtrack_time=20.0)
    C0 = (s.C0 @ dcm_from_rpy(np.array([5.0, -4.0, 60.0]) * DEG).T)[None]
    ref, one = AlignmentFilter(cfg, C0), AlignmentFilter(cfg, C0)
    for k in range(len(s.t) - 1):
        w, f = s.gyro[k], s.accel[k]
        dR = so3_exp(w * 0.01) if k % 2 else None          # given by the caller, or not
        ref.step(0.01, w[None], f[None], dR=dR)
        one.step_one(0.01, w, f, dR)
        for name in ("C", "v", "v_sum", "P", "S"):
            np.testing.assert_array_equal(getattr(one, name), getattr(ref, name), name)
        assert (one.t_int, one.t_acc, one.updates, one.stage) == (
            ref.t_int, ref.t_acc, ref.updates, ref.stage)
    np.testing.assert_array_equal(one.nis_mean, ref.nis_mean)
    assert one.backtracked and one.updates > 20
