"""Seed 003's conventional filters for GNSS-velocity-aided alignment in motion: an EKF on the
classic phi-angle error model and a UKF on the same errors, sigma points propagated through
the full nonlinear mechanization (numpy only, no ROS; vectorised over Monte Carlo runs).

Both estimate the 15 errors ``x = [phi, dv, dr, dbg, dba]`` of a local-level (ENU)
strapdown solution, defined against the truth as

- ``phi`` (ENU, rad): ``C_true = exp(phi x) C_hat`` (the convention of
  :func:`sins_align.core.rotation.attitude_error`);
- ``dv = v_hat - v`` (ENU, m/s): the *additive* velocity error in the navigation frame, the
  very definition seed 003 contrasts with its left-invariant one;
- ``dr`` (ENU, m): position error, ``[(R_N + h) cos(lat) dlon, (R_M + h) dlat, dh]``;
- ``dbg = bg_hat - bg``, ``dba = ba_hat - ba`` (body, rad/s and m/s^2): constant biases
  plus a random walk.

Error model (first order, what :func:`error_model_F` returns; ``f_n = C_hat f_hat``,
``a = 2 w_ie + w_en``)::

    d phi/dt = -(w_in x) phi + d w_in(dv, dr) + C_hat dbg        (- C_hat n_g)
    d dv/dt  = (f_n x) phi - (a x) dv + (v x) d a(dv, dr) - C_hat dba + g_h e_U dr_U
    d dr/dt  = dv
    d dbg/dt = n_bg,  d dba/dt = n_ba

``d w_in`` keeps the Earth rate's dependence on latitude and the transport rate's on
velocity (its dependence on position, of relative order h/R, is left out); ``g_h`` is the
normal gravity's height gradient. The measured specific force enters F through ``f_n``: that
is where heading becomes observable, and where a large heading error makes the linear model
wrong (the EKF linearises ``(I - exp(-phi x)) f_n`` as ``phi x f_n``).

Discretisation: ``Phi = prod_j (I + F_j dt)`` over the samples between two measurements
(F at each sample's estimate and measurements), process noise ``Q T`` over the interval
(``q_g`` on phi, ``q_a`` on dv, the bias walks on the biases: the same densities as our
filter). Velocity measurement ``z = v + n``: ``y = z - v_hat = -dv + n``. After each update
the estimate is fed back in full and the error state restarts at zero (closed loop, as the
seed's filters).

Tuning (seed 003 gives none, so the usual practice): initial covariance from the size of the
simulated misalignment (1 sigma = the error on each axis, the level std the larger of the
roll and pitch errors), velocity 0.1 m/s, position 1 m, biases at their specs; noise
densities those of the sensor specs; no innovation gating or inflation (the plain filters of
the seed; ours inflates the noise of innovations beyond NIS 5).

The UKF (:class:`VelocityUKF`) is the "full-state" form: each of the 2n + 1 sigma points of
``N(0, P)`` is turned into a candidate true state (``C = exp(phi x) C_hat``, ``v = v_hat -
dv``, ...), each candidate is mechanized through the samples with its own bias-corrected
measurements, and the errors of the propagated candidates about the propagated estimate (the
central point) give the predicted mean and covariance. No linearisation of the dynamics
anywhere; the measurement is linear in these errors, so the update is the Kalman update.
Sigma points: alpha = 1, beta = 2, kappa = 0 (points at +-sqrt(n) sigma, weights >= 0), as
the seed004 UKF. A propagated attitude error is taken on the branch of the logarithm nearest
the sigma point's own (``phi + 2 pi k u``), so a point beyond 180 deg keeps its place in the
distribution instead of wrapping.
"""
from __future__ import annotations

import numpy as np

from sins_align.core.earth import GRAVITY_PER_METRE, OMEGA_IE, normal_gravity, radii
from sins_align.core.rotation import skew, so3_exp, so3_log
from sins_align.estimators.baselines.unscented import SigmaPoints, linear_update, symmetrize

__all__ = ["NavBatch", "nav_step", "error_model_F", "apply_error", "state_error",
           "VelocityEKF", "VelocityUKF", "VELOCITY_BASELINES", "N_STATES"]

N_STATES = 15
IPHI, IDV, IDR, IBG, IBA = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12),
                            slice(12, 15))
_I3 = np.eye(3)


def _cross(a, b):
    return np.cross(a, b)


class NavBatch:
    """Navigation states with any leading shape: C (..., 3, 3) body to ENU, v (..., 3) ENU
    m/s, lat, lon (...) rad, h (...) m, bg, ba (..., 3) bias estimates (body)."""

    __slots__ = ("C", "v", "lat", "lon", "h", "bg", "ba")

    def __init__(self, C, v, lat, lon, h, bg, ba):
        self.C, self.v = np.asarray(C, float), np.asarray(v, float)
        self.lat, self.lon, self.h = (np.asarray(x, float) for x in (lat, lon, h))
        self.bg, self.ba = np.asarray(bg, float), np.asarray(ba, float)

    def copy(self) -> "NavBatch":
        return NavBatch(*(getattr(self, k).copy() for k in self.__slots__))


def _rates(v, lat, h):
    rm, rn = radii(lat)
    s, c = np.sin(lat), np.cos(lat)
    w_ie = np.stack([np.zeros_like(lat), OMEGA_IE * c, OMEGA_IE * s], -1)
    w_en = np.stack([-v[..., 1] / (rm + h), v[..., 0] / (rn + h),
                     v[..., 0] * s / c / (rn + h)], -1)
    return w_ie, w_en, rm, rn


def nav_step(s: NavBatch, dt: float, gyro, accel) -> NavBatch:
    """One strapdown step of every state: raw gyro, accel (..., 3) (interval means), each
    state corrected by its own bias estimates. Attitude: body rotation exp(w dt) and the
    navigation frame's rotation to first order; velocity with the specific force rotated at
    the middle of the interval, Coriolis, transport rate and normal gravity."""
    w = gyro - s.bg
    f = accel - s.ba
    w_ie, w_en, rm, rn = _rates(s.v, s.lat, s.h)
    w_in = w_ie + w_en
    Eh = so3_exp(0.5 * dt * w)
    Ch = s.C @ Eh
    fn = np.einsum("...ij,...j->...i", Ch, f)
    fn = fn - 0.5 * dt * _cross(w_in, fn)
    g = normal_gravity(s.lat, s.h)
    acc = fn - _cross(2.0 * w_ie + w_en, s.v)
    acc[..., 2] -= g
    v1 = s.v + dt * acc
    vm = 0.5 * (s.v + v1)
    lat1 = s.lat + dt * vm[..., 1] / (rm + s.h)
    lon1 = s.lon + dt * vm[..., 0] / ((rn + s.h) * np.cos(s.lat))
    h1 = s.h + dt * vm[..., 2]
    C1 = (s.C - dt * np.einsum("...ij,...jk->...ik", skew(w_in), s.C)) @ (Eh @ Eh)
    return NavBatch(C1, v1, lat1, lon1, h1, s.bg, s.ba)


def error_model_F(s: NavBatch, gyro, accel) -> np.ndarray:
    """The continuous error model F (..., 15, 15) at the estimate ``s`` and raw samples."""
    f = accel - s.ba
    w_ie, w_en, rm, rn = _rates(s.v, s.lat, s.h)
    lat = s.lat
    shape = s.lat.shape
    F = np.zeros(shape + (N_STATES, N_STATES))
    # d w_ie / d dr_N and d w_en / d dv
    dwie_drN = np.stack([np.zeros_like(lat), -OMEGA_IE * np.sin(lat), OMEGA_IE * np.cos(lat)],
                        -1) / (rm + s.h)[..., None]
    dwen_dv = np.zeros(shape + (3, 3))
    dwen_dv[..., 0, 1] = -1.0 / (rm + s.h)
    dwen_dv[..., 1, 0] = 1.0 / (rn + s.h)
    dwen_dv[..., 2, 0] = np.tan(lat) / (rn + s.h)
    w_in = w_ie + w_en
    F[..., IPHI, IPHI] = -skew(w_in)
    F[..., IPHI, IDV] = dwen_dv
    F[..., 0:3, 7] = dwie_drN
    F[..., IPHI, IBG] = s.C
    fn = np.einsum("...ij,...j->...i", s.C, f)
    a = 2.0 * w_ie + w_en
    Sv = skew(s.v)
    F[..., IDV, IPHI] = skew(fn)
    F[..., IDV, IDV] = -skew(a) + Sv @ dwen_dv
    F[..., 3:6, 7] = 2.0 * np.einsum("...ij,...j->...i", Sv, dwie_drN)
    F[..., 5, 8] += GRAVITY_PER_METRE
    F[..., IDV, IBA] = -s.C
    F[..., IDR, IDV] = _I3
    return F


def apply_error(s: NavBatch, x) -> NavBatch:
    """The state whose error relative to ``s`` is ``-x``: ``s`` with the errors ``x``
    removed (feedback; also how a sigma point becomes a candidate true state)."""
    x = np.asarray(x, float)
    rm, rn = radii(s.lat)
    C = so3_exp(x[..., IPHI]) @ s.C
    return NavBatch(C, s.v - x[..., IDV], s.lat - x[..., 7] / (rm + s.h),
                    s.lon - x[..., 6] / ((rn + s.h) * np.cos(s.lat)), s.h - x[..., 8],
                    s.bg - x[..., IBG], s.ba - x[..., IBA])


def state_error(est: NavBatch, true: NavBatch, near=None) -> np.ndarray:
    """The errors x (..., 15) of ``est`` against ``true``; ``near`` (..., 3): take phi on
    the branch of the logarithm nearest it."""
    rm, rn = radii(true.lat)
    x = np.empty(est.v.shape[:-1] + (N_STATES,))
    phi = so3_log(true.C @ np.swapaxes(est.C, -1, -2))
    if near is not None:
        th = np.linalg.norm(phi, axis=-1, keepdims=True)
        u = np.where(th > 1e-12, phi / np.maximum(th, 1e-300), 0.0)
        cands = phi[..., None, :] + (2.0 * np.pi * np.arange(-2, 3))[:, None] * u[..., None, :]
        k = np.argmin(np.linalg.norm(cands - near[..., None, :], axis=-1), axis=-1)
        phi = np.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    x[..., IPHI] = phi
    x[..., IDV] = est.v - true.v
    x[..., 6] = (rn + true.h) * np.cos(true.lat) * (est.lon - true.lon)
    x[..., 7] = (rm + true.h) * (est.lat - true.lat)
    x[..., 8] = est.h - true.h
    x[..., IBG] = est.bg - true.bg
    x[..., IBA] = est.ba - true.ba
    return x


class _VelocityFilter:
    """What the two filters share: start, noise, the velocity update and the feedback.

    noise : an object with ``gyro_arw``, ``accel_vrw``, ``gyro_bias_walk``,
    ``accel_bias_walk`` (the in-motion filter's :class:`NoiseModel`); sigma_v : m/s, the
    velocity measurement noise per axis."""

    name = "?"

    def __init__(self, noise, sigma_v: float):
        self.noise = noise
        self.R = np.eye(3) * sigma_v ** 2
        self.H = np.zeros((3, N_STATES))
        self.H[:, IDV] = -_I3
        self.q = np.zeros(N_STATES)
        self.q[IPHI] = noise.gyro_arw ** 2
        self.q[IDV] = noise.accel_vrw ** 2
        self.q[IBG] = noise.gyro_bias_walk ** 2
        self.q[IBA] = noise.accel_bias_walk ** 2
        self.nav: NavBatch | None = None
        self.P: np.ndarray | None = None

    def start(self, C0, v0, lat, lon, h, P0) -> None:
        """Runs' initial estimates: C0 (R, 3, 3), v0 (R, 3), lat/lon/h floats, P0 (15, 15)
        or (R, 15, 15)."""
        C0 = np.asarray(C0, float)
        R = len(C0)
        self.nav = NavBatch(C0.copy(), np.asarray(v0, float).reshape(R, 3).copy(),
                            np.full(R, float(lat)), np.full(R, float(lon)), np.full(R, float(h)),
                            np.zeros((R, 3)), np.zeros((R, 3)))
        self.P = np.broadcast_to(np.asarray(P0, float), (R, N_STATES, N_STATES)).copy()

    @property
    def C(self) -> np.ndarray:
        return self.nav.C

    @property
    def cov_enu(self) -> np.ndarray:
        """(R, 3, 3): covariance of phi (ENU, rad^2)."""
        return self.P[:, IPHI, IPHI]

    def _update(self, x, z) -> None:
        y = np.asarray(z, float) - self.nav.v
        x, P, _, _ = linear_update(x, self.P, y, self.H, self.R)
        self.P = P
        self.nav = apply_error(self.nav, x)


class VelocityEKF(_VelocityFilter):
    """Conventional EKF (additive velocity error, phi-angle attitude error, 15 states)."""

    name = "ekf"

    def propagate(self, dt: float, gyro, accel) -> None:
        """Samples gyro, accel (R, m, 3) of every run."""
        m = gyro.shape[1]
        Phi = np.broadcast_to(np.eye(N_STATES), self.P.shape).copy()
        for j in range(m):
            F = error_model_F(self.nav, gyro[:, j], accel[:, j])
            Phi = Phi + dt * (F @ Phi)
            self.nav = nav_step(self.nav, dt, gyro[:, j], accel[:, j])
        self.P = symmetrize(Phi @ self.P @ np.swapaxes(Phi, -1, -2) + np.diag(self.q) * (m * dt))

    def update_velocity(self, z) -> None:
        self._update(np.zeros((len(self.P), N_STATES)), z)


class VelocityUKF(_VelocityFilter):
    """UKF on the same errors, the full nonlinear mechanization for the time update."""

    name = "ukf"

    def __init__(self, noise, sigma_v: float, sigma_points: SigmaPoints | None = None):
        super().__init__(noise, sigma_v)
        self.sp = sigma_points or SigmaPoints(N_STATES)
        self.x = None

    def propagate(self, dt: float, gyro, accel) -> None:
        R = len(self.P)
        X = self.sp.points(np.zeros((R, N_STATES)), self.P)           # (R, S, 15)
        S = X.shape[1]
        cand = apply_error(NavBatch(self.nav.C[:, None], self.nav.v[:, None],
                                    self.nav.lat[:, None], self.nav.lon[:, None],
                                    self.nav.h[:, None], self.nav.bg[:, None],
                                    self.nav.ba[:, None]), X)
        for j in range(gyro.shape[1]):
            cand = nav_step(cand, dt, gyro[:, None, j], accel[:, None, j])
        centre = NavBatch(*(getattr(cand, k)[:, :1] for k in NavBatch.__slots__))
        centre_b = NavBatch(*(np.broadcast_to(getattr(centre, k), getattr(cand, k).shape)
                              for k in NavBatch.__slots__))
        # errors of the estimate (the centre) against each candidate true state
        Y = state_error(centre_b, cand, near=X[..., IPHI])
        wm, wc = self.sp.weights
        xm = np.einsum("s,rsi->ri", wm, Y)
        dY = Y - xm[:, None]
        P = np.einsum("s,rsi,rsj->rij", wc, dY, dY)
        self.nav = NavBatch(*(getattr(centre, k)[:, 0].copy() for k in NavBatch.__slots__))
        self.P = symmetrize(P) + np.diag(self.q) * (gyro.shape[1] * dt)
        self.x = xm
        del S

    def update_velocity(self, z) -> None:
        x = np.zeros((len(self.P), N_STATES)) if self.x is None else self.x
        self._update(x, z)
        self.x = None


VELOCITY_BASELINES = {"ekf": VelocityEKF, "ukf": VelocityUKF}
