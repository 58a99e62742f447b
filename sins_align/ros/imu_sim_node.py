"""imu_sim_node: publish simulated IMU data of a quasi-static base (sim.ImuSimulator) or, with
the ``trajectory`` parameter, of a moving vehicle with GNSS (sim.trajectory).

Topics (relative names)
-----------------------
- pub ``imu/data_raw``  sensor_msgs/Imu (sensor-data QoS) at ``rate`` Hz of data time:
  ``angular_velocity`` rad/s, ``linear_acceleration`` specific force m/s^2 (REP-145),
  ``angular_velocity_covariance`` = diag(arw^2 * rate), ``linear_acceleration_covariance`` =
  diag(vrw^2 * rate) (the white-noise part of the specs), ``orientation_covariance[0] = -1``
  (no orientation).
- pub ``imu_sim/truth`` geometry_msgs/QuaternionStamped, same stamps and frame_id: the true
  C_b^n (IMU frame in ENU, [x, y, z, w]) — what align_node's ``imu/data`` orientation estimates.

With ``trajectory`` set to a preset (car_city, car_straight, ship_under_way, car_with_turn,
uav_seed003) the vehicle moves, starting at ``latitude``/``height``; ``duration`` 0 means the
preset's own (a longer one continues its last commands), and the whole run is simulated at
startup (about 1.1 kB per IMU sample). Also published, at ``gnss_rate`` Hz of data time
(fields from :mod:`sins_align.io.gnss_fields`, as the simulate tool writes them):

- pub ``gnss/fix_velocity`` geometry_msgs/TwistWithCovarianceStamped: antenna velocity in
  ENU (``lever_arm`` m in IMU axes), noise ``gnss_noise`` m/s per axis, covariance
  diag(gnss_noise^2) with the angular part not provided (-1), as ublox_gps;
- pub ``gnss/fix`` sensor_msgs/NavSatFix: antenna position, noise ``gnss_position_noise`` m.

A GNSS message is stamped with its measurement time and published ``gnss_latency`` s of data
time later (after the IMU samples stamped up to then); the node is done once the last one is
out.

Time: stamps are data time, ``t0 + k / rate`` (``t0`` = the node clock at startup unless the
``t0`` parameter is given). ``speed`` data seconds are published per wall second, in batches
from a ``batch_rate`` Hz wall timer. ``duration`` s of data (0 = forever); with
``exit_when_done`` the node exits when done.
"""
from __future__ import annotations

import math
import sys
import time
from types import SimpleNamespace

import numpy as np

from sins_align.ros.params import SIM_PARAMS, param_help, sensor_specs
from sins_align.ros.runtime import (SPIN_PERIOD, build_arg_parser, declare_params, node_main,
                                    refuse_start)

#: The node's name: its executable's (``ros2 param list /imu_sim_node``).
NODE_NAME = "imu_sim_node"


class TrajectoryStream:
    """A moving-vehicle run (sim.trajectory), simulated at once and served in blocks as
    ``ImuSimulator.next_block`` serves its samples, with its GNSS epochs (numpy only).

    Attributes: ``result`` (the TrajectoryResult), ``specs``, ``total`` (IMU samples),
    ``imu_ns`` (each sample's stamp after t0, int ns), ``gnss_ns`` and ``arrival_ns`` (each
    GNSS epoch's stamp and delivery time after t0, int ns).
    """

    def __init__(self, v: dict, specs):
        from sins_align.core.rotation import quat_from_dcm
        from sins_align.io.gnss_fields import epoch_stamps_ns
        from sins_align.io.imu_fields import stamp_ns
        from sins_align.sim.trajectory import simulate_trajectory, trajectory_preset

        if any(v["rpy"]) or v["sway"] != "none" or v["sway_amplitude"] != 1.0:
            raise ValueError("rpy, sway and sway_amplitude do not apply with a trajectory "
                             "(the preset sets the motion)")
        if abs(v["latitude"]) > 85.0:
            raise ValueError(f"latitude must be within [-85, 85] deg with a trajectory, got "
                             f"{v['latitude']:g}")
        traj = trajectory_preset(v["trajectory"], lat_deg=v["latitude"], height_m=v["height"])
        self.rate = v["rate"]
        self.specs = specs
        self.result = r = simulate_trajectory(
            traj, self.rate, specs=specs, seed=None if v["seed"] < 0 else int(v["seed"]),
            gnss_rate=v["gnss_rate"], gnss_sigma=v["gnss_noise"], lever_arm=v["lever_arm"],
            duration=v["duration"] if v["duration"] > 0 else None,
            gnss_latency=v["gnss_latency"], gnss_pos_sigma=v["gnss_position_noise"])
        self.total = len(r.gyro)
        self.t = np.arange(1, self.total + 1) / self.rate
        self.imu_ns = np.rint(self.t * 1e9).astype(np.int64)
        self.quat = quat_from_dcm(r.C[1:])
        self.gnss_ns = epoch_stamps_ns(0, self.rate, r.gnss_index)
        self.arrival_ns = self.gnss_ns + stamp_ns(v["gnss_latency"])
        self.sigma = (v["gnss_noise"], v["gnss_position_noise"])
        self.pos = 0

    def next_block(self, n: int):
        a, b = self.pos, min(self.pos + n, self.total)
        self.pos = b
        r = self.result
        return SimpleNamespace(t=self.t[a:b], gyro=r.gyro[a:b], accel=r.accel[a:b],
                               quat_true=self.quat[a:b])

    def gnss(self, j: int, t0_ns: int):
        """The GnssFields of epoch j with the data-time origin t0_ns."""
        from sins_align.io.gnss_fields import GNSS_FRAME, gnss_fields

        r = self.result
        return next(gnss_fields(t0_ns + self.gnss_ns[j:j + 1], t0_ns + self.arrival_ns[j:j + 1],
                                r.gnss_v[j:j + 1], r.gnss_llh[j:j + 1], *self.sigma,
                                r.gnss_vertical, GNSS_FRAME))


def make_node_class():
    """Define the rclpy node class (rclpy is imported only after --help was handled)."""
    from geometry_msgs.msg import QuaternionStamped, TwistWithCovarianceStamped
    from rclpy.clock import Clock, ClockType
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from rclpy.task import Future
    from sensor_msgs.msg import Imu, NavSatFix

    from sins_align.io.gnss_fields import (GNSS_FIX_TOPIC, GNSS_VELOCITY_TOPIC, SERVICE_GPS,
                                           STATUS_FIX)

    from sins_align.sim.simulator import ImuSimulator

    class ImuSimNode(Node):
        """Publishes ImuSimulator samples in data time, ``speed`` x faster than wall time."""

        def __init__(self, **kwargs):
            super().__init__(NODE_NAME, **kwargs)
            # statically typed from the schema: rate:=100 is the double 100.0
            values, reason = declare_params(self, SIM_PARAMS)
            sim = None
            if reason is None:
                try:
                    sim = self._make_sim(values)
                except ValueError as e:
                    reason = str(e)
            if reason is not None:
                refuse_start(self, reason)
            self.p = values
            self.sim = sim
            self.done = Future()
            rate = values["rate"]
            self.moving = sim if isinstance(sim, TrajectoryStream) else None
            self.total = (sim.total if self.moving is not None       # 0 = forever
                          else int(math.floor(values["duration"] * rate + 1e-9)))
            self.gnss_next = 0
            t0 = values["t0"]
            self.t0_ns = (self.get_clock().now().nanoseconds if t0 < 0
                          else int(round(t0 * 1e9)))
            sp = sim.specs
            self.cov_w = [0.0] * 9
            self.cov_f = [0.0] * 9
            for i in (0, 4, 8):
                self.cov_w[i] = sp.gyro_arw ** 2 * rate
                self.cov_f[i] = sp.accel_vrw ** 2 * rate
            self.pub = self.create_publisher(Imu, "imu/data_raw", qos_profile_sensor_data)
            self.pub_truth = (self.create_publisher(QuaternionStamped, "imu_sim/truth", 10)
                              if values["publish_truth"] else None)
            self.pub_vel = self.pub_fix = None
            if self.moving is not None:
                self.pub_vel = self.create_publisher(TwistWithCovarianceStamped,
                                                     GNSS_VELOCITY_TOPIC, 10)
                self.pub_fix = self.create_publisher(NavSatFix, GNSS_FIX_TOPIC, 10)
            self.wall0 = None if values["wait_for_subscribers"] else time.monotonic()
            self.emitted = 0
            steady = Clock(clock_type=ClockType.STEADY_TIME)
            self.timer = self.create_timer(1.0 / values["batch_rate"], self._tick, clock=steady)
            motion = (f"rpy {values['rpy']} deg, sway {values['sway']}" if self.moving is None
                      else f"trajectory {values['trajectory']} with GNSS at "
                      f"{values['gnss_rate']:g} Hz (latency {values['gnss_latency']:g} s)")
            self.get_logger().info(
                f"publishing {rate:g} Hz x speed {values['speed']:g}, {motion}, "
                f"latitude {values['latitude']:g} deg, grade {values['grade']}, "
                + (f"{self.total / rate:g} s of data" if self.total else "until stopped"))

        @staticmethod
        def _make_sim(v):
            if v["trajectory"]:
                return TrajectoryStream(v, sensor_specs(v))
            return ImuSimulator(rate=v["rate"], lat_deg=v["latitude"], height_m=v["height"],
                                rpy_deg=v["rpy"], specs=sensor_specs(v), sway=v["sway"],
                                sway_amplitude=v["sway_amplitude"],
                                seed=None if v["seed"] < 0 else int(v["seed"]))

        def _tick(self):
            rate, speed = self.p["rate"], self.p["speed"]
            if self.wall0 is None:
                if self.pub.get_subscription_count() == 0 or any(
                        p is not None and p.get_subscription_count() == 0
                        for p in (self.pub_truth, self.pub_vel)):
                    return
                self.wall0 = time.monotonic()
                if self.p["t0"] < 0:
                    self.t0_ns = self.get_clock().now().nanoseconds
                self.get_logger().info("subscribers present: starting")
            data_s = (time.monotonic() - self.wall0) * speed
            due = int(data_s * rate)
            if self.total:
                due = min(due, self.total)
            if self.moving is not None:
                self._publish_gnss_until(int(data_s * 1e9), due)
            n = due - self.emitted
            if n > 0:
                self._publish(self.sim.next_block(n))
                self.emitted = due
            gnss_done = self.moving is None or self.gnss_next >= len(self.moving.arrival_ns)
            if self.total and self.emitted >= self.total and gnss_done \
                    and not self.done.done():
                self.get_logger().info(
                    f"done: {self.emitted} samples ({self.emitted / rate:g} s of data)")
                self.destroy_timer(self.timer)
                if self.p["exit_when_done"]:
                    # let the last messages go out before the process exits
                    self._exit_timer = self.create_timer(0.5, self._finish)

        def _publish_gnss_until(self, now_ns: int, due: int):
            """Publish the GNSS epochs delivered by data time ``now_ns`` (after t0), each after
            the IMU samples (below ``due``) stamped up to its delivery time."""
            ms = self.moving
            while self.gnss_next < len(ms.arrival_ns) and ms.arrival_ns[self.gnss_next] <= now_ns:
                j = self.gnss_next
                k = min(due, int(np.searchsorted(ms.imu_ns, ms.arrival_ns[j], side="right")))
                if k > self.emitted:
                    self._publish(self.sim.next_block(k - self.emitted))
                    self.emitted = k
                f = ms.gnss(j, self.t0_ns)
                v = TwistWithCovarianceStamped()
                v.header.stamp.sec, v.header.stamp.nanosec = f.sec, f.nanosec
                v.header.frame_id = f.frame_id
                lin = v.twist.twist.linear
                lin.x, lin.y, lin.z = f.velocity_enu
                v.twist.covariance = list(f.velocity_covariance)
                self.pub_vel.publish(v)
                fx = NavSatFix()
                fx.header = v.header
                fx.status.status, fx.status.service = STATUS_FIX, SERVICE_GPS
                fx.latitude, fx.longitude, fx.altitude = (f.latitude_deg, f.longitude_deg,
                                                          f.altitude_m)
                fx.position_covariance = list(f.position_covariance)
                fx.position_covariance_type = f.position_covariance_type
                self.pub_fix.publish(fx)
                self.gnss_next = j + 1

        def _finish(self):
            self.destroy_timer(self._exit_timer)
            self.done.set_result(True)

        def _publish(self, blk):
            frame = self.p["frame_id"]
            t0 = self.t0_ns
            for k in range(len(blk.t)):
                ns = t0 + int(round(blk.t[k] * 1e9))
                m = Imu()
                m.header.stamp.sec, m.header.stamp.nanosec = divmod(ns, 1_000_000_000)
                m.header.frame_id = frame
                m.orientation_covariance[0] = -1.0
                w, f = blk.gyro[k], blk.accel[k]
                m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = \
                    float(w[0]), float(w[1]), float(w[2])
                m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = \
                    float(f[0]), float(f[1]), float(f[2])
                m.angular_velocity_covariance = self.cov_w
                m.linear_acceleration_covariance = self.cov_f
                self.pub.publish(m)
                if self.pub_truth is not None:
                    q = blk.quat_true[k]
                    tm = QuaternionStamped()
                    tm.header = m.header
                    tm.quaternion.x, tm.quaternion.y, tm.quaternion.z, tm.quaternion.w = \
                        float(q[0]), float(q[1]), float(q[2]), float(q[3])
                    self.pub_truth.publish(tm)

    return ImuSimNode


def main(args: list[str] | None = None) -> int:
    """Entry point of ``imu_sim_node`` / ``python -m sins_align.ros.imu_sim_node``."""
    parser = build_arg_parser(
        "imu_sim_node",
        "Simulated IMU on a quasi-static base: publishes imu/data_raw (sensor_msgs/Imu) and "
        "the true attitude on imu_sim/truth (geometry_msgs/QuaternionStamped); with "
        "trajectory:=NAME a moving vehicle, plus gnss/fix_velocity "
        "(geometry_msgs/TwistWithCovarianceStamped, ENU) and gnss/fix (sensor_msgs/NavSatFix).",
        param_help(SIM_PARAMS, "parameters (all read-only; --ros-args -p name:=value):")
        + "\n\nexample:\n  ros2 run sins_align imu_sim_node --ros-args "
        "-p rpy:='[2.0, -1.0, 30.0]' -p speed:=5.0 -p sway:=car\n"
        "  ros2 run sins_align imu_sim_node --ros-args -p trajectory:=car_city "
        "-p gnss_latency:=0.1 -p lever_arm:='[0.5, 0.0, 1.2]'")
    return node_main("imu_sim_node", parser, args, make_node_class, spin_until_done)


def spin_until_done(node, stop) -> None:
    """Spin ``node`` until it is done (``exit_when_done``), ``stop`` is set (SIGINT, SIGTERM,
    SIGHUP) or its context shuts down."""
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        while node.context.ok() and not stop.is_set() and not node.done.done():
            executor.spin_once(timeout_sec=SPIN_PERIOD)
    finally:
        executor.shutdown()


if __name__ == "__main__":
    sys.exit(main())
