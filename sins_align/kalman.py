"""Kalman-filter numerics shared by every model: discretisation and a Joseph-form update.

Kept apart from the models so the discretisation lives in one place (STYLE.md).
"""
from __future__ import annotations

import numpy as np


def discretize(F: np.ndarray, Qc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition matrix and discrete process noise for ``x' = F x + w``, ``E[w w^T] = Qc delta``.

    Third-order series in ``F dt``. For the alignment models ``|F dt|`` is below 1e-3 for
    any sample interval up to a second (Earth rate 7.3e-5 rad/s, gravity enters only
    through products with it), so the truncation error is below 1e-12.

    Parameters
    ----------
    F : ndarray, shape (n, n) — continuous system matrix.
    Qc : ndarray, shape (n, n) — continuous process noise spectral density.
    dt : float, s — interval.

    Returns
    -------
    Phi : ndarray, shape (n, n) ; Qd : ndarray, shape (n, n)
    """
    Fdt = F * dt
    F2 = Fdt @ Fdt
    Phi = np.eye(F.shape[0]) + Fdt + F2 / 2.0 + F2 @ Fdt / 6.0
    FQ = F @ Qc
    Qd = Qc * dt + (FQ + FQ.T) * (dt * dt / 2.0) \
        + (F @ FQ + 2.0 * FQ @ F.T + (F @ FQ).T) * (dt ** 3 / 6.0)
    return Phi, 0.5 * (Qd + Qd.T)


def joseph_update(P: np.ndarray, nu: np.ndarray, H: np.ndarray, R: np.ndarray):
    """Kalman measurement update in Joseph form for an error state with zero prior mean.

    Parameters
    ----------
    P : ndarray, shape (n, n) — prior covariance.
    nu : ndarray, shape (m,) — innovation ``z - H x_prior`` (``x_prior`` = 0 after feedback).
    H : ndarray, shape (m, n) ; R : ndarray, shape (m, m).

    Returns
    -------
    x : ndarray (n,) — posterior error-state estimate.
    P : ndarray (n, n) — posterior covariance (symmetrised).
    K : ndarray (n, m) — gain.
    nis : float — normalised innovation squared ``nu^T S^-1 nu`` (chi-square, m dof, when the
        model fits the data; large values mean motion or a bad sensor).
    """
    PHt = P @ H.T
    S = H @ PHt + R
    K = np.linalg.solve(S, PHt.T).T
    IKH = np.eye(P.shape[0]) - K @ H
    P = IKH @ P @ IKH.T + K @ R @ K.T
    x = K @ nu
    nis = float(nu @ np.linalg.solve(S, nu))
    return x, 0.5 * (P + P.T), K, nis
