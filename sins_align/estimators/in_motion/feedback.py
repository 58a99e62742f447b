"""LQR-designed feedback of the estimated errors (seed 002), the option beside full reset.

Seed 002 feeds a platform INS's estimated errors back through gains chosen by the linear
quadratic criterion, so that early, unconverged estimates do not make the loop oscillate. In
a strapdown filter the "platform" is the mechanization: the error estimate is carried on
(propagated with the filter's transition) and, after each update, the part
``G(T) = I - expm(-K T)`` of it is removed from the state, ``T`` being the time since the
last feedback, ``K = R^-1 B^T X`` the LQR gain of the continuous error model
``d x/dt = A x + B u`` (``B = I``: every error state is corrected directly) and ``X`` the
solution of the continuous algebraic Riccati equation ``A^T X + X A - X B R^-1 B^T X + W =
0`` (scipy.linalg.solve_continuous_are). The weights are ``W = I`` and ``R = tau^2 I``, so
that each error decays with a time constant near ``tau`` where the model's own dynamics are
slow (they are, next to seconds).

``A`` is the filter's error model on a level, still platform (specific force ``g`` up, the
Earth rate in body axes for the given latitude and heading 0).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm, solve_continuous_are

from sins_align.core.earth import OMEGA_IE
from sins_align.core.rotation import skew

__all__ = ["lqr_gain", "LqrFeedback", "FractionalFeedback"]


def lqr_gain(n: int, lat_rad: float, g: float, tau: float) -> np.ndarray:
    """The (n, n) LQR gain K for the error model with ``n`` states (12, 15 or 18)."""
    A = np.zeros((n, n))
    w = OMEGA_IE * np.array([0.0, math.cos(lat_rad), math.sin(lat_rad)])
    A[0:3, 0:3] = -skew(w)
    A[0:3, 6:9] = -np.eye(3)
    A[3:6, 0:3] = -skew(np.array([0.0, 0.0, g]))
    A[3:6, 3:6] = -skew(w)
    A[3:6, 9:12] = -np.eye(3)
    B = np.eye(n)
    W = np.eye(n)
    R = np.eye(n) * tau * tau
    X = solve_continuous_are(A, B, W, R)
    return np.linalg.solve(R, B.T @ X)


class LqrFeedback:
    """``G(T) = I - expm(-K T)`` for the time T since the last feedback, cached per
    millisecond of T."""

    def __init__(self, K: np.ndarray):
        self.K = np.asarray(K, dtype=float)
        self._cache: dict[int, np.ndarray] = {}

    def __call__(self, T: float) -> np.ndarray:
        key = int(round(T * 1000.0))
        G = self._cache.get(key)
        if G is None:
            G = np.eye(len(self.K)) - expm(-self.K * (key / 1000.0))
            if len(self._cache) < 10000:
                self._cache[key] = G
        return G


class FractionalFeedback:
    """A constant fraction of the carried error estimate fed back after every update
    (``G = fraction I`` whatever the time since the last feedback): the simplest schedule
    between full reset (``fraction`` 1) and none, the third option of the ``feedback`` study
    (``MotionConfig(feedback="fraction", feedback_fraction=...)``)."""

    def __init__(self, n: int, fraction: float):
        if not (0.0 < fraction <= 1.0):
            raise ValueError(f"fraction must be within (0, 1], got {fraction!r}")
        self.fraction = float(fraction)
        self._G = np.eye(n) * self.fraction

    def __call__(self, T: float) -> np.ndarray:
        return self._G
