"""Reference-sensor messages for bags written with rosbags: a master INS as
``nav_msgs/Odometry``, its velocity as ``geometry_msgs/TwistWithCovarianceStamped`` and its
position as ``sensor_msgs/NavSatFix``; and the frame conversions that fill them. The one set
of builders of these messages: ``import_imu`` writes a master INS with them, ``simulate`` the
GNSS receiver (its field values from :mod:`sins_align.io.gnss_fields`).

No ROS imports: the messages are rosbags objects of the ROS 2 Jazzy typestore
(:func:`sins_align.io.bagio.typestore`), serialised with ``store.serialize_cdr``.

Conventions (REP-103, REP-105, ALGORITHM.md)
--------------------------------------------
- World frame: a local-level frame with ENU axes (default name :data:`WORLD_FRAME`,
  ``enu``). Orientations are C_b^n of the body in ENU as quaternions ``[x, y, z, w]``.
- ``Odometry``: ``header.frame_id`` the world frame, ``child_frame_id`` the body frame;
  ``pose`` in the world frame; ``twist`` in the **child** frame: linear = ``C_b^n^T v^n``
  (:func:`body_velocity`), angular = rate of the body relative to the world frame in body
  axes (:func:`body_rates`).
- ``TwistWithCovarianceStamped`` of a velocity reference: ``header.frame_id`` the world
  frame, so the twist is in ENU (linear = ``v^n``, angular = ``C_b^n`` times the body rate).
- ``NavSatFix``: latitude and longitude in degrees, altitude in metres as the source gives
  it; ``position_covariance`` in m^2, ENU, row-major.
- Covariances: 6x6 row-major over (x, y, z, rotation about x, y, z); 3x3 row-major.
- Stamps: integer nanoseconds (:func:`sins_align.io.imu_fields.split_stamp`).
"""
from __future__ import annotations

import numpy as np

from sins_align.io.imu_fields import split_stamp

ODOMETRY = "nav_msgs/msg/Odometry"
TWIST_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/TwistWithCovarianceStamped"
NAV_SAT_FIX = "sensor_msgs/msg/NavSatFix"

#: Relative topic names of a master INS (resolved at root in bags: /master/odom ...).
MASTER_ODOM_TOPIC = "master/odom"
MASTER_VELOCITY_TOPIC = "master/velocity"
MASTER_FIX_TOPIC = "master/fix"
#: Default world frame (local level, ENU axes) and body frame of a master INS.
WORLD_FRAME = "enu"
MASTER_FRAME = "master_link"

#: sensor_msgs/NavSatFix position_covariance_type values
COVARIANCE_TYPE_UNKNOWN = 0
COVARIANCE_TYPE_APPROXIMATED = 1
COVARIANCE_TYPE_DIAGONAL_KNOWN = 2
#: sensor_msgs/NavSatStatus: a fix; the service unknown or GPS
STATUS_FIX = 0
SERVICE_UNKNOWN = 0
SERVICE_GPS = 1


def covariance6(linear_std: float, angular_std: float) -> np.ndarray:
    """Row-major 6x6 diagonal covariance (36 floats): ``linear_std^2`` on x, y, z and
    ``angular_std^2`` on the three rotations (units of the field: m or m/s, rad or rad/s)."""
    return np.diag([float(linear_std) ** 2] * 3 + [float(angular_std) ** 2] * 3).reshape(36)


def covariance3(std: float) -> np.ndarray:
    """Row-major 3x3 diagonal covariance (9 floats) ``std^2 * I``."""
    return (float(std) ** 2 * np.eye(3)).reshape(9)


def body_velocity(C_bn: np.ndarray, v_n: np.ndarray) -> np.ndarray:
    """Velocity in body axes ``C_b^n^T v^n`` (REP-105 twist of an Odometry).

    C_bn : (..., 3, 3); v_n : (..., 3), m/s, ENU. Returns (..., 3), m/s.
    """
    return np.einsum("...ji,...j->...i", np.asarray(C_bn, float), np.asarray(v_n, float))


def body_rates(t: np.ndarray, C_bn: np.ndarray) -> np.ndarray:
    """Angular rate of the body relative to the navigation frame, in body axes, rad/s, from
    a sequence of attitudes: ``log(C_k-1^T C_k+1) / (t_k+1 - t_k-1)`` (central difference;
    one-sided at the two ends).

    t : (M,), s, increasing, M >= 2; C_bn : (M, 3, 3). Returns (M, 3). With M == 1: zeros.
    """
    from sins_align.core.rotation import so3_log

    t = np.asarray(t, dtype=float)
    C = np.asarray(C_bn, dtype=float)
    m = t.shape[0]
    if m < 2:
        return np.zeros((m, 3))
    lo = np.maximum(np.arange(m) - 1, 0)
    hi = np.minimum(np.arange(m) + 1, m - 1)
    rel = np.einsum("kji,kjl->kil", C[lo], C[hi])          # C_lo^T C_hi
    return so3_log(rel) / (t[hi] - t[lo])[:, None]


def local_enu(lat_rad, lon_rad, height_m, origin: tuple[float, float, float]) -> np.ndarray:
    """East, north, up offsets (m) of geodetic positions from ``origin`` = (lat, lon, h):
    a flat-Earth approximation with the WGS-84 radii of curvature at the origin (error
    about ``d^2 / (2 R)``: 0.2 m at 1.5 km).

    lat_rad, lon_rad : (M,), rad; height_m : (M,), m. Returns (M, 3).
    """
    from sins_align.core.earth import radii

    lat0, lon0, h0 = (float(x) for x in origin)
    rm, rn = radii(lat0)
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    h = np.asarray(height_m, dtype=float)
    dlon = (lon - lon0 + np.pi) % (2.0 * np.pi) - np.pi
    return np.stack([dlon * (rn + h0) * np.cos(lat0), (lat - lat0) * (rm + h0), h - h0], -1)


def header(store, stamp_ns: int, frame_id: str):
    """``std_msgs/Header`` of a stamp in ns."""
    sec, nsec = split_stamp(stamp_ns)
    t = store.types
    return t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=int(sec), nanosec=int(nsec)),
        frame_id=frame_id)


def _vector3(store, xyz):
    return store.types["geometry_msgs/msg/Vector3"](x=float(xyz[0]), y=float(xyz[1]),
                                                    z=float(xyz[2]))


def _twist(store, linear, angular):
    return store.types["geometry_msgs/msg/Twist"](linear=_vector3(store, linear),
                                                  angular=_vector3(store, angular))


def _cov(values, n: int) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64).reshape(-1)
    if a.size != n:
        raise ValueError(f"a covariance needs {n} values, got {a.size}")
    return a


def odometry(store, stamp_ns: int, frame_id: str, child_frame_id: str, position,
             orientation_xyzw, pose_covariance, linear, angular, twist_covariance):
    """``nav_msgs/Odometry``.

    position : 3 floats, m, in ``frame_id``; orientation_xyzw : C_b^n of the child frame in
    ``frame_id``; linear (m/s) and angular (rad/s) : the twist in ``child_frame_id`` axes;
    pose_covariance, twist_covariance : 36 floats each (:func:`covariance6`).
    """
    t = store.types
    q = orientation_xyzw
    pose = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=float(position[0]), y=float(position[1]),
                                              z=float(position[2])),
        orientation=t["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]),
                                                      z=float(q[2]), w=float(q[3])))
    return t[ODOMETRY](
        header=header(store, stamp_ns, frame_id), child_frame_id=child_frame_id,
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose,
                                                       covariance=_cov(pose_covariance, 36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=_twist(store, linear, angular), covariance=_cov(twist_covariance, 36)))


def twist_with_covariance_stamped(store, stamp_ns: int, frame_id: str, linear, angular,
                                  covariance):
    """``geometry_msgs/TwistWithCovarianceStamped``: linear (m/s) and angular (rad/s) in
    ``frame_id`` axes, covariance 36 floats."""
    t = store.types
    return t[TWIST_WITH_COVARIANCE_STAMPED](
        header=header(store, stamp_ns, frame_id),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=_twist(store, linear, angular),
                                                         covariance=_cov(covariance, 36)))


def nav_sat_fix(store, stamp_ns: int, frame_id: str, latitude_deg: float,
                longitude_deg: float, altitude_m: float, position_covariance,
                covariance_type: int = COVARIANCE_TYPE_APPROXIMATED, status: int = STATUS_FIX,
                service: int = SERVICE_UNKNOWN):
    """``sensor_msgs/NavSatFix``: degrees, metres, ENU position covariance (9 floats, m^2)."""
    t = store.types
    return t[NAV_SAT_FIX](
        header=header(store, stamp_ns, frame_id),
        status=t["sensor_msgs/msg/NavSatStatus"](status=int(status), service=int(service)),
        latitude=float(latitude_deg), longitude=float(longitude_deg),
        altitude=float(altitude_m), position_covariance=_cov(position_covariance, 9),
        position_covariance_type=int(covariance_type))
