"""The published covariance stays honest when the accelerometer is noisier than its specs.

Seed 004's static scenario (32.37 deg N, navigation-grade biases, 50 ug/sqrt(Hz) configured)
with 28.8x the configured white accelerometer noise added, which the Aligner is not told
about (seed 004's 0.02 (m/s^2)^2 per sample). With the configured density as its process
noise the fine pass fitted the velocity random walk as attitude error: its heading was
degrees off while the published std said 0.05 deg (54 % of the instants beyond 3 sigma, the
flag up while wrong). The fine pass now measures the density on the backtrack's buffer and
uses it when significantly above the configured one, and says so in the summary.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from sins_align.core.rotation import rpy_from_dcm, so3_log
from sins_align.core.specs import DPH, DPSH, UG, UG_PSHZ, SensorSpecs
from sins_align.estimators.quasi_static import AlignConfig, Aligner
from sins_align.estimators.quasi_static.backtrack import velocity_random_walk
from sins_align.sim.simulator import simulate_runs

LAT = 32.37
SPECS = SensorSpecs(gyro_bias=0.01 * DPH, gyro_arw=0.001 * DPSH, accel_bias=100 * UG,
                    accel_vrw=50 * UG_PSHZ)


def _run(seed: int, excess: float, duration: float = 400.0):
    """Aligner on the static scenario with ``excess`` x the configured per-sample noise added;
    the error, published std and flag after every second, and the summary."""
    s = simulate_runs(duration, [seed], 100.0, LAT, specs=SPECS,
                      gyro_bias=np.full(3, SPECS.gyro_bias),
                      accel_bias=np.full(3, SPECS.accel_bias))
    rng = np.random.default_rng([seed, 4004])
    acc = s.accel[:, 0] + excess * SPECS.accel_vrw * 10.0 * rng.standard_normal((len(s.accel), 3))
    C0 = s.C0[0]
    # start 30 deg off in heading and 1 deg in level (seed 004)
    rpy0 = np.degrees(rpy_from_dcm(C0)) + np.array([1.0, 1.0, 30.0])
    al = Aligner(AlignConfig(latitude_deg=LAT, specs=SPECS, rate_hz=100.0,
                             initial_rpy_deg=tuple(rpy0)))
    t = np.arange(len(acc)) / 100.0
    out = []
    for k in range(0, len(acc), 100):
        al.update(t[k:k + 100], s.gyro[k:k + 100, 0], acc[k:k + 100])
        err = so3_log(C0 @ al.dcm.T)
        out.append((t[min(k + 99, len(t) - 1)], err, np.sqrt(np.diag(al.covariance)),
                    al.aligned))
    return out, al.summary()


@pytest.mark.parametrize("seed", [0, pytest.param(2, marks=pytest.mark.xfail(
    strict=True, reason="known miss: the random walk is significant in the 1 s and 2 s "
    "means, but their differences fail the whiteness test (a random walk's are correlated "
    "at lag 1) and the 5 s means chosen then are too few to show it"))])
def test_unmodelled_accelerometer_noise_is_measured_and_covered(seed):
    series, summary = _run(seed, 28.8)
    after = [(e, sd, a) for t, e, sd, a in series if t >= 60.0]   # the fine pass
    over = [np.any(np.abs(e) > 3.0 * sd) for e, sd, _ in after]
    assert np.mean(over) <= 0.01, np.mean(over)
    assert not any(o and a for o, (_, _, a) in zip(over, after))
    assert summary["accel_noise_above_spec"] is True
    # the measured density is near the true one (sqrt(1 + 28.8^2) x the configured)
    ratio = summary["accel_noise_density"] / SPECS.accel_vrw
    assert 20.0 < ratio < 40.0, ratio


def test_noise_within_specs_keeps_the_configured_density():
    series, summary = _run(1, 0.0, duration=120.0)
    assert summary["accel_noise_above_spec"] is False
    assert summary["accel_noise_density"] == SPECS.accel_vrw


def test_velocity_random_walk_sees_a_random_walk_not_a_bounded_sway():
    """The long-run variance of the differenced interval means is q p for a random walk of
    density q, zero for white noise on the means (a sway averaged over the interval)."""
    rng = np.random.default_rng(7)
    q, p, m = 4e-4, 1.0, 60
    rw = np.cumsum(rng.standard_normal((m * 100, 1, 3)) * math.sqrt(q * 0.01), axis=0)
    means = rw.reshape(m, 100, 1, 3).mean(axis=1)
    est, found = velocity_random_walk(np.diff(means, axis=0), p, q0=1e-6)
    assert found[0] and 0.5 * q < est[0] < 1.6 * q, est
    sway = rng.standard_normal((m, 1, 3)) * 0.05          # white means: bounded velocity
    est, found = velocity_random_walk(np.diff(sway, axis=0), p, q0=1e-6)
    assert not found[0], est
