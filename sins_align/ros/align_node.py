"""align_node: live SINS self-alignment of an IMU on a quasi-static base.

Subscribes ``imu/data_raw`` (sensor_msgs/Imu, REP-145 units) and runs the numpy
:class:`~sins_align.estimators.quasi_static.Aligner` on every sample; the node only converts
messages and publishes (STYLE.md: algorithm apart from ROS). What it publishes comes from
:mod:`sins_align.ros.outputs`, the same values the bag replay writes.

Topics (relative names, remap as usual)
---------------------------------------
- sub ``imu/data_raw``  sensor_msgs/Imu — sensor-data QoS (best effort) with a deeper
  history (``queue_size``) so the backtrack pass does not drop samples. Taken serialised:
  the usual encoding is read and republished in place (:class:`sins_align.io.cdr.ImuLayout`),
  anything else is deserialised by rclpy; both give the same output.
- sub ``velocity_topic`` (when set) of ``velocity_type`` (TwistWithCovarianceStamped,
  TwistStamped or nav_msgs/Odometry) and ``navsat_topic`` (sensor_msgs/NavSatFix): the
  in-motion alignment's velocity reference and position, converted by
  :mod:`sins_align.io.velocity` through a :class:`~sins_align.ros.reference.ReferenceFeed`
  (the replay's too); sensor-data QoS, depth 100.
- pub ``imu/data``      sensor_msgs/Imu — the input sample (same header) with ``orientation``
  (C_b^n, IMU frame in ENU) and ``orientation_covariance`` (rad^2, E/N/U) filled in.
  Rejected samples are not republished. Reliable, volatile, history depth ``queue_size``:
  at kHz rates a reliable subscriber held up for a few ms is repaired from that history
  (with depth 10, bench_node at 2 kHz lost up to ~160 of 20000 messages on the way out).
- pub ``alignment/aligned``   std_msgs/Bool — RELIABLE + TRANSIENT_LOCAL, depth 1: false at
  start, then on every change. Subscribers must ask for TRANSIENT_LOCAL to get the latched value.
- pub ``alignment/euler_deg`` geometry_msgs/Vector3Stamped — REP-103 roll, pitch, yaw in
  degrees at ``euler_rate`` Hz, stamped with the latest input stamp and frame.
- pub ``/diagnostics``  diagnostic_msgs/DiagnosticArray at 1 Hz.
- srv ``alignment/reset`` std_srvs/Trigger — restart the alignment, keep the node.

Parameters: :data:`sins_align.ros.params.ALIGN_NODE_PARAMS`, the estimator's
(:data:`~sins_align.ros.params.PARAMS`, ``latitude`` is required) plus the node-only
``euler_rate`` (Hz) and ``queue_size``. See ``config/align.yaml``. Numeric parameters are
statically typed doubles: ``latitude:=34`` or ``ros2 param set /align_node disturbance_nis 5``
are taken as 34.0 and 5.0 and the type stays double
(:func:`sins_align.ros.runtime.declare_params`).

The node is named ``align_node``, after its executable (``ros2 param list /align_node``);
``-r __node:=<name>`` renames it, and the shipped YAML is keyed ``/**`` so it applies under
any name. Command-line errors (a missing ``--params-file``, ``-p name`` without ``:=value``)
end in one line on stderr and exit status 2; SIGINT, SIGTERM and SIGHUP stop the node
cleanly (:func:`sins_align.ros.runtime.run_node`).
"""
from __future__ import annotations

import math
import sys
import time

from sins_align.io.velocity import VELOCITY_TYPES
from sins_align.ros.params import (ALIGN_NODE_PARAMS, NODE_NAME, PARAMS, check_param,
                                   estimator_config, make_estimator,
                                   param_help, param_spec, velocity_reference)
from sins_align.ros.runtime import (build_arg_parser, declare_params, node_main, plain,
                                    refuse_start, spin_events)

#: What each rejection reason (estimator.REJECT_REASONS) means, for the throttled warnings.
REASON_TEXT = {
    "nonfinite": "NaN or Inf in the stamp, angular_velocity or linear_acceleration",
    "duplicate_stamp": "same stamp as the previous sample",
    "stamp_backwards": "stamp earlier than the previous sample",
    "dt_too_small": "stamp interval far below the nominal IMU period",
    "time_jump": "stamp gap above max_gap: time re-anchored, alignment kept",
    "gravity_removed": "|linear_acceleration| far below g: gravity was removed "
                       "(REP-145 wants specific force)",
    "specific_force_out_of_range": "|linear_acceleration| too far from g "
                                   "for over 1 s (units? the platform is not "
                                   "quasi-static?)",
    "rate_too_high": "|angular_velocity| above max_angular_rate (deg/s instead of rad/s, "
                     "or real motion)",
    "rates_look_like_deg_per_s": "gyro and accelerometer tilt disagree beyond the gyro "
                                 "specs: angular_velocity looks like deg/s (REP-145 wants "
                                 "rad/s), or the gyro is far worse than the configured "
                                 "grade (a MEMS as 'navigation' or 'tactical': set grade, "
                                 "gyro_bias)",
    "undecodable": "the message bytes are not a valid sensor_msgs/Imu",
}

#: What the in-motion estimator's own reasons mean (MOTION_REJECT_REASONS), where they differ.
MOTION_REASON_TEXT = {
    "measurement_too_late": "a velocity or attitude stamped more than max_measurement_lag "
                            "before the newest IMU sample (GNSS and IMU clocks apart?)",
    "measurement_invalid": "a measurement with an unusable covariance or value",
    "measurement_duplicate": "a velocity or attitude with the same stamp as one already "
                             "received (the message delivered twice?)",
    "time_jump": "IMU stamp gap above max_gap: the in-motion alignment starts over",
    "no_position": "no position yet: the latitude was left out, waiting for the first fix "
                   "on navsat_topic",
}

WARN_PERIOD = 5.0   # s (wall) between warnings for one rejection reason


def make_node_class():
    """Define the rclpy node class (rclpy is imported only after --help was handled)."""
    import numpy as np
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import Vector3Stamped
    from rcl_interfaces.msg import SetParametersResult
    from rclpy.clock import JumpThreshold
    from rclpy.duration import Duration
    from rclpy.node import Node
    from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                           qos_profile_sensor_data)
    from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Imu, NavSatFix
    from std_msgs.msg import Bool
    from std_srvs.srv import Trigger

    from sins_align.io.cdr import ImuLayout
    from sins_align.estimators.session import AlignmentSession
    from sins_align.ros.outputs import (StampClock, euler_deg, imu_output, imu_output_list,
                                        imu_sample, motion_diagnostics, node_diagnostics)
    from sins_align.ros.reference import REFUSE_TEXT, VELOCITY_SILENCE, ReferenceFeed

    #: velocity_type -> message class of the velocity topic
    VELOCITY_MSG = {"twist_with_covariance": TwistWithCovarianceStamped,
                    "twist": TwistStamped, "odometry": Odometry}

    class AlignNode(Node):
        """ROS wrapper of the estimator (the quasi-static :class:`Aligner`, or the in-motion
        ``MotionAligner`` when ``velocity_topic`` is set): messages in, messages out, nothing
        else."""

        def __init__(self, **kwargs):
            super().__init__(NODE_NAME, **kwargs)
            reason = self._declare_parameters()
            if reason is None:
                try:
                    values = self._alignment_values()
                    self.config = estimator_config(values)
                    self.reference = velocity_reference(values)
                except ValueError as e:
                    reason = str(e)
                    if reason.startswith("grade is required"):
                        reason += " (-p grade:=<name>)"
                    if reason == "latitude is required":
                        reason += (" (give the IMU's geodetic latitude in deg: -p "
                                   "latitude:=<deg>; in motion a navsat_topic can give it)")
            if reason is not None:
                refuse_start(self, reason)
            self._pending = None
            self.add_on_set_parameters_callback(self._on_set_parameters)
            self.add_post_set_parameters_callback(self._after_set_parameters)

            self.aligner = make_estimator(self.config)
            #: in-motion alignment: the estimator takes the velocity reference (capability
            #: decided once here; the quasi-static Aligner's own extras are used otherwise)
            self.motion = self.reference.enabled
            self.session = AlignmentSession(self.aligner, on_event=self._on_event)
            self.stamp_clock = StampClock()
            self.last_header = None
            self._rx_count = 0
            self._rate_mark = (time.monotonic(), 0)
            self._input_rate: float | None = None
            self._rejected_seen = 0
            self._warn_state: dict[str, list] = {}

            depth = int(self.get_parameter("queue_size").value)
            qos_in = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                                reliability=qos_profile_sensor_data.reliability,
                                durability=qos_profile_sensor_data.durability)
            latched = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                                 reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.pub_imu = self.create_publisher(Imu, "imu/data", depth)
            self.pub_aligned = self.create_publisher(Bool, "alignment/aligned", latched)
            self.pub_euler = self.create_publisher(Vector3Stamped, "alignment/euler_deg", 10)
            self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
            self.srv_reset = self.create_service(Trigger, "alignment/reset", self._on_reset)
            self._layout = None   # cdr.ImuLayout of the last input that had one
            self.sub = self.create_subscription(Imu, "imu/data_raw", self._on_raw, qos_in,
                                                raw=True)
            self.feed = None
            if self.motion:
                self._subscribe_reference(depth)
            self.diag_timer = self.create_timer(1.0, self._publish_diagnostics)
            self.euler_timer = None
            self._start_euler_timer(float(self.get_parameter("euler_rate").value))
            # a bag loop or a restarted simulator sets ROS time back: start over
            self._jump_handle = self.get_clock().create_jump_callback(
                JumpThreshold(min_forward=None, min_backward=Duration(seconds=-1),
                              on_clock_change=True),
                post_callback=self._on_clock_jump)
            self._publish_aligned(force=True)
            c = self.config
            if self.motion:
                r = self.reference
                site = (f"latitude {c.latitude_deg:.4f} deg, longitude {c.longitude_deg:.4f}"
                        f" deg" if not math.isnan(c.latitude_deg) else
                        f"the position of the first fix on {self.sub_navsat.topic_name}")
                self.get_logger().info(
                    f"in-motion alignment at {site}, vehicle {c.vehicle}; velocity reference "
                    f"{self.sub_velocity.topic_name} ({VELOCITY_TYPES[r.type]}, {r.frame}), "
                    f"lever arm {', '.join('%g' % x for x in c.lever_arm)} m; position "
                    + (f"from {self.sub_navsat.topic_name}" if r.navsat_topic
                       else "from the parameters"))
            else:
                self.get_logger().info(
                    f"aligning at latitude {c.latitude_deg:.4f} deg, model {c.model}, "
                    f"backtrack {'after %g s' % c.backtrack_time if c.backtrack else 'off'}; "
                    f"heading "
                    f"{'observable' if self.aligner.heading_observable else 'UNOBSERVABLE'}"
                    f" (limit std E/N/U "
                    f"{', '.join('%.4f' % x for x in self.aligner.limit_std_deg)} deg)")

        def _subscribe_reference(self, depth: int):
            """The velocity topic (its configured type) and the NavSatFix topic, if set:
            sensor-data QoS (best effort takes reliable publishers too)."""
            r = self.reference
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=min(depth, 100),
                             reliability=qos_profile_sensor_data.reliability,
                             durability=qos_profile_sensor_data.durability)
            self.feed = ReferenceFeed(self.session, r, self.stamp_clock,
                                      on_refused=self._warn_refused)
            self.sub_velocity = self.create_subscription(
                VELOCITY_MSG[r.type], r.topic, self._on_velocity, qos)
            self.sub_navsat = None
            if r.navsat_topic:
                self.sub_navsat = self.create_subscription(NavSatFix, r.navsat_topic,
                                                           self._on_navsat, qos)
            self._first_imu_wall: float | None = None
            self._last_imu_wall = -math.inf
            self._velocity_wall: float | None = None
            self._silence_warned = -math.inf

        # -------------------------------------------------------------- parameters
        def _declare_parameters(self) -> str | None:
            """Declare every parameter (:func:`declare_params`); return the first reason a
            value is bad, or None."""
            _, reason = declare_params(self, ALIGN_NODE_PARAMS)
            return reason

        def _alignment_values(self) -> dict:
            """The estimator's parameters (a required one left out: NaN)."""
            from rclpy.exceptions import ParameterUninitializedException

            values = {}
            for p in PARAMS:
                try:
                    values[p.name] = plain(self.get_parameter(p.name).value)
                except ParameterUninitializedException:
                    values[p.name] = math.nan             # (declared without a value)
            return values

        def _on_set_parameters(self, params) -> SetParametersResult:
            """Validate runtime changes; the new AlignConfig is applied after the set. The
            in-motion estimator reads its configuration at start only: its parameters are
            refused at run time (the node-only ones are still settable)."""
            values = self._alignment_values()
            for p in params:
                spec = param_spec(p.name, "node") or param_spec(p.name, "align")
                if spec is None:
                    continue   # not ours (use_sim_time ...)
                if self.motion and spec.scope == "align":
                    return SetParametersResult(successful=False, reason=(
                        f"{p.name} cannot be changed at run time during an in-motion "
                        "alignment (velocity_topic is set): restart the node"))
                reason = check_param(p.name, plain(p.value), spec.scope)
                if spec.scope == "align":
                    values[p.name] = plain(p.value)
                if reason:
                    return SetParametersResult(successful=False, reason=reason)
            try:
                # (estimator_config: in motion the latitude may be NaN, from the first fix)
                self._pending = estimator_config(values)
            except ValueError as e:
                return SetParametersResult(successful=False, reason=str(e))
            return SetParametersResult(successful=True)

        def _after_set_parameters(self, params):
            """Apply accepted changes to the live Aligner: thresholds, no restart."""
            names = {p.name for p in params}
            if "euler_rate" in names:
                self._start_euler_timer(float(self.get_parameter("euler_rate").value))
            if self._pending is not None and not self.motion \
                    and names & {p.name for p in PARAMS}:
                # only non-read-only (non-structural) fields can differ: swap the config,
                # keep the filter state and the aligned flag
                self.config = self._pending
                self.aligner.config = self.config
                self.aligner.filter.config = self.config
                self.get_logger().info("parameters changed: " + ", ".join(
                    f"{p.name}={p.value}" for p in params))
            self._pending = None

        def _start_euler_timer(self, rate_hz: float):
            if self.euler_timer is not None:
                self.destroy_timer(self.euler_timer)
            self.euler_timer = self.create_timer(1.0 / rate_hz, self._publish_euler)

        # -------------------------------------------------------------- data path
        def _on_raw(self, raw: bytes):
            """Serialised imu/data_raw. The usual encoding (CDR little-endian, what rclpy and
            rclcpp send on little-endian machines) is read in place and republished as the
            same bytes with the orientation fields overwritten; anything else goes through
            the message path, which publishes the same message more slowly."""
            layout = self._layout
            if layout is None or not layout.matches(raw):
                layout = ImuLayout.of(raw)
                if layout is None:
                    try:
                        msg = deserialize_message(raw, Imu)
                    except Exception:            # malformed bytes: count, warn, keep going
                        self._rx_count += 1
                        self.aligner.reject_undecodable()   # warned through _on_event
                        return
                    self._on_imu(msg)
                    return
                self._layout = layout
            sec, nanosec, w, f = layout.read(raw)
            if self._sample(self.stamp_clock(sec, nanosec), np.array(w), np.array(f)):
                self.last_header = (sec, nanosec, layout.frame_id)
                self.pub_imu.publish(layout.with_orientation(raw, imu_output_list(self.aligner)))
            self._publish_aligned()

        def _on_imu(self, msg):
            """A deserialised imu/data_raw message: the same steps on rclpy message objects."""
            if self._sample(*imu_sample(msg, self.stamp_clock)):
                st = msg.header.stamp
                self.last_header = (st.sec, st.nanosec, msg.header.frame_id)
                out = imu_output(self.aligner)
                q = msg.orientation
                q.x, q.y, q.z, q.w = out.orientation_xyzw
                msg.orientation_covariance = out.orientation_covariance
                self.pub_imu.publish(msg)
            self._publish_aligned()

        def _sample(self, t: float, w, f) -> bool:
            """One sample through the session; True when it is to be republished."""
            self._rx_count += 1
            if self.feed is not None:
                self._last_imu_wall = time.monotonic()
                if self._first_imu_wall is None:
                    self._first_imu_wall = self._last_imu_wall
            return self.session.feed(t, w, f)

        def _on_velocity(self, msg):
            """A velocity-reference message: converted and handed over by the feed."""
            self._velocity_wall = time.monotonic()
            self.feed.on_velocity(msg)
            self._publish_aligned()

        def _on_navsat(self, msg):
            self.feed.on_navsat(msg)

        def _on_event(self, event):
            """The Aligner's events: throttled warnings for rejections, restarts logged."""
            if event.kind == "rejected":
                self._warn_rejected(event.value)
            elif event.kind == "restarted":
                self.get_logger().warning(f"alignment restarted: {event.value}")
            elif event.kind == "inconsistent":
                self.get_logger().error(
                    f"the velocity reference contradicts the IMU (mean NIS {event.value:.0f} "
                    f"per degree of freedom, honest ~1): check velocity_frame (enu/ned), "
                    f"lever_arm, velocity_latency and velocity_noise; the attitude is "
                    f"published as unknown meanwhile")

        def _warn_rejected(self, reason: str):
            now = time.monotonic()
            st = self._warn_state.setdefault(reason, [-math.inf, 0])
            st[1] += 1
            if now - st[0] >= WARN_PERIOD:
                what = "input(s)" if reason.startswith("measurement") else "sample(s)"
                text = (self.motion and MOTION_REASON_TEXT.get(reason)) or \
                    REASON_TEXT.get(reason, "?")
                self.get_logger().warning(f"rejected {st[1]} {what}: {reason} ({text})")
                st[0], st[1] = now, 0

        def _warn_refused(self, kind: str, reason: str, text: str):
            """A velocity or NavSatFix message the conversion refused (throttled)."""
            now = time.monotonic()
            st = self._warn_state.setdefault(f"{kind}:{reason}", [-math.inf, 0])
            st[1] += 1
            if now - st[0] >= WARN_PERIOD:
                topic = (self.sub_velocity if kind == "velocity" else self.sub_navsat).topic_name
                self.get_logger().warning(
                    f"refused {st[1]} message(s) on {topic}: {text} "
                    f"({REFUSE_TEXT.get(reason, reason)})")
                st[0], st[1] = now, 0

        def _velocity_silence(self) -> float | None:
            """How long IMU data has come without a velocity message (wall s, since the first
            sample or the last velocity message), when above VELOCITY_SILENCE and the IMU
            data still comes; else None."""
            if self._first_imu_wall is None or \
                    time.monotonic() - self._last_imu_wall > VELOCITY_SILENCE:
                return None
            last = max(self._first_imu_wall, self._velocity_wall or -math.inf)
            silent = self._last_imu_wall - last
            return silent if silent > VELOCITY_SILENCE else None

        def _on_clock_jump(self, jump):
            # runs inside the clock update: only flag it, the next sample restarts
            if jump.delta.nanoseconds < 0:
                self.session.request_restart(
                    f"ROS time jumped back by {-jump.delta.nanoseconds * 1e-9:.3f} s")

        def _on_reset(self, request, response):
            previous = "" if self.motion else \
                f" (previous run: {self.aligner.elapsed:.1f} s of data)"
            self.session.restart("reset service called")
            self._publish_aligned()
            response.success = True
            response.message = "alignment restarted" + previous
            return response

        # -------------------------------------------------------------- outputs
        def _publish_aligned(self, force: bool = False):
            """Publish the flag when it changed since the last publication (the session's
            flag changes of this sample, or a forced publication)."""
            value = self.session.flag_to_publish()
            if force and value is None:
                value = bool(self.aligner.aligned)
            if value is not None:
                self.pub_aligned.publish(Bool(data=value))
                if value and (self.motion or self.aligner.time_to_aligned is not None):
                    std = self.aligner.std_enu_deg
                    when = ("" if self.motion else
                            f" after {self.aligner.time_to_aligned:.1f} s of data")
                    self.get_logger().info(
                        f"ALIGNED{when}: "
                        f"rpy {', '.join('%.4f' % x for x in euler_deg(self.aligner))} deg, "
                        f"std E/N/U {std[0]:.4f}, {std[1]:.4f}, {std[2]:.4f} deg")

        def _publish_euler(self):
            if self.last_header is None or self.aligner.t_last is None:
                return
            m = Vector3Stamped()
            m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id = self.last_header
            m.vector.x, m.vector.y, m.vector.z = euler_deg(self.aligner)
            self.pub_euler.publish(m)

        def _publish_diagnostics(self):
            now = time.monotonic()
            t0, n0 = self._rate_mark
            if now > t0:
                self._input_rate = (self._rx_count - n0) / (now - t0)
            self._rate_mark = (now, self._rx_count)
            al = self.aligner
            if self.motion:
                silent = self._velocity_silence()
                if silent is not None and now - self._silence_warned >= WARN_PERIOD:
                    self._silence_warned = now
                    self.get_logger().warning(
                        f"no velocity messages on {self.sub_velocity.topic_name} "
                        f"({VELOCITY_TYPES[self.reference.type]}) for {silent:.0f} s while "
                        "IMU data comes: heading cannot be aligned without them (check the "
                        "topic name and type: velocity_topic, velocity_type)")
                level, message, values, self._rejected_seen = motion_diagnostics(
                    al, self._input_rate, self._rejected_seen, self.session.resets,
                    self.session.last_reset_reason, self.feed, self.sub_velocity.topic_name,
                    silent)
            else:
                level, message, values, self._rejected_seen = node_diagnostics(
                    al, self._input_rate, self._rejected_seen, self.session.resets,
                    self.session.last_reset_reason)
            st = DiagnosticStatus(
                level=bytes([level]), name=f"{self.get_name()}: alignment", message=message,
                hardware_id=self.last_header[2] if self.last_header else "",
                values=[KeyValue(key=k, value=v) for k, v in values])
            arr = DiagnosticArray(status=[st])
            arr.header.stamp = self.get_clock().now().to_msg()
            self.pub_diag.publish(arr)

    return AlignNode


def main(args: list[str] | None = None) -> int:
    """Entry point of ``align_node`` / ``python -m sins_align.ros.align_node``; returns exit
    code."""
    parser = build_arg_parser(
        "align_node",
        "SINS self-alignment node: roll, pitch and true heading of an IMU on a quasi-static "
        "base, from gravity and Earth rate, or in motion from a velocity reference "
        "(velocity_topic).\nSubscribes imu/data_raw (and velocity_topic, navsat_topic when "
        "set); publishes imu/data, "
        "alignment/aligned (latched), alignment/euler_deg, /diagnostics; service "
        "alignment/reset.",
        param_help(ALIGN_NODE_PARAMS, "parameters (set with --ros-args -p name:=value or "
                   "--params-file):") + "\n\nexample:\n  ros2 run sins_align align_node --ros-args "
        "-p latitude:=34.0 --params-file align.yaml")
    return node_main("align_node", parser, args, make_node_class, spin_events)


if __name__ == "__main__":
    sys.exit(main())
