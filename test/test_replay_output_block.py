"""replay --output on the block path equals the node-equivalent one-sample path.

The block path (:meth:`ReplaySession.on_imu_output_block`) takes every output from the
estimator's outputs after each sample (``AlignmentSession.feed_block_states``: the state
coasted in closed form between updates, the diagnostics from the estimator's ``view()`` at
their sample), not from feeding the samples one at a time as align_node does
(:meth:`ReplaySession.on_imu`, ``per_sample=True``). The arithmetic differs, so the
orientation and its covariance may differ in the last bits: they are compared to 1e-9
(rad, and relative for the covariance); everything else (which messages, their topics,
log times and order, every header, the angular velocity and acceleration fields and their
covariances, the aligned flags, the diagnostics' levels, texts and values) must be equal,
and the Euler angles to 1e-7 deg. (The diagnostics print the std to 6 decimals from the block
path's covariance: a value on a rounding edge could in principle print one digit apart; it
does not on these bags.) Cases: a swaying base through coarse pass, backtrack and
fine pass; and an input with rejected samples (NaN, a spike), a gap and a restart (stamps
jumping back).
"""
from __future__ import annotations

import numpy as np
import pytest

from sins_align.io.bagio import Messages, open_reader, open_writer, qos_profile, read_messages
from sins_align.estimators.quasi_static.aligner import AlignConfig
from sins_align.tools import replay, simulate


def _decoded(bag):
    r = open_reader(bag)
    try:
        return [(c.topic, ns, r.deserialize(raw, c.msgtype))
                for c, ns, raw in read_messages(r, r.connections, bag)]
    finally:
        r.close()


def _flat(msg, prefix=""):
    """Every field of a rosbags message as (name, value) leaves."""
    out = []
    if hasattr(msg, "__msgtype__"):
        for k in msg.__dataclass_fields__:
            if k != "__msgtype__":
                out += _flat(getattr(msg, k), f"{prefix}{k}.")
    elif isinstance(msg, list):
        for i, v in enumerate(msg):
            out += _flat(v, f"{prefix}{i}.")
    else:
        out.append((prefix, msg))
    return out


def _compare(a, b):
    assert [(t, ns) for t, ns, _ in a] == [(t, ns) for t, ns, _ in b]
    for (topic, ns, ma), (_, _, mb) in zip(a, b):
        fa, fb = _flat(ma), _flat(mb)
        assert [k for k, _ in fa] == [k for k, _ in fb]
        for (k, va), (_, vb) in zip(fa, fb):
            where = f"{topic} at {ns}: {k}"
            if topic == "/imu/data" and k.startswith("orientation."):
                assert abs(va - vb) <= 1e-9, where
            elif topic == "/imu/data" and k.startswith("orientation_covariance"):
                np.testing.assert_allclose(va, vb, rtol=1e-9, atol=1e-20, err_msg=where)
            elif topic == "/alignment/euler_deg" and k.startswith("vector."):
                d = abs(va - vb)
                assert min(d, 360 - d) <= 1e-7, where
            elif isinstance(va, np.ndarray):
                assert np.array_equal(va, vb), where
            else:
                assert va == vb, where


def _both(tmp_path, bag, cfg):
    out = {}
    for per_sample in (False, True):
        p = out[per_sample] = tmp_path / f"out_{per_sample}"
        s, sess = replay.replay(bag, cfg, output=p, progress=False, per_sample=per_sample)
    return _decoded(out[False]), _decoded(out[True])


def test_block_output_equals_per_sample_sway(tmp_path):
    bag = tmp_path / "sim"
    assert simulate.main(["--latitude", "34", "--duration", "90", "--rate", "100",
                          "--sway", "car", "--rpy", "1.5", "-0.7", "40", "--seed", "3",
                          str(bag)]) == 0
    cfg = AlignConfig(latitude_deg=34.0, backtrack_time=20.0,
                      initial_rpy_deg=(60.0, -45.0, 170.0))
    a, b = _both(tmp_path, bag, cfg)
    topics = [t for t, _, _ in a]
    assert topics.count("/imu/data") == 9000 and topics.count("/diagnostics") >= 90
    assert [m.data for t, _, m in a if t == "/alignment/aligned"] == [False, True]
    _compare(a, b)


def test_block_output_equals_per_sample_bad_input(tmp_path):
    """Rejections (NaN, a rate spike), a gap, a restart (stamps jump back), two frames.
    One NaN comes before the backtrack (10 s), at 4 s: the double interval it leaves has
    its midpoint on a 1 s boundary of the backtrack's sway analysis, a tie that rounding
    used to decide differently in the block and one-sample paths (0.04 rad apart after the
    backtrack on this bag before the fix; test_reject_before_backtrack)."""
    src = tmp_path / "sim"
    assert simulate.main(["--latitude", "34", "--duration", "40", "--rate", "100",
                          "--sway", "ship", "--seed", "4", str(src)]) == 0
    msgs = [m for t, _, m in _decoded(src) if t == "/imu/data_raw"]
    bag = tmp_path / "bad"
    M = Messages()
    w = open_writer(bag)
    c = w.add_connection("/imu/data_raw", Messages.IMU, typestore=M.store,
                         offered_qos_profiles=[qos_profile()])
    order = list(range(2500)) + list(range(2600, 3200)) + list(range(0, 800))
    for k, i in enumerate(order):
        m = msgs[i]
        if k in (400, 1700):
            m.angular_velocity.x = float("nan")
        if k == 1200:
            m.angular_velocity.z = 5.0
        if k >= 2800:
            m.header.frame_id = "other_frame"
        w.write(c, 10**18 + k * 10**7, M.serialize(m))      # log time: in writing order
    w.close()
    cfg = AlignConfig(latitude_deg=34.0, backtrack_time=10.0)
    a, b = _both(tmp_path, bag, cfg)
    diags = [m for t, _, m in a if t == "/diagnostics"]
    vals = [dict((kv.key, kv.value) for kv in d.status[0].values) for d in diags]
    # (the reader returns the messages by log time = header stamp: not in writing order)
    assert max(int(v["resets"]) for v in vals) == 1
    assert max(int(v["samples_rejected"]) for v in vals) >= 3
    assert len({m.header.frame_id for t, _, m in a if t == "/imu/data"}) == 2
    _compare(a, b)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_block_output_reading(tmp_path, storage):
    bag = tmp_path / "sim"
    assert simulate.main(["--latitude", "34", "--duration", "5", "--rate", "100",
                          "--storage", storage, str(bag)]) == 0
    s, sess = replay.replay(bag, AlignConfig(latitude_deg=34.0), output=tmp_path / "o",
                            progress=False)
    assert sess.reading[0] == ("mcap-numpy" if storage == "mcap" else "sqlite3-bulk") \
        or sess.reading[0] == "rosbags"
    assert len([1 for t, _, _ in _decoded(tmp_path / "o") if t == "/imu/data"]) == 500


@pytest.mark.parametrize("frame", ["", "imu", "imu_link", "a_longer_frame_name_x"])
def test_vector3_stamped_cdr_is_rosbags_serialisation(frame):
    from sins_align.io.cdr import vector3_stamped_cdr

    M = Messages()
    xyz = (1.5, -2.25e-7, 359.999)
    assert vector3_stamped_cdr(1700000000, 123456789, frame, xyz) == M.serialize(
        M.vector3_stamped(M.header(1700000000, 123456789, frame), xyz))


@pytest.mark.parametrize("frame", ["", "i", "imu", "imu_link", "a_longer_frame_name_x", "ü"])
def test_vector3_stamped_cdr_many_is_each_message_alone(frame):
    from sins_align.io.cdr import vector3_stamped_cdr, vector3_stamped_cdr_many

    rng = np.random.default_rng(7)
    sec = rng.integers(0, 2**31 - 1, 5)
    nsec = rng.integers(0, 10**9, 5)
    xyz = rng.normal(size=(5, 3)) * 100.0
    many = vector3_stamped_cdr_many(sec, nsec, frame, xyz)
    assert many == [vector3_stamped_cdr(int(a), int(b), frame, v)
                    for a, b, v in zip(sec, nsec, xyz)]
    assert vector3_stamped_cdr_many(sec[:0], nsec[:0], frame, xyz[:0]) == []


@pytest.mark.parametrize("frame", ["", "imu", "imu_lin"])
def test_diagnostic_array_cdr_is_rosbags_serialisation(frame):
    from sins_align.io.cdr import diagnostic_array_cdr

    M = Messages()
    for statuses in ([], [(1, "n", "", frame, [])],
                     [(2, "align_node: alignment", "fault: ü", frame,
                       [("state", "aligned"), ("", "x"), ("elapsed_s", "12.345")])],
                     [(0, "a", "bc", "def", [("k", "v")]), (3, "", "x", "", [("ab", "")])]):
        assert diagnostic_array_cdr(12, 345, frame, statuses) == M.serialize(
            M.diagnostic_array(M.header(12, 345, frame), statuses)), statuses


def test_bool_cdr_and_definitions_are_rosbags():
    from sins_align.io.bagio import typestore
    from sins_align.io.msgdefs import DEFINITIONS

    M = Messages()
    for v in (False, True):
        assert replay.BOOL_CDR[v] == bytes(M.serialize(M.bool(v)))
    ts = typestore()
    for t, (msgdef, rihs01) in DEFINITIONS.items():
        assert ts.generate_msgdef(t, ros_version=2)[0] == msgdef
        assert ts.hash_rihs01(t) == rihs01
