"""The estimator's events and the session's data-path rules, which align_node and replay share
(sins_align.estimators.session): the same results one sample at a time and in blocks."""
from __future__ import annotations

import numpy as np

from sins_align.core.specs import DEG
from sins_align.estimators.quasi_static import EVENT_KINDS, AlignConfig, Aligner
from sins_align.estimators.session import BACKWARD_JUMP_CONFIRM, AlignmentSession
from sins_align.sim import simulate


def recorded(**kw):
    """An Aligner (latitude 34, backtrack at 30 s) and the list its events go to."""
    kw.setdefault("latitude_deg", 34.0)
    kw.setdefault("backtrack_time", 30.0)
    al = Aligner(AlignConfig(**kw))
    events = []
    al.subscribe(events.append)
    return al, events


def test_events_are_the_same_in_blocks_and_one_by_one():
    """rad/s (aligned), then deg/s for 44 s (the units check faults: the flag drops, the filter
    restarts), then rad/s again (aligned again), with bad samples among them: blocks of 5000
    and single samples give the same events, in the same order, with the same stamps; every
    rejection is an event with its reason and the counters agree with them."""
    s = simulate(240, 100, 34.0, specs="navigation", seed=12)
    gyro, accel = s.gyro.copy(), s.accel.copy()
    gyro[6050:10500] /= DEG
    gyro[2000] = np.nan
    accel[15000] = 0.1 * accel[15000]                      # gravity_removed
    a, ea = recorded()
    b, eb = recorded()
    for k in range(0, len(s.t), 5000):
        a.update(s.t[k:k + 5000], gyro[k:k + 5000], accel[k:k + 5000])
    for k in range(len(s.t)):
        b.update(s.t[k], gyro[k], accel[k])
    assert ea == eb
    assert {e.kind for e in ea} == set(EVENT_KINDS)
    flags = [(e.stamp, e.value) for e in ea if e.kind == "aligned"]
    assert [v for _, v in flags] == [True, False, True], flags
    restarts = [e for e in ea if e.kind == "restarted"]
    assert [e.value for e in restarts] == ["rates_look_like_deg_per_s"]
    # the window that closes after the deg/s start restarts the filter; the flag was down by
    # then (the wrong rates upset the fine pass first) and comes back after it
    assert flags[1][0] <= restarts[0].stamp < flags[2][0] and 60.5 < restarts[0].stamp < 105.0
    rejected = [e.value for e in ea if e.kind == "rejected"]
    assert len(rejected) == sum(a.rejected.values()) == sum(b.rejected.values())
    assert rejected.count("nonfinite") == 1 and rejected.count("gravity_removed") == 1
    assert a.time_to_aligned == b.time_to_aligned


def test_reset_tells_subscribers_and_keeps_the_counters():
    s = simulate(80, 100, 34.0, specs="navigation", seed=3)
    al, ev = recorded()
    al.update(s.t, s.gyro, s.accel)
    assert al.aligned
    al.update(s.t[-1], s.gyro[-1], s.accel[-1])             # duplicate_stamp
    ev.clear()
    al.reset("operator asked")
    assert [(e.kind, e.value) for e in ev] == [("aligned", False), ("restarted", "operator asked")]
    assert al.rejected["duplicate_stamp"] == 1 and al.t_last is None and not al.aligned


def _loop_stream():
    """50 s of data, then the same recording again from its start (a bag played in a loop:
    stamps jump back 50 s), with one sample stamped 100 s in the past in the first pass."""
    s = simulate(50, 100, 34.0, specs="navigation", seed=4)
    t = np.concatenate((s.t, s.t + 0.0))
    w = np.concatenate((s.gyro, s.gyro))
    f = np.concatenate((s.accel, s.accel))
    t[3000] -= 100.0
    return t, w, f


def test_session_blocks_equal_samples_with_a_bag_loop():
    """The session restarts the alignment after BACKWARD_JUMP_CONFIRM stamps far behind the
    last accepted one (the loop), not for one old stamp; fed one sample at a time or as one
    block (cut where a stamp could be far behind), it accepts the same samples, restarts at
    the same place and ends in the same state."""
    t, w, f = _loop_stream()
    one, one_ev = recorded()
    blk, blk_ev = recorded()
    s1 = AlignmentSession(one, record_flag_changes=True)
    s2 = AlignmentSession(blk, record_flag_changes=True)
    accepted = [s1.feed(float(t[k]), w[k], f[k]) for k in range(len(t))]
    n2 = s2.feed_block(t, w, f)
    assert sum(accepted) == n2
    assert not accepted[3000] and one.rejected["stamp_backwards"] == 1 + (
        BACKWARD_JUMP_CONFIRM - 1)
    # the first samples of the second pass are rejected until the jump is confirmed
    assert accepted[5000:5000 + BACKWARD_JUMP_CONFIRM - 1] == [False] * (
        BACKWARD_JUMP_CONFIRM - 1)
    assert s1.resets == s2.resets == 1 and "jumped back" in s1.last_reset_reason
    assert s1.last_reset_reason == s2.last_reset_reason
    assert one_ev == blk_ev
    assert s1.take_flag_changes() == s2.take_flag_changes()
    assert np.array_equal(one.dcm, blk.dcm) or np.abs(one.dcm - blk.dcm).max() < 1e-12
    assert one.rejected == blk.rejected and one.samples_used == blk.samples_used


def test_session_restart_request_and_flag_publication():
    """A restart asked for (the reset service, ROS time set back) happens before the next
    sample; the flag is to be published at the start and whenever it changes, once."""
    s = simulate(80, 100, 34.0, specs="navigation", seed=3)
    al, _ = recorded()
    ses = AlignmentSession(al)
    assert ses.flag_to_publish() is False and ses.flag_to_publish() is None
    ses.feed_block(s.t[:7000], s.gyro[:7000], s.accel[:7000])
    assert ses.flag_to_publish() is True and ses.flag_to_publish() is None
    ses.request_restart("ROS time jumped back by 3.000 s")
    assert al.aligned and ses.resets == 0                 # not before the next sample
    assert ses.feed(float(s.t[7000]), s.gyro[7000], s.accel[7000])
    assert ses.resets == 1 and ses.last_reset_reason == "ROS time jumped back by 3.000 s"
    assert ses.flag_to_publish() is False
    assert al.t_first == s.t[7000]
