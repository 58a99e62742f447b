"""Observability of the velocity-matching alignment: the piece-wise constant system analysis
of seed 001 (numpy/scipy only, no ROS).

The model
---------
The error model of a SINS aided by a velocity reference, in the navigation frame n = ENU
(ALGORITHM.md, "In-motion alignment with a velocity reference"), simplified as seed 001 does
(its eq. 4: the terms of the order of the velocity or position error over the Earth's radius
are dropped; the attitude error keeps the Earth rate)::

    d(phi)/dt = -(w_in^n x) phi - C_b^n eps          (attitude error phi, E/N/U, rad)
    d(dv)/dt  =  (f^n x) phi + C_b^n nabla            (velocity error, E/N/U, m/s)
    d(eps)/dt = 0,  d(nabla)/dt = 0,  d(dl)/dt = 0    (gyro and accelerometer biases in body
                                                       axes; lever-arm error, body, m)

with the attitude-error convention of ALGORITHM.md (true = exp(phi x) estimate), ``f^n`` the
specific force and ``w_in^n`` the rate of the navigation frame, here the Earth rate: the
transport rate (v / R, 1.6e-6 rad/s at 10 m/s) is of the order of the terms the seed drops.

The measurement is the velocity of the antenna, ``z = v + C_b^n (w_nb^b x l^b)``::

    dz = dv + ((C_b^n (w_nb^b x l^b)) x) phi - C_b^n (l^b x) eps + C_b^n (w_nb^b x) dl

(the lever-arm terms vanish for a zero lever arm and a body that does not turn). Dropping
the Coriolis term ``-(2 w_ie + w_en) x dv`` (as the seed does) changes no verdict: it is an
output injection (``dv`` is measured), which leaves the unobservable subspace unchanged.

The states are, in this order (:data:`STATES`, the in-motion filter's order):
``phi_E, phi_N, phi_U, dv_E, dv_N, dv_U, bg_x, bg_y, bg_z, ba_x, ba_y, ba_z`` and, with
``lever_states``, ``lever_x, lever_y, lever_z`` (:data:`LEVER_STATES`).

Piece-wise constant system (PWCS)
---------------------------------
The trajectory is cut into pieces (windows) over which ``F_j`` and ``H_j`` are held at the
piece's mean specific force and rates and its middle attitude (:func:`pieces_from_series`).
The stripped observability matrix (SOM) up to piece r stacks the pieces' own observability
matrices, ``Q_s(r) = [Q_1; ...; Q_r]`` with ``Q_j = [H_j; H_j F_j; ...; H_j F_j^(n-1)]``; the
total observability matrix (TOM) carries each ``Q_j`` back to the start through the earlier
pieces' transitions, ``Q_j e^(F_(j-1) T_(j-1)) ... e^(F_1 T_1)``. The SOM is the seed's tool;
its rank equals the TOM's when the unobservable subspace of every piece lies in the null
space of its F (Goshen-Meskin and Bar-Itzhack), which the INS error model only nearly meets:
both ranks are reported.

Scaling (it decides the singular values, not the ranks): each state is divided by its prior
standard deviation (:class:`Scales`), each measurement by the velocity noise, and the block
``H F^k`` is multiplied by ``T^k / k!`` (T = the piece's length): block k is then the k-th
Taylor term of the velocity error over the piece, in units of the noise, caused by a one-sigma
initial error. The matrices are stacked through their triangular factor (QR), so a run of
thousands of pieces costs a 15 x 15 SVD per piece.

Degree of observability (per state)
-----------------------------------
Two numbers per state k, from the SVD ``Q_s = U S V^T`` in those scaled units. The numerical
``rank`` counts the singular values above ``RANK_RTOL`` times the largest (the structural
rank of the theory: 9 of 12 on a static base). The verdicts also drop the directions whose
singular value is below an absolute floor (``SV_FLOOR``, noise units; ``effective_rank``
counts the rest): the Coriolis force of a vehicle cruising North (7e-4 m/s^2 sideways at 10
m/s) or the Earth rate acting on the up gyro bias make directions formally observable that
no filter resolves in an hour. The columns ``N`` of V for the remaining directions span the
unobservable subspace:

- ``unresolved[k] = ||N^T e_k||``, in [0, 1]: the fraction of the state's prior standard
  deviation that no data of this motion can remove. It is exactly the posterior/prior std
  ratio of state k once every observable combination is known without error, for a Gaussian
  prior with the scales as standard deviations (the posterior covariance is then the
  projection N N^T). A state outside the unobservable subspace has 0; a state coupled with
  others (level with the horizontal accelerometer biases, heading with the east gyro bias)
  has what its partners' priors leave: a 1 deg level prior coupled with a 100 ug
  accelerometer bias keeps 0.6 % of it (the bias over g), the bias keeps nearly all of its own.
- ``degree[k]``: the singular value the state's initial error maps to, generalised so that it
  is well defined when a state loads on several singular vectors: the weighted harmonic mean
  ``sqrt(1 - unresolved^2) / sqrt(sum_i V[k, i]^2 / s_i^2)`` over the observable directions,
  i.e. the size, in noise units, of the smallest SOM output that moves the minimum-norm
  reconstruction of the state by its observable part. It equals ``s_i`` when the state's axis
  is the singular vector ``v_i`` (the singular-value method's "state i maps to s_i"), grows
  with the data like the singular values do, and is 0 for a state with nothing observable.
  (The plain method assigns each state the singular value of the vector it loads most on; it
  is ambiguous when several states share one vector, which coupled INS states do, so it is
  not used.) The SOM sees each piece on its own, not the slow build-up over many pieces
  (a gyro bias integrated twice), so degrees compare states of one kind and one state over
  time; across kinds they are a rough guide (a gyro bias of degree 0.1 is resolved by a
  filter sooner than an accelerometer bias of degree 0.5).

Verdicts: ``observable`` when ``unresolved`` < :data:`UNRESOLVED_OBSERVABLE` and the degree
is at least :data:`DEGREE_WEAK`, ``weak`` when only the degree is below it, ``unobservable``
when ``unresolved`` >= :data:`UNRESOLVED_UNOBSERVABLE` (the data cannot remove even half its
prior std), and ``coupled`` in between (in the unobservable subspace, mostly resolved
because its partners' priors are tight). On seed 001's manoeuvres the in-motion filter's
covariance follows them (test/test_observability.py): a coupled state's std ends at its
``unresolved`` fraction to a few per cent.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from sins_align.core.earth import earth_rate_enu
from sins_align.core.rotation import skew
from sins_align.core.specs import DEG, SensorSpecs
from sins_align.core.strapdown import transport_rate

__all__ = ["STATES", "LEVER_STATES", "Scales", "Piece", "Step", "PwcsObservability",
           "error_model", "pieces_from_series", "pieces_from_trajectory", "analyze",
           "coupling_groups", "verdict", "RANK_RTOL", "UNRESOLVED_OBSERVABLE",
           "UNRESOLVED_UNOBSERVABLE", "SV_FLOOR", "DEGREE_WEAK", "SCENARIOS", "scenario"]

STATES = ("phi_E", "phi_N", "phi_U", "dv_E", "dv_N", "dv_U", "bg_x", "bg_y", "bg_z",
          "ba_x", "ba_y", "ba_z")
LEVER_STATES = ("lever_x", "lever_y", "lever_z")

#: singular values below this fraction of the largest do not count in the numerical rank
RANK_RTOL = 1e-9
#: singular values (noise units) below this span the unobservable subspace of the verdicts
SV_FLOOR = 1e-4
#: below this unresolved fraction a state is observable (the data can remove 99 % of its
#: prior std)
UNRESOLVED_OBSERVABLE = 0.01
#: an observable state with a degree below this (noise units) is only weakly observable
DEGREE_WEAK = 0.1
#: from this unresolved fraction on a state is unobservable
UNRESOLVED_UNOBSERVABLE = 0.5

_PHI, _DV, _BG, _BA, _LEV = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12),
                             slice(12, 15))


@dataclass(frozen=True)
class Scales:
    """Prior standard deviations (the state scaling) and the measurement noise.

    Attributes
    ----------
    level, heading : rad — attitude error about E and N, and about U.
    velocity : m/s. gyro_bias : rad/s. accel_bias : m/s^2. lever : m.
    velocity_noise : m/s — 1-sigma of a velocity measurement (per axis).
    """

    level: float = 1.0 * DEG
    heading: float = 10.0 * DEG
    velocity: float = 0.1
    gyro_bias: float = 10.0 * DEG / 3600.0
    accel_bias: float = 1e-3
    lever: float = 0.1
    velocity_noise: float = 0.1

    def __post_init__(self):
        for name in ("level", "heading", "velocity", "gyro_bias", "accel_bias", "lever",
                     "velocity_noise"):
            x = getattr(self, name)
            if not (isinstance(x, (int, float)) and math.isfinite(x) and x > 0):
                raise ValueError(f"Scales.{name} must be a finite number > 0, got {x!r}")

    @classmethod
    def from_specs(cls, specs: SensorSpecs, **kw) -> "Scales":
        """The bias priors from ``specs`` (zero biases fall back to the defaults); ``kw``
        sets the others."""
        bias = {}
        if specs.gyro_bias > 0:
            bias["gyro_bias"] = specs.gyro_bias
        if specs.accel_bias > 0:
            bias["accel_bias"] = specs.accel_bias
        return cls(**{**bias, **kw})

    def vector(self, lever_states: bool = False) -> np.ndarray:
        """The prior stds in state order (:data:`STATES`, then :data:`LEVER_STATES`)."""
        s = [self.level, self.level, self.heading] + [self.velocity] * 3 \
            + [self.gyro_bias] * 3 + [self.accel_bias] * 3
        if lever_states:
            s += [self.lever] * 3
        return np.array(s)


@dataclass(frozen=True)
class Piece:
    """One piece of the PWCS: the interval [t0, t1] s and its constant F (n, n), H (3, n)."""

    t0: float
    t1: float
    F: np.ndarray
    H: np.ndarray

    @property
    def duration(self) -> float:
        return self.t1 - self.t0


def error_model(C, f_n, w_in, w_nb=None, lever_arm=None, lever_states: bool = False
                ) -> tuple[np.ndarray, np.ndarray]:
    """F (n, n) and H (3, n) of the error model (module docstring) at one instant.

    C : (3, 3) C_b^n. f_n : (3,) specific force, ENU, m/s^2. w_in : (3,) rate of the
    navigation frame, ENU, rad/s. w_nb : (3,) body rate w.r.t. the navigation frame, body
    axes (None: 0). lever_arm : (3,) m, body (None: 0). lever_states : add the lever-arm error
    states (n = 15, else 12).
    """
    C = np.asarray(C, dtype=float).reshape(3, 3)
    w_nb = np.zeros(3) if w_nb is None else np.asarray(w_nb, dtype=float).reshape(3)
    lev = np.zeros(3) if lever_arm is None else np.asarray(lever_arm, dtype=float).reshape(3)
    n = 15 if lever_states else 12
    F = np.zeros((n, n))
    F[_PHI, _PHI] = -skew(np.asarray(w_in, dtype=float).reshape(3))
    F[_PHI, _BG] = -C
    F[_DV, _PHI] = skew(np.asarray(f_n, dtype=float).reshape(3))
    F[_DV, _BA] = C
    H = np.zeros((3, n))
    H[:, _DV] = np.eye(3)
    H[:, _PHI] = skew(C @ np.cross(w_nb, lev))
    H[:, _BG] = -C @ skew(lev)
    if lever_states:
        H[:, _LEV] = C @ skew(w_nb)
    return F, H


def _window_edges(t: np.ndarray, window: float, breaks=()) -> list[tuple[int, int]]:
    """Index ranges [a, b) of the samples in consecutive windows of ``window`` s, also cut at
    the times ``breaks`` (so that no window straddles a phase boundary)."""
    t0, t1 = float(t[0]), float(t[-1])
    cuts = np.arange(t0, t1, window)[1:]
    cuts = np.unique(np.concatenate([cuts, [b for b in breaks if t0 < b < t1]]))
    idx = np.searchsorted(t, cuts, side="left")
    bounds = np.unique(np.concatenate([[0], idx, [len(t)]]))
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def pieces_from_series(t, C, f_b, w_ib, v, lat, h, window: float = 1.0, *, lever_arm=None,
                       lever_states: bool = False, breaks=(), deadband: float = 0.0
                       ) -> list[Piece]:
    """The PWCS pieces of a run given per sample.

    t : (N,) s, increasing. C : (N, 3, 3) C_b^n. f_b, w_ib : (N, 3) specific force (m/s^2)
    and angular rate (rad/s), body axes. v : (N, 3) m/s ENU. lat : (N,) rad; h : (N,) m.
    window : s — piece length; ``breaks`` (s) cut pieces too (phase boundaries).

    Each piece holds the mean specific force and rates over its samples (rotated into ENU
    sample by sample) and the attitude of its middle sample.

    deadband : for measured data (> 0): a component of a piece's mean horizontal specific
    force or body rate smaller than ``deadband`` times its standard error (the samples'
    scatter over sqrt(count)) is set to 0. Sensor noise otherwise looks like motion and
    makes heading (and the lever arm) formally observable on a vehicle that stands still.
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    C = np.asarray(C, dtype=float).reshape(-1, 3, 3)
    f_b = np.asarray(f_b, dtype=float).reshape(-1, 3)
    w_ib = np.asarray(w_ib, dtype=float).reshape(-1, 3)
    v = np.asarray(v, dtype=float).reshape(-1, 3)
    lat = np.broadcast_to(np.asarray(lat, dtype=float), t.shape)
    h = np.broadcast_to(np.asarray(h, dtype=float), t.shape)
    n = len(t)
    if n < 2 or not (C.shape[0] == f_b.shape[0] == w_ib.shape[0] == v.shape[0] == n):
        raise ValueError("pieces_from_series needs at least 2 samples and arrays of one length")
    if not np.all(np.diff(t) > 0):
        raise ValueError("sample times must increase")
    if not (math.isfinite(window) and window > 0):
        raise ValueError(f"window must be a finite number of seconds > 0, got {window!r}")
    for name, x in (("C", C), ("f_b", f_b), ("w_ib", w_ib), ("v", v), ("lat", lat), ("h", h)):
        if not np.all(np.isfinite(x)):
            raise ValueError(f"{name} has non-finite values")
    f_n = np.einsum("kij,kj->ki", C, f_b)
    w_ie = earth_rate_enu(lat)
    # the body's own rate uses the full rate of the navigation frame; the model's w_in
    # only the Earth rate (module docstring: the transport rate is a v/R term)
    w_nb = w_ib - np.einsum("kji,kj->ki", C, w_ie + transport_rate(v, lat, h))
    dt = np.median(np.diff(t))
    out = []
    for a, b in _window_edges(t, window, breaks):
        m = (a + b - 1) // 2
        fm, wm = f_n[a:b].mean(0), w_nb[a:b].mean(0)
        if deadband > 0 and b - a > 1:
            k = math.sqrt(b - a)
            fm[:2] = np.where(np.abs(fm[:2]) < deadband * f_n[a:b, :2].std(0) / k, 0.0,
                              fm[:2])
            wm = np.where(np.abs(wm) < deadband * w_nb[a:b].std(0) / k, 0.0, wm)
        F, H = error_model(C[m], fm, w_ie[a:b].mean(0), wm, lever_arm, lever_states)
        # a piece covers its samples' intervals: (t[a] - dt, t[b-1]]
        out.append(Piece(float(t[a] - dt), float(t[b - 1]), F, H))
    return out


def pieces_from_trajectory(result, window: float = 1.0, *, lever_states: bool = False,
                           breaks=()) -> list[Piece]:
    """The pieces of a simulated run (:class:`~sins_align.sim.trajectory.TrajectoryResult`):
    its error-free specific force and rates, true attitude, velocity and position, and its
    lever arm."""
    return pieces_from_series(result.t[1:], result.C[1:], result.accel_true, result.gyro_true,
                              result.v[1:], result.lat[1:], result.h[1:], window,
                              lever_arm=result.lever_arm, lever_states=lever_states,
                              breaks=breaks)


@dataclass
class Step:
    """The analysis after one piece (the SOM and TOM of the pieces up to it).

    Attributes
    ----------
    t : s — end of the piece. rank, tom_rank : numerical ranks of the SOM and the TOM
    (singular values above ``rtol`` times the largest). effective_rank : the SOM's singular
    values above the floor too (the directions the verdicts count as observable).
    singular_values : (n,) of the scaled SOM, descending.
    unresolved, degree : (n,) per state (module docstring), state order.
    null_space : (n, n - effective_rank) basis of the unobservable subspace (scaled states).
    """

    t: float
    rank: int
    effective_rank: int
    tom_rank: int
    singular_values: np.ndarray
    unresolved: np.ndarray
    degree: np.ndarray
    null_space: np.ndarray = field(repr=False)


def verdict(unresolved: float, degree: float) -> str:
    """'observable', 'weak', 'coupled' or 'unobservable' (module docstring)."""
    if unresolved < UNRESOLVED_OBSERVABLE:
        return "observable" if degree >= DEGREE_WEAK else "weak"
    return "unobservable" if unresolved >= UNRESOLVED_UNOBSERVABLE else "coupled"


def coupling_groups(step: Step, names) -> list[list[str]]:
    """The states of the unobservable subspace (``unresolved`` >= 1e-4) in groups: two
    states are in one group when the projection on that subspace links them (``|N N^T|[k,
    l]`` above 1e-9); each group is one set of errors that the data see only in
    combination (level with the horizontal accelerometer biases, heading with the east gyro
    bias)."""
    N = step.null_space
    if N.shape[1] == 0:
        return []
    P = N @ N.T
    member = np.sqrt(np.clip(np.diag(P), 0, None)) >= 1e-4
    idx = [k for k in range(len(names)) if member[k]]
    groups: list[list[int]] = []
    seen: set[int] = set()
    for k in idx:
        if k in seen:
            continue
        todo, grp = [k], []
        seen.add(k)
        while todo:
            i = todo.pop()
            grp.append(i)
            for j in idx:
                if j not in seen and abs(P[i, j]) > 1e-9:
                    seen.add(j)
                    todo.append(j)
        groups.append(sorted(grp))
    return [[names[i] for i in g] for g in groups]


class PwcsObservability:
    """Accumulates the SOM and TOM piece by piece (:meth:`add`).

    Parameters
    ----------
    scales : (n,) prior stds in state order (:meth:`Scales.vector`).
    velocity_noise : m/s — the measurement scale.
    rtol : :data:`RANK_RTOL`. floor : :data:`SV_FLOOR`.
    """

    def __init__(self, scales, velocity_noise: float, rtol: float = RANK_RTOL,
                 floor: float = SV_FLOOR):
        self.s = np.asarray(scales, dtype=float).reshape(-1)
        self.n = len(self.s)
        if self.n not in (12, 15) or not np.all(self.s > 0):
            raise ValueError("scales must be 12 or 15 positive numbers")
        self.sigma_v = float(velocity_noise)
        self.rtol = float(rtol)
        self.floor = float(floor)
        if not (self.sigma_v > 0 and 0 < self.rtol < 1 and self.floor >= 0):
            raise ValueError("velocity_noise > 0, 0 < rtol < 1 and floor >= 0 needed")
        self._R = np.zeros((0, self.n))       # triangular factor of the SOM
        self._Rt = np.zeros((0, self.n))      # of the TOM
        self._Phi = np.eye(self.n)            # transition from the start, scaled states

    def piece_matrix(self, piece: Piece) -> np.ndarray:
        """The scaled observability matrix ``Q_j`` of one piece (3n, n)."""
        F = piece.F / self.s[:, None] * self.s[None, :]
        M = piece.H * self.s[None, :] / self.sigma_v
        T = piece.duration
        blocks = [M]
        for k in range(1, self.n):
            M = M @ F * (T / k)
            blocks.append(M)
        return np.vstack(blocks)

    @staticmethod
    def _stack(R: np.ndarray, Q: np.ndarray) -> np.ndarray:
        r = scipy.linalg.qr(np.vstack([R, Q]), mode="r", check_finite=False)[0]
        return r[:Q.shape[1]]

    def add(self, piece: Piece) -> Step:
        if piece.F.shape != (self.n, self.n) or piece.H.shape != (3, self.n):
            raise ValueError(f"piece of the wrong size for {self.n} states")
        Q = self.piece_matrix(piece)
        self._R = self._stack(self._R, Q)
        self._Rt = self._stack(self._Rt, Q @ self._Phi)
        Fs = piece.F / self.s[:, None] * self.s[None, :]
        self._Phi = scipy.linalg.expm(Fs * piece.duration) @ self._Phi
        return self.result(piece.t1)

    def result(self, t: float) -> Step:
        _, sv, Vt = np.linalg.svd(self._R)
        top = sv[0] if len(sv) and sv[0] > 0 else np.inf
        rank = int(np.sum(sv > self.rtol * top))
        obs = sv > max(self.rtol * top, self.floor)
        V = Vt.T
        N = V[:, ~obs]
        unresolved = np.sqrt(np.clip(np.sum(N ** 2, axis=1), 0.0, 1.0))
        resolved2 = np.clip(1.0 - unresolved ** 2, 0.0, 1.0)
        inv = np.sum(V[:, obs] ** 2 / sv[obs] ** 2, axis=1)
        degree = np.zeros(self.n)
        ok = (resolved2 > 1e-12) & (inv > 0)
        degree[ok] = np.sqrt(resolved2[ok] / inv[ok])
        svt = np.linalg.svd(self._Rt, compute_uv=False)
        tom_rank = int(np.sum(svt > self.rtol * svt[0])) if len(svt) and svt[0] > 0 else 0
        return Step(float(t), rank, int(obs.sum()), tom_rank, sv, unresolved, degree, N)


def analyze(pieces, scales: Scales, lever_states: bool = False, rtol: float = RANK_RTOL,
            floor: float = SV_FLOOR) -> list[Step]:
    """One :class:`Step` per piece: the SOM (and TOM) from the first piece to it."""
    acc = PwcsObservability(scales.vector(lever_states), scales.velocity_noise, rtol, floor)
    return [acc.add(p) for p in pieces]


# ----------------------------------------------------------------------------- seed 001
#: latitude of seed 001's authors (Wuhan), deg
SCENARIO_LATITUDE = 30.53


def _scenario(name: str):
    """Seed 001's manoeuvres as (segments, phases): the vehicle heads North, level (its up
    axis along U); phases name the intervals (end times, s) the tables report."""
    from sins_align.sim.trajectory import Segment
    if name == "static":
        return (Segment(800.0),), [("static", 800.0)]
    if name == "forward":
        # 100 s still, 1 m/s^2 forward for 10 s (1 s smoothstep ramps: the speed change is
        # exactly 10 m/s), then 10 m/s North
        segs = (Segment(100.0), Segment(10.0, accel=1.0), Segment(290.0))
        return segs, [("static", 100.0), ("accelerate", 111.0), ("cruise N", 400.0)]
    if name == "turn":
        # the same, 100 s North, a 90 deg left turn at 2 deg/s, 100 s West, stop at 2 m/s^2
        segs = (Segment(100.0), Segment(10.0, accel=1.0), Segment(100.0),
                Segment(45.0, yaw_rate=2.0), Segment(100.0), Segment(5.0, accel=-2.0),
                Segment(40.0))
        return segs, [("static", 100.0), ("accelerate", 111.0), ("cruise N", 210.0),
                      ("turn left 90", 256.0), ("cruise W", 355.0), ("stop", 361.0),
                      ("static", 400.0)]
    raise ValueError(f"unknown scenario {name!r}; choose one of {', '.join(SCENARIOS)}")


#: seed 001's three manoeuvres (its experiments 1-3)
SCENARIOS = ("static", "forward", "turn")


def scenario(name: str, lat_deg: float = SCENARIO_LATITUDE):
    """Seed 001's manoeuvre ``name`` (:data:`SCENARIOS`) as a
    :class:`~sins_align.sim.trajectory.Trajectory` (heading North, yaw 90 deg REP-103) and its
    phases ``[(label, end time s)]``."""
    from sins_align.sim.trajectory import Trajectory
    segs, phases = _scenario(name)
    return Trajectory(segs, lat_deg, 114.36, 30.0, 90.0, 0.0, f"seed001_{name}"), phases
