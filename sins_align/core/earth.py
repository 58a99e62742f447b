"""WGS-84 Earth model: normal gravity and Earth rotation rate in ENU.

Navigation frame n = ENU (x East, y North, z Up), REP-103.
"""
from __future__ import annotations

import numpy as np

#: Earth rotation rate, rad/s (WGS-84).
OMEGA_IE = 7.2921151467e-5

_GE = 9.7803253359
_K = 0.00193185265241
_E2 = 0.00669437999013
_DG_DH = 3.086e-6


def gravity(lat_rad: float, height_m: float = 0.0) -> float:
    """Normal gravity magnitude (Somigliana, WGS-84) with a linear height term.

    Parameters
    ----------
    lat_rad : float, rad — geodetic latitude.
    height_m : float, m — height above the ellipsoid.

    Returns
    -------
    g : float, m/s^2.
    """
    s2 = np.sin(lat_rad) ** 2
    return float(_GE * (1.0 + _K * s2) / np.sqrt(1.0 - _E2 * s2) - _DG_DH * height_m)


def gravity_enu(lat_rad: float, height_m: float = 0.0) -> np.ndarray:
    """Gravity vector g^n = [0, 0, -g], shape (3,), m/s^2, ENU."""
    return np.array([0.0, 0.0, -gravity(lat_rad, height_m)])


def earth_rate_enu(lat_rad: float) -> np.ndarray:
    """Earth rate omega_ie^n = [0, w cos L, w sin L], shape (3,), rad/s, ENU."""
    return np.array([0.0, OMEGA_IE * np.cos(lat_rad), OMEGA_IE * np.sin(lat_rad)])
