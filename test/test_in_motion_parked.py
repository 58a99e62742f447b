"""The in-motion aligner on a parked vehicle: the stillness detector and the heading's
consider update (:mod:`sins_align.estimators.in_motion.stillness`).

A MEMS IMU standing still cannot find its heading (its gyro bias hides the Earth rate), and
plain velocity updates gave it heading information that is not there (the standing-MEMS
defect, ``test_in_motion_static_heading.py``): while the detector says parked and the gyro
cannot gyrocompass, the aligner makes the heading a consider state of the velocity updates.
A navigation-grade IMU keeps gyrocompassing."""
import math

import numpy as np
from scipy.stats import chi2

from sins_align.analysis.observability import scenario
from sins_align.core.earth import OMEGA_IE
from sins_align.core.rotation import attitude_error, rpy_from_dcm
from sins_align.core.specs import DEG, DPH, DPSH, UG, UG_PSHZ, SensorSpecs, grade_specs
from sins_align.estimators.in_motion import MotionAligner, MotionConfig
from sins_align.estimators.in_motion.stillness import gyrocompass_limit, is_parked
from sins_align.sim.trajectory import PRESETS, simulate_trajectory

#: the consumer MEMS of the car benchmarks (bench_in_motion.CAR_MEMS)
CAR_MEMS = SensorSpecs(gyro_bias=10.0 * DPH, gyro_arw=0.3 * DPSH, accel_bias=1000 * UG,
                       accel_vrw=100 * UG_PSHZ)
G = 9.80


def _rest(rng, n=100, dt=0.01, specs=CAR_MEMS):
    t = np.arange(n) * dt
    w = rng.normal(0, specs.gyro_arw / math.sqrt(dt), (n, 3)) + [0, 5e-5, 5e-5]
    f = rng.normal(0, specs.accel_vrw / math.sqrt(dt), (n, 3)) + [0, 0, G]
    return t, w, f


def test_detector_on_samples():
    rng = np.random.default_rng(3)
    R = np.eye(3) * 0.05 ** 2
    z0 = np.array([0.02, -0.03, 0.01])
    t, w, f = _rest(rng)
    assert is_parked(z0, R, t, w, f, CAR_MEMS, G, 0.01)
    # a reference that moves (constant velocity: the IMU alone cannot tell)
    assert not is_parked([1.0, 0.0, 0.0], R, t, w, f, CAR_MEMS, G, 0.01)
    assert not is_parked([np.nan] * 3, R, t, w, f, CAR_MEMS, G, 0.01)
    # a slow turn, a vertical acceleration (a horizontal one leaves |f| at g to first
    # order: the reference sees it moving within a second or two), a vibrating engine, too
    # short a window
    assert not is_parked(z0, R, t, w + [0, 0, 2 * DEG], f, CAR_MEMS, G, 0.01)
    assert not is_parked(z0, R, t, w, f + [0, 0, 0.1], CAR_MEMS, G, 0.01)
    assert not is_parked(z0, R, t, 2.0 * w, f, CAR_MEMS, G, 0.01)
    assert not is_parked(z0, R, t, w, 2.0 * f - [0, 0, G], CAR_MEMS, G, 0.01)
    assert not is_parked(z0, R, t[:50], w[:50], f[:50], CAR_MEMS, G, 0.01)


def test_gyrocompass_limit():
    lat = 45.0 * DEG
    assert math.isclose(gyrocompass_limit(OMEGA_IE, 0.0), 1.0)
    assert gyrocompass_limit(10.0 * DPH, lat) / DEG > 50.0                  # MEMS
    assert gyrocompass_limit(grade_specs("navigation").gyro_bias, lat) / DEG < 0.1
    assert gyrocompass_limit(1e-6, math.pi / 2) == math.inf


def test_detector_flags_the_stands_of_a_city_drive_not_the_driving():
    """car_city (stands 15 s, drives, stands 24 s, drives, ends standing 28 s), consumer
    MEMS, blocks of 0.1 s: which velocity updates were taken as parked."""
    traj = PRESETS["car_city"]()
    r = simulate_trajectory(traj, 100.0, CAR_MEMS, seed=0, gnss_rate=10.0, gnss_sigma=0.05)
    al = MotionAligner(MotionConfig(latitude_deg=traj.lat_deg, longitude_deg=traj.lon_deg,
                                    height_m=traj.height_m, specs=CAR_MEMS,
                                    initial_heading_std_deg=180.0, velocity_noise=0.05))
    for tg, vg in zip(r.gnss_t, r.gnss_v):
        al.add_velocity(tg, vg)
    speed, parked = [], []
    for k in range(0, len(r.gyro), 10):
        before = al.events["velocity_parked"]
        al.update(r.t[k + 1:k + 11], r.gyro[k:k + 10], r.accel[k:k + 10])
        speed.append(np.linalg.norm(r.v[max(k - 100, 0):k + 11], axis=1).max())
        parked.append(al.events["velocity_parked"] > before)
    speed, parked = np.array(speed), np.array(parked)
    # never while the car moves faster than the reference's sigma within the last second
    assert not parked[speed > 0.05].any()
    # nearly always once it has stood 1 s (and the filter has started: 1 s)
    standing = speed == 0.0
    standing[:20] = False
    assert standing.sum() > 400
    assert parked[standing].mean() > 0.95
    # and the heading std grows at the stands after driving (it shrank there before)
    assert al.events["velocity_parked"] > 400


def _parked_bank(specs, runs, duration, gnss_sigma, **cfg):
    traj, _ = scenario("static")
    E, S, parked = [], [], []
    for seed in range(runs):
        r = simulate_trajectory(traj, 100.0, specs, seed=seed, gnss_rate=10.0,
                                gnss_sigma=gnss_sigma, duration=duration)
        rng = np.random.default_rng(1000 + seed)
        rpy0 = rpy_from_dcm(r.C[0]) / DEG + [0.0, 0.0, rng.normal(0.0, 10.0)]
        al = MotionAligner(MotionConfig(
            latitude_deg=traj.lat_deg, longitude_deg=traj.lon_deg, height_m=traj.height_m,
            specs=specs, initial_rpy_deg=tuple(rpy0), initial_heading_std_deg=10.0,
            velocity_noise=gnss_sigma, **cfg))
        for tg, vg in zip(r.gnss_t, r.gnss_v):
            al.add_velocity(tg, vg)
        al.update(r.t[1:], r.gyro, r.accel)
        E.append(attitude_error(r.C[len(r.gyro)], al.dcm)[2])
        S.append(math.sqrt(al.covariance[2, 2]))
        parked.append(al.events["velocity_parked"] / al.events["velocity"])
        if cfg.get("vehicle") == "ground":
            assert al.events["nhc_parked"] > 0.95 * al.events["nhc"]
    return np.array(E), np.array(S), np.array(parked)


def test_parked_mems_heading_honest_through_the_aligner():
    """16 parked MEMS runs of 200 s, 1 cm/s reference, heading guessed within 10 deg: the
    heading (e/sigma)^2 at the end within chi-square bounds (without the consider update:
    3.1, std 5.2 deg against an error of 9.3 deg RMS)."""
    K = 16
    e, sd, parked = _parked_bank(CAR_MEMS, K, 200.0, 0.01)
    nees = float(np.mean((e / sd) ** 2))
    lo, hi = chi2.ppf(0.001, K) / K, chi2.ppf(0.999, K) / K
    assert lo < nees < hi, f"heading (e/s)^2 {nees:.2f} outside [{lo:.2f}, {hi:.2f}]"
    assert parked.min() > 0.95


def test_parked_navigation_grade_keeps_gyrocompassing():
    e, sd, parked = _parked_bank(grade_specs("navigation"), 2, 300.0, 0.05)
    assert parked.max() == 0.0
    assert np.all(sd < 0.1 * DEG) and np.all(np.abs(e) < 3.0 * sd)


def test_parked_tactical_gyrocompasses_down_to_its_limit():
    """A 1 deg/h gyro (gyrocompass limit 5.4 deg at 45 deg of latitude) learns its heading
    standing from the 10 deg guess down to about that limit, then holds it (considered)."""
    e, sd, parked = _parked_bank(grade_specs("tactical"), 2, 300.0, 0.05)
    assert np.all(sd < 0.6 * 10.0 * DEG) and np.all(np.abs(e) < 3.0 * sd)
    assert parked.max() > 0.0


def test_parked_ground_vehicle_heading_std_does_not_shrink():
    """With the non-holonomic constraint (a parked car): its heading regressor, the estimated
    body velocity, is noise too, and it is a consider update as well (without that, the
    heading std fell to 8.0 deg in 300 s over 24 runs, velocity updates alone considered)."""
    e, sd, parked = _parked_bank(CAR_MEMS, 4, 300.0, 0.05, vehicle="ground", nhc_axis=1)
    assert np.all(sd > 0.95 * 10.0 * DEG)
