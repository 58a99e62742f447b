"""Rotation utilities: exact, singularity-free, and in the conventions of ALGORITHM.md."""
import numpy as np
import pytest

from sins_align.core import rotation as r
from sins_align.core.specs import DEG


def random_dcms(n, seed=0):
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return r.dcm_from_quat(q / np.linalg.norm(q, axis=1, keepdims=True))


def test_exp_log_roundtrip_all_angles_including_pi():
    """so3_log inverts so3_exp for random rotations and at 0, 1e-9, pi - 1e-9 and pi."""
    C = random_dcms(2000)
    assert np.abs(r.so3_exp(r.so3_log(C)) - C).max() < 1e-14
    for ang in (0.0, 1e-9, 1e-5, np.pi - 1e-9, np.pi):
        for axis in np.eye(3).tolist() + [[1 / np.sqrt(3)] * 3]:
            rv = ang * np.array(axis)
            C1 = r.so3_exp(rv)
            assert np.abs(C1 @ C1.T - np.eye(3)).max() < 1e-15
            assert np.abs(r.so3_exp(r.so3_log(C1)) - C1).max() < 1e-14
            assert abs(np.linalg.norm(r.so3_log(C1)) - ang) < 1e-12


def test_exp_matches_series():
    """Rodrigues agrees with a long matrix power series (no convention slip)."""
    rv = np.array([0.3, -1.1, 2.0])
    K = r.skew(rv)
    E, term = np.eye(3), np.eye(3)
    for k in range(1, 40):
        term = term @ K / k
        E = E + term
    assert np.abs(r.so3_exp(rv) - E).max() < 1e-13


def test_quaternion_dcm_consistent():
    """quat <-> dcm round trip; the product of quaternions is the product of DCMs; w >= 0."""
    C = random_dcms(500, 1)
    q = r.quat_from_dcm(C)
    assert (q[:, 3] >= 0).all()
    assert np.abs(r.dcm_from_quat(q) - C).max() < 1e-14
    qp = r.quat_multiply(q[:-1], q[1:])
    assert np.abs(r.dcm_from_quat(qp) - C[:-1] @ C[1:]).max() < 1e-14
    rv = r.so3_log(C)
    assert np.abs(r.dcm_from_quat(r.quat_from_rotvec(rv)) - C).max() < 1e-14


def test_rep103_rpy_definition():
    """C = Rz(yaw) Ry(pitch) Rx(roll): yaw 90 deg turns body x from East to North."""
    C = r.dcm_from_rpy(np.array([0.0, 0.0, 90.0]) * DEG)
    assert np.allclose(C @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    C = r.dcm_from_rpy(np.array([0.0, 30.0, 0.0]) * DEG)   # nose down for positive pitch
    assert C[2, 0] == pytest.approx(-np.sin(30 * DEG))


@pytest.mark.parametrize("rpy", [(10, 90, 20), (10, -90, 20), (0, 89.9999, 179.9), (180, 0, 0),
                                 (179.9, 1, -179.9), (-180, 45, 180), (0, 0, 180), (0, 0, -180)])
def test_rpy_roundtrip_singular_and_upside_down(rpy):
    """rpy_from_dcm reproduces the rotation at pitch +-90, heading +-180 and upside down."""
    C = r.dcm_from_rpy(np.array(rpy, dtype=float) * DEG)
    assert np.abs(r.dcm_from_rpy(r.rpy_from_dcm(C)) - C).max() < 1e-9


def test_rpy_roundtrip_random():
    C = random_dcms(1000, 2)
    assert np.abs(r.dcm_from_rpy(r.rpy_from_dcm(C)) - C).max() < 1e-12


def test_true_heading_clockwise_from_north():
    """Body x East = 90 deg, North = 0, West = 270, South = 180; defined when x is vertical."""
    for yaw, hdg in ((0, 90), (90, 0), (180, 270), (-90, 180), (45, 45)):
        C = r.dcm_from_rpy(np.array([0, 0, yaw]) * DEG)
        assert r.heading_from_dcm(C) / DEG == pytest.approx(hdg % 360, abs=1e-9)
    C = r.dcm_from_rpy(np.array([0, 90, 30]) * DEG)       # x points down
    h = r.heading_from_dcm(C)
    assert np.isfinite(h) and 0 <= h < 2 * np.pi


def test_attitude_error_convention():
    """phi satisfies C_true = exp(phi x) C_est (paper eq. 15), also for large angles."""
    C = random_dcms(100, 3)
    phi = np.random.default_rng(4).normal(size=(100, 3))
    Ct = r.so3_exp(phi) @ C
    got = r.attitude_error(Ct, C)
    assert np.abs(r.so3_exp(got) @ C - Ct).max() < 1e-13


@pytest.mark.parametrize("roll", [0.0, 25.0, -160.0])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_heading_at_and_near_the_poles_of_pitch(roll, sign):
    """heading = 90 deg - yaw (rpy_from_dcm) mod 360 for pitch swept up to exactly +-90 deg;
    with roll 0 also equal to the direct construction 90 deg - yaw (continuous at the pole).
    The sign of the offset at the pole (x axis vertical) matters: heading(y) - 90 deg fails."""
    pitches = sign * np.concatenate([np.linspace(0.0, 89.0, 90),
                                     90.0 - np.logspace(0, -12, 25), [90.0]])
    for yaw in (30.0, -100.0, 0.0, 179.0):
        rpy = np.stack([np.full_like(pitches, roll), pitches, np.full_like(pitches, yaw)], -1)
        C = r.dcm_from_rpy(rpy * DEG)
        h = r.heading_from_dcm(C) / DEG
        assert ((h >= 0) & (h < 360)).all()
        ref = 90.0 - r.rpy_from_dcm(C)[:, 2] / DEG
        d = (h - ref + 180.0) % 360.0 - 180.0
        assert np.abs(d).max() < 1e-6, (yaw, pitches[np.argmax(np.abs(d))])
        # single matrices take the same route
        assert r.heading_from_dcm(C[-1]) / DEG == pytest.approx(h[-1], abs=1e-12)
        if roll == 0.0:
            # the direct construction: body x at azimuth 90 - yaw wherever it is not vertical,
            # and the same value (the limit) at the pole
            d = (h - (90.0 - yaw) + 180.0) % 360.0 - 180.0
            assert np.abs(d).max() < 1e-6, (yaw, pitches[np.argmax(np.abs(d))])


def test_heading_pole_against_body_y_axis():
    """At exactly pitch +90 deg (x down) and -90 deg (x up) with yaw 30 deg: heading 60 deg,
    and the body y axis (horizontal) points at heading - 90 deg."""
    for p in (90.0, -90.0):
        C = r.dcm_from_rpy(np.array([0.0, p, 30.0]) * DEG)
        assert r.heading_from_dcm(C) / DEG == pytest.approx(60.0, abs=1e-9)
        y = C[:, 1]
        assert np.degrees(np.arctan2(y[0], y[1])) % 360 == pytest.approx(330.0, abs=1e-9)


def test_left_jacobian_inverse_maps_a_small_error_about_a_rotation():
    """log(exp(e x) exp(phi x)) = phi + J_l^-1(phi) e to first order, at small, medium and
    near-pi angles (where the error normal to phi is magnified by (theta/2)/sin(theta/2))."""
    import math
    so3_left_jacobian_inv, so3_log, so3_exp = r.so3_left_jacobian_inv, r.so3_log, r.so3_exp
    rng = np.random.default_rng(3)
    phis = [np.zeros(3), np.array([0.0, 0.0, 1e-6]), rng.normal(size=3) * 0.3,
            np.array([0.0, 0.0, 2.0]), np.array([0.1, -0.2, 3.1]) / np.linalg.norm(
                [0.1, -0.2, 3.1]) * 3.1]
    J = so3_left_jacobian_inv(np.array(phis))
    assert J.shape == (len(phis), 3, 3)
    for phi, Jk in zip(phis, J):
        assert np.allclose(so3_left_jacobian_inv(phi), Jk)
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1e-6
            num = (so3_log(so3_exp(e) @ so3_exp(phi)) - so3_log(so3_exp(-e) @ so3_exp(phi))) / 2e-6
            assert np.allclose(num, Jk[:, k], atol=1e-6), (phi, k, num, Jk[:, k])
    # the magnification normal to a rotation of 2 rad about z
    gain = np.linalg.norm(J[3] @ np.array([1.0, 0.0, 0.0]))
    assert gain == pytest.approx(1.0 / math.sin(1.0), rel=1e-9)
