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

Parameters: every entry of :data:`sins_align.ros.params.PARAMS` (``latitude`` is required),
plus the node-only ``euler_rate`` (Hz) and ``queue_size``. See ``config/align.yaml``.
Numeric parameters are statically typed doubles: ``latitude:=34`` or
``ros2 param set /align_node disturbance_nis 5`` are taken as 34.0 and 5.0 and the type stays
double (:func:`declare_typed`, :func:`accept_int_as_double`).

The node is named ``align_node``, after its executable (``ros2 param list /align_node``);
``-r __node:=<name>`` renames it, and the shipped YAML is keyed ``/**`` so it applies under
any name. Command-line errors (a missing ``--params-file``, ``-p name`` without ``:=value``)
end in one line on stderr and exit status 2; SIGINT, SIGTERM and SIGHUP stop the node
cleanly (:func:`run_node`).
"""
from __future__ import annotations

import argparse
import math
import os
import re
import signal
import sys
import time

from sins_align.ros.params import NODE_NAME, PARAMS, check_param, config_from_params

#: Node-only parameters: name -> (default, description, low, high, read_only).
NODE_PARAMS = {
    "euler_rate": (10.0, "Publishing rate of alignment/euler_deg, Hz.", 0.1, 1000.0, False),
    "queue_size": (1000, "History depth of the imu/data_raw subscription (sensor-data QoS "
                         "otherwise): covers the pause of the backtrack pass; also the history "
                         "depth of the imu/data publisher.", 5, 100000, True),
}

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
    "rates_look_like_deg_per_s": "gyro and accelerometer tilt disagree: angular_velocity "
                                 "looks like deg/s (REP-145 wants rad/s)",
    "undecodable": "the message bytes are not a valid sensor_msgs/Imu",
}

WARN_PERIOD = 5.0   # s (wall) between warnings for one rejection reason


class StartupError(RuntimeError):
    """The node cannot start (bad parameters); the reason was logged already."""


class ArgsError(Exception):
    """A bad command line (ROS arguments included): one line on stderr, exit status 2."""


def refuse_start(node, reason: str):
    """Log the one-line reason, drop the node and raise StartupError (main() exits 1)."""
    node.get_logger().fatal(f"cannot start: {reason}")
    node.destroy_node()
    raise StartupError(reason)


def build_arg_parser(prog: str, description: str, epilog: str) -> argparse.ArgumentParser:
    """An argparse parser that only documents (``--help``); ROS arguments pass through."""
    return argparse.ArgumentParser(
        prog=prog, description=description, epilog=epilog, allow_abbrev=False,
        formatter_class=argparse.RawDescriptionHelpFormatter)


def _ros_sections(argv: list[str]) -> list[list[str]]:
    """The ``--ros-args ... [--]`` sections of a command line."""
    out, cur = [], None
    for a in argv:
        if cur is None:
            if a == "--ros-args":
                cur = []
        elif a == "--":
            out.append(cur)
            cur = None
        elif a == "--ros-args":
            continue
        else:
            cur.append(a)
    if cur is not None:
        out.append(cur)
    return out


def check_ros_args(argv: list[str]) -> None:
    """Check the ROS arguments as rcl will parse them; raise :class:`ArgsError` with one line.

    Parameter files are checked first (missing, not a file, unreadable), then rcl parses
    everything (``rclpy.utilities.remove_ros_args``, which logs nothing); its message loses
    the C source locations and lexer details.
    """
    from rclpy.utilities import remove_ros_args

    for sec in _ros_sections(argv):
        for flag, value in zip(sec, sec[1:] + [None]):
            if flag == "--params-file" and value is not None:
                if not os.path.exists(value):
                    raise ArgsError(f"parameters file {value} does not exist "
                                    "(--params-file)")
                if not os.path.isfile(value):
                    raise ArgsError(f"parameters file {value} is not a file (--params-file)")
                if not os.access(value, os.R_OK):
                    raise ArgsError(f"parameters file {value} is not readable (--params-file)")
            elif flag in ("-p", "--param") and value is not None and ":=" not in value:
                raise ArgsError(f"'{flag} {value}' has no value: write {flag} {value}:=VALUE")
    try:
        remove_ros_args(argv)
    except Exception as e:   # noqa: BLE001 - rclpy's RCLInvalidROSArgsError, UnknownROSArgsError
        raise ArgsError(ros_args_message(e)) from None


def ros_args_message(e: BaseException) -> str:
    """rcl's message for bad ROS arguments on one line, without C source locations."""
    text = str(e)
    if type(e).__name__ == "UnknownROSArgsError":
        return f"unknown ROS arguments: {text.strip('[]')}"
    text = re.sub(r",? at [^,]*?\.c:\d+", "", text)
    text = re.sub(r"\.?\s*Error: Expected lexeme type \(\d+\) not found, search ended at index "
                  r"\d+", " (not of the form name:=value)", text)
    for prefix in ("Failed to parse ROS arguments: ", "failed to initialize rcl: "):
        text = text.removeprefix(prefix)
    text = " ".join(text.split())
    return f"bad ROS arguments: {text}" if text else "bad ROS arguments"


def parse_cli(parser: argparse.ArgumentParser, args: list[str] | None) -> argparse.Namespace:
    """Parse the non-ROS command line (``--help`` exits here, before rclpy.init).

    Raises :class:`ArgsError` for bad ROS arguments (see :func:`check_ros_args`).
    """
    from rclpy.utilities import remove_ros_args

    argv = list(sys.argv if args is None else args)
    check_ros_args(argv)
    ns, unknown = parser.parse_known_args(remove_ros_args(argv)[1:])
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)} "
                     "(ROS arguments go after --ros-args)")
    return ns


def _param_help() -> str:
    lines = ["parameters (set with --ros-args -p name:=value or --params-file):"]
    for p in PARAMS:
        ro = "" if p.read_only else " [runtime]"
        lines.append(f"  {p.name} (default {p.default!r}){ro}: {p.description}")
    for name, (default, text, _, _, ro) in NODE_PARAMS.items():
        lines.append(f"  {name} (default {default!r}){'' if ro else ' [runtime]'}: {text}")
    return "\n".join(lines)


def _plain(value):
    """A parameter value as plain Python (arrays to lists, ints to floats where numeric)."""
    if isinstance(value, (str, bool)) or value is None:
        return value
    if isinstance(value, (int, float)):
        return float(value)
    return [float(x) for x in value]


def _as_declared_type(default, value):
    """``value`` in the type of ``default`` (a value, or an rclpy ``Parameter.Type``) where
    ROS would store another one: an integer (``latitude:=34``) for a double, integers for a
    double array. Anything else unchanged."""
    from rclpy.parameter import Parameter

    double = isinstance(default, float) or default == Parameter.Type.DOUBLE
    if double and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(default, list) and not isinstance(value, (str, bytes)) and value is not None:
        try:
            items = list(value)
        except TypeError:
            return value
        if items and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                         for x in items):
            return [float(x) for x in items]
    return value


def declare_typed(node, name: str, default, descriptor, check) -> tuple[object, str | None]:
    """Declare ``name`` statically typed as ``default`` (double, double array, integer, ...;
    or an rclpy ``Parameter.Type`` for a parameter without a default, whose value is then
    None unless it is given).

    An override of an integer for a double parameter (``-p latitude:=34``, ``latitude: 34`` in
    a params file) is declared as that double: the parameter's type stays the declared one.
    ``check(value)`` gives the reason a value is refused, or None. Returns ``(value, None)``,
    or ``(None, reason)`` for a refused value (the parameter is then left undeclared or at a
    valid value; the node is not to start).
    """
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException

    try:
        value = node.declare_parameter(name, default, descriptor).value
    except (InvalidParameterTypeException, InvalidParameterValueException):
        # another type or out of the descriptor's range: read the override with a dynamically
        # typed probe, convert an integer to the declared double, check, then declare it
        from rclpy.parameter import Parameter

        probe = ParameterDescriptor(dynamic_typing=True)
        initial = None if isinstance(default, Parameter.Type) else default
        value = _as_declared_type(default, node.declare_parameter(name, initial, probe).value)
        node.undeclare_parameter(name)
        reason = check(value)
        if reason:
            return None, reason
        try:
            value = node.declare_parameter(name, value, descriptor, ignore_override=True).value
        except (InvalidParameterTypeException, InvalidParameterValueException) as e:
            return None, str(e.args[0]).removesuffix(f": {name}")
    reason = check(value)
    return (None, reason) if reason else (value, None)


def accept_int_as_double(node):
    """A pre-set callback for ``node``: an integer set on a double parameter
    (``ros2 param set /align_node disturbance_nis 5``) is set as that double, so the value is
    accepted and the parameter's type stays double (rclpy would otherwise refuse a statically
    typed one, or turn a dynamically typed one into an integer). Other types are left to
    rclpy's type check ("Wrong parameter type, expected 'Type.DOUBLE' ...")."""
    from rcl_interfaces.msg import ParameterType
    from rclpy.parameter import Parameter

    def callback(params):
        out = []
        for p in params:
            if p.type_ == Parameter.Type.INTEGER and node.has_parameter(p.name) and \
                    node.describe_parameter(p.name).type == ParameterType.PARAMETER_DOUBLE:
                p = Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            out.append(p)
        return out

    return callback


def _make_node_class():
    """Define the rclpy node class (rclpy is imported only after --help was handled)."""
    import numpy as np
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import Vector3Stamped
    from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                    SetParametersResult)
    from rclpy.clock import JumpThreshold
    from rclpy.duration import Duration
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                           qos_profile_sensor_data)
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Imu
    from std_msgs.msg import Bool
    from std_srvs.srv import Trigger

    from sins_align.io.cdr import ImuLayout
    from sins_align.estimators.quasi_static import Aligner
    from sins_align.estimators.session import AlignmentSession
    from sins_align.ros.outputs import (StampClock, euler_deg, imu_output, imu_output_values,
                                        imu_sample, node_diagnostics)

    class AlignNode(Node):
        """ROS wrapper of :class:`Aligner`: messages in, messages out, nothing else."""

        def __init__(self, **kwargs):
            super().__init__(NODE_NAME, **kwargs)
            reason = self._declare_parameters()
            if reason is None:
                try:
                    self.config = config_from_params(self._alignment_values())
                except ValueError as e:
                    reason = str(e)
            if reason is not None:
                refuse_start(self, reason)
            self._pending = None
            self.add_on_set_parameters_callback(self._on_set_parameters)
            self.add_post_set_parameters_callback(self._after_set_parameters)

            self.aligner = Aligner(self.config)
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
            self.get_logger().info(
                f"aligning at latitude {c.latitude_deg:.4f} deg, model {c.model}, "
                f"backtrack {'after %g s' % c.backtrack_time if c.backtrack else 'off'}; "
                f"heading {'observable' if self.aligner.heading_observable else 'UNOBSERVABLE'}"
                f" (limit std E/N/U {', '.join('%.4f' % x for x in self.aligner.limit_std_deg)}"
                " deg)")

        # -------------------------------------------------------------- parameters
        def _declare_parameters(self) -> str | None:
            """Declare every parameter; return the first reason a value is bad, or None.

            Statically typed (:func:`declare_typed`): doubles stay doubles whatever a user
            writes (``latitude:=34``, ``ros2 param set ... 5``, :func:`accept_int_as_double`).
            """
            for p in PARAMS:
                d = ParameterDescriptor(description=p.description, read_only=p.read_only)
                if p.choices:
                    d.additional_constraints = "one of: " + ", ".join(p.choices)
                elif p.low is not None:
                    d.additional_constraints = f"within [{p.low:g}, {p.high:g}]"
                    if isinstance(p.default, float):
                        d.floating_point_range = [FloatingPointRange(
                            from_value=float(p.low), to_value=float(p.high), step=0.0)]
                default = p.default

                def check(v, name=p.name):
                    return check_param(name, _plain(v))
                if p.name == "latitude":
                    # no default: unset is "required", a NaN given is "must be finite"
                    default = Parameter.Type.DOUBLE
                    def check(v, name=p.name):
                        if v is None:
                            return "latitude is required"
                        if v != v:
                            return "latitude must be finite, got nan"
                        return check_param(name, _plain(v))
                _, reason = declare_typed(self, p.name, default, d, check)
                if reason:
                    if p.name == "latitude" and "required" in reason:
                        reason += " (give the IMU's geodetic latitude in deg: -p latitude:=<deg>)"
                    return reason
            for name, (default, text, low, high, ro) in NODE_PARAMS.items():
                d = ParameterDescriptor(description=text, read_only=ro)
                if isinstance(default, int):
                    d.integer_range = [IntegerRange(from_value=low, to_value=high, step=1)]
                else:
                    d.floating_point_range = [FloatingPointRange(
                        from_value=low, to_value=high, step=0.0)]
                _, reason = declare_typed(self, name, default, d,
                                          lambda v, name=name: self._check_node_param(name, v))
                if reason:
                    return reason
            self.add_pre_set_parameters_callback(accept_int_as_double(self))
            return None

        @staticmethod
        def _check_node_param(name, value) -> str | None:
            _, _, low, high, _ = NODE_PARAMS[name]
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                return f"{name} must be a number"
            if not (math.isfinite(value) and low <= value <= high):
                return f"{name} must be within [{low:g}, {high:g}], got {value!r}"
            return None

        def _alignment_values(self) -> dict:
            return {p.name: _plain(self.get_parameter(p.name).value) for p in PARAMS}

        def _on_set_parameters(self, params) -> SetParametersResult:
            """Validate runtime changes; the new AlignConfig is applied after the set."""
            values = self._alignment_values()
            for p in params:
                if p.name in NODE_PARAMS:
                    reason = self._check_node_param(p.name, p.value)
                elif p.name in values:
                    reason = check_param(p.name, _plain(p.value))
                    values[p.name] = _plain(p.value)
                else:
                    continue   # not ours (use_sim_time ...)
                if reason:
                    return SetParametersResult(successful=False, reason=reason)
            try:
                self._pending = config_from_params(values)
            except ValueError as e:
                return SetParametersResult(successful=False, reason=str(e))
            return SetParametersResult(successful=True)

        def _after_set_parameters(self, params):
            """Apply accepted changes to the live Aligner: thresholds, no restart."""
            names = {p.name for p in params}
            if "euler_rate" in names:
                self._start_euler_timer(float(self.get_parameter("euler_rate").value))
            if self._pending is not None and names & {p.name for p in PARAMS}:
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
                self.pub_imu.publish(layout.with_orientation(raw, imu_output_values(self.aligner)))
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
            return self.session.feed(t, w, f)

        def _on_event(self, event):
            """The Aligner's events: throttled warnings for rejections, restarts logged."""
            if event.kind == "rejected":
                self._warn_rejected(event.value)
            elif event.kind == "restarted":
                self.get_logger().warning(f"alignment restarted: {event.value}")

        def _warn_rejected(self, reason: str):
            now = time.monotonic()
            st = self._warn_state.setdefault(reason, [-math.inf, 0])
            st[1] += 1
            if now - st[0] >= WARN_PERIOD:
                self.get_logger().warning(
                    f"rejected {st[1]} sample(s): {reason} ({REASON_TEXT.get(reason, '?')})")
                st[0], st[1] = now, 0

        def _on_clock_jump(self, jump):
            # runs inside the clock update: only flag it, the next sample restarts
            if jump.delta.nanoseconds < 0:
                self.session.request_restart(
                    f"ROS time jumped back by {-jump.delta.nanoseconds * 1e-9:.3f} s")

        def _on_reset(self, request, response):
            elapsed = self.aligner.elapsed
            self.session.restart("reset service called")
            self._publish_aligned()
            response.success = True
            response.message = f"alignment restarted (previous run: {elapsed:.1f} s of data)"
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
                if value and self.aligner.time_to_aligned is not None:
                    std = self.aligner.std_enu_deg
                    self.get_logger().info(
                        f"ALIGNED after {self.aligner.time_to_aligned:.1f} s of data: "
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


class StopRequest:
    """Set by SIGINT, SIGTERM or SIGHUP: the spin loop ends and the node shuts down in order.

    rclpy's own handlers shut the context down from the signal, while a callback may still be
    publishing: the EventsExecutor then logs ``[FATAL] ... publisher's context is invalid``
    with a traceback. Here the signal only sets this flag; the loop returns between callbacks,
    then the executor, the node and the context go down one after the other. A second signal
    kills the process at once (the default action is restored after the first).
    """

    SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")

    def __init__(self):
        self.signum: int | None = None
        self._previous = {}

    def is_set(self) -> bool:
        return self.signum is not None

    def _handler(self, signum, frame):
        self.signum = signum
        for sig in self._previous:
            signal.signal(sig, signal.SIG_DFL)

    def install(self) -> "StopRequest":
        for name in self.SIGNALS:
            sig = getattr(signal, name)
            if sig == getattr(signal, "SIGHUP", None) and \
                    signal.getsignal(sig) is signal.SIG_IGN:
                continue          # nohup: leave SIGHUP ignored (SIGINT is handled even when
                # a shell started the node in the background with it ignored, as rclpy does)
            self._previous[sig] = signal.signal(sig, self._handler)
        return self

    def restore(self):
        for sig, old in self._previous.items():
            signal.signal(sig, old)
        self._previous = {}


#: How long a spin loop waits for work before it looks at the StopRequest again, s.
SPIN_PERIOD = 0.1


def main(args: list[str] | None = None) -> int:
    """Entry point of ``align_node`` / ``python -m sins_align.ros.align_node``; returns exit
    code."""
    parser = build_arg_parser(
        "align_node",
        "SINS self-alignment node: roll, pitch and true heading of an IMU on a quasi-static "
        "base, from gravity and Earth rate.\nSubscribes imu/data_raw; publishes imu/data, "
        "alignment/aligned (latched), alignment/euler_deg, /diagnostics; service "
        "alignment/reset.",
        _param_help() + "\n\nexample:\n  ros2 run sins_align align_node --ros-args "
        "-p latitude:=34.0 --params-file align.yaml")
    return node_main("align_node", parser, args, _make_node_class, spin_events)


def spin_events(node, stop: StopRequest) -> None:
    """Spin ``node`` until ``stop`` is set or its context shuts down, with rclpy's
    EventsExecutor: its event loop is C++, far less time per callback than the
    SingleThreadedExecutor's Python one.

    Always with a timeout: in rclpy 7.1 its ``spin()`` and ``spin_once()`` without one
    busy-wait at 100 % CPU and never return at shutdown.
    """
    from rclpy.experimental.events_executor import EventsExecutor

    executor = EventsExecutor(context=node.context)
    executor.add_node(node)
    try:
        while node.context.ok() and not stop.is_set():
            executor.spin_once(timeout_sec=SPIN_PERIOD)
    finally:
        executor.shutdown()


def node_main(prog: str, parser: argparse.ArgumentParser, args: list[str] | None,
              make_node_class, spin) -> int:
    """``main()`` of a node executable: the command line (``--help``; bad ROS arguments in
    one line on stderr, exit status 2), then :func:`run_node`."""
    try:
        parse_cli(parser, args)
    except ArgsError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 2
    return run_node(args, make_node_class(), spin)


def run_node(args, node_class, spin) -> int:
    """rclpy lifecycle shared by the executables (Jazzy style): init, spin, clean shutdown.

    Returns 1 when the node refuses to start (StartupError, already logged in one line),
    else 0. SIGINT (Ctrl-C), SIGTERM and SIGHUP set a :class:`StopRequest` (rclpy's own
    handlers are not installed); ``spin(node, stop)`` returns between callbacks and the
    executor, the node and the context are shut down in that order, so no callback runs on
    a context that is gone.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    stop = StopRequest().install()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as e:   # noqa: BLE001 - bad ROS arguments that slipped past parse_cli
        print(f"{node_class.__name__}: error: {ros_args_message(e)}", file=sys.stderr)
        stop.restore()
        return 2
    node = None
    try:
        node = node_class()
        spin(node, stop)
    except StartupError:
        return 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        stop.restore()
    return 0


if __name__ == "__main__":
    sys.exit(main())
