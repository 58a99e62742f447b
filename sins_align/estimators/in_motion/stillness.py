"""Is the vehicle parked, and can its gyro find the heading there? (numpy only).

Standing still, the transition of the in-motion filter is built from measured rates and
specific forces that hold only the IMU's noise; taken as exact regressors (the left-invariant
error's Jacobian) that noise gives the filter heading information that is not there: a MEMS
IMU parked with a velocity reference saw its heading std fall from 10 deg to ~4.5 deg in 300 s
while the error stayed ~11 deg ((e/sigma)^2 6.6 over 40 runs,
``test/test_in_motion_static_heading.py``). What a standing IMU really knows of its heading
comes from gyrocompassing alone: the Earth rate's horizontal component ``Omega cos(lat)``
against the east gyro bias, which limits the heading std to ``sigma_bE / (Omega cos(lat))``
(:func:`gyrocompass_limit`; the specs' gyro bias: standing still, the filter learns its own
east bias only together with the heading). When the filter's heading std is at or below that
limit (a MEMS gyro of 10 deg/h: 54 deg at 45 deg of latitude, above the heading std any
filter of the bank starts with; a tactical one of 1 deg/h: 5.4 deg, which it gyrocompasses
down to first; a navigation-grade one of 0.01 deg/h: 0.05 deg, below the 0.08 deg it
gyrocompasses to in 300 s, so it keeps gyrocompassing), an update cannot hold more heading
information standing, and what it would give is the noise's; so the aligner makes the heading
a consider state of its velocity and non-holonomic updates
(``InvariantEKF.update_velocity(..., consider_heading=True)``, ``update_lateral``): the
heading variance cannot shrink through them (nor, measured, through the propagation: every
interval of a 300 s standing bank grew it). A navigation-grade IMU keeps gyrocompassing.

:func:`is_parked` is the detector: the velocity reference within three of its own sigmas of
zero on every measured axis, and the IMU's samples over the last :data:`WINDOW` s what noise
at rest gives: per axis, the sample variance of the rates and of the specific forces within
the upper bound of white noise of the specs' density (five sigmas of the sample variance's
spread), the mean rate within the Earth rate plus three sigmas of the bias and of the noise's
mean, the mean specific force's magnitude within gravity plus the same for the
accelerometer. A vehicle that moves fails one of them (a constant velocity the reference; a
rotation, a vertical or a changing acceleration the IMU; a steady horizontal acceleration
leaves ``|f|`` at g to first order, and the reference sees the speed it builds within a
second or two); a false "parked" costs only the heading information
of those updates (the update is still a valid, suboptimal one), a missed one leaves the
filter as it was without the detector (an engine's vibration fails the variance test).
"""
from __future__ import annotations

import math

import numpy as np

from sins_align.core.earth import OMEGA_IE

__all__ = ["WINDOW", "gyrocompass_limit", "imu_at_rest", "is_parked", "reference_still"]

#: s of IMU samples the detector looks at, before the velocity update's sample
WINDOW = 1.0
#: fewer samples than this in the window: not parked (too little to tell)
_MIN_SAMPLES = 10


def gyrocompass_limit(sigma_east_bias: float, lat: float) -> float:
    """The heading std (rad) gyrocompassing can reach at best, standing still: the east gyro
    bias's std ``sigma_east_bias`` (rad/s) over the Earth rate's horizontal component at
    latitude ``lat`` (rad); inf at a pole."""
    horizontal = OMEGA_IE * abs(math.cos(lat))
    return math.inf if horizontal < 1e-12 * OMEGA_IE else sigma_east_bias / horizontal


def _variance_bound(var: float, n: int) -> float:
    """Upper bound of the sample variance of n white samples of variance ``var`` (the mean
    plus five standard deviations of the chi-square's, ``var sqrt(2 / (n - 1))``)."""
    return var * (1.0 + 5.0 * math.sqrt(2.0 / (n - 1)))


def reference_still(z, R) -> bool:
    """The velocity reference ``z`` (3,) m/s (NaN: not measured) within three of its sigmas
    (covariance ``R``) of zero on every measured axis (and some axis measured)."""
    z = np.asarray(z, dtype=float).tolist()
    R = np.asarray(R, dtype=float)
    seen = False
    for i in range(3):
        if math.isfinite(z[i]):              # (NaN: not measured)
            if z[i] * z[i] > 9.0 * float(R[i, i]):
                return False
            seen = True
    return seen


def is_parked(z, R, t, w, f, specs, gravity: float, nominal_dt: float) -> bool:
    """The detector (see the module): velocity reference ``z`` (3,) m/s ENU (NaN: not
    measured) of covariance ``R`` (3, 3); the IMU samples of the last :data:`WINDOW` s before
    it, stamps ``t`` (m,), rates ``w`` and specific forces ``f`` (m, 3); ``specs`` the IMU's
    :class:`~sins_align.core.specs.SensorSpecs`; ``gravity`` m/s^2 there; ``nominal_dt`` s,
    the sample interval."""
    return reference_still(z, R) and imu_at_rest(t, w, f, specs, gravity, nominal_dt)


def imu_at_rest(t, w, f, specs, gravity: float, nominal_dt: float) -> bool:
    """The IMU part of :func:`is_parked` (the same arguments): what depends on the samples
    only."""
    n = len(t)
    if n < _MIN_SAMPLES or float(t[-1] - t[0]) < 0.8 * WINDOW:
        return False
    T = float(t[-1] - t[0]) + nominal_dt
    x = np.hstack((w, f))                               # (one pass for both sensors)
    mean = x.mean(axis=0)
    d = x - mean
    var = (np.einsum("ij,ij->j", d, d) / n).tolist()
    m = mean.tolist()
    # white noise of one sample (and the increments' quantisation, uniform), and its
    # sample variance's upper bound
    qw = specs.gyro_quantization / nominal_dt
    qf = specs.accel_quantization / nominal_dt
    if (max(var[:3]) > _variance_bound(specs.gyro_arw ** 2 / nominal_dt + qw * qw / 12.0, n)
            or max(var[3:]) > _variance_bound(specs.accel_vrw ** 2 / nominal_dt
                                              + qf * qf / 12.0, n)):
        return False
    # the means: Earth rate (<= Omega per axis) and bias, gravity and bias, three sigmas
    # each of the bias with its wander (per axis, or the norm's for the force) and of the
    # noise's mean
    bg = math.hypot(specs.gyro_bias, specs.gyro_bias_instability)
    ba = math.hypot(specs.accel_bias, specs.accel_bias_instability)
    if max(abs(v) for v in m[:3]) > OMEGA_IE + 3.0 * bg + 3.0 * specs.gyro_arw / math.sqrt(T):
        return False
    fm = math.sqrt(m[3] * m[3] + m[4] * m[4] + m[5] * m[5])
    return abs(fm - gravity) <= 3.0 * math.sqrt(3.0) * ba + 3.0 * specs.accel_vrw / math.sqrt(T)
