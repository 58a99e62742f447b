"""Bag tools: simulate -> bag -> replay, import_imu, and every user-error path.

What is proved here:
- ``simulate`` writes exactly what the simulator produces (values, stamps, frames, REP-145
  covariances from the specs) on the topics and types imu_sim_node uses;
- ``replay`` reaches the truth within the limit-based bound of its own published std, and gives
  bit-identical results from mcap, sqlite3 and ROS 1 bags of the same data;
- ``replay`` publishes the node's topics with the node's conversion: every /imu/data orientation
  equals what an :class:`Aligner` fed the same samples through ``outputs`` gives;
- ``import_imu`` on the real PSINS laser-gyro log (the project's xz copy, first 300 s) +
  ``replay`` from a small and from a [89, 89, 179] deg larger initial error agree (heading
  0.05 deg, level 0.01 deg) and match an independent inertial-frame alignment within 3 sigma;
- text logs import with declared units (rates, increments, deg, g) and columns;
- every bad input gives a non-zero exit, exactly one line on stderr, no traceback and no
  output left behind.
"""
from __future__ import annotations

import json
import lzma
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import cli, listing
from inertial_alignment import inertial_frame_alignment
import sins_align
from sins_align.tools import import_imu
from sins_align.tools import replay
from sins_align.tools import simulate
from sins_align.data import LASERGYRO
from sins_align.core.earth import gravity
from sins_align.estimators.quasi_static.aligner import JUMP_CONFIRM, AlignConfig, Aligner
from sins_align.io.imu_fields import imu_covariances, sample_stamps_ns
from sins_align.ros.outputs import StampClock, imu_output
from sins_align.io.psins import psins_att_to_dcm, read_psins
from sins_align.core.rotation import attitude_error, dcm_from_quat, dcm_from_rpy, rpy_from_dcm
from sins_align.sim.simulator import simulate as sim_simulate
from sins_align.core.specs import DEG, grade_specs

LAT = 34.0
SIM = dict(duration=80.0, rate=100.0, rpy=(1.0, -2.0, 30.0), seed=3, grade="navigation")
SIM_ARGS = ["--latitude", str(LAT), "--rpy", *map(str, SIM["rpy"]), "--duration",
            str(SIM["duration"]), "--rate", str(SIM["rate"]), "--seed", str(SIM["seed"]),
            "--grade", SIM["grade"]]
PSINS_LAT = 34.246048


def read_topic(bag: Path, topic: str):
    """[(log time ns, message)] of one topic (any bag kind)."""
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as r:
        conns = [c for c in r.connections if c.topic == topic]
        return [(ns, r.deserialize(raw, c.msgtype)) for c, ns, raw in r.messages(conns)]


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


# ------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("bags")


@pytest.fixture(scope="module")
def sim_bag(work) -> Path:
    out = work / "sim_mcap"
    assert simulate.main([*SIM_ARGS, "--compression", "zstd", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def sim_truth():
    """The same simulation in memory (what the bag must hold)."""
    return sim_simulate(SIM["duration"], rate=SIM["rate"], lat_deg=LAT, rpy_deg=SIM["rpy"],
                        specs=SIM["grade"], seed=SIM["seed"])


@pytest.fixture(scope="module")
def mcap_run(work, sim_bag):
    """One replay of the mcap bag with every output and the truth."""
    d = work / "run_mcap"
    d.mkdir()
    rc = replay.main([str(sim_bag), "--latitude", str(LAT), "--grade", "navigation",
                      "--truth-topic", "/imu_sim/truth",
                      "--output", str(d / "out"), "--csv", str(d / "a.csv"),
                      "--summary-json", str(d / "s.json"), "--quiet"])
    assert rc == 0
    return d, json.loads((d / "s.json").read_text())


def _ros1_copy(src: Path, dst: Path):
    """Write the messages of a rosbag2 bag to a ROS 1 bag (ROS 1 Noetic typestore)."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts1 = get_typestore(Stores.ROS1_NOETIC)
    T = ts1.types
    with AnyReader([src]) as r, Writer(dst) as w:
        conns = {}
        for c in r.connections:
            conns[c.id] = w.add_connection(c.topic, c.msgtype, typestore=ts1)
        seq = 0
        for c, ns, raw in r.messages():
            m = r.deserialize(raw, c.msgtype)
            h = T["std_msgs/msg/Header"](seq=seq, stamp=T["builtin_interfaces/msg/Time"](
                sec=m.header.stamp.sec, nanosec=m.header.stamp.nanosec),
                frame_id=m.header.frame_id)
            seq += 1
            if c.msgtype == "sensor_msgs/msg/Imu":
                m1 = T[c.msgtype](header=h, orientation=T["geometry_msgs/msg/Quaternion"](
                    x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=m.orientation_covariance,
                    angular_velocity=T["geometry_msgs/msg/Vector3"](
                        x=m.angular_velocity.x, y=m.angular_velocity.y, z=m.angular_velocity.z),
                    angular_velocity_covariance=m.angular_velocity_covariance,
                    linear_acceleration=T["geometry_msgs/msg/Vector3"](
                        x=m.linear_acceleration.x, y=m.linear_acceleration.y,
                        z=m.linear_acceleration.z),
                    linear_acceleration_covariance=m.linear_acceleration_covariance)
            else:
                q = m.quaternion
                m1 = T[c.msgtype](header=h, quaternion=T["geometry_msgs/msg/Quaternion"](
                    x=q.x, y=q.y, z=q.z, w=q.w))
            w.write(conns[c.id], ns, ts1.serialize_ros1(m1, c.msgtype))


# ------------------------------------------------------------------------------ simulate
def test_simulate_writes_the_simulator_samples_as_imu_sim_node_publishes(sim_bag, sim_truth):
    imu = read_topic(sim_bag, "/imu/data_raw")
    truth = read_topic(sim_bag, "/imu_sim/truth")
    n = len(sim_truth.t)
    assert len(imu) == len(truth) == n == 8000
    stamps = sample_stamps_ns(0.0, SIM["rate"], 0, n)
    assert [ns for ns, _ in imu] == [stamp_ns(m) for _, m in imu] == stamps.tolist()
    assert [stamp_ns(m) for _, m in truth] == stamps.tolist()
    gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                     for _, m in imu])
    acc = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                    for _, m in imu])
    np.testing.assert_array_equal(gyro, sim_truth.gyro)
    np.testing.assert_array_equal(acc, sim_truth.accel)
    q = np.array([[m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w]
                  for _, m in truth])
    np.testing.assert_array_equal(q, sim_truth.quat_true)
    m0 = imu[0][1]
    covs = imu_covariances(grade_specs("navigation"), SIM["rate"])
    assert m0.header.frame_id == "imu_link" and truth[0][1].header.frame_id == "imu_link"
    assert tuple(m0.angular_velocity_covariance) == covs.angular_velocity
    assert tuple(m0.linear_acceleration_covariance) == covs.linear_acceleration
    assert m0.orientation_covariance[0] == -1.0


# ------------------------------------------------------------------------------ replay
def test_replay_reaches_the_truth_within_its_published_std(mcap_run):
    _, s = mcap_run
    fin = s["final"]
    err = np.array(fin["error_enu_deg"])
    std = np.array(fin["std_enu_deg"])
    lim = np.array(s["limit_std_enu_deg"])
    assert s["aligned"] and s["samples"] == 8000 and s["rejected"] == {}
    assert np.all(std >= lim * 0.99), "published std below the limit accuracy"
    assert np.all(np.abs(err) <= 3.0 * std), (err, std)
    truth_rpy = np.array(fin["truth_rpy_deg"])
    np.testing.assert_allclose(truth_rpy, SIM["rpy"], atol=1e-6)
    for key in ("samples", "rejected", "duration_s", "aligned", "time_to_aligned_s",
                "limit_std_enu_deg"):
        assert key in s
    for key in ("stamp_s", "orientation_xyzw", "rpy_deg", "heading_deg", "std_enu_deg"):
        assert key in fin
    assert s["config"]["latitude_deg"] == LAT and s["config"]["model"] == "constant"
    assert s["config"]["grade"] == "navigation"
    assert abs(s["duration_s"] - 79.99) < 1e-9 and fin["stamp_s"] == 80.0
    # heading: true, clockwise from North, of the x axis; REP-103 yaw is CCW from East
    dh = (fin["heading_deg"] - (90.0 - fin["rpy_deg"][2]) + 180.0) % 360.0 - 180.0
    assert abs(dh) < 1e-9


def test_replay_gives_identical_results_from_sqlite3_and_ros1_bags(work, sim_bag, mcap_run,
                                                                  capsys):
    _, ref = mcap_run
    db = work / "sim_sqlite"
    assert cli(simulate, [*SIM_ARGS, "--storage", "sqlite3", db], capsys)[0] == 0
    ros1 = work / "sim_ros1.bag"
    _ros1_copy(sim_bag, ros1)
    for bag in (db, ros1):
        js = work / f"{bag.name}.json"
        rc, _, err = cli(replay, [bag, "--latitude", LAT, "--grade", "navigation",
                                  "--truth-topic", "/imu_sim/truth",
                                  "--summary-json", js, "--quiet"], capsys)
        assert rc == 0, err
        s = json.loads(js.read_text())
        assert s["final"]["orientation_xyzw"] == ref["final"]["orientation_xyzw"], bag
        assert s["final"]["error_enu_deg"] == ref["final"]["error_enu_deg"], bag
        assert s["samples"] == ref["samples"]
    # summary only (the block path: numpy MCAP reader, SQLite's bulk read, rosbags for ROS 1;
    # blocks of the same boundaries whatever the storage): bit-identical too
    block = []
    for bag, how in ((sim_bag, "mcap-numpy"), (db, "sqlite3-bulk"), (ros1, "rosbags")):
        s, sess = replay.replay(bag, AlignConfig(latitude_deg=LAT), progress=False)
        assert sess.block and sess.reading[0] == how
        block.append(s["final"]["orientation_xyzw"])
    assert block[0] == block[1] == block[2]


def test_replay_publishes_the_node_topics_with_the_node_conversion(mcap_run, sim_truth):
    d, s = mcap_run
    out = d / "out"
    from rosbags.highlevel import AnyReader

    with AnyReader([out]) as r:
        types = {t: i.msgtype for t, i in r.topics.items()}
    assert types == {"/imu/data": "sensor_msgs/msg/Imu",
                     "/alignment/aligned": "std_msgs/msg/Bool",
                     "/alignment/euler_deg": "geometry_msgs/msg/Vector3Stamped",
                     "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray"}
    imu = read_topic(out, "/imu/data")
    stamps = sample_stamps_ns(0.0, SIM["rate"], 0, len(sim_truth.t))
    assert [ns for ns, _ in imu] == [stamp_ns(m) for _, m in imu] == stamps.tolist()

    # the same samples through Aligner + outputs.imu_output, as align_node does
    al = Aligner(AlignConfig(latitude_deg=LAT))
    clock = StampClock()
    for k, (ns, m) in enumerate(imu):
        sec, nsec = divmod(int(stamps[k]), 1_000_000_000)
        al.update(clock(sec, nsec), sim_truth.gyro[k], sim_truth.accel[k])
        if k % 97 == 0 or k == len(imu) - 1:
            o = imu_output(al)
            q = m.orientation
            assert (q.x, q.y, q.z, q.w) == o.orientation_xyzw, k
            assert tuple(m.orientation_covariance) == o.orientation_covariance, k
            assert m.angular_velocity.x == sim_truth.gyro[k, 0]
    q = imu[-1][1].orientation
    assert [q.x, q.y, q.z, q.w] == s["final"]["orientation_xyzw"]

    aligned = read_topic(out, "/alignment/aligned")
    assert aligned[0][0] == stamps[0] and aligned[0][1].data is False
    assert [m.data for _, m in aligned] == [False, True]
    t_al = (aligned[1][0] - stamps[0]) / 1e9
    assert abs(t_al - s["time_to_aligned_s"]) < 1e-9

    euler = read_topic(out, "/alignment/euler_deg")
    ticks = np.unique(stamps // 100_000_000, return_index=True)[1]
    assert [ns for ns, _ in euler] == stamps[ticks].tolist()        # first sample of each 0.1 s
    assert all(ns == stamp_ns(m) for ns, m in euler)
    e = euler[-1][1].vector
    q = imu[-1][1].orientation
    rpy = rpy_from_dcm(dcm_from_quat(np.array([q.x, q.y, q.z, q.w]))) / DEG
    assert euler[-1][0] == stamps[-1]                                # 80.00 s starts a bin
    np.testing.assert_allclose([e.x, e.y, e.z], rpy, atol=1e-9)
    diag = read_topic(out, "/diagnostics")
    seconds = np.unique(stamps // 10**9, return_index=True)[1]
    assert [ns for ns, _ in diag] == stamps[seconds].tolist()       # first sample of each 1 s
    assert diag[-1][1].status[0].name == "align_node: alignment"
    kv = {v.key: v.value for v in diag[-1][1].status[0].values}
    assert kv["state"] == "aligned" and kv["input_rate_hz"] == "100.00"

    rows = (d / "a.csv").read_text().splitlines()
    head = rows[0].split(",")
    assert head[:13] == ["t", "qx", "qy", "qz", "qw", "roll", "pitch", "yaw", "heading",
                         "std_e", "std_n", "std_u", "aligned"]
    assert head[-3:] == ["err_e", "err_n", "err_u"]
    assert len(rows) - 1 == len(ticks)        # every 0.1 s tick (the final sample is one)
    last = dict(zip(head, rows[-1].split(",")))
    assert float(last["t"]) == pytest.approx(79.99) and last["aligned"] == "1"
    assert float(last["heading"]) == pytest.approx(s["final"]["heading_deg"], abs=1e-6)
    assert [float(last[k]) for k in ("err_e", "err_n", "err_u")] == pytest.approx(
        s["final"]["error_enu_deg"], abs=1e-5)


# ------------------------------------------------------------------------------ block feeding
def write_imu_bag(path: Path, stamps_ns, gyro, accel, frames=None, compression="zstd"):
    """rosbag2 mcap bag of /imu/data_raw with the given header stamps (log time: 10 ms steps,
    always increasing, whatever the stamps do)."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    from sins_align.io.bagio import typestore

    ts = typestore()
    T = ts.types
    V = T["geometry_msgs/msg/Vector3"]
    w = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    if compression == "zstd":
        w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    w.open()
    c = w.add_connection("/imu/data_raw", "sensor_msgs/msg/Imu", typestore=ts)
    cov = np.zeros(9)
    for k in range(len(stamps_ns)):
        sec, nsec = divmod(int(stamps_ns[k]), 1_000_000_000)
        hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=nsec), frame_id=frames[k] if frames else "imu_link")
        m = T["sensor_msgs/msg/Imu"](
            header=hdr, orientation=T["geometry_msgs/msg/Quaternion"](0., 0., 0., 1.),
            orientation_covariance=cov, angular_velocity=V(*map(float, gyro[k])),
            angular_velocity_covariance=cov, linear_acceleration=V(*map(float, accel[k])),
            linear_acceleration_covariance=cov)
        w.write(c, 1_000_000_000 + 10_000_000 * k, ts.serialize_cdr(m, "sensor_msgs/msg/Imu"))
    w.close()


def _replay_both(bag, config, **kw):
    """Summary-only (block path) and per-sample replays of one bag, with CSV and plot rows."""
    out = {}
    for per_sample in (False, True):
        csv = bag.parent / f"{bag.name}_{per_sample}.csv"
        s, sess = replay.replay(bag, config, per_sample=per_sample, progress=False, **kw)
        s_csv, sess_csv = replay.replay(bag, config, per_sample=per_sample, csv_path=csv,
                                        keep_plot=True, progress=False, **kw)
        assert sess.reading[0] == ("rosbags" if per_sample else "mcap-numpy"), sess.reading
        assert sess.block is not per_sample and sess_csv.block is not per_sample
        for x in (s, s_csv):
            x.pop("wall_time_s")
            x.pop("messages_per_s")
        out[per_sample] = (s, s_csv, csv.read_text(), sess_csv.series.rows)
    return out[False], out[True]


def _assert_same_csv(a: str, b: str):
    """CSV rows of the block path (Aligner.update_states: the fast path's outputs after each
    sample) against the per-sample path's: same rows, header and flags; values to rounding
    (the fast path agrees with the one-sample path to ~1e-11 rad and ~1e-9 relative in the
    covariance, so a printed last digit may differ: not character for character)."""
    la, lb = a.splitlines(), b.splitlines()
    assert la[0] == lb[0] and len(la) == len(lb)
    x = np.array([[float(v) for v in line.split(",")] for line in la[1:]])
    y = np.array([[float(v) for v in line.split(",")] for line in lb[1:]])
    np.testing.assert_allclose(x, y, rtol=1e-7, atol=1e-9)


def _assert_same_summary(a, b, tol_rad=1e-9):
    """Same counts, flags, times; final attitude within tol_rad; covariance to rounding."""
    fa, fb = a["final"], b["final"]
    err = attitude_error(dcm_from_quat(np.array(fa["orientation_xyzw"])),
                         dcm_from_quat(np.array(fb["orientation_xyzw"])))
    assert np.abs(err).max() < tol_rad, err
    np.testing.assert_allclose(fa["covariance_enu_rad2"], fb["covariance_enu_rad2"],
                               rtol=1e-7, atol=1e-20)
    for k in ("samples", "samples_used", "rejected", "events", "duration_s", "aligned",
              "time_to_aligned_s", "status", "resets", "stage", "aligned_changes", "config",
              "limit_std_enu_deg"):
        assert a[k] == b[k], k
    assert fa["stamp_s"] == fb["stamp_s"] and fa["frame_id"] == fb["frame_id"]


def test_block_fed_replay_equals_per_sample_replay_with_bad_samples(work):
    """A 100 Hz bag with everything the per-sample path handles sample by sample: a looped
    start (stamps jump back 20 s: the node's restart), a NaN, a duplicate and a backward
    stamp, a 10 s forward time jump, frame_id changes, and a lasting disturbance that drops
    the aligned flag (re-inflation) and raises it again. The summary-only replay (blocks of
    thousands on the
    estimator's fast path, MCAP read by numpy) and the per-sample replay agree: attitude to
    1e-9 rad, identical rejected counts, events, resets, time to aligned and the sample of
    every aligned-flag change; the CSV and plot rows (from the block path's outputs
    after each sample) agree to rounding."""
    sim = sim_simulate(330.0, rate=100.0, lat_deg=LAT, rpy_deg=(1.0, -2.0, 30.0), seed=3,
                       specs="navigation")
    n = len(sim.t)
    stamps = 1_700_000_000 * 10**9 + np.arange(n, dtype=np.int64) * 10_000_000
    stamps[3000:] -= 20 * 10**9                 # looped: restart at the third such stamp
    stamps[25000:] += 10 * 10**9                # a forward time jump (time_jump, re-anchor)
    gyro, acc = sim.gyro.copy(), sim.accel.copy()
    acc[12000:13000, 0] += 0.05                 # 10 s of a tilt-like force after alignment:
    #                                             re-inflated, aligned again later
    gyro[15000] = np.nan
    stamps[17000] = stamps[16999]               # duplicate
    stamps[17500] = stamps[17499] - 1_000_000_000   # 1 s backwards (no restart)
    frames = ["imu_link"] * n
    frames[20000:20003] = ["imu_a", "imu_b", "imu_a"]
    frames[28000:] = ["imu_final"] * (n - 28000)
    bag = work / "bad_samples"
    write_imu_bag(bag, stamps, gyro, acc, frames)
    (s, s_csv, csv, rows), (r, r_csv, r_csvtext, r_rows) = _replay_both(
        bag, AlignConfig(latitude_deg=LAT))
    _assert_same_summary(s, r)
    _assert_same_summary(s, s_csv)
    assert r == r_csv
    assert s["resets"] == 1 and s["events"]["time_jump"] == 1 and s["samples"] == n
    # counters survive the restart: the two looped samples before it stay counted; the
    # time jump is taken after JUMP_CONFIRM samples agree on the new time line
    assert s["rejected"] == {"nonfinite": 1, "duplicate_stamp": 1, "stamp_backwards": 3,
                             "time_jump": JUMP_CONFIRM}
    assert [c["aligned"] for c in s["aligned_changes"]] == [False, True, False, True]
    assert s["final"]["frame_id"] == "imu_final" and s["aligned"]
    _assert_same_csv(csv, r_csvtext)
    assert len(rows) == len(r_rows)
    np.testing.assert_allclose(np.array(rows), np.array(r_rows), rtol=1e-7, atol=1e-9)


def test_block_fed_replay_of_a_units_fault_and_a_1khz_bag(work):
    """Gyro rates switched to deg/s after alignment: the units check drops the flag at a
    rejected sample, placed as the per-sample path places it. And at 1 kHz, where the CSV
    blocks between 10 Hz ticks are long enough for the fast path, the rows agree with the
    per-sample ones to rounding."""
    sim = sim_simulate(200.0, rate=100.0, lat_deg=LAT, rpy_deg=(1.0, -2.0, 30.0), seed=3,
                       specs="navigation")
    stamps = np.arange(len(sim.t), dtype=np.int64) * 10_000_000 + 10_000_000
    gyro = sim.gyro.copy()
    gyro[12000:] *= 180.0 / np.pi
    bag = work / "units"
    write_imu_bag(bag, stamps, gyro, sim.accel)
    (s, _, csv, _), (r, _, r_csv, _) = _replay_both(bag, AlignConfig(latitude_deg=LAT))
    _assert_same_summary(s, r)
    assert [c["aligned"] for c in s["aligned_changes"]] == [False, True, False]
    # deg/s from 120 s: the innovations leave the gate at once and the covariance is
    # re-inflated once that persists, before the units window closes at 150 s
    assert 120.0 < s["aligned_changes"][2]["t_s"] < 150.1
    assert s["rejected"]["rates_look_like_deg_per_s"] > 0
    _assert_same_csv(csv, r_csv)

    sim = sim_simulate(30.0, rate=1000.0, lat_deg=LAT, rpy_deg=(1.0, -2.0, 30.0), seed=4,
                       specs="navigation", sway="car")
    stamps = np.arange(len(sim.t), dtype=np.int64) * 1_000_000 + 1_000_000
    bag = work / "fast_1khz"
    write_imu_bag(bag, stamps, sim.gyro, sim.accel, compression="none")
    config = AlignConfig(latitude_deg=LAT, backtrack_time=20.0)
    (s, _, csv, rows), (r, _, r_csv, r_rows) = _replay_both(bag, config)
    _assert_same_summary(s, r)
    a = np.array([[float(x) for x in line.split(",")] for line in csv.splitlines()[1:]])
    b = np.array([[float(x) for x in line.split(",")] for line in r_csv.splitlines()[1:]])
    assert a.shape == b.shape == (301, 14)
    np.testing.assert_allclose(a, b, rtol=1e-7, atol=1e-9)
    assert len(rows) == len(r_rows)


def test_params_yaml_is_the_node_format_and_flags_override_it(work, sim_bag, capsys):
    y = work / "align.yaml"
    y.write_text("align_node:\n  ros__parameters:\n    latitude: 34.0\n    grade: navigation\n"
                 "    model: conventional\n"
                 "    backtrack_time: 30.0\n")
    js = work / "params.json"
    rc, _, err = cli(replay, [sim_bag, "--params", y, "--model", "constant", "--summary-json",
                              js, "--quiet"], capsys)
    assert rc == 0, err
    c = json.loads(js.read_text())["config"]
    assert c["model"] == "constant" and c["backtrack_time_s"] == 30.0 and c["latitude_deg"] == 34
    # the node's own parameter file (with node-only euler_rate/queue_size) works as it is
    node_yaml = Path(sins_align.__file__).parent / "config" / "align.yaml"
    js2 = work / "params_node.json"
    rc, _, err = cli(replay, [sim_bag, "--params", node_yaml, "--summary-json", js2, "--quiet"],
                     capsys)
    assert rc == 0, err
    assert json.loads(js2.read_text())["config"]["latitude_deg"] == 34.0


# ------------------------------------------------------------------------------ real data
def test_import_tells_an_xz_compressed_psins_log_by_its_first_line(work, capsys):
    """A PSINS log under a name that says nothing (``log.xz``) is still read as PSINS: the
    first line of the decompressed text starts with '%'. A compressed CSV is read as CSV; a
    truncated one is refused in one line and writes nothing."""
    renamed = work / "log.xz"
    shutil.copyfile(LASERGYRO, renamed)
    rc, out, err = cli(import_imu, [renamed, work / "lg", "--max-samples", 100], capsys)
    assert rc == 0, err
    assert "from psins log.xz" in out and "100 samples" in out
    csv = work / "csv.xz"
    with lzma.open(csv, "wt") as fh:
        fh.write("t,gx,gy,gz,ax,ay,az\n" + "".join(
            f"{0.01 * k},0,0,0,0,0,9.8\n" for k in range(1, 50)))
    rc, out, err = cli(import_imu, [csv, work / "csv_out"], capsys)
    assert rc == 0, err
    assert "49 samples" in out and "from text csv.xz" in out
    assert len(read_topic(work / "csv_out", "/imu/data_raw")) == 49
    cut = work / "cut.xz"
    cut.write_bytes(csv.read_bytes()[:-30])
    rc, out, err = cli(import_imu, [cut, work / "cut_out"], capsys)
    assert rc != 0 and "not a readable xz file" in err and len(err.strip().splitlines()) == 1
    assert not (work / "cut_out").exists()


def test_psins_log_import_and_replay_agree_from_a_large_initial_error(work, capsys):
    """import_imu on the project's copy of the real log (xz) + replay from a small and from a
    [89, 89, 179] deg larger error: both agree, and both land within 3 sigma of their
    published std of an independent inertial-frame alignment of the same samples (before:
    level within 0.6 deg of a value 0.5 deg from the start, heading within 1 deg)."""
    bag = work / "lasergyro300"
    rc, out, err = cli(import_imu, [LASERGYRO, bag, "--max-duration", 300], capsys)
    assert rc == 0, err
    assert "from psins lasergyro.imu.xz" in out      # told a PSINS log by its name (.imu.xz)
    imu = read_topic(bag, "/imu/data_raw")
    assert len(imu) == 30000 and imu[0][1].header.frame_id == "imu_link"
    assert stamp_ns(imu[0][1]) == 10_000_000 and stamp_ns(imu[-1][1]) == 300_000_000_000
    # the shipped sample bag is this import (bags/README.md gives the command)
    shipped = read_topic(Path(__file__).resolve().parents[1] / "bags" / "lasergyro_300s",
                         "/imu/data_raw")
    assert len(shipped) == len(imu)
    for (_, m), (_, s) in zip(imu, shipped):
        assert stamp_ns(m) == stamp_ns(s) and m.header.frame_id == s.header.frame_id
        assert (m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) == \
            (s.angular_velocity.x, s.angular_velocity.y, s.angular_velocity.z)
        assert (m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z) == \
            (s.linear_acceleration.x, s.linear_acceleration.y, s.linear_acceleration.z)
    # the file's coarse attitude (PSINS pitch, roll, yaw) -> REP-103 rpy of its RFU axes
    rpy0 = rpy_from_dcm(psins_att_to_dcm(np.array([0.9, 0.4, -90.6]) * DEG)) / DEG
    small = rpy0 + np.array([0.5, -0.5, 2.0])
    large = small + np.array([89.0, 89.0, 179.0])
    procs = []
    for name, rpy in (("small", small), ("large", large)):
        js = work / f"psins_{name}.json"
        procs.append((js, subprocess.Popen(
            [sys.executable, "-m", "sins_align.replay", str(bag), "--latitude", str(PSINS_LAT),
             "--grade", "navigation",
             "--initial-rpy", *map(str, rpy), "--summary-json", str(js), "--quiet"],
            stderr=subprocess.PIPE, text=True)))
    res = []
    for js, p in procs:
        _, e = p.communicate(timeout=120)
        assert p.returncode == 0, e
        res.append(json.loads(js.read_text()))
    a, b = res
    assert a["aligned"] and b["aligned"]
    dh = (a["final"]["heading_deg"] - b["final"]["heading_deg"] + 180.0) % 360.0 - 180.0
    phi = attitude_error(dcm_from_quat(np.array(a["final"]["orientation_xyzw"])),
                         dcm_from_quat(np.array(b["final"]["orientation_xyzw"]))) / DEG
    assert abs(dh) < 0.05, dh
    assert np.all(np.abs(phi[:2]) < 0.01), phi
    # and it is the right answer: the independent reference from the same 300 s of samples
    log = read_psins(LASERGYRO, max_samples=30000)
    ref = inertial_frame_alignment(log.ts, log.gyro, log.accel, log.lat_rad,
                                   gravity(log.lat_rad, log.height_m))
    for r, rpy in ((a, small), (b, large)):
        # the start was off by more than the bound: a replay that did not move would fail
        start_err = attitude_error(ref, dcm_from_rpy(np.asarray(rpy) * DEG)) / DEG
        sd = np.array(r["final"]["std_enu_deg"])
        assert np.any(np.abs(start_err) > 3 * sd), (start_err, sd)
        e = attitude_error(ref, dcm_from_quat(np.array(r["final"]["orientation_xyzw"]))) / DEG
        assert np.all(np.abs(e) < 3 * sd), (e, sd)


# ------------------------------------------------------------------------------ text import
def _check_imported(bag: Path, ref_t_ns, ref_gyro, ref_acc, rtol=1e-12):
    imu = read_topic(bag, "/imu/data_raw")
    assert [stamp_ns(m) for _, m in imu] == list(ref_t_ns)
    g = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                  for _, m in imu])
    a = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                  for _, m in imu])
    np.testing.assert_allclose(g, ref_gyro, rtol=rtol, atol=1e-15)
    np.testing.assert_allclose(a, ref_acc, rtol=rtol, atol=1e-15)


def test_import_csv_with_header_in_deg_per_s_and_g(work, sim_truth, capsys):
    r = sim_truth
    n = 300
    ns = sample_stamps_ns(1.7e9, 100.0, 0, n)           # epoch stamps keep every nanosecond
    lines = ["time [s],gyro_x (deg/s),gyro_y (deg/s),gyro_z (deg/s),acc_x [g],acc_y [g],"
             "acc_z [g],temperature"]
    for k in range(n):
        t = f"{ns[k] // 10**9}.{ns[k] % 10**9:09d}"
        lines.append(",".join([t, *(repr(float(x) / DEG) for x in r.gyro[k]),
                               *(repr(float(x) / 9.80665) for x in r.accel[k]), "25.0"]))
    src = work / "log.csv"
    src.write_text("\n".join(lines) + "\n")
    out = work / "csv_bag"
    rc, o, err = cli(import_imu, [src, out, "--gyro-units", "deg/s", "--accel-units", "g"],
                     capsys)
    assert rc == 0, err
    _check_imported(out, ns, r.gyro[:n], r.accel[:n])


def test_import_whitespace_increments_with_columns_and_skip_rows(work, sim_truth, capsys):
    r = sim_truth
    n = 200
    ns = sample_stamps_ns(0.0, 100.0, 0, n)
    dt = 0.01
    lines = ["my logger v1", "units: whatever"]
    for k in range(n):
        lines.append("  ".join(["7", f"{ns[k] / 1e6:.6f}",
                                *(repr(float(x) * dt) for x in r.accel[k]),
                                *(repr(float(x) * dt / DEG) for x in r.gyro[k])]))
    src = work / "log.txt"
    src.write_text("\n".join(lines) + "\n")
    out = work / "txt_bag"
    rc, _, err = cli(import_imu, [src, out, "--columns", "_,t,ax,ay,az,gx,gy,gz",
                                  "--skip-rows", 2, "--time-units", "ms", "--gyro-units", "deg",
                                  "--accel-units", "m/s", "--max-samples", 150], capsys)
    assert rc == 0, err
    _check_imported(out, ns[:150], r.gyro[:150], r.accel[:150], rtol=1e-9)


@pytest.mark.parametrize("body, extra, where", [
    ("t,gx,gy,gz,ax,ay,az\n0.01,0,0,0,0,0,9.8\n0.02,0,0,x,0,0,9.8\n", [], ":3:"),
    ("0.01 0 0 0 0 0 9.8\n0.02 0 0 0 0 9.8\n", [], ":2:"),
    ("0.01 0 0 0 0 0 9.8\n0.02 0 0 0 0 0 9.8\n0.02 0 0 0 0 0 9.8\n", [], ":3:"),
    ("time,a,b,c\n1,2,3,4\n", [], ":1:"),
    ("0.01 0 0 0 0 0 nan\n", [], ":1:"),
    ("# nothing\n", [], "no data lines"),
    ("0.01 0 0 0 0 0 9.8\n", ["--columns", "t,gx,gy"], "--columns"),
])
def test_import_malformed_text_names_the_line(work, capsys, body, extra, where, request):
    src = work / f"bad_{request.node.callspec.id}.txt"
    src.write_text(body)
    before = listing(work)
    rc, _, err = cli(import_imu, [src, work / "never", *extra], capsys)
    assert rc != 0 and where in err and len(err.strip().splitlines()) == 1, err
    assert listing(work) == before


def test_import_malformed_psins_header_names_the_line(work, capsys):
    src = work / "bad.imu"
    src.write_text("% header\n0 0 -90 0 0 0\n34 108 380 0 10\n")
    rc, _, err = cli(import_imu, [src, work / "never"], capsys)
    assert rc == 2 and "bad.imu:3:" in err and len(err.strip().splitlines()) == 1
    assert not (work / "never").exists()


# ------------------------------------------------------------------------------ errors
@pytest.fixture(scope="module")
def bad_inputs(work, sim_bag):
    """Broken bags and parameter files, built once."""
    from rosbags.rosbag2 import Writer

    from sins_align.io.bagio import typestore

    d = work / "bad"
    d.mkdir()
    (d / "notes.txt").write_text("not a bag\n")
    (d / "garbage.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 40)
    mc = next(sim_bag.glob("*.mcap")).read_bytes()
    (d / "truncated.mcap").write_bytes(mc[: len(mc) // 2])
    w = Writer(d / "empty_imu", version=9)
    w.open()
    w.add_connection("/imu/data_raw", "sensor_msgs/msg/Imu", typestore=typestore())
    w.close()
    (d / "bad_syntax.yaml").write_text("sins_align: [\n")
    (d / "bad_value.yaml").write_text("/**:\n  ros__parameters:\n    latitude: 34.0\n"
                                      "    backtrack_time: -1.0\n")
    (d / "three_specs.yaml").write_text("/**:\n  ros__parameters:\n    latitude: 34.0\n"
                                        "    gyro_bias: 0.5\n    gyro_arw: 0.01\n"
                                        "    accel_bias: 200.0\n")
    (d / "no_node.yaml").write_text("other_node:\n  ros__parameters:\n    latitude: 34.0\n")
    (d / "exists").mkdir()
    (d / "exists.csv").write_text("x\n")
    return d


#: the site and grade every case gives unless it is about them
SITE = ["--latitude", "34", "--grade", "navigation"]
REPLAY_ERRORS = {
    "missing file": (["{d}/nope.mcap", *SITE], "does not exist"),
    "not a bag": (["{d}/notes.txt", *SITE], "not a rosbag2"),
    "corrupt bag": (["{d}/garbage.mcap", *SITE], "cannot read bag"),
    "truncated bag": (["{d}/truncated.mcap", *SITE], "cannot read bag"),
    "topic absent": (["{bag}", *SITE, "--topic", "/nope"], "not in"),
    "topic wrong type": (["{bag}", *SITE, "--topic", "/imu_sim/truth"],
                         "not sensor_msgs/msg/Imu"),
    "truth wrong type": (["{bag}", *SITE, "--truth-topic", "/imu/data_raw"],
                         "not geometry_msgs/msg/QuaternionStamped"),
    "no samples": (["{d}/empty_imu", *SITE], "no messages"),
    "output exists": (["{bag}", *SITE, "--output", "{d}/exists"], "already exists"),
    "csv exists": (["{bag}", *SITE, "--csv", "{d}/exists.csv"], "already exists"),
    "summary exists": (["{bag}", *SITE, "--summary-json", "{d}/exists.csv"],
                       "already exists"),
    "latitude missing": (["{bag}"], "latitude is required"),
    "grade missing": (["{bag}", "--latitude", "34"], "grade is required: pass --grade"),
    "specs without grade": (["{bag}", "--params", "{d}/three_specs.yaml"],
                            "grade is required"),
    "latitude out of range": (["{bag}", "--latitude", "95"], "latitude"),
    "bad model": (["{bag}", *SITE, "--model", "kalman"], "model"),
    "params syntax": (["{bag}", "--params", "{d}/bad_syntax.yaml"], "parameters file"),
    "params value": (["{bag}", "--params", "{d}/bad_value.yaml"], "backtrack_time"),
    "params no node": (["{bag}", "--params", "{d}/no_node.yaml"], "ros__parameters"),
    "params missing": (["{bag}", "--params", "{d}/nope.yaml"], "does not exist"),
}


@pytest.mark.parametrize("case", sorted(REPLAY_ERRORS))
def test_replay_bad_input_is_one_line_and_leaves_nothing(case, bad_inputs, sim_bag, capsys):
    args, expect = REPLAY_ERRORS[case]
    d = bad_inputs
    args = [a.format(d=d, bag=sim_bag) for a in args]
    new = d / f"new_{case.replace(' ', '_')}"
    outs = ["--output", f"{new}_bag", "--csv", f"{new}.csv", "--summary-json", f"{new}.json"]
    if case in ("output exists", "csv exists", "summary exists"):
        outs = []
    before = listing(d)
    rc, out, err = cli(replay, [*args, *outs], capsys)
    assert rc != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("replay: error:"), err
    assert expect in lines[0] and "Traceback" not in err
    assert listing(d) == before, "output left behind"


def test_plot_without_matplotlib_fails_before_any_work(bad_inputs, sim_bag, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)      # import matplotlib -> ImportError
    d = bad_inputs
    before = listing(d)
    rc, _, err = cli(replay, [sim_bag, "--latitude", 34, "--grade", "navigation", "--plot",
                              d / "p.png", "--summary-json", d / "p.json"], capsys)
    assert rc != 0 and err.count("\n") == 1 and "pip install matplotlib" in err
    assert listing(d) == before


def test_plot_is_written(work, sim_bag, capsys):
    """--plot writes a PNG. matplotlib is a pinned test requirement (.ci/requirements.txt,
    checked in test_montecarlo), so it is imported here outright: without it this test
    fails instead of skipping."""
    import matplotlib

    pin = [r for r in (Path(__file__).resolve().parents[1] / ".ci" / "requirements.txt")
           .read_text().split() if r.startswith("matplotlib==")]
    assert pin == [f"matplotlib=={matplotlib.__version__}"], (pin, matplotlib.__version__)
    png = work / "plot.png"
    rc, _, err = cli(replay, [sim_bag, "--latitude", 34, "--grade", "navigation",
                              "--truth-topic", "/imu_sim/truth",
                              "--plot", png, "--quiet"], capsys)
    assert rc == 0, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_simulate_and_import_errors_are_one_line(bad_inputs, capsys):
    d = bad_inputs
    for mod, args in ((simulate, ["--rate", "0", d / "x1"]),
                      (simulate, ["--duration", "0.001", d / "x2"]),
                      (simulate, [d / "exists"]),
                      (import_imu, [d / "nope.csv", d / "x3"]),
                      (import_imu, [d / "notes.txt", d / "exists"])):
        before = listing(d)
        rc, _, err = cli(mod, args, capsys)
        assert rc != 0 and len(err.strip().splitlines()) == 1, (args, err)
        assert "Traceback" not in err and listing(d) == before


def test_tools_run_as_python_modules(bad_inputs):
    for tool in ("replay", "simulate", "import_imu"):
        p = subprocess.run([sys.executable, "-m", f"sins_align.{tool}", "--help"],
                           capture_output=True, text=True, timeout=60)
        assert p.returncode == 0 and "usage:" in p.stdout, p.stderr
    p = subprocess.run([sys.executable, "-m", "sins_align.tools.replay", str(bad_inputs / "nope")],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "does not exist" in p.stderr
