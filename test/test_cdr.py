"""Bulk Imu decoding (sins_align.io.cdr) against rosbags' own deserializer, field by field.

What is proved here:
- random ROS 2 (CDR) and ROS 1 messages, frame_ids of 0..40 UTF-8 bytes (ASCII and not),
  any float64 bit pattern (NaN, inf, -0, subnormal) and the full int32/uint32 stamp ranges
  decode bit-identically to ``deserialize_cdr`` / ``deserialize_ros1``, in one batch of
  mixed lengths, in same-length batches and message by message, all on the fast path;
- big-endian CDR, encapsulation options, trailing padding go to the deserializer (same
  values); truncated, extended, bit-flipped, NUL-less and non-UTF-8 messages either decode
  to exactly what rosbags gives or raise (never a silently different value);
- a bag's Imu layout is recognised for rosbag2 and ROS 1 bags and refused for a bag whose
  Imu definition is not the standard one;
- one message at a time (align_node's raw subscription), :class:`cdr.ImuLayout` reads the
  stamp, gyro and accel rclpy decodes, and its rewritten message (new orientation fields)
  is what rclpy decodes as that message and rclpy's own encoding of it byte for byte but
  for the padding after the frame_id (zero here, leftover buffer bytes in rclpy); anything
  it cannot rewrite in place (big-endian, options, trailing bytes, a bad string) is refused;
- the replay, which now decodes in chunks, feeds the session exactly the messages rosbags
  gives, across chunk boundaries, with a truth topic interleaved, frame_ids changing and
  big-endian messages mixed in; a corrupt Imu message is a one-line error naming its time.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from sins_align.io import cdr
from sins_align.io.bagio import finite_or_none

from sins_align.tools import replay
from sins_align.io.cdr import (CDR_BE, CDR_LE, ImuDecodeError, ImuLayout, decode_imu_batch,
                            imu_nbytes, reader_imu_layout)

IMU = "sensor_msgs/msg/Imu"
FRAME_IDS = ["", "a", "ab", "abc", "imu", "imu_link", "base_link/imu0", "x" * 11, "y" * 12,
             "z" * 19, "w" * 20, "é", "重力", "imu_Ω_link", "🛰", "frame_ünïcödé_" * 2,
             "n" * 40]


@pytest.fixture(scope="module")
def ts2():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


@pytest.fixture(scope="module")
def ts1():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS1_NOETIC)


def random_floats(rng, n):
    """float64 with any bit pattern: normal, huge, tiny, subnormal, +-0, +-inf, NaNs."""
    x = rng.normal(size=n) * 10.0 ** rng.integers(-300, 300, size=n)
    bits = rng.integers(0, 2**63, size=n, dtype=np.uint64) * np.uint64(2) + \
        rng.integers(0, 2, size=n, dtype=np.uint64)
    special = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 5e-324, -2.2250738585072014e-308,
                        1.7976931348623157e308])
    kind = rng.integers(0, 3, size=n)
    x = np.where(kind == 1, bits.view(np.float64), x)
    return np.where(kind == 2, special[rng.integers(0, len(special), size=n)], x)


def random_imus(ts, rng, n, ros1=False, frame_ids=FRAME_IDS):
    T = ts.types
    out = []
    for k in range(n):
        f = random_floats(rng, 37)
        hk = dict(stamp=T["builtin_interfaces/msg/Time"](
            sec=int(rng.integers(-2**31, 2**31)), nanosec=int(rng.integers(0, 2**32))),
            frame_id=frame_ids[int(rng.integers(len(frame_ids)))])
        if ros1:
            hk["seq"] = int(rng.integers(0, 2**32))
        V = T["geometry_msgs/msg/Vector3"]
        out.append(T[IMU](
            header=T["std_msgs/msg/Header"](**hk),
            orientation=T["geometry_msgs/msg/Quaternion"](*map(float, f[0:4])),
            orientation_covariance=f[4:13].copy(),
            angular_velocity=V(*map(float, f[13:16])),
            angular_velocity_covariance=f[16:25].copy(),
            linear_acceleration=V(*map(float, f[25:28])),
            linear_acceleration_covariance=f[28:37].copy()))
    return out


def as_row(msg) -> tuple:
    """Every field of an Imu message (floats as bit patterns, so NaNs compare)."""
    q, w, a = msg.orientation, msg.angular_velocity, msg.linear_acceleration
    f = np.concatenate([[q.x, q.y, q.z, q.w], msg.orientation_covariance, [w.x, w.y, w.z],
                        msg.angular_velocity_covariance, [a.x, a.y, a.z],
                        msg.linear_acceleration_covariance]).astype(np.float64)
    h = msg.header
    return (h.stamp.sec, h.stamp.nanosec, h.frame_id, getattr(h, "seq", None),
            tuple(f.view(np.uint64).tolist()))


def batch_rows(b) -> list[tuple]:
    bits = b.floats.view(np.uint64)
    seq = b.seq.tolist() if b.seq is not None else [None] * len(b)
    return [(int(b.sec[i]), int(b.nanosec[i]), b.frame_id[i], seq[i], tuple(bits[i].tolist()))
            for i in range(len(b))]


def assert_batch_equals(b, ref_msgs):
    assert len(b) == len(ref_msgs)
    assert batch_rows(b) == [as_row(m) for m in ref_msgs]
    # the named views and the message objects carry the same values
    assert b.gyro.shape == b.accel.shape == (len(b), 3) and b.orientation.shape == (len(b), 4)
    for name in ("orientation_covariance", "angular_velocity_covariance",
                 "linear_acceleration_covariance"):
        assert getattr(b, name).shape == (len(b), 9)
    assert b.sec.dtype == b.nanosec.dtype == np.int64
    assert [as_row(m) for m in b.messages()] == [as_row(m) for m in ref_msgs]
    for i, m in enumerate(ref_msgs):
        w, a = m.angular_velocity, m.linear_acceleration
        np.testing.assert_array_equal(b.gyro[i], [w.x, w.y, w.z])
        np.testing.assert_array_equal(b.accel[i], [a.x, a.y, a.z])


def decode_ref(ts, raws, ros1=False):
    return [ts.deserialize_ros1(r, IMU) if ros1 else ts.deserialize_cdr(r, IMU) for r in raws]


# ------------------------------------------------------------------------------ ROS 2
def test_random_ros2_messages_decode_exactly_as_rosbags(ts2):
    rng = np.random.default_rng(1)
    msgs = random_imus(ts2, rng, 3000)
    raws = [ts2.serialize_cdr(m, IMU, little_endian=True) for m in msgs]
    assert all(bytes(r[:4]) == CDR_LE for r in raws)
    assert {len(r) for r in raws} == {imu_nbytes(len(f.encode())) for f in FRAME_IDS}
    ref = decode_ref(ts2, raws)
    assert [as_row(m) for m in ref] == [as_row(m) for m in msgs]   # rosbags round trip

    b = decode_imu_batch(raws)                       # mixed lengths: grouped
    assert b.fallback == {}
    assert_batch_equals(b, ref)
    b = decode_imu_batch([bytes(r) for r in raws])   # bytes as well as memoryviews
    assert b.fallback == {} and batch_rows(b) == batch_rows(decode_imu_batch(raws))
    for k in (0, 1, 7, 2999):                        # one at a time
        assert batch_rows(decode_imu_batch(raws[k:k + 1])) == [as_row(ref[k])]
    assert len(decode_imu_batch([])) == 0


def test_same_length_batches_with_different_frame_ids(ts2):
    """One length, several string lengths (1..4 bytes + NUL pad to the same size) and ids."""
    rng = np.random.default_rng(2)
    ids = ["", "a", "b", "ab", "xyz", "é", "abc"]           # L = 1..4: all 4 + 16 + 296 bytes
    msgs = random_imus(ts2, rng, 500, frame_ids=ids)
    raws = [ts2.serialize_cdr(m, IMU) for m in msgs]
    assert {len(r) for r in raws} == {316}
    b = decode_imu_batch(raws)
    assert b.fallback == {}
    assert_batch_equals(b, decode_ref(ts2, raws))
    same = random_imus(ts2, rng, 300, frame_ids=["imu_link"])
    b = decode_imu_batch([ts2.serialize_cdr(m, IMU) for m in same])
    assert b.frame_id == ["imu_link"] * 300 and b.fallback == {}


def test_big_endian_options_and_trailing_padding_fall_back_with_the_same_values(ts2):
    rng = np.random.default_rng(3)
    msgs = random_imus(ts2, rng, 60)
    le = [bytes(ts2.serialize_cdr(m, IMU, little_endian=True)) for m in msgs]
    be = [bytes(ts2.serialize_cdr(m, IMU, little_endian=False)) for m in msgs]
    assert all(r[:4] == CDR_BE for r in be)
    opts = [r[:2] + b"\x00\x03" + r[4:] for r in le]       # encapsulation options set
    trail = [r + b"\x00" * (1 + k % 3) for k, r in enumerate(le)]   # rosbags accepts <= 3
    mixed = [x for group in zip(le, be, opts, trail) for x in group]
    b = decode_imu_batch(mixed)
    assert sorted(b.fallback) == [k for k in range(len(mixed)) if k % 4]
    assert_batch_equals(b, decode_ref(ts2, mixed))
    assert [as_row(m) for m in decode_ref(ts2, be)] == [as_row(m) for m in msgs]


def check_same_or_raises(ts, raws, ros1=False):
    """Decode each message alone and in a batch: rosbags' values or ImuDecodeError."""
    layout = "ros1" if ros1 else "ros2"
    outcomes = []
    for k, raw in enumerate(raws):
        try:
            ref = (ts.deserialize_ros1 if ros1 else ts.deserialize_cdr)(raw, IMU)
        except Exception:   # noqa: BLE001 - any rosbags error means "must raise"
            ref = None
        if ref is None:
            with pytest.raises(ImuDecodeError) as ei:
                decode_imu_batch([raw], layout)
            assert ei.value.index == 0
        else:
            assert batch_rows(decode_imu_batch([raw], layout)) == [as_row(ref)], k
        outcomes.append(ref is not None)
    return outcomes


def test_corrupt_ros2_messages_decode_as_rosbags_or_raise(ts2):
    rng = np.random.default_rng(4)
    msgs = random_imus(ts2, rng, 40)
    good = [bytes(ts2.serialize_cdr(m, IMU)) for m in msgs]
    bad = []
    for k, r in enumerate(good):
        L = int.from_bytes(r[12:16], "little")
        bad += [r[:-1], r[:-8], r[:len(r) // 2], r[:3], b"", r + b"\x00" * 8,
                r[:15 + L] + b"x" + r[16 + L:],                         # NUL replaced
                r[:12] + (L + 8).to_bytes(4, "little") + r[16:],        # length too long
                r[:12] + (L + 1).to_bytes(4, "little") + r[16:],        # within the padding
                r[:12] + (0).to_bytes(4, "little") + r[16:],            # no terminator room
                r[:12] + (2**32 - 1).to_bytes(4, "little") + r[16:],
                b"\x01\x01" + r[2:], b"\x00\x02" + r[2:]]               # not CDR
        if L > 1:
            bad.append(r[:16] + b"\xff" + r[17:])                       # not UTF-8
            bad.append(r[:16] + b"\xc3" + r[17:])
        for _ in range(6):                                              # random bit flips
            x = bytearray(r)
            pos = int(rng.integers(0, min(len(r), 24 + L)))
            x[pos] ^= 1 << int(rng.integers(8))
            bad.append(bytes(x))
    ok = check_same_or_raises(ts2, bad)
    assert 0 < sum(ok) < len(ok)            # both outcomes occur
    # in a batch of good messages, a corrupt one is named by its index
    for k in (0, 17, 39):
        raws = list(good)
        raws[k] = good[k][:-1]
        with pytest.raises(ImuDecodeError, match=f"message {k} of the batch") as ei:
            decode_imu_batch(raws)
        assert ei.value.index == k and ei.value.__cause__ is not None
    # a caller's fallback sees the message and its index; its exceptions propagate as they are
    seen = []

    def fb(raw, i):
        seen.append(i)
        raise KeyError("mine")

    raws = list(good)
    raws[5] = good[5][:-1]
    with pytest.raises(KeyError, match="mine"):
        decode_imu_batch(raws, fallback=fb)
    assert seen == [5]


def test_nul_and_utf8_are_checked_per_message_in_a_batch(ts2):
    """Same-length batch where one message differs only in the string bytes."""
    rng = np.random.default_rng(5)
    raws = [bytes(ts2.serialize_cdr(m, IMU)) for m in random_imus(ts2, rng, 50,
                                                                   frame_ids=["imu_link"])]
    r = list(raws)
    r[3] = r[3][:16] + b"imu_lin\xff" + r[3][24:]          # not UTF-8
    with pytest.raises(ImuDecodeError, match="message 3 of the batch"):
        decode_imu_batch(r)
    r = list(raws)
    r[7] = r[7][:24] + b"y" + r[7][25:]                 # NUL of "imu_link" at 16 + 9 - 1
    with pytest.raises(ImuDecodeError, match="message 7 of the batch"):
        decode_imu_batch(r)
    r = list(raws)
    r[9] = r[9][:16] + "imu_línk".encode()[:8] + r[9][24:]   # other valid bytes: decoded
    b = decode_imu_batch(r)
    assert b.fallback == {} and b.frame_id[9] == ts2.deserialize_cdr(r[9], IMU).header.frame_id
    assert b.frame_id[8] == "imu_link"


# ------------------------------------------------------------------------------ ROS 1
def test_random_ros1_messages_decode_exactly_as_rosbags(ts1):
    rng = np.random.default_rng(6)
    msgs = random_imus(ts1, rng, 2000, ros1=True)
    raws = [ts1.serialize_ros1(m, IMU) for m in msgs]
    assert {len(r) for r in raws} == {imu_nbytes(len(f.encode()), "ros1") for f in FRAME_IDS}
    ref = decode_ref(ts1, raws, ros1=True)
    b = decode_imu_batch(raws, "ros1")
    assert b.fallback == {}
    assert_batch_equals(b, ref)
    assert b.seq.tolist() == [m.header.seq for m in msgs]


def test_corrupt_ros1_messages_decode_as_rosbags_or_raise(ts1):
    rng = np.random.default_rng(7)
    good = [bytes(ts1.serialize_ros1(m, IMU)) for m in random_imus(ts1, rng, 30, ros1=True)]
    bad, cut = [], []
    for r in good:
        L = int.from_bytes(r[12:16], "little")
        cut += [len(bad), len(bad) + 1, len(bad) + 2, len(bad) + 3]
        bad += [r[:-1], r[:-8], r + b"\x00", r[:10], r[:12] + (L + 1).to_bytes(4, "little")
                + r[16:], r[:12] + (max(L - 1, 0)).to_bytes(4, "little") + r[16:]]
        if L:
            bad.append(r[:16] + b"\xff" + r[17:])
    ok = check_same_or_raises(ts1, bad, ros1=True)
    assert not any(ok[k] for k in cut)          # truncated or extended: always an error


def test_unknown_layout_is_refused():
    with pytest.raises(ValueError, match="unknown layout"):
        decode_imu_batch([], "ros3")
    with pytest.raises(ValueError, match="unknown layout"):
        imu_nbytes(3, "xml")


# ------------------------------------------------------------------------------ one message
def bits(values) -> tuple:
    return tuple(np.asarray(values, np.float64).view(np.uint64).tolist())


def with_orientation(ts, msg, values):
    """A rosbags Imu with orientation and its covariance set from 13 values."""
    from dataclasses import replace

    return replace(msg, orientation=ts.types["geometry_msgs/msg/Quaternion"](
        *map(float, values[:4])), orientation_covariance=np.array(values[4:], np.float64))


def test_imu_layout_reads_and_rewrites_as_rclpy_decodes_and_encodes(ts2):
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Imu

    rng = np.random.default_rng(10)
    for m in random_imus(ts2, rng, 1000):
        raw = bytes(ts2.serialize_cdr(m, IMU))
        layout = ImuLayout.of(raw)
        assert layout is not None and layout.matches(raw)
        ref = deserialize_message(raw, Imu)                 # the message path
        assert layout.frame_id == ref.header.frame_id == m.header.frame_id
        sec, nanosec, w, a = layout.read(raw)
        assert (sec, nanosec) == (ref.header.stamp.sec, ref.header.stamp.nanosec)
        g, f = ref.angular_velocity, ref.linear_acceleration
        assert bits(w) == bits([g.x, g.y, g.z]) and bits(a) == bits([f.x, f.y, f.z])

        values = random_floats(rng, 13)
        out = layout.with_orientation(raw, values)
        q = ref.orientation
        q.x, q.y, q.z, q.w = map(float, values[:4])
        ref.orientation_covariance = values[4:]
        assert as_row(deserialize_message(out, Imu)) == as_row(ref)
        # rclpy's bytes for the same message, but for the padding after the frame_id
        enc = serialize_message(ref)
        pad = slice(16 + len(layout.frame_id.encode()) + 1, layout.floats)
        assert len(out) == len(enc) == len(raw) and out[pad] == bytes(len(out[pad]))
        assert out[:pad.start] == enc[:pad.start] and out[pad.stop:] == enc[pad.stop:]
        # rosbags zero-pads: its encoding is the same bytes
        assert out == bytes(ts2.serialize_cdr(with_orientation(ts2, m, values), IMU))


def test_imu_layout_ignores_padding_and_refuses_what_it_cannot_rewrite(ts2):
    rng = np.random.default_rng(11)
    m = random_imus(ts2, rng, 1, frame_ids=["imu_link"])[0]
    raw = bytes(ts2.serialize_cdr(m, IMU))
    layout = ImuLayout.of(raw)
    assert layout.size == len(raw) == imu_nbytes(8) and layout.floats == 28
    # leftover bytes in the padding (as rclpy leaves them) are not content
    junk = raw[:25] + b"\xaa" * 3 + raw[28:]
    assert ImuLayout.of(junk).frame_id == "imu_link" and layout.matches(junk)
    assert layout.read(junk) == layout.read(raw)
    values = np.arange(13.0)
    assert layout.with_orientation(junk, values) == layout.with_orientation(raw, values)

    L = 9
    refused = {
        "big-endian": bytes(ts2.serialize_cdr(m, IMU, little_endian=False)),
        "options": raw[:2] + b"\x00\x03" + raw[4:],
        "trailing bytes": raw + b"\x00" * 8,
        "truncated": raw[:-1],
        "empty": b"",
        "encapsulation only": raw[:4],
        "NUL replaced": raw[:15 + L] + b"x" + raw[16 + L:],
        "length in the padding": raw[:12] + (L + 1).to_bytes(4, "little") + raw[16:],
        "length zero": raw[:12] + (0).to_bytes(4, "little") + raw[16:],
        "length huge": raw[:12] + (2**32 - 1).to_bytes(4, "little") + raw[16:],
        "not UTF-8": raw[:16] + b"\xff" + raw[17:],
        "NUL inside": raw[:17] + b"\x00" + raw[18:],      # rclpy would cut the frame_id
    }
    for what, bad in refused.items():
        assert ImuLayout.of(bad) is None, what
        assert not layout.matches(bad), what
    assert not layout.matches(raw[:16] + b"imu_lenk" + raw[24:])   # same size, other name
    assert ImuLayout("imu_lin").size == layout.size and not ImuLayout("imu_lin").matches(raw)
    with pytest.raises(ValueError, match="NUL"):
        ImuLayout("a\0b")
    with pytest.raises(ValueError, match="13 values"):
        layout.with_orientation(raw, np.zeros(12))


# ------------------------------------------------------------------------------ bags
def write_bag(path, items, typestore=None, truth=None):
    """rosbag2 (mcap) with /imu raw messages [(ns, raw)] and optional truth [(ns, raw)]."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from sins_align.io.bagio import typestore as jazzy

    w = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    w.open()
    c = w.add_connection("/imu", IMU, typestore=typestore or jazzy())
    ct = None
    if truth is not None:
        ct = w.add_connection("/truth", "geometry_msgs/msg/QuaternionStamped", typestore=jazzy())
    seq = sorted([(ns, 0, raw) for ns, raw in items] + [(ns, 1, raw) for ns, raw in truth or []],
                 key=lambda x: (x[0], x[1]))
    for ns, which, raw in seq:
        w.write(ct if which else c, ns, raw)
    w.close()


def test_reader_layout_ros2_ros1_and_custom_definition(tmp_path, ts2, ts1):
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    rng = np.random.default_rng(8)
    m2 = random_imus(ts2, rng, 3)
    write_bag(tmp_path / "b2", [(k, ts2.serialize_cdr(m, IMU)) for k, m in enumerate(m2)])
    with AnyReader([tmp_path / "b2"]) as r:
        assert reader_imu_layout(r) == "ros2"
    with Writer1(tmp_path / "b1.bag") as w:
        c = w.add_connection("/imu", IMU, typestore=ts1)
        for k, m in enumerate(random_imus(ts1, rng, 3, ros1=True)):
            w.write(c, k + 1, ts1.serialize_ros1(m, IMU))
    with AnyReader([tmp_path / "b1.bag"]) as r:
        assert reader_imu_layout(r) == "ros1"
        got = [r.deserialize(raw, IMU) for _, _, raw in r.messages()]
        raws = [raw for _, _, raw in r.messages()]
    assert batch_rows(decode_imu_batch(raws, "ros1")) == [as_row(m) for m in got]

    custom = get_typestore(Stores.EMPTY)
    custom.register(get_types_from_msg(
        "std_msgs/Header header\nfloat32[3] angular_velocity\n", IMU))
    custom.register({k: v for k, v in ts2.fielddefs.items()
                     if k in ("std_msgs/msg/Header", "builtin_interfaces/msg/Time")})
    Msg = custom.types[IMU]
    raw = custom.serialize_cdr(Msg(header=ts2.types["std_msgs/msg/Header"](
        stamp=ts2.types["builtin_interfaces/msg/Time"](sec=1, nanosec=2), frame_id="f"),
        angular_velocity=np.zeros(3, np.float32)), IMU)
    write_bag(tmp_path / "custom", [(1, raw)], typestore=custom)
    with AnyReader([tmp_path / "custom"]) as r:
        assert reader_imu_layout(r) is None
    assert reader_imu_layout(object()) is None


def strip(s):
    """A replay() summary without what ReplaySession.summary does not hold."""
    return {k: v for k, v in s.items()
            if k not in ("wall_time_s", "messages_per_s", "bag", "topic", "truth_topic")}


def test_replay_feeds_the_session_what_rosbags_gives(tmp_path, ts2, monkeypatch):
    """Bulk-decoded chunks == per-message rosbags, across chunks, truth, frame ids, endianness."""
    from rosbags.highlevel import AnyReader

    from sins_align.estimators.quasi_static.aligner import AlignConfig
    from sins_align.sim.simulator import simulate as sim_simulate

    monkeypatch.setattr(replay, "READ_CHUNK", 500)
    sim = sim_simulate(25.0, rate=100.0, lat_deg=34.0, rpy_deg=(1.0, -2.0, 30.0), seed=4,
                       specs="navigation")
    T = ts2.types
    V = T["geometry_msgs/msg/Vector3"]
    items, truth = [], []
    for k in range(len(sim.t)):
        ns = 1_700_000_000 * 10**9 + k * 10_000_000
        sec, nsec = divmod(ns, 10**9)
        hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=nsec), frame_id=("imu_link" if k < 1200 else "imu_linké_2"))
        m = T[IMU](header=hdr, orientation=T["geometry_msgs/msg/Quaternion"](0., 0., 0., 1.),
                   orientation_covariance=np.full(9, -1.0),
                   angular_velocity=V(*map(float, sim.gyro[k])),
                   angular_velocity_covariance=np.eye(3).ravel() * 1e-12,
                   linear_acceleration=V(*map(float, sim.accel[k])),
                   linear_acceleration_covariance=np.eye(3).ravel() * 1e-8)
        items.append((ns, ts2.serialize_cdr(m, IMU, little_endian=k % 97 != 5)))
        if k % 3 == 0:
            q = T["geometry_msgs/msg/QuaternionStamped"](header=hdr, quaternion=T[
                "geometry_msgs/msg/Quaternion"](*map(float, sim.quat_true[k])))
            truth.append((ns, ts2.serialize_cdr(q, q.__msgtype__)))
    bag = tmp_path / "bag"
    write_bag(bag, items, truth=truth)
    config = AlignConfig(latitude_deg=34.0)
    s, _ = replay.replay(bag, config, truth_topic="/truth", csv_path=tmp_path / "a.csv",
                         output=tmp_path / "out", progress=False)

    with open(tmp_path / "b.csv", "w", newline="", encoding="utf-8") as f, \
            AnyReader([bag]) as r:
        w = replay.open_writer(tmp_path / "ref_out", "mcap", "zstd")
        ref = replay.ReplaySession(config, writer=w, csv_file=f, with_truth=True)
        for c, _, raw in r.messages():
            m = r.deserialize(raw, c.msgtype)
            (ref.on_imu if c.msgtype == IMU else ref.on_truth)(m)
        ref.finish()
        w.close()
    s_ref = finite_or_none(ref.summary(replay.config_echo(config, {})))
    assert s["samples"] == len(items) == 2500 and s["truth"]["samples"] == len(truth)
    assert json.dumps(strip(s), sort_keys=True) == json.dumps(s_ref, sort_keys=True)
    assert s["final"]["frame_id"] == "imu_linké_2"
    assert (tmp_path / "a.csv").read_text() == (tmp_path / "b.csv").read_text()
    # the published bags hold the same messages, byte for byte
    with AnyReader([tmp_path / "out"]) as a, AnyReader([tmp_path / "ref_out"]) as b:
        got = [(c.topic, ns, bytes(raw)) for c, ns, raw in a.messages()]
        want = [(c.topic, ns, bytes(raw)) for c, ns, raw in b.messages()]
    assert len(got) > 2500 and got == want


def test_replay_names_a_corrupt_imu_message(tmp_path, ts2, capsys):
    rng = np.random.default_rng(9)
    msgs = random_imus(ts2, rng, 20, frame_ids=["imu"])
    items = [(k * 10_000_000 + 1, bytes(ts2.serialize_cdr(m, IMU))) for k, m in enumerate(msgs)]
    ns, raw = items[13]
    items[13] = (ns, raw[:-1])
    write_bag(tmp_path / "bag", items)
    rc = replay.main([str(tmp_path / "bag"), "--latitude", "34", "--grade", "navigation"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert err[0].startswith(f"replay: error: cannot decode a {IMU} message at {ns} ns"), err


def test_module_constants():
    assert imu_nbytes(0) == 4 + 16 + 296 and imu_nbytes(4) == 4 + 24 + 296
    assert imu_nbytes(8) == 4 + 24 + 296 and imu_nbytes(0, "ros1") == 16 + 296
    assert cdr.N_FLOATS * 8 == cdr.FLOATS_NBYTES == 296
