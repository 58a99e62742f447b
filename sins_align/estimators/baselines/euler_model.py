"""Seed 004's large-azimuth-misalignment error model on Euler platform-error angles, and the
open-loop (no feedback) damped mechanization it describes (numpy only).

Mechanization (ALGORITHM.md, damped form; seed 004 runs it without feedback)::

    C~_j = exp(-(w_ie x) s_j) C~_0 B_j,   B_j = exp(w_1 dt) ... exp(w_j dt)
    v~_j = v~_{j-1} + (C~_j f~_j + g^n) dt

Error angles. Seed 004 rotates the true frame n into the computed frame n' about z, then x,
then y by (phi_z, phi_x, phi_y). Written as the rotation that carries computed into true::

    D(phi) = C_{n'}^n = C_true C~^T = Rz(phi_z) Rx(phi_x) Ry(phi_y)

(R* active rotations), so for small angles D ~ I + (phi x): phi is then the package's attitude
error (ALGORITHM.md, ``C_true = exp(phi x) C~``) and the heading error phi_z may be large.

Error dynamics, exact for this mechanization on a static base (derived from the two attitude
equations; eps = gyro bias, body; nabla = accelerometer bias, body)::

    dD/dt   = -(w_ie x) D + D (w_ie x) - D ((C~ eps) x)
    d dv/dt = (I - D) f~^{n'} + D C~ nabla,      f~^{n'} = C~ f~  (the computed specific force)

which is seed 004's attitude- and velocity-error equations with the transport-rate and
Coriolis terms of the full navigation equations absent, as they are from the damped
mechanization (our simulator's data are exact for it). One filter step spans ``m`` IMU
samples (1 s by default): D advances by exp(-(w_ie x) T) D exp((w_ie x) T) exp(-(C~ eps T) x)
with C~ at the middle of the interval, the velocity error by the trapezoid of the above with
the interval's mean computed specific force (the velocity increment over the interval).

State (10, as the classic large-azimuth alignment filters): phi_x, phi_y, phi_z (rad);
dv_E, dv_N (m/s); eps_x, eps_y, eps_z (deg/h); nabla_x, nabla_y (mg). The biases are in
deg/h and mg so that the covariance is well conditioned. Measurement: the computed
horizontal velocity (the true velocity is zero), z = [dv_E, dv_N] + noise.
"""
from __future__ import annotations

import numpy as np

from sins_align.core.earth import earth_rate_enu, gravity_enu
from sins_align.core.preint import earth_poly, open_loop_velocity, prefix_rotations
from sins_align.core.rotation import dcm_from_quat_components, so3_exp
from sins_align.estimators.baselines.unscented import ErrorModel

__all__ = ["euler_dcm", "dcm_euler", "StaticMechanization", "mechanize_static",
           "EulerErrorModel", "STATE_LABELS", "DPH_RAD", "MG"]

DPH_RAD = np.pi / 180.0 / 3600.0     # deg/h -> rad/s
MG = 9.80665e-3                      # mg -> m/s^2
STATE_LABELS = ("phi_x rad", "phi_y rad", "phi_z rad", "dv_E m/s", "dv_N m/s",
                "eps_x deg/h", "eps_y deg/h", "eps_z deg/h", "nabla_x mg", "nabla_y mg")


def euler_dcm(phi: np.ndarray) -> np.ndarray:
    """D = Rz(phi_z) Rx(phi_x) Ry(phi_y): (..., 3) [x, y, z] -> (..., 3, 3)."""
    sx, cx = np.sin(phi[..., 0]), np.cos(phi[..., 0])
    sy, cy = np.sin(phi[..., 1]), np.cos(phi[..., 1])
    sz, cz = np.sin(phi[..., 2]), np.cos(phi[..., 2])
    # Rx Ry = [[cy, 0, sy], [sx sy, cx, -sx cy], [-cx sy, sx, cx cy]]; Rz on the left
    r10, r11, r12 = sx * sy, cx, -sx * cy
    D = np.empty(phi.shape[:-1] + (3, 3))
    D[..., 0, 0] = cz * cy - sz * r10
    D[..., 0, 1] = -sz * r11
    D[..., 0, 2] = cz * sy - sz * r12
    D[..., 1, 0] = sz * cy + cz * r10
    D[..., 1, 1] = cz * r11
    D[..., 1, 2] = sz * sy + cz * r12
    D[..., 2, 0] = -cx * sy
    D[..., 2, 1] = sx
    D[..., 2, 2] = cx * cy
    return D


def dcm_euler(D: np.ndarray) -> np.ndarray:
    """Inverse of :func:`euler_dcm` (phi_x in [-90, 90] deg)."""
    phi_x = np.arcsin(np.clip(D[..., 2, 1], -1.0, 1.0))
    phi_y = np.arctan2(-D[..., 2, 0], D[..., 2, 2])
    phi_z = np.arctan2(-D[..., 0, 1], D[..., 1, 1])
    return np.stack([phi_x, phi_y, phi_z], axis=-1)


class StaticMechanization:
    """The open-loop damped mechanization sampled at the filter steps.

    Attributes
    ----------
    t : (K + 1,) s — step boundaries (0 = start).
    C : (K + 1, N, 3, 3) — computed attitude C~ at the boundaries.
    C_mid : (K, N, 3, 3) — computed attitude in the middle of each step.
    f_mean : (K, N, 3) — mean computed specific force C~ f~ over each step, ENU.
    v : (K + 1, N, 3) — computed velocity at the boundaries, ENU.
    step : s — filter step; w_ie, g_n : (3,) ENU.
    """

    def __init__(self, t, C, C_mid, f_mean, v, step, w_ie, g_n):
        self.t, self.C, self.C_mid, self.f_mean, self.v = t, C, C_mid, f_mean, v
        self.step, self.w_ie, self.g_n = step, w_ie, g_n


def mechanize_static(dt: float, gyro: np.ndarray, accel: np.ndarray, C0: np.ndarray,
                     lat_rad: float, height_m: float = 0.0, samples_per_step: int = 100
                     ) -> StaticMechanization:
    """Run the open-loop damped mechanization over gyro, accel (T, N, 3) from C0 (N, 3, 3).

    T is cut to a whole number of steps of ``samples_per_step`` samples."""
    m = int(samples_per_step)
    K = len(gyro) // m
    if K < 1:
        raise ValueError(f"need at least {m} samples, got {len(gyro)}")
    gyro, accel = gyro[:K * m], accel[:K * m]
    w_ie = earth_rate_enu(lat_rad)
    g_n = gravity_enu(lat_rad, height_m)
    dts = np.full(K * m, float(dt))
    v = open_loop_velocity(dts, gyro, accel, C0, w_ie, g_n)
    q = prefix_rotations(float(dt), gyro[None])
    Kk, W = earth_poly(w_ie)

    def attitude(j: np.ndarray) -> np.ndarray:
        """C~ after j samples, j (J,) >= 1."""
        B = dcm_from_quat_components(*(c[0, j - 1] for c in q))          # (J, N, 3, 3)
        s = j * dt
        E = (np.eye(3) + np.sin(W * s)[:, None, None] * Kk
             + (1.0 - np.cos(W * s))[:, None, None] * (Kk @ Kk))
        return E[:, None] @ C0[None] @ B

    ends = np.arange(1, K + 1) * m
    C = np.concatenate([C0[None], attitude(ends)])
    C_mid = attitude(ends - m // 2)
    v_b = np.concatenate([np.zeros((1,) + v.shape[1:]), v[ends - 1]])
    T = m * dt
    f_mean = np.diff(v_b, axis=0) / T - g_n
    return StaticMechanization(np.arange(K + 1) * T, C, C_mid, f_mean, v_b, T, w_ie, g_n)


def _skew(v: np.ndarray) -> np.ndarray:
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


class EulerErrorModel(ErrorModel):
    """The 10-state nonlinear error model above, one step per mechanization step.

    Parameters
    ----------
    mech : StaticMechanization of the N runs.
    gyro_arw : rad/sqrt(s); accel_vrw : m/s/sqrt(s) — white noise of the sensors (Q).
    gyro_bias_walk : deg/h/sqrt(s); accel_bias_walk : mg/sqrt(s) — random walk given to the
        bias states (Q; zero makes them random constants).
    velocity_noise : m/s, measurement noise std (R).
    """

    n = 10
    H = np.zeros((2, 10))
    H[0, 3] = H[1, 4] = 1.0

    def __init__(self, mech: StaticMechanization, gyro_arw: float, accel_vrw: float,
                 gyro_bias_walk: float, accel_bias_walk: float, velocity_noise: float):
        self.mech = mech
        T = mech.step
        self.T = T
        self.A = so3_exp(-mech.w_ie * T)
        self.B = self.A.T
        q = np.array([gyro_arw ** 2] * 3 + [accel_vrw ** 2] * 2 + [gyro_bias_walk ** 2] * 3
                     + [accel_bias_walk ** 2] * 2) * T
        self._Q = np.diag(q)
        self.R = np.eye(2) * velocity_noise ** 2
        self.z = mech.v[1:, :, :2]                     # (K, N, 2)

    def propagate(self, X: np.ndarray, k: int) -> np.ndarray:
        """Step k (0-based: from t[k] to t[k+1]) of points X (N, ..., 10)."""
        extra = X.ndim - 2
        shp = (X.shape[0],) + (1,) * extra
        Cm = self.mech.C_mid[k].reshape(shp + (3, 3))
        fm = self.mech.f_mean[k].reshape(shp + (3,))
        T = self.T
        D = euler_dcm(X[..., 0:3])
        eps_n = np.einsum("...ij,...j->...i", Cm, X[..., 5:8] * DPH_RAD)
        D1 = self.A @ D @ self.B @ (np.eye(3) - _skew(eps_n * T))
        nab_b = np.concatenate([X[..., 8:10] * MG, np.zeros(X.shape[:-1] + (1,))], axis=-1)
        nab_n = np.einsum("...ij,...j->...i", Cm, nab_b)
        Dm = 0.5 * (D + D1)
        acc = fm - np.einsum("...ij,...j->...i", Dm, fm) + np.einsum("...ij,...j->...i",
                                                                      Dm, nab_n)
        Y = X.copy()
        Y[..., 0:3] = dcm_euler(D1)
        Y[..., 3:5] = X[..., 3:5] + acc[..., :2] * T
        return Y
