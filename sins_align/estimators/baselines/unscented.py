"""Sigma-point machinery shared by the baseline filters: the scaled unscented transform, the
Kalman update for a linear measurement, the strong-tracking fading factor, and a
linear-Gaussian model for checking them (numpy only).

Every array carries leading batch dimensions ``(runs, particles)``: a UKF is the one-particle
case, so one implementation serves the UKF, the UPF and the adaptive UPF.

A *model* is any object with

- ``n`` (state size), ``H`` (m, n) — the measurement is linear, ``z = H x + v`` (true of the
  seed 004 model: the measured quantity is the computed velocity, a state),
- ``R`` (m, m) and ``Q(k)`` (n, n) — measurement noise and the additive process noise of step k,
- ``propagate(X, k)`` — the state transition of step k applied to points X (runs, ..., n);
  the same transition for every point of one run.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SigmaPoints", "unscented_predict", "linear_update", "fading_factor",
           "symmetrize", "LinearGaussianModel", "kalman_filter"]


def symmetrize(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + np.swapaxes(P, -1, -2))


@dataclass(frozen=True)
class SigmaPoints:
    """Scaled symmetric sigma-point set (2n + 1 points).

    Defaults alpha = 1, beta = 2, kappa = 0: the points lie at +-sqrt(n) sigma, the central
    point has mean weight 0 and covariance weight 2, every covariance weight is >= 0 (so the
    predicted covariance stays positive semi-definite; a small alpha gives a large negative
    central weight with n = 10 states). beta = 2 is the Gaussian optimum for the fourth
    moment.
    """

    n: int
    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0

    @property
    def lam(self) -> float:
        return self.alpha ** 2 * (self.n + self.kappa) - self.n

    @property
    def weights(self) -> tuple[np.ndarray, np.ndarray]:
        """(Wm, Wc), each (2n + 1,)."""
        n, lam = self.n, self.lam
        wm = np.full(2 * n + 1, 0.5 / (n + lam))
        wc = wm.copy()
        wm[0] = lam / (n + lam)
        wc[0] = wm[0] + 1.0 - self.alpha ** 2 + self.beta
        return wm, wc

    def points(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Sigma points of N(x, P): x (..., n), P (..., n, n) -> (..., 2n + 1, n)."""
        L = robust_cholesky((self.n + self.lam) * P)
        d = np.swapaxes(L, -1, -2)                       # rows = columns of L
        return np.concatenate([x[..., None, :], x[..., None, :] + d, x[..., None, :] - d],
                              axis=-2)


def robust_cholesky(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of a (batch of) covariance(s); a matrix that lost positive
    definiteness to rounding gets a diagonal jitter (relative 1e-12, then grown) first."""
    P = symmetrize(P)
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        pass
    d = np.abs(np.diagonal(P, axis1=-2, axis2=-1))
    eye = np.eye(P.shape[-1])
    for rel in (1e-12, 1e-9, 1e-6, 1e-3):
        try:
            return np.linalg.cholesky(P + (rel * d + 1e-300)[..., None] * eye)
        except np.linalg.LinAlgError:
            continue
    # last resort: the eigen-decomposition with negative eigenvalues clipped
    w, V = np.linalg.eigh(P)
    return np.linalg.cholesky(V @ (np.maximum(w, 1e-12 * d.max(-1, keepdims=True))[..., None]
                                   * np.swapaxes(V, -1, -2)) + 1e-300 * eye)


def unscented_predict(model, sp: SigmaPoints, x: np.ndarray, P: np.ndarray, k: int
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time update of step k through the unscented transform.

    x (R, M, n), P (R, M, n, n) -> (x_pred, P_pred without Q, centre point propagated)."""
    X = sp.points(x, P)                                  # (R, M, S, n)
    Y = model.propagate(X, k)
    wm, wc = sp.weights
    xp = np.einsum("s,...si->...i", wm, Y)
    dY = Y - xp[..., None, :]
    Pp = np.einsum("s,...si,...sj->...ij", wc, dY, dY)
    return xp, symmetrize(Pp), Y[..., 0, :]


def linear_update(x: np.ndarray, P: np.ndarray, z: np.ndarray, H: np.ndarray, R: np.ndarray):
    """Kalman update for z = H x + v (Joseph form). z (R, m) broadcast over particles.

    Returns x, P, innovation nu (..., m), its covariance S (..., m, m)."""
    PHt = P @ H.T
    S = symmetrize(H @ PHt + R)
    K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)
    nu = z - x @ H.T
    x = x + np.einsum("...ij,...j->...i", K, nu)
    IKH = np.eye(P.shape[-1]) - K @ H
    P = IKH @ P @ np.swapaxes(IKH, -1, -2) + K @ R @ np.swapaxes(K, -1, -2)
    return x, symmetrize(P), nu, S


def fading_factor(V: np.ndarray, Pzz_no_noise: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Strong-tracking fading factor lambda = max(1, tr(V - R) / tr(Pzz - R)).

    V : (..., m, m) — the innovation covariance estimated from the innovations themselves;
    Pzz_no_noise : (..., m, m) — the filter's predicted measurement covariance without R.
    """
    num = np.trace(V - R, axis1=-2, axis2=-1)
    den = np.trace(Pzz_no_noise, axis1=-2, axis2=-1)
    return np.maximum(1.0, num / np.maximum(den, 1e-300))


# ----------------------------------------------------------------------------- models
class ErrorModel:
    """What the filters read of a model: ``n``, ``H``, ``R``, the measurements ``z`` (steps,
    runs, m), ``Q(k)`` and ``propagate(X, k)`` (subclasses give the last)."""

    n: int
    H: np.ndarray
    R: np.ndarray
    z: np.ndarray | None
    _Q: np.ndarray

    @property
    def steps(self) -> int:
        return len(self.z)

    def Q(self, k: int) -> np.ndarray:
        return self._Q

    def propagate(self, X: np.ndarray, k: int) -> np.ndarray:
        raise NotImplementedError


# ----------------------------------------------------------------------------- linear check
class LinearGaussianModel(ErrorModel):
    """x_k = F x_{k-1} + w, z_k = H x_k + v: the case where UKF and KF must agree exactly
    and where a consistent particle filter's mean converges to the KF's."""

    def __init__(self, F, Q, H, R, z=None):
        self.F = np.asarray(F, dtype=float)
        self._Q = np.asarray(Q, dtype=float)
        self.H = np.asarray(H, dtype=float)
        self.R = np.asarray(R, dtype=float)
        self.n = self.F.shape[0]
        #: measurements (K, runs, m) the filters' ``filter`` methods read
        self.z = None if z is None else np.asarray(z, dtype=float)

    def propagate(self, X: np.ndarray, k: int) -> np.ndarray:
        return X @ self.F.T

    def simulate(self, steps: int, x0: np.ndarray, rng: np.random.Generator, runs: int = 1):
        """(x (steps, runs, n), z (steps, runs, m)) drawn from the model."""
        Lq = np.linalg.cholesky(self._Q)
        Lr = np.linalg.cholesky(self.R)
        x = np.broadcast_to(x0, (runs, self.n)).copy()
        xs, zs = [], []
        for _ in range(steps):
            x = x @ self.F.T + rng.standard_normal((runs, self.n)) @ Lq.T
            xs.append(x.copy())
            zs.append(x @ self.H.T + rng.standard_normal((runs, len(self.R))) @ Lr.T)
        return np.array(xs), np.array(zs)


def kalman_filter(model: LinearGaussianModel, z: np.ndarray, x0: np.ndarray, P0: np.ndarray):
    """The plain Kalman filter of a linear model: z (K, R, m) -> means (K, R, n), covs
    (K, R, n, n) after each update (the reference of the tests)."""
    x = np.broadcast_to(np.asarray(x0, float), (z.shape[1], model.n)).copy()
    P = np.broadcast_to(np.asarray(P0, float), (z.shape[1], model.n, model.n)).copy()
    xs, Ps = [], []
    for k in range(len(z)):
        x = x @ model.F.T
        P = model.F @ P @ model.F.T + model.Q(k)
        x, P, _, _ = linear_update(x, P, z[k], model.H, model.R)
        xs.append(x)
        Ps.append(P)
    return np.array(xs), np.array(Ps)
