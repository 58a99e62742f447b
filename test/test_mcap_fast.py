"""The numpy MCAP reader (sins_align.io.bagio.TopicBlocks / McapTopicReader) against rosbags.

Every case is checked the same way: the (log time, bytes) sequence of the topic read through
``TopicBlocks`` equals rosbags' ``reader.messages(connections)`` exactly. The files are
written here byte by byte (a small MCAP writer), so chunk compression (zstd, lz4, none),
chunk boundaries, interleaved channels, unsorted chunks, records inside chunks, overlapping
chunks, missing indexes and corrupt chunks can all be produced. What the fast path must
read itself is asserted (``fast_messages``); what is unusual must go to rosbags, whole or
from the chunk concerned on, with the same result.
"""
from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from sins_align.tools import replay
from sins_align.io.bagio import CliError, McapTopicReader, MessageBlock, TopicBlocks, open_reader, \
    read_messages, typestore
from sins_align.io.cdr import decode_imu_array, decode_imu_batch

from cli_helpers import simulated_bags

IMU = "sensor_msgs/msg/Imu"
QUAT = "geometry_msgs/msg/QuaternionStamped"
MAGIC = b"\x89MCAP0\r\n"


# ------------------------------------------------------------------------------ a writer
def _rec(op: int, body: bytes) -> bytes:
    return bytes([op]) + struct.pack("<Q", len(body)) + body


def _s(text: str) -> bytes:
    b = text.encode()
    return struct.pack("<I", len(b)) + b


def _schema(sid: int, name: str) -> bytes:
    data = typestore().generate_msgdef(name, ros_version=2)[0].encode()
    return _rec(0x03, struct.pack("<H", sid) + _s(name) + _s("ros2msg")
                + struct.pack("<I", len(data)) + data)


def _channel(cid: int, sid: int, topic: str) -> bytes:
    return _rec(0x04, struct.pack("<HH", cid, sid) + _s(topic) + _s("cdr")
                + struct.pack("<I", 0))


def _message(cid: int, log: int, data: bytes) -> bytes:
    return _rec(0x05, struct.pack("<HIQQ", cid, 0, log, log) + data)


def _compress(raw: bytes, how: str) -> bytes:
    if how == "zstd":
        try:
            from compression import zstd
        except ImportError:
            from backports import zstd
        return zstd.compress(raw)
    if how == "lz4":
        from lz4.frame import compress
        return compress(raw)
    return raw


def write_mcap(path: Path, chunks, topics=(("/imu", IMU), ("/truth", QUAT)), *,
               summary=True, crc=True, time_range=None, unindexed=(), break_crc=()):
    """An MCAP file (ros2 profile) with channels 1.. = ``topics`` and the given chunks.

    ``chunks``: list of (compression, [(channel, log ns, data)], prefix records) where
    prefix records (bytes) are put at the start of the chunk. ``unindexed``: (chunk, k)
    messages left out of the message index; ``break_crc``: chunks with a wrong CRC;
    ``time_range``: {chunk: (start, end)} declared instead of the real range.
    """
    out = bytearray(MAGIC)
    out += _rec(0x01, _s("ros2") + _s("test"))
    schemas = b""
    channels = b""
    for i, (topic, msgtype) in enumerate(topics, 1):
        schemas += _schema(i, msgtype)
        channels += _channel(i, i, topic)
    out += schemas + channels
    index = b""
    for ci, (how, msgs, prefix) in enumerate(chunks):
        body = bytearray(prefix)
        entries: dict[int, list[tuple[int, int]]] = {}
        for k, (cid, log, data) in enumerate(msgs):
            if (ci, k) not in unindexed:
                entries.setdefault(cid, []).append((log, len(body)))
            body += _message(cid, log, data)
        raw = bytes(body)
        logs = [log for _, log, _ in msgs]
        start, end = (time_range or {}).get(ci, (min(logs), max(logs)))
        c = zlib.crc32(raw) if crc else 0
        if ci in break_crc:
            c ^= 1
        comp = _compress(raw, how)
        chunk_start = len(out)
        out += _rec(0x06, struct.pack("<QQQI", start, end, len(raw), c) + _s(how)
                    + struct.pack("<Q", len(comp)) + comp)
        chunk_len = len(out) - chunk_start
        offsets = []
        for cid, ent in entries.items():
            offsets.append((cid, len(out)))
            out += _rec(0x07, struct.pack("<HI", cid, 16 * len(ent))
                        + b"".join(struct.pack("<QQ", a, b) for a, b in ent))
        index += _rec(0x08, struct.pack("<QQQQ", start, end, chunk_start, chunk_len)
                      + struct.pack("<I", 10 * len(offsets))
                      + b"".join(struct.pack("<HQ", c_, o) for c_, o in offsets)
                      + struct.pack("<Q", len(out) - chunk_start - chunk_len) + _s(how)
                      + struct.pack("<QQ", len(comp), len(raw)))
    out += _rec(0x0F, struct.pack("<I", 0))
    summary_start = len(out) if summary else 0
    if summary:
        out += schemas + channels + index
    out += _rec(0x02, struct.pack("<QQI", summary_start, 0, 0)) + MAGIC
    path.write_bytes(bytes(out))
    return path


# ------------------------------------------------------------------------------ messages
def imu_raw(k: int, frame: str = "imu_link") -> bytes:
    T = typestore().types
    V = T["geometry_msgs/msg/Vector3"]
    hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
        sec=k // 100, nanosec=(k % 100) * 10_000_000), frame_id=frame)
    m = T[IMU](header=hdr, orientation=T["geometry_msgs/msg/Quaternion"](0., 0., 0., 1.),
               orientation_covariance=np.full(9, -1.0),
               angular_velocity=V(1e-5 * k, -2e-5, 3e-5),
               angular_velocity_covariance=np.eye(3).ravel() * 1e-12,
               linear_acceleration=V(0.01, -0.02, 9.79 + 1e-6 * k),
               linear_acceleration_covariance=np.eye(3).ravel() * 1e-8)
    return bytes(typestore().serialize_cdr(m, IMU))


def truth_raw(k: int) -> bytes:
    T = typestore().types
    q = T[QUAT](header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
        sec=k // 100, nanosec=0), frame_id="imu_link"),
        quaternion=T["geometry_msgs/msg/Quaternion"](0., 0., 0., 1.))
    return bytes(typestore().serialize_cdr(q, QUAT))


def interleaved(k0: int, k1: int, frame=lambda k: "imu_link"):
    """Imu (channel 1) and truth (channel 2) messages alternating, 10 ms apart."""
    out = []
    for k in range(k0, k1):
        out.append((1, 10_000_000 * k + 1, imu_raw(k, frame(k))))
        out.append((2, 10_000_000 * k + 1, truth_raw(k)))
    return out


def compare(path: Path, topic: str = "/imu", block_size: int = 4096):
    """Read ``topic`` with TopicBlocks and with rosbags; assert equality; the TopicBlocks."""
    r = open_reader(path)
    try:
        conns = [c for c in r.connections if c.topic == topic]
        want = [(ns, bytes(raw)) for _, ns, raw in read_messages(r, conns, path)]
        tb = TopicBlocks(r, conns, path, block_size)
        got = []
        for b in tb:
            assert isinstance(b, MessageBlock) and b.log_ns.dtype == np.int64
            got += [(int(b.log_ns[i]), b.raw(i)) for i in range(len(b))]
    finally:
        r.close()
    assert len(got) == len(want)
    assert got == want
    return tb


# ------------------------------------------------------------------------------ fast path
def test_zstd_lz4_and_plain_chunks_with_interleaved_channels(tmp_path):
    """Chunk compressions mixed; truth (another size) between Imu messages; a frame_id change
    (another Imu size) inside a chunk; chunks touching in time; schema and channel records
    at the start of the first chunk (as rosbags writes them)."""
    prefix = _schema(1, IMU) + _channel(1, 1, "/imu")
    chunks = [("zstd", interleaved(0, 300), prefix),
              ("lz4", interleaved(300, 700, lambda k: "imu" if k < 500 else "imu_long_frame"), b""),
              ("", interleaved(700, 900), b"")]
    # chunk 2 starts at the log time chunk 1 ends with (a truth message there)
    chunks[1][1].append((2, 10_000_000 * 700 + 1, truth_raw(700)))
    p = write_mcap(tmp_path / "a.mcap", chunks)
    tb = compare(p)
    assert tb.fallback_reason is None and tb.fast_messages == 900
    tb = compare(p, "/truth")
    assert tb.fallback_reason is None and tb.fast_messages == 901
    # a truth message missing from its index lies between indexed records: walked, not Imu
    p = write_mcap(tmp_path / "a2.mcap", chunks, unindexed={(1, 101)})
    tb = compare(p)
    assert tb.fallback_reason is None and tb.fast_messages == 900


def test_unsorted_chunk_is_sorted_stably_and_imu_only_chunks(tmp_path):
    """rosbags sorts a chunk's messages by log time, keeping the record order of equal
    times; a chunk of one channel only (one record size: a strided view)."""
    msgs = [(1, 10_000_000 * k, imu_raw(k)) for k in range(400)]
    rng = np.random.default_rng(1)
    shuffled = [msgs[i] for i in rng.permutation(400)]
    ties = [(1, 5, imu_raw(k)) for k in range(1000, 1010)]      # equal log times
    p = write_mcap(tmp_path / "b.mcap", [("zstd", shuffled, b""),
                                         ("", [(1, 4_000_000_000 + m[1], m[2]) for m in ties]
                                          + [(1, 4_000_000_000, imu_raw(7))], b"")],
                   topics=(("/imu", IMU),), crc=False)
    tb = compare(p, block_size=7)
    assert tb.fallback_reason is None and tb.fast_messages == 411


def test_directory_bag_with_two_files(tmp_path):
    d = tmp_path / "bag"
    d.mkdir()
    write_mcap(d / "bag_0.mcap", [("zstd", interleaved(0, 200), b"")])
    write_mcap(d / "bag_1.mcap", [("lz4", interleaved(200, 300), b""),
                                  ("zstd", interleaved(300, 450), b"")])
    topics = "".join(f"""
  - message_count: {n}
    topic_metadata:
      name: {t}
      offered_qos_profiles: []
      serialization_format: cdr
      type: {ty}
      type_description_hash: ''""" for t, ty, n in (("/imu", IMU, 450), ("/truth", QUAT, 450)))
    (d / "metadata.yaml").write_text(f"""rosbag2_bagfile_information:
  compression_format: ''
  compression_mode: ''
  custom_data: {{}}
  duration:
    nanoseconds: 4500000000
  files: []
  message_count: 900
  relative_file_paths:
  - bag_0.mcap
  - bag_1.mcap
  ros_distro: rosbags
  starting_time:
    nanoseconds_since_epoch: 1
  storage_identifier: mcap
  topics_with_message_count:{topics}
  version: 9
""")
    tb = compare(d)
    assert tb.fallback_reason is None and tb.fast_messages == 450


def test_bags_written_by_rosbags_and_simulate(tmp_path):
    for comp, bag in simulated_bags(tmp_path):
        for topic in ("/imu/data_raw", "/imu_sim/truth"):
            tb = compare(bag, topic)
            assert tb.fallback_reason is None and tb.fast_messages == 4000
        tb = compare(next(bag.glob("*.mcap")), "/imu/data_raw")      # the .mcap file alone
        assert tb.fallback_reason is None and tb.fast_messages == 4000


# ------------------------------------------------------------------------------ fallbacks
@pytest.mark.parametrize("case", ["overlap", "no summary", "unindexed", "outside range",
                                  "disabled"])
def test_unusual_files_go_to_rosbags_with_the_same_result(tmp_path, case):
    chunks = [("zstd", interleaved(0, 300), b""), ("lz4", interleaved(300, 600), b""),
              ("", interleaved(600, 800), b"")]
    kw = {}
    if case == "overlap":                 # chunk 1 reaches into chunk 2's time
        chunks[1][1].append((1, 10_000_000 * 650, imu_raw(650)))
    elif case == "no summary":
        kw["summary"] = False
    elif case == "unindexed":            # an Imu message missing from chunk 1's index
        kw["unindexed"] = {(1, 100)}
    elif case == "outside range":        # rosbags drops a message outside its chunk's range
        kw["time_range"] = {1: (10_000_000 * 300 + 1, 10_000_000 * 590 + 1)}
    p = write_mcap(tmp_path / "c.mcap", chunks, **kw)
    r = open_reader(p)
    try:
        conns = [c for c in r.connections if c.topic == "/imu"]
        tb = TopicBlocks(r, conns, p, 128, fast=case != "disabled")
        got = [(int(b.log_ns[i]), b.raw(i)) for b in tb for i in range(len(b))]
        want = [(ns, bytes(raw)) for _, ns, raw in read_messages(r, conns, p)]
    finally:
        r.close()
    assert got == want and tb.fallback_reason
    # mid-bag problems: the chunk before was read fast, the rest by rosbags
    assert tb.fast_messages == (300 if case in ("unindexed", "outside range") else 0)


def test_corrupt_chunk_is_rosbags_error(tmp_path, capsys):
    """A CRC mismatch in the second chunk: the fast path hands over, rosbags raises, replay
    reports it on one line."""
    p = write_mcap(tmp_path / "d.mcap", [("zstd", interleaved(0, 300), b""),
                                         ("zstd", interleaved(300, 600), b"")],
                   break_crc={1})
    r = open_reader(p)
    try:
        conns = [c for c in r.connections if c.topic == "/imu"]
        tb = TopicBlocks(r, conns, p)
        with pytest.raises(CliError, match="cannot read bag .*checksum"):
            list(tb)
    finally:
        r.close()
    assert tb.fast_messages == 300 and "CRC" in tb.fallback_reason
    rc = replay.main([str(p), "--latitude", "34", "--grade", "navigation"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "cannot read bag" in err[0]


def test_plan_refuses_what_it_does_not_read(tmp_path):
    p = write_mcap(tmp_path / "e.mcap", [("zstd", interleaved(0, 10), b""),
                                         ("zstd", interleaved(5, 20), b"")])
    from sins_align.io.bagio import McapUnusual
    with pytest.raises(McapUnusual, match="overlap"):
        list(McapTopicReader([(p, frozenset({1}))]).blocks())
    with pytest.raises(McapUnusual, match="not an MCAP"):
        (tmp_path / "x.mcap").write_bytes(b"nope" * 20)
        list(McapTopicReader([(tmp_path / "x.mcap", frozenset({1}))]).blocks())


# ------------------------------------------------------------------------------ decoding
def test_decode_from_chunk_views_equals_decode_imu_batch(tmp_path):
    """Imu messages sliced out of a chunk (strided and gathered) decode as the same bytes
    copied out one by one; a corrupt one goes to the fallback with its index."""
    raws = [imu_raw(k, "imu" if k < 50 else "imu_other") for k in range(120)]
    filler = [b"\x07" * 40, b"\x01" * 13]
    buf = bytearray()
    starts = []
    for k, raw in enumerate(raws):
        buf += filler[k % 2] if k >= 80 else filler[0]       # regular, then irregular gaps
        starts.append(len(buf))
        buf += raw
    starts = np.array(starts)
    sizes = np.array([len(r) for r in raws])
    u8 = np.frombuffer(bytes(buf), np.uint8)
    a = decode_imu_array(u8, starts, sizes)
    b = decode_imu_batch(raws)
    assert a.fallback == {} == b.fallback and a.frame_id == b.frame_id
    assert np.array_equal(a.floats, b.floats) and np.array_equal(a.sec, b.sec) \
        and np.array_equal(a.nanosec, b.nanosec)
    bad = bytearray(buf)
    bad[starts[60]] = 9                                     # not an encapsulation header
    seen = []
    decode_imu_array(np.frombuffer(bytes(bad), np.uint8), starts, sizes,
                     fallback=lambda raw, i: seen.append((i, raw)) or b.fallback.get(i)
                     or _ref(raws[i]))
    assert [i for i, _ in seen] == [60] and seen[0][1] == bytes(bad[starts[60]:starts[60]
                                                                     + sizes[60]])
    with pytest.raises(ValueError, match="outside buf"):
        decode_imu_array(u8, starts + len(buf), sizes)


def _ref(raw):
    return typestore().deserialize_cdr(raw, IMU)


def test_replay_summary_from_numpy_mcap_equals_rosbags_reading(tmp_path):
    """The whole replay on the fast reader and on rosbags' reader (both block-fed): the same
    summary, bit for bit."""
    from sins_align.tools import simulate

    bag = tmp_path / "sim"
    assert simulate.main(["--latitude", "34", "--duration", "70", "--rate", "100",
                          "--sway", "car", str(bag)]) == 0
    assert_replay_equals_rosbags(bag, "mcap-numpy")


def assert_replay_equals_rosbags(path, reading: str) -> None:
    """replay's summary of ``path`` read the fast way (``reading``) equals rosbags' reading
    of it, timings aside."""
    from sins_align.estimators.quasi_static.aligner import AlignConfig

    cfg = AlignConfig(latitude_deg=34.0)
    s1, sess1 = replay.replay(path, cfg, progress=False)
    s2, sess2 = replay.replay(path, cfg, progress=False, fast_mcap=False)
    assert sess1.reading == (reading, None) and sess2.reading[0] == "rosbags"
    for s in (s1, s2):
        s.pop("wall_time_s")
        s.pop("messages_per_s")
    assert json.dumps(s1, sort_keys=True) == json.dumps(s2, sort_keys=True)
