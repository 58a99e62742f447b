"""Moving-vehicle IMU and GNSS-velocity simulator with per-sample truth (numpy only, no ROS).

The test bench of the in-motion estimator (ALGORITHM.md, "In-motion alignment with a velocity
reference"); consistent with :mod:`sins_align.core.strapdown` (same frames, same Earth model).

Trajectory
----------
A trajectory is a list of :class:`Segment` s. Each segment holds commanded values (forward,
lateral and vertical acceleration in the heading frame, yaw rate, pitch and roll angles);
at the start of every segment but the first, each value moves from the previous segment's to
its own along the 7th-order smoothstep ``S`` over ``ramp`` s (C3: rates, accelerations and
their derivatives stay continuous). With ``q(t)`` such a channel:

- speeds in the heading frame ``u = u0 + int accel``, ``w = int lateral``, ``v_U = int climb``;
- yaw ``psi = psi0 + int yaw_rate``; pitch and roll are the channels themselves;
- ``v^n = [u cos psi - w sin psi, u sin psi + w cos psi, v_U]`` (ENU; ``w`` to the left of the
  heading), ``C_b^n = dcm_from_rpy([roll, pitch, psi])`` (REP-103).

All integrals are analytic (the smoothstep integrates to a polynomial); the position
(lat, lon, h) is integrated from the velocity by Simpson's rule on the half-sample grid.

Sensors
-------
On that half-sample grid the exact rates and specific force are::

    w_ib^b = w_nb^b + C^T (w_ie^n + w_en^n)
    f^b    = C^T (dv/dt + (2 w_ie^n + w_en^n) x v - g^n)

with ``w_nb^b`` from the Euler-angle rates. IMU sample k is their mean over
``(t[k-1], t[k]]`` by Simpson's rule (exact for a cubic in time), i.e. the increment divided by
dt, the convention of :mod:`sins_align.sim.simulator` and :mod:`sins_align.core.strapdown`.
Sensor errors, from a :class:`~sins_align.core.specs.SensorSpecs`: constant biases drawn
``N(0, bias^2)`` per axis and white noise of std ``arw / sqrt(dt)``, ``vrw / sqrt(dt)``
per sample (bias wander and quantisation are not simulated here).

GNSS velocity at the antenna, lever arm ``l^b`` from the IMU to the antenna:
``v_ant = v^n + C_b^n (w_nb^b x l^b)`` at every ``rate / gnss_rate``-th truth instant (the
first at t = 0), plus white noise (ENU, per axis).

Randomness: ``np.random.SeedSequence(seed)`` spawned into three independent streams (biases,
IMU noise, GNSS noise), so turning one off does not change the others.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sins_align.core.rotation import dcm_from_rpy
from sins_align.core.specs import DEG, DPH, DPSH, UG, UG_PSHZ, SensorSpecs, grade_specs
from sins_align.core.strapdown import (NavState, earth_rate, normal_gravity, radii,
                                       transport_rate)

__all__ = ["Segment", "Trajectory", "TrajectoryResult", "simulate_trajectory", "car_with_turn",
           "uav_seed003", "PRESETS", "trajectory_preset", "SEED003_SPECS"]

#: The MEMS IMU of seed 003: gyro bias 10 deg/h, accelerometer bias 0.1 mg. The seed gives no
#: noise densities; these (0.1 deg/sqrt(h), 50 ug/sqrt(Hz)) are assumptions.
SEED003_SPECS = SensorSpecs(gyro_bias=10.0 * DPH, gyro_arw=0.1 * DPSH,
                            accel_bias=100.0 * UG, accel_vrw=50.0 * UG_PSHZ)

_CHANNELS = ("accel", "lateral_accel", "climb_accel", "yaw_rate", "pitch", "roll")


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
class Trajectory:
    """Segments plus the initial position, heading and forward speed.

    Attributes
    ----------
    segments : the segments, in order.
    lat_deg, lon_deg : deg; height_m : m — initial position.
    yaw_deg : deg — initial yaw (REP-103: 0 = body x East, 90 = North).
    speed : m/s — initial forward speed (along the heading).
    name : label.
    """

    segments: tuple[Segment, ...]
    lat_deg: float = 34.0
    lon_deg: float = 108.0
    height_m: float = 0.0
    yaw_deg: float = 0.0
    speed: float = 0.0
    name: str = "custom"

    def __post_init__(self):
        object.__setattr__(self, "segments", tuple(self.segments))
        if not self.segments:
            raise ValueError("Trajectory needs at least one segment")

    @property
    def duration(self) -> float:
        return float(sum(s.duration for s in self.segments))


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


def _cum_simpson(f: np.ndarray, dt: float, y0) -> np.ndarray:
    """Integral of f given on the half grid (2N+1 points, spacing dt/2) at the full grid (N+1
    points) and, by cubic Hermite interpolation, at the midpoints: the whole half grid."""
    inc = dt / 6.0 * (f[0:-1:2] + 4.0 * f[1::2] + f[2::2])
    full = np.concatenate([[0.0], np.cumsum(inc)]) + y0
    out = np.empty_like(f)
    out[0::2] = full
    out[1::2] = 0.5 * (full[:-1] + full[1:]) + dt / 8.0 * (f[0:-1:2] - f[2::2])
    return out


def _kinematics(traj: Trajectory, t: np.ndarray, dt: float) -> dict:
    """Truth on the half grid t (2N+1 points): C, v, dv/dt, w_nb^b, lat, lon, h."""
    ch = _channels(traj, t)
    a_u, _, Q_u = ch["accel"]
    a_w, _, Q_w = ch["lateral_accel"]
    a_z, _, Q_z = ch["climb_accel"]
    yr, _, Q_y = ch["yaw_rate"]
    pitch, dpitch, _ = ch["pitch"]
    roll, droll, _ = ch["roll"]
    u, w, vz = traj.speed + Q_u, Q_w, Q_z
    psi = traj.yaw_deg * DEG + Q_y * DEG
    dpsi = yr * DEG
    th, dth, ph, dph = pitch * DEG, dpitch * DEG, roll * DEG, droll * DEG
    cp, sp = np.cos(psi), np.sin(psi)
    v = np.stack([u * cp - w * sp, u * sp + w * cp, vz], -1)
    vdot = np.stack([a_u * cp - a_w * sp - dpsi * (u * sp + w * cp),
                     a_u * sp + a_w * cp + dpsi * (u * cp - w * sp), a_z], -1)
    C = dcm_from_rpy(np.stack([ph, th, psi], -1))
    # Body rate of C = Rz(psi) Ry(th) Rx(ph): w_nb^b = dph e_x + Rx^T dth e_y + (Rz Ry Rx)^T ...
    w_nb = np.stack([dph - dpsi * np.sin(th),
                     dth * np.cos(ph) + dpsi * np.sin(ph) * np.cos(th),
                     -dth * np.sin(ph) + dpsi * np.cos(ph) * np.cos(th)], -1)
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
    """A simulated run: truth at N+1 instants, N IMU samples, M GNSS velocities.

    Attributes
    ----------
    t : (N+1,) s — truth instants ``k / rate``; IMU sample k-1 covers ``(t[k-1], t[k]]``.
    C : (N+1, 3, 3) — true ``C_b^n``; v : (N+1, 3) m/s ENU; lat, lon : (N+1,) rad;
        h : (N+1,) m.
    w_nb : (N+1, 3) rad/s — true body rate w.r.t. ENU, body axes.
    gyro, accel : (N, 3) — IMU samples (rad/s, m/s^2) with sensor errors.
    gyro_true, accel_true : (N, 3) — the error-free samples.
    gyro_bias, accel_bias : (3,) — the constant biases added (body axes).
    gnss_index : (M,) int — truth index of each GNSS velocity; gnss_t : (M,) s.
    gnss_v : (M, 3) m/s ENU — measured antenna velocity; gnss_v_true : (M, 3) — without noise.
    lever_arm : (3,) m, body — IMU to antenna. rate, gnss_rate : Hz. gnss_sigma : m/s.
    specs : the sensor specs used (None: error-free). trajectory : the Trajectory.
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

    @property
    def dt(self) -> float:
        return 1.0 / self.rate

    def state(self, k: int = 0) -> NavState:
        """The true navigation state at truth index k (0: before the first sample)."""
        return NavState(self.C[k], self.v[k], self.lat[k], self.lon[k], self.h[k])


def simulate_trajectory(traj: Trajectory, rate: float = 100.0,
                        specs: SensorSpecs | str | None = None, seed: int | None = 0,
                        gnss_rate: float = 10.0, gnss_sigma: float = 0.0,
                        lever_arm=(0.0, 0.0, 0.0)) -> TrajectoryResult:
    """Simulate ``traj`` (see the module docstring).

    Parameters
    ----------
    traj : Trajectory.
    rate : Hz — IMU rate; the duration is rounded to a whole number of samples.
    specs : SensorSpecs, a grade name ('navigation', 'tactical', 'consumer') or None for an
        error-free IMU.
    seed : int — seeds the biases, the IMU noise and the GNSS noise.
    gnss_rate : Hz — GNSS velocity rate; ``rate / gnss_rate`` must be a whole number.
    gnss_sigma : m/s — white noise std of each GNSS velocity axis (0: none).
    lever_arm : (3,) m, body axes — from the IMU to the GNSS antenna.
    """
    if not rate > 0.0:
        raise ValueError(f"rate must be > 0 Hz, got {rate!r}")
    step = rate / gnss_rate if gnss_rate > 0.0 else np.nan
    if not (np.isfinite(step) and abs(step - round(step)) < 1e-9 and round(step) >= 1):
        raise ValueError(f"rate / gnss_rate must be a whole number, got {rate} / {gnss_rate}")
    if not (np.isfinite(gnss_sigma) and gnss_sigma >= 0.0):
        raise ValueError(f"gnss_sigma must be >= 0, got {gnss_sigma!r}")
    lever = np.asarray(lever_arm, dtype=float).reshape(3)
    if isinstance(specs, str):
        specs = grade_specs(specs)
    dt = 1.0 / rate
    n = int(round(traj.duration * rate))
    if n < 1:
        raise ValueError("the trajectory is shorter than one IMU sample")
    th = np.arange(2 * n + 1) * (0.5 * dt)
    k = _kinematics(traj, th, dt)
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

    s_bias, s_imu, s_gnss = (np.random.default_rng(s)
                             for s in np.random.SeedSequence(seed).spawn(3))
    gyro, accel = gyro_true.copy(), accel_true.copy()
    gb, ab = np.zeros(3), np.zeros(3)
    if specs is not None:
        gb = s_bias.normal(0.0, specs.gyro_bias, 3)
        ab = s_bias.normal(0.0, specs.accel_bias, 3)
        gyro += gb + s_imu.normal(0.0, specs.gyro_arw / np.sqrt(dt), (n, 3))
        accel += ab + s_imu.normal(0.0, specs.accel_vrw / np.sqrt(dt), (n, 3))

    full = slice(0, None, 2)
    Cf, vf, wf = C[full], v[full], k["w_nb"][full]
    gi = np.arange(0, n + 1, int(round(step)))
    v_ant = vf[gi] + np.einsum("nij,nj->ni", Cf[gi], np.cross(wf[gi], lever))
    v_meas = v_ant + (s_gnss.normal(0.0, gnss_sigma, v_ant.shape) if gnss_sigma > 0.0 else 0.0)
    t = np.arange(n + 1) * dt
    return TrajectoryResult(t=t, C=Cf.copy(), v=vf.copy(), lat=lat[full].copy(),
                            lon=k["lon"][full].copy(), h=h[full].copy(), w_nb=wf.copy(),
                            gyro=gyro, accel=accel, gyro_true=gyro_true, accel_true=accel_true,
                            gyro_bias=gb, accel_bias=ab, gnss_index=gi, gnss_t=t[gi],
                            gnss_v=v_meas, gnss_v_true=v_ant, lever_arm=lever, rate=float(rate),
                            gnss_rate=float(gnss_rate), gnss_sigma=float(gnss_sigma),
                            specs=specs, trajectory=traj)


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


#: The presets by name.
PRESETS = {"car_with_turn": car_with_turn, "uav_seed003": uav_seed003}


def trajectory_preset(name: str) -> Trajectory:
    """A preset trajectory by name (see :data:`PRESETS`)."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise ValueError(f"unknown trajectory {name!r}; choose one of {sorted(PRESETS)}") from None
