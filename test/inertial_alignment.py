"""An independent attitude reference for real logs: inertial-frame alignment, written here
from the textbook equations and sharing no code with the estimator (not even its Earth
model: the Earth rate is written again below).

On a base that sways but does not travel, the specific force integrated twice in the body
frame frozen at the first sample (b0) equals, up to the sway displacement (millimetres) and
a term linear in time (the velocity the base had at the first sample), the same integral for
a point fixed to the Earth in the inertial frame i that coincides with ENU at the first
sample. The latter has a closed form, so the constant rotation C_b0^i follows from a
least-squares fit (Wahba's problem) over many instants, and the attitude at the end is
C_b^n(T) = C_i^n(T) C_b0^i C_b^b0(T). Sway and tilts that come and go cancel in the
integrals, unlike in a plain average of rates and forces (which is off by 7 deg in heading on
the first 300 s of the laser-gyro log). Gyro and accelerometer biases bias it as they bias
any static alignment (the limit accuracy).

Checked against the simulator's truth in test_inertial_alignment.py.
"""
from __future__ import annotations

import numpy as np

OMEGA_E = 7.2921151467e-5     # rad/s, WGS-84 (written again here on purpose)


def _cross(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _rodrigues(phi: np.ndarray) -> np.ndarray:
    """exp((phi x)) for each row of phi (n, 3), rad -> (n, 3, 3)."""
    th = np.linalg.norm(phi, axis=1)
    small = th < 1e-6
    safe = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th ** 2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - th ** 2 / 24.0, (1.0 - np.cos(safe)) / safe ** 2)
    K = np.zeros((len(phi), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -phi[:, 2], phi[:, 1], -phi[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = phi[:, 2], -phi[:, 1], phi[:, 0]
    return np.eye(3) + a[:, None, None] * K + b[:, None, None] * (K @ K)


def inertial_frame_alignment(dt: float, gyro: np.ndarray, accel: np.ndarray, lat_rad: float,
                             g: float, n_fit: int = 60) -> np.ndarray:
    """C_b^n (ENU) at the last sample of a quasi-static log.

    Parameters
    ----------
    dt : float, s — sample interval (uniform).
    gyro, accel : ndarray (N, 3) — mean rate (rad/s) and specific force (m/s^2) over each
        interval, body axes.
    lat_rad : float, rad — latitude. g : float, m/s^2 — local gravity.
    n_fit : int — number of instants in the fit, evenly spread from a tenth of the log to
        its end (the first tenth carries little information and much relative sway).
    """
    n = len(gyro)
    steps = _rodrigues(gyro * dt)
    # body attitude relative to b0 at the start of every interval; each velocity increment
    # is rotated into b0 with the attitude at the middle of its interval (to first order in
    # the interval's rotation angle, micro-radians here: dv + dtheta x dv / 2)
    C = np.empty((n + 1, 3, 3))
    C[0] = np.eye(3)
    for k in range(n):
        C[k + 1] = C[k] @ steps[k]
    dv_b = accel * dt
    dv_b = dv_b + 0.5 * np.cross(gyro * dt, dv_b)
    dv = np.einsum("kij,kj->ki", C[:-1], dv_b)
    # integrated twice: the sway velocity (up to 0.1 m/s in a burst) drops out of the first
    # integral only on average, its displacement (millimetres) is all that reaches the second
    V_b = np.cumsum(dv, axis=0)                     # at t_k = (k + 1) dt
    S_b = np.cumsum(0.5 * (V_b + np.vstack([np.zeros(3), V_b[:-1]])) * dt, axis=0)  # trapezoid
    w = OMEGA_E * np.array([0.0, np.cos(lat_rad), np.sin(lat_rad)])   # Earth rate in ENU
    K = _cross(w)
    K2 = K @ K
    W = OMEGA_E
    t = dt * np.arange(1, n + 1)
    idx = np.unique(np.linspace(n // 10, n - 1, n_fit).astype(int))
    up_g = np.array([0.0, 0.0, g])
    S_i = []
    for k in idx:
        tk = t[k]
        c, s_ = np.cos(W * tk), np.sin(W * tk)
        # int_0^t int_0^tau exp(s K) ds dtau, with exp(s K) = I + sin(W s)/W K
        # + (1 - cos(W s))/W^2 K^2 (Rodrigues, |K| = W):
        integ2 = (tk ** 2 / 2 * np.eye(3) + (tk / W - s_ / W ** 2) / W * K
                  + (tk ** 2 / 2 - (1.0 - c) / W ** 2) / W ** 2 * K2)
        S_i.append(integ2 @ up_g)
    S_i = np.array(S_i)
    # The base may be moving when the log starts (mid-sway: a centimetre per second is
    # metres after 300 s), so S_b = C^T (S_i + u t) + mm with an unknown u. Minimising
    # sum |S_i + u t - C S_b|^2 over u leaves Wahba's problem for the two series with their
    # least-squares fit on t taken out.
    tf = t[idx][:, None]
    S_i = S_i - tf * (tf.T @ S_i) / (tf.T @ tf)
    S_f = S_b[idx] - tf * (tf.T @ S_b[idx]) / (tf.T @ tf)
    # Wahba: C_b0^i = argmin sum |S_i - C S_f|^2 (SVD solution, proper rotation)
    B = S_i.T @ S_f
    U, _, Vt = np.linalg.svd(B)
    D = np.diag([1.0, 1.0, np.linalg.det(U @ Vt)])
    C_b0_i = U @ D @ Vt
    T = t[-1]
    C_i_n = _rodrigues((-w * T)[None])[0]           # n(T) is i turned by w T
    return C_i_n @ C_b0_i @ C[-1]
