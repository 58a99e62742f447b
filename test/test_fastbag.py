"""Bags opened without rosbags (sins_align.io.fastbag) against rosbags.

What the fast opening reads must be what rosbags reads: the (log time, bytes) sequence of a
topic through ``TopicBlocks`` on a ``FastBag`` equals rosbags' ``reader.messages`` exactly,
the decoded arrays equal rosbags' deserialiser, and a replay gives the same summary. What
it does not take (message-compressed sqlite3, split bags, a non-standard Imu definition, a
corrupt database, stamps out of order) goes to rosbags, whole or from where it was found.
"""
from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from sins_align.io.bagio import (MessageBlock, TopicBlocks, open_reader, open_writer,
                                 qos_profile, read_messages, typestore)
from sins_align.io.cdr import decode_imu_array
from sins_align.io.fastbag import FastBag, Unusual, check_definition, open_fast
from sins_align.estimators.quasi_static.aligner import AlignConfig
from sins_align.tools import replay

from cli_helpers import simulated_bags
from test_mcap_fast import IMU, QUAT, assert_replay_equals_rosbags, imu_raw, truth_raw

NS = 10_000_000


def write_bag(path, items, storage="sqlite3", compression="none"):
    """A rosbag2 bag written by rosbags' Writer: ``items`` [(topic, log ns, raw)] in order."""
    w = open_writer(path, storage, compression)
    st = typestore()
    conns = {"/imu": w.add_connection("/imu", IMU, typestore=st,
                                      offered_qos_profiles=[qos_profile()]),
             "/truth": w.add_connection("/truth", QUAT, typestore=st)}
    for topic, ns, raw in items:
        w.write(conns[topic], ns, raw)
    w.close()
    return path


def interleaved(k0, k1, frame=lambda k: "imu_link"):
    out = []
    for k in range(k0, k1):
        out.append(("/imu", NS * k + 1, imu_raw(k, frame(k))))
        out.append(("/truth", NS * k + 1, truth_raw(k)))
    return out


def rosbags_messages(path, topic):
    r = open_reader(path)
    try:
        conns = [c for c in r.connections if c.topic == topic]
        return [(ns, bytes(raw)) for _, ns, raw in read_messages(r, conns, path)]
    finally:
        r.close()


def fast_read(path, topic):
    """(TopicBlocks on the FastBag, its (log ns, bytes) sequence)."""
    bag = open_fast(path)
    assert isinstance(bag, FastBag)
    try:
        conns = [c for c in bag.connections if c.topic == topic]
        tb = TopicBlocks(bag, conns, path)
        got = [(int(b.log_ns[i]), b.raw(i)) for b in tb for i in range(len(b))]
    finally:
        bag.close()
    return tb, got


def to_arrays(batches):
    return [np.concatenate(x) for x in zip(*((b.sec, b.nanosec, b.floats) for b in batches))]


# ------------------------------------------------------------------------------ sqlite3
def test_sqlite3_bag_read_in_bulk_equals_rosbags(tmp_path):
    """Imu and truth interleaved, a frame_id change (another message size); the bytes and
    log times, in windows of any size, and the decoded arrays equal rosbags'."""
    bag = write_bag(tmp_path / "a", interleaved(0, 1500, lambda k: "imu" if k < 700 else
                                                 "imu_longer_frame"))
    for topic in ("/imu", "/truth"):
        tb, got = fast_read(bag, topic)
        assert tb.fallback_reason is None and tb.fast_messages == 1500
        assert got == rosbags_messages(bag, topic)
    fast = open_fast(bag)
    try:
        conns = [c for c in fast.connections if c.topic == "/imu"]
        assert fast.topics["/imu"].msgtype == IMU and fast.topics["/imu"].msgcount == 1500
        blocks = list(fast.fast_blocks(conns, 7))             # small windows
        assert all(isinstance(b, MessageBlock) for b in blocks) and len(blocks) == 215
        ours = to_arrays([decode_imu_array(b.buf, b.starts, b.sizes) for b in blocks])
    finally:
        fast.close()
    r = open_reader(bag)
    try:
        conns = [c for c in r.connections if c.topic == "/imu"]
        msgs = [r.deserialize(raw, IMU) for _, _, raw in read_messages(r, conns, bag)]
    finally:
        r.close()
    ref = [np.array([m.header.stamp.sec for m in msgs]),
           np.array([m.header.stamp.nanosec for m in msgs]),
           np.array([np.concatenate([[m.orientation.x, m.orientation.y, m.orientation.z,
                                      m.orientation.w], m.orientation_covariance,
                                     [m.angular_velocity.x, m.angular_velocity.y,
                                      m.angular_velocity.z], m.angular_velocity_covariance,
                                     [m.linear_acceleration.x, m.linear_acceleration.y,
                                      m.linear_acceleration.z],
                                     m.linear_acceleration_covariance]) for m in msgs])]
    for a, b in zip(ours, ref):
        assert np.array_equal(a, b)


def test_replay_of_sqlite3_bag_equals_rosbags_reading(tmp_path):
    from sins_align.tools import simulate

    bag = tmp_path / "sim"
    assert simulate.main(["--latitude", "34", "--duration", "70", "--rate", "100",
                          "--sway", "car", "--storage", "sqlite3", str(bag)]) == 0
    assert_replay_equals_rosbags(bag, "sqlite3-bulk")


@pytest.mark.parametrize("case", ["back in time", "tie"])
def test_sqlite3_stamps_out_of_order_go_to_rosbags_from_there(tmp_path, case):
    """rosbags orders by timestamp; rows out of stamp order (or two at one stamp, whose
    order SQLite's plan decides) hand over to rosbags, with rosbags' sequence."""
    items = interleaved(0, 20000)
    k = 2 * 17000
    items[k] = ("/imu", items[k][1] - (5 * NS if case == "back in time" else 2 * NS),
                items[k][2])
    bag = write_bag(tmp_path / "b", items)
    tb, got = fast_read(bag, "/imu")
    assert got == rosbags_messages(bag, "/imu")
    assert tb.fast_messages == 16384 and "timestamp order" in tb.fallback_reason


def test_message_compressed_sqlite3_and_split_bags_open_with_rosbags(tmp_path):
    bag = write_bag(tmp_path / "z", interleaved(0, 50), compression="zstd")
    assert open_fast(bag) is None
    s, sess = replay.replay(bag, AlignConfig(latitude_deg=34.0), progress=False)
    assert sess.reading[0] == "rosbags" and s["samples"] == 50
    split = write_bag(tmp_path / "s", interleaved(0, 50))
    meta = (split / "metadata.yaml").read_text()
    (split / "metadata.yaml").write_text(meta.replace("  - s.db3\n",
                                                      "  - s.db3\n  - s.db3\n"))
    assert open_fast(split) is None


def test_corrupt_or_unusual_sqlite3_bags(tmp_path, capsys):
    """A database that is not one, and a non-standard Imu definition: rosbags opens them
    (and reports the corrupt one on one line, as before)."""
    bag = write_bag(tmp_path / "c", interleaved(0, 50))
    (bag / "c.db3").write_bytes(b"not a database" * 100)
    assert open_fast(bag) is None
    rc = replay.main([str(bag), "--latitude", "34", "--grade", "navigation"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "cannot read bag" in err[0]
    odd = write_bag(tmp_path / "d", interleaved(0, 50))
    db = sqlite3.connect(odd / "d.db3")
    db.execute("UPDATE message_definitions SET encoded_message_definition = "
               "replace(encoded_message_definition, 'float64[9] orientation_covariance', "
               "'float32[9] orientation_covariance')")
    db.commit()
    db.close()
    assert open_fast(odd) is None
    assert open_fast(write_bag(tmp_path / "e", interleaved(0, 50))) is not None


# ------------------------------------------------------------------------------ mcap
def test_mcap_bags_of_simulate_and_of_rosbags_writer(tmp_path):
    for comp, bag in simulated_bags(tmp_path):
        for topic in ("/imu/data_raw", "/imu_sim/truth"):
            tb, got = fast_read(bag, topic)
            assert tb.fallback_reason is None and tb.fast_messages == 4000
            assert got == rosbags_messages(bag, topic)
        bag = write_bag(tmp_path / f"w_{comp}", interleaved(0, 300), "mcap", comp)
        tb, got = fast_read(bag, "/imu")
        assert tb.fallback_reason is None and got == rosbags_messages(bag, "/imu")


def test_mcap_corrupt_summary_opens_with_rosbags(tmp_path):
    bag = write_bag(tmp_path / "m", interleaved(0, 300), "mcap", "zstd")
    f = bag / "m.mcap"
    data = bytearray(f.read_bytes())
    data[-28:-20] = (len(data) + 5).to_bytes(8, "little")      # summary offset past the end
    f.write_bytes(bytes(data))
    assert open_fast(bag) is None


# ------------------------------------------------------------------------------ definitions
JAZZY_STYLE = """# This is a message to hold data from an IMU
#
# Accelerations should be in m/s^2 (not in g's)

std_msgs/Header header # two-integer timestamp and frame

geometry_msgs/Quaternion orientation
float64[9] orientation_covariance # Row major about x, y, z axes

geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance # Row major about x, y, z axes

geometry_msgs/Vector3 linear_acceleration
float64[9] linear_acceleration_covariance # Row major x, y z
================================================================================
MSG: std_msgs/Header
# Standard metadata
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
================================================================================
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
"""


def test_definition_check():
    check_definition(IMU, "ros2msg", JAZZY_STYLE)
    check_definition(IMU, "", "")
    check_definition(IMU, "ros2msg", typestore().generate_msgdef(IMU, ros_version=2)[0])
    check_definition(QUAT, "ros2msg", typestore().generate_msgdef(QUAT, ros_version=2)[0])
    for bad in (JAZZY_STYLE.replace("uint32 nanosec", "int32 nanosec"),
                JAZZY_STYLE.replace("float64 z\n", "float64 z\nfloat64 t\n"),
                JAZZY_STYLE.replace("string frame_id", "string frame_id\nuint8 X=1"),
                JAZZY_STYLE + "=" * 80 + "\nMSG: foo/Extra\nint8 a\n"):
        with pytest.raises(Unusual):
            check_definition(IMU, "ros2msg", bad)
    with pytest.raises(Unusual, match="encoding"):
        check_definition(IMU, "ros2idl", "module sensor_msgs {};")


# ------------------------------------------------------------------------------ YAML
ROSBAG2_STYLE = """rosbag2_bagfile_information:
  version: 9
  storage_identifier: mcap
  duration:
    nanoseconds: 599990000000
  starting_time:
    nanoseconds_since_epoch: 1700000000123456789
  message_count: 120000
  topics_with_message_count:
    - topic_metadata:
        name: /imu/data_raw
        type: sensor_msgs/msg/Imu
        serialization_format: cdr
        offered_qos_profiles:
          - history: keep_last
            depth: 1000
            reliability: reliable
            durability: volatile
            deadline:
              sec: 9223372036
              nsec: 854775807
            avoid_ros_namespace_conventions: false
        type_description_hash: RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55f
      message_count: 60000
  compression_format: ""
  compression_mode: ''
  relative_file_paths:
    - rosbag2_2024_01_01-00_00_00_0.mcap
  files:
    - path: rosbag2_2024_01_01-00_00_00_0.mcap
      starting_time:
        nanoseconds_since_epoch: 1700000000123456789
  custom_data:
    note: a long value folded
      over two lines
  ros_distro: jazzy
"""


def test_block_yaml_reads_rosbag2_metadata_as_pyyaml_or_refuses():
    import yaml

    from sins_align.io.fastbag import SKIPPED_KEYS, block_yaml

    texts = [ROSBAG2_STYLE, "- a: 1\n  b:\n    c: x\n- d: []\n  e: {}\n  f: ~\n",
             "k:\n- 1\n- -2\n- 'it''s'\nm: true\n"]
    for t in texts:
        want = yaml.safe_load(t)
        if isinstance(want, dict) and "rosbag2_bagfile_information" in want:
            for k in SKIPPED_KEYS:
                want["rosbag2_bagfile_information"][k] = None
        assert block_yaml(t) == want
    for odd in ("a: 1.5\n", "a: 010\n", "a: yes\n", "a: 0x1f\n", "a: [1, 2]\n", "a: |\n  x\n",
                "a: \"x\\ny\"\n", "a: &x 1\n", "---\na: 1\n", "a: b: c\n", "a: 2024-01-01\n",
                "a: x # c\n", "a: 1\na: 2\n", "  a: 1\n", "a: b\n  c\n"):
        with pytest.raises(ValueError):
            block_yaml(odd)


# ------------------------------------------------------------------------------ bad input
def test_bad_data_in_fast_opened_bags_is_one_line_error(tmp_path, capsys):
    """Bytes zeroed inside an mcap directory bag's second chunk and a truncated Imu message
    in a sqlite3 bag: the fast reader hands over to rosbags (reading, or deserialising the
    message it refuses); the same one-line error as when rosbags opens and reads the bag,
    nothing written."""
    from sins_align.io.bagio import CliError, McapTopicReader

    bag = write_bag(tmp_path / "m", interleaved(0, 3000), "mcap", "zstd")
    f = bag / "m.mcap"
    chunks = McapTopicReader._plan(f, frozenset({1}))
    assert len(chunks) >= 2
    data = bytearray(f.read_bytes())
    at = chunks[1].offset + 80                      # inside the second chunk
    data[at:at + 64] = bytes(64)
    f.write_bytes(bytes(data))
    items = interleaved(0, 300)
    items[101] = ("/imu", items[101][1], items[101][2][:-9])        # truncated
    sq = write_bag(tmp_path / "s", items)
    cfg = AlignConfig(latitude_deg=34.0)
    for b in (bag, sq):
        assert open_fast(b) is not None
        errors = []
        for fast in (True, False):
            with pytest.raises(CliError) as e:
                replay.replay(b, cfg, progress=False, fast_mcap=fast)
            errors.append(str(e.value))
        assert errors[0] == errors[1] and str(b) in errors[0]
        js = tmp_path / f"{b.name}.json"
        rc = replay.main([str(b), "--latitude", "34", "--grade", "navigation",
                          "--summary-json", str(js)])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and err == [f"replay: error: {errors[0]}"]
        assert not js.exists()


# ------------------------------------------------------------------------------ bare files
def test_bare_mcap_files_open_as_rosbags_opens_them(tmp_path):
    """A lone .mcap (rosbags' McapReader: the channels are the connections, counted by the
    statistics record, or by the chunk indexes when there is none): the same connections,
    topics and messages; a replay of it takes the fast path with rosbags' summary."""
    from test_mcap_fast import interleaved as mcap_messages, write_mcap

    from sins_align.tools import simulate

    sim = tmp_path / "sim"
    assert simulate.main(["--latitude", "34", "--duration", "40", "--rate", "100",
                          "--compression", "zstd", str(sim)]) == 0
    no_stats = write_mcap(tmp_path / "n.mcap", [("zstd", mcap_messages(0, 300), b""),
                                                ("lz4", mcap_messages(300, 450), b"")])
    for f, topic in ((next(sim.glob("*.mcap")), "/imu/data_raw"), (no_stats, "/imu")):
        fast, r = open_fast(f), open_reader(f)
        try:
            assert fast is not None and fast.bare
            assert [(c.id, c.topic, c.msgtype, c.msgcount) for c in fast.connections] == \
                [(c.id, c.topic, c.msgtype, c.msgcount) for c in r.connections]
            assert {k: (v.msgtype, v.msgcount) for k, v in fast.topics.items()} == \
                {k: (v.msgtype, v.msgcount) for k, v in r.topics.items()}
        finally:
            fast.close()
            r.close()
        tb, got = fast_read(f, topic)
        assert tb.fallback_reason is None and got == rosbags_messages(f, topic)
    assert_replay_equals_rosbags(next(sim.glob("*.mcap")), "mcap-numpy")
