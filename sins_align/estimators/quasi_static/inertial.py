"""Inertial-frame coarse alignment: attitude from a buffer of samples, immune to sway.

Why
---
The paper's filter (the coarse pass) reads attitude from a zero-velocity measurement. On a
base that sways horizontally (a boat's surge, a car rocking on its springs) the velocity is
not zero, its tiny measurement noise is far too small, and after a minute the heading it
hands to the fine pass can be off by anything, with a covariance that does not know it.
The inertial-frame method (the "i0" alignment of the SINS literature, e.g. PSINS's
``alignsb``/``CAligni0`` family) does not care: angular sway is removed exactly by the gyro
integration, and linear sway only adds a *bounded* displacement.

Method
------
With ``B(t)`` the body rotation since the first sample (gyro only, an inertially fixed frame
b0) and ``n0`` the ENU frame at the first sample, also frozen in inertial space, a base that
stays where it is on the Earth obeys, for the double integral of the specific force,

    C0 P_b(t) = P_g(t) + p(t) - p(0) - v(0) t,        P_b(t) = int int B f,

where ``C0`` is the attitude at the first sample, ``P_g`` the double integral of gravity
turned by the Earth's rotation (closed form), and ``p``, ``v`` the sway displacement and
velocity (bounded). Projected on the polynomials ``1, t, t^2, t^3`` both sides match
coefficient by coefficient; the constant and linear terms only hold the nuisances. The t^2
coefficient points up (level, as gravity), the t^3 coefficient points East (Earth rate
tilting gravity in inertial space: the heading); the attitude is the TRIAD of the two pairs.

Uncertainty
-----------
The coefficients are linear in the data, so their error is a weighted sum of the residual
displacement. Its variance is computed from the residual's own autocovariance (Bartlett
weighted, half the window: correlated sway counts in full, fast sway averages out), plus the
noise and bias terms no residual can show (they look like attitude): the limit accuracy of
the specs and the white-noise terms over the window. Returned as per-axis std (E, N, U).
"""
from __future__ import annotations

import math

import numpy as np

from sins_align.core.preint import start_frame_increments

__all__ = ["InertialFit", "inertial_alignment"]

_MAX_POINTS = 4000


class InertialFit:
    """Result of :func:`inertial_alignment` for N runs.

    Attributes
    ----------
    C0 : ndarray (N, 3, 3) — C_b^n at the first sample.
    std : ndarray (N, 3) — one-sigma attitude error (E, N, U), rad.
    v0 : ndarray (N, 3) — ENU velocity at the first sample (the sway's), m/s.
    v0_std : ndarray (N, 3) — its one-sigma error, m/s.
    """

    def __init__(self, C0, std, v0, v0_std):
        self.C0, self.std, self.v0, self.v0_std = C0, std, v0, v0_std


def _s3(x):
    """x - sin x, accurate for small x."""
    x = np.asarray(x, dtype=float)
    small = x < 0.1
    x2 = x * x
    series = x * x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0))
    return np.where(small, series, x - np.sin(x))


def gravity_velocity_n0(s: np.ndarray, w_ie: np.ndarray, g_n: np.ndarray) -> np.ndarray:
    """Integral over [0, s] of the specific force of a base at rest on the Earth, in the
    inertially frozen ENU frame of time 0: ``int exp((w_ie x) t) (-g_n) dt``, (M, 3)."""
    W = float(np.linalg.norm(w_ie))
    k = w_ie / W
    a = -np.asarray(g_n, dtype=float)
    ka = np.cross(k, a)
    kka = np.cross(k, ka)
    x = W * np.asarray(s, dtype=float)
    c1 = 2.0 * np.sin(0.5 * x) ** 2 / W          # (1 - cos x) / W
    c2 = _s3(x) / W                               # (W s - sin W s) / W
    return s[:, None] * a + c1[:, None] * ka + c2[:, None] * kka


def _unit(v):
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


def _triad(x1, x2):
    """Orthonormal frames (..., 3, 3), columns: x1, x1 x x2, x1 x (x1 x x2), normalised."""
    t1 = _unit(x1)
    t2 = _unit(np.cross(x1, x2))
    return np.stack([t1, t2, np.cross(t1, t2)], axis=-1)


def _fft_length(n: int) -> int:
    """The smallest 2^a 3^b >= n (a length pocketfft transforms fast)."""
    best = 1 << max(0, (n - 1).bit_length())
    p3 = 3
    while p3 < best:
        best = min(best, p3 << max(0, (-(-n // p3) - 1).bit_length()))     # p3 2^a >= n
        p3 *= 3
    return best


def _bartlett_variances(r: np.ndarray, weights: np.ndarray, band: int) -> np.ndarray:
    """Variance of ``sum_k a_k r_k`` for a stationary residual r (M, ...) observed once, for
    each row ``a`` of ``weights`` (W, M): sum over lags of (1 - |l|/band) gamma(l) c_a(l),
    gamma from r, c_a of the weights; (W, ...). The lagged products come from FFTs of a
    length of at least M + band, so that no lag below ``band`` wraps round: the transform of
    r is taken once for all the weights, those of the weights in one call."""
    M = len(r)
    nfft = _fft_length(M + band)
    R = np.fft.rfft(r, nfft, axis=0)
    gam = np.fft.irfft(np.abs(R) ** 2, nfft, axis=0)[:band] / M
    A = np.fft.rfft(weights, nfft, axis=-1)
    ca = np.fft.irfft(np.abs(A) ** 2, nfft, axis=-1)[:, :band]
    wts = (1.0 - np.arange(band) / band) * ca
    wts[:, 1:] *= 2.0
    return np.maximum(np.tensordot(wts, gam, axes=(1, 0)), 0.0)


def inertial_alignment(dt: np.ndarray, w: np.ndarray, f: np.ndarray, w_ie: np.ndarray,
                       g_n: np.ndarray, limit_std: np.ndarray, gyro_arw: float,
                       accel_vrw: float, increments=None) -> InertialFit:
    """Attitude at the first sample from a buffer, for N runs sharing one time line.

    Parameters
    ----------
    dt : ndarray (T,) s ; w, f : ndarray (T, N, 3) rad/s, m/s^2 (body).
    w_ie, g_n : ndarray (3,) — Earth rate and gravity in ENU.
    limit_std : ndarray (3,) rad — limit accuracy (E, N, U) of the bias specs (inf allowed).
    gyro_arw : rad/sqrt(s) ; accel_vrw : m/s/sqrt(s).
    increments : :func:`sins_align.core.preint.start_frame_increments` of the same samples, when
        the caller has them already.
    """
    dt = np.asarray(dt, dtype=float)
    u = start_frame_increments(dt, w, f) if increments is None else increments   # b0
    s = np.cumsum(dt)
    Vb = np.cumsum(u, axis=0)
    Vg = gravity_velocity_n0(s, w_ie, g_n)                # (T, 3), n0
    Pb = np.cumsum(Vb * dt[:, None, None], axis=0)        # same rule on both sides
    Pg = np.cumsum(Vg * dt[:, None], axis=0)
    step = max(1, len(dt) // _MAX_POINTS)
    idx = np.arange(len(dt) - 1, -1, -step)[::-1]         # always keeps the last sample
    T = float(s[-1])
    tn = s[idx] / T
    X = np.vander(tn, 4, increasing=True)                 # 1, t, t^2, t^3 (normalised)
    A = np.linalg.pinv(X)                                 # (4, M)
    Pbi = Pb[idx]
    M, N = Pbi.shape[:2]
    # products over the M points as GEMMs on (M, N * 3) views (einsum: 4x slower)
    cb = (A @ Pbi.reshape(M, -1)).reshape(4, N, 3)        # (4, N, 3)
    cg = A @ Pg[idx]                                      # (4, 3)
    Mb = _triad(cb[2], cb[3])                             # (N, 3, 3)
    Mg = _triad(cg[2], cg[3])                             # (3, 3)
    C0 = Mg @ Mb.mT                                       # b0 -> n0 = C_b^n at time 0
    D = (Pbi.transpose(1, 0, 2) @ C0.mT).transpose(1, 0, 2) - Pg[idx][:, None, :]
    coef = (A @ D.reshape(M, -1)).reshape(4, N, 3)
    r = D - (X @ coef.reshape(4, -1)).reshape(M, N, 3)   # (M, N, 3) residual displacement
    band = max(2, len(idx) // 2)
    # (N, 3) each: of the t^2, t^3 and t coefficients
    var2, var3, var1 = _bartlett_variances(r, A[[2, 3, 1]], band)
    up = float(np.linalg.norm(cg[2]))
    east = float(np.linalg.norm(cg[3][:2]))
    horiz = math.hypot(w_ie[0], w_ie[1])              # Omega cos(lat)
    g = float(np.linalg.norm(g_n))
    lim = np.asarray(limit_std, dtype=float)
    noise_level = 2.0 * accel_vrw / (g * math.sqrt(T))
    noise_head = (2.0 * gyro_arw / (horiz * math.sqrt(T))) if horiz > 0 else math.inf
    std = np.empty((len(C0), 3))
    std[:, 0] = np.sqrt(var2[:, 1] / up ** 2 + lim[0] ** 2 + noise_level ** 2)
    std[:, 1] = np.sqrt(var2[:, 0] / up ** 2 + lim[1] ** 2 + noise_level ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        std[:, 2] = np.sqrt(var3[:, 1] / east ** 2 + lim[2] ** 2 + noise_head ** 2)
    v0 = -coef[1] / T                                     # d/dt of the linear term
    v0_std = np.sqrt(var1) / T
    return InertialFit(C0, std, v0, v0_std)
