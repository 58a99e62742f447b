"""Aligner.update_states (the block path's outputs after every sample) equals feeding the
samples one at a time and reading dcm, covariance and aligned after each: what align_node
publishes. Tolerances: those of the fast path itself (test_fast_path: its gain schedule is
batched, agreeing with the step-by-step recursion to ~1e-9 relative), 1e-9 rad for the
attitude and 1e-8 relative for the covariance; the flags and the rejections are identical."""
import numpy as np
import pytest

from sins_align.core.rotation import attitude_error
from sins_align.estimators.quasi_static.aligner import AlignConfig, Aligner
from sins_align.sim.simulator import simulate


def one_by_one(cfg, t, w, f):
    al = Aligner(cfg)
    n = len(t)
    C, P = np.empty((n, 3, 3)), np.empty((n, 3, 3))
    flags, acc = np.empty(n, bool), np.empty(n, bool)
    for i in range(n):
        r = sum(al.rejected.values())
        al.update(t[i], w[i], f[i])
        acc[i] = sum(al.rejected.values()) == r
        C[i], P[i], flags[i] = al.dcm, al.covariance, al.aligned
    return al, C, P, flags, acc


def assert_equal_states(cfg, t, w, f, chunk=None):
    ref, C, P, flags, acc = one_by_one(cfg, t, w, f)
    al = Aligner(cfg)
    chunk = chunk or len(t)
    parts = [al.update_states(t[k:k + chunk], w[k:k + chunk], f[k:k + chunk])
             for k in range(0, len(t), chunk)]
    dcm = np.concatenate([p.dcm for p in parts])
    cov = np.concatenate([p.covariance for p in parts])
    err = np.abs(attitude_error(C, dcm)).max()
    assert err < 1e-9, err
    rel = (np.abs(P - cov).max(axis=(1, 2)) / np.abs(P).max(axis=(1, 2))).max()
    assert rel < 1e-8, rel
    assert np.array_equal(np.concatenate([p.aligned for p in parts]), flags)
    assert np.array_equal(np.concatenate([p.accepted for p in parts]), acc)
    assert sum(p.used for p in parts) == ref.samples_used == al.samples_used
    assert al.rejected == ref.rejected and al.events == ref.events
    assert al.stage == ref.stage == "fine"
    return flags


@pytest.mark.parametrize("sway", ["none", "car"])
def test_states_equal_one_sample_path_coarse_backtrack_fine(sway):
    """A large initial error (coarse floors from the accelerometer), the backtrack at 40 s,
    the fine pass; static and swaying base; one call and chunks that cut intervals."""
    s = simulate(120, 100, 34.0, rpy_deg=(10, -5, 60), sway=sway, seed=3)
    cfg = AlignConfig(latitude_deg=34.0, backtrack_time=40.0, initial_rpy_deg=(60, -45, 170))
    t = s.t + 100.0
    flags = assert_equal_states(cfg, t, s.gyro, s.accel)
    assert flags.any()
    assert_equal_states(cfg, t, s.gyro, s.accel, chunk=777)


def test_states_equal_with_shove_gap_and_rejections():
    """A shove (gated, absorbed), a 0.3 s gap, a NaN, a duplicate stamp and a too-strong
    force: those samples go one by one, the rest on the block path."""
    s = simulate(120, 100, 34.0, rpy_deg=(1, -2, 30), sway="car", seed=5)
    t = s.t + 100.0
    w, f = s.gyro.copy(), s.accel.copy()
    f[7000:7030, 0] += 3.0                       # a shove in the fine pass
    keep = np.ones(len(t), bool)
    keep[8000:8030] = False                      # a gap
    w[9000] = np.nan
    t[9500] = t[9499]
    f[10000, 2] += 30.0
    t, w, f = t[keep], w[keep], f[keep]
    cfg = AlignConfig(latitude_deg=34.0, backtrack_time=30.0)
    assert_equal_states(cfg, t, w, f)
    ref = one_by_one(cfg, t, w, f)[0]
    assert ref.events["gap"] + ref.events["missing_samples"] >= 1
    assert sum(ref.rejected.values()) >= 2


def test_states_heading_unobservable_and_want():
    """Consumer grade (heading unobservable: the U row and column cleared) and outputs
    asked for some samples only (the others not computed)."""
    s = simulate(90, 100, 34.0, rpy_deg=(1, -2, 30), sway="car", seed=6, specs="consumer")
    cfg = AlignConfig(latitude_deg=34.0, backtrack_time=30.0, specs="consumer")
    assert not Aligner(cfg).heading_observable
    assert_equal_states(cfg, s.t, s.gyro, s.accel)
    _, C, P, flags, _ = one_by_one(cfg, s.t, s.gyro, s.accel)
    want = np.zeros(len(s.t), bool)
    want[::10] = True
    st = Aligner(cfg).update_states(s.t, s.gyro, s.accel, want)
    assert np.abs(attitude_error(C[want], st.dcm[want])).max() < 1e-9
    np.testing.assert_allclose(st.covariance[want], P[want], rtol=1e-8, atol=1e-20)
    assert np.array_equal(st.aligned, flags)
