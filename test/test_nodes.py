"""align_node and imu_sim_node over real DDS.

The nodes run as child processes (``python -m sins_align.<node>``, which also proves
``main()``); the test talks to them through an rclpy probe node in this process. Data time
runs 10x faster than wall time (50 Hz IMU, speed 10) and the backtrack starts after 20 s of
data, so an alignment takes a few wall seconds.

Each test names what it proves. Bounds on the attitude error come from what the node
publishes itself (its covariance and limit accuracy), never from hand-picked tolerances.
"""
from __future__ import annotations

import math
import os
import time
from types import SimpleNamespace

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from rclpy.serialization import serialize_message
from rclpy.qos import (DurabilityPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_sensor_data)
from sensor_msgs.msg import Imu
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from ros_helpers import (LATCHED, NodeProcess, Probe, assert_refuses_start, diag_values,
                         latest_diag, stamp_ns, wait_until)
import sins_align
from sins_align.ros import align_node
from sins_align.estimators.session import BACKWARD_JUMP_CONFIRM
from sins_align.ros.outputs import covariance_is_valid
from sins_align.ros.params import (ALIGN_NODE_PARAMS, PARAMS, check_param, config_from_params,
                                   load_params_yaml)
from sins_align.core.rotation import attitude_error, dcm_from_quat, rpy_from_dcm
from sins_align.sim.simulator import SwayProfile, simulate
from sins_align.core.specs import DEG, grade_specs, limit_std

RATE = 50.0          # Hz, data time
SPEED = 10.0         # data s per wall s
BACKTRACK = 20.0     # s of data
# names carry the pid: another test run that lands on the same ROS domain cannot interfere
RUN = os.getpid()
NS = f"/nt_{RUN}"
NODE = f"align_a_{RUN}"
STATUS = f"{NODE}: alignment"
TRUE_RPY = (2.0, -1.0, 30.0)
RELIABLE_DEEP = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE)
SENSOR_DEEP = QoSProfile(depth=5000, reliability=qos_profile_sensor_data.reliability,
                         durability=qos_profile_sensor_data.durability)
ALIGN_TIMEOUT = 90.0   # wall s; the alignment needs ~60 s of data = ~6 s wall


@pytest.fixture(scope="module")
def probe():
    p = Probe("test_nodes_probe")
    yield p
    p.close()


def _diag_fail(pair) -> str:
    return f"latest diagnostics: {latest_diag(pair.diags, STATUS)}\n{pair.node.output()}"


@pytest.fixture(scope="module")
def pair(probe, tmp_path_factory):
    """align_node (large initial error) fed by imu_sim_node; the probe listens."""
    logs = tmp_path_factory.mktemp("nodes")
    aligned = probe.subscribe(Bool, f"{NS}/alignment/aligned", LATCHED)
    diags = probe.subscribe(DiagnosticArray, "/diagnostics", 50, maxlen=200)
    truth = probe.subscribe(QuaternionStamped, f"{NS}/imu_sim/truth", RELIABLE_DEEP, maxlen=3000)
    node = NodeProcess("align_node", [
        "-r", f"__ns:={NS}", "-r", f"__node:={NODE}", "-p", "latitude:=34.0",
        "-p", "grade:=navigation", "-p", f"backtrack_time:={BACKTRACK}",
        "-p", "initial_rpy:=[89.0, 89.0, 179.0]"],
        logs, NODE)
    sim = None
    try:
        wait_until(lambda: len(aligned) or not node.alive(), 30.0, "align_node to come up")
        assert node.alive(), node.output()
        sim = NodeProcess("imu_sim_node", [
            "-r", f"__ns:={NS}", "-r", "__node:=sim_a", "-p", f"rate:={RATE}",
            "-p", f"speed:={SPEED}", "-p", f"rpy:=[{TRUE_RPY[0]}, {TRUE_RPY[1]}, {TRUE_RPY[2]}]",
            "-p", "seed:=3", "-p", "wait_for_subscribers:=true"], logs, "sim_a")
        yield SimpleNamespace(node=node, sim=sim, aligned=aligned, diags=diags, truth=truth)
    finally:
        for p in (sim, node):
            if p is not None:
                p.stop()


def test_aligned_flag_starts_false_and_latches_true(pair):
    """alignment/aligned is false at start, turns true once, and stays true."""
    first = wait_until(lambda: pair.aligned.msgs, 5.0, "the initial aligned message")
    assert first[0].data is False, "the first aligned message must be false"
    try:
        wait_until(lambda: any(m.data for m in pair.aligned.msgs), ALIGN_TIMEOUT, "aligned=true")
    except AssertionError as e:
        raise AssertionError(f"{e}\n{_diag_fail(pair)}") from None
    time.sleep(2.0)
    values = [m.data for m in pair.aligned.msgs]
    k = values.index(True)
    assert all(values[k:]), f"aligned flag dropped after latching: {values}"
    assert values[:k] == [False] * k, values   # published on change only
    d = wait_until(lambda: latest_diag(pair.diags, STATUS), 5.0, "diagnostics")
    assert d["state"] == "aligned" and d["aligned"] == "true", d


def test_late_transient_local_subscriber_gets_the_latched_flag(pair, probe):
    """A subscriber that joins after the change still receives aligned=true (TRANSIENT_LOCAL);
    a VOLATILE one does not, so the flag is latched, not re-published periodically."""
    wait_until(lambda: any(m.data for m in pair.aligned.msgs), ALIGN_TIMEOUT, "aligned=true")
    late = probe.subscribe(Bool, f"{NS}/alignment/aligned", LATCHED)
    volatile = probe.subscribe(Bool, f"{NS}/alignment/aligned",
                               QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                          durability=DurabilityPolicy.VOLATILE))
    try:
        wait_until(lambda: len(late), 10.0, "the latched aligned message")
        assert [m.data for m in late.msgs] == [True]
        time.sleep(1.0)
        assert len(volatile) == 0, "aligned was re-published although it did not change"
    finally:
        probe.unsubscribe(late)
        probe.unsubscribe(volatile)


def _window(probe, seconds: float, extra=()):
    """Collect imu/data, imu/data_raw (and ``extra`` topics) for ``seconds`` wall seconds."""
    out = probe.subscribe(Imu, f"{NS}/imu/data", RELIABLE_DEEP)
    raw = probe.subscribe(Imu, f"{NS}/imu/data_raw", SENSOR_DEEP)
    more = [probe.subscribe(t, f"{NS}/{name}", 50) for t, name in extra]
    time.sleep(seconds)
    for c in (out, raw, *more):
        probe.unsubscribe(c)
    return out.msgs, raw.msgs, [c.msgs for c in more]


def test_imu_data_orientation_matches_truth_within_published_covariance(pair, probe):
    """imu/data = the input sample (same header and data) plus an orientation whose error
    against imu_sim/truth stays inside 4 sigma of the published covariance, and that
    covariance is as tight as the aligned criterion (limit accuracy) promises."""
    wait_until(lambda: any(m.data for m in pair.aligned.msgs), ALIGN_TIMEOUT, "aligned=true")
    out, raw, _ = _window(probe, 2.0)
    truth = {stamp_ns(m.header.stamp): m.quaternion for m in pair.truth.msgs}
    raw_by = {stamp_ns(m.header.stamp): m for m in raw}
    pairs = [(m, truth[stamp_ns(m.header.stamp)]) for m in out
             if stamp_ns(m.header.stamp) in truth]
    assert len(pairs) >= 0.5 * RATE * SPEED, f"only {len(pairs)} imu/data samples matched truth"

    d = latest_diag(pair.diags, STATUS)
    limit = np.array([float(d[f"limit_{a}_deg"]) for a in ("east", "north", "up")]) * DEG
    cfg = config_from_params({"latitude": 34.0, "grade": "navigation"})
    bound = np.maximum(cfg.aligned_std_ratio * limit,
                       np.array([cfg.aligned_min_level_std_deg] * 2
                                + [cfg.aligned_min_heading_std_deg]) * DEG)
    worst = 0.0
    passthrough = 0
    for m, qt in pairs:
        q = m.orientation
        assert abs(math.sqrt(q.x ** 2 + q.y ** 2 + q.z ** 2 + q.w ** 2) - 1.0) < 1e-9, q
        C_est = dcm_from_quat(np.array([q.x, q.y, q.z, q.w]))
        C_true = dcm_from_quat(np.array([qt.x, qt.y, qt.z, qt.w]))
        phi = attitude_error(C_true, C_est)
        assert covariance_is_valid(m.orientation_covariance), m.orientation_covariance
        sigma = np.sqrt(np.diag(np.array(m.orientation_covariance).reshape(3, 3)))
        assert np.all(sigma <= bound * (1 + 1e-9)), (sigma / DEG, bound / DEG)
        worst = max(worst, float(np.max(np.abs(phi) / sigma)))
        assert np.all(np.abs(phi) <= 4.0 * sigma), (
            f"attitude error {phi / DEG} deg outside 4 sigma {sigma / DEG} deg")
        r = raw_by.get(stamp_ns(m.header.stamp))
        if r is not None:
            passthrough += 1
            assert m.header.frame_id == r.header.frame_id == "imu_link"
            for f in ("angular_velocity", "linear_acceleration"):
                a, b = getattr(m, f), getattr(r, f)
                assert (a.x, a.y, a.z) == (b.x, b.y, b.z), f
            assert list(m.angular_velocity_covariance) == list(r.angular_velocity_covariance)
    assert passthrough > 0, "no imu/data_raw sample seen next to its imu/data twin"
    print(f"{len(pairs)} samples, worst |phi|/sigma = {worst:.2f}")


def test_euler_deg_rate_stamp_and_values(pair, probe):
    """alignment/euler_deg comes at ~euler_rate (10 Hz), carries the latest input stamp and
    frame, and equals the REP-103 roll/pitch/yaw of the imu/data orientation of that stamp."""
    out, _, (euler,) = _window(probe, 3.0, extra=[(Vector3Stamped, "alignment/euler_deg")])
    assert 15 <= len(euler) <= 45, f"{len(euler)} euler messages in 3 s at 10 Hz"
    by_stamp = {stamp_ns(m.header.stamp): m.orientation for m in out}
    checked = 0
    for e in euler:
        assert e.header.frame_id == "imu_link"
        q = by_stamp.get(stamp_ns(e.header.stamp))
        if q is None:
            continue
        rpy = rpy_from_dcm(dcm_from_quat(np.array([q.x, q.y, q.z, q.w]))) / DEG
        assert np.allclose([e.vector.x, e.vector.y, e.vector.z], rpy, atol=1e-9), (e.vector, rpy)
        checked += 1
    assert checked >= len(euler) // 2, f"only {checked}/{len(euler)} euler stamps were inputs"


def test_diagnostics_report_state_limits_counts_and_rate(pair):
    """/diagnostics (1 Hz) carries state, per-axis std and limit (the analytic limit accuracy
    of the configured specs), heading observability, sample counts and the input rate."""
    wait_until(lambda: any(m.data for m in pair.aligned.msgs), ALIGN_TIMEOUT, "aligned=true")
    n0 = sum(diag_values(a, STATUS) is not None for a in pair.diags.msgs)
    time.sleep(3.2)
    n = sum(diag_values(a, STATUS) is not None for a in pair.diags.msgs) - n0
    assert 2 <= n <= 5, f"{n} diagnostics in 3.2 s (1 Hz expected)"
    d = latest_diag(pair.diags, STATUS)
    assert d["state"] == "aligned" and d["level"] == "0", d
    assert d["heading_observable"] == "true" and d["stage"] == "fine"
    lim = limit_std(34.0 * DEG, grade_specs("navigation")) / DEG
    got = [float(d[f"limit_{a}_deg"]) for a in ("east", "north", "up")]
    assert np.allclose(got, lim, rtol=2e-3), (got, lim)
    assert all(float(d[f"std_{a}_deg"]) > 0 for a in ("east", "north", "up"))
    assert int(d["samples_used"]) > BACKTRACK * RATE and d["samples_rejected"] == "0", d
    rate = float(d["input_rate_hz"])
    assert abs(rate - RATE * SPEED) < 0.25 * RATE * SPEED, f"input rate {rate}"
    assert abs(float(d["data_rate_hz"]) - RATE) < 0.01 * RATE


def test_runtime_parameter_changes_are_checked_and_applied_live(pair, probe):
    """Bad runtime values are refused with a reason; accepted thresholds act on the running
    alignment without restarting it (disturbance_nis below the live NIS reports 'disturbed'
    and keeps the good alignment; an unreachable criterion withdraws aligned, restoring it
    gives aligned back)."""
    fqn = f"{NS}/{NODE}"
    wait_until(lambda: any(m.data for m in pair.aligned.msgs), ALIGN_TIMEOUT, "aligned=true")
    for values, words in [({"max_angular_rate": 1000.0}, "max_angular_rate"),
                          ({"disturbance_nis": "high"}, "expected 'Type.DOUBLE'"),
                          ({"aligned_min_level_std": -1.0}, "aligned_min_level_std"),
                          ({"model": "se3"}, "read-only"),
                          ({"euler_rate": 0.0}, "euler_rate")]:
        (res,) = probe.set_parameters(fqn, **values)
        assert not res.successful, f"{values} was accepted"
        assert words in res.reason, (values, res.reason)

    before = latest_diag(pair.diags, STATUS)
    (res,) = probe.set_parameters(fqn, aligned_std_ratio=2.0)
    assert res.successful, res.reason
    n_flags = len(pair.aligned)
    # disturbance_nis below the live NIS: reported as disturbed, the alignment stays good
    (res,) = probe.set_parameters(fqn, disturbance_nis=0.1)
    assert res.successful, res.reason
    try:
        wait_until(lambda: latest_diag(pair.diags, STATUS)["state"] == "disturbed", 5.0,
                   "state disturbed")
        assert latest_diag(pair.diags, STATUS)["aligned"] == "true"
        assert len(pair.aligned) == n_flags, "a disturbance alone withdrew aligned"
    finally:
        (res,) = probe.set_parameters(fqn, disturbance_nis=3.0)
        assert res.successful, res.reason
    # a criterion the std cannot meet withdraws the flag at the next update
    res = probe.set_parameters(fqn, aligned_std_ratio=1.0, aligned_min_level_std=0.0,
                               aligned_min_heading_std=0.0)
    assert all(r.successful for r in res), [r.reason for r in res]
    try:
        wait_until(lambda: [m.data for m in pair.aligned.msgs[n_flags:]] == [False], 10.0,
                   "aligned=false under an unreachable criterion")
    finally:
        res = probe.set_parameters(fqn, aligned_std_ratio=2.0, aligned_min_level_std=0.01,
                                   aligned_min_heading_std=0.1)
        assert all(r.successful for r in res), [r.reason for r in res]
    wait_until(lambda: pair.aligned.msgs[-1].data, 10.0, "aligned=true again")
    after = wait_until(lambda: (lambda d: d if d["state"] == "aligned" else None)(
        latest_diag(pair.diags, STATUS)), 5.0, "state aligned")
    # same run: no restart, time and samples kept growing
    assert after["resets"] == before["resets"] == "0"
    assert float(after["elapsed_s"]) > float(before["elapsed_s"])
    assert int(after["samples_used"]) > int(before["samples_used"])


def test_euler_rate_change_restarts_the_euler_timer(pair, probe):
    """euler_rate set at runtime replaces the euler timer: 2 Hz, then 10 Hz again."""
    fqn = f"{NS}/{NODE}"
    try:
        (res,) = probe.set_parameters(fqn, euler_rate=2.0)
        assert res.successful, res.reason
        _, _, (slow,) = _window(probe, 3.0, extra=[(Vector3Stamped, "alignment/euler_deg")])
    finally:
        (res,) = probe.set_parameters(fqn, euler_rate=10.0)
        assert res.successful, res.reason
    _, _, (fast,) = _window(probe, 3.0, extra=[(Vector3Stamped, "alignment/euler_deg")])
    assert 3 <= len(slow) <= 9, f"{len(slow)} euler messages in 3 s at 2 Hz"
    assert 15 <= len(fast) <= 45, f"{len(fast)} euler messages in 3 s at 10 Hz"


def test_reset_service_restarts_the_alignment(pair, probe):
    """alignment/reset: aligned goes false, diagnostics say aligning, then aligned again."""
    wait_until(lambda: pair.aligned.msgs and pair.aligned.msgs[-1].data, ALIGN_TIMEOUT,
               "aligned=true")
    n = len(pair.aligned)
    resp = probe.call(Trigger, f"{NS}/alignment/reset", Trigger.Request())
    assert resp.success, resp.message
    wait_until(lambda: [m.data for m in pair.aligned.msgs[n:]][:1] == [False], 10.0,
               "aligned=false after reset")
    d = wait_until(lambda: (lambda d: d if d["resets"] == "1" else None)(
        latest_diag(pair.diags, STATUS)), 5.0, "diagnostics after the reset")
    assert d["state"] == "aligning" and d["aligned"] == "false", d
    assert "reset service" in d["last_reset_reason"]
    assert float(d["elapsed_s"]) < BACKTRACK, d
    try:
        wait_until(lambda: pair.aligned.msgs[-1].data, ALIGN_TIMEOUT, "aligned=true again")
    except AssertionError as e:
        raise AssertionError(f"{e}\n{_diag_fail(pair)}") from None


def test_nodes_exit_cleanly_on_sigint(pair):
    """Ctrl-C ends both nodes with status 0 and no traceback (main's shutdown path)."""
    for p in (pair.sim, pair.node):
        assert p.alive(), p.output()
        assert p.stop() == 0, p.output()
        assert "Traceback" not in p.stderr(), p.output()


# ---------------------------------------------------------------------------- startup errors
@pytest.mark.parametrize("args, reason", [
    ([], "latitude is required"),
    (["-p", "latitude:=34.0"], "grade is required"),
    (["-p", "latitude:=34.0", "-p", "gyro_bias:=0.5", "-p", "gyro_arw:=0.01",
      "-p", "accel_bias:=100.0"], "grade is required"),
    (["-p", "latitude:=95.0"], "latitude must be within [-90, 90]"),
    (["-p", "latitude:=34.0", "-p", "model:=kalman"], "model must be one of"),
    (["-p", "latitude:=34.0", "-p", "backtrack_time:=1.0"], "backtrack_time must be within"),
], ids=["missing-latitude", "missing-grade", "three-specs-without-grade",
        "latitude-out-of-range", "bad-model", "backtrack-too-short"])
def test_bad_startup_parameters_exit_1_with_one_line(args, reason, tmp_path):
    """A bad or missing parameter: exit status 1 and one log line with the reason."""
    p = assert_refuses_start("align_node", ["-r", "__node:=align_bad_param", *args], reason,
                             tmp_path)
    assert "Traceback" not in p.output()


def test_align_yaml_lists_every_parameter_with_its_default():
    """config/align.yaml sets every parameter (node-only ones too) to its default, except the
    two required ones it gives examples of (latitude, grade); the values make a valid
    AlignConfig."""
    from pathlib import Path

    path = Path(sins_align.__file__).parent / "config" / "align.yaml"
    values = load_params_yaml(path)
    assert set(values) == {p.name for p in ALIGN_NODE_PARAMS}
    assert {p.name for p in ALIGN_NODE_PARAMS} == {p.name for p in PARAMS} | {"euler_rate",
                                                                            "queue_size"}
    for p in ALIGN_NODE_PARAMS:
        if p.name not in ("latitude", "grade"):
            assert values[p.name] == p.default, (p.name, values[p.name], p.default)
            assert check_param(p.name, values[p.name], p.scope) is None, p.name
    assert math.isfinite(values["latitude"]) and values["grade"] == "consumer"
    config_from_params({p.name: values[p.name] for p in PARAMS})


# ---------------------------------------------------------------------------- bad input
BAD_EACH = 5          # samples of each defect
_BAD_NODES = iter(range(1_000_000))


@pytest.fixture
def bad(probe, tmp_path):
    """A fresh align_node for each test (each stands alone), fed by the test itself
    (nominal 50 Hz, 5 s units-check window); its own namespace and node name."""
    k = next(_BAD_NODES)
    ns, name = f"/bad{k}_{RUN}", f"align_bad{k}_{RUN}"
    diags = probe.subscribe(DiagnosticArray, "/diagnostics", 50, maxlen=200)
    out = probe.subscribe(Imu, f"{ns}/imu/data", RELIABLE_DEEP)
    node = NodeProcess("align_node", [
        "-r", f"__ns:={ns}", "-r", f"__node:={name}", "-p", "latitude:=34.0",
        "-p", "grade:=navigation", "-p", f"rate:={RATE}", "-p", "units_check_window:=5.0"],
        tmp_path, name)
    pub = probe.node.create_publisher(Imu, f"{ns}/imu/data_raw", qos_profile_sensor_data)
    try:
        wait_until(lambda: (pub.get_subscription_count() > 0
                            and out.subscription.get_publisher_count() > 0)
                   or not node.alive(), 30.0, "align_node to subscribe and publish imu/data")
        assert node.alive(), node.output()
        time.sleep(0.5)
        yield SimpleNamespace(node=node, pub=pub, diags=diags, out=out, sent=0,
                              status=f"{name}: alignment")
    finally:
        node.stop()
        probe.node.destroy_publisher(pub)
        probe.unsubscribe(diags)
        probe.unsubscribe(out)


def _imu(t: float, w, f, frame: str = "imu_link") -> Imu:
    m = Imu()
    ns = int(round(t * 1e9))
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(ns, 1_000_000_000)
    m.header.frame_id = frame
    m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = map(float, w)
    m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = map(float, f)
    return m


def _send(bad, msgs, per_burst: int = 10, pause: float = 0.02):
    for i in range(0, len(msgs), per_burst):
        for m in msgs[i:i + per_burst]:
            bad.pub.publish(m)
        time.sleep(pause)
    bad.sent += len(msgs)


def _accounted(bad):
    """Diagnostics once every sent sample is used, rejected or the first one."""
    def done():
        d = latest_diag(bad.diags, bad.status)
        if d and int(d["samples_used"]) + int(d["samples_rejected"]) + 1 == bad.sent:
            return d
        return None
    try:
        return wait_until(done, 15.0, f"diagnostics accounting for {bad.sent} samples")
    except AssertionError as e:
        raise AssertionError(f"{e}: {latest_diag(bad.diags, bad.status)}\n"
                             f"{bad.node.output()}") from None


T0 = 1_000_000.0      # s, stamps of the hand-made stream


def test_bad_samples_are_counted_by_reason_and_the_node_keeps_going(bad):
    """NaNs, duplicate and backward stamps, gravity-removed accelerations and deg/s gyro rates
    are rejected and counted by reason (never republished, warned about by name); the node
    stays up, reports a fault for the deg/s rates, and resumes on good data."""
    dt = 1.0 / RATE
    a = simulate(10.0, rate=RATE, seed=11)
    msgs, defects = [], {"nonfinite": 0, "duplicate_stamp": 0, "stamp_backwards": 0,
                         "gravity_removed": 0}
    for k in range(len(a.t)):
        t, w, f = T0 + a.t[k], a.gyro[k], a.accel[k]
        msgs.append(_imu(t, w, f))
        slot = k % 20
        if k < 20 * BAD_EACH and 0 < k:
            if slot == 3:
                msgs.append(_imu(t + dt / 2, [math.nan, 0.0, 0.0], f))
                defects["nonfinite"] += 1
            elif slot == 7:
                msgs.append(_imu(t, w, f))
                defects["duplicate_stamp"] += 1
            elif slot == 11:
                msgs.append(_imu(t - 0.5, w, f))
                defects["stamp_backwards"] += 1
            elif slot == 15:
                msgs.append(_imu(t + dt / 2, w, f - np.array([0.0, 0.0, 9.79])))
                defects["gravity_removed"] += 1
    assert all(v == BAD_EACH for v in defects.values()), defects
    # deg/s rates: a base swaying 2 deg at 0.05 Hz, gyro numbers 57.3x too large
    sway = SwayProfile(ang_amp=(2.0 * DEG, 2.0 * DEG, 0.0), ang_freq=(0.05, 0.05, 0.05))
    b = simulate(12.0, rate=RATE, seed=12, sway=sway)
    t_b = T0 + a.t[-1]
    msgs += [_imu(t_b + b.t[k], b.gyro[k] / DEG, b.accel[k]) for k in range(len(b.t))]
    _send(bad, msgs)
    d = _accounted(bad)
    for reason, n in defects.items():
        assert d.get(f"rejected_{reason}") == str(n), (reason, d)
    assert int(d.get("rejected_rates_look_like_deg_per_s", "0")) > 0, d
    assert d["state"] == "fault" and d["level"] == "2", d
    assert bad.node.alive(), bad.node.output()
    # never republished: one imu/data per used sample plus the first (time anchor)
    wait_until(lambda: bad.out.count == int(d["samples_used"]) + 1, 5.0,
               f"imu/data count {bad.out.count} == used + 1 ({d['samples_used']} + 1)")
    err = bad.node.stderr()
    for reason in (*defects, "rates_look_like_deg_per_s"):
        assert f"sample(s): {reason}" in err, f"no warning naming {reason}:\n{err}"

    # good data again: the fault clears, the alignment carries on
    c = simulate(15.0, rate=RATE, seed=13)
    t_c = t_b + b.t[-1]
    used_before = int(d["samples_used"])
    _send(bad, [_imu(t_c + c.t[k], c.gyro[k], c.accel[k]) for k in range(len(c.t))])
    d = _accounted(bad)
    assert d["state"] == "aligning", d
    assert int(d["samples_used"]) > used_before + 5 * RATE, d
    assert bad.node.alive()


def _good_start(bad, seconds: float, seed: int, defects: bool = False) -> float:
    """Send ``seconds`` of clean samples from T0 (with ``defects``: also one NaN sample and
    one duplicate stamp, which are rejected); wait until they are accounted for; return the
    last stamp sent."""
    a = simulate(seconds, rate=RATE, seed=seed)
    msgs = [_imu(T0 + a.t[k], a.gyro[k], a.accel[k]) for k in range(len(a.t))]
    if defects:
        msgs.insert(10, _imu(T0 + a.t[9] + 0.5 / RATE, [math.nan, 0.0, 0.0], a.accel[9]))
        msgs.insert(20, _imu(T0 + a.t[18], a.gyro[18], a.accel[18]))
    _send(bad, msgs)
    _accounted(bad)
    return T0 + a.t[-1]


def test_undecodable_messages_are_counted_and_the_node_keeps_going(bad):
    """Bytes that are no sensor_msgs/Imu (truncated, garbage after a CDR header) reach the
    raw subscription: each is counted as 'undecodable', warned about by name, never
    republished, and the samples around them are used as usual."""
    t_end = _good_start(bad, 2.0, seed=16)
    good = serialize_message(_imu(0.0, [0.0, 0.0, 0.0], [0.0, 0.0, 9.8]))
    junk = [b"\x00\x01\x00\x00\x01\x02", good[:40], b"\x00\x01\x00\x00" + b"\xff" * 300]
    a = simulate(2.0, rate=RATE, seed=15)
    d0 = _accounted(bad)
    used0 = int(d0["samples_used"])
    wait_until(lambda: bad.out.count == used0 + 1, 5.0, "imu/data for the first samples")
    out0 = bad.out.count
    msgs = []
    for k in range(len(a.t)):
        msgs.append(_imu(t_end + a.t[k], a.gyro[k], a.accel[k]))
        if k % 25 == 10:
            msgs.append(junk[(k // 25) % len(junk)])
    n_junk = sum(isinstance(m, bytes) for m in msgs)
    assert n_junk == 4
    _send(bad, msgs)
    d = _accounted(bad)
    assert d.get("rejected_undecodable") == str(n_junk), d
    assert int(d["samples_used"]) == used0 + len(a.t), d
    assert bad.node.alive(), bad.node.output()
    wait_until(lambda: bad.out.count == out0 + len(a.t), 5.0, "imu/data for the good samples")
    assert "sample(s): undecodable" in bad.node.stderr()


def test_stamps_jumping_back_restart_the_alignment(bad):
    """Stamps far behind the last one (a bag loop) restart the alignment after a few samples;
    a single late sample would only be rejected. The rejection counters (two bad samples
    before the jump) survive the restart."""
    t_end = _good_start(bad, 3.0, seed=17, defects=True)
    a = simulate(1.0, rate=RATE, seed=14)
    t0 = t_end - 100.0
    d0 = _accounted(bad)
    assert int(d0["samples_rejected"]) == 2 and d0["resets"] == "0", d0
    _send(bad, [_imu(t0 + a.t[k], a.gyro[k], a.accel[k]) for k in range(len(a.t))])

    def restarted():      # after the restart, and once every sample sent is accounted for
        d = latest_diag(bad.diags, bad.status)
        done = d and int(d["samples_used"]) + int(d["samples_rejected"]) == \
            len(a.t) + int(d0["samples_rejected"]) - 1
        return d if done and d["resets"] == "1" else None
    d = wait_until(restarted, 10.0, "a restart after the stamps jumped back")
    n_confirm = BACKWARD_JUMP_CONFIRM
    back = t_end - (t0 + a.t[n_confirm - 1])
    assert f"input stamps jumped back by {back:.3f} s" in d["last_reset_reason"], d
    # the confirming sample starts the new run; the ones before it were plain rejections
    assert int(d["samples_used"]) == len(a.t) - n_confirm, d
    # the rejection counters survive the restart: the samples before it stay counted
    assert d["state"] == "aligning", d
    assert int(d["samples_rejected"]) == int(d0["samples_rejected"]) + n_confirm - 1, (d0, d)


def test_ros_time_jumping_back_restarts_the_alignment(probe):
    """With use_sim_time, ROS time set back (a bag loop with --clock) restarts the
    alignment at the next sample. In-process node, real DDS for the sample."""
    from rclpy.parameter import Parameter
    from rclpy.time import Time

    node = align_node.make_node_class()(
        context=probe.context, namespace=f"/jump_{RUN}",
        parameter_overrides=[Parameter("latitude", value=34.0),
                             Parameter("grade", value="navigation"),
                             Parameter("use_sim_time", value=True)])
    probe.executor.add_node(node)
    pub = probe.node.create_publisher(Imu, f"/jump_{RUN}/imu/data_raw", qos_profile_sensor_data)
    try:
        wait_until(lambda: pub.get_subscription_count() > 0, 10.0, "subscription")
        s = simulate(1.0, rate=RATE, seed=15)
        clock = node.get_clock()
        clock.set_ros_time_override(Time(seconds=1000))
        for k in range(10):
            pub.publish(_imu(T0 + s.t[k], s.gyro[k], s.accel[k]))
            time.sleep(0.01)
        wait_until(lambda: node.aligner.samples_used >= 5, 5.0, "samples used")
        assert node.session.resets == 0
        clock.set_ros_time_override(Time(seconds=900))
        for k in range(10, 20):
            pub.publish(_imu(T0 + s.t[k], s.gyro[k], s.accel[k]))
            time.sleep(0.01)
        wait_until(lambda: node.session.resets == 1, 5.0, "a restart after ROS time jumped back")
        assert "ROS time jumped back by 100" in node.session.last_reset_reason
    finally:
        probe.node.destroy_publisher(pub)
        probe.executor.remove_node(node)
        node.destroy_node()


class _Published(list):
    """Stands in for a publisher: keeps what is published."""

    def publish(self, msg):
        self.append(msg)


def test_queue_size_sets_the_imu_history_depth_in_and_out(probe):
    """queue_size is the history depth of the imu/data_raw subscription (best effort) and of
    the imu/data publisher (reliable)."""
    from rclpy.parameter import Parameter
    from rclpy.qos import ReliabilityPolicy

    node = align_node.make_node_class()(
        context=probe.context, namespace=f"/depth_{RUN}",
        parameter_overrides=[Parameter("latitude", value=34.0),
                             Parameter("grade", value="navigation"),
                             Parameter("queue_size", value=321)])
    try:
        assert node.sub.qos_profile.depth == node.pub_imu.qos_profile.depth == 321
        assert node.sub.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
        assert node.pub_imu.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    finally:
        node.destroy_node()


def test_raw_path_publishes_what_the_message_path_publishes(probe):
    """The node reads serialised imu/data_raw (raw subscription) and republishes the bytes with
    the orientation fields overwritten; its message path (rclpy deserialisation, message
    objects) is the reference. Two in-process nodes get the same serialised stream (good
    samples, each kind of bad sample, a frame_id change, big-endian messages, which the raw
    path hands to the message path, and stamps jumping back): both publish the same imu/data
    messages, the raw path's bytes being rclpy's encoding of the reference message but for the
    padding after the frame_id; the same aligned flags; the same counters at the end."""
    from rclpy.parameter import Parameter
    from rclpy.serialization import deserialize_message, serialize_message
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    nodes = []
    for path in ("raw", "msg"):
        node = align_node.make_node_class()(
            context=probe.context, namespace=f"/{path}_path_{RUN}",
            parameter_overrides=[Parameter("latitude", value=34.0),
                                 Parameter("grade", value="navigation"),
                                 Parameter("rate", value=RATE),
                                 Parameter("backtrack_time", value=5.0)])
        node.pub_imu, node.pub_aligned = _Published(), _Published()
        nodes.append(node)
    raw_node, msg_node = nodes

    def feed(raws):
        for r in raws:
            raw_node._on_raw(r)
            msg_node._on_imu(deserialize_message(r, Imu))

    def big_endian(r):
        return bytes(ts.serialize_cdr(ts.deserialize_cdr(r, "sensor_msgs/msg/Imu"),
                                      "sensor_msgs/msg/Imu", little_endian=False))

    a = simulate(30.0, rate=RATE, seed=16)
    raws = []
    for k in range(len(a.t)):
        t, w, f = T0 + a.t[k], a.gyro[k], a.accel[k]
        frame = "imu_link" if k < 900 else "imu_b"
        r = serialize_message(_imu(t, w, f, frame))
        raws.append(big_endian(r) if k % 37 == 5 else r)
        slot = k % 100
        if 0 < k < 600 and slot in (3, 7, 11, 15):
            bad = {3: (t + 0.01, [math.nan, 0.0, 0.0], f), 7: (t, w, f), 11: (t - 0.5, w, f),
                   15: (t + 0.01, w, f - np.array([0.0, 0.0, 9.79]))}[slot]
            raws.append(serialize_message(_imu(*bad, frame)))
    try:
        feed(raws)
        assert raw_node.aligner.filter.backtracked and msg_node.aligner.filter.backtracked
        assert raw_node.aligner.rejected == msg_node.aligner.rejected
        assert set(raw_node.aligner.rejected) >= {
            "nonfinite", "duplicate_stamp", "stamp_backwards", "gravity_removed"}
        back = simulate(0.2, rate=RATE, seed=17)
        feed([serialize_message(_imu(T0 + back.t[k], back.gyro[k], back.accel[k], "imu_b"))
              for k in range(len(back.t))])

        got, ref = raw_node.pub_imu, msg_node.pub_imu
        assert len(got) == len(ref) > 1400
        fast = 0
        for out, m in zip(got, ref):
            if isinstance(out, bytes):
                fast += 1
                enc = serialize_message(m)
                pad = slice(17 + len(m.header.frame_id.encode()), len(enc) - 8 * 37)
                assert len(out) == len(enc)
                assert out[:pad.start] == enc[:pad.start] and out[pad.stop:] == enc[pad.stop:]
                out = deserialize_message(out, Imu)
            assert out == m
        assert 0 < fast < len(got), "both paths must have been taken"
        assert ([m.data for m in raw_node.pub_aligned]
                == [m.data for m in msg_node.pub_aligned])
        for name in ("resets", "last_reset_reason"):
            assert getattr(raw_node.session, name) == getattr(msg_node.session, name), name
        assert raw_node.last_header == msg_node.last_header
        assert raw_node.aligner.rejected == msg_node.aligner.rejected
        assert raw_node.session.resets == 1
        assert raw_node.aligner.samples_used == msg_node.aligner.samples_used > 0
    finally:
        for node in nodes:
            node.destroy_node()


def test_imu_sim_node_publishes_rep145_samples_and_truth(probe, tmp_path):
    """imu_sim_node: the simulator's samples (same seed => same numbers as sim.simulate) at
    exact 1/rate stamps starting at the node clock, REP-145 covariances from the specs
    (orientation not provided), the truth on the same stamps; exits 0 when done."""
    ns, rate, duration = f"/sim_{RUN}", 50.0, 4.0
    raw = probe.subscribe(Imu, f"{ns}/imu/data_raw", SENSOR_DEEP)
    truth = probe.subscribe(QuaternionStamped, f"{ns}/imu_sim/truth", RELIABLE_DEEP)
    wall0 = time.time()
    sim = NodeProcess("imu_sim_node", [
        "-r", f"__ns:={ns}", "-p", f"rate:={rate}", "-p", "speed:=10.0",
        "-p", f"duration:={duration}", "-p", "exit_when_done:=true", "-p", "seed:=21",
        "-p", "rpy:=[10.0, -20.0, 135.0]", "-p", "frame_id:=imu_test", "-p", "sway:=car",
        "-p", "wait_for_subscribers:=true"], tmp_path, "sim_t")
    try:
        assert sim.wait(timeout=30) == 0, sim.output()
        n = int(rate * duration)
        wait_until(lambda: len(raw) == n and len(truth) == n, 5.0,
                   f"{n} samples (got {len(raw)}, truth {len(truth)})")
    finally:
        sim.stop()
        probe.unsubscribe(raw)
        probe.unsubscribe(truth)
    ref = simulate(duration, rate=rate, rpy_deg=(10.0, -20.0, 135.0), sway="car", seed=21)
    spec = grade_specs("navigation")
    stamps = [stamp_ns(m.header.stamp) for m in raw.msgs]
    assert np.all(np.diff(stamps) == int(1e9 / rate)), "stamps are not exactly 1/rate apart"
    assert abs(stamps[0] * 1e-9 - wall0) < 10.0, "data time does not start at the node clock"
    assert [stamp_ns(m.header.stamp) for m in truth.msgs] == stamps
    for k, m in enumerate(raw.msgs):
        assert m.header.frame_id == "imu_test"
        w, f = m.angular_velocity, m.linear_acceleration
        assert [w.x, w.y, w.z] == ref.gyro[k].tolist() and [f.x, f.y, f.z] == ref.accel[k].tolist()
        assert m.orientation_covariance[0] == -1.0
        assert np.allclose(np.array(m.angular_velocity_covariance).reshape(3, 3),
                           np.eye(3) * spec.gyro_arw ** 2 * rate, rtol=1e-12, atol=0)
        assert np.allclose(np.array(m.linear_acceleration_covariance).reshape(3, 3),
                           np.eye(3) * spec.accel_vrw ** 2 * rate, rtol=1e-12, atol=0)
        q = truth.msgs[k].quaternion
        assert [q.x, q.y, q.z, q.w] == ref.quat_true[k].tolist()
