"""Vectorised pre-integration of IMU samples over update intervals (the fast path).

Between two Kalman updates the damped mechanization (paper eq. 1) has no feedback, so the
state at the end of an interval follows in closed form from attitude-independent sums:

    C_j = E(s_j) C_0 Q_j            Q_j = exp(w_1 dt) ... exp(w_j dt)   (prefix product)
    v_j = v_0 + sum_{i<=j} E(s_i) C_0 u_i + g s_j,   u_i = Q_i f_i dt

with ``E(s) = exp(-(w_ie x) s) = I + sin(W s) K + (1 - cos(W s)) K^2`` (K = skew of the unit
vector -w_ie/|w_ie|), s_j = j dt. So
``sum_i E(s_i) C_0 u_i = C_0 A0 + K C_0 Aa + K^2 C_0 Ab`` with the three sums
``A0 = sum u_i, Aa = sum sin(W s_i) u_i, Ab = sum (1 - cos(W s_i)) u_i``, and the mean velocity
over the interval needs the same sums weighted by (m - i + 1) dt.

How it is computed: intervals of equal length are reshaped (not copied) into (intervals,
samples, runs), in pieces small enough that every scratch array stays in cache; the arrays
are component-major (one array per quaternion or vector component). The prefix products
run position by position, each step vectorised over all intervals and runs of the piece
(a running product, so only step-sized scratch arrays exist); long intervals with few runs
use a two-level scan instead, and a Hillis-Steele scan is the fallback when a step would be
too small to pay numpy's per-call cost. The exponential of a gyro increment is a Taylor
polynomial (exact to double precision below 1e-2 rad; the closed forms above that).
"""
from __future__ import annotations

import functools
import math

import numpy as np

from sins_align.core.rotation import dcm_entries_from_quat, horner


def _qmul(a, b):
    """Hamilton product of component tuples (x, y, z, w) of equal-shape arrays."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def _qexp(rv):
    """Quaternion components of exp(rotvec), rotvec (..., 3); exact at every angle."""
    return _qexp_c(rv[..., 0].copy(), rv[..., 1].copy(), rv[..., 2].copy())


#: Taylor coefficients in t^2 of sin(t/2)/t and cos(t/2)
_SIN_HALF = (0.5, -1.0 / 48.0, 1.0 / 3840.0, -1.0 / 645120.0, 1.0 / 185794560.0)
_COS_HALF = (1.0, -1.0 / 8.0, 1.0 / 384.0, -1.0 / 46080.0, 1.0 / 10321920.0)


def _qexp_c(ax, ay, az):
    """Quaternion components of exp(a) from component arrays, overwriting ax, ay, az.

    When every angle is below 1e-2 rad (IMU increments always are) the coefficients are
    Taylor polynomials in t^2, with as many terms (1 to 4) as the largest angle needs for
    the first omitted term to stay below 1e-20: exact to double precision, with no
    sqrt / sin / cos. Otherwise the closed forms (series below 1e-4 rad).
    """
    th2 = ax * ax
    th2 += ay * ay
    th2 += az * az
    top = float(th2.max()) if th2.size else 0.0
    if top < 1e-4:
        n = next(n for n in range(1, 5) if top ** n * abs(_COS_HALF[n]) < 1e-20)
        k, c = horner(th2, _SIN_HALF[:n]), horner(th2, _COS_HALF[:n])
    else:
        th = np.sqrt(th2)
        small = th < 1e-4
        ths = np.where(small, 1.0, th)
        k = np.where(small, 0.5 - th2 / 48.0, np.sin(0.5 * ths) / ths)
        c = np.cos(0.5 * th)
    ax *= k
    ay *= k
    az *= k
    return (ax, ay, az, c)


def _qmul_into(a, b, out, tmp):
    """Hamilton product a b of quaternion components into the arrays ``out`` (x, y, z, w),
    with one scratch array: no allocation (out must not alias a or b)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    ox, oy, oz, ow = out
    mul = np.multiply
    mul(aw, bx, out=ox); mul(ax, bw, out=tmp); ox += tmp                # noqa: E702
    mul(ay, bz, out=tmp); ox += tmp; mul(az, by, out=tmp); ox -= tmp      # noqa: E702
    mul(aw, by, out=oy); mul(ax, bz, out=tmp); oy -= tmp                # noqa: E702
    mul(ay, bw, out=tmp); oy += tmp; mul(az, bx, out=tmp); oy += tmp      # noqa: E702
    mul(aw, bz, out=oz); mul(ax, by, out=tmp); oz += tmp                # noqa: E702
    mul(ay, bx, out=tmp); oz -= tmp; mul(az, bw, out=tmp); oz += tmp      # noqa: E702
    mul(aw, bw, out=ow); mul(ax, bx, out=tmp); ow -= tmp                # noqa: E702
    mul(ay, by, out=tmp); ow -= tmp; mul(az, bz, out=tmp); ow -= tmp      # noqa: E702


def rotate_vectors(q, v):
    """Rotate vectors v (..., 3) by unit quaternion components q = (x, y, z, w), each of
    v's shape without its last axis: returns a new (..., 3) array."""
    out = np.moveaxis(np.array(v, dtype=float), -1, 0)
    _qrot_c(q, out)
    return np.moveaxis(out, 0, -1)


def _qrot_c(q, v, buf=None):
    """Rotate component vectors ``v = (vx, vy, vz)`` by quaternion components, in place
    (``buf``: four scratch arrays of v's shape, so that nothing is allocated)."""
    qx, qy, qz, qw = q
    vx, vy, vz = v
    tx, ty, tz, tmp = buf if buf is not None else [np.empty_like(vx) for _ in range(4)]
    mul = np.multiply
    for t, a, b, pa, pb in ((tx, qy, qz, vz, vy), (ty, qz, qx, vx, vz), (tz, qx, qy, vy, vx)):
        mul(a, pa, out=t)                                    # t = 2 q x v
        mul(b, pb, out=tmp)
        t -= tmp
        t *= 2.0
    for o, t, a, b, pa, pb in ((vx, tx, qy, qz, tz, ty), (vy, ty, qz, qx, tx, tz),
                               (vz, tz, qx, qy, ty, tx)):
        mul(qw, t, out=tmp)                                  # v += w t + q x t
        o += tmp
        mul(a, pa, out=tmp)
        o += tmp
        mul(b, pb, out=tmp)
        o -= tmp


def _scan(q, v=None):
    """Inclusive prefix products along axis 1 of quaternion components (S, L, ...), in
    place, and the vectors ``v`` (component arrays of the same shape) rotated by them.

    One position after the other (each step vectorised over the other axes, scratch
    arrays reused); when the steps are too small to pay numpy's per-call cost, a two-level
    scan (L = m1 m2 with a divisor near sqrt L) or, failing a divisor, a Hillis-Steele scan
    (log2 L steps over whole arrays)."""
    x = q[0]
    L, width = x.shape[1], x.size // max(x.shape[1], 1)
    if L >= 16 and width < 1000 and all(c.flags.c_contiguous for c in q):
        m2 = _near_sqrt_divisor(L)
        if m2:
            _two_level_scan(q, m2)
            if v is not None:
                _qrot_c(q, v)
            return
    if L > 2 and L * (1000 + width) > 1.5 * math.log2(L) * (1000 + L * width):
        d = 1
        while d < L:
            prod = _qmul(tuple(c[:, :-d] for c in q), tuple(c[:, d:] for c in q))
            for c, p in zip(q, prod):
                c[:, d:] = p
            d *= 2
        if v is not None:
            _qrot_c(q, v)
        return
    x, y, z, w = q
    o = [np.empty_like(x[:, 0]) for _ in range(5)]
    tmp = o.pop()
    buf = [np.empty_like(x[:, 0]) for _ in range(3)] + [tmp]
    for j in range(x.shape[1]):
        bx, by, bz, bw = x[:, j], y[:, j], z[:, j], w[:, j]
        if j:
            _qmul_into((x[:, j - 1], y[:, j - 1], z[:, j - 1], w[:, j - 1]),
                       (bx, by, bz, bw), o, tmp)
            bx[...], by[...], bz[...], bw[...] = o
        if v is not None:
            _qrot_c((bx, by, bz, bw), tuple(c[:, j] for c in v), buf)


@functools.lru_cache(maxsize=64)
def _near_sqrt_divisor(L: int) -> int:
    """The divisor d of L (1 < d < L) with d^2 nearest L, the smaller on a tie; 0 when L is
    prime. Divisors come in pairs (d, L / d) with d <= sqrt(L): O(sqrt L) steps."""
    best = None
    for d in range(2, math.isqrt(L) + 1):
        if L % d == 0:
            for e in (d, L // d):
                k = (abs(e * e - L), e)
                if best is None or k < best:
                    best = k
    return 0 if best is None else best[1]


def _two_level_scan(q, m2: int):
    """Prefix products along axis 1 (length L = m1 m2) of contiguous components: scans
    inside the m1 sub-blocks of m2 (one long step axis of S m1 rows), a scan over the
    sub-block totals, then each sub-block times the product of the ones before it."""
    S, L, rest = q[0].shape[0], q[0].shape[1], q[0].shape[2:]
    m1 = L // m2
    _scan(tuple(c.reshape((S * m1, m2) + rest) for c in q))
    blocks = [c.reshape((S, m1, m2) + rest) for c in q]
    tot = tuple(np.ascontiguousarray(b[:, :, -1]) for b in blocks)
    _scan(tot)
    prod = _qmul(tuple(t[:, :-1, None] for t in tot), tuple(b[:, 1:] for b in blocks))
    for b, p in zip(blocks, prod):
        b[:, 1:] = p


def prefix_rotations(dt, w: np.ndarray) -> tuple:
    """Inclusive prefix products of exp(w_j dt) along axis 1, quaternion components.

    Parameters
    ----------
    dt : float or ndarray broadcastable to w[..., 0], s.
    w : ndarray (S, L, ..., 3) rad/s — padded with zeros past each interval's end.
    """
    q = _qexp(w * np.asarray(dt)[..., None])
    _scan(q)
    return q


def prefix_rotations_components(rx, ry, rz) -> tuple:
    """:func:`prefix_rotations` of rotation increments given component-major: ``rx, ry, rz``
    (equal C-contiguous shapes (S, L, ...), rad; overwritten) are exp'd and their inclusive
    prefix products along axis 1 returned as quaternion components (x, y, z, w)."""
    q = _qexp_c(rx, ry, rz)
    _scan(q)
    return q


def rotate_components(q, v) -> None:
    """Rotate component vectors ``v = (vx, vy, vz)`` by unit quaternion components
    ``q = (x, y, z, w)`` of the same shape, in place."""
    _qrot_c(q, v)


#: Elements per sample position in one piece of :func:`preintegrate`: the scratch arrays
#: stay in cache and below malloc's mmap threshold (bigger ones cost page faults).
_PIECE = 1 << 13


def _weights(dt, s, seg_t, mean_weights: bool, w_ie_mag: float) -> list:
    """The interval weights of the velocity sums: 1, sin(W s), 1 - cos(W s), and the same
    times the time from each sample to the end of the interval (mean velocity)."""
    ws = [np.ones_like(s), np.sin(w_ie_mag * s), 1.0 - np.cos(w_ie_mag * s)]
    if mean_weights:
        c = seg_t - s + dt
        ws += [c, ws[1] * c, ws[2] * c]
    return ws


def scratch_array(scratch: dict | None, name: str, shape: tuple) -> np.ndarray:
    """An uninitialised float array of ``shape``, taken from ``scratch`` (a dict its owner
    keeps between calls; grown when too small) or new without one. Large temporaries
    reused this way are not faulted in page by page again at every call, as arrays above
    malloc's mmap threshold (128 kB) would be."""
    size = math.prod(shape)
    if scratch is None:
        return np.empty(shape)
    buf = scratch.get(name)
    if buf is None or buf.size < size:
        buf = scratch[name] = np.empty(size)
    return buf[:size].reshape(shape)


def _equal_intervals(dt: float, w, f, m: int, w_ie_mag: float, mean_weights: bool, B,
                     scratch: dict | None):
    """Sums of S = len(w) / m intervals of m samples each, uniform dt, into ``B`` (S, 3, K,
    N) (see :func:`preintegrate`), in pieces of about _PIECE samples per position,
    component-major, so every temporary stays in cache."""
    T, N = w.shape[0], w.shape[1]
    S = T // m
    s = dt * np.arange(1, m + 1)
    wts = np.array(_weights(dt, s, s[-1], mean_weights, w_ie_mag))        # (k, m)
    per = max(1, _PIECE // N)
    size = (3, min(per, S) * m * N)
    rot_buf, u_buf = (scratch_array(scratch, name, size) for name in ("rot", "u"))
    for a in range(0, S, per):
        b = min(S, a + per)
        # long intervals, few runs: the whole-array scan along the positions of (3, S, m, N)
        # arrays; otherwise the running scan on position-major (m, 3, S, N) arrays, whose
        # steps are contiguous and whose weighted sums are one GEMM without a copy
        whole = m >= 16 and (b - a) * N < 1000
        shape, order = ((3, b - a, m, N), (3, 0, 1, 2)) if whole else \
            ((m, 3, b - a, N), (1, 3, 0, 2))
        rot, u = (x.reshape(-1)[:3 * (b - a) * m * N].reshape(shape) for x in (rot_buf, u_buf))
        for out, x in ((rot, w), (u, f)):
            np.multiply(x[a * m:b * m].reshape(b - a, m, N, 3).transpose(order), dt, out=out)
        if whole:
            q = _qexp_c(rot[0], rot[1], rot[2])
            _scan(q, u)
            qend = tuple(c[:, -1] for c in q)
            sums = np.tensordot(wts, u, axes=([1], [2]))
        else:
            qend = _running_scan(rot, u)
            sums = np.matmul(wts, u.reshape(m, -1),
                             out=scratch_array(scratch, "sums", (len(wts), 3 * (b - a) * N)))
        B[a:b, :, 3:] = sums.reshape(len(wts), 3, b - a, N).transpose(2, 1, 0, 3)
        for c, e in enumerate(dcm_entries_from_quat(*qend)):
            B[a:b, c // 3, c % 3] = e
    return float(s[-1]), float((s * dt).sum())


def _running_scan(rot, u):
    """Rotation vectors ``rot`` (m, 3, ...) of m steps: rotate each ``u`` (same shape) by
    the product of the steps up to and including its own, in place; return the product of
    all m (quaternion components). Position by position: only step-sized scratch arrays."""
    q = None
    buf = [np.empty_like(rot[0, 0]) for _ in range(9)]
    for j in range(rot.shape[0]):
        e = _qexp_c(*rot[j])
        if q is None:
            q = tuple(np.array(c) for c in e)
        else:
            out = tuple(buf[4:8])
            _qmul_into(q, e, out, buf[8])
            buf[4:8], q = list(q), out
        _qrot_c(q, tuple(u[j]), buf[:3] + [buf[8]])
    return q


def _padded_intervals(dt, w, f, lengths, w_ie_mag: float, mean_weights: bool, B):
    """Sums of intervals of any lengths and per-sample dt (jittered stamps) into ``B``
    (see :func:`preintegrate`): the intervals padded to the longest with zero rates and
    forces."""
    S, L = len(lengths), int(lengths.max())
    T, N = w.shape[0], w.shape[1]
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    pos = np.arange(L)
    valid = pos[None, :] < lengths[:, None]
    idx = np.where(valid, starts[:, None] + pos[None, :], T)       # T = padding row
    dtp = np.concatenate([np.broadcast_to(np.asarray(dt, dtype=float), (T,)), [0.0]])[idx]
    dtp = dtp * valid
    rot = np.moveaxis(np.concatenate([w, np.zeros((1, N, 3))])[idx], -1, 0) * dtp[:, :, None]
    u = np.moveaxis(np.concatenate([f, np.zeros((1, N, 3))])[idx], -1, 0) * dtp[:, :, None]
    q = _qexp_c(rot[0], rot[1], rot[2])
    _scan(q, u)
    s = np.cumsum(dtp, axis=1)                        # time since the interval's start
    seg_t = s[:, -1]
    ws = _weights(dtp, s, seg_t[:, None], mean_weights, w_ie_mag)
    B[:, :, 3:] = np.einsum("ksl,jsln->sjkn", np.array(ws) * valid, u)
    last = (np.arange(S), lengths - 1)
    B[:, :, :3] = np.stack(dcm_entries_from_quat(*(c[last] for c in q)), 1).reshape(S, 3, 3, N)
    return seg_t, (s * dtp).sum(axis=1)


def preintegrate(dt, w: np.ndarray, f: np.ndarray, lengths: np.ndarray,
                 w_ie_mag: float, mean_weights: bool, scratch: dict | None = None):
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
    scratch : dict kept by the caller for the large arrays (see :func:`scratch_array`); B
        is then a view into it, valid until the next call with the same dict.

    Returns
    -------
    B : ndarray (S, 3, K, N), component-major: column k of each interval and run in
        ``B[s, :, k, n]``. Columns 0-2: Q_m as a DCM (body rotation over the interval);
        3-5: A0, Aa, Ab (m/s); 6-8 (K = 9, with ``mean_weights``): V0, Va, Vb, the
        mean-velocity sums (m).
    seg_t : ndarray (S,) — duration of each interval, s.
    s_dt : ndarray (S,) — sum over the interval of (time since its start) x dt, s^2.
    """
    lengths = np.asarray(lengths)
    B = scratch_array(scratch, "B", (len(lengths), 3, 9 if mean_weights else 6, w.shape[1]))
    if np.ndim(dt) != 0:
        return (B,) + _padded_intervals(dt, w, f, lengths, w_ie_mag, mean_weights, B)
    # uniform dt: consecutive intervals of equal length are reshaped, not copied
    seg_t, s_dt = np.empty(len(lengths)), np.empty(len(lengths))
    k = i = 0
    for grp in np.split(lengths, np.flatnonzero(np.diff(lengths)) + 1):
        n, j = len(grp) * int(grp[0]), i + len(grp)
        seg_t[i:j], s_dt[i:j] = _equal_intervals(float(dt), w[k:k + n], f[k:k + n],
                                                 int(grp[0]), w_ie_mag, mean_weights,
                                                 B[i:j], scratch)
        k, i = k + n, j
    return B, seg_t, s_dt


def total_rotation(dt, w: np.ndarray) -> np.ndarray:
    """Quaternion [x, y, z, w] of exp(w_1 dt_1) ... exp(w_T dt_T), w (T, 3): a pairwise
    product tree (T - 1 quaternion products) on component arrays."""
    q = _qexp(w * np.asarray(dt)[..., None])
    while len(q[0]) > 1:
        if len(q[0]) % 2:                     # odd: the last one waits for the next level
            last = tuple(c[-1:] for c in q)
            q = _qmul(tuple(c[0:-1:2] for c in q), tuple(c[1::2] for c in q))
            q = tuple(np.concatenate([c, e]) for c, e in zip(q, last))
        else:
            q = _qmul(tuple(c[0::2] for c in q), tuple(c[1::2] for c in q))
    return np.array([float(c[0]) for c in q])


def start_frame_increments(dt: np.ndarray, w: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Velocity increments ``B(t_k) f_k dt_k`` in the body frame of the first sample (an
    inertially fixed frame: ``B`` is the gyro's rotation since the start, Earth rate included).

    dt : ndarray (T,) s ; w, f : ndarray (T, N, 3). Returns (T, N, 3), m/s.
    """
    q = prefix_rotations(dt[None, :, None], w[None])
    q = tuple(c[0] for c in q)
    return rotate_vectors(q, f) * dt[:, None, None]


def open_loop_velocity(dt: np.ndarray, w: np.ndarray, f: np.ndarray, C0: np.ndarray,
                       w_ie: np.ndarray, g_n: np.ndarray, increments=None) -> np.ndarray:
    """Velocity of the damped mechanization without feedback, at every sample.

    Parameters
    ----------
    dt : ndarray (T,) s ; w, f : ndarray (T, N, 3) ; C0 : ndarray (N, 3, 3) ;
    w_ie, g_n : ndarray (3,) — Earth rate and gravity in ENU.

    Returns
    -------
    v : ndarray (T, N, 3), m/s ENU.

    ``increments``: :func:`start_frame_increments` of the same samples, when the caller has
    them already.
    """
    u = start_frame_increments(dt, w, f) if increments is None else increments
    s = np.cumsum(dt)
    a = (u.transpose(1, 0, 2) @ C0.mT).transpose(1, 0, 2)   # C0 u, one product per run
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
