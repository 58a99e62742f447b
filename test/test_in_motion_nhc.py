"""The non-holonomic constraint at the rear axle (in-motion honesty): a car's IMU ahead of its
rear axle moves sideways at yaw rate x distance in every turn, which the constraint must not
take for a heading error. Its model against finite differences, and car_city with the IMU
1.5 m ahead of the axle: honest with the lever arm estimated (the default) or given, and
not with the constraint at the IMU (the test's teeth)."""
import numpy as np
import pytest

from sins_align.core.rotation import (attitude_error, dcm_from_rpy, rpy_from_dcm,
                                      so3_exp)
from sins_align.core.specs import DPH, DPSH, UG, UG_PSHZ, SensorSpecs
from sins_align.core.strapdown import NavState, earth_rate, transport_rate
from sins_align.estimators.in_motion import InvariantEKF, MotionAligner, MotionConfig
from sins_align.estimators.in_motion.filter import NoiseModel
from sins_align.sim.trajectory import (Segment, Trajectory, car_city,
                                      simulate_trajectory)

from motion_helpers import fed_in_blocks

CAR_MEMS = SensorSpecs(gyro_bias=10.0 * DPH, gyro_arw=0.3 * DPSH, accel_bias=1000 * UG,
                       accel_vrw=100.0 * UG_PSHZ)


def _lateral(e, axis=1):
    """The lateral velocity of the non-holonomic point that an estimate predicts."""
    C, v = e.C[0], e.v[0]
    w_in = earth_rate(e.lat[0]) + transport_rate(v, e.lat[0], e.h[0])
    w_nb = e.w_last[0] - C.T @ w_in
    return (C.T @ v + np.cross(w_nb, e.nhc_lever[0]))[axis]


def _numeric_h(truth, st, predicted, eps=1e-6):
    """-d predicted / d x by central differences: each error state of ``truth`` (an
    InvariantEKF of one filter at the NavState ``st``, error = estimate - truth; attitude
    and the vehicle mounting on the right / left of the estimate as the filter has them)."""
    n = truth.n
    num = np.zeros(n)
    for i in range(n):
        out = []
        for s in (1.0, -1.0):
            dx = np.zeros(n)
            dx[i] = s * eps
            e = truth.copy()
            e.C[0] = st.C @ so3_exp(dx[0:3])
            e.v[0] = st.v + st.C @ dx[3:6]
            e.bg[0] = truth.bg[0] + dx[6:9]
            e.w_last[0] = truth.w_last[0] - dx[6:9]
            e.ba[0] = truth.ba[0] + dx[9:12]
            e.nhc_lever[0] = truth.nhc_lever[0] + dx[12:15]
            if truth.i_nhm is not None:
                e.nhc_mount[0] = so3_exp(dx[truth.i_nhm]) @ truth.nhc_mount[0]
            out.append(predicted(e))
        num[i] = -(out[0] - out[1]) / (2 * eps)
    return num


def test_constraint_model_matches_finite_differences():
    """H of the constraint at a lever arm (attitude, velocity, gyro bias, lever arm rows)
    against central differences of the predicted lateral velocity; the filter's update uses
    that H (a unit-covariance update with a huge noise moves P along H H^T)."""
    rng = np.random.default_rng(5)
    st = NavState(so3_exp(rng.normal(0, 1, 3)), [10.0, -3.0, 1.0], 0.6, 1.9, 100.0)
    n = 15
    zero = NoiseModel(0.0, 0.0, 0.0, 0.0)
    truth = InvariantEKF(st, np.zeros((n, n)), zero, extra=("nhc_lever",),
                         nhc_lever_arm=(-1.5, 0.3, 0.4))
    truth.w_last[0] = [0.3, -0.5, 0.8]
    num = _numeric_h(truth, st, _lateral)
    assert np.abs(num[12:15]).max() > 0.5 and np.abs(num[6:9]).max() > 0.3
    probe = truth.copy()
    probe.P[0] = np.eye(n)
    probe.update_lateral(1, 1e6)
    dP = np.eye(n) - probe.P[0]
    HH = np.outer(num, num)
    assert np.allclose(dP / np.abs(dP).max(), HH / np.abs(HH).max(), atol=1e-6)


def _side_velocity(e, axis=1):
    """The velocity along the vehicle's side, ``exp(eps x) e_axis``, that an estimate with the
    nhc_mount states predicts (at the non-holonomic point)."""
    C, v = e.C[0], e.v[0]
    w_in = earth_rate(e.lat[0]) + transport_rate(v, e.lat[0], e.h[0])
    w_nb = e.w_last[0] - C.T @ w_in
    return e.nhc_mount[0][:, axis] @ (C.T @ v + np.cross(w_nb, e.nhc_lever[0]))


@pytest.mark.parametrize("axis", [1, 0])
def test_constraint_model_with_the_mounting_states_matches_finite_differences(axis):
    """H of the constraint along a vehicle's side rotated against the IMU (nhc_mount: here
    (2, -3, 6) deg estimated) against central differences of the predicted side velocity;
    the mounting's error is a rotation on the left of its estimate (exp(d x) exp(eps x))."""
    rng = np.random.default_rng(8)
    st = NavState(so3_exp(rng.normal(0, 1, 3)), [10.0, -3.0, 1.0], 0.6, 1.9, 100.0)
    n = 18
    zero = NoiseModel(0.0, 0.0, 0.0, 0.0)
    truth = InvariantEKF(st, np.zeros((n, n)), zero, extra=("nhc_lever", "nhc_mount"),
                         nhc_lever_arm=(-1.5, 0.3, 0.4))
    truth.w_last[0] = [0.3, -0.5, 0.8]
    truth.nhc_mount = so3_exp(np.radians([2.0, -3.0, 6.0]))[None]
    num = _numeric_h(truth, st, lambda e: _side_velocity(e, axis))
    # the mounting's rows are there, and its component along the side is not
    assert np.abs(num[15:18]).max() > 0.05
    assert abs(num[15:18] @ truth.nhc_mount[0][:, axis]) < 1e-6
    probe = truth.copy()
    probe.P[0] = np.eye(n)
    probe.update_lateral(axis, 1e3)      # (dP = H^T H / (H H^T + R) for any R)
    dP = np.eye(n) - probe.P[0]
    HH = np.outer(num, num)
    assert np.allclose(dP / np.abs(dP).max(), HH / np.abs(HH).max(), atol=1e-6)
    # the feedback composes the rotation: an error d fed back leaves exp(-d x) exp(eps x)
    d = np.zeros(n)
    d[15:18] = [0.01, 0.02, -0.03]
    fed = truth.copy()
    fed.feedback(d[None])
    np.testing.assert_allclose(fed.nhc_mount[0], so3_exp(-d[15:18]) @ truth.nhc_mount[0],
                               atol=1e-14)


def _drive(seed, imu_position, seconds=150.0, sideslip_deg=0.0, **cfg):
    traj = car_city(sideslip_deg=sideslip_deg)
    r = simulate_trajectory(traj, 100.0, CAR_MEMS, seed=seed, gnss_rate=10.0, gnss_sigma=0.05,
                            duration=seconds, imu_position=imu_position)
    al = MotionAligner(MotionConfig(latitude_deg=traj.lat_deg, longitude_deg=traj.lon_deg,
                                    height_m=traj.height_m, specs=CAR_MEMS, velocity_noise=0.05,
                                    vehicle="ground", nhc_axis=1, **cfg))
    ratios = []
    for j in fed_in_blocks(al, r, 10):
        if al.initialized and al.hypotheses == 1:
            e = np.abs(attitude_error(r.C[j], al.dcm))
            ratios.append(e / np.sqrt(np.diag(al.covariance)))
    return al, np.array(ratios)


@pytest.mark.parametrize("seed", [0, 2])
def test_imu_ahead_of_the_rear_axle_stays_honest(seed):
    """IMU 1.5 m ahead of the axle and 0.3 m to the left: 0.24 m/s sideways in the 9 deg/s
    turns. Measured (seeds 0-5, 300 s, bench_in_motion 'car_city/ground+axle', no slip
    model): the constraint at the IMU put 55-68 % of the instants beyond 3 sigma (max 10
    sigma); with the lever arm estimated (default prior 2 m) 0.8 %, as with the IMU on the
    axle. The slip model is off here but in the last run (it widens the constraint in turns
    too, and would hide the lever's part)."""
    pos = (1.5, 0.3, 0.0)
    al, r = _drive(seed, pos, nhc_slip_deg=0.0)
    over = (r > 3.0).any(axis=1).mean()
    assert over <= 0.02 and r.max() < 4.5, (over, r.max(axis=0))
    # the lever arm (IMU -> axle) is learnt along x from the turns
    assert abs(al.nhc_lever_arm[0] + 1.5) < 0.3, al.nhc_lever_arm
    # given exactly, honest too
    al2, r2 = _drive(seed, pos, nhc_lever_arm=(-1.5, -0.3, 0.0), nhc_lever_arm_std=0.0,
                     nhc_slip_deg=0.0)
    assert (r2 > 3.0).any(axis=1).mean() <= 0.02 and r2.max() < 4.5
    # the teeth: the constraint at the IMU (lever 0, taken as exact) lies in the turns
    # (the vehicle's axes taken as the IMU's too: the mounting states would take up part
    # of what the missing lever arm does in the turns, 19 % instead of > 20 % in seed 0)
    al3, r3 = _drive(seed, pos, nhc_lever_arm_std=0.0, nhc_slip_deg=0.0,
                     nhc_mount_std_deg=0.0)
    assert (r3 > 3.0).any(axis=1).mean() > 0.2, (r3 > 3.0).any(axis=1).mean()
    # the defaults (lever estimated, slip model on): honest
    al4, r4 = _drive(seed, pos)
    assert (r4 > 3.0).any(axis=1).mean() <= 0.02 and r4.max() < 4.5


def test_tyre_sideslip_in_turns_stays_honest():
    """The velocity turned outward of the heading in every turn by 1 deg per m/s^2 of
    centripetal acceleration (up to 0.26 m/s sideways at 12 m/s, 6 deg/s): the constraint's
    noise covers it (nhc_slip_deg, default 1 deg per m/s^2 lasting 3 s), so the heading stays
    within its 3 sigma; told there is no slip (nhc_slip_deg 0), the constraint pulls the
    heading to the slipping velocity (the teeth). Measured over 300 s, seeds 0-2: slip
    0.5 deg per m/s^2 put 5-7 % of the instants beyond 3 sigma (max 4.6 sigma on the
    heading) without the slip model, as many as with no slip (0-4 %, max 2.2 sigma on the
    heading) with it."""
    for seed in (0, 1):
        al, r = _drive(seed, (0.0, 0.0, 0.0), seconds=300.0, sideslip_deg=1.0)
        over = (r > 3.0).any(axis=1).mean()
        assert over <= 0.05 and r[:, 2].max() < 3.0, (over, r.max(axis=0))
        al0, r0 = _drive(seed, (0.0, 0.0, 0.0), seconds=300.0, sideslip_deg=1.0,
                         nhc_slip_deg=0.0)
        assert r0[:, 2].max() > 4.0 and (r0 > 3.0).any(axis=1).mean() > 0.05, (
            (r0 > 3.0).any(axis=1).mean(), r0.max(axis=0))


def _askew(seed, mount_rpy_deg, **cfg):
    """A car that stands 10 s, accelerates at 1.5 m/s^2 for 5 s and drives straight for 60 s,
    its IMU bolted rotated by ``mount_rpy_deg`` (roll, pitch, yaw) against the car: the
    published (error / sigma) per ENU axis after the bank, and the aligner."""
    segs = (Segment(10.0), Segment(5.0, accel=1.5, ramp=1.0), Segment(60.0, ramp=1.0))
    traj = Trajectory(segs, 34.0, 108.0, 400.0, 130.0, 0.0, "straight")
    r = simulate_trajectory(traj, 100.0, CAR_MEMS, seed=seed, gnss_rate=10.0, gnss_sigma=0.05)
    M = dcm_from_rpy(np.radians(mount_rpy_deg))        # car axes <- IMU axes
    gyro, accel, C = r.gyro @ M, r.accel @ M, r.C @ M
    al = MotionAligner(MotionConfig(latitude_deg=traj.lat_deg, longitude_deg=traj.lon_deg,
                                    height_m=traj.height_m, specs=CAR_MEMS,
                                    velocity_noise=0.05, vehicle="ground", **cfg))
    for tg, vg in zip(r.gnss_t, r.gnss_v):
        al.add_velocity(tg, vg)
    z = []
    for k in range(0, len(gyro), 10):
        e = min(k + 10, len(gyro))
        al.update(r.t[k + 1:e + 1], gyro[k:e], accel[k:e])
        if al.initialized and al.hypotheses == 1:
            z.append(attitude_error(C[e], al.dcm) / np.sqrt(np.diag(al.covariance)))
    return al, np.abs(np.array(z))


@pytest.mark.parametrize("seed", [0, 1])
def test_an_imu_mounted_askew_on_a_car_stays_honest(seed):
    """The constraint says the car does not move sideways; an IMU bolted 3 deg askew in yaw
    (and 2 deg in roll) sees 0.5 m/s of the car's 10 m/s on its own side axis. Taken as the
    car's side (nhc_mount_std_deg 0), the constraint turns the heading by the mounting angle
    and its std says hundredths: 95-98 % of the instants beyond 3 sigma with 2 or 5 deg of
    yaw, flagged aligned (seeds 0-2). With the mounting estimated (default 2 deg 1-sigma),
    0 % beyond 3 sigma, and the mounting is learnt from the acceleration the velocity
    reference sees (yaw 2 / 5 deg came out -1.85 to -2.3 / -4.84 to -5.28: the car's axes
    against the IMU's)."""
    mount = (2.0, 0.0, 3.0)
    al, z = _askew(seed, mount)
    over = (z > 3.0).any(axis=1).mean()
    assert over <= 0.02 and z.max() < 4.0, (over, z.max(axis=0))
    est = np.degrees(rpy_from_dcm(so3_exp(al.nhc_mount)))   # car <- IMU, the inverse of M
    assert abs(est[2] + mount[2]) < 0.6, est
    assert al.summary()["nhc_mount_deg"] is not None
    # the teeth: the IMU's axes taken as the car's: far beyond 3 sigma, or (session 17)
    # caught by its bias estimates going beyond their specs, the attitude then unknown
    al0, z0 = _askew(seed, mount, nhc_mount_std_deg=0.0)
    over0 = (z0 > 3.0).any(axis=1).mean()
    assert over0 > 0.5 or (not al0.specs_consistent and over0 > 0.02), \
        (over0, al0.specs_consistent)
