"""Kalman-filter numerics shared by every model: discretisation and a Joseph-form update.

Kept apart from the models so the discretisation lives in one place (STYLE.md). Every
function works on a single filter or on a stack of filters (leading dimension N).
"""
from __future__ import annotations

import numpy as np


def _T(a: np.ndarray) -> np.ndarray:
    return np.swapaxes(a, -1, -2)


def inv3(S: np.ndarray) -> np.ndarray:
    """Inverse of 3x3 matrices (..., 3, 3); a single one (shape (3, 3) or (1, 3, 3)) by the
    adjugate in scalar arithmetic, which is several times faster than LAPACK for one 3x3."""
    if S.size != 9:
        return np.linalg.inv(S)
    (a, b, c), (d, e, f), (g, h, i) = S.reshape(3, 3).tolist()
    A, B, C = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * A + b * B + c * C
    if det == 0.0:
        return np.linalg.inv(S)          # raises LinAlgError like numpy would
    r = 1.0 / det
    out = np.array([[A * r, (c * h - b * i) * r, (b * f - c * e) * r],
                    [B * r, (a * i - c * g) * r, (c * d - a * f) * r],
                    [C * r, (b * g - a * h) * r, (a * e - b * d) * r]])
    return out.reshape(S.shape)


def discretize(F: np.ndarray, Qc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition matrix and discrete process noise for ``x' = F x + w``, ``E[w w^T] = Qc delta``.

    Third-order series in ``F dt``. For the alignment models ``|F dt|`` stays below 1e-3 for
    any interval up to several seconds (Earth rate 7.3e-5 rad/s; gravity enters only through
    products with it), so the truncation error is below 1e-12.

    Parameters
    ----------
    F : ndarray, shape (..., n, n) — continuous system matrix.
    Qc : ndarray, shape (n, n) — continuous process noise spectral density.
    dt : float, s — interval.

    Returns
    -------
    Phi : ndarray, shape (..., n, n) ; Qd : ndarray, shape (..., n, n)
    """
    Fdt = F * dt
    F2 = Fdt @ Fdt
    Phi = np.eye(F.shape[-1]) + Fdt + F2 / 2.0 + F2 @ Fdt / 6.0
    FQ = F @ Qc
    FFQ = F @ FQ
    Qd = Qc * dt + (FQ + _T(FQ)) * (dt * dt / 2.0) \
        + (FFQ + 2.0 * FQ @ _T(F) + _T(FFQ)) * (dt ** 3 / 6.0)
    return Phi, 0.5 * (Qd + _T(Qd))


def joseph_update(P: np.ndarray, H: np.ndarray, R: np.ndarray):
    """Covariance part of a Kalman update, Joseph form (error state with zero prior mean).

    Parameters
    ----------
    P : ndarray, shape (..., n, n) — prior covariance.
    H : ndarray, shape (..., m, n) ; R : ndarray, shape (..., m, m).

    Returns
    -------
    P : ndarray (..., n, n) — posterior covariance (symmetrised).
    K : ndarray (..., n, m) — gain; the error-state estimate is ``K @ innovation``.
    S : ndarray (..., m, m) — innovation covariance ``H P H^T + R``.
    """
    PHt = P @ H.mT
    S = H @ PHt + R
    K = PHt @ inv3(S) if H.shape[-2] == 3 else PHt @ np.linalg.inv(S)
    IKH = _eye(P.shape[-1]) - K @ H
    P = IKH @ P @ IKH.mT + K @ R @ K.mT
    return 0.5 * (P + P.mT), K, S


_EYES: dict = {}


def _eye(n: int) -> np.ndarray:
    e = _EYES.get(n)
    if e is None:
        e = _EYES[n] = np.eye(n)
        e.flags.writeable = False
    return e


def nis(nu: np.ndarray, S_inv: np.ndarray) -> np.ndarray:
    """Normalised innovation squared ``nu^T S^-1 nu``, shape (...,), from the inverse
    innovation covariance.

    Chi-square with m degrees of freedom when the model fits the data; large values mean
    motion, a bad sensor or a wrong noise setting.
    """
    return np.einsum("...i,...ij,...j->...", nu, S_inv, nu)
