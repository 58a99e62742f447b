"""Replay == live node: the same bag through align_node over DDS and through ``replay``.

A simulated bag (car sway, large initial error, backtrack after 20 s, aligned before 80 s) is
played into the node's ``imu/data_raw`` with a RELIABLE publisher at a modest rate; the node's
``imu/data`` is collected and compared, stamp by stamp, with the ``/imu/data`` of
``replay --output`` run with the same parameter file. Proves that the node and the replay share
one code path: the orientation and its covariance agree to 1e-9 on every sample, and both
republish the same samples.
"""
from __future__ import annotations

import time

import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu
from std_msgs.msg import Bool

from ros_helpers import LATCHED, NodeProcess, Probe, stamp_ns, wait_until
from sins_align.tools import replay
from sins_align.tools import simulate

NS = "/rv"
RATE = 50.0
DURATION = 80.0
PUBLISH_HZ = 500.0          # wall rate of the playback (10x real time)
RELIABLE = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
PARAMS = """/**:
  ros__parameters:
    latitude: 34.0
    grade: navigation
    backtrack_time: 20.0
    initial_rpy: [60.0, -45.0, 170.0]
"""


def _read(bag, topic):
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as r:
        conns = [c for c in r.connections if c.topic == topic]
        return [r.deserialize(raw, c.msgtype) for c, _, raw in r.messages(conns)]


def _to_rclpy(m) -> Imu:
    out = Imu()
    out.header.stamp.sec = int(m.header.stamp.sec)
    out.header.stamp.nanosec = int(m.header.stamp.nanosec)
    out.header.frame_id = m.header.frame_id
    out.orientation_covariance = [float(x) for x in m.orientation_covariance]
    out.angular_velocity.x, out.angular_velocity.y, out.angular_velocity.z = (
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z)
    out.linear_acceleration.x, out.linear_acceleration.y, out.linear_acceleration.z = (
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z)
    out.angular_velocity_covariance = [float(x) for x in m.angular_velocity_covariance]
    out.linear_acceleration_covariance = [float(x) for x in m.linear_acceleration_covariance]
    return out


@pytest.fixture(scope="module")
def probe():
    p = Probe("test_replay_vs_node_probe")
    yield p
    p.close()


def test_node_and_replay_publish_identical_orientations(tmp_path, probe):
    bag = tmp_path / "bag"
    assert simulate.main(["--latitude", "34", "--rpy", "1.5", "-0.7", "40", "--sway", "car",
                          "--rate", str(RATE), "--duration", str(DURATION), "--seed", "5",
                          str(bag)]) == 0
    yaml = tmp_path / "align.yaml"
    yaml.write_text(PARAMS)
    out = tmp_path / "replayed"
    assert replay.main([str(bag), "--params", str(yaml), "--output", str(out), "--quiet"]) == 0
    expected = {stamp_ns(m.header.stamp): m for m in _read(out, "/imu/data")}
    raw = _read(bag, "/imu/data_raw")
    assert len(expected) == len(raw) == int(RATE * DURATION)

    got = probe.subscribe(Imu, f"{NS}/imu/data", RELIABLE)
    aligned = probe.subscribe(Bool, f"{NS}/alignment/aligned", LATCHED)
    pub = probe.node.create_publisher(Imu, f"{NS}/imu/data_raw", RELIABLE)
    node = NodeProcess("align_node", ["-r", f"__ns:={NS}", "--params-file", str(yaml)],
                       tmp_path / "logs", "align_rv")
    try:
        wait_until(lambda: (pub.get_subscription_count() > 0
                            and probe.node.count_publishers(f"{NS}/imu/data") > 0)
                   or not node.alive(), 30.0, "align_node to come up")
        assert node.alive(), node.output()
        time.sleep(0.5)                        # let the discovery settle both ways
        t0 = time.monotonic()
        for k, m in enumerate(raw):
            pub.publish(_to_rclpy(m))
            delay = t0 + (k + 1) / PUBLISH_HZ - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        wait_until(lambda: len(got) >= len(expected) or not node.alive(), 30.0,
                   f"{len(expected)} imu/data messages (got {len(got)})")
        time.sleep(0.3)                        # nothing more may come
    finally:
        node.stop()
    live = {stamp_ns(m.header.stamp): m for m in got.msgs}
    assert len(got) == len(expected), node.output()
    assert live.keys() == expected.keys()
    worst = 0.0
    for ns, e in expected.items():
        m = live[ns]
        qe = np.array([e.orientation.x, e.orientation.y, e.orientation.z, e.orientation.w])
        ql = np.array([m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w])
        worst = max(worst, float(np.max(np.abs(qe - ql))))
        np.testing.assert_allclose(ql, qe, rtol=0, atol=1e-9, err_msg=f"stamp {ns}")
        np.testing.assert_allclose(np.array(m.orientation_covariance),
                                   e.orientation_covariance, rtol=1e-9, atol=1e-18,
                                   err_msg=f"stamp {ns}")
    # and the run reached the fine pass and the aligned flag, in both
    flags = [m.data for m in aligned.msgs]
    assert flags[0] is False and flags[-1] is True
    assert [m.data for m in _read(out, "/alignment/aligned")] == [False, True]
    print(f"max |q_node - q_replay| = {worst:.3g} over {len(live)} samples")
