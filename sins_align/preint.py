"""Vectorised pre-integration of IMU samples over update intervals (the fast path).

Between two Kalman updates the damped mechanization (paper eq. 1) has no feedback, so the
state at the end of an interval follows in closed form from attitude-independent sums:

    C_j = E(s_j) C_0 Q_j            Q_j = exp(w_1 dt) ... exp(w_j dt)   (prefix product)
    v_j = v_0 + sum_{i<=j} E(s_i) C_0 u_i + g s_j,   u_i = Q_i f_i dt

with ``E(s) = exp(-(w_ie x) s) = I + sin(W s) K + (1 - cos(W s)) K^2`` (K = skew of the unit
vector -w_ie/|w_ie|), s_j = j dt. So
``sum_i E(s_i) C_0 u_i = C_0 A0 + K C_0 Aa + K^2 C_0 Ab`` with the three sums
``A0 = sum u_i, Aa = sum sin(W s_i) u_i, Ab = sum (1 - cos(W s_i)) u_i``, and the mean velocity
over the interval needs the same sums weighted by (m - i + 1) dt. The prefix products are a
Hillis-Steele scan over all intervals at once; everything is numpy over whole arrays.
"""
from __future__ import annotations

import numpy as np

from .rotation import dcm_from_quat


def _qmul(a, b):
    """Hamilton product of component tuples (x, y, z, w) of equal-shape arrays."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def _qexp(rv):
    """Quaternion components of exp(rotvec), rotvec (..., 3); exact (series below 1e-4 rad)."""
    x, y, z = rv[..., 0], rv[..., 1], rv[..., 2]
    th2 = x * x + y * y + z * z
    th = np.sqrt(th2)
    small = th < 1e-4
    ths = np.where(small, 1.0, th)
    k = np.where(small, 0.5 - th2 / 48.0, np.sin(0.5 * ths) / ths)
    return (k * x, k * y, k * z, np.cos(0.5 * th))


def _qrot(q, v):
    """Rotate vectors v (..., 3) by quaternion components q: returns (..., 3)."""
    qx, qy, qz, qw = q
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    tx = 2.0 * (qy * vz - qz * vy)
    ty = 2.0 * (qz * vx - qx * vz)
    tz = 2.0 * (qx * vy - qy * vx)
    return np.stack([vx + qw * tx + (qy * tz - qz * ty),
                     vy + qw * ty + (qz * tx - qx * tz),
                     vz + qw * tz + (qx * ty - qy * tx)], axis=-1)


def prefix_rotations(dt, w: np.ndarray) -> tuple:
    """Inclusive prefix products of exp(w_j dt) along axis 1, quaternion components.

    Parameters
    ----------
    dt : float or ndarray broadcastable to w[..., 0], s.
    w : ndarray (S, L, ..., 3) rad/s — padded with zeros past each interval's end.
    """
    q = _qexp(w * np.asarray(dt)[..., None])
    L = w.shape[1]
    d = 1
    while d < L:
        prod = _qmul(tuple(c[:, :-d] for c in q), tuple(c[:, d:] for c in q))
        for c, p in zip(q, prod):
            c[:, d:] = p
        d *= 2
    return q


def preintegrate(dt, w: np.ndarray, f: np.ndarray, lengths: np.ndarray,
                 w_ie_mag: float, mean_weights: bool):
    """Attitude-independent sums of each interval.

    Parameters
    ----------
    dt : float, or ndarray (T,) — s, the sample interval(s).
    w, f : ndarray (T, N, 3) — rates (rad/s) and specific forces (m/s^2), the intervals
        laid end to end.
    lengths : ndarray (S,) int — samples per interval (sum = T).
    w_ie_mag : float, rad/s — Earth rate magnitude.
    mean_weights : also return the sums weighted by the time left in the interval, for
        the interval's mean velocity.

    Returns
    -------
    dcm_end : ndarray (S, N, 3, 3) — Q_m as a DCM (body rotation over the interval).
    A : ndarray (S, 3, N, 3) — [A0, Aa, Ab] (m/s).
    V : ndarray (S, 3, N, 3) or None — the mean-velocity sums [V0, Va, Vb] (m).
    seg_t : ndarray (S,) — duration of each interval, s.
    s_dt : ndarray (S,) — sum over the interval of (time since its start) x dt, s^2.
    """
    S, L = len(lengths), int(lengths.max())
    T, N = w.shape[0], w.shape[1]
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    pos = np.arange(L)
    idx = starts[:, None] + pos[None, :]
    valid = pos[None, :] < lengths[:, None]
    idx = np.where(valid, idx, T)                     # T = padding row
    wp = np.concatenate([w, np.zeros((1, N, 3))])[idx]       # (S, L, N, 3)
    fp = np.concatenate([f, np.zeros((1, N, 3))])[idx]
    if np.ndim(dt) == 0:
        dtp = np.where(valid, float(dt), 0.0)
    else:
        dtp = np.concatenate([np.asarray(dt, dtype=float), [0.0]])[idx] * valid
    q = prefix_rotations(dtp[:, :, None], wp)
    u = _qrot(q, fp) * dtp[:, :, None, None]          # (S, L, N, 3)
    s = np.cumsum(dtp, axis=1)                        # time since the interval's start
    ws = np.stack([np.ones_like(s), np.sin(w_ie_mag * s), 1.0 - np.cos(w_ie_mag * s)])
    A = np.einsum("ksl,slnj->sknj", ws, u)
    seg_t = s[:, -1]
    V = None
    if mean_weights:
        c = (seg_t[:, None] - s + dtp) * valid        # time from each sample to the end
        V = np.einsum("ksl,sl,slnj->sknj", ws, c, u)
    last = (np.arange(S), lengths - 1)
    dcm_end = dcm_from_quat(np.stack([comp[last] for comp in q], axis=-1))
    return dcm_end, A, V, seg_t, (s * dtp).sum(axis=1)


def total_rotation(dt, w: np.ndarray) -> np.ndarray:
    """Quaternion [x, y, z, w] of exp(w_1 dt_1) ... exp(w_T dt_T), w (T, 3): a pairwise
    product tree, about 2T quaternion products instead of the prefix scan's T log T."""
    q = np.stack(_qexp(w * np.asarray(dt)[..., None]), axis=-1)
    while len(q) > 1:
        if len(q) % 2:
            q = np.concatenate([q, [[0.0, 0.0, 0.0, 1.0]]])
        a, b = q[0::2], q[1::2]
        q = np.stack(_qmul(tuple(a.T), tuple(b.T)), axis=-1)
    return q[0]


def open_loop_velocity(dt: np.ndarray, w: np.ndarray, f: np.ndarray, C0: np.ndarray,
                       w_ie: np.ndarray, g_n: np.ndarray) -> np.ndarray:
    """Velocity of the damped mechanization without feedback, at every sample.

    Parameters
    ----------
    dt : ndarray (T,) s ; w, f : ndarray (T, N, 3) ; C0 : ndarray (N, 3, 3) ;
    w_ie, g_n : ndarray (3,) — Earth rate and gravity in ENU.

    Returns
    -------
    v : ndarray (T, N, 3), m/s ENU.
    """
    q = prefix_rotations(dt[None, :, None], w[None])
    q = tuple(c[0] for c in q)
    u = _qrot(q, f) * dt[:, None, None]                # (T, N, 3) body frame at start
    s = np.cumsum(dt)
    a = np.einsum("nij,tnj->tni", C0, u)
    W = np.linalg.norm(w_ie)
    K = _unit_skew(-w_ie / W)
    sa, sb = np.sin(W * s)[:, None, None], (1.0 - np.cos(W * s))[:, None, None]
    Ka = a @ K.T
    inc = a + sa * Ka + sb * (Ka @ K.T)
    return np.cumsum(inc, axis=0) + s[:, None, None] * g_n


def _unit_skew(k):
    return np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])


def earth_poly(w_ie: np.ndarray):
    """K with ``exp(-(w_ie x) s) = I + sin(W s) K + (1 - cos(W s)) K^2``, and W = |w_ie|."""
    W = float(np.linalg.norm(w_ie))
    return _unit_skew(-w_ie / W), W
