"""Rotation utilities: skew matrices, exact SO(3) exp/log, quaternions, REP-103 Euler angles.

Conventions
-----------
- A DCM ``C`` written ``C_b^n`` rotates body vectors into the navigation frame: ``x^n = C x^b``.
- Quaternions are stored ``[x, y, z, w]`` (ROS ``geometry_msgs/Quaternion`` order) and
  represent the same rotation as the DCM (Hamilton convention).
- Euler angles follow REP-103: ``C = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (fixed axes X, Y, Z).
  With n = ENU, yaw 0 means the body x axis points East, counter-clockwise positive.
- True heading is the azimuth of the body x axis, clockwise from North, in [0, 2*pi).

Every function accepts a single item or a stack (leading dimensions) of items.
"""
from __future__ import annotations

import math

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``(v x)``: shape (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def so3_exp(rotvec: np.ndarray) -> np.ndarray:
    """Exact exponential map ``exp((rotvec x))`` (Rodrigues), shape (..., 3) -> (..., 3, 3).

    Uses Taylor series for the coefficients below 1e-2 rad, so it is exact to double precision
    at every angle, including zero and pi.
    """
    rv = np.asarray(rotvec, dtype=float)
    if rv.size == 3:
        return np.array(so3_exp_entries(*rv.reshape(3).tolist())).reshape(rv.shape[:-1] + (3, 3))
    entries = so3_exp_entries(rv[..., 0], rv[..., 1], rv[..., 2])
    return np.stack(entries, axis=-1).reshape(rv.shape[:-1] + (3, 3))


def so3_exp_entries(x, y, z) -> tuple:
    """The nine entries, row by row, of ``exp((v x))`` for rotation vectors given as
    component arrays ``v = (x, y, z)`` (any equal shapes, rad): the component-major form of
    :func:`so3_exp`. Series coefficients where the angle is below 1e-2 rad, the closed
    forms (sin, cos) only for the vectors above. A single vector (size-1 components) is
    computed with scalar math and gives nine floats."""
    if isinstance(x, np.ndarray) and x.size == 1:
        x, y, z = x.item(), y.item(), z.item()
    if isinstance(x, float):
        th2 = x * x + y * y + z * z
        if th2 < 1e-4:
            # _exp_series written out for a float: the same operations as horner's
            a = ((th2 * (-1.0 / 5040.0) + 1.0 / 120.0) * th2 + (-1.0 / 6.0)) * th2 + 1.0
            b = ((th2 * (-1.0 / 40320.0) + 1.0 / 720.0) * th2 + (-1.0 / 24.0)) * th2 + 0.5
        else:
            th = math.sqrt(th2)
            a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
        return _rodrigues(x, y, z, a, b)
    th2 = x * x + y * y + z * z
    a, b = _exp_series(th2)
    if th2.size and float(th2.max()) >= 1e-4:
        big = np.flatnonzero(th2 >= 1e-4)
        t2 = th2.reshape(-1)[big]
        th = np.sqrt(t2)
        a = a.reshape(-1)
        b = b.reshape(-1)
        a[big] = np.sin(th) / th
        b[big] = (1.0 - np.cos(th)) / t2
        a, b = a.reshape(th2.shape), b.reshape(th2.shape)
    return _rodrigues(x, y, z, a, b)


def _exp_series(th2):
    """sin(t)/t and (1 - cos t)/t^2 from t^2 by their Taylor series through t^6: the first
    omitted terms (t^8/9!, t^8/10!) are below 3e-22 for t < 1e-2 rad, exact to double
    precision there."""
    return (horner(th2, (1.0, -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0)),
            horner(th2, (0.5, -1.0 / 24.0, 1.0 / 720.0, -1.0 / 40320.0)))


def horner(x, coefs):
    """``sum_i coefs[i] x^i`` (lowest order first) by Horner's rule, into new storage of
    x's shape (x a float or an array)."""
    if len(coefs) == 1:
        return np.full_like(x, coefs[0]) if isinstance(x, np.ndarray) else float(coefs[0])
    r = x * coefs[-1]
    for c in coefs[-2:0:-1]:
        r += c
        r *= x
    r += coefs[0]
    return r


def _rodrigues(x, y, z, a, b) -> tuple:
    """The nine entries, row by row, of I + a K + b K^2 (K the skew matrix of (x, y, z),
    K^2 = v v^T - |v|^2 I); floats or arrays."""
    bx, by = b * x, b * y
    ax, ay, az = a * x, a * y, a * z
    bxy, bxz, byz = bx * y, bx * z, by * z
    return (1.0 - b * (y * y + z * z), bxy - az, bxz + ay,
            bxy + az, 1.0 - b * (x * x + z * z), byz - ax,
            bxz - ay, byz + ax, 1.0 - b * (x * x + y * y))


def quat_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """Quaternion [x, y, z, w] of the rotation ``exp((rotvec x))``."""
    rv = np.asarray(rotvec, dtype=float)
    th2 = np.sum(rv * rv, axis=-1)
    th = np.sqrt(th2)
    small = th < 1e-4
    ths = np.where(small, 1.0, th)
    k = np.where(small, 0.5 - th2 / 48.0, np.sin(0.5 * ths) / ths)
    out = np.empty(rv.shape[:-1] + (4,))
    out[..., :3] = k[..., None] * rv
    out[..., 3] = np.cos(0.5 * th)
    return out


def rotvec_from_quat(q: np.ndarray) -> np.ndarray:
    """Rotation vector (log map) of a quaternion [x, y, z, w]; angle in [0, pi]."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., 3:4] < 0.0, -q, q)
    s = np.linalg.norm(q[..., :3], axis=-1)
    w = q[..., 3]
    th = 2.0 * np.arctan2(s, w)
    small = s < 1e-8
    k = np.where(small, 2.0 / np.where(small, w, 1.0), th / np.where(small, 1.0, s))
    return k[..., None] * q[..., :3]


def quat_from_dcm(C: np.ndarray) -> np.ndarray:
    """Quaternion [x, y, z, w] (w >= 0) of a DCM; Shepperd's method, stable at every angle."""
    C = np.asarray(C, dtype=float)
    if C.shape == (3, 3):
        return _quat_from_dcm_one(C)
    tr = np.trace(C, axis1=-2, axis2=-1)
    diag = np.stack([C[..., 0, 0], C[..., 1, 1], C[..., 2, 2], tr], axis=-1)
    choice = np.argmax(diag, axis=-1)
    q = np.empty(C.shape[:-2] + (4,))
    # candidate rows for each choice: computed for all, selected after.
    c = C
    cands = np.empty(C.shape[:-2] + (4, 4))
    # choice 0: x largest
    cands[..., 0, :] = np.stack([1 + 2 * c[..., 0, 0] - tr, c[..., 1, 0] + c[..., 0, 1],
                                 c[..., 2, 0] + c[..., 0, 2], c[..., 2, 1] - c[..., 1, 2]], -1)
    cands[..., 1, :] = np.stack([c[..., 1, 0] + c[..., 0, 1], 1 + 2 * c[..., 1, 1] - tr,
                                 c[..., 2, 1] + c[..., 1, 2], c[..., 0, 2] - c[..., 2, 0]], -1)
    cands[..., 2, :] = np.stack([c[..., 2, 0] + c[..., 0, 2], c[..., 2, 1] + c[..., 1, 2],
                                 1 + 2 * c[..., 2, 2] - tr, c[..., 1, 0] - c[..., 0, 1]], -1)
    cands[..., 3, :] = np.stack([c[..., 2, 1] - c[..., 1, 2], c[..., 0, 2] - c[..., 2, 0],
                                 c[..., 1, 0] - c[..., 0, 1], 1 + tr], -1)
    q = np.take_along_axis(cands, choice[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0.0, -q, q)


def _quat_from_dcm_one(C: np.ndarray) -> np.ndarray:
    """quat_from_dcm of a single DCM: the same Shepperd branches, scalar math."""
    return np.array(quat_values_from_dcm(C))


def quat_values_from_dcm(C: np.ndarray) -> list[float]:
    """:func:`quat_from_dcm` of one DCM (3, 3) as four floats [x, y, z, w] (w >= 0): the same
    Shepperd branches in scalar math (the node publishes one after every sample)."""
    (c00, c01, c02), (c10, c11, c12), (c20, c21, c22) = C.tolist()
    tr = c00 + c11 + c22
    # the largest of c00, c11, c22, tr, the first one on ties
    k, top = 0, c00
    if c11 > top:
        k, top = 1, c11
    if c22 > top:
        k, top = 2, c22
    if tr > top:
        k = 3
    if k == 0:
        q0, q1, q2, q3 = 1 + 2 * c00 - tr, c10 + c01, c20 + c02, c21 - c12
    elif k == 1:
        q0, q1, q2, q3 = c10 + c01, 1 + 2 * c11 - tr, c21 + c12, c02 - c20
    elif k == 2:
        q0, q1, q2, q3 = c20 + c02, c21 + c12, 1 + 2 * c22 - tr, c10 - c01
    else:
        q0, q1, q2, q3 = c21 - c12, c02 - c20, c10 - c01, 1 + tr
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    if q3 < 0.0:
        n = -n
    return [q0 / n, q1 / n, q2 / n, q3 / n]


def dcm_from_quat(q: np.ndarray) -> np.ndarray:
    """DCM of a quaternion [x, y, z, w] (normalised first)."""
    q = np.asarray(q, dtype=float)
    return dcm_from_quat_components(q[..., 0], q[..., 1], q[..., 2], q[..., 3])


def dcm_from_quat_components(x, y, z, w) -> np.ndarray:
    """DCM of quaternions given as component arrays (normalised first): (...) -> (..., 3, 3)."""
    return np.stack(dcm_entries_from_quat(x, y, z, w), axis=-1).reshape(np.shape(x) + (3, 3))


def dcm_entries_from_quat(x, y, z, w) -> tuple:
    """The nine entries, row by row, of the DCM of quaternions given as component arrays
    (normalised first): the component-major form of :func:`dcm_from_quat_components`."""
    s = 2.0 / (x * x + y * y + z * z + w * w)
    xs, ys, zs = x * s, y * s, z * s
    wx, wy, wz = w * xs, w * ys, w * zs
    xx, xy, xz = x * xs, x * ys, x * zs
    yy, yz, zz = y * ys, y * zs, z * zs
    return (1.0 - (yy + zz), xy - wz, xz + wy,
            xy + wz, 1.0 - (xx + zz), yz - wx,
            xz - wy, yz + wx, 1.0 - (xx + yy))


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p * q`` of [x, y, z, w] quaternions (DCM(p) @ DCM(q))."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    px, py, pz, pw = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qx, qy, qz, qw = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
        pw * qw - px * qx - py * qy - pz * qz,
    ], axis=-1)


def so3_log(C: np.ndarray) -> np.ndarray:
    """Exact logarithm of a DCM as a rotation vector, angle in [0, pi]; stable near 0 and pi."""
    return rotvec_from_quat(quat_from_dcm(C))


def dcm_from_rpy(rpy: np.ndarray) -> np.ndarray:
    """DCM ``Rz(yaw) Ry(pitch) Rx(roll)`` from REP-103 [roll, pitch, yaw], rad."""
    rpy = np.asarray(rpy, dtype=float)
    r, p, y = rpy[..., 0], rpy[..., 1], rpy[..., 2]
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    out = np.empty(rpy.shape[:-1] + (3, 3))
    out[..., 0, 0] = cy * cp
    out[..., 0, 1] = cy * sp * sr - sy * cr
    out[..., 0, 2] = cy * sp * cr + sy * sr
    out[..., 1, 0] = sy * cp
    out[..., 1, 1] = sy * sp * sr + cy * cr
    out[..., 1, 2] = sy * sp * cr - cy * sr
    out[..., 2, 0] = -sp
    out[..., 2, 1] = cp * sr
    out[..., 2, 2] = cp * cr
    return out


def rpy_from_dcm(C: np.ndarray) -> np.ndarray:
    """REP-103 [roll, pitch, yaw], rad, from a DCM.

    Pitch comes from ``atan2`` (accurate near +-90 deg). At gimbal lock (|pitch| = 90 deg) roll and
    yaw are not separable: roll is set to 0 and the whole rotation about the vertical is yaw,
    so ``dcm_from_rpy(rpy_from_dcm(C))`` still equals ``C``.
    """
    C = np.asarray(C, dtype=float)
    cp = np.hypot(C[..., 0, 0], C[..., 1, 0])
    pitch = np.arctan2(-C[..., 2, 0], cp)
    lock = cp < 1e-9
    roll = np.where(lock, 0.0, np.arctan2(C[..., 2, 1], C[..., 2, 2]))
    yaw = np.where(lock, np.arctan2(-C[..., 0, 1], C[..., 1, 1]),
                   np.arctan2(C[..., 1, 0], C[..., 0, 0]))
    return np.stack([roll, pitch, yaw], axis=-1)


def heading_from_dcm(C: np.ndarray) -> np.ndarray:
    """True heading of the body x axis, rad, clockwise from North, in [0, 2 pi).

    Everywhere ``heading = 90 deg - yaw`` (mod 360 deg) with the yaw of :func:`rpy_from_dcm`.
    Off the poles of pitch that is the azimuth of the horizontal projection of the body x
    axis. When that axis is vertical (|pitch| = 90 deg, the same test as rpy_from_dcm's
    gimbal lock) rpy_from_dcm puts roll to 0 and the whole rotation about the vertical into
    yaw; the body y axis is then horizontal and points 90 deg to the left of where the x
    axis points when the nose is lowered back to level (``C = Rz(yaw) Ry(+-90 deg)``: body y
    at azimuth -yaw, so heading = heading(body y) + 90 deg). With roll 0 the result is the
    limit of the heading as the pitch approaches +-90 deg.
    """
    C = np.asarray(C, dtype=float)
    e, n = C[..., 0, 0], C[..., 1, 0]
    vertical = np.hypot(e, n) < 1e-9
    h = np.where(vertical, np.arctan2(C[..., 0, 1], C[..., 1, 1]) + 0.5 * np.pi,
                 np.arctan2(e, n))
    return np.mod(h, 2.0 * np.pi)


def attitude_error(C_true: np.ndarray, C_est: np.ndarray) -> np.ndarray:
    """Attitude error phi (paper eq. 15): ``C_true = exp(phi x) C_est``, rad, ENU."""
    return so3_log(np.asarray(C_true) @ np.swapaxes(np.asarray(C_est), -1, -2))


def so3_left_jacobian_inv(rotvec: np.ndarray) -> np.ndarray:
    """Inverse left Jacobian of SO(3) at ``rotvec`` (..., 3), |rotvec| <= pi: (..., 3, 3).

    ``log(exp(e x) exp(phi x)) = phi + J_l^-1(phi) e`` to first order in ``e``: an error
    ``e`` about a rotation ``phi`` away becomes that much error about the origin. On the
    plane normal to ``phi`` its gain is ``(theta / 2) / sin(theta / 2)`` (1 at 0, 1.57 at
    pi) and it turns ``e`` by ``theta / 2``."""
    phi = np.asarray(rotvec, dtype=float)
    th = np.linalg.norm(phi, axis=-1)
    S = skew(phi)
    half = 0.5 * th
    big = th > 1e-4
    safe = np.where(big, th, 1.0)
    # (1 - (theta/2) cot(theta/2)) / theta^2, its series 1/12 + theta^2/720 near 0
    coef = np.where(big, (1.0 - half * np.cos(half) / np.where(big, np.sin(half), 1.0))
                    / (safe * safe), 1.0 / 12.0 + th * th / 720.0)
    return np.eye(3) - 0.5 * S + coef[..., None, None] * (S @ S)


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap an angle (rad) to [-pi, pi)."""
    return np.mod(np.asarray(a) + np.pi, 2.0 * np.pi) - np.pi
