"""Field values of the raw IMU and truth messages, shared by imu_sim_node and the bag tools.

One place turns sample arrays and sensor specs into the numbers that go into
``sensor_msgs/Imu`` (and the ``geometry_msgs/QuaternionStamped`` truth). The live simulator
node fills rclpy messages from these values, ``simulate`` and ``import_imu`` fill rosbags
messages from the same values, so a bag and a live run carry identical fields.
No ROS imports here (numpy only).

Conventions (REP-145, ALGORITHM.md)
-----------------------------------
- ``angular_velocity``: rad/s, body axes (the ``frame_id`` frame).
- ``linear_acceleration``: specific force, m/s^2 (a level IMU at rest reads about +g up).
- Covariances: 9 values, row-major. All zeros = unknown; element 0 = -1 = field not
  provided (a raw IMU has no orientation).
- Stamps: integer nanoseconds; ``split_stamp`` gives the ``(sec, nanosec)`` of a header.
- Truth: quaternion ``[x, y, z, w]`` of the true ``C_b^n`` (IMU frame in ENU), with the
  same header (stamp and ``frame_id``) as the IMU sample it belongs to.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from sins_align.core.specs import SensorSpecs

#: Default frame of the raw IMU messages (the body frame b).
IMU_FRAME = "imu_link"
#: Relative topic names used by imu_sim_node (resolved at root in bags: /imu/data_raw ...).
RAW_TOPIC = "imu/data_raw"
TRUTH_TOPIC = "imu_sim/truth"

Cov9 = tuple[float, float, float, float, float, float, float, float, float]

#: Covariance not known (REP-145: all zeros).
UNKNOWN_COVARIANCE: Cov9 = (0.0,) * 9
#: Field not provided (REP-145: element 0 = -1), e.g. the orientation of a raw IMU.
NOT_PROVIDED_COVARIANCE: Cov9 = (-1.0,) + (0.0,) * 8
#: Orientation of a raw IMU message (no orientation estimate).
NO_ORIENTATION_XYZW = (0.0, 0.0, 0.0, 1.0)

NS_PER_S = 1_000_000_000
#: First second a ``builtin_interfaces/Time`` cannot hold (``sec`` is an int32).
MAX_STAMP_S = 2 ** 31


def diagonal_covariance(variance: float) -> Cov9:
    """Row-major 3x3 covariance ``variance * I`` (isotropic sensor), 9 floats."""
    v = float(variance)
    return (v, 0.0, 0.0, 0.0, v, 0.0, 0.0, 0.0, v)


@dataclass(frozen=True)
class ImuCovariances:
    """The three covariance fields of a raw ``sensor_msgs/Imu``.

    Attributes
    ----------
    angular_velocity : 9 floats, (rad/s)^2.
    linear_acceleration : 9 floats, (m/s^2)^2.
    orientation : 9 floats — :data:`NOT_PROVIDED_COVARIANCE` for a raw IMU.
    """

    angular_velocity: Cov9 = UNKNOWN_COVARIANCE
    linear_acceleration: Cov9 = UNKNOWN_COVARIANCE
    orientation: Cov9 = NOT_PROVIDED_COVARIANCE


def imu_covariances(specs: SensorSpecs | None, rate_hz: float) -> ImuCovariances:
    """REP-145 covariances of one sample from the sensor specs.

    The white-noise part of one sample's error, diagonal (isotropic specs):
    ``arw^2 * rate`` (rad/s)^2 and ``vrw^2 * rate`` (m/s^2)^2. The constant biases are not
    included (they are not noise of a sample). ``specs=None`` gives "unknown" (all zeros).

    Parameters
    ----------
    specs : SensorSpecs or None — SI units (rad/s, rad/sqrt(s), m/s^2, m/s/sqrt(s)).
    rate_hz : float, Hz — sample rate (> 0).
    """
    if specs is None:
        return ImuCovariances()
    if not (math.isfinite(rate_hz) and rate_hz > 0.0):
        raise ValueError(f"rate must be > 0 Hz, got {rate_hz!r}")
    gyro = specs.gyro_arw ** 2 * rate_hz
    accel = specs.accel_vrw ** 2 * rate_hz
    return ImuCovariances(diagonal_covariance(gyro), diagonal_covariance(accel))


def stamp_ns(t_s: float) -> int:
    """Seconds (float) to integer nanoseconds, rounded."""
    return int(round(float(t_s) * NS_PER_S))


def split_stamp(ns: int) -> tuple[int, int]:
    """Integer nanoseconds to the ``(sec, nanosec)`` of a ``builtin_interfaces/Time``."""
    ns = int(ns)
    return ns // NS_PER_S, ns % NS_PER_S


def sample_stamps_ns(t0_s: float, rate_hz: float, first: int, n: int) -> np.ndarray:
    """Stamps of simulated samples ``first .. first + n - 1`` (0-based), int64 ns.

    Sample ``k`` is stamped ``t0 + (k + 1) / rate`` (as :mod:`sins_align.sim.simulator`), computed
    in integer nanoseconds from ``t0`` so that epoch-sized ``t0`` keeps full resolution.
    """
    k = np.arange(first + 1, first + n + 1, dtype=np.int64)
    return stamp_ns(t0_s) + np.rint(k * (NS_PER_S / float(rate_hz))).astype(np.int64)


@dataclass(frozen=True)
class ImuFields:
    """Field values of one raw ``sensor_msgs/Imu`` message (orientation not provided)."""

    sec: int
    nanosec: int
    frame_id: str
    angular_velocity: tuple[float, float, float]
    linear_acceleration: tuple[float, float, float]
    covariances: ImuCovariances
    orientation_xyzw: tuple[float, float, float, float] = NO_ORIENTATION_XYZW

    @property
    def stamp_ns(self) -> int:
        return self.sec * NS_PER_S + self.nanosec


@dataclass(frozen=True)
class TruthFields:
    """Field values of one truth ``geometry_msgs/QuaternionStamped`` (true C_b^n)."""

    sec: int
    nanosec: int
    frame_id: str
    quaternion_xyzw: tuple[float, float, float, float]

    @property
    def stamp_ns(self) -> int:
        return self.sec * NS_PER_S + self.nanosec


def imu_fields(stamps_ns, gyro, accel, covariances: ImuCovariances,
               frame_id: str = IMU_FRAME) -> Iterator[ImuFields]:
    """Raw IMU message fields for a block of samples.

    Parameters
    ----------
    stamps_ns : (N,) int — header stamps, ns.
    gyro : (N, 3) rad/s — angular rate, body axes.
    accel : (N, 3) m/s^2 — specific force, body axes.
    covariances : ImuCovariances — the same for every sample.
    frame_id : str — the body frame.
    """
    st = np.asarray(stamps_ns, dtype=np.int64)
    w = np.asarray(gyro, dtype=float).reshape(-1, 3).tolist()
    a = np.asarray(accel, dtype=float).reshape(-1, 3).tolist()
    if not (len(st) == len(w) == len(a)):
        raise ValueError(f"stamps, gyro and accel lengths differ: {len(st)}, {len(w)}, {len(a)}")
    for ns, wk, ak in zip(st.tolist(), w, a):
        sec, nsec = split_stamp(ns)
        yield ImuFields(sec, nsec, frame_id, tuple(wk), tuple(ak), covariances)


def truth_fields(stamps_ns, quat_xyzw, frame_id: str = IMU_FRAME) -> Iterator[TruthFields]:
    """Truth message fields: ``quat_xyzw`` (N, 4) of the true C_b^n at ``stamps_ns`` (N,).

    ``frame_id`` is the IMU sample's (the truth shares its header, as imu_sim_node does).
    """
    st = np.asarray(stamps_ns, dtype=np.int64)
    q = np.asarray(quat_xyzw, dtype=float).reshape(-1, 4).tolist()
    if len(st) != len(q):
        raise ValueError(f"stamps and quaternions lengths differ: {len(st)}, {len(q)}")
    for ns, qk in zip(st.tolist(), q):
        sec, nsec = split_stamp(ns)
        yield TruthFields(sec, nsec, frame_id, tuple(qk))
