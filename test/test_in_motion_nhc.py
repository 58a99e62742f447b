"""The non-holonomic constraint at the rear axle (in-motion honesty): a car's IMU ahead of its
rear axle moves sideways at yaw rate x distance in every turn, which the constraint must not
take for a heading error. Its model against finite differences, and car_city with the IMU
1.5 m ahead of the axle: honest with the lever arm estimated (the default) or given, and
not with the constraint at the IMU (the test's teeth)."""
import numpy as np
import pytest

from sins_align.core.rotation import attitude_error, so3_exp
from sins_align.core.specs import DPH, DPSH, UG, UG_PSHZ, SensorSpecs
from sins_align.core.strapdown import NavState, earth_rate, transport_rate
from sins_align.estimators.in_motion import InvariantEKF, MotionAligner, MotionConfig
from sins_align.estimators.in_motion.filter import NoiseModel
from sins_align.sim.trajectory import car_city, simulate_trajectory

from motion_helpers import fed_in_blocks

CAR_MEMS = SensorSpecs(gyro_bias=10.0 * DPH, gyro_arw=0.3 * DPSH, accel_bias=1000 * UG,
                       accel_vrw=100.0 * UG_PSHZ)


def _lateral(e, axis=1):
    """The lateral velocity of the non-holonomic point that an estimate predicts."""
    C, v = e.C[0], e.v[0]
    w_in = earth_rate(e.lat[0]) + transport_rate(v, e.lat[0], e.h[0])
    w_nb = e.w_last[0] - C.T @ w_in
    return (C.T @ v + np.cross(w_nb, e.nhc_lever[0]))[axis]


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
    eps = 1e-6
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
            out.append(_lateral(e))
        num[i] = -(out[0] - out[1]) / (2 * eps)
    assert np.abs(num[12:15]).max() > 0.5 and np.abs(num[6:9]).max() > 0.3
    probe = truth.copy()
    probe.P[0] = np.eye(n)
    probe.update_lateral(1, 1e6)
    dP = np.eye(n) - probe.P[0]
    HH = np.outer(num, num)
    assert np.allclose(dP / np.abs(dP).max(), HH / np.abs(HH).max(), atol=1e-6)


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
    al3, r3 = _drive(seed, pos, nhc_lever_arm_std=0.0, nhc_slip_deg=0.0)
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
