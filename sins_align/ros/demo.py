"""demo: align a simulated IMU from a wildly wrong initial attitude, live over ROS 2.

Starts ``imu_sim_node`` and ``align_node`` as child processes (``python -m ...``) on a private
ROS domain (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, random ``ROS_DOMAIN_ID`` unless
``--domain-id``), listens to ``imu/data``, ``imu_sim/truth`` and ``alignment/aligned``, prints
the attitude error against the truth as the data comes in, and ends with a one-line verdict.

Exit status: 0 when the node claimed ``aligned`` and its error is inside 3 sigma of its own
published covariance; 1 otherwise (not aligned in time, or aligned but wrong).
"""
from __future__ import annotations

import argparse
import math
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sins_align.core.rotation import (attitude_error, dcm_from_quat, heading_from_dcm, rpy_from_dcm,
                                      wrap_angle)

DEG = math.pi / 180.0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="demo", description=__doc__.split("\n\n")[0] + "\n\n" + __doc__.split("\n\n")[1],
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rpy", type=float, nargs=3, default=(2.0, -1.0, 30.0),
                   metavar=("R", "P", "Y"), help="true REP-103 roll pitch yaw, deg "
                   "(default 2 -1 30)")
    p.add_argument("--initial-rpy", type=float, nargs=3, default=(180.0, 0.0, -150.0),
                   metavar=("R", "P", "Y"), help="the node's initial guess, deg (default "
                   "180 0 -150: upside down and facing backwards)")
    p.add_argument("--latitude", type=float, default=34.0, help="deg (default 34)")
    p.add_argument("--rate", type=float, default=100.0, help="IMU rate, Hz (default 100)")
    p.add_argument("--speed", type=float, default=4.0,
                   help="data seconds per wall second (default 4)")
    p.add_argument("--sway", default="none", choices=("none", "car", "ship"),
                   help="base motion preset (default none)")
    p.add_argument("--after", type=float, default=90.0,
                   help="data seconds to keep going after the aligned flag (default 90)")
    p.add_argument("--max-data", type=float, default=300.0,
                   help="give up after this many data seconds (default 300)")
    p.add_argument("--every", type=float, default=10.0,
                   help="data seconds between table rows (default 10)")
    p.add_argument("--seed", type=int, default=7, help="simulator seed (default 7)")
    p.add_argument("--domain-id", type=int, default=None,
                   help="ROS_DOMAIN_ID to use (default: random 102..232)")
    return p


class _Child:
    """A node started as ``python -m sins_align.<module>``, logging to a file."""

    def __init__(self, module: str, ros_args: list[str], log_dir: Path, env: dict):
        self.name = module
        self.log_path = log_dir / f"{module}.log"
        self._log = open(self.log_path, "w")
        cmd = [sys.executable, "-m", f"sins_align.{module}", "--ros-args", *ros_args]
        self.proc = subprocess.Popen(cmd, env=env, stdout=self._log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL)

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()

    def tail(self, n: int = 8) -> str:
        lines = self.log_path.read_text(errors="replace").splitlines()[-n:]
        return "\n".join(f"    {self.name}| {ln}" for ln in lines)


def _p(v) -> str:
    return "[" + ",".join(f"{x:g}" for x in v) + "]"


class _Monitor:
    """Subscribes to the node's outputs and the truth; computes the error of the latest sample."""

    def __init__(self, node):
        from rclpy.qos import (DurabilityPolicy, QoSProfile, ReliabilityPolicy,
                               qos_profile_sensor_data)
        from geometry_msgs.msg import QuaternionStamped
        from sensor_msgs.msg import Imu
        from std_msgs.msg import Bool

        self.truth: dict[int, tuple] = {}
        self.latest = None          # (stamp ns, quat xyzw, cov 9)
        self.recent: dict[int, tuple] = {}
        self.aligned: bool | None = None
        self.t_first_ns: int | None = None
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(Imu, "imu/data", self._on_imu, qos_profile_sensor_data)
        node.create_subscription(QuaternionStamped, "imu_sim/truth", self._on_truth, 200)
        node.create_subscription(Bool, "alignment/aligned", self._on_aligned, latched)

    @staticmethod
    def _ns(stamp) -> int:
        return stamp.sec * 1_000_000_000 + stamp.nanosec

    def _on_truth(self, m):
        ns = self._ns(m.header.stamp)
        q = m.quaternion
        self.truth[ns] = (q.x, q.y, q.z, q.w)
        if len(self.truth) > 4000:
            for k in sorted(self.truth)[:2000]:
                del self.truth[k]

    def _on_imu(self, m):
        ns = self._ns(m.header.stamp)
        if self.t_first_ns is None:
            self.t_first_ns = ns
        q = m.orientation
        self.latest = (ns, (q.x, q.y, q.z, q.w), tuple(m.orientation_covariance))
        self.recent[ns] = self.latest
        if len(self.recent) > 400:
            for k in sorted(self.recent)[:200]:
                del self.recent[k]

    def _on_aligned(self, m):
        self.aligned = bool(m.data)

    def data_time(self) -> float | None:
        if self.latest is None:
            return None
        return (self.latest[0] - self.t_first_ns) * 1e-9

    def errors(self):
        """(data time, roll/pitch/heading error deg, level error deg, std E/N/U deg) or None."""
        both = [ns for ns in self.recent if ns in self.truth]
        if not both:
            return None
        ns, q, cov = self.recent[max(both)]
        qt = self.truth[ns]
        Ce, Ct = dcm_from_quat(np.array(q)), dcm_from_quat(np.array(qt))
        d_rpy = wrap_angle(rpy_from_dcm(Ce) - rpy_from_dcm(Ct)) / DEG
        d_head = float(wrap_angle(heading_from_dcm(Ce) - heading_from_dcm(Ct))) / DEG
        phi = attitude_error(Ct, Ce) / DEG
        std = np.sqrt(np.maximum(np.diag(np.array(cov).reshape(3, 3)), 0.0)) / DEG
        return ((ns - self.t_first_ns) * 1e-9, d_rpy[0], d_rpy[1], d_head,
                float(math.hypot(phi[0], phi[1])), std)


def main(args: list[str] | None = None) -> int:
    """Run the demo; returns the exit status."""
    a = _parser().parse_args(args)
    domain = a.domain_id if a.domain_id is not None else random.randint(102, 232)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    env = dict(os.environ)

    import rclpy
    from rclpy.executors import ExternalShutdownException

    log_dir = Path(tempfile.mkdtemp(prefix="sins_align_demo_"))
    print(f"sins_align demo — ROS_DOMAIN_ID={domain}, logs in {log_dir}")
    print(f"  truth rpy {_p(a.rpy)} deg, the node starts from {_p(a.initial_rpy)} deg; "
          f"latitude {a.latitude:g} deg, navigation-grade IMU, {a.rate:g} Hz, sway {a.sway}, "
          f"data at {a.speed:g}x real time")
    rclpy.init(args=[])
    node = rclpy.create_node("sins_align_demo")
    mon = _Monitor(node)
    children: list[_Child] = []
    ok = False
    try:
        children.append(_Child("align_node", [
            "-p", f"latitude:={a.latitude}", "-p", "grade:=navigation",
            "-p", f"initial_rpy:={_p(a.initial_rpy)}",
            "-p", f"rate:={a.rate}"], log_dir, env))
        t_wall = time.monotonic()
        while mon.aligned is None:       # the latched 'false' says the node is up
            rclpy.spin_once(node, timeout_sec=0.1)
            if children[0].proc.poll() is not None or time.monotonic() - t_wall > 30:
                print("align_node did not come up:\n" + children[0].tail())
                return 1
        children.append(_Child("imu_sim_node", [
            "-p", f"latitude:={a.latitude}", "-p", f"rpy:={_p(a.rpy)}", "-p", f"rate:={a.rate}",
            "-p", f"speed:={a.speed}", "-p", f"sway:={a.sway}", "-p", f"seed:={a.seed}",
            "-p", f"duration:={a.max_data}", "-p", "exit_when_done:=true",
            "-p", "wait_for_subscribers:=true"], log_dir, env))
        ok = _run(a, node, mon, children, rclpy)
    except (KeyboardInterrupt, ExternalShutdownException):
        print("interrupted")
    finally:
        for c in reversed(children):
            c.stop()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0 if ok else 1


def _run(a, node, mon: _Monitor, children: list[_Child], rclpy) -> bool:
    print(f"{'data s':>7} {'roll err':>9} {'pitch err':>9} {'head err':>9} {'level err':>9} "
          f"{'std lvl':>8} {'std head':>8}  aligned")
    t_wall0 = time.monotonic()
    wall_limit = a.max_data / a.speed + 30.0
    next_row = 0.0
    t_aligned = None
    last = None
    while True:
        rclpy.spin_once(node, timeout_sec=0.05)
        dt = mon.data_time()
        if dt is not None and dt >= next_row:
            e = mon.errors()
            if e is not None and e[0] >= next_row - 0.5 / a.rate:
                last = e
                t, dr, dp, dh, lvl, std = e
                print(f"{t:7.1f} {dr:9.4f} {dp:9.4f} {dh:9.4f} {lvl:9.4f} "
                      f"{max(std[0], std[1]):8.4f} {std[2]:8.4f}  {mon.aligned}", flush=True)
                while next_row <= t + 0.5 / a.rate:
                    next_row += a.every
        if mon.aligned and t_aligned is None and dt is not None:
            t_aligned = dt
            print(f"{dt:7.1f}  -- alignment/aligned: true --", flush=True)
        if t_aligned is not None and dt is not None and dt >= t_aligned + a.after:
            break
        if any(c.proc.poll() is not None for c in children):
            if children[0].proc.poll() is not None:
                print("align_node exited unexpectedly:\n" + children[0].tail())
                return False
            break                        # the simulator finished max_data
        if time.monotonic() - t_wall0 > wall_limit:
            print("wall-clock limit reached")
            break
    wall = time.monotonic() - t_wall0
    e = mon.errors() or last
    if e is None:
        print("NOT ALIGNED: no output from align_node\n" + children[0].tail())
        return False
    t, dr, dp, dh, lvl, std = e
    slvl, shead = max(std[0], std[1]), std[2]
    if not mon.aligned or t_aligned is None:
        print(f"NOT ALIGNED after {t:.0f} s data time: heading error {dh:.3f} deg "
              f"(std {shead:.3f}), level {lvl:.4f} deg")
        return False
    honest = abs(dh) <= 3.0 * shead and lvl <= 3.0 * math.sqrt(2.0) * slvl
    word = "ALIGNED" if honest else "ALIGNED BUT OUTSIDE 3 SIGMA"
    print(f"{word} in {t_aligned:.0f} s data time ({wall:.0f} s wall): heading error "
          f"{dh:.3f} deg (std {shead:.3f}), level {lvl:.4f} deg (std {slvl:.4f}) "
          f"at {t:.0f} s")
    return honest


if __name__ == "__main__":
    sys.exit(main())
