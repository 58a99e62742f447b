#!/usr/bin/env python3
"""How fast can align_node go? A script that prints figures (not a test).

For each IMU rate (100, 400, 1000, 2000 Hz) a publisher process sends ~10 s of simulated
sensor_msgs/Imu at that rate (wall clock) to a fresh ``python -m sins_align.ros.align_node``;
this script counts the ``imu/data`` messages that come back and reads the node's CPU time
from ``/proc/<pid>/stat`` (utime + stime). A rate is *sustained* when every input came back.
Columns: ``used`` the samples the node's diagnostics count as used, plus the first one (the
time anchor, republished too): below ``sent`` the loss was on the way in, below it ``out``
on the way out; node CPU as % of one core and per input message (µs); the whole machine's
busy CPU over the trial (% of one core, 200 = both cores): publisher, node and this script's
counting subscriber share the machine, and other load there shows up in that column.

Two phases of the filter are measured:
- coarse: backtrack_time 60 s, so the whole run is the coarse pass (a Kalman update at
  every sample: the most expensive steady state);
- fine: backtrack_time 5 s, so the run contains the backtrack (the buffer re-processed in
  one go, a pause the subscription queue must absorb) and then the fine pass.

A third row per rate, ``floor``, runs the same harness around a minimal rclpy node
(``--floor``): it takes the serialised Imu with align_node's QoS and EventsExecutor and
publishes the same bytes back, nothing else. Its µs per message is what rclpy and Fast DDS
cost on this machine in the same minutes, whatever the callback does.

``--callback`` measures, instead, the node's own part in-process (no DDS): a node's ``_on_raw``
is fed 10 s of serialised 2 kHz messages (publishing to no subscriber) and timed per call,
coarse and fine pass, with a second pass timing its parts (reading the bytes, the
estimator's update, the published orientation and covariance, writing the bytes, publishing
and the flag).

Usage: ``.venv/bin/python test/benchmarks/bench_node.py [--rates 100 400] [--duration 10]``
(``make bench`` runs it); ``... bench_node.py --callback``. Uses its own ROS_DOMAIN_ID (random)
on localhost.
"""
from __future__ import annotations

import argparse
import json
import os
import queue
import random
import subprocess
import sys
import threading
import time
from pathlib import Path

NS = "/bench"
#: issue 14: node CPU per message at 2 kHz, coarse and fine pass, no message lost
TARGET_US_PER_MSG = 100.0
CLK_TCK = os.sysconf("SC_CLK_TCK")


def machine_busy_seconds() -> float:
    """CPU seconds the whole machine spent outside idle and iowait (first line of /proc/stat:
    user nice system idle iowait irq softirq steal, then guest times already in user)."""
    ticks = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:9]]
    return (sum(ticks) - ticks[3] - ticks[4]) / CLK_TCK


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process, s (fields 14 and 15 of /proc/<pid>/stat)."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2:].split()   # after "pid (comm) "
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


# ------------------------------------------------------------------------------ publisher
def publisher(rate: float, duration: float) -> None:
    """Child process: publish ``duration`` s of IMU samples at ``rate`` Hz of wall time."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu

    from sins_align.sim.simulator import simulate

    sim = simulate(duration, rate=rate, seed=1)
    t0 = 1_700_000_000
    msgs = []
    for k in range(len(sim.t)):
        m = Imu()
        m.header.frame_id = "imu_link"
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(
            t0 * 1_000_000_000 + int(round(sim.t[k] * 1e9)), 1_000_000_000)
        m.orientation_covariance[0] = -1.0
        w, f = sim.gyro[k], sim.accel[k]
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = map(float, w)
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = map(float, f)
        msgs.append(m)
    rclpy.init(args=[])
    node = rclpy.create_node("bench_publisher")
    pub = node.create_publisher(Imu, f"{NS}/imu/data_raw", qos_profile_sensor_data)
    deadline = time.monotonic() + 30.0
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)
    print(json.dumps({"ready": True}), flush=True)
    sys.stdin.readline()                       # "go" from the parent
    start = time.monotonic()
    sent = 0
    while sent < len(msgs):
        due = min(len(msgs), int((time.monotonic() - start) * rate) + 1)
        while sent < due:
            pub.publish(msgs[sent])
            sent += 1
        time.sleep(0.0005)
    wall = time.monotonic() - start
    print(json.dumps({"sent": sent, "wall": wall}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


# ------------------------------------------------------------------------------ the floor
def floor_node() -> None:
    """Child process: the least an rclpy node can do with align_node's traffic. Takes the
    serialised Imu (raw, align_node's QoS, EventsExecutor) and publishes the same bytes on
    ``imu/data``; latches ``alignment/aligned`` once so the harness sees it up; counts
    ``samples_used`` in diagnostics every second like the node. Stops on SIGINT."""
    import signal

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.experimental.events_executor import EventsExecutor
    from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                           qos_profile_sensor_data)
    from sensor_msgs.msg import Imu
    from std_msgs.msg import Bool

    rclpy.init(args=sys.argv)
    node = rclpy.create_node("bench_align", namespace=NS)
    depth = 1000
    qos_in = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                        reliability=qos_profile_sensor_data.reliability,
                        durability=qos_profile_sensor_data.durability)
    pub = node.create_publisher(Imu, "imu/data", depth)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_publisher(Bool, "alignment/aligned", latched).publish(Bool(data=False))
    diag = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
    count = [0]

    def on_raw(data: bytes) -> None:
        count[0] += 1
        pub.publish(data)

    def on_timer() -> None:
        st = DiagnosticStatus(name="bench_align: alignment",
                              values=[KeyValue(key="samples_used", value=str(count[0] - 1))])
        diag.publish(DiagnosticArray(status=[st]))

    node.create_subscription(Imu, "imu/data_raw", on_raw, qos_in, raw=True)
    node.create_timer(1.0, on_timer)
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    ex = EventsExecutor(context=node.context)
    ex.add_node(node)
    while not stop:
        ex.spin_once(timeout_sec=0.1)
    ex.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()


# ------------------------------------------------------------------------------ in-process
def callback_cost(rate: float = 2000.0, duration: float = 10.0) -> None:
    """The node's callback alone: ``_on_raw`` on serialised messages, coarse and fine pass
    (backtrack at 60 s / 5 s; the fine figures from the samples after the backtrack), CPU
    µs per call; then its parts, timed with process_time in a second node."""
    import numpy as np
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Imu

    from sins_align.ros.align_node import make_node_class
    from sins_align.ros.outputs import imu_output_list
    from sins_align.sim.simulator import simulate

    sim = simulate(duration, rate=rate, seed=1)
    raws = []
    for k in range(len(sim.t)):
        m = Imu()
        m.header.frame_id = "imu_link"
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(
            1_700_000_000 * 1_000_000_000 + int(round(sim.t[k] * 1e9)), 1_000_000_000)
        m.orientation_covariance[0] = -1.0
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = map(float, sim.gyro[k])
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = map(
            float, sim.accel[k])
        raws.append(serialize_message(m))
    rclpy.init(args=[])
    Node = make_node_class()
    print(f"align_node callback in-process, {len(raws)} messages at {rate:g} Hz")
    for phase, backtrack in (("coarse", 60.0), ("fine", 5.0)):
        start = 0 if backtrack > duration else int((backtrack + 0.5) * rate)
        nodes = [Node(namespace=f"/callback_{phase}_{i}",
                      parameter_overrides=[Parameter("latitude", value=34.0),
                                           Parameter("rate", value=rate),
                                           Parameter("backtrack_time", value=backtrack)])
                 for i in range(2)]
        node = nodes[0]
        for r in raws[:start]:
            node._on_raw(r)
        c0 = time.process_time()
        for r in raws[start:]:
            node._on_raw(r)
        per_call = 1e6 * (time.process_time() - c0) / (len(raws) - start)
        node = nodes[1]                        # the parts, as _on_raw runs them
        node._on_raw(raws[0])
        lay, al, pc = node._layout, node.aligner, time.process_time
        parts = np.zeros(4)
        for i, r in enumerate(raws[1:], 1):
            a = pc()
            sec, nanosec, w, f = lay.read(r)
            t, w, f = node.stamp_clock(sec, nanosec), np.array(w), np.array(f)
            b = pc()
            ok = node.session.feed(t, w, f)
            c = pc()
            values = imu_output_list(al)
            d = pc()
            if ok:
                node.pub_imu.publish(lay.with_orientation(r, values))
            node._publish_aligned()
            e = pc()
            if i >= start:
                parts += (b - a, c - b, d - c, e - d)
        parts *= 1e6 / (len(raws) - max(start, 1))
        print(f"{phase:<7} _on_raw {per_call:6.1f} µs CPU per call; parts (CPU): read "
              f"{parts[0]:.1f}, estimator update {parts[1]:.1f}, orientation + covariance "
              f"{parts[2]:.1f}, bytes + publish + flag {parts[3]:.1f} µs", flush=True)
        for n in nodes:
            n.destroy_node()
    rclpy.try_shutdown()


# ------------------------------------------------------------------------------ one trial
def trial(rate: float, duration: float, backtrack: float | None, env: dict) -> dict:
    """One rate through align_node (``backtrack`` s) or, with ``backtrack=None``, through
    the floor node."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu
    from std_msgs.msg import Bool

    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=[])
    probe = rclpy.create_node("bench_probe", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(probe)
    got = {"out": 0, "aligned": None, "diag": None}

    def on_out(_m):
        got["out"] += 1

    def on_diag(arr):
        for st in arr.status:
            if st.name == "bench_align: alignment":
                got["diag"] = {kv.key: kv.value for kv in st.values}

    probe.create_subscription(Imu, f"{NS}/imu/data", on_out,
                              QoSProfile(depth=20000, reliability=ReliabilityPolicy.RELIABLE))
    probe.create_subscription(
        Bool, f"{NS}/alignment/aligned", lambda m: got.__setitem__("aligned", m.data),
        QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL))
    probe.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)

    def spin_for(seconds: float):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.01)

    cmd = ([sys.executable, __file__, "--floor-node"] if backtrack is None else
           [sys.executable, "-m", "sins_align.ros.align_node", "--ros-args", "-r",
            f"__ns:={NS}", "-r", "__node:=bench_align", "-p", "latitude:=34.0", "-p",
            "grade:=navigation", "-p", f"rate:={rate}", "-p", f"backtrack_time:={backtrack}"])
    node = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    pub = subprocess.Popen([sys.executable, __file__, "--publish", str(rate), str(duration)],
                           env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + 30
        while got["aligned"] is None and time.monotonic() < end:
            spin_for(0.1)
        while probe.count_publishers(f"{NS}/imu/data") == 0 and time.monotonic() < end:
            spin_for(0.1)
        assert json.loads(pub.stdout.readline())["ready"]
        spin_for(1.0)
        cpu0, box0, t0 = cpu_seconds(node.pid), machine_busy_seconds(), time.monotonic()
        pub.stdin.write("go\n")
        pub.stdin.flush()
        # spin while the publisher runs (it prints its summary when done)
        lines: queue.Queue = queue.Queue()
        threading.Thread(target=lambda: lines.put(pub.stdout.readline()), daemon=True).start()
        while lines.empty():
            spin_for(0.05)
        info = json.loads(lines.get())
        # drain: wait until the output stops growing (the node may be behind)
        still = 0.0
        while still < 1.0 and time.monotonic() - t0 < duration * 6 + 30:
            n = got["out"]
            spin_for(0.2)
            still = still + 0.2 if got["out"] == n else 0.0
        t1 = time.monotonic() - still
        cpu = cpu_seconds(node.pid) - cpu0
        box = (machine_busy_seconds() - box0) / (time.monotonic() - t0)
        spin_for(1.2)                            # one more diagnostics message
        d = got["diag"] or {}
        return {"rate": rate, "sent": info["sent"], "out": got["out"],
                "used": int(d.get("samples_used", 0)),
                "pub_rate": info["sent"] / info["wall"],
                "lag": max(0.0, (t1 - t0) - info["wall"]),
                "cpu": 100.0 * cpu / (t1 - t0), "us_per_msg": 1e6 * cpu / info["sent"],
                "box": 100.0 * box, "stage": d.get("stage", "?")}
    finally:
        for p in (pub, node):
            if p.poll() is None:
                p.send_signal(2)
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
        probe.destroy_node()
        rclpy.try_shutdown(context=ctx)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rates", type=float, nargs="+", default=[100, 400, 1000, 2000])
    ap.add_argument("--duration", type=float, default=10.0, help="s of publishing per trial")
    ap.add_argument("--no-floor", action="store_true",
                    help="skip the floor rows (a raw take-and-republish node, no estimator)")
    ap.add_argument("--callback", action="store_true",
                    help="time the node's callback in-process instead (no DDS, 2 kHz)")
    ap.add_argument("--publish", type=float, nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--floor-node", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.publish:
        publisher(*a.publish)
        return 0
    if a.floor_node:
        floor_node()
        return 0
    if a.callback:
        callback_cost(duration=a.duration)
        return 0
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.setdefault("ROS_DOMAIN_ID", str(random.randint(102, 232)))
    os.environ.update(env)
    print(f"align_node throughput, {a.duration:g} s per trial, {os.cpu_count()} CPUs, "
          f"ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']}")
    print(f"{'phase':<7}{'rate Hz':>8}{'sent':>7}{'used':>7}{'out':>7}{'lost':>6}{'pub Hz':>8}"
          f"{'lag s':>7}{'CPU %':>7}{'µs/msg':>7}{'box %':>7}  result")
    best, worst_us = {}, {}
    phases = [("coarse", 60.0), ("fine", 5.0)] + ([] if a.no_floor else [("floor", None)])
    for phase, backtrack in phases:
        for rate in a.rates:
            r = trial(rate, a.duration, backtrack, env)
            lost = r["sent"] - r["out"]
            ok = lost == 0 and r["lag"] < 1.0
            if ok:
                best[phase] = max(best.get(phase, 0), rate)
            if rate == 2000:
                worst_us[phase] = r["us_per_msg"] if ok else float("inf")
            verdict = "sustained" if ok else (
                f"NOT sustained ({lost} lost)" if lost else "NOT sustained (falls behind)")
            print(f"{phase:<7}{rate:>8g}{r['sent']:>7}{r['used'] + 1:>7}{r['out']:>7}{lost:>6}"
                  f"{r['pub_rate']:>8.0f}{r['lag']:>7.1f}{r['cpu']:>7.0f}{r['us_per_msg']:>7.0f}"
                  f"{r['box']:>7.0f}  {verdict}",
                  flush=True)
    for phase, us in worst_us.items():
        if phase == "floor":
            print(f"rclpy floor (raw take + republish, no estimator) at 2000 Hz: {us:.0f} µs "
                  f"per message, measured in the same minutes")
            continue
        print(f"node CPU per message at 2000 Hz, {phase} pass: {us:.0f} µs "
              f"(target <= {TARGET_US_PER_MSG:.0f} µs, no message lost)")
    for phase in ("coarse", "fine"):
        print(f"highest sustained rate, {phase} pass: "
              f"{best.get(phase, 0):g} Hz" if phase in best else
              f"highest sustained rate, {phase} pass: none of {a.rates}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
