"""simulate --trajectory: the moving-vehicle bag (IMU, truth, GNSS velocity and fix) holds
exactly what sim.trajectory simulates, GNSS stamped at the measurement time and logged late
by the latency; the moving-vehicle options are checked."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from cli_helpers import cli
from sins_align.core.rotation import quat_from_dcm
from sins_align.core.specs import grade_specs
from sins_align.io.imu_fields import imu_covariances, sample_stamps_ns
from sins_align.sim.trajectory import simulate_trajectory, trajectory_preset
from sins_align.tools import simulate

ARGS = dict(trajectory="car_straight", latitude=47.0, height=250.0, duration=30.0, rate=50.0,
            seed=5, grade="tactical", t0=100.0, gnss_rate=5.0, gnss_noise=0.1,
            gnss_latency=0.25, lever_arm=(0.4, -0.3, 1.1), gnss_position_noise=2.0)


def _argv(**over):
    a = dict(ARGS, **over)
    out = []
    for k, v in a.items():
        out += [f"--{k.replace('_', '-')}", *(map(str, v) if isinstance(v, tuple) else [str(v)])]
    return out


def _read(bag: Path):
    """{topic: [(log time ns, message)]} and the bag's custom data."""
    from rosbags.highlevel import AnyReader

    out = {}
    with AnyReader([bag]) as r:
        for c, ns, raw in r.messages():
            out.setdefault(c.topic, []).append((ns, c.msgtype, r.deserialize(raw, c.msgtype)))
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())
    return out, meta["rosbag2_bagfile_information"].get("custom_data") or {}


def _stamp(m) -> int:
    return m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec


@pytest.fixture(scope="module")
def moving_bag(tmp_path_factory):
    out = tmp_path_factory.mktemp("moving") / "car"
    assert simulate.main([*_argv(), str(out)]) == 0
    ref = simulate_trajectory(
        trajectory_preset("car_straight", lat_deg=47.0, height_m=250.0), 50.0,
        specs=grade_specs("tactical"), seed=5, gnss_rate=5.0, gnss_sigma=0.1,
        lever_arm=ARGS["lever_arm"], duration=30.0, gnss_latency=0.25, gnss_pos_sigma=2.0)
    return _read(out), ref


def test_moving_bag_holds_the_trajectory_imu_and_truth(moving_bag):
    (topics, custom), ref = moving_bag
    assert sorted(topics) == ["/gnss/fix", "/gnss/fix_velocity", "/imu/data_raw",
                              "/imu_sim/truth"]
    imu, truth = topics["/imu/data_raw"], topics["/imu_sim/truth"]
    n = len(ref.gyro)
    assert len(imu) == len(truth) == n == 1500
    stamps = sample_stamps_ns(100.0, 50.0, 0, n).tolist()
    assert [ns for ns, _, _ in imu] == [_stamp(m) for _, _, m in imu] == stamps
    assert [_stamp(m) for _, _, m in truth] == stamps
    assert truth[0][1] == "geometry_msgs/msg/QuaternionStamped"
    gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                     for _, _, m in imu])
    acc = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                    for _, _, m in imu])
    np.testing.assert_array_equal(gyro, ref.gyro)
    np.testing.assert_array_equal(acc, ref.accel)
    q = np.array([[m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w]
                  for _, _, m in truth])
    np.testing.assert_array_equal(q, quat_from_dcm(ref.C[1:]))
    covs = imu_covariances(grade_specs("tactical"), 50.0)
    assert tuple(imu[0][2].angular_velocity_covariance) == covs.angular_velocity
    assert custom["sins_align.trajectory"] == "car_straight"
    assert json.loads(custom["sins_align.gnss_latency_s"]) == 0.25
    assert json.loads(custom["sins_align.gyro_bias_body_rad_s"]) == ref.gyro_bias.tolist()


def test_moving_bag_gnss_stamps_log_times_and_values(moving_bag):
    (topics, _), ref = moving_bag
    vel, fix = topics["/gnss/fix_velocity"], topics["/gnss/fix"]
    assert vel[0][1] == "geometry_msgs/msg/TwistWithCovarianceStamped"
    assert fix[0][1] == "sensor_msgs/msg/NavSatFix"
    m = len(ref.gnss_t)
    assert len(vel) == len(fix) == m == 151                      # 30 s at 5 Hz, t = 0 .. 30
    stamps = [100_000_000_000 + int(round(t * 1e9)) for t in ref.gnss_t]
    assert [_stamp(x) for _, _, x in vel] == [_stamp(x) for _, _, x in fix] == stamps
    assert [ns for ns, _, _ in vel] == [s + 250_000_000 for s in stamps]   # late by 0.25 s
    assert [ns for ns, _, _ in fix] == [ns for ns, _, _ in vel]
    v = np.array([[x.twist.twist.linear.x, x.twist.twist.linear.y, x.twist.twist.linear.z]
                  for _, _, x in vel])
    np.testing.assert_array_equal(v, ref.gnss_v)
    assert np.abs(v - ref.gnss_v_true).max() > 0.1                  # noisy as asked
    cov = np.array(vel[0][2].twist.covariance).reshape(6, 6)
    expect = np.zeros((6, 6))
    expect[[0, 1, 2], [0, 1, 2]] = 0.1 ** 2
    expect[3, 3] = -1.0
    np.testing.assert_array_equal(cov, expect)
    llh = np.array([[x.latitude, x.longitude, x.altitude] for _, _, x in fix])
    np.testing.assert_array_equal(llh[:, :2], np.degrees(ref.gnss_llh[:, :2]))
    np.testing.assert_array_equal(llh[:, 2], ref.gnss_llh[:, 2])
    f0 = fix[0][2]
    assert f0.status.status == 0 and f0.status.service == 1
    assert f0.position_covariance_type == 2
    np.testing.assert_array_equal(np.array(f0.position_covariance).reshape(3, 3),
                                  np.eye(3) * 4.0)
    assert f0.header.frame_id == "gnss_link"


def test_moving_bag_without_vertical_with_dropouts(tmp_path):
    out = tmp_path / "ship"
    assert simulate.main([*_argv(trajectory="ship_under_way", gnss_noise=0.0, gnss_latency=0.0,
                                 gnss_position_noise=0.0),
                          "--no-gnss-vertical", "--gnss-dropout", "10", "12",
                          "--gnss-dropout", "20", "20.5", str(out)]) == 0
    topics, _ = _read(out)
    vel = topics["/gnss/fix_velocity"]
    t = np.array([_stamp(x) for _, _, x in vel]) * 1e-9 - 100.0
    assert len(vel) == 151 - 10 - 3
    assert not np.any(((t >= 10.0) & (t < 12.0)) | ((t >= 20.0) & (t < 20.5)))
    assert all(np.isnan(x.twist.twist.linear.z) for _, _, x in vel)
    cov = np.array(vel[0][2].twist.covariance).reshape(6, 6)
    assert cov[2, 2] == -1.0 and cov[0, 0] == 0.0 and cov[3, 3] == -1.0
    assert [ns for ns, _, _ in vel] == [_stamp(x) for _, _, x in vel]       # no latency
    fix = topics["/gnss/fix"]
    assert fix[0][2].position_covariance_type == 0                           # exact position
    # the IMU and GNSS streams are interleaved in log-time order in the file
    from rosbags.highlevel import AnyReader
    with AnyReader([out]) as r:
        times = [ns for _, ns, _ in r.messages()]
    assert times == sorted(times)


@pytest.mark.parametrize("args, reason", [
    (["--gnss-rate", "5"], "--gnss-rate needs --trajectory"),
    (["--lever-arm", "0", "0", "1"], "--lever-arm needs --trajectory"),
    (["--no-gnss-vertical"], "--no-gnss-vertical needs --trajectory"),
    (["--trajectory", "car_city", "--rpy", "0", "0", "10"], "do not apply with --trajectory"),
    (["--trajectory", "car_city", "--sway", "car"], "do not apply with --trajectory"),
    (["--trajectory", "car_city", "--gnss-rate", "30"], "within [1, 20] Hz"),
    (["--trajectory", "car_city", "--gnss-rate", "3"], "must be a whole number"),
    (["--trajectory", "car_city", "--gnss-noise", "-1"], "--gnss-noise must be >= 0"),
    (["--trajectory", "car_city", "--gnss-latency", "nan"], "must be a finite number"),
    (["--trajectory", "car_city", "--gnss-dropout", "5", "4"], "START < END"),
    (["--trajectory", "car_city", "--latitude", "89"], "within [-85, 85]"),
])
def test_moving_options_are_checked(args, reason, tmp_path, capsys):
    rc, _, err = cli(simulate, [*args, tmp_path / "x"], capsys)
    assert rc != 0 and reason in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x").exists()


def test_preset_duration_is_the_default(tmp_path, capsys):
    rc, out, _ = cli(simulate, ["--trajectory", "car_with_turn", "--rate", "20",
                                tmp_path / "c"], capsys)
    assert rc == 0 and "1000 samples, 50.00 s at 20 Hz" in out and "GNSS at 10 Hz" in out
