"""IMU simulator for a quasi-static base (numpy only, no ROS).

Generates gyro and accelerometer samples of a strapdown IMU sitting at a fixed latitude and
height, optionally swaying (a parked car being boarded, a moored ship), with sensor errors.

Frames and conventions (ALGORITHM.md)
-------------------------------------
- n = ENU, fixed to the Earth, so it rotates with ``omega_ie^n`` relative to inertial space.
- b = the IMU's own axes. ``C_b^n`` rotates body vectors into ENU.
- True attitude: ``C_b^n(t) = C_ref · exp((theta(t) x))`` where ``C_ref = dcm_from_rpy(rpy)``
  is the mean (undisturbed) attitude and ``theta(t)`` (rad, about the body axes) is the sway,
  a smooth bounded analytic function of the time since ``t0``. ``C0 = C_b^n(t0)``, so the truth
  is also ``C0 · (exp(theta(t0)) ^T exp(theta(t)))``.
- True position of the IMU (ENU, m, relative to its mean position):
  ``p(t) = d(t) + C_ref (exp((theta(t) x)) - I) l^b`` — linear vibration ``d(t)`` of the rotation
  centre plus the lever-arm effect of the angular sway, lever arm ``l^b`` from the rotation
  centre to the IMU in body axes. ``v_true = dp/dt`` analytically.

Sensor model (exact for the damped mechanization of ALGORITHM.md)
-----------------------------------------------------------------
The error-free gyro sample ``k`` is the rotation-vector increment of the body w.r.t. inertial
space over ``(t[k-1], t[k]]`` divided by ``dt``::

    dC_k = C_{k-1}^T exp((omega_ie^n x) dt) C_k,       w_k = log(dC_k) / dt

so ``C_k = exp(-(omega_ie^n x) dt) C_{k-1} exp((w_k x) dt)`` reproduces the truth to round-off.
The error-free specific force makes ``v_k = v_{k-1} + (C_k f_k + g^n) dt`` reproduce ``v_true``::

    f_k = C_k^T ((v_true[k] - v_true[k-1]) / dt - g^n)

(the damped mechanization has no Coriolis or transport terms, and neither has this model).
Errors added: constant bias, white noise (``arw / sqrt(dt)``, ``vrw / sqrt(dt)`` per sample),
optional first-order Gauss-Markov bias wander, optional quantisation of the increments with the
residual carried forward.

Determinism
-----------
Everything random comes from ``np.random.default_rng(seed)`` split into independent child
streams (sway, biases, gyro noise, accel noise, gyro wander, accel wander). Samples are produced
in fixed chunks of ``_CHUNK`` samples aligned to sample 0, so :class:`ImuSimulator` streaming
``next_block`` calls of any sizes give bit-identical samples to :func:`simulate`.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from .earth import earth_rate_enu, gravity_enu
from .rotation import dcm_from_rpy, quat_from_dcm, skew, so3_exp, so3_log
from .specs import SensorSpecs, grade_specs

__all__ = ["SwayProfile", "SWAY_PRESETS", "sway_profile", "SimResult", "simulate",
           "ImuSimulator"]

_DEG = np.pi / 180.0
#: Samples generated per internal chunk (fixed so that streaming == batch bit for bit).
_CHUNK = 4096
#: Burst envelopes are cut where ``exp(-sigma s)`` falls below ``exp(-_BURST_CUT)`` (~1e-14).
_BURST_CUT = 32.0


def _vec3(x, name: str) -> tuple[float, float, float]:
    a = np.asarray(x, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers, got {x!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


@dataclass(frozen=True)
class SwayProfile:
    """Angular sway and linear vibration of a quasi-static base.

    Two kinds of motion, which may be combined:

    - steady sinusoids (a moored ship): ``theta_i(t) = ang_amp_i sin(2 pi ang_freq_i t + phase)``,
      ``d_i(t) = lin_amp_i sin(2 pi lin_freq_i t + phase)``, random phases from the seed;
    - random bursts (a parked car being boarded): onsets form a Poisson process of rate
      ``burst_rate``; each burst is a damped oscillation with smooth (C2) onset,
      ``x(s) = a (1 - exp(-s/burst_onset))^2 exp(-sigma s) sin(omega_d s)``, ``s`` time since onset,
      natural frequency drawn uniformly in ``burst_freq``, damping ratio ``burst_damping``,
      per-axis amplitudes ``a_i = amp_i * U(-1, 1)``.

    Attributes
    ----------
    name : str — label.
    ang_amp : (3,) rad — sinusoid amplitudes about body x, y, z (roll, pitch, yaw for FLU/RFU).
    ang_freq : (3,) Hz — sinusoid frequencies.
    lin_amp : (3,) m — sinusoid displacement amplitudes of the rotation centre on E, N, U.
    lin_freq : (3,) Hz — their frequencies.
    lever_arm : (3,) m, body axes — IMU position relative to the rotation centre.
    burst_rate : 1/s — mean number of bursts per second (0 = no bursts).
    burst_ang_amp : (3,) rad — largest burst angle amplitude about body x, y, z.
    burst_lin_amp : (3,) m — largest burst displacement amplitude on E, N, U.
    burst_freq : (2,) Hz — range of the burst natural frequency.
    burst_damping : — damping ratio zeta of the bursts, in (0, 1).
    burst_onset : s — onset time constant of a burst (> 0).
    """

    name: str = "custom"
    ang_amp: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ang_freq: tuple[float, float, float] = (0.1, 0.1, 0.1)
    lin_amp: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lin_freq: tuple[float, float, float] = (0.1, 0.1, 0.1)
    lever_arm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    burst_rate: float = 0.0
    burst_ang_amp: tuple[float, float, float] = (0.0, 0.0, 0.0)
    burst_lin_amp: tuple[float, float, float] = (0.0, 0.0, 0.0)
    burst_freq: tuple[float, float] = (1.0, 3.0)
    burst_damping: float = 0.2
    burst_onset: float = 0.05

    def __post_init__(self):
        for nm in ("ang_amp", "ang_freq", "lin_amp", "lin_freq", "lever_arm",
                   "burst_ang_amp", "burst_lin_amp"):
            object.__setattr__(self, nm, _vec3(getattr(self, nm), f"SwayProfile.{nm}"))
        for nm in ("ang_amp", "lin_amp", "burst_ang_amp", "burst_lin_amp"):
            if min(getattr(self, nm)) < 0.0:
                raise ValueError(f"SwayProfile.{nm} must be >= 0, got {getattr(self, nm)}")
        for nm in ("ang_freq", "lin_freq"):
            if min(getattr(self, nm)) <= 0.0:
                raise ValueError(f"SwayProfile.{nm} must be > 0 Hz, got {getattr(self, nm)}")
        fr = np.asarray(self.burst_freq, dtype=float)
        if fr.shape != (2,) or not np.all(np.isfinite(fr)) or not 0.0 < fr[0] <= fr[1]:
            raise ValueError(f"SwayProfile.burst_freq must be (lo, hi) Hz with 0 < lo <= hi, "
                             f"got {self.burst_freq!r}")
        object.__setattr__(self, "burst_freq", (float(fr[0]), float(fr[1])))
        if not np.isfinite(self.burst_rate) or self.burst_rate < 0.0:
            raise ValueError(f"SwayProfile.burst_rate must be finite and >= 0, got "
                             f"{self.burst_rate!r}")
        if not 0.0 < self.burst_damping < 1.0:
            raise ValueError(f"SwayProfile.burst_damping must be in (0, 1), got "
                             f"{self.burst_damping!r}")
        if not np.isfinite(self.burst_onset) or self.burst_onset <= 0.0:
            raise ValueError(f"SwayProfile.burst_onset must be > 0 s, got {self.burst_onset!r}")

    def scaled(self, amplitude: float) -> SwayProfile:
        """Copy with every angular and linear amplitude multiplied by ``amplitude`` (>= 0)."""
        amplitude = _check_amplitude(amplitude)
        if amplitude == 1.0:
            return self

        def s(v: tuple[float, ...]) -> tuple[float, ...]:
            return tuple(amplitude * x for x in v)

        return replace(self, ang_amp=s(self.ang_amp), lin_amp=s(self.lin_amp),
                       burst_ang_amp=s(self.burst_ang_amp), burst_lin_amp=s(self.burst_lin_amp))

    @property
    def is_static(self) -> bool:
        """True if the profile produces no motion at all."""
        bursts = self.burst_rate > 0.0 and max(self.burst_ang_amp + self.burst_lin_amp) > 0.0
        return not bursts and max(self.ang_amp + self.lin_amp) == 0.0


def _check_amplitude(amplitude: float) -> float:
    try:
        a = float(amplitude)
    except (TypeError, ValueError):
        raise ValueError(f"sway amplitude must be a number, got {amplitude!r}") from None
    if not np.isfinite(a) or a < 0.0:
        raise ValueError(f"sway amplitude must be finite and >= 0, got {amplitude!r}")
    return a


#: Sway presets. 'car': parked car being boarded (bursts of damped 1-3 Hz oscillations,
#: up to 0.3 deg roll/pitch, mm-level displacement). 'ship': moored ship (roll 3 deg / 8 s,
#: pitch 1 deg / 6 s, yaw 0.5 deg / 12 s; sway/surge/heave 0.3/0.2/0.4 m).
SWAY_PRESETS: dict[str, SwayProfile] = {
    "none": SwayProfile(name="none"),
    "car": SwayProfile(
        name="car",
        lever_arm=(0.5, 0.3, 0.4),
        burst_rate=0.1,
        burst_ang_amp=(0.3 * _DEG, 0.3 * _DEG, 0.05 * _DEG),
        burst_lin_amp=(1.0e-3, 1.0e-3, 3.0e-3),
        burst_freq=(1.0, 3.0),
        burst_damping=0.2,
        burst_onset=0.05,
    ),
    "ship": SwayProfile(
        name="ship",
        ang_amp=(3.0 * _DEG, 1.0 * _DEG, 0.5 * _DEG),
        ang_freq=(1.0 / 8.0, 1.0 / 6.0, 1.0 / 12.0),
        lin_amp=(0.3, 0.2, 0.4),
        lin_freq=(1.0 / 10.0, 1.0 / 14.0, 1.0 / 7.0),
        lever_arm=(2.0, 0.5, 3.0),
    ),
}


def sway_profile(name: str, amplitude: float = 1.0) -> SwayProfile:
    """Preset sway profile ``name`` ('none', 'car', 'ship') with amplitudes scaled by ``amplitude``.

    Raises
    ------
    ValueError
        Unknown name, or amplitude not finite or negative.
    """
    try:
        base = SWAY_PRESETS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown sway profile {name!r}; choose one of "
                         f"{sorted(SWAY_PRESETS)}") from None
    return base.scaled(amplitude)


@dataclass
class SimResult:
    """A block of simulated IMU samples with the truth.

    Attributes
    ----------
    t : (N,) s — sample stamps, ``t[k] = t0 + (k + 1) / rate`` (k counted from the start).
    gyro : (N, 3) rad/s, body — measured ``w_ib^b``: increment rotation vector over
        ``(t[k-1], t[k]]`` divided by ``dt``, with sensor errors.
    accel : (N, 3) m/s^2, body — measured specific force ``f^b`` (velocity increment / dt).
    C_true : (N, 3, 3) — true ``C_b^n`` (body to ENU) at ``t[k]``.
    quat_true : (N, 4) — ``[x, y, z, w]`` quaternion of ``C_true``.
    C0 : (3, 3) — true ``C_b^n`` at ``t0`` (before the first sample).
    gyro_bias : (3,) rad/s, body — constant gyro bias.
    accel_bias : (3,) m/s^2, body — constant accelerometer bias.
    lat_rad : rad; height_m : m; rate : Hz; specs : SensorSpecs; sway : SwayProfile.
    v_true : (N, 3) m/s, ENU — true velocity of the IMU w.r.t. the Earth.
    p_true : (N, 3) m, ENU — true IMU displacement from its mean position.
    v0 : (3,) m/s, ENU — true velocity at ``t0``.
    gyro_ideal, accel_ideal : (N, 3) — the error-free samples (same units as gyro, accel).
    gyro_drift, accel_drift : (N, 3) — Gauss-Markov bias wander added (zeros when off).
    """

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    C_true: np.ndarray
    quat_true: np.ndarray
    C0: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    lat_rad: float
    height_m: float
    rate: float
    specs: SensorSpecs
    sway: SwayProfile
    v_true: np.ndarray
    p_true: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    v0: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_ideal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    accel_ideal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    gyro_drift: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    accel_drift: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def dt(self) -> float:
        """Sample interval, s."""
        return 1.0 / self.rate

    def __len__(self) -> int:
        return len(self.t)


#: Per-sample array fields of SimResult, in the order the engine produces them.
_ARRAY_FIELDS = ("t", "gyro", "accel", "C_true", "quat_true", "v_true", "p_true",
                 "gyro_ideal", "accel_ideal", "gyro_drift", "accel_drift")


# ----------------------------------------------------------------------------------------------
# Sway kinematics
# ----------------------------------------------------------------------------------------------
def _right_jacobian(theta: np.ndarray) -> np.ndarray:
    """Right Jacobian of SO(3): ``d/dt exp(theta) = exp(theta) (J_r(theta) theta_dot x)``."""
    th2 = np.sum(theta * theta, axis=-1)
    th = np.sqrt(th2)
    small = th < 1e-4
    ths = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th2 / 24.0 + th2 * th2 / 720.0, (1.0 - np.cos(ths)) / (ths * ths))
    b = np.where(small, 1.0 / 6.0 - th2 / 120.0 + th2 * th2 / 5040.0,
                 (ths - np.sin(ths)) / (ths * ths * ths))
    K = skew(theta)
    return np.eye(3) - a[..., None, None] * K + b[..., None, None] * (K @ K)


class _SwayModel:
    """Deterministic realisation of a SwayProfile: angle, rate, displacement, velocity at any s.

    ``s`` is the time since ``t0`` in seconds. Bursts are drawn lazily, in onset order, from the
    sway stream, so the realisation does not depend on how far ahead it was evaluated.
    """

    def __init__(self, profile: SwayProfile, rng: np.random.Generator):
        self.p = profile
        self.rng = rng
        ph = rng.uniform(0.0, 2.0 * np.pi, size=6)
        self.ang_phase, self.lin_phase = ph[:3], ph[3:]
        self.ang_amp = np.array(profile.ang_amp)
        self.ang_w = 2.0 * np.pi * np.array(profile.ang_freq)
        self.lin_amp = np.array(profile.lin_amp)
        self.lin_w = 2.0 * np.pi * np.array(profile.lin_freq)
        self.lever = np.array(profile.lever_arm)
        self.has_bursts = profile.burst_rate > 0.0 and (
            max(profile.burst_ang_amp) > 0.0 or max(profile.burst_lin_amp) > 0.0)
        # bursts: rows [onset, sigma, omega_d, a_ang(3), a_lin(3)]
        self.bursts = np.zeros((0, 9))
        if self.has_bursts:
            wn_lo = 2.0 * np.pi * profile.burst_freq[0]
            self.burst_len = _BURST_CUT / (profile.burst_damping * wn_lo)
            # start the Poisson process early so the motion is already stationary at s = 0
            self._next_onset = -self.burst_len + rng.exponential(1.0 / profile.burst_rate)

    def _extend_bursts(self, s_max: float) -> None:
        p = self.p
        rows = []
        while self._next_onset <= s_max:
            u = self.rng.random(7)
            fn = p.burst_freq[0] + (p.burst_freq[1] - p.burst_freq[0]) * u[0]
            wn = 2.0 * np.pi * fn
            sigma = p.burst_damping * wn
            wd = wn * np.sqrt(1.0 - p.burst_damping ** 2)
            a_ang = np.array(p.burst_ang_amp) * (2.0 * u[1:4] - 1.0)
            a_lin = np.array(p.burst_lin_amp) * (2.0 * u[4:7] - 1.0)
            rows.append(np.concatenate([[self._next_onset, sigma, wd], a_ang, a_lin]))
            self._next_onset += self.rng.exponential(1.0 / p.burst_rate)
        if rows:
            self.bursts = np.vstack([self.bursts] + rows)

    def evaluate(self, s: np.ndarray):
        """Sway at times ``s`` (M,) s since t0.

        Returns
        -------
        theta : (M, 3) rad, body — sway rotation vector.
        omega : (M, 3) rad/s, body — sway angular rate (``R' = R (omega x)``).
        d : (M, 3) m, ENU — displacement of the rotation centre.
        d_dot : (M, 3) m/s, ENU — its velocity.
        """
        arg = s[:, None] * self.ang_w + self.ang_phase
        theta = self.ang_amp * np.sin(arg)
        theta_dot = self.ang_amp * self.ang_w * np.cos(arg)
        arg = s[:, None] * self.lin_w + self.lin_phase
        d = self.lin_amp * np.sin(arg)
        d_dot = self.lin_amp * self.lin_w * np.cos(arg)
        if self.has_bursts and len(s):
            self._extend_bursts(float(s[-1]))
            tau = self.p.burst_onset
            for row in self.bursts:
                onset, sigma, wd = row[0], row[1], row[2]
                if onset + self.burst_len < s[0] or onset >= s[-1]:
                    continue
                i0 = np.searchsorted(s, onset, side="right")
                i1 = np.searchsorted(s, onset + self.burst_len, side="right")
                u = s[i0:i1] - onset
                e1 = np.exp(-u / tau)
                ramp = (1.0 - e1) ** 2
                ramp_dot = 2.0 * (1.0 - e1) * e1 / tau
                dec = np.exp(-sigma * u)
                sn, cs = np.sin(wd * u), np.cos(wd * u)
                h = ramp * dec * sn
                h_dot = dec * (ramp_dot * sn + ramp * (wd * cs - sigma * sn))
                theta[i0:i1] += h[:, None] * row[3:6]
                theta_dot[i0:i1] += h_dot[:, None] * row[3:6]
                d[i0:i1] += h[:, None] * row[6:9]
                d_dot[i0:i1] += h_dot[:, None] * row[6:9]
            # evaluation times only move forward: forget bursts that have died out
            self.bursts = self.bursts[self.bursts[:, 0] + self.burst_len >= s[0]]
        omega = np.einsum("mij,mj->mi", _right_jacobian(theta), theta_dot)
        return theta, omega, d, d_dot


# ----------------------------------------------------------------------------------------------
# Error processes
# ----------------------------------------------------------------------------------------------
def _ar1_scan(y0: np.ndarray, drive: np.ndarray, a: float) -> np.ndarray:
    """``y_j = a y_{j-1} + drive_j`` for j = 0..M-1 starting from ``y0`` (3,), vectorised.

    Uses ``y_j = a^(j+1) (y0 + sum_{i<=j} drive_i a^-(i+1))`` on sub-blocks short enough that
    ``a^-L`` stays far from overflow.
    """
    m = len(drive)
    out = np.empty_like(drive)
    if a <= 0.0:
        out[:] = drive
        return out
    L = m if a ** m > 1e-100 else max(1, int(-100.0 * np.log(10.0) / np.log(a)))
    y = y0
    for j0 in range(0, m, L):
        blk = drive[j0:j0 + L]
        pw = a ** np.arange(1, len(blk) + 1, dtype=float)
        seg = pw[:, None] * (y + np.cumsum(blk / pw[:, None], axis=0))
        out[j0:j0 + L] = seg
        y = seg[-1]
    return out


def _quantize(inc: np.ndarray, q: float, residual: np.ndarray):
    """Quantise increments (M, 3) to multiples of ``q``, carrying the residual (3,).

    The sum of the outputs equals the sum of the inputs plus the old residual minus the new
    one, so no information is lost over time (|residual| <= q/2).
    """
    acc = residual + np.cumsum(inc, axis=0)
    n = np.round(acc / q)
    out = q * np.diff(n, axis=0, prepend=0.0)
    return out, acc[-1] - q * n[-1]


# ----------------------------------------------------------------------------------------------
# Simulator
# ----------------------------------------------------------------------------------------------
def _finite(x, name: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number, got {x!r}") from None
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite, got {x!r}")
    return v


class ImuSimulator:
    """Streaming IMU simulator: same physics and seed => same samples as :func:`simulate`.

    Parameters
    ----------
    rate : Hz — sample rate (> 0).
    lat_deg : deg — geodetic latitude, |lat| <= 90.
    height_m : m — height above the ellipsoid.
    rpy_deg : (3,) deg — mean attitude, REP-103 [roll, pitch, yaw] of ``C_b^n`` (ENU).
    specs : SensorSpecs or grade name ('navigation', 'tactical', 'consumer').
    sway : SwayProfile or preset name ('none', 'car', 'ship').
    sway_amplitude : — factor applied to the sway amplitudes (>= 0).
    seed : int or None — seed of ``np.random.default_rng``; None = fresh entropy.
    t0 : s — time origin; the first sample is stamped ``t0 + 1/rate``.
    gyro_bias : (3,) rad/s, body, optional — constant gyro bias (default: drawn N(0, spec)).
    accel_bias : (3,) m/s^2, body, optional — constant accel bias (default: drawn N(0, spec)).
    noise : bool — False switches off the random processes (white noise and bias wander);
        constant biases and quantisation stay.
    """

    def __init__(self, rate: float = 100.0, lat_deg: float = 34.0, height_m: float = 0.0,
                 rpy_deg: Sequence[float] = (0.0, 0.0, 0.0),
                 specs: SensorSpecs | str = "navigation", sway: SwayProfile | str = "none",
                 sway_amplitude: float = 1.0, seed: int | None = 0, t0: float = 0.0,
                 gyro_bias: Sequence[float] | None = None,
                 accel_bias: Sequence[float] | None = None, noise: bool = True):
        rate = _finite(rate, "rate")
        if rate <= 0.0:
            raise ValueError(f"rate must be > 0 Hz, got {rate!r}")
        lat_deg = _finite(lat_deg, "lat_deg")
        if abs(lat_deg) > 90.0:
            raise ValueError(f"lat_deg must be within [-90, 90], got {lat_deg!r}")
        self.height_m = _finite(height_m, "height_m")
        self.t0 = _finite(t0, "t0")
        rpy = np.array(_vec3(rpy_deg, "rpy_deg"))
        if isinstance(specs, str):
            specs = grade_specs(specs)
        elif not isinstance(specs, SensorSpecs):
            raise ValueError(f"specs must be a SensorSpecs or a grade name, got {specs!r}")
        if isinstance(sway, str):
            sway = sway_profile(sway, sway_amplitude)
        elif isinstance(sway, SwayProfile):
            sway = sway.scaled(sway_amplitude)
        else:
            raise ValueError(f"sway must be a SwayProfile or a preset name, got {sway!r}")
        if seed is not None and not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed must be an int or None, got {seed!r}")

        self.rate = rate
        self.dt = 1.0 / rate
        self.lat_rad = lat_deg * _DEG
        self.specs = specs
        self.sway = sway
        self.noise = bool(noise)
        self.seed = seed

        rng = np.random.default_rng(seed)
        (r_sway, r_bias, self._rng_gn, self._rng_an,
         r_gw, r_aw) = rng.spawn(6)
        self._rng_gw, self._rng_aw = r_gw, r_aw

        gb = r_bias.normal(0.0, specs.gyro_bias, 3)
        ab = r_bias.normal(0.0, specs.accel_bias, 3)
        self.gyro_bias = gb if gyro_bias is None else np.array(_vec3(gyro_bias, "gyro_bias"))
        self.accel_bias = ab if accel_bias is None else np.array(_vec3(accel_bias, "accel_bias"))

        self._sway = _SwayModel(sway, r_sway)
        self.C_ref = dcm_from_rpy(rpy * _DEG)
        self.w_ie_n = earth_rate_enu(self.lat_rad)
        self.g_n = gravity_enu(self.lat_rad, self.height_m)
        # inertial rotation of n over one interval, seen in the reference body axes:
        # C_ref^T exp(w dt) C_ref = exp(C_ref^T w dt), the latter keeps full relative precision
        self._E = so3_exp(self.C_ref.T @ self.w_ie_n * self.dt)

        th0, _, _, _ = self._sway.evaluate(np.zeros(1))
        self.C0 = self.C_ref @ so3_exp(th0[0])
        _, _, _, _, _, v0 = self._truth(np.zeros(1))
        self.v0 = v0[0]

        # error-process state
        self._a = float(np.exp(-self.dt / specs.bias_correlation_time))
        self._gw = (r_gw.normal(0.0, specs.gyro_bias_instability, 3) if self.noise
                    else np.zeros(3))
        self._aw = (r_aw.normal(0.0, specs.accel_bias_instability, 3) if self.noise
                    else np.zeros(3))
        self._gq_res = np.zeros(3)
        self._aq_res = np.zeros(3)

        self._chunk_start = 0            # sample index of the next chunk to generate
        self._buf: dict[str, np.ndarray] | None = None
        self._buf_pos = 0
        self.samples_emitted = 0

    # -- truth --------------------------------------------------------------------------------
    def _truth(self, s: np.ndarray):
        """True R (sway), C_b^n, displacement and velocity at times ``s`` since t0."""
        theta, omega, d, d_dot = self._sway.evaluate(s)
        R = so3_exp(theta)
        C = self.C_ref @ R
        lever = self._sway.lever
        p = d + (R - np.eye(3)) @ lever @ self.C_ref.T
        v = d_dot + np.einsum("mij,mj->mi", C, np.cross(omega, lever))
        return theta, R, C, p, d, v

    def _generate_chunk(self) -> dict[str, np.ndarray]:
        k0, m, dt = self._chunk_start, _CHUNK, self.dt
        # times of samples k0-1 .. k0+m-1 (index -1 is t0 itself)
        s = np.arange(k0, k0 + m + 1, dtype=float) / self.rate
        _, R, C, p, _, v = self._truth(s)
        dC = np.swapaxes(R[:-1], -1, -2) @ self._E @ R[1:]
        gyro_ideal = so3_log(dC) / dt
        accel_ideal = np.einsum("mji,mj->mi", C[1:], (v[1:] - v[:-1]) / dt - self.g_n)

        sp = self.specs
        gyro = gyro_ideal + self.gyro_bias
        accel = accel_ideal + self.accel_bias
        gdrift = np.zeros((m, 3))
        adrift = np.zeros((m, 3))
        if self.noise:
            sq = np.sqrt(self.rate)
            # draw unconditionally so each stream's sequence never depends on the specs
            wg = self._rng_gn.standard_normal((m, 3))
            wa = self._rng_an.standard_normal((m, 3))
            gyro += sp.gyro_arw * sq * wg
            accel += sp.accel_vrw * sq * wa
            c = np.sqrt(1.0 - self._a ** 2)
            if sp.gyro_bias_instability > 0.0:
                gdrift = _ar1_scan(self._gw, c * sp.gyro_bias_instability
                                   * self._rng_gw.standard_normal((m, 3)), self._a)
                self._gw = gdrift[-1]
                gyro += gdrift
            if sp.accel_bias_instability > 0.0:
                adrift = _ar1_scan(self._aw, c * sp.accel_bias_instability
                                   * self._rng_aw.standard_normal((m, 3)), self._a)
                self._aw = adrift[-1]
                accel += adrift
        if sp.gyro_quantization > 0.0:
            inc, self._gq_res = _quantize(gyro * dt, sp.gyro_quantization, self._gq_res)
            gyro = inc / dt
        if sp.accel_quantization > 0.0:
            inc, self._aq_res = _quantize(accel * dt, sp.accel_quantization, self._aq_res)
            accel = inc / dt

        self._chunk_start += m
        return {
            "t": self.t0 + s[1:], "gyro": gyro, "accel": accel, "C_true": C[1:],
            "quat_true": quat_from_dcm(C[1:]), "v_true": v[1:], "p_true": p[1:],
            "gyro_ideal": gyro_ideal, "accel_ideal": accel_ideal,
            "gyro_drift": gdrift, "accel_drift": adrift,
        }

    # -- public -------------------------------------------------------------------------------
    def next_block(self, n: int) -> SimResult:
        """The next ``n`` samples (continuing time): identical to slicing :func:`simulate`.

        Parameters
        ----------
        n : int >= 0 — number of samples.

        Returns
        -------
        SimResult with N = n samples.
        """
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"n must be an int >= 0, got {n!r}")
        pieces: list[dict[str, np.ndarray]] = []
        need = int(n)
        while need > 0:
            if self._buf is None or self._buf_pos >= _CHUNK:
                self._buf = self._generate_chunk()
                self._buf_pos = 0
            take = min(need, _CHUNK - self._buf_pos)
            sl = slice(self._buf_pos, self._buf_pos + take)
            pieces.append({k: v[sl] for k, v in self._buf.items()})
            self._buf_pos += take
            need -= take
        if len(pieces) == 1:
            arrays = {k: v.copy() for k, v in pieces[0].items()}
        elif pieces:
            arrays = {k: np.concatenate([p[k] for p in pieces]) for k in _ARRAY_FIELDS}
        else:
            arrays = {"t": np.zeros(0), "C_true": np.zeros((0, 3, 3)),
                      "quat_true": np.zeros((0, 4))}
            arrays.update({k: np.zeros((0, 3)) for k in _ARRAY_FIELDS if k not in arrays})
        self.samples_emitted += int(n)
        return SimResult(
            C0=self.C0.copy(), gyro_bias=self.gyro_bias.copy(),
            accel_bias=self.accel_bias.copy(), lat_rad=self.lat_rad, height_m=self.height_m,
            rate=self.rate, specs=self.specs, sway=self.sway, v0=self.v0.copy(), **arrays)


def simulate(duration: float, rate: float = 100.0, lat_deg: float = 34.0, height_m: float = 0.0,
             rpy_deg: Sequence[float] = (0.0, 0.0, 0.0), specs: SensorSpecs | str = "navigation",
             sway: SwayProfile | str = "none", sway_amplitude: float = 1.0,
             seed: int | None = 0, t0: float = 0.0,
             gyro_bias: Sequence[float] | None = None,
             accel_bias: Sequence[float] | None = None, noise: bool = True) -> SimResult:
    """Simulate ``duration`` seconds of IMU data on a quasi-static base.

    Parameters
    ----------
    duration : s (> 0) — N = floor(duration * rate) samples, stamped in (t0, t0 + duration].
    Other parameters : as :class:`ImuSimulator`.

    Returns
    -------
    SimResult — samples, truth (attitude, velocity, displacement), the biases drawn.

    Raises
    ------
    ValueError
        Non-finite or out-of-range arguments, unknown grade or sway preset, duration shorter
        than one sample.
    """
    duration = _finite(duration, "duration")
    if duration <= 0.0:
        raise ValueError(f"duration must be > 0 s, got {duration!r}")
    sim = ImuSimulator(rate=rate, lat_deg=lat_deg, height_m=height_m, rpy_deg=rpy_deg,
                       specs=specs, sway=sway, sway_amplitude=sway_amplitude, seed=seed, t0=t0,
                       gyro_bias=gyro_bias, accel_bias=accel_bias, noise=noise)
    n = int(np.floor(duration * sim.rate + 1e-9))
    if n < 1:
        raise ValueError(f"duration {duration!r} s is shorter than one sample at {sim.rate} Hz")
    return sim.next_block(n)
