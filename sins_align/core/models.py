"""The three error-state models of the paper (ALGORITHM.md, section "The error-state models").

State ``x = [phi; dv]`` (6): attitude error phi on E/N/U, rad (paper eq. 15:
``C_true = exp(phi x) C_est``) and a velocity error (m/s). The velocity error is
``dv = v_est - v_true`` for 'constant' and 'conventional', and the SE(3) error
``dv = v_true - exp(phi x) v_est`` (approximately ``-dv + v_est x phi``, eq. 22) for 'se3'.
"""
from __future__ import annotations

import numpy as np

from sins_align.core.rotation import skew, so3_exp

MODELS = ("constant", "conventional", "se3")


def check_model(name: str) -> str:
    """Return ``name`` if it is a known model, else raise ValueError naming the choices."""
    if name not in MODELS:
        raise ValueError(f"unknown model {name!r}; choose one of {', '.join(MODELS)}")
    return name


def system_matrix(model: str, w_ie_n: np.ndarray, g_n: np.ndarray,
                  f_n: np.ndarray | None = None, v_est: np.ndarray | None = None) -> np.ndarray:
    """Continuous system matrix F, shape (6, 6).

    Parameters
    ----------
    model : 'constant' (paper eq. 30), 'conventional' (eq. 18) or 'se3' (eq. 25).
    w_ie_n : ndarray (3,), rad/s — Earth rate in ENU.
    g_n : ndarray (3,), m/s^2 — gravity vector in ENU ([0, 0, -g]).
    f_n : ndarray (..., 3), m/s^2 — ``C_est f^b``, needed by 'conventional'.
    v_est : ndarray (..., 3), m/s — velocity estimate, needed by 'se3'.

    Returns
    -------
    F : ndarray (6, 6), or (..., 6, 6) for stacked f_n / v_est.
    """
    check_model(model)
    lead = ()
    if model == "conventional":
        lead = np.shape(f_n)[:-1]
    elif model == "se3":
        lead = np.shape(v_est)[:-1]
    F = np.zeros(lead + (6, 6))
    F[..., :3, :3] = -skew(w_ie_n)
    if model == "constant":
        F[..., 3:, :3] = -skew(g_n)
    elif model == "conventional":
        F[..., 3:, :3] = skew(f_n)
    else:
        F[..., 3:, :3] = skew(g_n) - skew(v_est) @ skew(w_ie_n)
    return F


def measurement_matrix(model: str, v_est: np.ndarray | None = None) -> np.ndarray:
    """H, shape (3, 6) (or (..., 3, 6) for 'se3' with stacked v_est), for the zero-velocity
    measurement ``z = v_est`` (the true velocity is zero)."""
    if model == "se3":
        H = np.zeros(np.shape(v_est)[:-1] + (3, 6))
        H[..., :3] = skew(v_est)
        H[..., 3:] = -np.eye(3)
    else:
        H = np.zeros((3, 6))
        H[:, 3:] = np.eye(3)
    return H


def averaged_measurement_matrix(H: np.ndarray, F: np.ndarray, period: float) -> np.ndarray:
    """H for the mean velocity over the ``period`` ending at the update time.

    Over the interval the velocity error obeys ``d(dv)/dt = F21 phi``, so its mean is the
    end value minus ``F21 phi period / 2``; the attitude error changes negligibly
    (Earth-rate coupling only).
    """
    Ha = np.array(np.broadcast_to(H, np.broadcast_shapes(H.shape, F.shape[:-2] + (3, 6))))
    Ha[..., :3] = H[..., :3] - H[..., 3:] @ F[..., 3:, :3] * (0.5 * period)
    return Ha


def bias_input_matrix(model: str) -> np.ndarray:
    """Gamma, shape (6, 6): effect of constant ENU biases ``[accel_n; gyro_n]`` on ``dx/dt``.

    A gyro bias drives ``phi' = -eps^n``; an accelerometer bias drives the velocity error
    (``+nabla^n`` for v_est - v_true, ``-nabla^n`` for the SE(3) error).
    """
    Gm = np.zeros((6, 6))
    Gm[:3, 3:] = -np.eye(3)
    Gm[3:, :3] = -np.eye(3) if model == "se3" else np.eye(3)
    return Gm


def apply_correction(model: str, C_est: np.ndarray, v_est: np.ndarray, x: np.ndarray,
                     turn_velocity: bool = False):
    """Feed the estimated error back into the state (exact exponential on SO(3)).

    Shapes: C_est (..., 3, 3), v_est (..., 3), x (..., 6). Returns the corrected
    ``(C_est, v_est)``; the error state is zero afterwards. ``turn_velocity`` (constant and
    conventional models): the velocity turns with the attitude correction before its own
    correction, so a velocity the base really has (sway) stays tied to the estimated frame
    and an attitude error shows in it as ``phi x v`` (zero on average) instead of as a
    constant ``phi x v(0)`` the model has no term for.
    """
    E = so3_exp(x[..., :3])
    C_new = E @ C_est
    if turn_velocity and model != "se3":
        v_new = (E @ v_est[..., None])[..., 0] - x[..., 3:]
    elif model == "se3":
        v_new = (E @ v_est[..., None])[..., 0] + x[..., 3:]
    else:
        v_new = v_est - x[..., 3:]
    return C_new, v_new
