"""The estimator on the real ring-laser-gyro log of the paper's car test (the project's copy,
sins_align/data/psins-lasergyro).

There is no attitude reference, so (as in the paper, section 3.2) the checks are consistency
checks, each with a bound from the estimator's own covariance:
- a start from [89, 89, 179] deg must end where a small-error start ends;
- that far start must land, within its published std, on an independent inertial-frame
  alignment of the same samples (test/inertial_alignment.py; it shares no code with the
  estimator and is checked against the simulator's truth in test_inertial_alignment.py);
- the heading found in the swaying first 300 s must agree with the calm 600-960 s segment.
"""
import numpy as np
import pytest

from inertial_alignment import inertial_frame_alignment
from sins_align.data import LASERGYRO
from sins_align.core.earth import gravity
from sins_align.estimators.quasi_static.aligner import Aligner, AlignConfig
from sins_align.io.psins import psins_att_to_dcm, read_psins
from sins_align.core.rotation import attitude_error, dcm_from_rpy, rpy_from_dcm
from sins_align.core.specs import DEG


@pytest.fixture(scope="module")
def log():
    return read_psins(LASERGYRO)


# header coarse attitude: PSINS [pitch, roll, yaw] = [0, 0, -90.6] deg, body axes R-F-U
def small_start():
    return psins_att_to_dcm(np.array([0.0, 0.0, -90.6]) * DEG)


def far_start():
    return small_start() @ dcm_from_rpy(np.array([89.0, 89.0, 179.0]) * DEG)


def span(log, t0, t1):
    i0, i1 = int(round(t0 / log.ts)), int(round(t1 / log.ts))
    return log.t[i0:i1], log.gyro[i0:i1], log.accel[i0:i1]


def align(log, C_init, t0, t1):
    cfg = AlignConfig(latitude_deg=log.lat_rad / DEG, height_m=log.height_m,
                      initial_rpy_deg=tuple(rpy_from_dcm(C_init) / DEG))
    al = Aligner(cfg)
    al.update(*span(log, t0, t1))
    return al


def noise_std(al):
    """The filter's own (noise) std per axis, rad: the published covariance without the
    bias floor. Two results from the same IMU share its biases, so this is the scale of
    what can tell them apart."""
    return np.sqrt(np.diag(al.filter.P[0, :3, :3]))


def fwd(C):
    """True heading of the body y (forward) axis, deg."""
    return np.degrees(np.arctan2(C[0, 1], C[1, 1])) % 360


@pytest.fixture(scope="module")
def first_300(log):
    return align(log, small_start(), 0, 300), align(log, far_start(), 0, 300)


def test_swaying_300s_large_error_matches_small_error(first_300):
    """0-300 s (people getting in and out): the start leaves no trace the data could show.
    From small + [89, 89, 179] deg the result differs from the small-error start by less
    than a tenth of the filter's own noise std on every axis (heading 0.0019 deg, level
    1.1e-5 deg; README: measured 0.0008 and < 0.00001 deg). Before: 0.05 / 0.01 deg."""
    small, big = first_300
    phi = attitude_error(small.dcm, big.dcm)
    assert np.all(np.abs(phi) < 0.1 * noise_std(small)), (phi / DEG, noise_std(small) / DEG)
    assert small.aligned and big.aligned


def test_far_start_lands_on_an_independent_alignment(log, first_300):
    """From 179 deg off in heading (and 89/89 deg in level) the estimate at 300 s agrees with
    an inertial-frame alignment of the same 30,000 samples within 3 sigma of its published
    std on every axis (heading 0.15 deg, level 0.017 deg; before: the forward axis anywhere
    in 89-92 deg, which the small start passes without moving). The reference is biased by
    the gyro and accelerometer biases as the estimator is, so this bound is generous."""
    _, big = first_300
    t, w, f = span(log, 0, 300)
    ref = inertial_frame_alignment(log.ts, w, f, log.lat_rad, gravity(log.lat_rad,
                                                                      log.height_m))
    # the start was far from it: a result that never moved would fail
    assert np.linalg.norm(attitude_error(ref, far_start())) > 90 * DEG
    phi = attitude_error(ref, big.dcm)
    sd = big.std_enu_deg * DEG
    assert np.all(np.abs(phi) < 3 * sd), (phi / DEG, sd / DEG)


def test_heading_is_consistent_with_calm_segment(log, first_300):
    """The calm 600-960 s segment, 5 minutes later, gives the same forward-axis heading as the
    swaying 0-300 s: both segments share the IMU's biases, so they may differ by their noise
    only, 3 x hypot of the two noise stds (0.074 deg; README: 0.03 deg measured; before:
    0.1 deg)."""
    small, _ = first_300
    calm = align(log, small_start(), 600, 960)
    d = fwd(calm.dcm) - fwd(small.dcm)
    allow = 3 * np.hypot(noise_std(calm)[2], noise_std(small)[2]) / DEG
    assert abs(d) < allow, (fwd(calm.dcm), fwd(small.dcm), allow)
    assert calm.aligned


def test_real_data_fits_the_quasi_static_model(first_300):
    """No sample is rejected, the deg/s check stays quiet, the innovations fit (not
    'disturbed') and the measured sway velocity noise is mm/s, as for a parked car."""
    small, _ = first_300
    sm = small.summary()
    assert sm["rejected"] == {} and sm["status"] == "aligned"
    assert max(sm["fine_velocity_noise_mps"]) < 0.01
