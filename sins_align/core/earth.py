"""WGS-84 Earth model: normal gravity, radii of curvature and Earth rotation rate in ENU.

Navigation frame n = ENU (x East, y North, z Up), REP-103.
"""
from __future__ import annotations

import numpy as np

#: Earth rotation rate, rad/s (WGS-84).
OMEGA_IE = 7.2921151467e-5
#: WGS-84 semi-major axis, m.
WGS84_A = 6378137.0
#: WGS-84 first eccentricity squared.
WGS84_E2 = 0.00669437999013
#: Normal gravity at the equator, m/s^2, and Somigliana's constant k (WGS-84).
GRAVITY_EQUATOR = 9.7803253359
SOMIGLIANA_K = 0.00193185265241
#: Free-air decrease of gravity with height, (m/s^2)/m.
GRAVITY_PER_METRE = 3.086e-6


def normal_gravity(lat_rad, height_m=0.0):
    """Normal gravity magnitude (Somigliana, WGS-84) with a linear height term, m/s^2.

    ``lat_rad`` (geodetic latitude, rad) and ``height_m`` (above the ellipsoid, m) are floats
    or arrays (the result has their broadcast shape)."""
    s2 = np.sin(lat_rad) ** 2
    return (GRAVITY_EQUATOR * (1.0 + SOMIGLIANA_K * s2) / np.sqrt(1.0 - WGS84_E2 * s2)
            - GRAVITY_PER_METRE * height_m)


def gravity(lat_rad: float, height_m: float = 0.0) -> float:
    """:func:`normal_gravity` at one place, as a float (m/s^2)."""
    return float(normal_gravity(lat_rad, height_m))


def radii(lat_rad):
    """WGS-84 radii of curvature ``(R_M, R_N)``, m: meridian and prime vertical.

    ``lat_rad`` rad, a float or an array (the radii then have its shape)."""
    s2 = np.sin(lat_rad) ** 2
    d = 1.0 - WGS84_E2 * s2
    rn = WGS84_A / np.sqrt(d)
    return rn * (1.0 - WGS84_E2) / d, rn


def gravity_enu(lat_rad: float, height_m: float = 0.0) -> np.ndarray:
    """Gravity vector g^n = [0, 0, -g], shape (3,), m/s^2, ENU."""
    return np.array([0.0, 0.0, -gravity(lat_rad, height_m)])


def earth_rate_enu(lat_rad) -> np.ndarray:
    """Earth rate omega_ie^n = [0, w cos L, w sin L], rad/s, ENU: shape (3,) for a float
    latitude, ``lat_rad.shape + (3,)`` for an array."""
    lat = np.asarray(lat_rad, dtype=float)
    return np.stack([np.zeros_like(lat), OMEGA_IE * np.cos(lat), OMEGA_IE * np.sin(lat)], -1)
