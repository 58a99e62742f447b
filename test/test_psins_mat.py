"""The PSINS transfer-alignment data (``sins_align.data.TRANSFER_FOG_MEMS``): reader,
conventions checked against the data itself, and ``import_imu --format psins-mat``.

What the tests prove:

- the shipped file is the original (md5), with its README and BSD-2 LICENSE;
- ``read_psins_mat`` gives the file's numbers in SI rates (compared with ``scipy.io.loadmat``
  read here independently) and the run the data README describes;
- the master's PSINS Euler angles are converted with the right axes and signs: the master's
  attitude changes over each 0.1 s agree with the MEMS gyro increments, and its level
  attitude with the MEMS specific force (against what the master's own velocity says the
  specific force is), within what the MEMS biases and the mounting angles allow;
- the sign of the mounting ``mu0`` in the slave's true attitude: the MEMS fits the reader's
  slave attitude better than the master's, and the master's better than the opposite sign;
  a least-squares fit of the yaw mounting to the gyro alone (no lever arm there) lands on
  the reader's side;
- the bag written by ``import_imu`` holds exactly the reader's arrays on every topic, with the
  REP-105 twist (body axes) and the positions consistent with the velocities;
- corrupt input (truncated, a variable missing, not a .mat) is one line, non-zero exit, and
  leaves nothing behind.
"""
from __future__ import annotations

import hashlib
import json
import shutil

import numpy as np
import pytest
import scipy.io

from cli_helpers import cli, listing
from sins_align.core.earth import earth_rate_enu, normal_gravity, radii
from sins_align.core.rotation import dcm_from_quat, skew, so3_exp, so3_log
from sins_align.data import TRANSFER_FOG_MEMS
from sins_align.io.psins import read_psins_mat
from sins_align.tools import import_imu

DEG = np.pi / 180.0
MD5 = "d457e668e81b3ffc0087ba5fe273dfd5"


@pytest.fixture(scope="module")
def mat():
    return read_psins_mat(TRANSFER_FOG_MEMS)


@pytest.fixture(scope="module")
def raw():
    """The file as scipy reads it, without the reader."""
    return scipy.io.loadmat(TRANSFER_FOG_MEMS)


@pytest.fixture(scope="module")
def intervals(mat, raw):
    """Per master interval (k-1, k] (0.1 s): the MEMS increments summed over the 10 samples
    of the interval, the master's attitude change, its mid-interval C_b^n, and the specific
    force the master's velocity implies (dv/dt + Coriolis and transport - gravity), ENU."""
    mimu = raw["mimu"]
    k = np.rint(mat.master_t / mat.ts).astype(int)          # mimu row of each record
    assert np.allclose(mimu[k, 6], mat.master_t, atol=1e-9)  # same time base
    rows = [slice(a + 1, b + 1) for a, b in zip(k[:-1], k[1:])]
    dth = np.array([mimu[r, 0:3].sum(0) for r in rows])
    dv = np.array([mimu[r, 3:6].sum(0) for r in rows])
    dt = np.diff(mat.master_t)
    C = mat.master_dcm
    rel = so3_log(np.einsum("kji,kjl->kil", C[:-1], C[1:]))
    Cm = C[:-1] @ so3_exp(0.5 * rel)
    v = mat.master_vel
    vm = 0.5 * (v[1:] + v[:-1])
    lat = 0.5 * (mat.master_lat[1:] + mat.master_lat[:-1])
    h = 0.5 * (mat.master_height[1:] + mat.master_height[:-1])
    rm, rn = radii(lat)
    w_ie = earth_rate_enu(lat)
    w_en = np.stack([-vm[:, 1] / (rm + h), vm[:, 0] / (rn + h),
                     vm[:, 0] * np.tan(lat) / (rn + h)], -1)
    g = normal_gravity(lat, h)
    f_n = np.diff(v, axis=0) / dt[:, None] + np.cross(2 * w_ie + w_en, vm)
    f_n[:, 2] += g
    w_in_b = np.einsum("kji,kj->ki", Cm, w_ie + w_en)
    return dict(dth=dth, f_s=dv / dt[:, None], dt=dt, rel=rel, Cm=Cm, f_n=f_n, g=g,
                rel_ib=rel + w_in_b * dt[:, None])


def _windows(x, w=10):
    n = len(x) // w * w
    return x[:n].reshape(-1, w, x.shape[1]).mean(1)


# ------------------------------------------------------------------------------ the files
def test_shipped_copy_is_the_original_with_readme_and_license():
    assert hashlib.md5(TRANSFER_FOG_MEMS.read_bytes()).hexdigest() == MD5
    folder = TRANSFER_FOG_MEMS.parent
    lic = (folder / "LICENSE").read_text()
    assert "Copyright (c) 2009-2015, Gongmin Yan" in lic and "BSD 2-clause" in lic
    assert "Redistributions in binary form must reproduce" in lic
    readme = (folder / "README.md").read_text()
    assert MD5 in readme and "WangShanpeng/PSINS" in readme


# ------------------------------------------------------------------------------ reader
def test_reader_gives_the_file_in_si_rates(mat, raw):
    mimu, fog = raw["mimu"], raw["fogavp"]
    assert (mat.n, mat.n_master) == (10001, 1000)
    assert mat.ts == pytest.approx(0.01, abs=1e-12) and mat.body_axes == "RFU"
    assert mat.gyro.shape == mat.accel.shape == (10001, 3)
    np.testing.assert_array_equal(mat.t, mimu[:, 6])
    np.testing.assert_allclose(mat.gyro * 0.01, mimu[:, 0:3], rtol=1e-10, atol=0)
    np.testing.assert_allclose(mat.accel * 0.01, mimu[:, 3:6], rtol=1e-10, atol=0)
    np.testing.assert_array_equal(mat.master_t, fog[:, 9])
    np.testing.assert_array_equal(mat.master_att, fog[:, 0:3])
    np.testing.assert_array_equal(mat.master_vel, fog[:, 3:6])
    np.testing.assert_array_equal(np.stack([mat.master_lat, mat.master_lon,
                                            mat.master_height], -1), fog[:, 6:9])
    for key in ("eb0", "db0", "mu0"):
        np.testing.assert_array_equal(getattr(mat, key), raw[key].ravel())
    assert mat.master_quat.shape == mat.slave_quat.shape == (1000, 4)
    np.testing.assert_allclose(dcm_from_quat(mat.master_quat), mat.master_dcm, atol=1e-12)
    np.testing.assert_allclose(dcm_from_quat(mat.slave_quat), mat.slave_dcm, atol=1e-12)
    assert np.all(mat.master_quat[:, 3] >= 0)


def test_the_run_is_the_one_the_data_readme_describes(mat):
    """Mean |f| 9.77 m/s^2, latitude 34.43 deg N, 11.5-15.8 m/s roughly north, roll through
    -32 .. +33 deg, the reference biases and mounting angles (data README)."""
    assert np.linalg.norm(mat.accel, axis=1).mean() == pytest.approx(9.77, abs=0.01)
    assert np.all(np.abs(np.rad2deg(mat.master_lat) - 34.43) < 0.01)
    assert np.all(np.abs(np.rad2deg(mat.master_lon) - 111.43) < 0.01)
    speed = np.hypot(mat.master_vel[:, 0], mat.master_vel[:, 1])
    assert 11.5 < speed.min() < 12.0 and 15.5 < speed.max() < 15.8
    track = np.rad2deg(np.arctan2(mat.master_vel[:, 0], mat.master_vel[:, 1]))
    assert np.all(np.abs(track) < 10)                               # roughly north
    roll = np.rad2deg(mat.master_att[:, 1])
    assert roll.min() < -30 and roll.max() > 30
    np.testing.assert_allclose(mat.eb0 / DEG * 3600, [-214, 159, 84], atol=1)
    np.testing.assert_allclose(mat.db0 / 9.8 * 1e3, [2.9, -7.2, -4.7], atol=0.1)
    np.testing.assert_allclose(mat.mu0 / DEG, [-0.088, 0.041, -0.293], atol=0.001)


def test_master_attitude_changes_agree_with_the_mems_gyro(intervals):
    """Over each 0.1 s the master's attitude change (from the converted Euler angles) equals
    the MEMS's summed gyro increments up to the MEMS bias and noise: a wrong axis or sign
    in the conversion would leave errors the size of the signal (roll changes up to 1 deg)."""
    rel, dth = intervals["rel"], intervals["dth"]
    signal = np.sqrt((rel ** 2).sum(1).mean())
    err = np.sqrt(((rel - dth) ** 2).sum(1).mean())
    assert signal > 3e-3                                   # the vehicle does roll
    assert err < 0.15 * signal, (err, signal)
    # the yaw rate: heading changes of a few degrees must come out with the right sign
    assert np.corrcoef(rel[:, 2], dth[:, 2])[0, 1] > 0.8


def test_master_forward_axis_keeps_a_constant_angle_to_its_track(mat):
    """Heading of the body Y (forward) axis = -yaw (PSINS yaw is counter-clockwise): it
    follows the track of the master's velocity with a constant offset (the mount), whereas
    +yaw would wander against it by the 4 deg the heading changes."""
    C = mat.master_dcm
    heading = np.arctan2(C[:, 0, 1], C[:, 1, 1])          # azimuth of body Y, clockwise
    np.testing.assert_allclose(heading, -mat.master_att[:, 2], atol=1e-12)
    track = np.arctan2(mat.master_vel[:, 0], mat.master_vel[:, 1])
    assert np.std(track - heading) < 0.5 * DEG < np.std(track + heading)


def test_master_level_attitude_agrees_with_the_mems_specific_force(mat, intervals):
    """C_m^n f_mems against the specific force the master's velocity implies: the horizontal
    mismatch, averaged over the run and in 1 s windows, stays within what the MEMS
    accelerometer bias and the mounting can make (|db0| + g |mu0|), while the vehicle rolls
    through +-33 deg (a roll or pitch conversion error would show as g sin(error))."""
    Cm, f_s, f_n = intervals["Cm"], intervals["f_s"], intervals["f_n"]
    g = float(intervals["g"].mean())
    bound = np.linalg.norm(mat.db0) + g * np.linalg.norm(mat.mu0)
    d = np.einsum("kij,kj->ki", Cm, f_s) - f_n
    mean_h = np.linalg.norm(d.mean(0)[:2])
    rms_h = np.sqrt((_windows(d)[:, :2] ** 2).sum(1).mean())
    assert mean_h < bound and rms_h < bound, (mean_h, rms_h, bound)
    # the simple form: the run's mean specific force, put in ENU by the master's attitude,
    # is vertical up to the mean horizontal acceleration and the same bound
    fm = np.einsum("kij,kj->ki", Cm, f_s).mean(0)
    tilt = np.arctan2(np.hypot(fm[0], fm[1]), fm[2])
    acc_h = np.linalg.norm((mat.master_vel[-1, :2] - mat.master_vel[0, :2])
                           / (mat.master_t[-1] - mat.master_t[0]))
    assert tilt < (bound + acc_h) / g, (tilt, bound, acc_h)


def test_slave_truth_uses_the_mounting_with_the_sign_the_data_shows(mat, intervals):
    """The reader's slave attitude is the master's rotated by the mounting x (from the
    reader's arrays). In the MEMS's body axes, with a constant accelerometer bias removed
    (fitted), the 1 s mean specific force fits the slave's attitude better than the master's,
    and the master's better than the mounting with the opposite sign. A least-squares fit of
    the mounting to the gyro (free of lever arm; bias fitted too) puts its yaw on the side of
    x, more than 3 sigma from -x."""
    x = so3_log(np.einsum("kji,kjl->kil", mat.master_dcm, mat.slave_dcm))
    np.testing.assert_allclose(x, np.broadcast_to(x[0], x.shape), atol=1e-12)  # constant
    x = x[0]
    assert np.linalg.norm(x) == pytest.approx(np.linalg.norm(mat.mu0), rel=1e-9)
    Cm, f_s, f_n = intervals["Cm"], intervals["f_s"], intervals["f_n"]

    def misfit(rot):
        pred = np.einsum("kji,kj->ki", Cm @ so3_exp(rot), f_n)       # C_n^s f^n
        r = _windows(f_s - pred)
        r -= r.mean(0)
        return np.sqrt((r ** 2).sum(1).mean())

    slave, master, opposite = misfit(x), misfit(0 * x), misfit(-x)
    assert slave < master < opposite, (slave, master, opposite)
    # gyro: C_s^n = C_m^n exp(m x) -> w_s = exp(-m x) w_m + eb = w_m + (w_m x) m + eb, so
    # per interval dth - rel_ib = skew(rel_ib) m + eb dt (m and eb fitted)
    rel_ib, dth, dt = intervals["rel_ib"], intervals["dth"], intervals["dt"]
    a = np.concatenate([skew(rel_ib), np.eye(3) * dt[:, None, None]], axis=2).reshape(-1, 6)
    b = (dth - rel_ib).reshape(-1)
    sol, res, *_ = np.linalg.lstsq(a, b, rcond=None)
    sd = np.sqrt(res[0] / (b.size - 6) * np.diag(np.linalg.inv(a.T @ a)))
    assert abs(sol[2] - x[2]) < 3 * sd[2] < abs(sol[2] + x[2]), (sol[2], x[2], sd[2])


# ------------------------------------------------------------------------------ import
def read_bag(bag):
    """topic -> [(log ns, message)], and the metadata's custom data."""
    from rosbags.highlevel import AnyReader

    out: dict[str, list] = {}
    with AnyReader([bag]) as r:
        types = {c.topic: c.msgtype for c in r.connections}
        for c, ns, data in r.messages():
            out.setdefault(c.topic, []).append((ns, r.deserialize(data, c.msgtype)))
    import yaml
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())
    return out, types, meta["rosbag2_bagfile_information"]["custom_data"]


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def _xyz(v):
    return [v.x, v.y, v.z]


def _xyzw(q):
    return [q.x, q.y, q.z, q.w]


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    d = tmp_path_factory.mktemp("mat")
    rc = import_imu.main([str(TRANSFER_FOG_MEMS), str(d / "full")])
    assert rc == 0
    return d / "full"


def test_import_writes_every_topic_with_the_reader_values(mat, imported):
    topics, types, custom = read_bag(imported)
    assert types == {"/imu/data_raw": "sensor_msgs/msg/Imu",
                     "/master/odom": "nav_msgs/msg/Odometry",
                     "/master/velocity": "geometry_msgs/msg/TwistWithCovarianceStamped",
                     "/master/fix": "sensor_msgs/msg/NavSatFix",
                     "/imu_sim/truth": "geometry_msgs/msg/QuaternionStamped"}
    imu = [m for _, m in topics["/imu/data_raw"]]
    assert len(imu) == 10001
    assert [_stamp(m) for m in imu] == np.rint(mat.t * 1e9).astype(np.int64).tolist()
    assert [ns for ns, _ in topics["/imu/data_raw"]] == [_stamp(m) for m in imu]
    np.testing.assert_array_equal([_xyz(m.angular_velocity) for m in imu], mat.gyro)
    np.testing.assert_array_equal([_xyz(m.linear_acceleration) for m in imu], mat.accel)
    assert {m.header.frame_id for m in imu} == {"imu_link"}
    assert imu[0].orientation_covariance[0] == -1.0

    master_ns = np.rint(mat.master_t * 1e9).astype(np.int64).tolist()
    odom = [m for _, m in topics["/master/odom"]]
    vel = [m for _, m in topics["/master/velocity"]]
    fix = [m for _, m in topics["/master/fix"]]
    truth = [m for _, m in topics["/imu_sim/truth"]]
    for msgs in (odom, vel, fix, truth):
        assert [_stamp(m) for m in msgs] == master_ns
    # odometry: ENU world frame -> the master's body; orientation = C_b^n
    assert {(m.header.frame_id, m.child_frame_id) for m in odom} == {("enu", "master_link")}
    np.testing.assert_array_equal([_xyzw(m.pose.pose.orientation) for m in odom],
                                  mat.master_quat)
    # twist in the child frame (REP-105): rotated back to ENU it is the master velocity
    v_b = np.array([_xyz(m.twist.twist.linear) for m in odom])
    np.testing.assert_allclose(np.einsum("kij,kj->ki", mat.master_dcm, v_b), mat.master_vel,
                               atol=1e-12)
    # velocity topic: ENU as in the file; its angular rate is the odometry's, in ENU
    assert {m.header.frame_id for m in vel} == {"enu"}
    np.testing.assert_array_equal([_xyz(m.twist.twist.linear) for m in vel], mat.master_vel)
    w_b = np.array([_xyz(m.twist.twist.angular) for m in odom])
    w_n = np.array([_xyz(m.twist.twist.angular) for m in vel])
    np.testing.assert_allclose(np.einsum("kij,kj->ki", mat.master_dcm, w_b), w_n, atol=1e-15)
    # ... and the body rate agrees with the MEMS gyro (1 s means; MEMS bias ~ 1e-3 rad/s)
    gyro_at = np.array([mat.gyro[max(0, k - 5):k + 5].mean(0)
                        for k in np.rint(mat.master_t / mat.ts).astype(int)])
    assert np.sqrt(((_windows(w_b) - _windows(gyro_at)) ** 2).sum(1).mean()) < 3e-3
    cov = np.array(vel[0].twist.covariance).reshape(6, 6)
    np.testing.assert_allclose(np.diag(cov)[:3], 0.01 ** 2)
    cov = np.array(odom[0].pose.covariance).reshape(6, 6)
    np.testing.assert_allclose(np.diag(cov), [1.0] * 3 + [(0.01 * DEG) ** 2] * 3)
    # positions: ENU offsets from the first record, consistent with the velocities
    pos = np.array([_xyz(m.pose.pose.position) for m in odom])
    assert np.all(pos[0] == 0.0)
    steps = np.diff(pos, axis=0)
    from_vel = 0.5 * (mat.master_vel[1:] + mat.master_vel[:-1]) * np.diff(mat.master_t)[:, None]
    assert np.linalg.norm(pos[-1]) > 1000                              # 1.3 km driven
    np.testing.assert_allclose(steps.sum(0), from_vel.sum(0), atol=0.01 * np.linalg.norm(pos[-1]))
    # fix: degrees and the file's height
    np.testing.assert_array_equal([m.latitude for m in fix], np.rad2deg(mat.master_lat))
    np.testing.assert_array_equal([m.longitude for m in fix], np.rad2deg(mat.master_lon))
    np.testing.assert_array_equal([m.altitude for m in fix], mat.master_height)
    assert {m.header.frame_id for m in fix} == {"master_link"}
    # truth: the slave's attitude, in the Imu's frame, as replay's --truth-topic reads it
    assert {m.header.frame_id for m in truth} == {"imu_link"}
    np.testing.assert_array_equal([_xyzw(m.quaternion) for m in truth], mat.slave_quat)
    # the reference values travel in the metadata
    np.testing.assert_array_equal(json.loads(custom["sins_align.psins_mat.mu0_rad"]), mat.mu0)
    np.testing.assert_array_equal(json.loads(custom["sins_align.psins_mat.db0_m_s2"]), mat.db0)
    np.testing.assert_array_equal(json.loads(custom["sins_align.psins_mat.eb0_rad_s"]), mat.eb0)
    assert custom["sins_align.format"] == "psins-mat"


def test_import_t0_limits_topic_names_and_detection_by_header(mat, tmp_path, capsys):
    """--t0 shifts every stamp; --max-duration keeps the IMU samples of the first S seconds
    and the master records up to the last of them; topic and frame flags rename; a .mat under
    another name is told by its MATLAB header."""
    src = tmp_path / "data.bin"
    shutil.copyfile(TRANSFER_FOG_MEMS, src)
    out = tmp_path / "cut"
    rc, o, err = cli(import_imu, [src, out, "--max-duration", 10, "--t0", 1000,
                                  "--master-odom-topic", "/ins/odom", "--truth-topic", "/gt",
                                  "--world-frame", "local_enu", "--grade", "consumer"], capsys)
    assert rc == 0, err
    assert "from psins-mat data.bin" in o and "1000 samples" in o
    topics, _, _ = read_bag(out)
    assert set(topics) == {"/imu/data_raw", "/ins/odom", "/master/velocity", "/master/fix",
                           "/gt"}
    imu = [m for _, m in topics["/imu/data_raw"]]
    keep = mat.t < mat.t[0] + 10
    assert len(imu) == int(keep.sum())
    t0 = 1000 * 1_000_000_000
    assert [_stamp(m) for m in imu] == (t0 + np.rint(mat.t[keep] * 1e9)).astype(int).tolist()
    last = mat.t[keep][-1]
    n_master = int((mat.master_t <= last + 1e-9).sum())
    assert 0 < n_master < mat.n_master
    for topic in ("/ins/odom", "/master/velocity", "/master/fix", "/gt"):
        assert [_stamp(m) for _, m in topics[topic]] == \
            (t0 + np.rint(mat.master_t[:n_master] * 1e9)).astype(int).tolist()
    assert topics["/ins/odom"][0][1].header.frame_id == "local_enu"
    assert imu[0].angular_velocity_covariance[0] > 0                 # --grade applies


# ------------------------------------------------------------------------------ errors
@pytest.fixture(scope="module")
def bad_mats(tmp_path_factory):
    d = tmp_path_factory.mktemp("badmat")
    data = TRANSFER_FOG_MEMS.read_bytes()
    (d / "truncated.mat").write_bytes(data[: len(data) // 2])
    (d / "last_byte_cut.mat").write_bytes(data[:-1])
    (d / "header_only.mat").write_bytes(data[:128])
    (d / "text.mat").write_text("t,gx,gy,gz,ax,ay,az\n0,0,0,0,0,0,9.8\n")
    m = scipy.io.loadmat(TRANSFER_FOG_MEMS)
    keep = {k: v for k, v in m.items() if not k.startswith("__")}
    scipy.io.savemat(d / "no_mu0.mat", {k: v for k, v in keep.items() if k != "mu0"})
    scipy.io.savemat(d / "narrow.mat", {**keep, "fogavp": keep["fogavp"][:, :9]})
    back = keep["mimu"].copy()
    back[50, 6] = back[49, 6]
    scipy.io.savemat(d / "time_stalls.mat", {**keep, "mimu": back})
    nan = keep["fogavp"].copy()
    nan[3, 4] = np.nan
    scipy.io.savemat(d / "nan.mat", {**keep, "fogavp": nan})
    return d


BAD = {"truncated.mat": "not a readable MATLAB .mat file",
       "last_byte_cut.mat": "not a readable MATLAB .mat file",
       "header_only.mat": "variable 'mimu' missing",
       "text.mat": "not a readable MATLAB .mat file",
       "no_mu0.mat": "variable 'mu0' missing",
       "narrow.mat": "'fogavp' must be an (n, 10) array",
       "time_stalls.mat": "mimu time does not increase at row 51",
       "nan.mat": "'fogavp' has a non-finite value (row 4)"}


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_mat_is_one_line_and_leaves_nothing(bad_mats, name, capsys):
    before = listing(bad_mats)
    with pytest.raises(ValueError, match=str(bad_mats / name)):
        read_psins_mat(bad_mats / name)
    rc, out, err = cli(import_imu, [bad_mats / name, bad_mats / "out"], capsys)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, err
    assert lines[0].startswith("import_imu: error:") and str(bad_mats / name) in lines[0]
    assert BAD[name] in lines[0], lines[0]
    assert listing(bad_mats) == before and out == ""


def test_mat_options_are_refused_with_other_formats(tmp_path, capsys):
    csv = tmp_path / "a.csv"
    csv.write_text("t,gx,gy,gz,ax,ay,az\n0.01,0,0,0,0,0,9.8\n0.02,0,0,0,0,0,9.8\n")
    rc, _, err = cli(import_imu, [csv, tmp_path / "o", "--truth-topic", "/x"], capsys)
    assert rc == 2 and "--truth-topic: only for --format psins-mat" in err
    rc, _, err = cli(import_imu, [TRANSFER_FOG_MEMS, tmp_path / "o", "--truth-topic",
                                  "/imu/data_raw"], capsys)
    assert rc == 2 and "topics must differ" in err
    rc, _, err = cli(import_imu, [TRANSFER_FOG_MEMS, tmp_path / "o", "--gyro-units", "deg"],
                     capsys)
    assert rc == 2 and "PSINS .mat states its own units" in err
    rc, _, err = cli(import_imu, [TRANSFER_FOG_MEMS, tmp_path / "o", "--t0", "-5"], capsys)
    assert rc == 2 and "outside a ROS stamp's range" in err
    assert listing(tmp_path) == {"a.csv"}
