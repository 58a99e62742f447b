"""The single-filter path of InvariantEKF (a bank of K == 1 takes 2-D arrays and Python floats
instead of the batch axis): it must give the numbers of the bank path, to rounding. A bank of
two identical filters runs the bank path; one filter alone the single path; both are fed the
same runs and measurements (every update type, every optional state, nis inflation, the
scheduled feedback), and a bank reduced to one filter in the middle of a pass (the rows of
a pass's sums) is compared with that filter run alone from the start."""
import numpy as np
import pytest

from sins_align.core.rotation import so3_exp
from sins_align.core.strapdown import NavState
from sins_align.estimators.in_motion import InvariantEKF, NoiseModel
from sins_align.estimators.in_motion import filter as filter_module
from sins_align.estimators.in_motion.filter import extra_size
from sins_align.estimators.in_motion.feedback import LqrFeedback, lqr_gain

NOISE = NoiseModel(1e-3, 1e-2, 1e-5, 1e-4)
STATES = ("C", "v", "lat", "lon", "h", "P", "bg", "ba", "lever", "mount", "sf", "sa",
          "nhc_lever", "nhc_mount", "dx", "w_last", "f_last")


def _samples(m, seed):
    rng = np.random.default_rng(seed)
    t = np.arange(m) * 0.01
    gyro = np.c_[0.3 * np.sin(0.7 * t), 0.2 * np.cos(0.4 * t), 0.25 * np.sin(0.3 * t)]
    accel = np.c_[1.5 * np.cos(0.5 * t), np.sin(0.9 * t), 9.8 + 0.3 * np.sin(t)]
    return (np.full(m, 0.01) * (1.0 + 0.05 * np.sin(np.arange(m))),
            gyro + rng.normal(0, 0.01, (m, 3)), accel + rng.normal(0, 0.05, (m, 3)))


def _filter(K, extra, lever, nhc_lever, schedule, C=None, seed=5):
    rng = np.random.default_rng(seed)
    st = NavState(so3_exp(rng.normal(0, 1, 3)), [8.0, -3.0, 0.5], 0.7, 2.0, 250.0)
    n = 12 + 3 * len(extra)
    A = rng.normal(0, 1, (n, n))
    P0 = 1e-3 * (A @ A.T) + np.diag(np.r_[np.full(3, 1e-2), np.full(3, 0.1),
                                          np.full(3, 1e-6), np.full(3, 1e-3),
                                          np.full(n - 12, 1e-2)])
    if C is None:
        C = np.repeat(st.C[None], K, axis=0)
    e = InvariantEKF(st, P0, NOISE, lever_arm=lever, C=C, extra=extra,
                     nhc_lever_arm=nhc_lever)
    if schedule:
        e.schedule = LqrFeedback(lqr_gain(n, 0.7, 9.8, 5.0))
    return e


def _run(e, seed, select=None):
    """Runs of 1 to 25 samples, each followed by a measurement; returns the NIS seen."""
    dt, gyro, accel = _samples(600, seed)
    ends = list(np.cumsum([1, 7, 25, 10, 1, 1, 3, 12, 20, 9, 25, 10, 10, 1, 5]))
    ends = [e_ for e_ in ends if e_ < 600] + [600]
    rng = np.random.default_rng(seed + 1)
    out = []
    for r in e.propagate_runs(dt, gyro, accel, ends):
        if select is not None and r == 0:
            e.select(select)
        z = e.v[0] + rng.normal(0, 0.3, 3)
        kind = r % 5
        if kind == 0:
            out.append(e.update_velocity(z, np.diag([0.04, 0.05, 0.06]))[0])
        elif kind == 1:
            z[2] = np.nan
            out.append(e.update_velocity(z, np.eye(3) * 0.04, nis_limit=1.5)[0])
        elif kind == 2:
            out.append(e.update_lateral(1, 0.1, nis_limit=2.0, slip=0.01, slip_updates=3.0)[0])
        elif kind == 3:
            C_ref = e.C[0] @ so3_exp(rng.normal(0, 0.01, 3))
            out.append(e.update_attitude(C_ref, np.eye(3) * 1e-4)[0])
        else:
            out.append(e.update_velocity(z, np.eye(3) * 1e-4, nis_limit=1.0)[0])
    return np.array(out)


def _assert_same(one, bank, row, rtol=1e-11):
    for k in STATES:
        a, b = getattr(one, k)[0], getattr(bank, k)[row]
        scale = max(np.abs(b).max(), 1e-300)
        assert np.abs(a - b).max() <= rtol * scale, (k, np.abs(a - b).max(), scale)


@pytest.mark.parametrize("extra, lever, nhc_lever, schedule", [
    ((), (0, 0, 0), (0, 0, 0), False),
    (("lever",), (0.4, -0.2, 0.9), (0, 0, 0), False),
    (("lever", "mount", "gyro_scale", "accel_scale", "nhc_lever", "nhc_mount"), (0.4, -0.2, 0.9),
     (-1.2, 0.1, -0.3), False),
    (("gyro_scale", "accel_scale"), (0, 0, 0), (-1.2, 0.1, -0.3), True),
])
def test_one_filter_equals_a_bank_of_identical_filters(extra, lever, nhc_lever, schedule):
    one = _filter(1, extra, lever, nhc_lever, schedule)
    bank = _filter(2, extra, lever, nhc_lever, schedule)
    nis1 = _run(one, 3)
    nis2 = _run(bank, 3)
    assert nis2.shape == (len(nis1), 2)
    np.testing.assert_allclose(nis1[:, 0], nis2[:, 0], rtol=1e-10)
    np.testing.assert_array_equal(nis2[:, 0], nis2[:, 1])
    for row in (0, 1):
        _assert_same(one, bank, row)
    # the measurements moved the state far from its start: the comparison has teeth
    assert np.abs(one.bg[0]).max() > 1e-4
    assert float(np.trace(one.P[0])) < 0.5 * float(np.trace(_filter(1, extra, lever, nhc_lever,
                                                                      schedule).P[0]))


def test_bank_reduced_to_one_filter_within_a_pass_equals_that_filter_alone():
    rng = np.random.default_rng(11)
    Cs = so3_exp(rng.normal(0, 1, (3, 3)))
    extra = ("lever", "gyro_scale")
    bank = _filter(3, extra, (0.4, -0.2, 0.9), (0, 0, 0), False, C=Cs)
    one = _filter(1, extra, (0.4, -0.2, 0.9), (0, 0, 0), False, C=Cs[1:2])
    _run(bank, 4, select=[1])
    _run(one, 4)
    assert bank.K == 1
    # the pass's sums of three filters round differently from those of one (so does the
    # bank path: 5e-11 relative on the velocity after these 15 updates, as before the single
    # path existed); a wrong row or sign would show at 1e-3 and more
    _assert_same(one, bank, 0, rtol=1e-9)


@pytest.mark.parametrize("extra", [(), ("gyro_scale", "accel_scale", "lever")])
def test_one_sample_steps_equal_the_pass_path(extra):
    """A pass of one sample of one filter takes a shortcut (no pass object, floats): the
    same numbers as the pass path (per-filter samples (1, 1, 3) take it) and as a bank of two
    identical filters, sample by sample with updates between."""
    lever = (0.4, -0.2, 0.9) if extra else (0, 0, 0)
    a, b, c = (_filter(K, extra, lever, (0, 0, 0), False) for K in (1, 1, 2))
    dt, gyro, accel = _samples(120, 8)
    rng = np.random.default_rng(9)
    for k in range(120):
        a.propagate(dt[k:k + 1], gyro[k:k + 1], accel[k:k + 1])
        b.propagate(dt[k:k + 1], gyro[None, k:k + 1], accel[None, k:k + 1])
        c.propagate(dt[k:k + 1], gyro[k:k + 1], accel[k:k + 1])
        if k % 10 == 9:
            z = a.v[0] + rng.normal(0, 0.3, 3)
            for e in (a, b, c):
                e.update_velocity(z, np.eye(3) * 0.01)
    _assert_same(a, b, 0, rtol=1e-14)
    _assert_same(a, c, 1)
    assert np.abs(a.bg[0]).max() > 1e-5


@pytest.mark.parametrize("extra, lever, nhc_lever", [
    ((), (0, 0, 0), (0, 0, 0)),
    ((), (0.4, -0.2, 0.9), (-1.2, 0.1, -0.3)),
    (("lever", "latency"), (0, 0, 0), (0, 0, 0)),
    (("lever", "gyro_scale", "nhc_lever", "nhc_mount", "latency"), (0.4, -0.2, 0.9),
     (-1.2, 0.1, -0.3)),
])
def test_float_models_of_one_filter_are_the_bank_arithmetic_bit_for_bit(extra, lever,
                                                                         nhc_lever, monkeypatch):
    """A bank of one filter computes its velocity model and non-holonomic update in Python
    floats (filter.SINGLE_FLOATS): the same numbers, to the bit, as the bank's arithmetic on
    that filter (the in-motion replay's outputs stay those of before), through runs and
    velocity (with a latency, a vehicle's force and rate) and lateral (with and without
    sideslip) updates."""
    dt, gyro, accel = _samples(400, 21)
    ends = list(range(10, 401, 10))
    out = {}
    for floats in (False, True):
        monkeypatch.setattr(filter_module, "SINGLE_FLOATS", floats)
        rng = np.random.default_rng(2)
        st = NavState(so3_exp(rng.normal(0, 1, 3)), [8.0, -3.0, 0.5], 0.7, 2.0, 250.0)
        n = 12 + extra_size(extra)
        A = rng.normal(0, 1, (n, n))
        e = InvariantEKF(st, 1e-3 * (A @ A.T) + 1e-2 * np.eye(n), NOISE, lever_arm=lever,
                         extra=extra, nhc_lever_arm=nhc_lever)
        e.latency = np.array([[0.05]])
        models, nis = [], []
        for r in e.propagate_runs(dt, gyro, accel, ends):
            force = e.f_last + rng.normal(0, 0.5, (1, 3))
            rate = e.w_last + rng.normal(0, 0.05, (1, 3))
            models.append(e.velocity_model(force, rate))
            z = e.v[0] + rng.normal(0, 0.3, 3)
            nis.append(e.update_velocity(z, np.diag([0.04, 0.05, 0.06]), nis_limit=3.0,
                                         force=force, rate=rate)[0])
            nis.append(e.update_lateral(1, 0.1, nis_limit=2.0, slip=0.02 * (r % 2),
                                        slip_updates=3.0)[0])
        out[floats] = (models, nis, {k: getattr(e, k).copy() for k in STATES})
    (m0, n0, s0), (m1, n1, s1) = out[False], out[True]
    for (z0, H0), (z1, H1) in zip(m0, m1):
        np.testing.assert_array_equal(z1, z0)
        np.testing.assert_array_equal(H1, H0)
    np.testing.assert_array_equal(np.array(n1), np.array(n0))
    for k in STATES:
        np.testing.assert_array_equal(s1[k], s0[k], err_msg=k)
    # the updates moved the state: the comparison has teeth
    assert np.abs(s1["bg"][0]).max() > 1e-4
