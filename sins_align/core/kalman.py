"""Kalman-filter numerics shared by every model: discretisation and a Joseph-form update.

Kept apart from the models so the discretisation lives in one place (STYLE.md). Every
function works on a single filter or on a stack of filters (leading dimension N).
"""
from __future__ import annotations

import math

import numpy as np


def _T(a: np.ndarray) -> np.ndarray:
    return np.swapaxes(a, -1, -2)


def inv3(S: np.ndarray) -> np.ndarray:
    """Inverse of 3x3 matrices (..., 3, 3) by the adjugate: a single one (shape (3, 3) or
    (1, 3, 3)) in scalar arithmetic, a stack as whole-array arithmetic on its nine entries
    (LAPACK costs about 0.6 us per 3x3 matrix, mostly per-matrix overhead)."""
    if S.size == 9:
        det, ((a, b, c), (d, e, f), (g, h, i)) = _adjugate3(*S.reshape(3, 3).tolist())
        if det == 0.0:
            return np.linalg.inv(S)      # raises LinAlgError like numpy would
        r = 1.0 / det
        return np.array([[a * r, b * r, c * r], [d * r, e * r, f * r],
                         [g * r, h * r, i * r]]).reshape(S.shape)
    det, adj = _adjugate3(*np.moveaxis(S, (-2, -1), (0, 1)))
    if not np.all(det != 0.0):
        return np.linalg.inv(S)
    r = 1.0 / det
    out = np.empty(S.shape)
    for i, row in enumerate(adj):
        for j, v in enumerate(row):
            np.multiply(v, r, out=out[..., i, j])
    return out


def _adjugate3(r0, r1, r2):
    """Determinant and adjugate (rows) of a 3x3 matrix given by its rows; the entries may
    be floats or equal-shape arrays."""
    (a, b, c), (d, e, f), (g, h, i) = r0, r1, r2
    A, B, C = e * i - f * h, f * g - d * i, d * h - e * g
    return a * A + b * B + c * C, ((A, c * h - b * i, b * f - c * e),
                                   (B, a * i - c * g, c * d - a * f),
                                   (C, b * g - a * h, a * e - b * d))


def discretize(F: np.ndarray, Qc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition matrix and discrete process noise for ``x' = F x + w``, ``E[w w^T] = Qc delta``.

    Exact for any interval (to rounding): ``Phi = exp(F dt)`` and
    ``Qd = int_0^dt exp(F s) Qc exp(F s)^T ds``, i.e. Van Loan's block exponential
    ``exp([[-F, Qc], [0, F^T]] dt)`` evaluated block by block, by scaling and squaring:

    - the interval is halved s times until ``|F h|_1 <= 1/2``, or until
      ``max(|(F h)^2|^(1/2), |(F h)^3|^(1/3)) <= 1/2`` (h = dt / 2^s), which bounds the
      terms from the third on just as well. For the alignment models |F| is about g but
      F^2 about g x Earth rate: s = 0 up to about 20 s, 2 at 60 s, 8 at 3600 s;
    - over h both series are summed, ``Phi = sum (F h)^k / k!`` and
      ``Qd = sum Q_k h^(k+1) / (k+1)!`` with ``Q_0 = Qc``, ``Q_k = F Q_(k-1) + Q_(k-1) F^T``,
      until a term is below 2^-56 of the sum (block-wise, so a small Qd is as accurate as
      Phi). The terms then shrink at least by 1/(2 k) from the second on, so the rest is
      below rounding as well;
    - the pair is doubled s times, ``Phi <- Phi Phi``, ``Qd <- Phi Qd Phi^T + Qd`` (two
      consecutive intervals: exact composition).

    For the alignment models F is nearly nilpotent (Earth rate 7.3e-5 rad/s; gravity enters
    only through products with it), so at 100 Hz the series stop after the 4th or 5th term
    and the result equals the former 3rd-order series to 1e-20 of the largest entry (the
    smallest entries, 1e-17 of Qd's largest, differ by that series' own truncation, up to
    4e-14 relative); over the long gaps (up to max_gap, or 3600 s) the 3rd-order series
    was off by up to 3e-3 relative, this is exact to rounding (the test compares with closed
    forms).

    Parameters
    ----------
    F : ndarray, shape (..., n, n) — continuous system matrix.
    Qc : ndarray, shape (n, n) — continuous process noise spectral density.
    dt : float, s — interval (>= 0).

    Returns
    -------
    Phi : ndarray, shape (..., n, n) ; Qd : ndarray, shape (..., n, n)
    """
    F = np.asarray(F, dtype=float)
    Qc = np.asarray(Qc, dtype=float)
    dt = float(dt)
    s = 0
    if F.size and float(np.abs(F).sum(axis=-2).max()) * abs(dt) > 0.5:
        # the terms of the series shrink with |(F h)^k|^(1/k), k >= 2, rather than with
        # |F h|: (F h)^k <= |F h| a^(k-1) for a = max(|(F h)^2|^(1/2), |(F h)^3|^(1/3)).
        # For the alignment models (a large but nilpotent gravity coupling) that needs far
        # fewer halvings than |F h| (each squaring adds rounding).
        F2 = F @ F
        a = max(_norm1(F2) ** 0.5, _norm1(F2 @ F) ** (1.0 / 3.0)) * abs(dt)
        if a > 0.5:
            s = int(math.ceil(math.log2(a / 0.5)))
    h = dt / 2.0 ** s
    Fh = F * h
    term = Fh                                  # (F h)^k / k!
    Phi = _eye(F.shape[-1]) + Fh
    Qk = Qc * h                                # Q_k h^(k+1) / (k+1)! (symmetric)
    Qd = Qk
    tiny = 2.0 ** -56
    for k in range(2, 60):
        term = term @ Fh
        term *= 1.0 / k
        FQ = Fh @ Qk
        Qk = FQ + _T(FQ)
        Qk *= 1.0 / k
        Phi = Phi + term
        Qd = Qd + Qk
        if (np.abs(term).max() <= tiny * np.abs(Phi).max()
                and np.abs(Qk).max() <= tiny * np.abs(Qd).max()):
            break
    Qd = 0.5 * (Qd + _T(Qd))
    for _ in range(s):
        Qd = Phi @ Qd @ _T(Phi) + Qd
        Qd = 0.5 * (Qd + _T(Qd))
        Phi = Phi @ Phi
    return Phi, Qd


def _norm1(A: np.ndarray) -> float:
    """Largest 1-norm (column sum) over a stack of matrices."""
    return float(np.abs(A).sum(axis=-2).max())


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


def riccati_steps(P: np.ndarray, Phi: np.ndarray, Qd: np.ndarray, H: np.ndarray,
                  R: np.ndarray, n: int, chunk: int = 16, tol: float = 1e-9):
    """n identical Kalman steps (predict with Phi, Qd; then update with H, R), batched.

    The covariance recursion alone, without data: what n calls of ``P = Phi P Phi^T + Qd``
    followed by :func:`joseph_update` compute, with the per-step Python and numpy call
    overhead taken out. With ``P = X Y^-1`` both the prediction and the update are linear
    in (X, Y) (the Riccati equation as a linear fractional transformation), so the priors of
    ``chunk`` consecutive steps are ``T M^(j-1) [P; I]``, j = 1..chunk (M = update o predict,
    T = predict): one batched product and one batched solve per chunk. Only the posterior
    that starts the next chunk is taken sequentially. The powers of M grow apart at the
    rate of the fastest-converging mode, so a chunk is kept short; every prior is then
    checked against one exact prediction from the posterior before it (the first chunk
    as soon as it is computed, so that a chunk length that fails costs one chunk), and the
    chunk is halved until they agree to ``tol`` (relative to sqrt(P_ii P_jj)); below 4
    steps a chunk (or for fewer than 4 steps) it is the plain recursion. The posteriors,
    gains and innovation covariances then come from the priors by the same Joseph update,
    batched. The check bounds one step's error; over the whole run the results agree with
    the plain recursion to about ``tol`` (the recursion's own sensitivity to rounding is of
    the same order in the fine pass).

    Parameters
    ----------
    P : ndarray (n_x, n_x) — posterior covariance before the first step.
    Phi, Qd : ndarray (n_x, n_x) — transition and process noise of one step.
    H : ndarray (m, n_x) ; R : ndarray (m, m) — measurement of every step.
    n : int — number of steps.

    Returns
    -------
    P : ndarray (n, n_x, n_x) — posterior covariance after each step.
    K : ndarray (n, n_x, m) — gain of each step.
    S : ndarray (n, m, m) — innovation covariance of each step.
    """
    nx = P.shape[-1]
    T = M = None
    while True:
        J = max(1, min(chunk, n))
        if J < 4:                        # the plain recursion
            out = []
            for _ in range(n):
                P = Phi @ P @ Phi.T + Qd
                out.append(joseph_update(P, H, R))
                P = out[-1][0]
            return tuple(np.array(x) for x in zip(*out))
        if T is None:
            eye, zero = np.eye(nx), np.zeros((nx, nx))
            PhiIT = np.linalg.inv(Phi).T
            T = np.block([[Phi, Qd @ PhiIT], [zero, PhiIT]])
            info = H.T @ (inv3(R) if H.shape[0] == 3 else np.linalg.inv(R)) @ H
            M = np.block([[eye, zero], [info, eye]]) @ T
        pw = np.empty((J, 2 * nx, 2 * nx))
        pw[0] = T
        for j in range(1, J):
            pw[j] = pw[j - 1] @ M
        prior = np.empty((n, nx, nx))
        Z = np.empty((2 * nx, nx))
        Z[nx:] = np.eye(nx)
        Pk = P
        try:
            for k in range(0, n, J):
                c = min(J, n - k)
                Z[:nx] = Pk
                XY = pw[:c] @ Z
                # P = X Y^-1, i.e. Y^T P^T = X^T
                Pm = np.linalg.solve(XY[:, nx:].mT, XY[:, :nx].mT).mT
                prior[k:k + c] = 0.5 * (Pm + Pm.mT)
                if k == 0 and not _prior_error(P, prior[:c], Phi, Qd, H, R) <= tol:
                    break                     # the first chunk already fails (or is NaN)
                Pk = joseph_update(prior[k + c - 1], H, R)[0]
            else:
                post, K, S = joseph_update(prior, H, R)
                if _prior_error(P, prior, Phi, Qd, H, R, post) <= tol:
                    return post, K, S
        except np.linalg.LinAlgError:
            pass
        chunk = J // 2


def _prior_error(P0, prior, Phi, Qd, H, R, post=None) -> float:
    """Largest difference between each prior and one exact prediction from the posterior
    before it (P0 for the first), relative to sqrt(P_ii P_jj) of the prediction."""
    if post is None:
        post = joseph_update(prior, H, R)[0]
    check = Phi @ np.concatenate([P0[None], post[:-1]]) @ Phi.T + Qd
    d = np.sqrt(np.abs(np.diagonal(check, axis1=-2, axis2=-1)))
    err = np.abs(check - prior) / (d[:, :, None] * d[:, None, :] + 1e-300)
    return float(err.max())


def affine_scan(A: np.ndarray, b: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """All states of the recursion ``x_k = A_k x_(k-1) + b_k``, k = 0..n-1, from ``x0``.

    A blocked scan: the maps are composed inside blocks of about sqrt(n) steps (one step
    for all blocks at once), the block ends are chained, and every state follows from its
    block's start in one batched product. Same products as the plain loop, regrouped.

    Parameters
    ----------
    A : ndarray (n, p, p) ; b : ndarray (n, p, q) ; x0 : ndarray (p, q).

    Returns
    -------
    x : ndarray (n, p, q).
    """
    n = len(A)
    c = max(1, int(math.isqrt(max(n - 1, 0))) + 1)
    nb = -(-n // c)
    pad = nb * c - n
    if pad:
        A = np.concatenate([A, np.broadcast_to(np.eye(A.shape[-1]), (pad,) + A.shape[1:])])
        b = np.concatenate([b, np.zeros((pad,) + b.shape[1:])])
    A = A.reshape((nb, c) + A.shape[1:])
    b = b.reshape((nb, c) + b.shape[1:])
    Ac, bc = np.empty_like(A), np.empty_like(b)      # composed maps from each block start
    Ac[:, 0], bc[:, 0] = A[:, 0], b[:, 0]
    for j in range(1, c):
        Ac[:, j] = A[:, j] @ Ac[:, j - 1]
        bc[:, j] = A[:, j] @ bc[:, j - 1] + b[:, j]
    starts = np.empty((nb,) + x0.shape)
    x = x0
    for i in range(nb):
        starts[i] = x
        x = Ac[i, -1] @ x + bc[i, -1]
    out = Ac @ starts[:, None] + bc
    return out.reshape((nb * c,) + out.shape[2:])[:n]
