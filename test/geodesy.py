"""Geodetic helpers written independently of sins_align's code, for tests that check the
simulator and the strapdown against kinematics in ECEF."""
import numpy as np

from sins_align.core.earth import WGS84_A, WGS84_E2


def ecef(lat, lon, h):
    """ECEF position (..., 3) of geodetic latitude, longitude (rad) and height (m)."""
    rn = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    return np.stack([(rn + h) * np.cos(lat) * np.cos(lon), (rn + h) * np.cos(lat) * np.sin(lon),
                     (rn * (1.0 - WGS84_E2) + h) * np.sin(lat)], -1)


def C_en(lat, lon):
    """ENU-to-ECEF rotation (..., 3, 3), columns East, North, Up."""
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    z = np.zeros_like(lat)
    return np.stack([np.stack([-so, co, z], -1), np.stack([-sl * co, -sl * so, cl], -1),
                     np.stack([cl * co, cl * so, sl], -1)], -1)
