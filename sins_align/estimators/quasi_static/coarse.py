"""Analytic coarse alignment on a static base (double-vector / TRIAD).

Navigation frame n = ENU; the body frame is whatever the IMU's axes are.
"""
from __future__ import annotations

import numpy as np

from sins_align.core.earth import earth_rate_enu

_MIN_SIN = 1e-9


def _triad(v1: np.ndarray, v2: np.ndarray, what: str) -> np.ndarray:
    """Orthonormal triad [u1, u2, u3] (as columns): u1 || v1, u2 || v1 x v2, u3 = u1 x u2."""
    n1 = np.linalg.norm(v1)
    n2 = np.linalg.norm(v2)
    if not (n1 > 0.0 and n2 > 0.0):
        raise ValueError(f"{what}: zero-length vector")
    u1 = v1 / n1
    c = np.cross(u1, v2 / n2)
    s = np.linalg.norm(c)
    if s < _MIN_SIN:
        raise ValueError(f"{what}: specific force and Earth rate are parallel "
                         f"(sin of angle {s:.3g}); heading is unobservable")
    u2 = c / s
    return np.column_stack([u1, u2, np.cross(u1, u2)])


def static_coarse_alignment(mean_gyro_b: np.ndarray, mean_accel_b: np.ndarray,
                            lat_rad: float) -> np.ndarray:
    """Double-vector (TRIAD) alignment from mean rate and specific force on a static base.

    The mean specific force is the primary vector (it fixes the vertical exactly); the mean
    angular rate supplies only the heading through its component orthogonal to it. Only
    directions are used, so the magnitudes of gravity and Earth rate need not match a model.

    Parameters
    ----------
    mean_gyro_b : array_like (3,), rad/s — mean angular rate omega_ib^b in the body axes.
    mean_accel_b : array_like (3,), m/s^2 — mean specific force f^b in the body axes
        (points up at rest: f^n = -g^n = [0, 0, g]).
    lat_rad : float, rad — geodetic latitude.

    Returns
    -------
    C_b^n : ndarray (3, 3) — rotates body vectors into ENU.

    Raises
    ------
    ValueError
        Non-finite input, a zero vector, or rate parallel to specific force in the body or
        in the navigation frame (e.g. at the poles): heading is then unobservable.

    Notes
    -----
    With n-frame references f^n = [0, 0, 1] and w^n = omega_ie^n = [0, w cos L, w sin L],
    the triads T_x = [f, f x w, f x (f x w)] (normalised) satisfy T_n = C_b^n T_b, hence
    C_b^n = T_n T_b^T. Heading accuracy is limited by the gyro bias: an east bias eps_E gives
    about eps_E / (omega_ie cos L) rad of heading error; MEMS gyros cannot use this method.
    """
    w_b = np.asarray(mean_gyro_b, dtype=float).reshape(3)
    f_b = np.asarray(mean_accel_b, dtype=float).reshape(3)
    if not (np.all(np.isfinite(w_b)) and np.all(np.isfinite(f_b)) and np.isfinite(lat_rad)):
        raise ValueError("static_coarse_alignment: non-finite input")
    f_n = np.array([0.0, 0.0, 1.0])
    w_n = earth_rate_enu(lat_rad)
    T_n = _triad(f_n, w_n, "navigation frame")
    T_b = _triad(f_b, w_b, "body frame")
    return T_n @ T_b.T
