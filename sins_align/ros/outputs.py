"""What align_node publishes, as plain values: one code path for the node and the replay.

The node fills rclpy messages from these values and the replay tool fills rosbags
messages from the same values, so a live run and a replay publish identical numbers.
No ROS imports here.

Conventions (README "Frames")
-----------------------------
- ``orientation``: quaternion [x, y, z, w] of C_b^n, the IMU frame (the input
  ``header.frame_id``) in ENU, as imu_filter_madgwick publishes it.
- ``orientation_covariance``: 3x3 row-major, rad^2, covariance of the attitude error
  rotation vector phi (paper eq. 15) about the ENU axes x = East, y = North, z = Up.
  When heading is unobservable (consumer gyros, near the poles) the z variance is pi^2
  and its cross terms are zero: the yaw is then arbitrary, roll and pitch still hold.
- ``euler_deg``: REP-103 roll, pitch, yaw in degrees (yaw 0 = IMU x axis East, CCW).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sins_align.core.specs import DPH, UG
from sins_align.estimators.quasi_static import Aligner

#: diagnostic_msgs/DiagnosticStatus levels
OK, WARN, ERROR, STALE = 0, 1, 2, 3

STATE_TEXT = {
    "waiting": "waiting for IMU data",
    "aligning": "aligning",
    "aligned": "aligned",
    "disturbed": "disturbed: the platform is not quasi-static",
    "fault": "fault: gyro rates do not match the accelerometer (deg/s sent as rad/s? or a "
             "gyro far worse than the configured grade: set grade)",
}


#: The in-motion estimator's states where they read otherwise.
MOTION_STATE_TEXT = {
    "waiting": "waiting for IMU data and a velocity measurement",
    "aligning": "aligning in motion",
}


@dataclass(frozen=True)
class ImuOutput:
    """Orientation fields added to the input sample."""

    orientation_xyzw: tuple[float, float, float, float]
    orientation_covariance: tuple[float, ...]   # 9 values, row-major


def imu_output_values(al: Aligner) -> np.ndarray:
    """(13,) float64: the orientation [x, y, z, w], then its covariance (9, row-major)."""
    return np.array(imu_output_list(al))


def imu_output_list(al: Aligner) -> list[float]:
    """:func:`imu_output_values` as 13 Python floats (the node's path after every sample:
    the estimator's ``orientation_values``)."""
    return al.orientation_values()


def imu_output(al: Aligner) -> ImuOutput:
    """Orientation and its covariance for the output ``sensor_msgs/Imu``."""
    v = imu_output_values(al).tolist()
    return ImuOutput(tuple(v[:4]), tuple(v[4:]))


def euler_deg(al: Aligner) -> tuple[float, float, float]:
    """REP-103 roll, pitch, yaw of the IMU frame in ENU, deg."""
    r = al.rpy_deg
    return float(r[0]), float(r[1]), float(r[2])


def diagnostic_status(al: Aligner, input_rate_hz: float | None = None
                      ) -> tuple[int, str, list[tuple[str, str]]]:
    """Level, message and key/value pairs of the node's DiagnosticStatus.

    Returns
    -------
    level : int — OK (aligned or aligning), WARN (waiting, disturbed), ERROR (fault). The
        node raises OK to WARN itself when samples were rejected recently (it knows when).
    message : str
    values : list of (key, value) strings
    """
    st = al.status
    level = {"waiting": WARN, "aligning": OK, "aligned": OK,
             "disturbed": WARN, "fault": ERROR}[st]
    std = al.std_enu_deg
    lim = al.limit_std_deg
    msg = STATE_TEXT[st]
    ratio = al.gyro_noise_ratio
    if not al.specs_consistent:
        msg = (f"the gyro's white noise is {ratio:.0f} x the configured gyro_arw: the IMU is "
               f"worse than its grade, so its biases cannot be trusted either; attitude "
               f"published as unknown: set grade (tactical, or consumer for a MEMS IMU) or "
               f"the four specs, and restart")
    elif not al.heading_observable:
        msg += " (level only: heading unobservable with this gyro grade / latitude)"
    values = [
        ("state", st),
        ("stage", al.stage),
        ("aligned", str(al.aligned).lower()),
        ("heading_observable", str(al.heading_observable).lower()),
        ("elapsed_s", f"{al.elapsed:.3f}"),
        ("std_east_deg", f"{std[0]:.6f}"),
        ("std_north_deg", f"{std[1]:.6f}"),
        ("std_up_deg", f"{std[2]:.6f}"),
        ("limit_east_deg", f"{lim[0]:.6f}"),
        ("limit_north_deg", f"{lim[1]:.6f}"),
        ("limit_up_deg", f"{lim[2]:.6f}"),
        ("samples_used", str(al.samples_used)),
        ("samples_rejected", str(sum(al.rejected.values()))),
        ("last_reject_reason", al.last_reject or ""),
        ("nis", f"{al.nis:.3f}"),
        ("specs_consistent", str(bool(al.specs_consistent)).lower()),
        ("gyro_noise_ratio", "" if ratio is None else f"{ratio:.2f}"),
        ("input_rate_hz", "" if input_rate_hz is None else f"{input_rate_hz:.2f}"),
    ]
    values += [(f"rejected_{k}", str(v)) for k, v in sorted(al.rejected.items())]
    values += [(f"event_{k}", str(v)) for k, v in sorted(al.events.items())]
    if al.time_to_aligned is not None:
        values.append(("time_to_aligned_s", f"{al.time_to_aligned:.3f}"))
    return level, msg, values


def node_diagnostics(al: Aligner, input_rate_hz: float | None, rejected_seen: int,
                     resets: int, last_reset_reason: str):
    """:func:`diagnostic_status` plus what align_node reports (the replay writes the same):
    WARN when samples were rejected since the last report (``rejected_seen`` = the total
    then), the data rate from the stamps, and the restarts.

    Returns
    -------
    level, message, values as :func:`diagnostic_status`, and the rejected total now.
    """
    level, message, values = diagnostic_status(al, input_rate_hz)
    rejected = sum(al.rejected.values())
    recent = rejected - rejected_seen if rejected >= rejected_seen else rejected
    if recent and level < WARN:
        level = WARN
        message += f"; {recent} sample(s) rejected ({al.last_reject})"
    values = values + [
        ("data_rate_hz", "" if al.nominal_dt is None else f"{1.0 / al.nominal_dt:.2f}"),
        ("resets", str(resets)),
        ("last_reset_reason", last_reset_reason),
    ]
    return level, message, values, rejected


#: m/s^2 per mg (bias estimates in diagnostics and the replay summary)
MG = 1e3 * UG


def bias_estimates(est) -> tuple[list[float], list[float]]:
    """The gyro bias estimate in deg/h and the accelerometer bias estimate in mg (IMU axes)
    of an estimator that has them (``bias_gyro`` rad/s, ``bias_accel`` m/s^2)."""
    return ((np.asarray(est.bias_gyro, dtype=float) / DPH).tolist(),
            (np.asarray(est.bias_accel, dtype=float) / MG).tolist())


def motion_diagnostics(est, input_rate_hz: float | None, rejected_seen: int, resets: int,
                       last_reset_reason: str, feed, topic: str,
                       silent_s: float | None) -> tuple[int, str, list, int]:
    """align_node's diagnostics for an in-motion estimator (the public interface only:
    ``status``, ``aligned``, ``heading_observable``, ``reference_consistent``,
    ``specs_consistent``, ``bias_spec_ratio``,
    ``reference_nis``, ``noise_scale``, ``std_enu_deg``, ``rejected``, ``events``,
    ``bias_gyro``, ``bias_accel``, ``velocity``, ``t_last``, ``position``) plus what the
    :class:`~sins_align.ros.reference.ReferenceFeed` counted.

    ``silent_s``: how long the velocity topic has been silent while IMU data came (None:
    not silent); the status is then WARN and says so. As :func:`node_diagnostics`, WARN
    when inputs were rejected since the last report (``rejected_seen`` = the total then).

    Returns level, message, values and the rejected total now.
    """
    st = str(est.status)
    level = {"waiting": WARN, "disturbed": WARN, "fault": ERROR}.get(st, OK)
    msg = MOTION_STATE_TEXT.get(st, STATE_TEXT.get(st, st))
    if st == "waiting" and math.isnan(est.position[0]):
        msg = "waiting for the first NavSatFix (no latitude given): IMU samples refused"
    if st != "waiting" and not est.heading_observable:
        msg += " (heading not observable yet: it needs horizontal acceleration or turns)"
    consistent = bool(est.reference_consistent)
    if not consistent:
        level = ERROR
        msg = (f"velocity reference contradicts the IMU (mean NIS {est.reference_nis:.0f}): "
               f"check velocity_frame (enu/ned), lever_arm, velocity_latency, velocity_noise; "
               f"attitude published as unknown")
    zg, za = (float(x) for x in est.bias_spec_ratio)
    if not bool(est.specs_consistent):
        level = ERROR
        msg = (f"the IMU's bias estimates reached {max(zg, za):.0f} x the configured bias "
               f"specs (gyro {zg:.1f}, accelerometer {za:.1f}): the IMU is worse than its "
               f"grade; attitude published as unknown: set grade (consumer for a MEMS IMU), "
               f"gyro_bias, accel_bias and restart")
    std = est.std_enu_deg
    bg, ba = bias_estimates(est)
    v = np.asarray(est.velocity, dtype=float)
    counts = feed.counts()
    last_v = feed.last_velocity_stamp
    age = "" if last_v is None or est.t_last is None else f"{est.t_last - last_v:.3f}"
    values = [
        ("state", st),
        ("aligned", str(bool(est.aligned)).lower()),
        ("heading_observable", str(bool(est.heading_observable)).lower()),
        ("reference_consistent", str(consistent).lower()),
        ("specs_consistent", str(bool(est.specs_consistent)).lower()),
        ("bias_spec_ratio_gyro", f"{zg:.2f}"),
        ("bias_spec_ratio_accel", f"{za:.2f}"),
        ("velocity_noise_scale", f"{float(est.noise_scale):.3f}"),
        ("std_east_deg", f"{std[0]:.6f}"),
        ("std_north_deg", f"{std[1]:.6f}"),
        ("std_up_deg", f"{std[2]:.6f}"),
        *((f"bias_gyro_{a}_deg_h", f"{x:.4f}") for a, x in zip("xyz", bg)),
        *((f"bias_accel_{a}_mg", f"{x:.4f}") for a, x in zip("xyz", ba)),
        *((f"velocity_{a}_mps", f"{x:.4f}") for a, x in zip("enu", v)),
        ("samples_rejected", str(sum(est.rejected.values()))),
        ("input_rate_hz", "" if input_rate_hz is None else f"{input_rate_hz:.2f}"),
        ("velocity_topic", topic),
        ("velocity_messages", str(counts["velocity_received"])),
        ("velocity_used", str(counts["velocity_used"])),
        ("velocity_age_s", age),
        ("position_messages", str(counts["position_received"])),
        ("position_used", str(counts["position_used"])),
        ("attitude_used", str(counts["attitude_used"])),
        ("last_refused_reason", feed.last_reason),
    ]
    values += [(f"refused_{k}", str(n)) for k, n in counts["refused"].items()]
    values += [(f"rejected_by_estimator_{k}", str(n))
               for k, n in counts["rejected_by_estimator"].items()]
    rejected_by = dict(est.rejected)
    values += [(f"rejected_{k}", str(n)) for k, n in sorted(rejected_by.items())]
    values += [(f"event_{k}", str(n)) for k, n in sorted(est.events.items())]
    if silent_s is not None:
        level = max(level, WARN)
        msg += f"; no velocity messages on {topic} for {silent_s:.0f} s"
    rejected = sum(rejected_by.values())
    recent = rejected - rejected_seen if rejected >= rejected_seen else rejected
    if recent and level < WARN:
        level = WARN
        msg += f"; {recent} input(s) rejected"
    values += [("resets", str(resets)), ("last_reset_reason", last_reset_reason)]
    return level, msg, values, rejected


def covariance_is_valid(cov9) -> bool:
    """True if a 9-value covariance is finite, symmetric and positive semi-definite."""
    c = np.asarray(cov9, dtype=float).reshape(3, 3)
    if not np.isfinite(c).all() or not np.allclose(c, c.T, atol=1e-15):
        return False
    return bool(np.linalg.eigvalsh(c).min() >= -1e-15)


class StampClock:
    """Turns (sec, nanosec) header stamps into float seconds without losing precision.

    Seconds are counted from the integer second of the first stamp seen, so float64 keeps
    nanosecond resolution even for epoch stamps (1.7e9 s). The node and the replay both
    use it, so both hand the estimator the same numbers.
    """

    def __init__(self):
        self.epoch: int | None = None

    def __call__(self, sec: int, nanosec: int) -> float:
        if self.epoch is None:
            self.epoch = int(sec)
        return float(int(sec) - self.epoch) + int(nanosec) * 1e-9


def imu_sample(msg, clock: StampClock) -> tuple[float, np.ndarray, np.ndarray]:
    """(stamp s, gyro rad/s (3,), specific force m/s^2 (3,)) from a sensor_msgs/Imu.

    Works for rclpy messages and rosbags message objects alike (same field names).
    """
    st = msg.header.stamp
    w = msg.angular_velocity
    a = msg.linear_acceleration
    return (clock(st.sec, st.nanosec), np.array([w.x, w.y, w.z], dtype=float),
            np.array([a.x, a.y, a.z], dtype=float))

