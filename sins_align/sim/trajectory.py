"""Moving-vehicle IMU and GNSS simulator with per-sample truth (numpy only, no ROS).

The test bench of the in-motion estimator (ALGORITHM.md, "In-motion alignment with a velocity
reference"); consistent with :mod:`sins_align.core.strapdown` (same frames, same Earth model).

Trajectory
----------
A trajectory is a list of :class:`Segment` s plus optional periodic :class:`Wave` s. Each
segment holds commanded values (forward, lateral and vertical acceleration in the heading
frame, yaw rate, pitch and roll angles); at the start of every segment but the first, each
value moves from the previous segment's to its own along the 7th-order smoothstep ``S`` over
``ramp`` s (C3: rates, accelerations and their derivatives stay continuous). After the last
segment the last commands hold (a run longer than the trajectory continues it). With ``q(t)``
such a channel:

- speeds in the heading frame ``u = u0 + int accel``, ``w = int lateral``, ``v_U = int climb``;
- track yaw ``psi = psi0 + int yaw_rate``; pitch and roll are the channels themselves;
- ``v^n = [u cos psi - w sin psi, u sin psi + w cos psi, v_U]`` (ENU; ``w`` to the left of the
  heading), ``C_b^n = dcm_from_rpy([roll, pitch, psi])`` (REP-103).

The trajectory is that of one point of the body (a car's rear-axle centre: the point whose
velocity has no sideways component). ``imu_position`` (body axes, m) puts the IMU elsewhere
on the rigid body: its velocity is ``v + C (w_nb^b x r)``, its acceleration gets
``C (dw_nb^b/dt x r + w_nb^b x (w_nb^b x r))`` (``dw/dt`` by central differences on the
half-sample grid) and its position is integrated from that velocity; the attitude is the
body's. An IMU ahead of a car's rear axle sees a sideways velocity ``yaw rate x distance``
in every turn.

Waves (a ship's sway) add ``A sin(2 pi t / P + phase)`` to the roll, pitch or yaw angle of the
body, or to its height (heave). The angle waves turn the body about the track only: the
velocity keeps the track yaw ``psi`` (a hull yawing +-1 deg does not steer its course), and
heave moves the body up and down (``v_U`` and ``dv_U/dt`` get its derivatives).

All integrals are analytic (the smoothstep integrates to a polynomial, a wave is a sine); the
position (lat, lon, h) is integrated from the velocity by Simpson's rule on the half-sample
grid.

Sensors
-------
On that half-sample grid the exact rates and specific force are::

    w_ib^b = w_nb^b + C^T (w_ie^n + w_en^n)
    f^b    = C^T (dv/dt + (2 w_ie^n + w_en^n) x v - g^n)

with ``w_nb^b`` from the Euler-angle rates. IMU sample k is their mean over
``(t[k-1], t[k]]`` by Simpson's rule (exact for a cubic in time; for a wave of angular
frequency w its error is (w dt)^4 / 2880 of the wave's rate amplitude, 1e-12 for an 8 s period
at 100 Hz), i.e. the increment divided by dt, the convention of
:mod:`sins_align.sim.simulator` and :mod:`sins_align.core.strapdown`.

Sensor errors (each sample, per axis ``i``)::

    meas_i = (1 + s_i) (true_i + vib_i) + b_i + noise_i

- ``s``: scale-factor error, drawn ``N(0, (ppm 1e-6)^2)`` per axis and run
  (``gyro_scale_ppm``, ``accel_scale_ppm``; consumer MEMS are ~1000-5000 ppm, tactical
  ~100-300 ppm, navigation grade a few ppm);
- ``b``: constant bias ``N(0, bias^2)`` per axis and run, and ``noise`` white of std
  ``arw / sqrt(dt)``, ``vrw / sqrt(dt)``, from a :class:`~sins_align.core.specs.SensorSpecs`;
  plus, when the specs give them, the bias wander (first-order Gauss-Markov of stationary
  std ``*_bias_instability`` and correlation time ``bias_correlation_time``, started from its
  stationary distribution) and a warm-up (a power-on bias ``N(0, *_warmup^2)`` per axis
  that settles as ``exp(-t / warmup_time)``);
  the samples are then quantised as increments (``*_quantization``, rad and m/s) with the
  residual carried, as :mod:`sins_align.sim.simulator` does;
- ``vib``: rotor vibration (:class:`Vibration`), an additive input that is not part of the
  truth (the body's vibration displacement is a fraction of a millimetre). Each axis is a sum
  of sinusoids ``a sin(2 pi f t + phi)`` of frequencies drawn uniformly in a band (e.g.
  20-80 Hz), random phases, and amplitudes ``a = rms sqrt(2 / tones)`` (``rms`` is the
  continuous signal's RMS per axis). **What a sample contains**: its exact interval mean,
  ``a sinc(f dt) sin(2 pi f (t[k] - dt/2) + phi)`` with ``sinc(x) = sin(pi x) / (pi x)``:
  the mean over one interval is not zero unless ``f`` is a multiple of the rate. At 100 Hz a
  20 Hz tone keeps 94 % of its amplitude, 50 Hz 64 %, 80 Hz 23 %, and every tone appears in
  the samples at its alias ``|f - m rate|`` (80 Hz at 20 Hz): strong vibration is a large,
  zero-mean, non-white error on every sample, which the strapdown integrates (and a tone near
  a multiple of the rate aliases close to 0 Hz). Coning and sculling rectification (a
  coupled angular and linear vibration) is not simulated: the vibration's long-run mean is 0.

GNSS
----
Epochs at every ``rate / gnss_rate``-th truth instant (the first at t = 0; stamped with the
measurement time ``gnss_t``), lever arm ``l^b`` from the IMU to the antenna:

- velocity ``v_ant = v^n + C_b^n (w_nb^b x l^b)`` plus white noise ``gnss_sigma`` per ENU
  axis; with ``gnss_vertical=False`` (an NMEA-style receiver: course and speed over ground
  only) the vertical component is NaN;
- antenna position ``p + C_b^n l^b`` as (lat, lon, h) plus white noise ``gnss_pos_sigma`` m
  per ENU axis;
- ``gnss_latency`` s: the measurement is delivered at ``gnss_arrival_t = gnss_t + latency``;
- dropouts: an epoch inside a window ``[start, end)`` of ``gnss_dropouts``, or dropped at
  random with probability ``gnss_dropout_prob``, has no measurement (it is absent from the
  ``gnss_*`` arrays; its time is in ``gnss_dropped_t``).

Randomness: ``np.random.SeedSequence(seed)`` spawned into independent streams (biases, IMU
noise, GNSS velocity noise, scale factors, vibration, GNSS dropouts, GNSS position noise,
gyro and accelerometer bias wander, warm-up), so
turning one error off does not change the others; noise is drawn for every epoch before the
dropouts are removed.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from sins_align.core.rotation import dcm_from_rpy
from sins_align.core.specs import DEG, DPH, DPSH, UG, UG_PSHZ, SensorSpecs, grade_specs
from sins_align.core.strapdown import (NavState, earth_rate, normal_gravity, radii,
                                       transport_rate)

__all__ = ["Segment", "Wave", "Trajectory", "Vibration", "VibrationTones", "TrajectoryResult",
           "simulate_trajectory", "car_with_turn", "uav_seed003", "car_city", "car_straight",
           "ship_under_way", "PRESETS", "trajectory_preset", "SEED003_SPECS", "UAV_VIBRATION"]

#: The MEMS IMU of seed 003: gyro bias 10 deg/h, accelerometer bias 0.1 mg. The seed gives no
#: noise densities; these (0.1 deg/sqrt(h), 50 ug/sqrt(Hz)) are assumptions.
SEED003_SPECS = SensorSpecs(gyro_bias=10.0 * DPH, gyro_arw=0.1 * DPSH,
                            accel_bias=100.0 * UG, accel_vrw=50.0 * UG_PSHZ)

_CHANNELS = ("accel", "lateral_accel", "climb_accel", "yaw_rate", "pitch", "roll")
_WAVE_CHANNELS = ("roll", "pitch", "yaw", "heave")


@dataclass(frozen=True)
class Segment:
    """A piece of trajectory with held commands (reached by a smoothstep at its start).

    Attributes
    ----------
    duration : s (> 0).
    accel : m/s^2 — forward acceleration along the heading (horizontal).
    lateral_accel : m/s^2 — rate of change of the horizontal speed to the left of the heading.
    climb_accel : m/s^2 — vertical acceleration (up).
    yaw_rate : deg/s — rate of the yaw (REP-103, counter-clockwise from East).
    pitch, roll : deg — REP-103 pitch (positive nose down) and roll (positive right side down).
    ramp : s — smoothstep time from the previous segment's commands (> 0; ignored for the
        first segment). A ramp longer than the segment overlaps the next one's: the channels
        are sums of smoothsteps, so the motion stays smooth.
    """

    duration: float
    accel: float = 0.0
    lateral_accel: float = 0.0
    climb_accel: float = 0.0
    yaw_rate: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    ramp: float = 1.0

    def __post_init__(self):
        for nm in ("duration", "ramp") + _CHANNELS:
            if not np.isfinite(getattr(self, nm)):
                raise ValueError(f"Segment.{nm} must be finite")
        if not (self.duration > 0.0 and self.ramp > 0.0):
            raise ValueError(f"Segment needs duration > 0 and ramp > 0, got "
                             f"{self.duration!r}, {self.ramp!r}")


@dataclass(frozen=True)
class Wave:
    """A periodic term ``amplitude sin(2 pi t / period + phase)`` over the whole run.

    Attributes
    ----------
    channel : 'roll', 'pitch', 'yaw' (body attitude about the track, deg) or 'heave'
        (height, m).
    amplitude : deg or m.
    period : s (> 0).
    phase : deg.
    """

    channel: str
    amplitude: float
    period: float
    phase: float = 0.0

    def __post_init__(self):
        if self.channel not in _WAVE_CHANNELS:
            raise ValueError(f"Wave.channel must be one of {_WAVE_CHANNELS}, got "
                             f"{self.channel!r}")
        if not (np.isfinite(self.amplitude) and np.isfinite(self.phase)
                and np.isfinite(self.period) and self.period > 0.0):
            raise ValueError(f"Wave needs a finite amplitude and phase and a period > 0, got "
                             f"{self.amplitude!r}, {self.phase!r}, {self.period!r}")


@dataclass(frozen=True)
class Trajectory:
    """Segments and waves plus the initial position, heading and forward speed.

    Attributes
    ----------
    segments : the segments, in order.
    lat_deg, lon_deg : deg; height_m : m — initial position.
    yaw_deg : deg — initial track yaw (REP-103: 0 = body x East, 90 = North).
    speed : m/s — initial forward speed (along the heading).
    name : label.
    waves : periodic terms added to the attitude or the height (:class:`Wave`).
    """

    segments: tuple[Segment, ...]
    lat_deg: float = 34.0
    lon_deg: float = 108.0
    height_m: float = 0.0
    yaw_deg: float = 0.0
    speed: float = 0.0
    name: str = "custom"
    waves: tuple[Wave, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "segments", tuple(self.segments))
        object.__setattr__(self, "waves", tuple(self.waves))
        if not self.segments:
            raise ValueError("Trajectory needs at least one segment")

    @property
    def duration(self) -> float:
        return float(sum(s.duration for s in self.segments))


@dataclass(frozen=True)
class Vibration:
    """Additive high-frequency vibration of the IMU's inputs (see the module docstring).

    Attributes
    ----------
    accel_rms : m/s^2 — RMS of the continuous specific-force vibration, per axis.
    gyro_rms : rad/s — RMS of the continuous angular-rate vibration, per axis.
    band : (low, high) Hz — the tones' frequencies are drawn uniformly in it (low = high:
        every tone at that frequency).
    tones : sinusoids per axis and sensor (>= 1).
    """

    accel_rms: float = 0.0
    gyro_rms: float = 0.0
    band: tuple[float, float] = (20.0, 80.0)
    tones: int = 3

    def __post_init__(self):
        object.__setattr__(self, "band", tuple(float(x) for x in self.band))
        lo, hi = self.band if len(self.band) == 2 else (np.nan, np.nan)
        if not (np.isfinite(self.accel_rms) and self.accel_rms >= 0.0
                and np.isfinite(self.gyro_rms) and self.gyro_rms >= 0.0):
            raise ValueError("Vibration needs finite accel_rms, gyro_rms >= 0")
        if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 < lo <= hi):
            raise ValueError(f"Vibration.band must be (low, high) Hz with 0 < low <= high, "
                             f"got {self.band!r}")
        if int(self.tones) != self.tones or self.tones < 1:
            raise ValueError(f"Vibration.tones must be an integer >= 1, got {self.tones!r}")


#: Strong rotor-UAV vibration (a soft-mounted MEMS IMU on a quadrotor): 3 m/s^2 and 2 deg/s
#: RMS per axis, three tones per axis in 20-80 Hz.
UAV_VIBRATION = Vibration(accel_rms=3.0, gyro_rms=2.0 * DEG, band=(20.0, 80.0), tones=3)


@dataclass(frozen=True)
class VibrationTones:
    """The drawn tones of one sensor: ``sum_j amplitude[i, j] sin(2 pi freq_hz[i, j] t +
    phase[i, j])`` on axis i (t from the start of the run).

    Attributes: ``freq_hz``, ``amplitude`` (rad/s or m/s^2), ``phase`` (rad), each (3, tones).
    """

    freq_hz: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray

    def value(self, t) -> np.ndarray:
        """The continuous vibration at times ``t`` (K,): (K, 3)."""
        t = np.asarray(t, dtype=float)[:, None, None]
        return (self.amplitude * np.sin(2.0 * np.pi * self.freq_hz * t + self.phase)).sum(-1)

    def interval_mean(self, t_end, dt: float) -> np.ndarray:
        """Exact mean over ``(t_end - dt, t_end]`` for each of ``t_end`` (K,): (K, 3)."""
        t = np.asarray(t_end, dtype=float)[:, None, None] - 0.5 * dt
        return (self.amplitude * np.sinc(self.freq_hz * dt)
                * np.sin(2.0 * np.pi * self.freq_hz * t + self.phase)).sum(-1)


def _draw_tones(rng, rms: float, vib: Vibration) -> VibrationTones:
    m = int(vib.tones)
    lo, hi = vib.band
    freq = rng.uniform(lo, hi, (3, m))
    phase = rng.uniform(0.0, 2.0 * np.pi, (3, m))
    return VibrationTones(freq, np.full((3, m), rms * np.sqrt(2.0 / m)), phase)


# Smoothstep S(x) = x^4 (35 - 84 x + 70 x^2 - 20 x^3): value, derivative, integral over [0, x].
def _S(x):
    x = np.clip(x, 0.0, 1.0)
    return x ** 4 * (35.0 - 84.0 * x + 70.0 * x * x - 20.0 * x ** 3)


def _dS(x):
    inside = (x > 0.0) & (x < 1.0)
    y = np.clip(x, 0.0, 1.0)
    return np.where(inside, 140.0 * (y * (1.0 - y)) ** 3, 0.0)


def _IS(x):
    """int_0^x S: 0 before, the polynomial on [0, 1], 1/2 + (x - 1) after."""
    y = np.clip(x, 0.0, 1.0)
    poly = y ** 5 * (7.0 - 14.0 * y + 10.0 * y * y - 2.5 * y ** 3)
    return poly + np.maximum(x - 1.0, 0.0)


def _channels(traj: Trajectory, t: np.ndarray) -> dict:
    """Each channel's value q, its derivative dq and its integral Q from 0, at times t."""
    segs = traj.segments
    starts = np.cumsum([0.0] + [s.duration for s in segs[:-1]])
    out = {}
    for nm in _CHANNELS:
        vals = np.array([getattr(s, nm) for s in segs], dtype=float)
        q = np.full_like(t, vals[0])
        dq = np.zeros_like(t)
        Q = vals[0] * t
        for i in range(1, len(segs)):
            d = vals[i] - vals[i - 1]
            if d == 0.0:
                continue
            T = segs[i].ramp
            x = (t - starts[i]) / T
            q += d * _S(x)
            dq += d * _dS(x) / T
            Q += d * T * _IS(x)
        out[nm] = (q, dq, Q)
    return out


def _waves(traj: Trajectory, t: np.ndarray) -> dict:
    """Each wave channel's value, first and second derivative at times t (deg or m)."""
    out = {c: (np.zeros_like(t), np.zeros_like(t), np.zeros_like(t)) for c in _WAVE_CHANNELS}
    for wv in traj.waves:
        om = 2.0 * np.pi / wv.period
        arg = om * t + wv.phase * DEG
        s, c = np.sin(arg), np.cos(arg)
        q, dq, ddq = out[wv.channel]
        q += wv.amplitude * s
        dq += wv.amplitude * om * c
        ddq -= wv.amplitude * om * om * s
    return out


def _cum_simpson(f: np.ndarray, dt: float, y0) -> np.ndarray:
    """Integral of f given on the half grid (2N+1 points, spacing dt/2) at the full grid (N+1
    points) and, by cubic Hermite interpolation, at the midpoints: the whole half grid."""
    inc = dt / 6.0 * (f[0:-1:2] + 4.0 * f[1::2] + f[2::2])
    full = np.concatenate([[0.0], np.cumsum(inc)]) + y0
    out = np.empty_like(f)
    out[0::2] = full
    out[1::2] = 0.5 * (full[:-1] + full[1:]) + dt / 8.0 * (f[0:-1:2] - f[2::2])
    return out


def _kinematics(traj: Trajectory, t: np.ndarray, dt: float, imu_position=None) -> dict:
    """Truth on the half grid t (2N+1 points): C, v, dv/dt, w_nb^b, lat, lon, h; of the point
    ``imu_position`` (body axes, m) from the trajectory's point when given."""
    ch = _channels(traj, t)
    wv = _waves(traj, t)
    a_u, _, Q_u = ch["accel"]
    a_w, _, Q_w = ch["lateral_accel"]
    a_z, _, Q_z = ch["climb_accel"]
    yr, _, Q_y = ch["yaw_rate"]
    pitch, dpitch, _ = ch["pitch"]
    roll, droll, _ = ch["roll"]
    _, heave_v, heave_a = wv["heave"]
    u, w, vz = traj.speed + Q_u, Q_w, Q_z + heave_v
    psi = traj.yaw_deg * DEG + Q_y * DEG             # track yaw: the velocity's frame
    dpsi = yr * DEG
    psi_b = psi + wv["yaw"][0] * DEG                 # body yaw
    dpsi_b = dpsi + wv["yaw"][1] * DEG
    th, dth = (pitch + wv["pitch"][0]) * DEG, (dpitch + wv["pitch"][1]) * DEG
    ph, dph = (roll + wv["roll"][0]) * DEG, (droll + wv["roll"][1]) * DEG
    cp, sp = np.cos(psi), np.sin(psi)
    v = np.stack([u * cp - w * sp, u * sp + w * cp, vz], -1)
    vdot = np.stack([a_u * cp - a_w * sp - dpsi * (u * sp + w * cp),
                     a_u * sp + a_w * cp + dpsi * (u * cp - w * sp), a_z + heave_a], -1)
    C = dcm_from_rpy(np.stack([ph, th, psi_b], -1))
    # Body rate of C = Rz(psi) Ry(th) Rx(ph): w_nb^b = dph e_x + Rx^T dth e_y + (Rz Ry Rx)^T ...
    w_nb = np.stack([dph - dpsi_b * np.sin(th),
                     dth * np.cos(ph) + dpsi_b * np.sin(ph) * np.cos(th),
                     -dth * np.sin(ph) + dpsi_b * np.cos(ph) * np.cos(th)], -1)
    if imu_position is not None and np.any(imu_position):
        r = np.asarray(imu_position, dtype=float)
        dw = np.gradient(w_nb, 0.5 * dt, axis=0, edge_order=2)
        wxr = np.cross(w_nb, r)
        v = v + np.einsum("nij,nj->ni", C, wxr)
        vdot = vdot + np.einsum("nij,nj->ni", C, np.cross(dw, r) + np.cross(w_nb, wxr))
    lat0, lon0, h0 = traj.lat_deg * DEG, traj.lon_deg * DEG, traj.height_m
    h = _cum_simpson(v[:, 2], dt, h0)
    lat = np.full_like(t, lat0)
    for _ in range(3):      # the radii hardly depend on lat: a fixed point in three passes
        rm, rn = radii(lat)
        lat = _cum_simpson(v[:, 1] / (rm + h), dt, lat0)
    rm, rn = radii(lat)
    lon = _cum_simpson(v[:, 0] / ((rn + h) * np.cos(lat)), dt, lon0)
    return dict(C=C, v=v, vdot=vdot, w_nb=w_nb, lat=lat, lon=lon, h=h)


@dataclass
class TrajectoryResult:
    """A simulated run: truth at N+1 instants, N IMU samples, M GNSS measurements.

    Attributes
    ----------
    t : (N+1,) s — truth instants ``k / rate``; IMU sample k-1 covers ``(t[k-1], t[k]]``.
    C : (N+1, 3, 3) — true ``C_b^n``; v : (N+1, 3) m/s ENU; lat, lon : (N+1,) rad;
        h : (N+1,) m.
    w_nb : (N+1, 3) rad/s — true body rate w.r.t. ENU, body axes.
    gyro, accel : (N, 3) — IMU samples (rad/s, m/s^2) with sensor errors.
    gyro_true, accel_true : (N, 3) — the error-free samples.
    gyro_bias, accel_bias : (3,) — the constant biases added (body axes).
    gnss_index : (M,) int — truth index of each GNSS measurement; gnss_t : (M,) s — its
        measurement time (the stamp).
    gnss_v : (M, 3) m/s ENU — measured antenna velocity (vertical NaN when
        ``gnss_vertical`` is False); gnss_v_true : (M, 3) — without noise.
    lever_arm : (3,) m, body — IMU to antenna. rate, gnss_rate : Hz. gnss_sigma : m/s.
    specs : the sensor specs used (None: no bias, no noise). trajectory : the Trajectory.
    gyro_scale, accel_scale : (3,) — the scale-factor errors ``s`` (dimensionless; 1e-6 is
        1 ppm).
    gyro_vibration, accel_vibration : (N, 3) — the vibration in each sample (interval mean,
        before the scale factor); zeros without vibration.
    gyro_tones, accel_tones : the drawn :class:`VibrationTones` (None without vibration).
    vibration : the :class:`Vibration` asked for (None: none).
    gnss_arrival_t : (M,) s — delivery time, ``gnss_t + gnss_latency``.
    gnss_latency : s. gnss_dropped_t : (K,) s — measurement times of the epochs dropped.
    gnss_llh : (M, 3) — measured antenna position (lat rad, lon rad, h m);
        gnss_llh_true : (M, 3) — without noise. gnss_pos_sigma : m per ENU axis.
    gnss_vertical : bool — whether the GNSS velocity has a vertical component.
    """

    t: np.ndarray
    C: np.ndarray
    v: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    w_nb: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    gyro_true: np.ndarray
    accel_true: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    gnss_index: np.ndarray
    gnss_t: np.ndarray
    gnss_v: np.ndarray
    gnss_v_true: np.ndarray
    lever_arm: np.ndarray
    rate: float
    gnss_rate: float
    gnss_sigma: float
    specs: SensorSpecs | None
    trajectory: Trajectory = field(repr=False, default=None)
    gyro_scale: np.ndarray = field(default_factory=lambda: np.zeros(3))
    accel_scale: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_vibration: np.ndarray | None = field(repr=False, default=None)
    accel_vibration: np.ndarray | None = field(repr=False, default=None)
    gyro_tones: VibrationTones | None = field(repr=False, default=None)
    accel_tones: VibrationTones | None = field(repr=False, default=None)
    vibration: Vibration | None = None
    gnss_arrival_t: np.ndarray | None = None
    gnss_latency: float = 0.0
    gnss_dropped_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gnss_llh: np.ndarray | None = field(repr=False, default=None)
    gnss_llh_true: np.ndarray | None = field(repr=False, default=None)
    gnss_pos_sigma: float = 0.0
    gnss_vertical: bool = True

    def __post_init__(self):
        if self.gyro_vibration is None:
            self.gyro_vibration = np.zeros_like(self.gyro)
        if self.accel_vibration is None:
            self.accel_vibration = np.zeros_like(self.accel)
        if self.gnss_arrival_t is None:
            self.gnss_arrival_t = self.gnss_t + self.gnss_latency

    @property
    def dt(self) -> float:
        return 1.0 / self.rate

    def state(self, k: int = 0) -> NavState:
        """The true navigation state at truth index k (0: before the first sample)."""
        return NavState(self.C[k], self.v[k], self.lat[k], self.lon[k], self.h[k])


def _enu_to_llh(d, lat, h):
    """Small ENU offsets d (M, 3) m at (lat, h) to (dlat, dlon, dh) (M, 3)."""
    rm, rn = radii(lat)
    return np.stack([d[:, 1] / (rm + h), d[:, 0] / ((rn + h) * np.cos(lat)), d[:, 2]], -1)


def _check_dropouts(windows) -> list[tuple[float, float]]:
    out = []
    for w in windows:
        try:
            a, b = (float(x) for x in w)
        except (TypeError, ValueError):
            raise ValueError(f"each GNSS dropout must be (start, end) s, got {w!r}") from None
        if not (np.isfinite(a) and np.isfinite(b) and a < b):
            raise ValueError(f"a GNSS dropout needs finite start < end, got ({a!r}, {b!r})")
        out.append((a, b))
    return out


def simulate_trajectory(traj: Trajectory, rate: float = 100.0,
                        specs: SensorSpecs | str | None = None, seed: int | None = 0,
                        gnss_rate: float = 10.0, gnss_sigma: float = 0.0,
                        lever_arm=(0.0, 0.0, 0.0), *, duration: float | None = None,
                        gyro_scale_ppm: float = 0.0, accel_scale_ppm: float = 0.0,
                        vibration: Vibration | None = None, gnss_latency: float = 0.0,
                        gnss_dropouts: Sequence[tuple[float, float]] = (),
                        gnss_dropout_prob: float = 0.0, gnss_vertical: bool = True,
                        gnss_pos_sigma: float = 0.0,
                        imu_position=(0.0, 0.0, 0.0)) -> TrajectoryResult:
    """Simulate ``traj`` (see the module docstring).

    Parameters
    ----------
    traj : Trajectory.
    rate : Hz — IMU rate; the duration is rounded to a whole number of samples.
    specs : SensorSpecs, a grade name ('navigation', 'tactical', 'consumer') or None for no
        bias and no noise.
    seed : int — seeds every random error (independent streams).
    gnss_rate : Hz — GNSS rate; ``rate / gnss_rate`` must be a whole number.
    gnss_sigma : m/s — white noise std of each GNSS velocity axis (0: none).
    lever_arm : (3,) m, body axes — from the IMU to the GNSS antenna.
    duration : s — run length (None: the trajectory's; longer continues its last commands).
    gyro_scale_ppm, accel_scale_ppm : ppm — 1-sigma scale-factor error per axis (0: none).
    vibration : :class:`Vibration` or None.
    gnss_latency : s (>= 0) — delivery delay of every GNSS measurement.
    gnss_dropouts : (start, end) s windows without GNSS, ``start <= t < end``.
    gnss_dropout_prob : probability (0 to 1) that an epoch is lost at random.
    gnss_vertical : False — no vertical velocity (NaN).
    gnss_pos_sigma : m — white noise std of each ENU axis of the GNSS position (0: none).
    imu_position : (3,) m, body axes — from the trajectory's point (a car's rear-axle centre)
        to the IMU; the truth (v, position) is then the IMU's (see the module docstring).
    """
    if not rate > 0.0:
        raise ValueError(f"rate must be > 0 Hz, got {rate!r}")
    step = rate / gnss_rate if gnss_rate > 0.0 else np.nan
    if not (np.isfinite(step) and abs(step - round(step)) < 1e-9 and round(step) >= 1):
        raise ValueError(f"rate / gnss_rate must be a whole number, got {rate} / {gnss_rate}")
    for nm, val in (("gnss_sigma", gnss_sigma), ("gnss_latency", gnss_latency),
                    ("gnss_pos_sigma", gnss_pos_sigma), ("gyro_scale_ppm", gyro_scale_ppm),
                    ("accel_scale_ppm", accel_scale_ppm)):
        if not (np.isfinite(val) and val >= 0.0):
            raise ValueError(f"{nm} must be finite and >= 0, got {val!r}")
    if not (0.0 <= gnss_dropout_prob <= 1.0):
        raise ValueError(f"gnss_dropout_prob must be within [0, 1], got {gnss_dropout_prob!r}")
    windows = _check_dropouts(gnss_dropouts)
    lever = np.asarray(lever_arm, dtype=float).reshape(3)
    if not np.all(np.isfinite(lever)):
        raise ValueError(f"lever_arm must be finite, got {lever.tolist()}")
    imu_pos = np.asarray(imu_position, dtype=float).reshape(3)
    if not np.all(np.isfinite(imu_pos)):
        raise ValueError(f"imu_position must be finite, got {imu_pos.tolist()}")
    if isinstance(specs, str):
        specs = grade_specs(specs)
    dt = 1.0 / rate
    length = traj.duration if duration is None else float(duration)
    if not np.isfinite(length):
        raise ValueError(f"duration must be finite, got {duration!r}")
    n = int(round(length * rate))
    if n < 1:
        raise ValueError("the run is shorter than one IMU sample")
    th = np.arange(2 * n + 1) * (0.5 * dt)
    k = _kinematics(traj, th, dt, imu_pos)
    C, v, lat, h = k["C"], k["v"], k["lat"], k["h"]
    w_ie = earth_rate(lat)
    w_en = transport_rate(v, lat, h)
    gn = np.zeros_like(v)
    gn[:, 2] = -normal_gravity(lat, h)
    CT = np.swapaxes(C, -1, -2)
    w_ib = k["w_nb"] + np.einsum("nij,nj->ni", CT, w_ie + w_en)
    f_b = np.einsum("nij,nj->ni", CT, k["vdot"] + np.cross(2.0 * w_ie + w_en, v) - gn)
    gyro_true = (w_ib[0:-1:2] + 4.0 * w_ib[1::2] + w_ib[2::2]) / 6.0
    accel_true = (f_b[0:-1:2] + 4.0 * f_b[1::2] + f_b[2::2]) / 6.0
    t = np.arange(n + 1) * dt

    (s_bias, s_imu, s_gnss, s_scale, s_vib, s_drop, s_pos, s_gwander, s_awander,
     s_warm) = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(10))
    z = s_scale.standard_normal((2, 3))        # both drawn always: one off leaves the other
    sg, sa = z[0] * (gyro_scale_ppm * 1e-6), z[1] * (accel_scale_ppm * 1e-6)
    gyro_tones = accel_tones = None
    gvib, avib = np.zeros_like(gyro_true), np.zeros_like(accel_true)
    if vibration is not None:
        gyro_tones = _draw_tones(s_vib, vibration.gyro_rms, vibration)
        accel_tones = _draw_tones(s_vib, vibration.accel_rms, vibration)
        gvib = gyro_tones.interval_mean(t[1:], dt)
        avib = accel_tones.interval_mean(t[1:], dt)
    gyro = (1.0 + sg) * (gyro_true + gvib)
    accel = (1.0 + sa) * (accel_true + avib)
    gb, ab = np.zeros(3), np.zeros(3)
    if specs is not None:
        gb = s_bias.normal(0.0, specs.gyro_bias, 3)
        ab = s_bias.normal(0.0, specs.accel_bias, 3)
        gyro += gb + s_imu.normal(0.0, specs.gyro_arw / np.sqrt(dt), (n, 3))
        accel += ab + s_imu.normal(0.0, specs.accel_vrw / np.sqrt(dt), (n, 3))
        a = np.exp(-dt / specs.bias_correlation_time)
        warm = s_warm.standard_normal((2, 3))        # both drawn always
        decay = np.exp(-t[1:] / specs.warmup_time)[:, None]
        for out, wander, q, rng, w in (
                (gyro, specs.gyro_bias_instability, specs.gyro_quantization, s_gwander,
                 warm[0] * specs.gyro_warmup),
                (accel, specs.accel_bias_instability, specs.accel_quantization, s_awander,
                 warm[1] * specs.accel_warmup)):
            if wander > 0.0:            # first-order Gauss-Markov from its stationary state
                # scipy only here: the simulator's base stays numpy-only (test_strapdown)
                from scipy.signal import lfilter
                x0 = rng.normal(0.0, wander, 3)
                drive = rng.normal(0.0, wander * np.sqrt(1.0 - a * a), (n, 3))
                out += lfilter([1.0], [1.0, -a], drive, axis=0, zi=a * x0[None])[0]
            if np.any(w != 0.0):
                out += w * decay
            if q > 0.0:                 # increments quantised, the residual carried
                out[:] = np.diff(np.round(np.cumsum(out * dt, axis=0) / q), axis=0,
                                 prepend=0.0) * (q / dt)

    full = slice(0, None, 2)
    Cf, vf, wf = C[full], v[full], k["w_nb"][full]
    latf, lonf, hf = lat[full], k["lon"][full], h[full]
    gi = np.arange(0, n + 1, int(round(step)))
    v_ant = vf[gi] + np.einsum("nij,nj->ni", Cf[gi], np.cross(wf[gi], lever))
    v_meas = v_ant + (s_gnss.normal(0.0, gnss_sigma, v_ant.shape) if gnss_sigma > 0.0 else 0.0)
    if not gnss_vertical:
        v_meas[:, 2] = np.nan
    p_true = (np.stack([latf[gi], lonf[gi], hf[gi]], -1)
              + _enu_to_llh(np.einsum("nij,j->ni", Cf[gi], lever), latf[gi], hf[gi]))
    p_meas = p_true.copy()
    if gnss_pos_sigma > 0.0:
        p_meas += _enu_to_llh(s_pos.normal(0.0, gnss_pos_sigma, p_true.shape), latf[gi], hf[gi])
    keep = np.ones(len(gi), dtype=bool)
    for a, b in windows:
        keep &= ~((t[gi] >= a) & (t[gi] < b))
    if gnss_dropout_prob > 0.0:
        keep &= s_drop.random(len(gi)) >= gnss_dropout_prob
    gk = gi[keep]
    return TrajectoryResult(t=t, C=Cf.copy(), v=vf.copy(), lat=latf.copy(), lon=lonf.copy(),
                            h=hf.copy(), w_nb=wf.copy(), gyro=gyro, accel=accel,
                            gyro_true=gyro_true, accel_true=accel_true, gyro_bias=gb,
                            accel_bias=ab, gnss_index=gk, gnss_t=t[gk], gnss_v=v_meas[keep],
                            gnss_v_true=v_ant[keep], lever_arm=lever, rate=float(rate),
                            gnss_rate=float(gnss_rate), gnss_sigma=float(gnss_sigma),
                            specs=specs, trajectory=traj, gyro_scale=sg, accel_scale=sa,
                            gyro_vibration=gvib, accel_vibration=avib, gyro_tones=gyro_tones,
                            accel_tones=accel_tones, vibration=vibration,
                            gnss_arrival_t=t[gk] + float(gnss_latency),
                            gnss_latency=float(gnss_latency), gnss_dropped_t=t[gi[~keep]],
                            gnss_llh=p_meas[keep], gnss_llh_true=p_true[keep],
                            gnss_pos_sigma=float(gnss_pos_sigma),
                            gnss_vertical=bool(gnss_vertical))


def car_with_turn(lat_deg: float = 34.0, lon_deg: float = 108.0, height_m: float = 400.0,
                  yaw_deg: float = 30.0) -> Trajectory:
    """A car: stands 10 s, accelerates at 2 m/s^2 to 15 m/s (squatting 0.3 deg nose up),
    drives 10 s, turns 90 deg left at 9 deg/s (rolling 0.8 deg outward), drives 15 s: 50 s."""
    segs = (Segment(10.0),
            Segment(7.5, accel=2.0, pitch=-0.3, ramp=1.0),
            Segment(10.0, ramp=1.0),
            Segment(10.0, yaw_rate=9.0, roll=0.8, ramp=1.0),
            Segment(12.5, ramp=1.0))
    return Trajectory(segs, lat_deg, lon_deg, height_m, yaw_deg, 0.0, "car_with_turn")


def uav_seed003(lat_deg: float = 30.5, lon_deg: float = 114.4, height_m: float = 60.0,
                yaw_deg: float = 80.0) -> Trajectory:
    """A rotor UAV, 200 s (seed 003's flight length): hovers 10 s, climbs, then flies legs with
    forward and sideways accelerations (tilting into them, about atan(a/g)), yaws and turns,
    and comes back to a hover. Every command ramps over 1.5 s, so the yaw and speed changes
    are exactly rate x duration. Speeds up to about 7.3 m/s, tilts up to about 8.7 deg; ends
    at rest, yaw -40 deg."""
    def tilt(a):
        return float(np.degrees(np.arctan2(a, 9.8)))
    segs = (Segment(10.0),
            Segment(4.0, climb_accel=1.0, ramp=1.5),            # climb to 4 m/s up
            Segment(4.0, climb_accel=-1.0, ramp=1.5),           # back to level flight
            Segment(6.0, accel=1.0, pitch=tilt(1.0), ramp=1.5),     # forward to ~6 m/s
            Segment(20.0, ramp=1.5),
            Segment(15.0, yaw_rate=6.0, roll=-tilt(0.6), ramp=1.5),  # banked turn, 90 deg
            Segment(15.0, ramp=1.5),
            Segment(5.0, lateral_accel=0.8, roll=-tilt(0.8), ramp=1.5),  # sideways to the left
            Segment(15.0, ramp=1.5),
            Segment(10.0, yaw_rate=-9.0, ramp=1.5),             # yaw right 90 deg on the way
            Segment(10.0, ramp=1.5),
            Segment(5.0, accel=-1.0, lateral_accel=-0.8, pitch=-tilt(1.0), roll=tilt(0.8),
                    ramp=1.5),                                  # brake both
            Segment(10.0, ramp=1.5),
            Segment(6.0, accel=1.0, pitch=tilt(1.0), ramp=1.5),
            Segment(10.0, yaw_rate=-12.0, roll=tilt(1.5), ramp=1.5),  # turn right 120 deg
            Segment(15.0, ramp=1.5),
            Segment(7.0, accel=-1.0, pitch=-tilt(1.0), ramp=1.5),      # stop
            Segment(33.0, ramp=1.5))                             # hover
    return Trajectory(segs, lat_deg, lon_deg, height_m, yaw_deg, 0.0, "uav_seed003")


def _squat(a):
    """Body pitch of a car on its springs under a forward acceleration a (m/s^2): nose up when
    accelerating (REP-103 pitch is positive nose down), 0.15 deg per m/s^2."""
    return -0.15 * a


def _lean(speed, yaw_rate_dps):
    """Body roll of a car in a turn: outward, 0.35 deg per m/s^2 of centripetal acceleration
    (a left turn, positive yaw rate, rolls the right side down: positive roll)."""
    return 0.35 * speed * yaw_rate_dps * DEG


def car_city(lat_deg: float = 34.0, lon_deg: float = 108.0, height_m: float = 400.0,
             yaw_deg: float = 75.0, sideslip_deg: float = 0.0) -> Trajectory:
    """A car in town, 300 s: stands 15 s, drives off, speeds up and brakes (up to 18 m/s),
    turns left and right (90, 90, 60, 60, 90 deg), stops for 25 s and drives off again, and
    ends standing. The body squats and leans on its springs (pitch -0.15 deg per m/s^2,
    roll 0.35 deg per m/s^2 of centripetal acceleration: below 0.5 deg). Every command ramps
    over 1 s, so each speed and yaw change is exactly rate x duration; no sideslip (the
    velocity stays along the heading). Final yaw 75 + 90 - 90 + 60 - 60 - 90 = -15 deg.

    ``sideslip_deg`` (deg per m/s^2 of centripetal acceleration; cars 0.2-0.7): in each turn
    the velocity turns that much outward of the heading (the rear tyres' slip angle), built
    up over the turn's first second and taken back over its last, a sideways velocity of
    ``slip x a x speed`` (0.13 m/s at 0.5 deg per m/s^2, 12 m/s and 6 deg/s)."""
    def go(d, a):
        return Segment(d, accel=a, pitch=_squat(a))

    def turn(d, rate, speed):
        if not sideslip_deg:
            return Segment(d, yaw_rate=rate, roll=_lean(speed, rate))
        # outward: to the right (negative lateral speed) in a left turn
        w = -np.sign(rate) * sideslip_deg * DEG * speed * abs(rate) * DEG * speed
        roll = _lean(speed, rate)
        return (Segment(1.0, yaw_rate=rate, roll=roll, lateral_accel=w),
                Segment(d - 2.0, yaw_rate=rate, roll=roll),
                Segment(1.0, yaw_rate=rate, roll=roll, lateral_accel=-w))

    parts = (Segment(15.0),                     # stands
            go(6.0, 1.5),                       # drives off to 9 m/s
            Segment(12.0),
            go(5.0, 1.2),                       # to 15 m/s
            Segment(15.0),
            go(4.0, -2.0),                      # brakes to 7 m/s
            turn(10.0, 9.0, 7.0),               # left 90 deg
            Segment(5.0),
            go(5.0, 1.6),                       # to 15 m/s
            Segment(20.0),
            go(5.0, -1.6),                      # to 7 m/s
            turn(10.0, -9.0, 7.0),              # right 90 deg
            Segment(8.0),
            go(4.0, -1.75),                     # stops
            Segment(25.0),                      # stands 24 s (after the 1 s ramp)
            go(8.0, 1.5),                       # drives off to 12 m/s
            Segment(10.0),
            turn(15.0, 4.0, 12.0),              # left 60 deg
            Segment(10.0),
            turn(10.0, -6.0, 12.0),             # right 60 deg
            Segment(15.0),
            go(5.0, 1.2),                       # to 18 m/s
            Segment(20.0),
            go(6.0, -2.0),                      # to 6 m/s
            turn(10.0, -9.0, 6.0),              # right 90 deg
            Segment(10.0),
            go(4.0, -1.5),                      # stops
            Segment(28.0))                      # stands
    segs = tuple(x for p in parts for x in (p if isinstance(p, tuple) else (p,)))
    return Trajectory(segs, lat_deg, lon_deg, height_m, yaw_deg, 0.0, "car_city")


def car_straight(lat_deg: float = 34.0, lon_deg: float = 108.0, height_m: float = 400.0,
                 yaw_deg: float = 120.0) -> Trajectory:
    """A car on a straight road, 120 s: stands 10 s, accelerates at 1.5 m/s^2 for 10 s
    (squatting 0.225 deg nose up), then drives straight at 15 m/s for 100 s, level. After the
    acceleration the velocity in body axes is exactly [15, 0, 0] (the non-holonomic
    constraint holds; during it the squat tilts the body x axis 0.225 deg off the
    velocity)."""
    segs = (Segment(10.0), Segment(10.0, accel=1.5, pitch=_squat(1.5)), Segment(100.0))
    return Trajectory(segs, lat_deg, lon_deg, height_m, yaw_deg, 0.0, "car_straight")


def ship_under_way(lat_deg: float = 30.0, lon_deg: float = 122.0, height_m: float = 0.0,
                   yaw_deg: float = 60.0) -> Trajectory:
    """A ship under way, 300 s at a constant 6 m/s through the water: sways in roll +-5 deg
    (period 10 s), pitch +-2 deg (8 s), yaw +-1 deg (12 s) about its track and heaves
    +-0.5 m (9 s); after 100 s it changes course by 20 deg to port (0.5 deg/s for 40 s, 10 s
    ramps), then holds it."""
    segs = (Segment(100.0), Segment(40.0, yaw_rate=0.5, ramp=10.0), Segment(160.0, ramp=10.0))
    waves = (Wave("roll", 5.0, 10.0), Wave("pitch", 2.0, 8.0, 40.0),
             Wave("yaw", 1.0, 12.0, 110.0), Wave("heave", 0.5, 9.0, 200.0))
    return Trajectory(segs, lat_deg, lon_deg, height_m, yaw_deg, 6.0, "ship_under_way", waves)


#: The presets by name.
PRESETS = {"car_with_turn": car_with_turn, "uav_seed003": uav_seed003, "car_city": car_city,
           "car_straight": car_straight, "ship_under_way": ship_under_way}


def trajectory_preset(name: str, **kwargs) -> Trajectory:
    """A preset trajectory by name (see :data:`PRESETS`); ``kwargs`` (``lat_deg``,
    ``lon_deg``, ``height_m``, ``yaw_deg``) go to the preset's function."""
    try:
        make = PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown trajectory {name!r}; choose one of {sorted(PRESETS)}") from None
    return make(**kwargs)
