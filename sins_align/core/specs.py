"""Sensor error specifications, grade presets and the limit (theoretical) alignment accuracy.

All values are stored in SI units: rad/s, rad/sqrt(s), m/s^2, m/s/sqrt(s).
Specs are isotropic (one figure per sensor type), which keeps G Q G^T independent of the
attitude estimate (ALGORITHM.md).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sins_align.core.earth import OMEGA_IE, gravity

DEG = np.pi / 180.0
DPH = DEG / 3600.0                 # deg/h -> rad/s
DPSH = DEG / 60.0                  # deg/sqrt(h) -> rad/sqrt(s)
UG = 9.80665e-6                    # micro-g -> m/s^2
UG_PSHZ = UG                       # micro-g/sqrt(Hz) -> m/s/sqrt(s)


@dataclass(frozen=True)
class SensorSpecs:
    """One-sigma IMU error figures, isotropic.

    Attributes
    ----------
    gyro_bias : rad/s — constant (turn-on) gyro bias.
    gyro_arw : rad/sqrt(s) — angle random walk (white rate noise density).
    accel_bias : m/s^2 — constant accelerometer bias.
    accel_vrw : m/s/sqrt(s) — velocity random walk (white specific-force noise density).
    gyro_bias_instability : rad/s — stationary std of a first-order Gauss-Markov bias wander
        (a datasheet's bias instability); the estimators model it.
    accel_bias_instability : m/s^2 — likewise for the accelerometer.
    bias_correlation_time : s — correlation time of the bias wander.
    gyro_quantization : rad — angle increment quantum (simulation only, 0 = none).
    accel_quantization : m/s — velocity increment quantum (simulation only, 0 = none).
    gyro_warmup : rad/s — std of the extra bias at power-on that settles as
        ``exp(-t / warmup_time)`` (0 = none); the estimators cover it as one more wander
        of that std and correlation time.
    accel_warmup : m/s^2 — likewise for the accelerometer.
    warmup_time : s — time constant of the warm-up.
    """

    gyro_bias: float
    gyro_arw: float
    accel_bias: float
    accel_vrw: float
    gyro_bias_instability: float = 0.0
    accel_bias_instability: float = 0.0
    bias_correlation_time: float = 300.0
    gyro_quantization: float = 0.0
    accel_quantization: float = 0.0
    gyro_warmup: float = 0.0
    accel_warmup: float = 0.0
    warmup_time: float = 300.0

    def __post_init__(self):
        for name in ("gyro_bias", "gyro_arw", "accel_bias", "accel_vrw",
                     "gyro_bias_instability", "accel_bias_instability",
                     "gyro_quantization", "accel_quantization", "gyro_warmup", "accel_warmup"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0.0:
                raise ValueError(f"sensor spec {name} must be finite and >= 0, got {v!r}")
        for name in ("bias_correlation_time", "warmup_time"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0.0:
                raise ValueError(f"sensor spec {name} must be > 0")

    def with_(self, **kw) -> "SensorSpecs":
        """Copy with some fields replaced."""
        return replace(self, **kw)

    @property
    def bias_prior_var(self) -> tuple[float, float]:
        """(gyro, accelerometer) variance of the bias at any instant: the turn-on bias, the
        wander's stationary variance and the warm-up's (both estimators' bias prior)."""
        return (self.gyro_bias ** 2 + self.gyro_bias_instability ** 2 + self.gyro_warmup ** 2,
                self.accel_bias ** 2 + self.accel_bias_instability ** 2
                + self.accel_warmup ** 2)

    @property
    def bias_walk_var(self) -> tuple[float, float]:
        """(gyro, accelerometer) density of the random walk the bias wander and the warm-up
        make over times short next to their time constants, 2 s^2 / tau summed (per s)."""
        tau, tw = self.bias_correlation_time, self.warmup_time
        return (2.0 * (self.gyro_bias_instability ** 2 / tau + self.gyro_warmup ** 2 / tw),
                2.0 * (self.accel_bias_instability ** 2 / tau + self.accel_warmup ** 2 / tw))


#: Typical grades (ALGORITHM.md table). 'navigation' is the paper's IMU.
GRADES: dict[str, SensorSpecs] = {
    "navigation": SensorSpecs(gyro_bias=0.01 * DPH, gyro_arw=0.001 * DPSH,
                              accel_bias=100 * UG, accel_vrw=10 * UG_PSHZ),
    "tactical": SensorSpecs(gyro_bias=1.0 * DPH, gyro_arw=0.1 * DPSH,
                            accel_bias=1000 * UG, accel_vrw=50 * UG_PSHZ),
    "consumer": SensorSpecs(gyro_bias=0.1 * DEG, gyro_arw=0.3 * DPSH,
                            accel_bias=5000 * UG, accel_vrw=100 * UG_PSHZ),
}


def grade_specs(name: str) -> SensorSpecs:
    """Preset specs by grade name ('navigation', 'tactical', 'consumer')."""
    try:
        return GRADES[name]
    except KeyError:
        raise ValueError(f"unknown grade {name!r}; choose one of {sorted(GRADES)}") from None


def limit_error(lat_rad: float, accel_bias_n: np.ndarray, gyro_bias_n: np.ndarray,
                g: float | None = None) -> np.ndarray:
    """Steady-state attitude error phi (E, N, U), rad, caused by constant biases in ENU.

    phi_E = -bA_N / g ; phi_N = bA_E / g ; phi_U = -bG_E / (w cos L) + bA_E tan L / g.
    Heading is unobservable at the poles: phi_U is then +-inf (never a division by zero).
    """
    g = gravity(lat_rad) if g is None else g
    a = np.asarray(accel_bias_n, dtype=float)
    e = np.asarray(gyro_bias_n, dtype=float)
    cl = np.cos(lat_rad)
    if abs(cl) < 1e-9:
        up = np.full(np.broadcast_shapes(a.shape, e.shape)[:-1], np.inf)
    else:
        up = -e[..., 0] / (OMEGA_IE * cl) + a[..., 0] * np.tan(lat_rad) / g
    return np.stack([-a[..., 1] / g, a[..., 0] / g, up], axis=-1)


def limit_covariance(lat_rad: float, specs: SensorSpecs, g: float | None = None) -> np.ndarray:
    """Covariance (3x3, rad^2, E/N/U) of the limit error for biases drawn from ``specs``.

    With isotropic specs the ENU-projected biases are isotropic too, whatever the attitude.
    Near the poles the U variance grows without bound (returned as inf).
    """
    g = gravity(lat_rad) if g is None else g
    sa2, se2 = specs.accel_bias ** 2, specs.gyro_bias ** 2
    wc = OMEGA_IE * np.cos(lat_rad)
    # phi = M [aE, aN, aU, eE, eN, eU]
    t = np.tan(lat_rad)
    P = np.zeros((3, 3))
    P[0, 0] = sa2 / g ** 2
    P[1, 1] = sa2 / g ** 2
    P[1, 2] = P[2, 1] = sa2 * t / g ** 2
    if abs(np.cos(lat_rad)) < 1e-9:
        P[1, 2] = P[2, 1] = 0.0
        P[2, 2] = np.inf
    else:
        P[2, 2] = se2 / wc ** 2 + sa2 * t * t / g ** 2
    return P


def limit_std(lat_rad: float, specs: SensorSpecs, g: float | None = None) -> np.ndarray:
    """One-sigma limit accuracy per axis (E, N, U), rad."""
    return np.sqrt(np.diag(limit_covariance(lat_rad, specs, g)))
