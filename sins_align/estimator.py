"""Streaming self-alignment estimator: damped mechanization + error-state Kalman filter.

This is the numpy core shared by the ROS node, the bag replay and the benchmarks. It knows
nothing about ROS. Time comes only from the sample stamps.

Method (see README "How it aligns" and ALGORITHM.md)
----------------------------------------------------
1. **Coarse pass** — the paper's filter: damped mechanization (eq. 1) and a Kalman update
   with the zero-velocity measurement at every IMU sample, attitude fed back through the
   exact SO(3) exponential. It converges from any initial attitude.
2. **Backtrack** — at ``backtrack_time`` seconds of data the coarse estimate is carried back
   to the first sample through the stored gyro data (exact: ``C(0) = exp(W T) C(T) B(T)^T``)
   and the buffered samples are processed again by the **fine pass**: the same model started
   from that small error with a fresh covariance, updated every ``fine_update_period`` with
   the mean velocity over the interval, and a measurement noise measured from the data
   (sway velocity). The fine pass then runs live. This removes the two weak spots of the
   one-pass filter (overconfident large-angle transients, vibration leaking into heading).
3. **Honest covariance** — the filter has no bias states (they are not observable here), so
   its own covariance ignores the bias-induced error. A sensitivity matrix carried through
   the same closed loop (consider analysis) adds exactly that part for biases drawn from the
   configured specs; the published attitude covariance tends to the limit-accuracy
   covariance of ALGORITHM.md instead of collapsing below it. The gain stays the paper's.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np

from .earth import OMEGA_IE, earth_rate_enu, gravity_enu
from .kalman import discretize, joseph_update
from .models import (apply_correction, averaged_measurement_matrix, bias_input_matrix,
                     check_model, measurement_matrix, system_matrix)
from .rotation import dcm_from_rpy, heading_from_dcm, quat_from_dcm, rpy_from_dcm, so3_exp
from .specs import DEG, SensorSpecs, grade_specs, limit_covariance

#: Reasons a sample can be rejected. A rejected sample never touches the filter state.
REJECT_REASONS = (
    "nonfinite",                  # NaN or Inf in stamp, rate or specific force
    "duplicate_stamp",            # same stamp as the previous accepted sample
    "stamp_backwards",            # stamp earlier than the previous accepted sample
    "dt_too_small",               # 0 < dt < min_dt_ratio * nominal interval
    "time_jump",                  # dt > max_gap: time re-anchored, state kept
    "gravity_removed",            # |f| < 0.25 g: the driver removed gravity
    "specific_force_out_of_range",  # ||f| - g| > specific_force_tolerance * g
    "rate_too_high",              # |w| > max_angular_rate (deg/s sent as rad/s, or real motion)
    "rates_look_like_deg_per_s",  # gyro/accelerometer tilt mismatch: rates scaled by 57.3
)

STATES = ("waiting", "aligning", "aligned", "disturbed", "fault")


@dataclass(frozen=True)
class AlignConfig:
    """Everything that configures an :class:`Aligner`. Angles in degrees, SI otherwise.

    Attributes
    ----------
    latitude_deg : geodetic latitude (required), deg, [-90, 90].
    height_m : height above the ellipsoid, m.
    model : 'constant' (paper Model 3, default), 'conventional' (Model 1), 'se3' (Model 2).
    specs : sensor error specs (or a grade name) — Q, the bias floor and observability.
    initial_rpy_deg : optional REP-103 [roll, pitch, yaw] of the IMU frame in ENU; None = identity.
        Any value converges; this only shortens the transient.
    coarse_velocity_noise : m/s, measurement noise std of the coarse (per-sample) pass.
    coarse_initial_std_deg : (level, heading) initial attitude std of the coarse pass.
    initial_velocity_std : m/s, initial velocity std (both passes).
    backtrack : run the fine pass over the buffered data (False = the paper's one-pass filter).
    backtrack_time : s of data after which the fine pass starts over the buffer.
    fine_update_period : s between fine-pass updates (mean velocity over the interval).
    fine_initial_std_deg : (level, heading) initial attitude std of the fine pass.
    fine_min_velocity_noise : m/s, floor of the measured fine-pass measurement noise.
    rate_hz : nominal IMU rate; None = estimated from the first stamps.
    min_dt_ratio : reject dt below this fraction of the nominal interval.
    gap_ratio : dt above this multiple of the nominal interval is a gap: the sample is used
        for one nominal interval and the rest is bridged as static (covariance grows).
    max_gap : s; a larger dt is a time jump: the sample is rejected and time re-anchored.
    max_angular_rate : rad/s; larger rates are rejected.
    specific_force_tolerance : fraction of g allowed between |f| and g.
    units_check_window : s; gyro tilt vs accelerometer tilt check window (0 = off).
    aligned_std_ratio : aligned when every observable axis std <= this x limit std ...
    aligned_min_level_std_deg, aligned_min_heading_std_deg : ... or below these absolute values.
    heading_max_limit_std_deg : heading counts as observable when its limit std is below this.
    disturbance_nis : mean NIS per dof above which the platform counts as disturbed (moving).
    """

    latitude_deg: float
    height_m: float = 0.0
    model: str = "constant"
    specs: SensorSpecs | str = "navigation"
    initial_rpy_deg: tuple[float, float, float] | None = None
    coarse_velocity_noise: float = 0.01
    coarse_initial_std_deg: tuple[float, float] = (30.0, 90.0)
    initial_velocity_std: float = 0.1
    backtrack: bool = True
    backtrack_time: float = 60.0
    fine_update_period: float = 1.0
    fine_initial_std_deg: tuple[float, float] = (1.0, 10.0)
    fine_min_velocity_noise: float = 1e-4
    rate_hz: float | None = None
    min_dt_ratio: float = 0.2
    gap_ratio: float = 5.0
    max_gap: float = 5.0
    max_angular_rate: float = 1.0
    specific_force_tolerance: float = 0.5
    units_check_window: float = 20.0
    aligned_std_ratio: float = 1.5
    aligned_min_level_std_deg: float = 0.01
    aligned_min_heading_std_deg: float = 0.1
    heading_max_limit_std_deg: float = 10.0
    disturbance_nis: float = 10.0

    def __post_init__(self):
        if isinstance(self.specs, str):
            object.__setattr__(self, "specs", grade_specs(self.specs))
        check_model(self.model)
        _check(math.isfinite(self.latitude_deg) and abs(self.latitude_deg) <= 90.0,
               f"latitude_deg must be within [-90, 90], got {self.latitude_deg!r}")
        _check(math.isfinite(self.height_m) and -1e4 < self.height_m < 1e5,
               f"height_m must be within (-10000, 100000) m, got {self.height_m!r}")
        if self.initial_rpy_deg is not None:
            rpy = tuple(float(a) for a in self.initial_rpy_deg)
            _check(len(rpy) == 3 and all(math.isfinite(a) for a in rpy),
                   f"initial_rpy_deg must be 3 finite angles, got {self.initial_rpy_deg!r}")
            object.__setattr__(self, "initial_rpy_deg", rpy)
        for name in ("coarse_velocity_noise", "initial_velocity_std", "backtrack_time",
                     "fine_update_period", "fine_min_velocity_noise", "min_dt_ratio",
                     "max_gap", "max_angular_rate", "specific_force_tolerance",
                     "aligned_std_ratio", "disturbance_nis", "gap_ratio"):
            v = getattr(self, name)
            _check(math.isfinite(v) and v > 0.0, f"{name} must be finite and > 0, got {v!r}")
        for name in ("coarse_initial_std_deg", "fine_initial_std_deg"):
            v = getattr(self, name)
            _check(len(v) == 2 and all(math.isfinite(a) and a > 0 for a in v),
                   f"{name} must be two positive angles (level, heading), got {v!r}")
        _check(self.rate_hz is None or (math.isfinite(self.rate_hz) and self.rate_hz > 0),
               f"rate_hz must be > 0 or None, got {self.rate_hz!r}")
        _check(self.units_check_window == 0.0 or self.units_check_window >= 5.0,
               "units_check_window must be 0 (off) or >= 5 s")
        _check(self.min_dt_ratio < 1.0 < self.gap_ratio,
               "need min_dt_ratio < 1 < gap_ratio")

    def with_(self, **kw) -> "AlignConfig":
        """Copy with some fields replaced (validated again)."""
        return replace(self, **kw)


def _check(ok: bool, msg: str):
    if not ok:
        raise ValueError(msg)


@dataclass
class _Pass:
    """Filter state of one pass."""

    C: np.ndarray                 # C_b^n estimate
    v: np.ndarray                 # velocity estimate, m/s ENU
    P: np.ndarray                 # (6, 6) error covariance from noise (what the gain uses)
    S: np.ndarray                 # (6, 6) sensitivity of the error to ENU biases [accel; gyro]
    fine: bool
    R: np.ndarray                 # (3, 3) measurement noise
    v_sum: np.ndarray = field(default_factory=lambda: np.zeros(3))
    t_acc: float = 0.0            # time accumulated since the last fine update
    t_int: float = 0.0            # integrated time since the pass started
    nis_mean: float = 0.0         # running mean NIS per dof (fine pass)
    updates: int = 0


class Aligner:
    """Streaming SINS self-alignment on a quasi-static base.

    Feed samples with :meth:`update` (one sample or a block); read the result at any time
    from :attr:`quaternion`, :attr:`covariance`, :attr:`aligned` and friends.

    Parameters
    ----------
    config : AlignConfig

    Examples
    --------
    >>> al = Aligner(AlignConfig(latitude_deg=34.0))
    >>> al.update(t, gyro, accel)          # t (N,) s, gyro (N, 3) rad/s, accel (N, 3) m/s^2
    >>> al.quaternion, al.rpy_deg, al.std_enu_deg, al.aligned
    """

    def __init__(self, config: AlignConfig):
        self.config = config
        c = config
        self.lat = c.latitude_deg * DEG
        self.w_ie = earth_rate_enu(self.lat)
        self.g_n = gravity_enu(self.lat, c.height_m)
        self.g = -self.g_n[2]
        sp = c.specs
        self.Qc = np.diag([sp.gyro_arw ** 2] * 3 + [sp.accel_vrw ** 2] * 3)
        self.bias_cov = np.diag([sp.accel_bias ** 2] * 3 + [sp.gyro_bias ** 2] * 3)
        self.Gamma = bias_input_matrix(c.model)
        self.limit_cov = limit_covariance(self.lat, sp, self.g)
        self.limit_std = np.sqrt(np.diag(self.limit_cov))
        self.heading_observable = bool(
            np.isfinite(self.limit_std[2])
            and self.limit_std[2] < c.heading_max_limit_std_deg * DEG)
        self._Fconst = system_matrix("constant", self.w_ie, self.g_n)
        self._disc_cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self.reset()

    # ------------------------------------------------------------------ public state
    def reset(self):
        """Forget everything but the configuration (counters included)."""
        c = self.config
        self.rejected: Counter = Counter()
        self.events: Counter = Counter()
        self.last_reject: str | None = None
        self.samples_used = 0
        self.t_first: float | None = None
        self.t_last: float | None = None
        self._dt_seen: list[float] = []
        self.nominal_dt = 1.0 / c.rate_hz if c.rate_hz else None
        self._units = _UnitsMonitor(self) if c.units_check_window > 0 else None
        self.units_suspect = False
        self._restart_filter()

    def _restart_filter(self):
        c = self.config
        C0 = np.eye(3) if c.initial_rpy_deg is None else dcm_from_rpy(np.array(c.initial_rpy_deg) * DEG)
        self.pass_ = self._new_pass(C0, fine=not c.backtrack and False, std=c.coarse_initial_std_deg,
                                    R=np.eye(3) * c.coarse_velocity_noise ** 2)
        self.stage = "coarse"
        self.backtracked = False
        self.fine_R_std = None
        self._buf = _SampleBuffer() if c.backtrack else None
        self._B = np.eye(3)           # body rotation since the first sample (backtrack)
        self._aligned = False
        self.time_to_aligned: float | None = None

    def _new_pass(self, C0, fine, std, R) -> _Pass:
        P = np.zeros((6, 6))
        lv, hd = std[0] * DEG, std[1] * DEG
        P[:3, :3] = np.diag([lv ** 2, lv ** 2, hd ** 2])
        P[3:, 3:] = np.eye(3) * self.config.initial_velocity_std ** 2
        return _Pass(C=np.array(C0, dtype=float), v=np.zeros(3), P=P, S=np.zeros((6, 6)),
                     fine=fine, R=R)

    @property
    def dcm(self) -> np.ndarray:
        """C_b^n estimate, (3, 3): rotates IMU-frame vectors into ENU."""
        return self.pass_.C

    @property
    def quaternion(self) -> np.ndarray:
        """Orientation of the IMU frame in ENU, [x, y, z, w] (C_b^n, as imu_filter_madgwick)."""
        return quat_from_dcm(self.pass_.C)

    @property
    def rpy_deg(self) -> np.ndarray:
        """REP-103 [roll, pitch, yaw], deg (yaw 0 = x axis East, counter-clockwise)."""
        return rpy_from_dcm(self.pass_.C) / DEG

    @property
    def heading_deg(self) -> float:
        """True heading of the IMU x axis, deg clockwise from North, [0, 360)."""
        return float(heading_from_dcm(self.pass_.C) / DEG)

    @property
    def covariance(self) -> np.ndarray:
        """Published attitude-error covariance (E/N/U, rad^2, phi of paper eq. 15).

        Filter covariance plus the bias-induced part ``S Sigma_b S^T`` for biases drawn from
        the specs (consider analysis). When heading is unobservable the U row/column is
        cleared and its variance set to pi^2.
        """
        P = self._total_cov(self.pass_)[:3, :3]
        if not self.heading_observable:
            P[2, :] = 0.0
            P[:, 2] = 0.0
            P[2, 2] = math.pi ** 2
        return 0.5 * (P + P.T)

    @property
    def std_enu_deg(self) -> np.ndarray:
        """Published one-sigma attitude error per axis (E, N, U), deg."""
        return np.sqrt(np.diag(self.covariance)) / DEG

    @property
    def limit_std_deg(self) -> np.ndarray:
        """Limit accuracy (E, N, U) for the configured bias specs, deg (U may be inf)."""
        return self.limit_std / DEG

    @property
    def nis(self) -> float:
        """Running mean normalised innovation squared per degree of freedom (fine pass)."""
        return self.pass_.nis_mean

    @property
    def disturbed(self) -> bool:
        """True when the innovations no longer fit a quasi-static base (the platform moves)."""
        return self.pass_.fine and self.pass_.updates >= 5 and \
            self.pass_.nis_mean > self.config.disturbance_nis

    @property
    def aligned(self) -> bool:
        """Aligned flag (see :meth:`_aligned_now` for the criteria). Latches until disturbed."""
        return self._aligned

    @property
    def status(self) -> str:
        """One of :data:`STATES`."""
        if self.units_suspect:
            return "fault"
        if self.t_last is None:
            return "waiting"
        if self.disturbed:
            return "disturbed"
        return "aligned" if self._aligned else "aligning"

    @property
    def elapsed(self) -> float:
        """Data time since the first sample, s."""
        return 0.0 if self.t_first is None else self.t_last - self.t_first

    # ------------------------------------------------------------------ input
    def update(self, stamp, gyro, accel) -> int:
        """Process one sample or a block of samples.

        Parameters
        ----------
        stamp : float or ndarray (N,), s — sample times (any epoch, increasing).
        gyro : ndarray (3,) or (N, 3), rad/s — angular rate w_ib^b (REP-145).
        accel : ndarray (3,) or (N, 3), m/s^2 — specific force f^b (level at rest: +g up).

        Returns
        -------
        accepted : int — how many samples were used; the rest are counted in :attr:`rejected`.
        """
        t = np.atleast_1d(np.asarray(stamp, dtype=float))
        w = np.asarray(gyro, dtype=float).reshape(-1, 3)
        f = np.asarray(accel, dtype=float).reshape(-1, 3)
        if not (len(t) == len(w) == len(f)):
            raise ValueError(f"stamp, gyro and accel lengths differ: {len(t)}, {len(w)}, {len(f)}")
        n = 0
        for k in range(len(t)):
            n += self._sample(float(t[k]), w[k], f[k])
        return n

    def _reject(self, reason: str) -> int:
        self.rejected[reason] += 1
        self.last_reject = reason
        return 0

    def _sample(self, t: float, w: np.ndarray, f: np.ndarray) -> int:
        c = self.config
        if not (math.isfinite(t) and np.isfinite(w).all() and np.isfinite(f).all()):
            return self._reject("nonfinite")
        if self.t_last is None:
            # first sample: anchors time only (no interval to integrate over)
            self.t_first = self.t_last = t
            return self._reject_first(w, f)
        dt = t - self.t_last
        if dt == 0.0:
            return self._reject("duplicate_stamp")
        if dt < 0.0:
            return self._reject("stamp_backwards")
        if dt > c.max_gap:
            self.t_last = t
            self.events["time_jump"] += 1
            return self._reject("time_jump")
        if self.nominal_dt is None:
            self._dt_seen.append(dt)
            if len(self._dt_seen) >= 20:
                self.nominal_dt = float(np.median(self._dt_seen))
        nom = self.nominal_dt
        if nom is not None and dt < c.min_dt_ratio * nom:
            return self._reject("dt_too_small")
        fn = float(np.linalg.norm(f))
        if fn < 0.25 * self.g:
            return self._reject("gravity_removed")
        if abs(fn - self.g) > c.specific_force_tolerance * self.g:
            return self._reject("specific_force_out_of_range")
        if float(np.linalg.norm(w)) > c.max_angular_rate:
            return self._reject("rate_too_high")
        if self._units is not None:
            self._units.add(dt, w, f)
            if self.units_suspect:
                self.t_last = t
                return self._reject("rates_look_like_deg_per_s")
        gap = 0.0
        if nom is not None and dt > c.gap_ratio * nom:
            gap, dt = dt - nom, nom
            self.events["gap"] += 1
        self.t_last = t
        self._accept(dt, w, f, gap)
        return 1

    def _reject_first(self, w, f) -> int:
        # The first sample is not integrated; it is not an error either.
        self.events["first_sample"] += 1
        return 0

    # ------------------------------------------------------------------ filter
    def _accept(self, dt: float, w: np.ndarray, f: np.ndarray, gap: float):
        self.samples_used += 1
        if self._buf is not None and not self.backtracked:
            self._buf.append(dt, w, f, gap)
            self._B = self._B @ so3_exp(w * dt)
        self._step(self.pass_, dt, w, f, gap)
        if (self._buf is not None and not self.backtracked
                and self.pass_.t_int >= self.config.backtrack_time):
            self._backtrack()
        self._refresh_aligned()

    def _disc(self, F: np.ndarray, dt: float, const: bool):
        if not const:
            return discretize(F, self.Qc, dt)
        hit = self._disc_cache.get(dt)
        if hit is None:
            hit = discretize(F, self.Qc, dt)
            if len(self._disc_cache) < 64:
                self._disc_cache[dt] = hit
        return hit

    def _step(self, ps: _Pass, dt: float, w: np.ndarray, f: np.ndarray, gap: float = 0.0):
        """One IMU sample: mechanization (eq. 1), covariance propagation, maybe an update."""
        model = self.config.model
        if gap > 0.0:
            self._propagate_cov(ps, self._F(ps, None), gap, model == "constant")
        ps.C = so3_exp(-self.w_ie * dt) @ ps.C @ so3_exp(w * dt)
        fn = ps.C @ f
        ps.v = ps.v + (fn + self.g_n) * dt
        ps.t_int += dt
        F = self._F(ps, fn)
        self._propagate_cov(ps, F, dt, model == "constant")
        H = measurement_matrix(model, ps.v)
        if not ps.fine:
            self._correct(ps, ps.v, H)
            return
        ps.v_sum += ps.v * dt
        ps.t_acc += dt
        if ps.t_acc >= self.config.fine_update_period - 0.5 * dt:
            Ha = averaged_measurement_matrix(H, F, ps.t_acc)
            self._correct(ps, ps.v_sum / ps.t_acc, Ha)
            ps.v_sum = np.zeros(3)
            ps.t_acc = 0.0

    def _F(self, ps: _Pass, fn):
        model = self.config.model
        if model == "constant":
            return self._Fconst
        if fn is None:
            fn = -self.g_n
        return system_matrix(model, self.w_ie, self.g_n, fn, ps.v)

    def _propagate_cov(self, ps: _Pass, F, dt, const):
        """Propagate the noise covariance and the bias sensitivity through one interval."""
        Phi, Qd = self._disc(F, dt, const)
        ps.P = Phi @ ps.P @ Phi.T + Qd
        ps.S = Phi @ ps.S + self.Gamma * dt

    def _total_cov(self, ps: _Pass) -> np.ndarray:
        """Noise covariance plus the bias-induced part (consider covariance), (6, 6)."""
        return ps.P + ps.S @ self.bias_cov @ ps.S.T

    def _correct(self, ps: _Pass, z: np.ndarray, H: np.ndarray):
        Ptot = self._total_cov(ps)
        x, ps.P, K, _ = joseph_update(ps.P, z, H, ps.R)
        ps.S = ps.S - K @ (H @ ps.S)
        nis = float(z @ np.linalg.solve(H @ Ptot @ H.T + ps.R, z))
        ps.C, ps.v = apply_correction(self.config.model, ps.C, ps.v, x)
        ps.updates += 1
        a = 0.1 if ps.updates > 10 else 1.0 / ps.updates
        ps.nis_mean += a * (nis / 3.0 - ps.nis_mean)

    # ------------------------------------------------------------------ backtrack
    def _backtrack(self):
        """Carry the coarse estimate back to the first sample and rerun the fine pass."""
        c = self.config
        ps = self.pass_
        T = ps.t_int
        C0 = so3_exp(self.w_ie * T) @ ps.C @ self._B.T
        dt, w, f, gap = self._buf.arrays()
        r_std = self._sway_velocity_std(C0, dt, w, f, gap)
        self.fine_R_std = r_std
        fine = self._new_pass(C0, fine=True, std=c.fine_initial_std_deg, R=np.diag(r_std ** 2))
        for k in range(len(dt)):
            self._step(fine, dt[k], w[k], f[k], gap[k])
        self.pass_ = fine
        self.stage = "fine"
        self.backtracked = True
        self._buf = None

    def _sway_velocity_std(self, C0, dt, w, f, gap) -> np.ndarray:
        """Measured std (E, N, U) of the fine-pass measurement: interval-mean velocity noise.

        Open-loop damped mechanization from ``C0`` over the buffer; a cubic per axis removes
        the drift due to the remaining attitude error; what is left is the sway velocity
        plus the VRW-driven wander. The variance of first differences of its interval means
        (halved) estimates the white part seen by the fine update. Floored by the VRW term
        and ``fine_min_velocity_noise``.
        """
        c = self.config
        Wn = {}
        C = C0.copy()
        v = np.zeros(3)
        vs = np.empty((len(dt), 3))
        for k in range(len(dt)):
            d = dt[k]
            E = Wn.get(d)
            if E is None:
                E = Wn.setdefault(d, so3_exp(-self.w_ie * d))
            C = E @ C @ so3_exp(w[k] * d)
            v = v + (C @ f[k] + self.g_n) * d
            vs[k] = v
        t = np.cumsum(dt)
        period = c.fine_update_period
        idx = np.floor(t / period).astype(int)
        n_int = idx[-1]
        floor2 = c.specs.accel_vrw ** 2 * period / 3.0 + c.fine_min_velocity_noise ** 2
        if n_int < 8:
            return np.full(3, math.sqrt(floor2))
        tn = (t - t.mean()) / (t.std() + 1e-12)
        A = np.vander(tn, 4)
        coef, *_ = np.linalg.lstsq(A, vs, rcond=None)
        res = vs - A @ coef
        keep = idx < n_int
        counts = np.bincount(idx[keep], minlength=n_int)
        means = np.stack([np.bincount(idx[keep], weights=res[keep, j], minlength=n_int)
                          for j in range(3)], axis=1) / np.maximum(counts, 1)[:, None]
        var = 0.5 * np.mean(np.diff(means, axis=0) ** 2, axis=0)
        return np.sqrt(np.maximum(var, floor2))

    # ------------------------------------------------------------------ aligned flag
    def _aligned_now(self) -> bool:
        """Criteria: fine pass running (or backtrack off), no fault, not disturbed, and the
        published std of every observable axis below max(ratio x limit, absolute minimum)."""
        c = self.config
        if self.units_suspect or self.disturbed:
            return False
        if c.backtrack and not self.backtracked:
            return False
        std = np.sqrt(np.diag(self.covariance))
        lim = self.limit_std
        thr_level = max(c.aligned_std_ratio * lim[0], c.aligned_min_level_std_deg * DEG)
        ok = std[0] <= thr_level and std[1] <= max(c.aligned_std_ratio * lim[1],
                                                   c.aligned_min_level_std_deg * DEG)
        if self.heading_observable:
            ok = ok and std[2] <= max(c.aligned_std_ratio * lim[2],
                                      c.aligned_min_heading_std_deg * DEG)
        return bool(ok)

    def _refresh_aligned(self):
        if self.units_suspect or self.disturbed:
            self._aligned = False
            return
        if not self._aligned and self._aligned_now():
            self._aligned = True
            if self.time_to_aligned is None:
                self.time_to_aligned = self.elapsed

    # ------------------------------------------------------------------ summary
    def summary(self) -> dict:
        """A JSON-ready snapshot of the result (used by the node diagnostics and the replay)."""
        return {
            "status": self.status,
            "stage": self.stage,
            "aligned": self.aligned,
            "time_to_aligned_s": self.time_to_aligned,
            "elapsed_s": self.elapsed,
            "samples_used": self.samples_used,
            "rejected": dict(self.rejected),
            "events": dict(self.events),
            "heading_observable": self.heading_observable,
            "orientation_xyzw": self.quaternion.tolist(),
            "rpy_deg": self.rpy_deg.tolist(),
            "heading_deg": self.heading_deg,
            "std_enu_deg": self.std_enu_deg.tolist(),
            "limit_std_enu_deg": [float(x) for x in self.limit_std_deg],
            "fine_velocity_noise_mps": None if self.fine_R_std is None else self.fine_R_std.tolist(),
            "nis": self.nis,
        }


class _SampleBuffer:
    """Growable store of accepted samples [dt, w(3), f(3), gap] for the backtrack."""

    def __init__(self):
        self._a = np.empty((4096, 8))
        self._n = 0

    def append(self, dt, w, f, gap):
        if self._n == len(self._a):
            self._a = np.concatenate([self._a, np.empty_like(self._a)])
        row = self._a[self._n]
        row[0] = dt
        row[1:4] = w
        row[4:7] = f
        row[7] = gap
        self._n += 1

    def arrays(self):
        a = self._a[: self._n]
        return a[:, 0], a[:, 1:4], a[:, 4:7], a[:, 7]


class _UnitsMonitor:
    """Detects gyro rates that are not rad/s (deg/s is 57.3x too large).

    Over each window the tilt change predicted by integrating the gyro is compared with the
    tilt change seen by the accelerometer (direction of the mean specific force in the first
    and last second). On a quasi-static base they agree to within Earth rate, gyro bias and
    linear-acceleration effects; rates scaled by 57.3 break that by degrees per second.
    """

    TOL = 3.0 * DEG

    def __init__(self, al: Aligner):
        self.al = al
        self.window = al.config.units_check_window
        self.allow = OMEGA_IE + 3.0 * al.config.specs.gyro_bias
        self._start()

    def _start(self):
        self.T = 0.0
        self.B = np.eye(3)
        self.f_head = np.zeros(3)
        self.f_tail = np.zeros(3)

    def add(self, dt, w, f):
        self.B = self.B @ so3_exp(w * dt)
        self.T += dt
        if self.T <= 1.0:
            self.f_head += f * dt
        if self.T > self.window - 1.0:
            self.f_tail += f * dt
        if self.T >= self.window:
            a = self.f_head / np.linalg.norm(self.f_head)
            b = self.f_tail / np.linalg.norm(self.f_tail)
            pred = self.B.T @ a
            err = math.acos(max(-1.0, min(1.0, float(pred @ b))))
            bad = err > self.allow * self.T + self.TOL
            if bad and not self.al.units_suspect:
                self.al.units_suspect = True
                self.al._restart_filter()
            elif not bad:
                self.al.units_suspect = False
            self.last_mismatch_deg = err / DEG
            self._start()
