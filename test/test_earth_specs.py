"""WGS-84 constants, grade presets and the limit-accuracy formulas of ALGORITHM.md."""
import numpy as np
import pytest

from sins_align.core.earth import OMEGA_IE, earth_rate_enu, gravity, gravity_enu
from sins_align.core.specs import (DEG, DPH, GRADES, UG, SensorSpecs, grade_specs, limit_covariance,
                              limit_error, limit_std)


def test_normal_gravity_reference_values():
    """Somigliana: 9.7803253359 at the equator, 9.8321849378 at the poles; height lowers g."""
    assert gravity(0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert gravity(np.pi / 2) == pytest.approx(9.8321849378, abs=1e-9)
    assert gravity(0.6, 1000.0) == pytest.approx(gravity(0.6) - 3.086e-3, abs=1e-12)
    assert gravity_enu(0.3)[2] == -gravity(0.3)


# WGS-84 defining constants and Somigliana's normal gravity at the equator and the poles
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
G_EQUATOR, G_POLE = 9.7803253359, 9.8321849378
SIDEREAL_DAY = 86164.0905          # s


def _enu_axes_in_ecef(lat: float, lon: float) -> np.ndarray:
    """Rows: the East, North and Up unit vectors at geodetic (lat, lon) in ECEF, from the
    geometry of the ellipsoid (Up is the normal, East = z_ecef x Up normalised,
    North = Up x East): ECEF -> ENU rotation."""
    up = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    return np.array([east, np.cross(up, east), up])


@pytest.mark.parametrize("lat_deg", [-89.0, -60.0, -34.0, 0.0, 5.0, 34.0, 60.0, 89.0])
def test_earth_rate_is_the_earth_axis_seen_from_enu(lat_deg):
    """earth_rate_enu is the Earth's rotation vector, Omega along the ECEF z axis (towards the
    North pole), expressed in the local ENU axes built from the geometry at any longitude;
    |w| is one turn per sidereal day (to the 1e-7 the precession makes). Signs: the North
    component is positive in both hemispheres (the axis points to the celestial North pole,
    above the northern horizon), Up has the sign of the latitude, and a point on the surface
    is carried East (w x r)."""
    lat = lat_deg * DEG
    w = earth_rate_enu(lat)
    for lon in np.radians([0.0, 108.9, -75.0, 180.0]):
        expect = _enu_axes_in_ecef(lat, lon) @ np.array([0.0, 0.0, OMEGA_IE])
        np.testing.assert_allclose(w, expect, rtol=0, atol=1e-12 * OMEGA_IE)
    assert OMEGA_IE == pytest.approx(2 * np.pi / SIDEREAL_DAY, rel=2e-7)
    assert w[1] > 0 and np.sign(w[2]) == np.sign(lat_deg)
    velocity = np.cross(w, [0.0, 0.0, WGS84_A])           # of a point on the surface, ENU
    assert velocity[0] > 0 and abs(velocity[1]) < 1e-9 and abs(velocity[2]) < 1e-9


@pytest.mark.parametrize("lat_deg", [0.0, 15.0, 34.246048, 45.0, 60.0, 75.0, 90.0, -34.0])
def test_gravity_is_somigliana_closed_form(lat_deg):
    """gravity() equals Somigliana's formula written from the WGS-84 semi-axes and the
    equatorial and polar normal gravity, g = (a g_e cos^2 L + b g_p sin^2 L) /
    sqrt(a^2 cos^2 L + b^2 sin^2 L), to 1e-9 m/s^2 (a different form from earth.py's);
    the free-air decrease with height is about 2 g / R (within 1 %), and gravity points down."""
    lat = lat_deg * DEG
    b = WGS84_A * (1.0 - WGS84_F)
    c2, s2 = np.cos(lat) ** 2, np.sin(lat) ** 2
    g = (WGS84_A * G_EQUATOR * c2 + b * G_POLE * s2) / np.sqrt(WGS84_A ** 2 * c2 + b ** 2 * s2)
    assert gravity(lat) == pytest.approx(g, abs=1e-9)
    gradient = (gravity(lat) - gravity(lat, 1000.0)) / 1000.0
    assert gradient == pytest.approx(2 * g / 6371008.8, rel=0.01)
    gn = gravity_enu(lat, 500.0)
    assert gn[0] == gn[1] == 0.0 and gn[2] == -gravity(lat, 500.0) < 0


def test_paper_limit_accuracy_example():
    """34 deg N, 0.01 deg/h, 100 ug: level 20.6 arcsec, heading gyro term 2.76 arcmin."""
    lat = 34 * DEG
    phi = limit_error(lat, np.full(3, 100 * UG), np.full(3, 0.01 * DPH))
    g = gravity(lat)
    assert abs(phi[0]) / DEG * 3600 == pytest.approx(20.6, abs=0.1)
    assert phi[0] == pytest.approx(-100 * UG / g) and phi[1] == pytest.approx(100 * UG / g)
    gyro_term = 0.01 * DPH / (OMEGA_IE * np.cos(lat))
    assert gyro_term / DEG * 60 == pytest.approx(2.76, abs=0.01)
    assert phi[2] == pytest.approx(-gyro_term + 100 * UG * np.tan(lat) / g)


def test_limit_covariance_matches_monte_carlo():
    """The closed-form limit covariance equals the sample covariance of limit errors."""
    lat, sp = 50 * DEG, GRADES["tactical"]
    rng = np.random.default_rng(0)
    a = rng.normal(size=(200000, 3)) * sp.accel_bias
    e = rng.normal(size=(200000, 3)) * sp.gyro_bias
    phi = limit_error(lat, a, e)
    P = limit_covariance(lat, sp)
    assert np.allclose(np.cov(phi.T), P, rtol=0.02, atol=1e-3 * P.max())


def test_heading_unobservable_at_pole_is_inf_not_error():
    """cos L -> 0: heading limit std is inf, level stays finite; no division warning."""
    with np.errstate(all="raise"):
        s = limit_std(np.pi / 2, GRADES["navigation"])
    assert np.isinf(s[2]) and np.isfinite(s[:2]).all()
    phi = limit_error(np.pi / 2, np.ones(3) * 1e-3, np.ones(3) * 1e-7)
    assert np.isinf(phi[2])


def test_grades_and_validation():
    assert grade_specs("navigation").gyro_bias == pytest.approx(0.01 * DPH)
    assert limit_std(34 * DEG, GRADES["consumer"])[2] > 1.0      # MEMS: heading hopeless
    with pytest.raises(ValueError, match="unknown grade"):
        grade_specs("military")
    with pytest.raises(ValueError, match="gyro_bias"):
        SensorSpecs(gyro_bias=-1, gyro_arw=0, accel_bias=0, accel_vrw=0)
