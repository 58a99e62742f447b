"""WGS-84 constants, grade presets and the limit-accuracy formulas of ALGORITHM.md."""
import numpy as np
import pytest

from sins_align.earth import OMEGA_IE, earth_rate_enu, gravity, gravity_enu
from sins_align.specs import (DEG, DPH, GRADES, UG, SensorSpecs, grade_specs, limit_covariance,
                              limit_error, limit_std)


def test_normal_gravity_reference_values():
    """Somigliana: 9.7803253359 at the equator, 9.8321849378 at the poles; height lowers g."""
    assert gravity(0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert gravity(np.pi / 2) == pytest.approx(9.8321849378, abs=1e-9)
    assert gravity(0.6, 1000.0) == pytest.approx(gravity(0.6) - 3.086e-3, abs=1e-12)
    assert gravity_enu(0.3)[2] == -gravity(0.3)


def test_earth_rate_enu():
    w = earth_rate_enu(34 * DEG)
    assert np.linalg.norm(w) == pytest.approx(OMEGA_IE, rel=1e-15)
    assert w[0] == 0 and w[2] == pytest.approx(OMEGA_IE * np.sin(34 * DEG))


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
