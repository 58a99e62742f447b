"""Field values of the simulated GNSS messages, shared by imu_sim_node and the simulate tool.

As :mod:`sins_align.io.imu_fields` for the IMU: one place turns GNSS arrays into the numbers
of a ``geometry_msgs/TwistWithCovarianceStamped`` (velocity) and a ``sensor_msgs/NavSatFix``
(position), so a bag and a live run carry identical fields. No ROS imports here (numpy only):
imu_sim_node fills rclpy messages with these values, the simulate tool passes them to the
rosbags builders of :mod:`sins_align.io.reference_msgs` (where the NavSatFix constants are
defined too).

Conventions (as the ublox_gps driver publishes them)
----------------------------------------------------
- ``gnss/fix_velocity``: ``twist.linear`` = antenna velocity in ENU, m/s (x East, y North,
  z Up; the frame_id is the antenna's, the axes are ENU). ``twist.angular`` = 0, not
  provided. ``covariance`` (6x6 row-major): ``diag(sigma^2, sigma^2, sigma^2)`` for the
  linear part, element (3, 3) = -1 (angular rate not provided), the rest 0; ``sigma = 0``
  (an exact simulated velocity) leaves the linear part at zeros. Without a vertical
  velocity (NMEA-style receivers) ``linear.z`` is NaN and element (2, 2) is -1.
- ``gnss/fix``: latitude, longitude in deg, altitude in m above the WGS-84 ellipsoid (the
  message's definition), ``status`` STATUS_FIX with SERVICE_GPS, ``position_covariance``
  ``diag(sigma_p^2)`` ENU with COVARIANCE_TYPE_DIAGONAL_KNOWN, or zeros with
  COVARIANCE_TYPE_UNKNOWN when ``sigma_p = 0``.
- Stamps: ``header.stamp`` is the measurement time; a latency delays the delivery only
  (``arrival_ns``: the log time in a bag, the data time of publication in the node).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from sins_align.io.imu_fields import split_stamp
from sins_align.io.reference_msgs import (COVARIANCE_TYPE_DIAGONAL_KNOWN,
                                          COVARIANCE_TYPE_UNKNOWN, SERVICE_GPS, STATUS_FIX,
                                          covariance3)

__all__ = ["GNSS_VELOCITY_TOPIC", "GNSS_FIX_TOPIC", "GNSS_FRAME", "STATUS_FIX", "SERVICE_GPS",
           "COVARIANCE_TYPE_UNKNOWN", "COVARIANCE_TYPE_DIAGONAL_KNOWN", "velocity_covariance",
           "position_covariance", "GnssFields", "gnss_fields", "epoch_stamps_ns"]

#: Relative topic names (resolved at root in bags: /gnss/fix_velocity, /gnss/fix).
GNSS_VELOCITY_TOPIC = "gnss/fix_velocity"
GNSS_FIX_TOPIC = "gnss/fix"
#: Default frame_id of the GNSS messages (the antenna).
GNSS_FRAME = "gnss_link"


def velocity_covariance(sigma: float, vertical: bool = True) -> tuple[float, ...]:
    """The 36 row-major values of a ``TwistWithCovariance`` covariance (see the module
    docstring)."""
    c = [0.0] * 36
    var = float(sigma) ** 2
    c[0] = c[7] = var
    c[14] = var if vertical else -1.0
    c[21] = -1.0
    return tuple(c)


def position_covariance(sigma: float) -> tuple[tuple[float, ...], int]:
    """``(position_covariance, position_covariance_type)`` of a NavSatFix."""
    if sigma > 0.0:
        return tuple(covariance3(sigma).tolist()), COVARIANCE_TYPE_DIAGONAL_KNOWN
    return (0.0,) * 9, COVARIANCE_TYPE_UNKNOWN


@dataclass(frozen=True)
class GnssFields:
    """Field values of one GNSS epoch: its velocity and its fix (same header)."""

    sec: int
    nanosec: int
    arrival_ns: int
    frame_id: str
    velocity_enu: tuple[float, float, float]
    velocity_covariance: tuple[float, ...]
    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    position_covariance: tuple[float, ...]
    position_covariance_type: int

    @property
    def stamp_ns(self) -> int:
        return self.sec * 1_000_000_000 + self.nanosec


def gnss_fields(stamps_ns, arrival_ns, velocity_enu, llh, velocity_sigma: float,
                position_sigma: float, vertical: bool = True,
                frame_id: str = GNSS_FRAME) -> Iterator[GnssFields]:
    """GNSS message fields for M epochs.

    Parameters
    ----------
    stamps_ns : (M,) int — measurement times, ns (the header stamps).
    arrival_ns : (M,) int — delivery times, ns.
    velocity_enu : (M, 3) m/s — antenna velocity, ENU (z NaN when not ``vertical``).
    llh : (M, 3) — antenna latitude (rad), longitude (rad), height (m).
    velocity_sigma, position_sigma : m/s, m — the noise std per axis.
    vertical : whether the velocity has a vertical component.
    frame_id : the antenna frame.
    """
    st = np.asarray(stamps_ns, dtype=np.int64).tolist()
    ar = np.asarray(arrival_ns, dtype=np.int64).tolist()
    v = np.asarray(velocity_enu, dtype=float).reshape(-1, 3).tolist()
    p = np.asarray(llh, dtype=float).reshape(-1, 3)
    if not (len(st) == len(ar) == len(v) == len(p)):
        raise ValueError(f"GNSS arrays lengths differ: {len(st)}, {len(ar)}, {len(v)}, "
                         f"{len(p)}")
    if not (math.isfinite(velocity_sigma) and velocity_sigma >= 0.0
            and math.isfinite(position_sigma) and position_sigma >= 0.0):
        raise ValueError("GNSS noise std must be finite and >= 0")
    vcov = velocity_covariance(velocity_sigma, vertical)
    pcov, ptype = position_covariance(position_sigma)
    deg = np.degrees(p[:, :2]).tolist()
    alt = p[:, 2].tolist()
    for ns, arr, vk, (la, lo), h in zip(st, ar, v, deg, alt):
        sec, nsec = split_stamp(ns)
        yield GnssFields(sec, nsec, arr, frame_id, tuple(vk), vcov, la, lo, h, pcov, ptype)


def epoch_stamps_ns(t0_ns: int, rate_hz: float, index) -> np.ndarray:
    """Stamps of truth instants ``index`` (k / rate after t0), int64 ns: the same grid as
    :func:`sins_align.io.imu_fields.sample_stamps_ns` (IMU sample k-1 ends at index k)."""
    k = np.asarray(index, dtype=np.int64)
    return int(t0_ns) + np.rint(k * (1e9 / float(rate_hz))).astype(np.int64)
