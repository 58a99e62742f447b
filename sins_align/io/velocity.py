"""Velocity-reference and position messages as plain numbers (numpy only, no ROS imports).

align_node and the replay tool both turn their messages into estimator inputs here, so a live
run and a bag replay hand the in-motion estimator identical numbers. The message adapters
(:func:`from_twist_with_covariance`, :func:`from_twist`, :func:`from_odometry`,
:func:`from_navsat`) only read attributes, with the same names in rclpy messages and in
rosbags-deserialised ones; the conversions themselves work on plain fields.

Conventions
-----------
- Output velocity: ENU, m/s, at the antenna (or at the master INS), a NaN component = not
  measured. Output covariance: 3x3 ENU (m/s)^2, or None when the message carries none (the
  estimator then uses its configured ``velocity_noise``).
- The axis convention of the input is a parameter, ``velocity_frame``: ``enu`` or ``ned``; it
  is never guessed from ``frame_id``. NED -> ENU swaps x and y and negates z
  (:data:`NED_TO_ENU`, a proper rotation), and the covariance is permuted with it.
- ``geometry_msgs/TwistWithCovarianceStamped`` (ublox_gps ``fix_velocity``: ENU; Septentrio
  ``twist_gnss``: ENU or NED): ``twist.twist.linear`` in the world frame; the covariance is
  6x6 row-major (linear part = top-left 3x3). All zeros (on the provided axes), or -1 as its
  first element, means unknown (None); a variance of exactly -1 on one axis means that
  component is not provided (a receiver without vertical velocity): NaN. Any other negative
  or a non-finite variance refuses the message.
- ``geometry_msgs/TwistStamped`` (nmea_navsat_driver ``vel``: x East, y North): horizontal
  only. Its z is never used (the driver has no vertical velocity and writes 0): vertical =
  NaN; no covariance.
- ``nav_msgs/Odometry`` from a master INS: ``twist.twist.linear`` is expressed in
  ``child_frame_id`` (REP-105), so it is rotated into the world frame with
  ``pose.pose.orientation`` (the body in the world frame, which is ENU or NED per
  ``velocity_frame``), then into ENU; its covariance likewise. The orientation, converted to
  the body in ENU, is returned for attitude matching, with the orientation block of the pose
  covariance (rad^2 about the world axes, permuted for NED) when it is known.
- ``sensor_msgs/NavSatFix``: latitude, longitude (deg) and altitude (m above the WGS-84
  ellipsoid); refused when ``status.status`` < 0 (no fix, or Jazzy's STATUS_UNKNOWN -2, the
  field's default) or a value is not finite.

A message that cannot be used raises :class:`Refused` with a short reason key (counted by the
node and the replay) and a one-line text.
"""
from __future__ import annotations

import math
from typing import Callable, NamedTuple

import numpy as np

from sins_align.core.rotation import dcm_from_quat, quat_from_dcm

#: ``velocity_type`` values and the ROS message type each one names.
VELOCITY_TYPES: dict[str, str] = {
    "twist_with_covariance": "geometry_msgs/msg/TwistWithCovarianceStamped",
    "twist": "geometry_msgs/msg/TwistStamped",
    "odometry": "nav_msgs/msg/Odometry",
}
#: ``velocity_frame`` values: the axis convention of the velocity message's world frame.
VELOCITY_FRAMES = ("enu", "ned")
#: The position message (``navsat_topic``).
NAVSAT_TYPE = "sensor_msgs/msg/NavSatFix"

#: x_ENU = NED_TO_ENU @ x_NED: East = y_NED, North = x_NED, Up = -z_NED. A rotation
#: (det +1, 180 deg about (1, 1, 0)/sqrt(2)) and its own inverse.
NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

#: Largest departure of an Odometry quaternion's norm from 1 that is normalised away.
QUATERNION_NORM_TOLERANCE = 0.01

#: Why a message is refused (:class:`Refused`.reason).
REFUSE_REASONS = ("nonfinite", "negative_variance", "covariance_not_psd", "bad_orientation",
                  "no_fix")


class Refused(ValueError):
    """A message that cannot be used: ``reason`` (one of :data:`REFUSE_REASONS`) and a text."""

    def __init__(self, reason: str, text: str):
        super().__init__(text)
        self.reason = reason


class Velocity(NamedTuple):
    """A velocity measurement: stamp (s, the caller's clock), ENU velocity (3,) in m/s with
    NaN for an unmeasured component, ENU covariance (3, 3) in (m/s)^2 or None."""

    stamp: float
    v_enu: np.ndarray
    cov_enu: np.ndarray | None


class Attitude(NamedTuple):
    """A master INS attitude: stamp (s), quaternion [x, y, z, w] of the body in ENU, the
    covariance (3, 3) of its error about the E, N, U axes in rad^2 or None."""

    stamp: float
    quaternion_xyzw: np.ndarray
    cov_enu: np.ndarray | None


class Position(NamedTuple):
    """A GNSS position: stamp (s), geodetic latitude and longitude (deg), height above the
    WGS-84 ellipsoid (m)."""

    stamp: float
    lat_deg: float
    lon_deg: float
    height_m: float


def _check_frame(frame: str) -> None:
    if frame not in VELOCITY_FRAMES:
        raise ValueError(f"velocity_frame must be one of {', '.join(VELOCITY_FRAMES)}, "
                         f"got {frame!r}")


# ----------------------------------------------------------------------------- plain fields
def covariance_block(cov6x6, first: int = 0, what: str = "twist"
                     ) -> tuple[np.ndarray | None, np.ndarray]:
    """The 3x3 block at ``(first, first)`` of a row-major 6x6 covariance (36 values; 0 = the
    linear part of a twist, 3 = the orientation part of a pose), and which of its 3 axes are
    not provided (a variance of exactly -1 on the diagonal: a receiver without vertical
    velocity).

    The block is None when the covariance is unknown: -1 as the first of the 36 values, or
    the block all zeros on the provided axes. Otherwise the rows and columns of the axes not
    provided are zero with a NaN variance.

    Raises :class:`Refused` for a non-finite value, a negative variance or a block that is
    not positive semi-definite (on the provided axes).
    """
    c = np.asarray(cov6x6, dtype=float).reshape(-1)
    if c.size != 36:
        raise ValueError(f"a 6x6 covariance has 36 values, got {c.size}")
    block = c.reshape(6, 6)[first:first + 3, first:first + 3].copy()
    missing = np.diag(block) == -1.0
    if c[0] == -1.0:
        return None, missing
    keep = ~missing
    sub = block[np.ix_(keep, keep)]
    if not np.isfinite(sub).all():
        raise Refused("nonfinite", f"{what} covariance has a non-finite value")
    d = np.diag(sub)
    if (d < 0.0).any():
        listed = ", ".join(f"{x:g}" for x in d)
        raise Refused("negative_variance",
                      f"{what} covariance has a negative variance ({listed})")
    if not sub.any():
        return None, missing
    sub = 0.5 * (sub + sub.T)
    if float(np.linalg.eigvalsh(sub).min()) < -1e-9 * float(d.max()):
        raise Refused("covariance_not_psd", f"{what} covariance is not positive semi-definite")
    out = np.zeros((3, 3))
    out[np.ix_(keep, keep)] = sub
    out[missing, missing] = math.nan
    return out, missing


def to_enu(v, cov: np.ndarray | None, frame: str) -> tuple[np.ndarray, np.ndarray | None]:
    """A world-frame vector (3,) and its covariance (3, 3) or None, from ``frame`` (enu | ned)
    to ENU."""
    _check_frame(frame)
    v = np.array(v, dtype=float).reshape(3)
    if frame == "enu":
        return v, None if cov is None else np.array(cov, dtype=float)
    v_enu = np.array([v[1], v[0], -v[2]])
    if cov is None:
        return v_enu, None
    c = np.asarray(cov, dtype=float)
    return v_enu, c[np.ix_((1, 0, 2), (1, 0, 2))] * np.array([1.0, 1.0, -1.0])[:, None] \
        * np.array([1.0, 1.0, -1.0])


def world_velocity(linear, cov6x6, frame: str) -> tuple[np.ndarray, np.ndarray | None]:
    """ENU velocity and covariance from a world-frame twist (TwistWithCovarianceStamped):
    ``linear`` (3,) in ``frame``, ``cov6x6`` its 36-value twist covariance.

    A NaN component, or one whose variance is -1 (not provided), is not measured (NaN); an
    infinite one refuses the message, as does a message with no component measured.
    """
    v = np.array(linear, dtype=float).reshape(3)
    cov, missing = covariance_block(cov6x6)
    v[missing] = math.nan
    if np.isinf(v).any() or np.isnan(v).all():
        raise Refused("nonfinite", f"velocity is not finite ({', '.join(f'{x:g}' for x in v)})")
    return to_enu(v, cov, frame)


def horizontal_velocity(linear, frame: str) -> np.ndarray:
    """ENU velocity from a TwistStamped without vertical (nmea_navsat_driver ``vel``): x, y of
    ``linear`` in ``frame`` (enu: East, North; ned: North, East); Up = NaN, z is ignored."""
    _check_frame(frame)
    x, y = float(linear[0]), float(linear[1])
    if not (math.isfinite(x) and math.isfinite(y)):
        raise Refused("nonfinite", f"horizontal velocity is not finite ({x:g}, {y:g})")
    return np.array([x, y, math.nan] if frame == "enu" else [y, x, math.nan])


def body_orientation(q_xyzw) -> np.ndarray:
    """The DCM of an Odometry orientation (body in the world frame), checked: finite, its norm
    within :data:`QUATERNION_NORM_TOLERANCE` of 1 (normalised)."""
    q = np.array(q_xyzw, dtype=float).reshape(4)
    if not np.isfinite(q).all():
        raise Refused("nonfinite", "orientation is not finite")
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise Refused("bad_orientation", f"orientation is not a unit quaternion (norm {n:g}): "
                      "the twist in child_frame_id cannot be rotated into the world frame")
    return dcm_from_quat(q / n)


def odometry_velocity(linear_body, q_xyzw, twist_cov6x6, frame: str,
                      ) -> tuple[np.ndarray, np.ndarray | None]:
    """ENU velocity and covariance from an Odometry twist: ``linear_body`` (3,) in
    ``child_frame_id`` (REP-105), rotated by the orientation ``q_xyzw`` (body in the world
    frame, ``frame`` = enu | ned) into the world frame, then into ENU. The covariance is
    rotated the same way (C P C^T)."""
    C = body_orientation(q_xyzw)
    v_b = np.array(linear_body, dtype=float).reshape(3)
    cov_b, missing = covariance_block(twist_cov6x6)
    if not np.isfinite(v_b).all() or missing.any():
        raise Refused("nonfinite", "body velocity not finite or not provided on every axis "
                      f"({', '.join(f'{x:g}' for x in v_b)}): it cannot be rotated")
    cov_w = None if cov_b is None else C @ cov_b @ C.T
    return to_enu(C @ v_b, cov_w, frame)


def odometry_attitude(q_xyzw, pose_cov6x6, frame: str) -> tuple[np.ndarray, np.ndarray | None]:
    """The master's attitude as the quaternion [x, y, z, w] of its body in ENU, and the
    orientation block of its pose covariance (rad^2 about the world axes, in ENU), or None."""
    _check_frame(frame)
    C = body_orientation(q_xyzw)
    cov, missing = covariance_block(pose_cov6x6, 3, "orientation")
    if missing.any():
        cov = None
    if frame == "ned":
        C = NED_TO_ENU @ C
        if cov is not None:
            cov = NED_TO_ENU @ cov @ NED_TO_ENU.T
    return quat_from_dcm(C), cov


def fix_position(status: int, lat: float, lon: float, alt: float) -> tuple[float, float, float]:
    """(lat deg, lon deg, height m) of a NavSatFix, refused without a fix (status < 0) or
    with a non-finite value."""
    if int(status) < 0:
        what = "unknown" if int(status) == -2 else "no fix"   # -2: STATUS_UNKNOWN (Jazzy)
        raise Refused("no_fix", f"NavSatFix status {int(status)}: {what}")
    vals = (float(lat), float(lon), float(alt))
    if not all(math.isfinite(x) for x in vals):
        raise Refused("nonfinite", "NavSatFix latitude, longitude or altitude is not finite")
    return vals


# ----------------------------------------------------------------------------- messages
#: ``clock(sec, nanosec) -> float s``: the same clock as the IMU samples
#: (:class:`sins_align.ros.outputs.StampClock`).
Clock = Callable[[int, int], float]


def _stamp(msg, clock: Clock) -> float:
    st = msg.header.stamp
    return clock(int(st.sec), int(st.nanosec))


def _xyz(v) -> tuple[float, float, float]:
    return float(v.x), float(v.y), float(v.z)


def from_twist_with_covariance(msg, frame: str, clock: Clock) -> tuple[Velocity, None]:
    """geometry_msgs/TwistWithCovarianceStamped (rclpy or rosbags) -> (Velocity, None)."""
    v, cov = world_velocity(_xyz(msg.twist.twist.linear), msg.twist.covariance, frame)
    return Velocity(_stamp(msg, clock), v, cov), None


def from_twist(msg, frame: str, clock: Clock) -> tuple[Velocity, None]:
    """geometry_msgs/TwistStamped (rclpy or rosbags) -> (Velocity without vertical, None)."""
    return Velocity(_stamp(msg, clock), horizontal_velocity(_xyz(msg.twist.linear), frame),
                    None), None


def from_odometry(msg, frame: str, clock: Clock) -> tuple[Velocity, Attitude]:
    """nav_msgs/Odometry (rclpy or rosbags) -> (Velocity in ENU, the master's Attitude)."""
    o = msg.pose.pose.orientation
    q = (float(o.x), float(o.y), float(o.z), float(o.w))
    v, cov = odometry_velocity(_xyz(msg.twist.twist.linear), q, msg.twist.covariance, frame)
    q_enu, att_cov = odometry_attitude(q, msg.pose.covariance, frame)
    t = _stamp(msg, clock)
    return Velocity(t, v, cov), Attitude(t, q_enu, att_cov)


#: ``velocity_type`` -> adapter ``(msg, frame, clock) -> (Velocity, Attitude | None)``.
CONVERTERS: dict[str, Callable] = {
    "twist_with_covariance": from_twist_with_covariance,
    "twist": from_twist,
    "odometry": from_odometry,
}


def velocity_from_message(kind: str, msg, frame: str, clock: Clock
                          ) -> tuple[Velocity, Attitude | None]:
    """The adapter of ``velocity_type`` ``kind`` applied to ``msg``. Raises :class:`Refused`
    (a message that cannot be used) or ValueError (an unknown kind or frame)."""
    try:
        conv = CONVERTERS[kind]
    except KeyError:
        raise ValueError(f"velocity_type must be one of {', '.join(VELOCITY_TYPES)}, "
                         f"got {kind!r}") from None
    return conv(msg, frame, clock)


def from_navsat(msg, clock: Clock) -> Position:
    """sensor_msgs/NavSatFix (rclpy or rosbags) -> Position. Raises :class:`Refused`."""
    lat, lon, h = fix_position(msg.status.status, msg.latitude, msg.longitude, msg.altitude)
    return Position(_stamp(msg, clock), lat, lon, h)
