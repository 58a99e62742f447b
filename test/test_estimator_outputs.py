"""What the node publishes after every sample, computed the fast way, against its reference.

The Aligner's ``orientation_values`` / ``covariance`` (floats, the coarse pass's level floor
from running means) must equal, at every sample of a stream, the quaternion of the
vectorised ``quat_from_dcm`` and :meth:`Aligner.covariance_reference` (the covariance
computed from scratch with numpy): bit for bit where no running sum enters, to rounding
where the last second's mean specific force does. The stream holds what breaks running
state: shoves, a shock out of the force range, a short hole, a gap, a time jump, rejected
samples, the backtrack, a restart.
"""
import math

import numpy as np
import pytest

from sins_align.core.rotation import quat_from_dcm, quat_values_from_dcm
from sins_align.estimators.quasi_static.aligner import Aligner, AlignConfig
from sins_align.estimators.quasi_static.monitors import RecentMotion
from sins_align.io.cdr import ImuLayout
from sins_align.sim.simulator import simulate

RATE = 1000.0


def _stream(seconds: float, seed: int, sway: str = "none", specs: str = "navigation"):
    """(t, w, f) per sample, the simulator's samples with trouble put in: shoves within the
    force range, a shock out of it, a short hole, a gap, a time jump, rejected samples."""
    s = simulate(seconds, rate=RATE, seed=seed, rpy_deg=(4.0, -3.0, 40.0), sway=sway,
                 specs=specs)
    t, w, f = s.t.copy(), s.gyro.copy(), s.accel.copy()
    n = len(t)
    for k0, push in ((int(1.5 * RATE), 0.8), (int(9.2 * RATE), 1.5)):   # shoves, 50 ms
        f[k0:k0 + 100, 0] += push
    f[int(3.3 * RATE):int(3.3 * RATE) + 20, 2] += 8.0          # a shock out of the range
    f[int(10.4 * RATE):int(10.4 * RATE) + 20, 2] += 8.0
    keep = np.ones(n, dtype=bool)
    keep[int(2.5 * RATE):int(2.5 * RATE) + 3] = False           # a short hole
    keep[int(4.0 * RATE):int(4.0 * RATE) + 400] = False         # a gap (0.2 s)
    keep[int(11.0 * RATE):int(11.0 * RATE) + 300] = False
    t[int(5.0 * RATE):] += 7.0                                   # a time jump (> max_gap)
    out = []
    for k in np.flatnonzero(keep).tolist():
        out.append((float(t[k]), w[k], f[k]))
        if k % 997 == 5:                                         # rejected samples
            bad = (k // 997) % 3
            if bad == 0:
                out.append((float(t[k]), w[k], f[k]))            # duplicate stamp
            elif bad == 1:
                out.append((float(t[k]) + 1e-4, np.array([math.nan, 0.0, 0.0]), f[k]))
            else:
                out.append((float(t[k]) + 1e-4, w[k], f[k] * 0.01))   # gravity removed
    return out


def _reference(al: Aligner) -> tuple[np.ndarray, np.ndarray]:
    return quat_from_dcm(al.dcm[None])[0], al.covariance_reference()


@pytest.mark.parametrize("sway,specs", [("none", "navigation"), ("ship", "consumer")])
def test_published_orientation_and_covariance_equal_the_reference_at_every_sample(sway, specs):
    """Coarse pass, backtrack at 7 s, fine pass; a heading-unobservable grade (consumer) too.
    The quaternion equals the vectorised one to rounding, the covariance its from-scratch
    computation: bit for bit in the fine pass, to rounding in the coarse pass (where the last
    second's mean force comes from a running sum; that sum is checked on its own below, the
    1 s block means of the last 10 s mostly setting the floor here)."""
    al = Aligner(AlignConfig(latitude_deg=34.0, rate_hz=RATE, backtrack_time=7.0, specs=specs))
    stages, exact, checked = set(), 0, 0
    for i, (t, w, f) in enumerate(_stream(13.0, seed=3, sway=sway, specs=specs)):
        al.update(t, w, f)
        if al.t_last is None:
            continue
        if i == 4500:
            al.reset("test restart")                 # a new filter, a new recent-motion ring
            continue
        vals = al.orientation_values()
        assert type(vals) is list and len(vals) == 13
        q_ref, P_ref = _reference(al)
        np.testing.assert_allclose(vals[:4], q_ref, rtol=0, atol=4e-16)
        P = np.array(vals[4:]).reshape(3, 3)
        np.testing.assert_array_equal(P, al.covariance)
        scale = float(np.max(np.diag(P_ref)))
        np.testing.assert_allclose(P, P_ref, rtol=1e-9, atol=1e-12 * scale)
        np.testing.assert_array_equal(P, P.T)
        if al.filter.backtracked:
            np.testing.assert_array_equal(P, P_ref)
        exact += bool(np.array_equal(P, P_ref))
        stages.add(al.stage)
        checked += 1
    assert stages == {"coarse", "fine"}
    assert checked > 10000
    assert exact > checked // 2
    if specs == "consumer":
        assert not al.heading_observable


def test_second_mean_force_equals_mean_force_over_the_last_second():
    """RecentMotion's running mean of the last second against its sum from scratch, after
    every push and after blocks (extend): irregular intervals, intervals longer than the
    second, a ring that wraps, long stretches without a call."""
    rng = np.random.default_rng(5)
    r = RecentMotion()
    assert r.second_mean_force() is None
    calls = 0
    for step in range(60000):
        kind = step % 5000
        if kind == 4000:                                    # a block of samples
            m = int(rng.integers(1, 3000))
            dts = rng.uniform(2e-4, 8e-4, m)
            r.extend(dts, rng.normal(size=(m, 3)), rng.normal(size=(m, 3)) + [0, 0, 9.8])
        else:
            dt = 1.3 if kind == 2500 else float(rng.uniform(2e-4, 8e-4))
            r.push(dt, rng.normal(size=3), rng.normal(size=3) + [0.0, 0.0, 9.8])
        if 1000 <= kind < 1200:                             # no call for a while
            continue
        got = r.second_mean_force()
        ref = r.mean_force(1.0)
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)
        calls += 1
    assert calls > 50000


def test_quat_values_from_dcm_is_the_vectorised_quaternion():
    """Every Shepperd branch (and the w >= 0 sign): the floats against the vectorised
    function, and the single-DCM array path bit for bit against the floats."""
    from sins_align.core.rotation import dcm_from_quat

    rng = np.random.default_rng(9)
    q = rng.normal(size=(4000, 4))
    q[:1000, 0] *= 50.0           # x largest
    q[1000:2000, 1] *= 50.0       # y largest
    q[2000:3000, 2] *= 50.0       # z largest
    C = dcm_from_quat(q)
    ref = quat_from_dcm(C)
    for c, r in zip(C, ref):
        v = quat_values_from_dcm(c)
        np.testing.assert_allclose(v, r, rtol=0, atol=4e-16)
        assert v[3] >= 0.0
        np.testing.assert_array_equal(quat_from_dcm(c), v)


def test_with_orientation_packs_a_list_as_the_array_path():
    """The node's list of 13 floats gives the same bytes as the array path; a wrong count
    still fails clearly."""
    from sins_align.io.cdr import imu_nbytes

    lay = ImuLayout("imu_link")
    raw = bytes(range(256)) * (imu_nbytes(len("imu_link")) // 256 + 1)
    raw = b"\x00\x01\x00\x00" + raw[4:imu_nbytes(len("imu_link"))]
    raw = raw[:12] + lay.head + raw[12 + len(lay.head):]
    vals = [float(x) for x in np.random.default_rng(1).normal(size=13)]
    assert lay.with_orientation(raw, vals) == lay.with_orientation(raw, np.array(vals))
    with pytest.raises(ValueError):
        lay.with_orientation(raw, vals[:12])


def _close(a, b, what, k):
    a, b = np.asarray(a), np.asarray(b)
    scale = max(float(np.max(np.abs(b))), 1e-300)
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-13 * scale, err_msg=f"{what} at {k}")


def test_one_run_filter_steps_equal_the_stacked_reference():
    """AlignmentFilter.step for one run (2-D products: the node's path) against the same
    filter stacked over two identical runs with a covariance per run (numpy's stacked
    products: the general path), at every sample of a coarse pass, the backtrack and a fine
    pass, with gaps bridged by means, holes and a rotation handed in (as the Aligner does)."""
    from sins_align.core.rotation import dcm_from_rpy, so3_exp
    from sins_align.core.specs import DEG
    from sins_align.estimators.quasi_static.filter import AlignmentFilter

    s = simulate(9.0, rate=RATE, seed=4, rpy_deg=(2.0, 1.0, 30.0), sway="ship")
    cfg = AlignConfig(latitude_deg=34.0, rate_hz=RATE, backtrack_time=5.0)
    C0 = dcm_from_rpy(np.array([0.5, -0.5, 10.0]) * DEG)
    one = AlignmentFilter(cfg, C0[None])
    two = AlignmentFilter(cfg, np.stack([C0, C0]))

    def per_run(fl):
        fl.P = np.broadcast_to(fl.P, (2, 6, 6)).copy()
        fl.S = np.broadcast_to(fl.S, (2, 6, 6)).copy()

    per_run(two)
    dt = 1.0 / RATE
    stages = set()
    for k in range(len(s.t)):
        w, f = s.gyro[k], s.accel[k]
        gap, hole, bridge, dR = 0.0, (0.0, 0.0), None, None
        if k % 1500 == 700:
            gap, hole = 0.05, (1e-10, 1e-6)
            bridge = (s.gyro[k - 200:k].mean(0), s.accel[k - 200:k].mean(0))
        elif k % 1500 == 1100:
            hole = (2e-11, 3e-7)
        elif k % 3 == 0:
            dR = so3_exp(w * dt)                  # (3, 3), as the units check hands it
        was = two.backtracked
        one.step(dt, w[None], f[None], gap, dR, hole, bridge)
        two.step(dt, np.stack([w, w]), np.stack([f, f]), gap, dR, hole, bridge)
        if two.backtracked and not was:
            per_run(two)
        stages.add(one.stage)
        _close(one.C[0], two.C[0], "C", k)
        _close(one.C[0], two.C[1], "C", k)
        _close(one.v[0], two.v[1], "v", k)
        _close(one.P[0], two.P[1], "P", k)
        _close(one.S[0], two.S[1], "S", k)
        _close(one.attitude_covariance(0), one.total_covariance()[0, :3, :3], "cov", k)
    assert stages == {"coarse", "fine"}
    assert one.updates == two.updates > 3
