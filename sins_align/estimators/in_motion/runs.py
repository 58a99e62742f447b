"""The closed-form sums of many runs of samples at once (numpy only).

:class:`~sins_align.estimators.in_motion.filter.InvariantEKF` propagates between
measurements in runs (the module docstring of ``filter.py`` gives the closed form of one run).
A run's sums depend on the samples and on the biases (and scale factors) they are corrected
with, not on the attitude or velocity. So the sums of every run up to the next few
measurements are computed here in one vectorised pass, at the biases of that moment (the
*linearisation point*); a measurement that changes the biases afterwards is taken into
account to first order when the run is applied (:func:`bias_corrected`), exactly as
pre-integration with bias Jacobians does (Forster et al.): the run's own transition
matrix is the Jacobian. The filter computes the sums anew (re-linearises) when the biases
have moved so far that the neglected second-order term could reach 1e-10 rad
(:data:`RELINEARIZE_ROTATION`).

Each sum is first taken in the frame of the first sample of the pass (prefix products and
cumulative sums over the whole pass) and then turned into the frame of its run's start;
inside a run the cumulative sums restart at zero, so no long sums are differenced. A short
pass of one filter (a live stream's rewind, up to :data:`SHORT_PASS` samples) is summed in
Python floats instead (:func:`short_run_sums`, the same sums to rounding): numpy's per-call
cost would outweigh its arithmetic there.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from sins_align.core.preint import prefix_rotations
from sins_align.core.earth import GRAVITY_PER_METRE
from sins_align.core.rotation import dcm_entries_from_quat, quat_from_rotvec, so3_exp_entries

__all__ = ["RunSums", "run_sums", "short_run_sums", "one_sample_sums", "one_sample_entries",
           "advance_navigation", "SHORT_PASS", "mm", "white_noise_rate", "RELINEARIZE_ROTATION",
           "RELINEARIZE_VELOCITY"]

#: largest rotation, rad, that a change of the gyro biases (or scale factors) since the
#: linearisation point may cause over one run before the sums are computed anew; the
#: first-order correction's error is of its square (1e-10 rad)
RELINEARIZE_ROTATION = 1e-5
#: the same for the velocity, m/s, that a change of the accelerometer biases may cause over
#: one run (the correction is exact in the accelerometer biases; this bounds the error of the
#: transition matrix, which stays at the linearisation point: 1e-4 relative)
RELINEARIZE_VELOCITY = 1e-4

_I3 = np.eye(3)
_P1, _P2 = [1, 2, 0], [2, 0, 1]

_SKEW = np.zeros((3, 9))                 # skew(v).ravel() = v @ _SKEW
for _i, _j, _k, _s in ((0, 1, 2, -1), (0, 2, 1, 1), (1, 0, 2, 1), (1, 2, 0, -1),
                       (2, 0, 1, -1), (2, 1, 0, 1)):
    _SKEW[_k, 3 * _i + _j] = _s

# Hamilton product of [x, y, z, w] quaternions: (p q) = (p @ _QMUL).reshape(4, 4) @ q
_QMUL = np.zeros((4, 4, 4))              # [j, i, k]: coefficient of p_j q_k in (p q)_i
for _i, _terms in enumerate((
        ((3, 0, 1), (0, 3, 1), (1, 2, 1), (2, 1, -1)),
        ((3, 1, 1), (0, 2, -1), (1, 3, 1), (2, 0, 1)),
        ((3, 2, 1), (0, 1, 1), (1, 0, -1), (2, 3, 1)),
        ((3, 3, 1), (0, 0, -1), (1, 1, -1), (2, 2, -1)))):
    for _j, _k, _s in _terms:
        _QMUL[_j, _i, _k] = _s
_QMUL = _QMUL.reshape(4, 16)

# DCM of a unit quaternion as a quadratic form: C.ravel() = (q q^T).ravel() @ _QDCM
_QDCM = np.zeros((4, 4, 9))
for _e, _terms in enumerate((
        ((3, 3, 1), (0, 0, 1), (1, 1, -1), (2, 2, -1)),      # C00 = w2 + x2 - y2 - z2
        ((0, 1, 2), (3, 2, -2)), ((0, 2, 2), (3, 1, 2)),
        ((0, 1, 2), (3, 2, 2)),
        ((3, 3, 1), (0, 0, -1), (1, 1, 1), (2, 2, -1)),
        ((1, 2, 2), (3, 0, -2)), ((0, 2, 2), (3, 1, -2)), ((1, 2, 2), (3, 0, 2)),
        ((3, 3, 1), (0, 0, -1), (1, 1, -1), (2, 2, 1)))):
    for _k, _l, _s in _terms:
        _QDCM[_k, _l, _e] += _s
_QDCM = _QDCM.reshape(16, 9)


def cross(a, b):
    """a x b over the last axis (numpy's np.cross costs tens of microseconds on arrays
    this small; this costs a few)."""
    return a[..., _P1] * b[..., _P2] - a[..., _P2] * b[..., _P1]


def skew(v):
    """(v x) for (..., 3) vectors: (..., 3, 3), as a product with a constant matrix."""
    return (v @ _SKEW).reshape(v.shape[:-1] + (3, 3))


def qmul(p, q):
    """Hamilton products p q of (..., 4) quaternions [x, y, z, w]."""
    L = (p @ _QMUL).reshape(p.shape[:-1] + (4, 4))
    return (L @ q[..., None])[..., 0]


def dcm(q):
    """DCM of (..., 4) unit quaternions [x, y, z, w]: (..., 3, 3)."""
    return ((q[..., :, None] * q[..., None, :]).reshape(q.shape[:-1] + (16,))
            @ _QDCM).reshape(q.shape[:-1] + (3, 3))


def mT(a):
    return np.swapaxes(a, -1, -2)


@dataclass
class RunSums:
    """The sums of R runs for K filters, each array (K, R, ...) (the run's start frame).

    T (R,) durations, s; packed (K, R, 36): the run's rotation Gm, S = sum R_j dt_j and
    M = sum (dV_j x) (S_j - R_j dt_j / 2) (row by row), V = sum dV_j, Vt = sum dV_j t_j
    (t_j: the middle of sample j from the run's start) and Pm = sum (V_{j-1} + dV_j / 2)
    dt_j (the integral of V), side by side (what :func:`advance_navigation` reads; the
    properties give each as an array); Q (K, R, n, n): the run's process noise; Sw, Mw and
    Sa: the scale-factor sums (None without those states); w_max, f_max: the largest
    corrected rate and specific force (for the re-linearisation test).
    """

    T: np.ndarray
    packed: np.ndarray
    Q: np.ndarray
    Sw: np.ndarray | None
    Mw: np.ndarray | None
    Sa: np.ndarray | None
    w_max: float
    f_max: float

    def _mat(self, i):
        return self.packed[..., i:i + 9].reshape(self.packed.shape[:-1] + (3, 3))

    Gm = property(lambda self: self._mat(0))
    S = property(lambda self: self._mat(9))
    M = property(lambda self: self._mat(18))
    V = property(lambda self: self.packed[..., 27:30])
    Vt = property(lambda self: self.packed[..., 30:33])
    Pm = property(lambda self: self.packed[..., 33:36])


def _within(cum, starts, run_id):
    """Inclusive cumulative sums restarted at each run's start (cum: along axis 1)."""
    z = np.zeros_like(cum[:, :1])
    base = np.concatenate([z, cum], axis=1)[:, starts]
    return cum - base[:, run_id]


def run_sums(dt, w, f, ends, noise, n: int, i_sf=None, i_sa=None) -> RunSums:
    """Sums of the runs ``[ends[r-1], ends[r])`` of samples (``ends`` increasing, the last
    = number of samples; ``ends[-1] == len(dt)``).

    dt (N,) s; w, f (K, N, 3): the bias-corrected rates (rad/s) and specific forces (m/s^2)
    of each filter; noise: the :class:`~sins_align.estimators.in_motion.filter.NoiseModel`;
    n: the error state's size; i_sf, i_sa: the slices of the scale-factor states or None.
    """
    dt = np.asarray(dt, dtype=float)
    ends = np.asarray(ends, dtype=np.intp)
    starts = np.concatenate(([0], ends[:-1]))
    R = len(ends)
    K = w.shape[0]
    run_id = np.repeat(np.arange(R), ends - starts)
    dtc = dt[None, :, None]
    rv = w * dtc
    G = np.stack(prefix_rotations(dt, w), -1)                       # (K, N, 4)
    ident = np.broadcast_to([0.0, 0.0, 0.0, 1.0], (K, 1, 4))
    Gprev = np.concatenate([ident, G[:, :-1]], 1)
    Rm = dcm(qmul(Gprev, quat_from_rotvec(0.5 * rv)))              # (K, N, 3, 3)
    qs = Gprev[:, starts]
    qe = G[:, ends - 1]
    qs = qs / np.linalg.norm(qs, axis=-1, keepdims=True)
    qe = qe / np.linalg.norm(qe, axis=-1, keepdims=True)
    Gs, Ge = dcm(qs), dcm(qe)                                        # (K, R, 3, 3)
    qs_conj = qs * np.array([-1.0, -1.0, -1.0, 1.0])
    Gm = dcm(qmul(qs_conj, qe))
    GsT, GeT = mT(Gs), mT(Ge)
    T = np.add.reduceat(dt, starts)
    # ---------------------------------------------------------------- the sums
    Rdt = Rm * dt[None, :, None, None]
    S_in = _within(np.cumsum(Rdt, axis=1), starts, run_id)
    dV = np.einsum("knij,knj->kni", Rm, f) * dtc
    V_in = _within(np.cumsum(dV, axis=1), starts, run_id)
    last = ends - 1
    Sg, Vg = S_in[:, last], V_in[:, last]
    dVx = skew(dV)
    Mg = np.add.reduceat(dVx @ (S_in - 0.5 * Rdt), starts, axis=1)
    t_in = _within(np.cumsum(dt)[None], starts, run_id)[0] - 0.5 * dt
    Vtg = np.add.reduceat(dV * t_in[None, :, None], starts, axis=1)
    Pmg = np.add.reduceat((V_in - 0.5 * dV) * dtc, starts, axis=1)
    D = Vg[:, run_id] - V_in                                        # (K, N, 3)
    Ag = np.add.reduceat(D * dtc, starts, axis=1)
    d2 = np.add.reduceat(np.einsum("kni,kni->kn", D, D) * dt[None], starts, axis=1)
    DD = np.add.reduceat(D[..., :, None] * (D * dtc)[..., None, :], starts, axis=1)
    Bg = d2[..., None, None] * _I3 - DD
    S = GsT @ Sg
    M = GsT @ Mg
    V = (GsT @ Vg[..., None])[..., 0]
    Vt = (GsT @ Vtg[..., None])[..., 0]
    Pm = (GsT @ Pmg[..., None])[..., 0]
    # ---------------------------------------------------------------- the noise
    Sw = Mw = Sa = None
    if i_sf is not None:
        Rrv = Rm * rv[:, :, None, :]
        Sw_in = _within(np.cumsum(Rrv, axis=1), starts, run_id)
        Sw = GsT @ Sw_in[:, last]
        Mw = GsT @ np.add.reduceat(dVx @ (Sw_in - 0.5 * Rrv), starts, axis=1)
    if i_sa is not None:
        Sa = GsT @ np.add.reduceat(Rm * (f * dtc)[:, :, None, :], starts, axis=1)
    # white noise after every sample, and the gyro's through the velocity increments
    qg = noise.gyro_arw ** 2
    Q = np.broadcast_to(white_noise_rate(noise, n) * T[:, None, None], (K, R, n, n)).copy()
    c = qg * (GeT @ skew(Ag) @ Ge)
    Q[..., 0:3, 3:6] = c
    Q[..., 3:6, 0:3] = mT(c)
    Q[..., 3:6, 3:6] += qg * (GeT @ Bg @ Ge)
    w_max = float(np.abs(w).max()) if w.size else 0.0
    f_max = float(np.abs(f).max()) if f.size else 0.0
    packed = np.concatenate([Gm.reshape(K, R, 9), S.reshape(K, R, 9), M.reshape(K, R, 9),
                             V, Vt, Pm], axis=-1)
    return RunSums(T, packed, Q, Sw, Mw, Sa, w_max, f_max)


#: longest pass of one filter whose sums :func:`short_run_sums` computes in floats; the
#: vectorised :func:`run_sums` costs some 400 us in numpy calls at any length, the floats
#: about 30 us plus 4-5 us a sample, so they break even near 150-200 samples (measured with
#: 12 and 18 states); 64 keeps a 2x margin
SHORT_PASS = 64


def short_run_sums(dt, w, f, ends, noise, n: int, i_sf=None, i_sa=None) -> RunSums:
    """:func:`run_sums` of a short pass of one filter (K == 1; w, f (1, N, 3)) in Python
    floats: the same RunSums, field by field, to rounding (a live stream's rewinds re-sum
    some ten samples, where numpy's per-call cost outweighs the arithmetic).

    Each run is summed in its own start frame (the rotation restarts at the identity), so
    the sums need no turning into it; the noise's D terms take a second pass over the run's
    velocity sums once its end is known, turned into the run's end frame (``Gamma^T (a x)
    Gamma = (Gamma^T a x)``)."""
    dts = dt.tolist() if isinstance(dt, np.ndarray) else [float(x) for x in dt]
    w = np.asarray(w, dtype=float)
    f = np.asarray(f, dtype=float)
    ws, fs = w[0].tolist(), f[0].tolist()
    gyro_scale, accel_scale = i_sf is not None, i_sa is not None
    packed, Ts, Cq, Bq, Swl, Mwl, Sal = [], [], [], [], [], [], []
    a = 0
    for e in ends:
        e = int(e)
        # the rotation from the run's start (x, y, z, w) and the running sums
        qx = qy = qz = 0.0
        qw = 1.0
        s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = 0.0                 # S
        m0 = m1 = m2 = m3 = m4 = m5 = m6 = m7 = m8 = 0.0                 # M
        Vx = Vy = Vz = 0.0
        tx = ty = tz = 0.0                                             # Vt
        px = py = pz = 0.0                                             # Pm
        u0 = u1 = u2 = u3 = u4 = u5 = u6 = u7 = u8 = 0.0                 # Sw
        k0 = k1 = k2 = k3 = k4 = k5 = k6 = k7 = k8 = 0.0                 # Mw
        a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = a8 = 0.0                 # Sa
        tc = 0.0
        vs = []
        for j in range(a, e):
            d = dts[j]
            wx, wy, wz = ws[j]
            fx, fy, fz = fs[j]
            rx, ry, rz = wx * d, wy * d, wz * d
            # h = exp(rv / 2) as a quaternion (half angle th / 4)
            t2 = 0.25 * (rx * rx + ry * ry + rz * rz)
            if t2 < 1e-8:
                kk = 0.5 - t2 / 48.0
                c = 1.0 + t2 * (-0.125 + t2 / 384.0)
            else:
                t = math.sqrt(t2)
                kk = math.sin(0.5 * t) / t
                c = math.cos(0.5 * t)
            kk *= 0.5
            hx, hy, hz = kk * rx, kk * ry, kk * rz
            # the middle of the sample: q h; its end: q h h
            mx = c * qx + qw * hx + qy * hz - qz * hy
            my = c * qy + qw * hy + qz * hx - qx * hz
            mz = c * qz + qw * hz + qx * hy - qy * hx
            mw = c * qw - qx * hx - qy * hy - qz * hz
            qx = c * mx + mw * hx + my * hz - mz * hy
            qy = c * my + mw * hy + mz * hx - mx * hz
            qz = c * mz + mw * hz + mx * hy - my * hx
            qw = c * mw - mx * hx - my * hy - mz * hz
            r0, r1, r2, r3, r4, r5, r6, r7, r8 = dcm_entries_from_quat(mx, my, mz, mw)
            # S += R dt; dV = R f dt; M += (dV x) (S - R dt / 2)
            p0, p1, p2, p3, p4, p5, p6, p7, p8 = (r0 * d, r1 * d, r2 * d, r3 * d, r4 * d,
                                                  r5 * d, r6 * d, r7 * d, r8 * d)
            s0 += p0; s1 += p1; s2 += p2; s3 += p3; s4 += p4          # noqa: E702
            s5 += p5; s6 += p6; s7 += p7; s8 += p8                    # noqa: E702
            dx = (r0 * fx + r1 * fy + r2 * fz) * d
            dy = (r3 * fx + r4 * fy + r5 * fz) * d
            dz = (r6 * fx + r7 * fy + r8 * fz) * d
            b0, b1, b2 = s0 - 0.5 * p0, s1 - 0.5 * p1, s2 - 0.5 * p2
            b3, b4, b5 = s3 - 0.5 * p3, s4 - 0.5 * p4, s5 - 0.5 * p5
            b6, b7, b8 = s6 - 0.5 * p6, s7 - 0.5 * p7, s8 - 0.5 * p8
            m0 += dy * b6 - dz * b3; m1 += dy * b7 - dz * b4; m2 += dy * b8 - dz * b5  # noqa
            m3 += dz * b0 - dx * b6; m4 += dz * b1 - dx * b7; m5 += dz * b2 - dx * b8  # noqa
            m6 += dx * b3 - dy * b0; m7 += dx * b4 - dy * b1; m8 += dx * b5 - dy * b2  # noqa
            # V, Vt = sum dV t (t: the sample's middle), Pm = sum (V_{j-1} + dV / 2) dt
            tc += d
            tm = tc - 0.5 * d
            tx += dx * tm; ty += dy * tm; tz += dz * tm               # noqa: E702
            hd = 0.5 * d
            px += Vx * d + dx * hd; py += Vy * d + dy * hd; pz += Vz * d + dz * hd  # noqa
            Vx += dx; Vy += dy; Vz += dz                              # noqa: E702
            vs.append((d, Vx, Vy, Vz))
            if gyro_scale:
                # Sw += R (rv) (columns scaled); Mw += (dV x) (Sw - R (rv) / 2)
                p0, p1, p2, p3, p4, p5, p6, p7, p8 = (r0 * rx, r1 * ry, r2 * rz, r3 * rx,
                                                      r4 * ry, r5 * rz, r6 * rx, r7 * ry,
                                                      r8 * rz)
                u0 += p0; u1 += p1; u2 += p2; u3 += p3; u4 += p4      # noqa: E702
                u5 += p5; u6 += p6; u7 += p7; u8 += p8                # noqa: E702
                b0, b1, b2 = u0 - 0.5 * p0, u1 - 0.5 * p1, u2 - 0.5 * p2
                b3, b4, b5 = u3 - 0.5 * p3, u4 - 0.5 * p4, u5 - 0.5 * p5
                b6, b7, b8 = u6 - 0.5 * p6, u7 - 0.5 * p7, u8 - 0.5 * p8
                k0 += dy * b6 - dz * b3; k1 += dy * b7 - dz * b4; k2 += dy * b8 - dz * b5  # noqa
                k3 += dz * b0 - dx * b6; k4 += dz * b1 - dx * b7; k5 += dz * b2 - dx * b8  # noqa
                k6 += dx * b3 - dy * b0; k7 += dx * b4 - dy * b1; k8 += dx * b5 - dy * b2  # noqa
            if accel_scale:
                ex, ey, ez = fx * d, fy * d, fz * d
                a0 += r0 * ex; a1 += r1 * ey; a2 += r2 * ez           # noqa: E702
                a3 += r3 * ex; a4 += r4 * ey; a5 += r5 * ez           # noqa: E702
                a6 += r6 * ex; a7 += r7 * ey; a8 += r8 * ez           # noqa: E702
        # the run's rotation Gm (normalised) and the noise's D terms in its end frame
        g0, g1, g2, g3, g4, g5, g6, g7, g8 = dcm_entries_from_quat(qx, qy, qz, qw)
        ax = ay = az = d2 = cxx = cxy = cxz = cyy = cyz = czz = 0.0
        for d, x, y, z in vs:
            x, y, z = Vx - x, Vy - y, Vz - z                       # D_j, start frame
            ex = g0 * x + g3 * y + g6 * z                          # Gm^T D_j
            ey = g1 * x + g4 * y + g7 * z
            ez = g2 * x + g5 * y + g8 * z
            ax += ex * d; ay += ey * d; az += ez * d                  # noqa: E702
            xd, yd, zd = ex * d, ey * d, ez * d
            cxx += ex * xd; cxy += ex * yd; cxz += ex * zd            # noqa: E702
            cyy += ey * yd; cyz += ey * zd; czz += ez * zd            # noqa: E702
        d2 = cxx + cyy + czz
        Cq.append((0.0, -az, ay, az, 0.0, -ax, -ay, ax, 0.0))
        Bq.append((d2 - cxx, -cxy, -cxz, -cxy, d2 - cyy, -cyz, -cxz, -cyz, d2 - czz))
        Ts.append(tc)
        packed.append((g0, g1, g2, g3, g4, g5, g6, g7, g8, s0, s1, s2, s3, s4, s5, s6, s7, s8,
                       m0, m1, m2, m3, m4, m5, m6, m7, m8, Vx, Vy, Vz, tx, ty, tz, px, py, pz))
        if gyro_scale:
            Swl.append((u0, u1, u2, u3, u4, u5, u6, u7, u8))
            Mwl.append((k0, k1, k2, k3, k4, k5, k6, k7, k8))
        if accel_scale:
            Sal.append((a0, a1, a2, a3, a4, a5, a6, a7, a8))
        a = e
    R = len(Ts)
    T = np.array(Ts)
    qg = noise.gyro_arw ** 2
    Q = white_noise_rate(noise, n) * T[:, None, None]
    c = qg * np.array(Cq).reshape(R, 3, 3)
    Q[:, 0:3, 3:6] = c
    Q[:, 3:6, 0:3] = mT(c)
    Q[:, 3:6, 3:6] += qg * np.array(Bq).reshape(R, 3, 3)

    def mats(rows):
        return np.array(rows).reshape(1, R, 3, 3)

    return RunSums(T, np.array(packed).reshape(1, R, 36), Q[None],
                   mats(Swl) if gyro_scale else None, mats(Mwl) if gyro_scale else None,
                   mats(Sal) if accel_scale else None,
                   float(np.abs(w).max()) if w.size else 0.0,
                   float(np.abs(f).max()) if f.size else 0.0)


@functools.lru_cache(maxsize=16)
def white_noise_rate(noise, n: int) -> np.ndarray:
    """(n, n) covariance per second of the white noises on phi, nu and the biases (read
    only)."""
    q = np.zeros(n)
    q[0:3], q[3:6] = noise.gyro_arw ** 2, noise.accel_vrw ** 2
    q[6:9], q[9:12] = noise.gyro_bias_walk ** 2, noise.accel_bias_walk ** 2
    out = np.diag(q)
    out.flags.writeable = False
    return out


def one_sample_sums(dt: float, w, f, noise, n: int, i_sf=None, i_sa=None) -> RunSums:
    """:func:`run_sums` of a run of one sample (a live stream's usual run), in scalar
    arithmetic: the same sums (R_1 = exp(w dt / 2), S = R_1 dt, dV = R_1 f dt, M =
    (dV x) R_1 dt / 2, Vt = Pm = dV dt / 2, no D terms in the noise), without the fixed
    cost of some fifty numpy calls on one-sample arrays. dt float; w, f (K, 3)."""
    dt = float(dt)
    K = len(w)
    packed, Swl, Mwl, Sal, w_all, f_all = [], [], [], [], [], []
    for wk, fk in zip(np.asarray(w, float).tolist(), np.asarray(f, float).tolist()):
        w_all += wk
        f_all += fk
        p, Sw, Mw, Sa = one_sample_entries(dt, wk, fk, i_sf is not None, i_sa is not None)
        packed.append(p)
        Swl.append(Sw)
        Mwl.append(Mw)
        Sal.append(Sa)

    def arr(rows, shape):
        return np.array(rows).reshape((K, 1) + shape)

    Q = (white_noise_rate(noise, n) * dt)[None, None]
    if K > 1:
        Q = np.broadcast_to(Q, (K, 1, n, n))
    return RunSums(np.array([dt]), arr(packed, (36,)), Q,
                   arr(Swl, (3, 3)) if i_sf is not None else None,
                   arr(Mwl, (3, 3)) if i_sf is not None else None,
                   arr(Sal, (3, 3)) if i_sa is not None else None,
                   max(map(abs, w_all)), max(map(abs, f_all)))


def one_sample_entries(dt: float, w, f, gyro_scale: bool = False, accel_scale: bool = False):
    """One filter's sums of a one-sample run in floats (what :func:`one_sample_sums` gives
    each filter): dt float; w, f 3 floats each. Returns (the 36 packed floats, Sw, Mw, Sa:
    9 floats each, or None without the scale-factor states)."""
    wx, wy, wz = w
    fx, fy, fz = f
    h = so3_exp_entries(0.5 * wx * dt, 0.5 * wy * dt, 0.5 * wz * dt)
    Gm = so3_exp_entries(wx * dt, wy * dt, wz * dt)
    S = [x * dt for x in h]
    dx, dy, dz = (c * dt for c in _mv(h, fx, fy, fz))
    Hh = [0.5 * x for x in S]                              # R_1 dt / 2
    Dx = (0.0, -dz, dy, dz, 0.0, -dx, -dy, dx, 0.0)        # (dV x)
    M = _mm(Dx, Hh)
    hd = 0.5 * dt
    packed = list(Gm) + S + M + [dx, dy, dz] + [dx * hd, dy * hd, dz * hd] * 2
    Sw = Mw = Sa = None
    if gyro_scale:
        rv = (wx * dt, wy * dt, wz * dt)
        Sw = [h[3 * i + j] * rv[j] for i in range(3) for j in range(3)]
        Mw = _mm(Dx, [0.5 * x for x in Sw])
    if accel_scale:
        fd = (fx * dt, fy * dt, fz * dt)
        Sa = [h[3 * i + j] * fd[j] for i in range(3) for j in range(3)]
    return packed, Sw, Mw, Sa


# ------------------------------------------------------------------ one filter, one run
# Scalar arithmetic on 3-vectors and row-major 3x3 lists: on arrays this small each numpy
# call costs a microsecond or more, a Python float operation some tens of nanoseconds.
def _mm(a, b):
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    return [a0 * b0 + a1 * b3 + a2 * b6, a0 * b1 + a1 * b4 + a2 * b7,
            a0 * b2 + a1 * b5 + a2 * b8, a3 * b0 + a4 * b3 + a5 * b6,
            a3 * b1 + a4 * b4 + a5 * b7, a3 * b2 + a4 * b5 + a5 * b8,
            a6 * b0 + a7 * b3 + a8 * b6, a6 * b1 + a7 * b4 + a8 * b7,
            a6 * b2 + a7 * b5 + a8 * b8]


#: the product of two row-major 3x3 lists (9 floats each), a list of 9 floats
mm = _mm


def _mv(a, x, y, z):
    return (a[0] * x + a[1] * y + a[2] * z, a[3] * x + a[4] * y + a[5] * z,
            a[6] * x + a[7] * y + a[8] * z)


def advance_navigation(C, v, lat, lon, h, sums, T, dbg, dba, earth, dsf=None, Sw=None,
                       Mw=None, dsa=None, Sa=None):
    """One filter's navigation state over one run (scalar arithmetic).

    C: 9 floats (C_b^n row by row); v: 3 floats (ENU, m/s); lat, lon (rad), h (m); sums:
    the run's 36 packed floats (:class:`RunSums`), at the linearisation point; T: s;
    dbg, dba: 3 floats each, the biases now minus those of the linearisation point (and
    dsf, dsa with the scale-factor sums Sw, Mw, Sa, 9 floats each, when those are
    estimated); earth: (w_ie north, w_ie up, 1 / (R_M + h), 1 / (R_N + h), tan lat,
    1 / cos lat, gravity, h) of the pass.

    The change of the biases since the linearisation point is applied to first order: a
    rotation exp(-phi x), phi = S dbg, at the start of the run and a velocity change
    M dbg - S dba (start axes). Then the strapdown velocity, position and attitude: the
    specific force in the start's navigation axes turned by the frame's rotation over the
    run, gravity (normal gravity at the pass's height, corrected by its gradient), Coriolis
    and transport rate from the integral of the velocity, and the frame's rotation at the
    run's mean velocity. Returns (C1, v1, lat1, lon1, h1, Gb, Vb): C1 and the run's
    bias-corrected rotation Gb 9 floats, v1 and its corrected velocity sum Vb 3 floats.
    """
    Gm, S, M = sums[0:9], sums[9:18], sums[18:27]
    dgx, dgy, dgz = dbg
    dax, day, daz = dba
    px, py, pz = _mv(S, dgx, dgy, dgz)
    m1 = _mv(M, dgx, dgy, dgz)
    s1 = _mv(S, dax, day, daz)
    Vx, Vy, Vz = sums[27] + m1[0] - s1[0], sums[28] + m1[1] - s1[1], sums[29] + m1[2] - s1[2]
    if dsf is not None:
        a = _mv(Sw, *dsf)
        b = _mv(Mw, *dsf)
        px, py, pz = px + a[0], py + a[1], pz + a[2]
        Vx, Vy, Vz = Vx + b[0], Vy + b[1], Vz + b[2]
    if dsa is not None:
        a = _mv(Sa, *dsa)
        Vx, Vy, Vz = Vx - a[0], Vy - a[1], Vz - a[2]
    if px == 0.0 and py == 0.0 and pz == 0.0:     # (at the linearisation point: exp(0) = I)
        Gb = list(Gm)
    else:
        Gb = _mm(so3_exp_entries(-px, -py, -pz), Gm)
    wn, wu, irm, irn, tanl, icos, g_c, h_c = earth
    vx, vy, vz = v
    x0, y0, z0 = _mv(C, Vx, Vy, Vz)                      # C0 V
    x1, y1, z1 = _mv(C, sums[30], sums[31], sums[32])    # C0 Vt
    x2, y2, z2 = _mv(C, sums[33], sums[34], sums[35])    # C0 Pm
    # the frame's rate at the start: Earth rate and transport rate
    ax, ay, az = -vy * irm, wn + vx * irn, wu + vx * irn * tanl
    g0 = g_c - GRAVITY_PER_METRE * (h - h_c)
    # specific-force increment in navigation axes, the frame turning under it
    dx = x0 - (ay * z1 - az * y1)
    dy = y0 - (az * x1 - ax * z1)
    dz = z0 - (ax * y1 - ay * x1) - g0 * T
    # the integral of the velocity over the run (the frame's rotation within the run
    # changes it by less than 1e-8 m), then Coriolis (2 w_ie + w_en) and gravity's gradient
    ix, iy, iz = vx * T + x2, vy * T + y2, vz * T + z2 - 0.5 * g0 * T * T
    ox, oy, oz = ax, ay + wn, az + wu
    cx = -(oy * iz - oz * iy)
    cy = -(oz * ix - ox * iz)
    cz = -(ox * iy - oy * ix) + GRAVITY_PER_METRE * 0.5 * iz * T
    v1 = [vx + dx + cx, vy + dy + cy, vz + dz + cz]
    ix, iy, iz = ix + 0.5 * T * cx, iy + 0.5 * T * cy, iz + 0.5 * T * cz
    # the frame's rotation over the run, at the mean velocity
    mx, my = ix / T, iy / T
    Ew = so3_exp_entries(my * irm * T, -(wn + mx * irn) * T, -(wu + mx * irn * tanl) * T)
    C1 = _mm(_mm(Ew, C), Gb)
    return C1, v1, lat + iy * irm, lon + ix * irn * icos, h + iz, Gb, (Vx, Vy, Vz)
