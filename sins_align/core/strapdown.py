"""Strapdown mechanization on a moving base, local ENU frame, geodetic position (numpy only).

The base of the in-motion estimator (ALGORITHM.md, "In-motion alignment with a velocity
reference"; seed 003); not an estimator itself. The quasi-static filter keeps its own damped
mechanization (no Coriolis, no transport rate), which does not apply in motion.

Frames and conventions
----------------------
- n = local ENU at the vehicle (x East, y North, z Up); it moves with the vehicle over the
  WGS-84 ellipsoid and turns with the Earth. b = IMU axes. ``C = C_b^n`` (body to ENU).
- Position: geodetic latitude ``lat`` (rad), longitude ``lon`` (rad), height ``h`` (m).
- IMU sample k (REP-145: ``gyro`` = w_ib^b rad/s, ``accel`` = specific force f^b m/s^2) is the
  mean rate and mean specific force over the interval ``(t[k-1], t[k]]`` of length ``dt``
  (increment divided by dt), as in :mod:`sins_align.sim.simulator`.

Continuous equations (Titterton & Weston, "Strapdown Inertial Navigation Technology",
ch. 3; Groves, "Principles of GNSS, Inertial, and Multisensor Integrated Navigation",
ch. 5, written in ENU)::

    dC/dt   = C (w_ib^b x) - (w_in^n x) C,          w_in^n = w_ie^n + w_en^n
    dv/dt   = C f^b - (2 w_ie^n + w_en^n) x v + g^n
    dlat/dt = v_N / (R_M + h)
    dlon/dt = v_E / ((R_N + h) cos lat)
    dh/dt   = v_U

with the Earth rate ``w_ie^n = W [0, cos lat, sin lat]``, the transport rate
``w_en^n = [-v_N / (R_M + h), v_E / (R_N + h), v_E tan(lat) / (R_N + h)]``, the WGS-84 radii of
curvature ``R_M = a (1 - e^2) / (1 - e^2 sin^2 lat)^1.5`` (meridian) and
``R_N = a / (1 - e^2 sin^2 lat)^0.5`` (prime vertical), and normal gravity
``g^n = [0, 0, -g(lat, h)]`` (:func:`sins_align.core.earth.gravity`, which includes the
centrifugal term of the Earth's rotation).

Discrete step (:func:`mechanize`), second order in dt (global error O(dt^2) per unit time):

1. Earth and transport rates, gravity at the start of the interval (state k-1).
2. Half-step attitude ``C_h = exp(-w_in dt/2) C exp(w dt/2)``; specific force in n,
   ``f^n = C_h f`` (the interval mean of ``C f`` to second order).
3. Predictor ``v_h = v + dt/2 (f^n - (2 w_ie + w_en) x v + g)``, ``lat_h, h_h`` likewise;
   rates and gravity again at the midpoint; ``v_k = v + dt (f^n - (2 w_ie + w_en)_h x v_h + g_h)``
   (midpoint rule).
4. Position by the trapezoid of the velocities, with the radii at the midpoint.
5. Attitude ``C_k = exp(-w_in,h dt) C exp(w dt)``, both exponentials exact (Rodrigues,
   :func:`sins_align.core.rotation.so3_exp`); for rates constant over the interval this is the
   exact solution, since the left and right products commute. No coning or sculling
   correction: a single mean rate per sample carries no information for one.

Position is accumulated in plain double precision: adding a small increment to a longitude
of ~2 rad rounds it by ~1e-16 rad each sample (micrometres over minutes).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sins_align.core.earth import (GRAVITY_EQUATOR, GRAVITY_PER_METRE, OMEGA_IE, SOMIGLIANA_K,
                                   WGS84_A, WGS84_E2, normal_gravity, radii)
from sins_align.core.earth import earth_rate_enu as earth_rate
from sins_align.core.rotation import so3_exp

__all__ = ["WGS84_A", "WGS84_E2", "NavState", "NavTrack", "radii", "normal_gravity",
           "earth_rate", "transport_rate", "mechanize", "mechanize_block"]


def transport_rate(v, lat, h) -> np.ndarray:
    """Transport rate ``w_en^n = [-v_N/(R_M+h), v_E/(R_N+h), v_E tan(lat)/(R_N+h)]``, rad/s,
    ENU; ``v`` (..., 3) m/s ENU, ``lat`` rad and ``h`` m broadcast against ``v[..., 0]``."""
    v = np.asarray(v, dtype=float)
    rm, rn = radii(lat)
    vn, ve = np.broadcast_arrays(v[..., 1] / (rm + h), v[..., 0] / (rn + h))
    return np.stack([-vn, ve, ve * np.tan(lat)], -1)


@dataclass
class NavState:
    """Navigation state: attitude, velocity, geodetic position.

    Attributes
    ----------
    C : (3, 3) — ``C_b^n``, body to ENU.
    v : (3,) m/s — velocity w.r.t. the Earth, ENU.
    lat, lon : rad — geodetic latitude and longitude.
    h : m — height above the ellipsoid.
    """

    C: np.ndarray
    v: np.ndarray
    lat: float
    lon: float
    h: float

    def __post_init__(self):
        self.C = np.array(self.C, dtype=float).reshape(3, 3)
        self.v = np.array(self.v, dtype=float).reshape(3)
        self.lat, self.lon, self.h = float(self.lat), float(self.lon), float(self.h)
        if not (np.all(np.isfinite(self.C)) and np.all(np.isfinite(self.v))
                and math.isfinite(self.lat + self.lon + self.h)):
            raise ValueError("NavState must be finite")
        if abs(self.lat) >= 0.5 * math.pi - 1e-6:
            raise ValueError("NavState latitude must be off the poles (ENU is undefined there)")

    def copy(self) -> "NavState":
        return NavState(self.C.copy(), self.v.copy(), self.lat, self.lon, self.h)


@dataclass
class NavTrack:
    """States along a run: index 0 is the initial state, index k the state after sample k.

    Attributes: ``C`` (N+1, 3, 3), ``v`` (N+1, 3) m/s, ``lat``, ``lon`` (N+1,) rad, ``h``
    (N+1,) m.
    """

    C: np.ndarray
    v: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray

    def __len__(self) -> int:
        return len(self.lat)

    def state(self, k: int) -> NavState:
        """The state at index k."""
        return NavState(self.C[k], self.v[k], self.lat[k], self.lon[k], self.h[k])


def _rates(v, lat, h):
    """(w_ie, w_en, g, R_M, R_N) at one state, floats in ENU: core.earth's radii and
    normal_gravity (and transport_rate) written out in scalar math, since this runs twice per
    sample and numpy's per-call cost on floats would dominate it."""
    s, c = math.sin(lat), math.cos(lat)
    d = 1.0 - WGS84_E2 * s * s
    rn = WGS84_A / math.sqrt(d)
    rm = rn * (1.0 - WGS84_E2) / d
    ve = v[0] / (rn + h)
    w_ie = (0.0, OMEGA_IE * c, OMEGA_IE * s)
    w_en = (-v[1] / (rm + h), ve, ve * s / c)
    g = GRAVITY_EQUATOR * (1.0 + SOMIGLIANA_K * s * s) / math.sqrt(d) - GRAVITY_PER_METRE * h
    return w_ie, w_en, g, rm, rn


def _accel(fn, v, w_ie, w_en, g):
    """dv/dt = f^n - (2 w_ie + w_en) x v + g^n, as a list."""
    a = (2.0 * w_ie[0] + w_en[0], 2.0 * w_ie[1] + w_en[1], 2.0 * w_ie[2] + w_en[2])
    return [fn[0] - (a[1] * v[2] - a[2] * v[1]),
            fn[1] - (a[2] * v[0] - a[0] * v[2]),
            fn[2] - (a[0] * v[1] - a[1] * v[0]) - g]


def _step(C, v, lat, lon, h, dt, w, f):
    """One step on plain values: C (3, 3) array, v list of 3 floats; returns the same."""
    w_ie, w_en, g, rm, rn = _rates(v, lat, h)
    hdt = 0.5 * dt
    w_in = np.array([w_ie[0] + w_en[0], w_ie[1] + w_en[1], w_ie[2] + w_en[2]])
    C_h = so3_exp(-hdt * w_in) @ C @ so3_exp(hdt * w)
    fn = (C_h @ f).tolist()
    a0 = _accel(fn, v, w_ie, w_en, g)
    v_h = [v[i] + hdt * a0[i] for i in range(3)]
    lat_h = lat + hdt * v_h[1] / (rm + h)
    h_h = h + hdt * v_h[2]
    w_ie, w_en, g, rm, rn = _rates(v_h, lat_h, h_h)
    a = _accel(fn, v_h, w_ie, w_en, g)
    v1 = [v[i] + dt * a[i] for i in range(3)]
    lat1 = lat + dt * 0.5 * (v[1] + v1[1]) / (rm + h_h)
    lon1 = lon + dt * 0.5 * (v[0] + v1[0]) / ((rn + h_h) * math.cos(lat_h))
    h1 = h + dt * 0.5 * (v[2] + v1[2])
    w_in = np.array([w_ie[0] + w_en[0], w_ie[1] + w_en[1], w_ie[2] + w_en[2]])
    C1 = so3_exp(-dt * w_in) @ C @ so3_exp(dt * w)
    return C1, v1, lat1, lon1, h1


def _check(gyro, accel, n: int | None = None):
    gyro = np.asarray(gyro, dtype=float)
    accel = np.asarray(accel, dtype=float)
    shape = (3,) if n is None else (n, 3)
    if gyro.shape != shape or accel.shape != shape:
        raise ValueError(f"gyro and accel must have shape {shape}, got {gyro.shape}, "
                         f"{accel.shape}")
    return gyro, accel


def mechanize(state: NavState, dt: float, gyro, accel) -> NavState:
    """The state after one IMU sample (see the module docstring for the equations).

    Parameters
    ----------
    state : NavState — at the start of the interval (not modified).
    dt : s — interval length (> 0).
    gyro : (3,) rad/s — mean w_ib^b over the interval.
    accel : (3,) m/s^2 — mean specific force f^b over the interval.
    """
    if not dt > 0.0:
        raise ValueError(f"dt must be > 0, got {dt!r}")
    gyro, accel = _check(gyro, accel)
    C, v, lat, lon, h = _step(state.C, state.v.tolist(), state.lat, state.lon, state.h,
                              float(dt), gyro, accel)
    return NavState(C, v, lat, lon, h)


def mechanize_block(state: NavState, dts, gyro, accel) -> NavTrack:
    """Mechanize N samples from ``state``; every intermediate state is returned.

    Parameters
    ----------
    state : NavState — before the first sample.
    dts : float or (N,) s — interval of each sample (a float: the same for all).
    gyro, accel : (N, 3) — samples as in :func:`mechanize`.

    Returns
    -------
    NavTrack with N + 1 states (index 0 = ``state``).
    """
    gyro = np.asarray(gyro, dtype=float)
    n = len(gyro)
    gyro, accel = _check(gyro, accel, n)
    dts = np.broadcast_to(np.asarray(dts, dtype=float), (n,))
    if n and not np.all(dts > 0.0):
        raise ValueError("every dt must be > 0")
    Cs = np.empty((n + 1, 3, 3))
    vs = np.empty((n + 1, 3))
    pos = np.empty((n + 1, 3))
    C, v = state.C.copy(), state.v.tolist()
    lat, lon, h = state.lat, state.lon, state.h
    Cs[0], vs[0], pos[0] = C, v, (lat, lon, h)
    dl = dts.tolist()
    for k in range(n):
        C, v, lat, lon, h = _step(C, v, lat, lon, h, dl[k], gyro[k], accel[k])
        Cs[k + 1], vs[k + 1], pos[k + 1] = C, v, (lat, lon, h)
    return NavTrack(Cs, vs, pos[:, 0].copy(), pos[:, 1].copy(), pos[:, 2].copy())
