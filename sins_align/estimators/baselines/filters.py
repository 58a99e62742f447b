"""Seed 004's filters on its large-azimuth Euler-error model: UKF, unscented particle filter
(UPF) and adaptive UPF (strong-tracking fading factor), vectorised over Monte Carlo runs.

All three share one interface:

- constructed from a :class:`BaselineConfig` (latitude, sensor specs, tuning);
- ``run(dt, gyro, accel, C_est0, seed=0) -> BaselineResult``: open-loop mechanization of the
  samples (T, N, 3) from the computed initial attitude C_est0 (N, 3, 3), then the filter,
  one step per ``config.step`` s; estimates at every step;
- ``filter(model, x0, P0, rng) -> (x, P)`` on any model of
  :mod:`~sins_align.estimators.baselines.unscented` (the tests use a linear one).

Tuning (the seed's text lost its numbers; these are the classic choices, stated so that they
can be argued with):

- initial state 0, initial std 1 deg level / 30 deg heading (the misalignment of the study is
  [1, 1, 30] deg), 0.01 m/s velocity, biases at their 1-sigma specs;
- Q from the sensor specs (gyro angle random walk, accelerometer velocity random walk); the
  biases are given a random walk that would move them by 10 % of their 1-sigma in 2000 s;
- R: velocity noise 0.01 m/s per 1-s step;
- unscented transform alpha = 1, beta = 2, kappa = 0 (non-negative weights, see SigmaPoints).

No feedback (the seed): the mechanization runs open loop and the filter estimates the growing
error; the attitude estimate is ``D(phi_hat) C~`` at each step.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sins_align.core.specs import DEG, SensorSpecs
from sins_align.estimators.baselines.euler_model import (DPH_RAD, MG, EulerErrorModel,
                                                         euler_dcm, mechanize_static)
from sins_align.estimators.baselines.unscented import (SigmaPoints, fading_factor,
                                                       linear_update, robust_cholesky,
                                                       unscented_predict)

__all__ = ["BaselineConfig", "BaselineResult", "UKF", "UPF", "AdaptiveUPF", "BASELINES"]


@dataclass(frozen=True)
class BaselineConfig:
    """Scenario knowledge and tuning of the baseline filters (angles deg, SI otherwise)."""

    latitude_deg: float
    specs: SensorSpecs
    height_m: float = 0.0
    step: float = 1.0
    initial_std_deg: tuple[float, float, float] = (1.0, 1.0, 30.0)
    initial_velocity_std: float = 0.01
    velocity_noise: float = 0.01
    bias_walk_fraction: float = 0.1
    bias_walk_time: float = 2000.0
    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0

    def with_(self, **kw) -> "BaselineConfig":
        return replace(self, **kw)

    def initial(self) -> tuple[np.ndarray, np.ndarray]:
        """(x0 (10,), P0 (10, 10)) in the model's units."""
        sp = self.specs
        std = np.concatenate([np.asarray(self.initial_std_deg) * DEG,
                              [self.initial_velocity_std] * 2,
                              [max(sp.gyro_bias / DPH_RAD, 1e-6)] * 3,
                              [max(sp.accel_bias / MG, 1e-6)] * 2])
        return np.zeros(10), np.diag(std ** 2)

    def model(self, mech) -> EulerErrorModel:
        sp = self.specs
        walk = self.bias_walk_fraction / np.sqrt(self.bias_walk_time)
        return EulerErrorModel(mech, gyro_arw=sp.gyro_arw, accel_vrw=sp.accel_vrw,
                               gyro_bias_walk=max(sp.gyro_bias / DPH_RAD, 1e-6) * walk,
                               accel_bias_walk=max(sp.accel_bias / MG, 1e-6) * walk,
                               velocity_noise=self.velocity_noise)


@dataclass
class BaselineResult:
    """Estimates at the step boundaries t (K + 1,) of N runs.

    C_est : (K + 1, N, 3, 3) estimated C_b^n; phi : (K + 1, N, 3) estimated Euler error
    angles (rad); cov : (K + 1, N, 3, 3) their covariance (rad^2); ess : (K + 1,) mean
    effective sample size over the runs (1 for the UKF); extra : filter-specific traces.
    """

    t: np.ndarray
    C_est: np.ndarray
    phi: np.ndarray
    cov: np.ndarray
    ess: np.ndarray
    extra: dict


class _SigmaFilter:
    """What the three filters share: the run on IMU data around :meth:`filter`."""

    name = "?"
    particles = 1

    def __init__(self, config: BaselineConfig):
        self.config = config
        self.sp = SigmaPoints(10, config.alpha, config.beta, config.kappa)

    def _sigma(self, n: int) -> SigmaPoints:
        if self.sp.n != n:
            self.sp = SigmaPoints(n, self.config.alpha, self.config.beta, self.config.kappa)
        return self.sp

    def run(self, dt: float, gyro: np.ndarray, accel: np.ndarray, C_est0: np.ndarray,
            seed: int = 0) -> BaselineResult:
        c = self.config
        m = int(round(c.step / dt))
        mech = mechanize_static(dt, gyro, accel, C_est0, c.latitude_deg * DEG, c.height_m, m)
        model = c.model(mech)
        x0, P0 = c.initial()
        x, P, ess, extra = self.filter(model, x0, P0, np.random.default_rng(seed))
        N = C_est0.shape[0]
        phi = np.concatenate([np.broadcast_to(x0[:3], (1, N, 3)), x[:, :, :3]])
        cov = np.concatenate([np.broadcast_to(P0[:3, :3], (1, N, 3, 3)), P[:, :, :3, :3]])
        C_est = euler_dcm(phi) @ mech.C
        return BaselineResult(mech.t, C_est, phi, cov, np.concatenate([[self.particles], ess]),
                              extra)

    def filter(self, model, x0, P0, rng):
        raise NotImplementedError


class UKF(_SigmaFilter):
    """Unscented Kalman filter on the Euler-error model (seed 004's reference [6] filter
    family): sigma points through the nonlinear transition, additive Q, and the exact Kalman
    update of the linear velocity measurement."""

    name = "ukf"

    def filter(self, model, x0, P0, rng=None):
        N = model.z.shape[1]
        sp = self._sigma(model.n)
        x = np.broadcast_to(x0, (N, 1, model.n)).copy()
        P = np.broadcast_to(P0, (N, 1, model.n, model.n)).copy()
        xs, Ps = [], []
        for k in range(model.steps):
            x, Pp, _ = unscented_predict(model, sp, x, P, k)
            x, P, _, _ = linear_update(x, Pp + model.Q(k), model.z[k][:, None], model.H, model.R)
            xs.append(x[:, 0])
            Ps.append(P[:, 0])
        return np.array(xs), np.array(Ps), np.ones(model.steps), {}


def _log_gauss(d: np.ndarray, L: np.ndarray) -> np.ndarray:
    """log N(d; 0, L L^T) without the 2 pi constant: d (..., n), L (..., n, n) lower."""
    y = np.linalg.solve(L, d[..., None])[..., 0]
    return -0.5 * np.sum(y * y, axis=-1) - np.sum(np.log(np.abs(
        np.diagonal(L, axis1=-2, axis2=-1))), axis=-1)


def systematic_resample(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices (N, M) drawn by systematic resampling from normalised weights w (N, M)."""
    N, M = w.shape
    u = (rng.random((N, 1)) + np.arange(M)) / M
    c = np.cumsum(w, axis=1)
    c[:, -1] = 1.0
    return np.minimum(np.array([np.searchsorted(c[i], u[i]) for i in range(N)]), M - 1)


class UPF(_SigmaFilter):
    """Unscented particle filter (van der Merwe et al. 2000, as seed 004 section 2.1 runs it).

    Every particle carries its own UKF (mean and covariance). Per step: each particle's UKF
    predicts and updates (the proposal q = N(x_upd, P_upd) includes the newest measurement),
    a new particle is drawn from it, and its weight is multiplied by
    ``p(z | x) p(x | x_prev) / q(x)`` (seed 004's weight update: the importance density
    enters there); weights normalised, the estimate is the weighted mean, then systematic
    resampling at every step (seed 004, step 6). ``x_prev``'s transition density is Gaussian
    around the propagated particle with the model's Q.

    particles : 100 by default (seed 004 does not give its number; 100 is the usual figure in
        alignment UPF papers, and the study runs in minutes with it). The cost is linear in
        it: particles x 21 sigma points per run and step.
    weights : 'textbook' (above; consistent: converges to the exact posterior) or
        'predictive' (w *= N(z; z_pred, S) of each particle's UKF: the weight of the optimal
        proposal, which ignores the particles' own spread).
    """

    name = "upf"

    def __init__(self, config: BaselineConfig, particles: int = 100, weights: str = "textbook"):
        super().__init__(config)
        if weights not in ("textbook", "predictive"):
            raise ValueError(f"weights must be 'textbook' or 'predictive', got {weights!r}")
        self.particles = int(particles)
        self.weights = weights

    def _fade(self, model, k, xp, Pp, Q, V):
        """Hook of the adaptive filter: the predicted covariance to use (Pp without Q)."""
        return Pp + Q, None

    def filter(self, model, x0, P0, rng):
        N, M, n = model.z.shape[1], self.particles, model.n
        sp = self._sigma(n)
        L0 = np.linalg.cholesky(P0)
        x = x0 + rng.standard_normal((N, M, n)) @ L0.T
        P = np.broadcast_to(P0, (N, M, n, n)).copy()
        logw = np.full((N, M), -np.log(M))
        state = None
        LQ = np.linalg.cholesky(model.Q(0) + 1e-30 * np.eye(n))
        LR = np.linalg.cholesky(model.R)
        xs, Ps, ess, lams = [], [], [], []
        for k in range(model.steps):
            xp, Pp, centre = unscented_predict(model, sp, x, P, k)
            Q = model.Q(k)
            Pp, info = self._fade(model, k, xp, Pp, Q, state)
            z = model.z[k][:, None]
            xu, Pu, nu, S = linear_update(xp, Pp, z, model.H, model.R)
            Lu = robust_cholesky(Pu)
            xn = xu + np.einsum("...ij,...j->...i", Lu, rng.standard_normal((N, M, n)))
            if self.weights == "textbook":
                logw = (logw + _log_gauss(z - xn @ model.H.T, LR)
                        + _log_gauss(xn - centre, LQ) - _log_gauss(xn - xu, Lu))
            else:
                logw = logw + _log_gauss(nu, robust_cholesky(S))
            logw -= logw.max(axis=1, keepdims=True)
            w = np.exp(logw)
            w /= w.sum(axis=1, keepdims=True)
            mean = np.einsum("nm,nmi->ni", w, xn)
            d = xn - mean[:, None]
            xs.append(mean)
            Ps.append(np.einsum("nm,nmi,nmj->nij", w, d, d))
            ess.append(float(np.mean(1.0 / np.sum(w * w, axis=1))))
            idx = systematic_resample(w, rng)
            take = np.arange(N)[:, None]
            x, P = xn[take, idx], Pu[take, idx]
            logw = np.full((N, M), -np.log(M))
            state = self._after_update(info, nu, take, idx)
            if info is not None:
                lams.append(info["lambda_mean"])
        extra = {"fading_mean": np.array(lams)} if lams else {}
        return np.array(xs), np.array(Ps), np.array(ess), extra

    def _after_update(self, info, nu, take, idx):
        return None


class AdaptiveUPF(UPF):
    """Adaptive UPF of seed 004 section 2.2: the UPF whose particles' UKFs use the
    strong-tracking fading factor when the paper's criterion says the filter is off.

    Per particle, with innovation nu_k of its own UKF:

    - innovation covariance from the innovations themselves (fading memory, rho = 0.95 as in
      the strong-tracking filter of Zhou and Frank):
      ``V_1 = nu_1 nu_1^T``, ``V_k = (rho V_{k-1} + nu_k nu_k^T) / (1 + rho)``;
    - criterion (seed 004 eq. 13, from its reference [10]): the filter is normal while
      ``nu_k^T nu_k <= S tr(E[nu nu^T])`` with S = 3 the adjustment coefficient; the
      innovation is predicted with the *unfaded* covariance, and nothing changes;
    - otherwise (seed 004 eq. 15) the predicted covariance's propagated part is multiplied
      by ``lambda = max(1, tr(V_k - H Q H^T - R) / tr(H P_pred H^T))`` (P_pred: the
      propagated covariance without Q) before the update: ``P_pred <- lambda P_pred + Q``.

    The innovation of step k is the measurement less the unfaded prediction, so the
    criterion and V_k are known before the update; V travels with its particle through
    resampling.
    """

    name = "aupf"

    def __init__(self, config: BaselineConfig, particles: int = 100, weights: str = "textbook",
                 rho: float = 0.95, S: float = 3.0):
        super().__init__(config, particles, weights)
        self.rho, self.S = float(rho), float(S)

    def _fade(self, model, k, xp, Pp, Q, V):
        H, R = model.H, model.R
        HPH, HQH = H @ Pp @ H.T, H @ Q @ H.T                 # (N, M, m, m)
        nu = model.z[k][:, None] - xp @ H.T                  # innovation, unfaded prediction
        nn = np.einsum("...i,...j->...ij", nu, nu)
        Vk = nn if V is None else (self.rho * V + nn) / (1.0 + self.rho)
        normal = np.einsum("...i,...i->...", nu, nu) <= self.S * np.trace(HPH + HQH + R,
                                                                         axis1=-2, axis2=-1)
        lam = np.where(normal, 1.0, fading_factor(Vk - HQH, HPH, R))
        return lam[..., None, None] * Pp + Q, {"V": Vk, "lambda_mean": float(lam.mean())}

    def _after_update(self, info, nu, take, idx):
        return info["V"][take, idx]


BASELINES = {"ukf": UKF, "upf": UPF, "aupf": AdaptiveUPF}
