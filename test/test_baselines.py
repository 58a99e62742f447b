"""The baseline filters of issue 13 (sins_align.estimators.baselines): the UKF equals the
Kalman filter on a linear model, the unscented particle filter's mean converges to the
Kalman filter's on a linear-Gaussian model, and seed 004's Euler-error model reproduces the
open-loop mechanization it describes."""
import numpy as np
import pytest

from sins_align.core.rotation import skew
from sins_align.core.specs import DEG, DPH, UG, grade_specs
from sins_align.estimators.baselines import (UKF, UPF, AdaptiveUPF, BaselineConfig,
                                             LinearGaussianModel, dcm_euler, euler_dcm,
                                             kalman_filter, mechanize_static)
from sins_align.estimators.baselines.euler_model import DPH_RAD, MG
from sins_align.sim.simulator import simulate_runs

CFG = BaselineConfig(latitude_deg=32.37, specs=grade_specs("navigation"))


def _linear(n=4, m=2, q=0.05, r=0.2, steps=30, runs=3, seed=1):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    F = 0.95 * A / np.max(np.abs(np.linalg.eigvals(A)))       # stable, not symmetric
    Q = q * (np.eye(n) + 0.3 * np.ones((n, n)) / n)
    H = rng.normal(size=(m, n))
    R = r * np.eye(m)
    model = LinearGaussianModel(F, Q, H, R)
    _, z = model.simulate(steps, np.ones(n), rng, runs)
    model.z = z
    return model


def test_ukf_equals_kf_on_linear_model():
    model = _linear()
    x0, P0 = np.full(model.n, 0.5), np.eye(model.n) * 2.0
    x_kf, P_kf = kalman_filter(model, model.z, x0, P0)
    x_ukf, P_ukf, _, _ = UKF(CFG).filter(model, x0, P0)
    np.testing.assert_allclose(x_ukf, x_kf, rtol=0, atol=1e-10)
    np.testing.assert_allclose(P_ukf, P_kf, rtol=0, atol=1e-10)


@pytest.mark.parametrize("cls", [UPF, AdaptiveUPF])
def test_particle_filter_mean_converges_to_kf(cls):
    """Textbook weights (consistent importance sampling): with many particles the weighted
    mean is the KF mean within a small fraction of the KF std, and the error shrinks with
    the number of particles. The adaptive filter's fading stays off on a model that fits
    (its criterion holds) often enough for the same to hold."""
    model = _linear(n=2, m=1, q=0.3, r=0.5, steps=15, runs=1, seed=3)
    x0, P0 = np.zeros(2), np.eye(2)
    x_kf, P_kf = kalman_filter(model, model.z, x0, P0)
    sd = np.sqrt(np.diagonal(P_kf, axis1=-2, axis2=-1))
    errs = {}
    for M in (50, 4000):
        x_pf, P_pf, ess, _ = cls(CFG, particles=M).filter(model, x0, P0,
                                                           np.random.default_rng(7))
        errs[M] = np.max(np.abs(x_pf - x_kf) / sd)
        assert ess.min() > 0.1 * M            # the weights do not collapse on this model
    assert errs[4000] < 0.12, errs
    assert errs[4000] < errs[50], errs
    if cls is UPF:   # the particle spread matches the KF covariance
        np.testing.assert_allclose(np.sqrt(np.diagonal(P_pf[-1, 0])), sd[-1, 0], rtol=0.1)


def test_euler_angles_round_trip_and_small_angle():
    rng = np.random.default_rng(0)
    phi = rng.uniform(-1.2, 1.2, size=(200, 3))
    np.testing.assert_allclose(dcm_euler(euler_dcm(phi)), phi, atol=1e-12)
    small = np.array([1e-6, -2e-6, 3e-6])
    np.testing.assert_allclose(euler_dcm(small), np.eye(3) + skew(small), atol=1e-11)


def test_euler_error_model_reproduces_the_mechanization():
    """Noise-free samples, the true error state propagated by the model step by step: its
    velocity error is the open-loop mechanization's velocity (the measurement) and its
    angles the computed attitude's true error, after 120 s with 30 deg of heading error.
    (The 10-state model has no vertical accelerometer bias state: it is zero here; 80 ug of
    it on this tilted IMU leaks 5 ug into the horizontal, 6 mm/s in 120 s, into dv.)"""
    sp = grade_specs("navigation").with_(gyro_arw=0.0, accel_vrw=0.0)
    bg, ba = np.array([3, -2, 1]) * 0.01 * DPH, np.array([100, -50, 0]) * UG
    s = simulate_runs(120.0, [0], 100.0, 32.37, rpy_deg=(2.0, -3.0, 40.0), specs=sp,
                      gyro_bias=bg, accel_bias=ba, noise=False)
    phi0 = np.array([1.0, -1.0, 30.0]) * DEG
    C_est0 = euler_dcm(phi0).T @ s.C0
    mech = mechanize_static(0.01, s.gyro, s.accel, C_est0, 32.37 * DEG)
    model = CFG.model(mech)
    x = np.concatenate([phi0, [0, 0], bg / DPH_RAD, ba[:2] / MG])[None, None]
    for k in range(model.steps):
        x = model.propagate(x, k)
        # the true Euler error of the computed attitude at the step's end
        D_true = s.C0[0] @ mech.C[k + 1, 0].T
        np.testing.assert_allclose(x[0, 0, :3], dcm_euler(D_true), atol=2e-8)
    v = mech.v[-1, 0, :2]
    assert np.max(np.abs(v)) > 1.0          # the open-loop velocity has grown
    # the trapezoid over a step puts the attitude half a sample early: ~1e-6 m/s per step
    np.testing.assert_allclose(x[0, 0, 3:5], v, rtol=0, atol=5e-4)


def test_filters_share_interface_and_reject_bad_weights():
    with pytest.raises(ValueError):
        UPF(CFG, weights="magic")
    s = simulate_runs(20.0, [0, 1], 100.0, 32.37, specs="navigation")
    C_est0 = euler_dcm(np.array([1.0, 1.0, 30.0]) * DEG).T @ s.C0
    for f in (UKF(CFG), UPF(CFG, particles=8), AdaptiveUPF(CFG, particles=8)):
        r = f.run(0.01, s.gyro, s.accel, C_est0)
        assert r.C_est.shape == (21, 2, 3, 3) and r.cov.shape == (21, 2, 3, 3)
        assert r.phi.shape == (21, 2, 3) and np.all(np.isfinite(r.C_est))
        np.testing.assert_allclose(r.t, np.arange(21.0))
