"""imu_sim_node: publish simulated IMU data of a quasi-static base (sim.ImuSimulator).

Topics (relative names)
-----------------------
- pub ``imu/data_raw``  sensor_msgs/Imu (sensor-data QoS) at ``rate`` Hz of data time:
  ``angular_velocity`` rad/s, ``linear_acceleration`` specific force m/s^2 (REP-145),
  ``angular_velocity_covariance`` = diag(arw^2 * rate), ``linear_acceleration_covariance`` =
  diag(vrw^2 * rate) (the white-noise part of the specs), ``orientation_covariance[0] = -1``
  (no orientation).
- pub ``imu_sim/truth`` geometry_msgs/QuaternionStamped, same stamps and frame_id: the true
  C_b^n (IMU frame in ENU, [x, y, z, w]) — what align_node's ``imu/data`` orientation estimates.

Time: stamps are data time, ``t0 + k / rate`` (``t0`` = the node clock at startup unless the
``t0`` parameter is given). ``speed`` data seconds are published per wall second, in batches
from a ``batch_rate`` Hz wall timer. ``duration`` s of data (0 = forever); with
``exit_when_done`` the node exits when done.
"""
from __future__ import annotations

import math
import sys
import time

from sins_align.ros.params import SIM_PARAMS, param_help, sensor_specs
from sins_align.ros.runtime import (SPIN_PERIOD, build_arg_parser, declare_params, node_main,
                                    refuse_start)

#: The node's name: its executable's (``ros2 param list /imu_sim_node``).
NODE_NAME = "imu_sim_node"


def make_node_class():
    """Define the rclpy node class (rclpy is imported only after --help was handled)."""
    from geometry_msgs.msg import QuaternionStamped
    from rclpy.clock import Clock, ClockType
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from rclpy.task import Future
    from sensor_msgs.msg import Imu

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
            self.total = int(math.floor(values["duration"] * rate + 1e-9))  # 0 = forever
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
            self.wall0 = None if values["wait_for_subscribers"] else time.monotonic()
            self.emitted = 0
            steady = Clock(clock_type=ClockType.STEADY_TIME)
            self.timer = self.create_timer(1.0 / values["batch_rate"], self._tick, clock=steady)
            self.get_logger().info(
                f"publishing {rate:g} Hz x speed {values['speed']:g}, rpy {values['rpy']} deg, "
                f"latitude {values['latitude']:g} deg, grade {values['grade']}, sway "
                f"{values['sway']}, "
                + (f"{values['duration']:g} s of data" if self.total else "until stopped"))

        @staticmethod
        def _make_sim(v):
            return ImuSimulator(rate=v["rate"], lat_deg=v["latitude"], height_m=v["height"],
                                rpy_deg=v["rpy"], specs=sensor_specs(v), sway=v["sway"],
                                sway_amplitude=v["sway_amplitude"],
                                seed=None if v["seed"] < 0 else int(v["seed"]))

        def _tick(self):
            rate, speed = self.p["rate"], self.p["speed"]
            if self.wall0 is None:
                if self.pub.get_subscription_count() == 0 or (
                        self.pub_truth is not None
                        and self.pub_truth.get_subscription_count() == 0):
                    return
                self.wall0 = time.monotonic()
                if self.p["t0"] < 0:
                    self.t0_ns = self.get_clock().now().nanoseconds
                self.get_logger().info("subscribers present: starting")
            due = int((time.monotonic() - self.wall0) * speed * rate)
            if self.total:
                due = min(due, self.total)
            n = due - self.emitted
            if n > 0:
                self._publish(self.sim.next_block(n))
                self.emitted = due
            if self.total and self.emitted >= self.total and not self.done.done():
                self.get_logger().info(
                    f"done: {self.emitted} samples ({self.emitted / rate:g} s of data)")
                self.destroy_timer(self.timer)
                if self.p["exit_when_done"]:
                    # let the last messages go out before the process exits
                    self._exit_timer = self.create_timer(0.5, self._finish)

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
        "the true attitude on imu_sim/truth (geometry_msgs/QuaternionStamped).",
        param_help(SIM_PARAMS, "parameters (all read-only; --ros-args -p name:=value):")
        + "\n\nexample:\n  ros2 run sins_align imu_sim_node --ros-args "
        "-p rpy:='[2.0, -1.0, 30.0]' -p speed:=5.0 -p sway:=car")
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
