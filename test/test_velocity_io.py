"""sins_align.io.velocity: velocity-reference and NavSatFix messages as estimator inputs.

Every expected number is worked out by hand in the test (axis swaps, 90 deg rotations). Each
message test runs twice: on an rclpy message (what align_node receives) and on the same
message serialised and deserialised by rosbags (what replay reads from a bag), so both fronts
get the same numbers from the same adapters.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.serialization import serialize_message
from sensor_msgs.msg import NavSatFix

from sins_align.io import velocity as vel
from sins_align.io.bagio import typestore
from sins_align.ros.outputs import StampClock

S45 = math.sqrt(0.5)


def _as_rclpy(msg):
    return msg


def _as_rosbags(msg):
    """The same message as rosbags reads it from a bag."""
    name = type(msg).__module__.split(".")[0] + "/msg/" + type(msg).__name__
    return typestore().deserialize_cdr(serialize_message(msg), name)


@pytest.fixture(params=[_as_rclpy, _as_rosbags], ids=["rclpy", "rosbags"])
def source(request):
    return request.param


def _stamp(msg, sec=100, nanosec=250_000_000):
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    return msg


def _cov36(linear=None, angular=None):
    c = np.zeros((6, 6))
    if linear is not None:
        c[:3, :3] = linear
    if angular is not None:
        c[3:, 3:] = angular
    return c.reshape(-1).tolist()


def _twist_cov(v, cov36):
    m = _stamp(TwistWithCovarianceStamped())
    m.header.frame_id = "gnss"
    m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z = v
    m.twist.twist.angular.x = 5.0                 # never read
    m.twist.covariance = cov36
    return m


def _clock():
    c = StampClock()
    c(100, 0)                                     # epoch: second 100
    return c


# NED covariance with every term distinct, and its ENU image worked out by hand:
# E = y_NED, N = x_NED, U = -z_NED, so P_EE = P_yy, P_EN = P_yx, P_EU = -P_yz, P_NU = -P_xz.
P_NED = np.array([[0.04, 0.01, 0.002],
                  [0.01, 0.09, 0.003],
                  [0.002, 0.003, 0.25]])
P_ENU = np.array([[0.09, 0.01, -0.003],
                  [0.01, 0.04, -0.002],
                  [-0.003, -0.002, 0.25]])


# ---------------------------------------------------------------- TwistWithCovarianceStamped
def test_twist_with_covariance_enu_is_taken_as_is(source):
    """ENU (ublox fix_velocity): velocity and the linear 3x3 block unchanged; the angular
    block and the angular velocity are not used; the stamp goes through the given clock."""
    lin = np.diag([0.01, 0.04, 0.09])
    lin[0, 1] = lin[1, 0] = 0.005
    m = source(_twist_cov((1.0, 2.0, -0.5), _cov36(lin, np.eye(3) * 7.0)))
    v, att = vel.velocity_from_message("twist_with_covariance", m, "enu", _clock())
    assert att is None
    assert v.stamp == 0.25
    np.testing.assert_array_equal(v.v_enu, [1.0, 2.0, -0.5])
    np.testing.assert_array_equal(v.cov_enu, lin)


def test_twist_with_covariance_ned_swaps_x_y_and_negates_z(source):
    """NED (a Septentrio set to NED): (N 1, E 2, D 3) m/s is (E 2, N 1, U -3); the covariance
    is permuted the same way, signs of the cross terms with Up included."""
    m = source(_twist_cov((1.0, 2.0, 3.0), _cov36(P_NED)))
    v, _ = vel.from_twist_with_covariance(m, "ned", _clock())
    np.testing.assert_array_equal(v.v_enu, [2.0, 1.0, -3.0])
    np.testing.assert_allclose(v.cov_enu, P_ENU, rtol=0, atol=1e-15)


@pytest.mark.parametrize("first", [0.0, -1.0], ids=["all-zero", "minus-one"])
def test_unknown_twist_covariance_is_none(source, first):
    """All zeros, or -1 as the first element: unknown (the configured noise stands in)."""
    cov = [0.0] * 36
    cov[0] = first
    v, _ = vel.from_twist_with_covariance(source(_twist_cov((1.0, 0.0, 0.0), cov)), "enu",
                                          _clock())
    assert v.cov_enu is None


def test_a_linear_block_of_zeros_is_unknown_even_with_the_angular_part_marked(source):
    """What a receiver with an exact (or no) velocity accuracy sends: the linear variances 0,
    the angular one -1 (not provided)."""
    cov = [0.0] * 36
    cov[21] = -1.0
    v, _ = vel.from_twist_with_covariance(source(_twist_cov((1.0, 2.0, 0.5), cov)), "enu",
                                          _clock())
    assert v.cov_enu is None
    np.testing.assert_array_equal(v.v_enu, [1.0, 2.0, 0.5])


@pytest.mark.parametrize("frame, expected", [("enu", [3.0, 4.0, math.nan]),
                                             ("ned", [4.0, 3.0, math.nan])])
def test_a_variance_of_minus_one_on_one_axis_means_that_component_is_not_provided(
        source, frame, expected):
    """A receiver without vertical velocity: variance (2, 2) = -1 and z 0 or NaN. The vertical
    is not measured (NaN) and its row and column drop out; E and N keep theirs."""
    lin = np.array([[0.04, 0.01, 0.0], [0.01, 0.09, 0.0], [0.0, 0.0, -1.0]])
    cov = _cov36(lin)
    cov[21] = -1.0
    v, _ = vel.from_twist_with_covariance(source(_twist_cov((3.0, 4.0, 0.0), cov)), frame,
                                          _clock())
    np.testing.assert_array_equal(v.v_enu, expected)
    horizontal = lin[:2, :2] if frame == "enu" else lin[:2, :2][::-1, ::-1]
    np.testing.assert_array_equal(v.cov_enu[:2, :2], horizontal)
    assert math.isnan(v.cov_enu[2, 2])
    assert not v.cov_enu[2, :2].any() and not v.cov_enu[:2, 2].any()


@pytest.mark.parametrize("diag, reason", [
    ((0.01, -0.01, 0.01), "negative_variance"),
    ((0.01, 0.01, -2.0), "negative_variance"),
    ((0.01, math.nan, 0.01), "nonfinite"),
    ((0.01, 0.01, math.inf), "nonfinite"),
], ids=["negative", "minus-two", "nan", "inf"])
def test_bad_twist_variance_refuses_the_message(source, diag, reason):
    m = source(_twist_cov((1.0, 0.0, 0.0), _cov36(np.diag(diag))))
    with pytest.raises(vel.Refused) as e:
        vel.from_twist_with_covariance(m, "enu", _clock())
    assert e.value.reason == reason
    assert "covariance" in str(e.value)


def test_a_covariance_that_is_not_psd_is_refused():
    """Variances 1 and 1 with covariance 2 (correlation 2): not a covariance."""
    lin = np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    with pytest.raises(vel.Refused) as e:
        vel.world_velocity((0.0, 0.0, 0.0), _cov36(lin), "enu")
    assert e.value.reason == "covariance_not_psd"


def test_velocity_components_nan_is_unmeasured_inf_is_refused():
    v, cov = vel.world_velocity((1.0, 2.0, math.nan), _cov36(np.eye(3)), "ned")
    assert v[0] == 2.0 and v[1] == 1.0 and math.isnan(v[2])
    for bad in ((math.inf, 0.0, 0.0), (math.nan,) * 3):
        with pytest.raises(vel.Refused) as e:
            vel.world_velocity(bad, [0.0] * 36, "enu")
        assert e.value.reason == "nonfinite"


def test_unknown_frame_or_type_is_a_value_error():
    with pytest.raises(ValueError, match="velocity_frame must be one of enu, ned"):
        vel.world_velocity((0.0, 0.0, 0.0), [0.0] * 36, "nwu")
    with pytest.raises(ValueError, match="velocity_type must be one of"):
        vel.velocity_from_message("imu", None, "enu", _clock())


# ---------------------------------------------------------------- TwistStamped
@pytest.mark.parametrize("frame, expected", [("enu", (3.0, 4.0)), ("ned", (4.0, 3.0))])
def test_twist_stamped_is_horizontal_only(source, frame, expected):
    """nmea_navsat_driver vel (x East, y North, z written as 0): Up not measured (NaN), no
    covariance; with velocity_frame ned x is North."""
    m = _stamp(TwistStamped(), 101, 0)
    m.twist.linear.x, m.twist.linear.y, m.twist.linear.z = 3.0, 4.0, 0.0
    v, att = vel.velocity_from_message("twist", source(m), frame, _clock())
    assert att is None and v.cov_enu is None and v.stamp == 1.0
    assert tuple(v.v_enu[:2]) == expected and math.isnan(v.v_enu[2])


def test_twist_stamped_non_finite_is_refused():
    with pytest.raises(vel.Refused) as e:
        vel.horizontal_velocity((math.nan, 1.0, 0.0), "enu")
    assert e.value.reason == "nonfinite"


# ---------------------------------------------------------------- Odometry
def _odom(q, v_body, twist_cov=None, pose_cov=None):
    m = _stamp(Odometry(), 102, 500_000_000)
    m.header.frame_id, m.child_frame_id = "map", "base_link"
    o = m.pose.pose.orientation
    o.x, o.y, o.z, o.w = q
    m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z = v_body
    m.twist.covariance = twist_cov if twist_cov is not None else [0.0] * 36
    m.pose.covariance = pose_cov if pose_cov is not None else [0.0] * 36
    return m


def test_odometry_twist_is_rotated_from_the_body_into_enu(source):
    """A master INS whose body x points North (REP-103 yaw 90 deg) driving forward at 10 m/s
    and sliding left at 1 m/s moves North 10, West 1: ENU (-1, 10, 0). Its body covariance
    diag(1, 4, 9) becomes diag(4, 1, 9) in ENU. The attitude is passed on unchanged."""
    q = (0.0, 0.0, S45, S45)
    m = source(_odom(q, (10.0, 1.0, 0.0), _cov36(np.diag([1.0, 4.0, 9.0])),
                     _cov36(angular=np.diag([1e-6, 2e-6, 3e-6]))))
    v, att = vel.velocity_from_message("odometry", m, "enu", _clock())
    assert v.stamp == att.stamp == 2.5
    np.testing.assert_allclose(v.v_enu, [-1.0, 10.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(v.cov_enu, np.diag([4.0, 1.0, 9.0]), atol=1e-12)
    np.testing.assert_allclose(att.quaternion_xyzw, q, atol=1e-12)
    np.testing.assert_allclose(att.cov_enu, np.diag([1e-6, 2e-6, 3e-6]), atol=1e-18)


def test_odometry_in_ned_gives_enu_velocity_and_attitude(source):
    """NED world, FRD body heading East (yaw 90 deg about Down): forward 10 m/s and 1 m/s
    down is NED (0, 10, 1), ENU (10, 0, -1). The body in ENU is x East, y South, z Down:
    180 deg about x, quaternion (1, 0, 0, 0). The pose's orientation variances about N, E, D
    (1, 2, 3 e-6) are about E, N, U (2, 1, 3 e-6)."""
    m = source(_odom((0.0, 0.0, S45, S45), (10.0, 0.0, 1.0), None,
                     _cov36(angular=np.diag([1e-6, 2e-6, 3e-6]))))
    v, att = vel.from_odometry(m, "ned", _clock())
    np.testing.assert_allclose(v.v_enu, [10.0, 0.0, -1.0], atol=1e-12)
    assert v.cov_enu is None
    q = att.quaternion_xyzw * np.sign(att.quaternion_xyzw[0])
    np.testing.assert_allclose(q, [1.0, 0.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(att.cov_enu, np.diag([2e-6, 1e-6, 3e-6]), atol=1e-18)


def test_odometry_twist_with_an_axis_not_provided_is_refused():
    """A body velocity with a component missing cannot be rotated into the world frame."""
    lin = np.diag([0.01, 0.01, -1.0])
    with pytest.raises(vel.Refused) as e:
        vel.odometry_velocity((10.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), _cov36(lin), "enu")
    assert e.value.reason == "nonfinite" and "cannot be rotated" in str(e.value)


def test_odometry_non_unit_quaternion_is_normalised_within_tolerance():
    v, _ = vel.odometry_velocity((10.0, 0.0, 0.0), (0.0, 0.0, 1.005 * S45, 1.005 * S45),
                                 [0.0] * 36, "enu")
    np.testing.assert_allclose(v, [0.0, 10.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("q, reason", [((0.0, 0.0, 0.0, 0.0), "bad_orientation"),
                                       ((0.0, 0.0, 0.0, 2.0), "bad_orientation"),
                                       ((math.nan, 0.0, 0.0, 1.0), "nonfinite")])
def test_odometry_without_a_usable_orientation_is_refused(source, q, reason):
    """A zero quaternion (a driver that fills no orientation) cannot rotate the twist."""
    with pytest.raises(vel.Refused) as e:
        vel.from_odometry(source(_odom(q, (1.0, 0.0, 0.0))), "enu", _clock())
    assert e.value.reason == reason


# ---------------------------------------------------------------- NavSatFix
def _fix(status, lat=34.25, lon=108.75, alt=412.5):
    m = _stamp(NavSatFix(), 103, 0)
    m.status.status = status
    m.latitude, m.longitude, m.altitude = lat, lon, alt
    return m


def test_navsat_fix_gives_the_position(source):
    p = vel.from_navsat(source(_fix(0)), _clock())
    assert p == vel.Position(3.0, 34.25, 108.75, 412.5)
    assert vel.from_navsat(source(_fix(2)), _clock()).lat_deg == 34.25      # GBAS fix


@pytest.mark.parametrize("kw, reason", [({"status": -1}, "no_fix"),
                                        ({"status": 0, "alt": math.nan}, "nonfinite"),
                                        ({"status": 0, "lat": math.inf}, "nonfinite")])
def test_navsat_without_fix_or_finite_values_is_refused(source, kw, reason):
    with pytest.raises(vel.Refused) as e:
        vel.from_navsat(source(_fix(**kw)), _clock())
    assert e.value.reason == reason


def test_message_type_names_are_the_ros2_ones():
    """What replay looks for in a bag's topic list."""
    ts = typestore()
    for name in (*vel.VELOCITY_TYPES.values(), vel.NAVSAT_TYPE):
        assert name in ts.types, name
