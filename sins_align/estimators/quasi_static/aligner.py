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
import statistics
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from sins_align.core.earth import OMEGA_IE, earth_rate_enu, gravity_enu
from sins_align.core.kalman import affine_scan, discretize, inv3, joseph_update, nis, riccati_steps
from sins_align.estimators.quasi_static.inertial import inertial_alignment
from sins_align.core.models import (apply_correction, averaged_measurement_matrix,
                                    bias_input_matrix, check_model, measurement_matrix,
                                    system_matrix)
from sins_align.core.preint import (earth_poly, open_loop_velocity, preintegrate, scratch_array,
                     start_frame_increments)
from sins_align.core.rotation import (dcm_from_quat, dcm_from_rpy, heading_from_dcm, quat_from_dcm,
                                      rpy_from_dcm, so3_exp, so3_exp_entries, so3_log)
from sins_align.core.specs import DEG, SensorSpecs, grade_specs, limit_covariance

#: Reasons a sample can be rejected. A rejected sample never touches the filter state.
REJECT_REASONS = (
    "nonfinite",                  # NaN or Inf in stamp, rate or specific force
    "duplicate_stamp",            # same stamp as the previous accepted sample
    "stamp_backwards",            # stamp earlier than the previous accepted sample
    "dt_too_small",               # 0 < dt < min_dt_ratio * nominal interval
    "time_jump",                  # dt > max_gap: time re-anchored, state kept
    "gravity_removed",            # |f| < 0.25 g: the driver removed gravity
    "specific_force_out_of_range",  # ||f| - g| > specific_force_tolerance * g for longer
                                  # than FORCE_SHOCK_TIME (shorter: a shock, used)
    "rate_too_high",              # |w| > max_angular_rate (deg/s sent as rad/s, or real motion)
    "rates_look_like_deg_per_s",  # gyro/accelerometer tilt mismatch: rates scaled by 57.3
    "undecodable",                # (align_node) a message whose bytes could not be decoded
)

#: blocks of at least this many clean samples take the fast path in Aligner.update
FAST_MIN_BLOCK = 64
FAST_MAX_BLOCK = 65536
#: samples in a row that must agree on a new time line before it is taken (a time jump)
JUMP_CONFIRM = 3
#: an interval above this multiple of the nominal one means samples are missing
HOLE_RATIO = 1.5
#: s: with heading unobservable, the gyro bias is attitude noise reaching its size in this time
BIAS_TRACK_TIME = 10.0
#: s: a specific force out of range for at most this long is a shock: the sample is used, its
#: velocity increment with a variance (event 'force_out_of_range'); longer, they are rejected
FORCE_SHOCK_TIME = 1.0

#: gain schedules of the constant model, shared between filter instances (see _cov_block)
_SCHEDULE_CACHE: dict = {}
_SCHEDULE_CACHE_MAX = 20000         # cached steps, about 1 kB each (a 10 min bag: 1200)
_SCHEDULE_SIZE = 0
#: samples x runs pre-integrated at once by the fast path (bounds its temporaries)
_PIECE_SAMPLE_RUNS = 1 << 18
_THIRDS = np.full(3, 1.0 / 3.0)     # NIS per degree of freedom

STATES = ("waiting", "aligning", "aligned", "disturbed", "fault")

#: What an Aligner tells its subscribers (:meth:`Aligner.subscribe`).
EVENT_KINDS = (
    "aligned",      # the aligned flag changed; value: the new flag
    "restarted",    # the alignment started over; value: why
    "rejected",     # a sample was rejected; value: the reason (REJECT_REASONS)
)


@dataclass(frozen=True)
class AlignmentEvent:
    """One event of an :class:`Aligner`: ``kind`` (EVENT_KINDS), ``stamp`` (s, of the sample
    being processed; None when there is none) and ``value`` (the new flag, or a reason)."""
    kind: str
    stamp: float | None
    value: bool | str


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
    coarse_velocity_noise : m/s, measurement noise std of a coarse-pass update 0.01 s apart;
        for an interval D it is scaled by sqrt(0.01 / D), so the noise density (and the
        behaviour) does not depend on the IMU rate or the update interval.
    coarse_update_period : s between coarse-pass updates (the instantaneous zero-velocity
        measurement of the paper); 0 = at every sample, as in the paper.
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
        for one nominal interval and the rest is bridged as static. Any hole (dt above 1.5
        nominal intervals) grows the covariance by what the recent motion could have done
        in that time.
    max_gap : s; a larger dt is a time jump: the sample is rejected and time re-anchored.
    max_angular_rate : rad/s; larger rates are rejected.
    specific_force_tolerance : fraction of g allowed between |f| and g; beyond it for at most
        FORCE_SHOCK_TIME the samples are a shock (used, the velocity taking the variance of
        a possible accelerometer glitch), for longer they are rejected.
    units_check_window : s; gyro tilt vs accelerometer tilt check window (0 = off).
    aligned_std_ratio : aligned when every observable axis std <= this x limit std ...
    aligned_min_level_std_deg, aligned_min_heading_std_deg : ... or below these absolute values.
    heading_max_limit_std_deg : heading counts as observable when its limit std is below this.
    disturbance_nis : mean NIS per dof above which the platform counts as disturbed (moving).
    reinflate_nis : coarse pass: mean NIS per dof above which the covariance is re-inflated to
        its initial value (the error is far larger than the filter believes: a large-angle
        transient).
    reinflate_holdoff : s between two re-inflations of the same run.
    gate_nis : fine pass: an update whose NIS (3 dof, chi-square when the model fits)
        exceeds this is not applied (a shove, a door slam: the model cannot explain it);
        the state and covariance coast over it. When the next one is out of the gate too,
        the velocity variance is grown by the innovation and the update applied (a lasting
        velocity error). Default: the 0.999 chi-square quantile.
    reinflate_gated_time : fine pass: s of consecutive gated updates after which the
        attitude is taken to have really changed (re-levelled, moved): the covariance is
        re-inflated to the fine pass's initial value (plus the velocity the innovations
        show), so the aligned flag drops and the filter re-converges.
    """

    latitude_deg: float
    height_m: float = 0.0
    model: str = "constant"
    specs: SensorSpecs | str = "navigation"
    initial_rpy_deg: tuple[float, float, float] | None = None
    coarse_velocity_noise: float = 0.01
    coarse_update_period: float = 0.1
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
    units_check_window: float = 30.0
    aligned_std_ratio: float = 1.5
    aligned_min_level_std_deg: float = 0.01
    aligned_min_heading_std_deg: float = 0.1
    heading_max_limit_std_deg: float = 10.0
    disturbance_nis: float = 3.0
    reinflate_nis: float = 100.0
    reinflate_holdoff: float = 5.0
    gate_nis: float = 16.27
    reinflate_gated_time: float = 5.0

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
                     "aligned_std_ratio", "disturbance_nis", "gap_ratio", "reinflate_nis",
                     "reinflate_holdoff", "gate_nis", "reinflate_gated_time"):
            v = getattr(self, name)
            _check(math.isfinite(v) and v > 0.0, f"{name} must be finite and > 0, got {v!r}")
        for name in ("coarse_initial_std_deg", "fine_initial_std_deg"):
            v = getattr(self, name)
            _check(len(v) == 2 and all(math.isfinite(a) and a > 0 for a in v),
                   f"{name} must be two positive angles (level, heading), got {v!r}")
        _check(math.isfinite(self.coarse_update_period)
               and 0.0 <= self.coarse_update_period <= 10.0,
               f"coarse_update_period must be within [0, 10] s, got {self.coarse_update_period!r}")
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


class AlignmentFilter:
    """The filter itself, vectorised over N independent runs that share one time line.

    No input checking: callers hand it accepted samples only. :class:`Aligner` (N = 1)
    wraps it for streaming data; Monte Carlo and batch tools drive N runs at once. With
    the 'constant' model the coarse-pass covariance and gain do not depend on the data,
    so they are computed once and shared by all runs (shape (1, 6, 6)).

    Parameters
    ----------
    config : AlignConfig
    C0 : ndarray (N, 3, 3) — initial C_b^n estimate of each run.
    fast_backtrack : re-run the buffer with the fast path when it is uniformly sampled
        (constant model); False keeps the whole run on the per-sample reference path.
    """

    def __init__(self, config: AlignConfig, C0: np.ndarray, fast_backtrack: bool = True):
        self.config = c = config
        self.fast_backtrack = fast_backtrack
        self.lat = c.latitude_deg * DEG
        self.w_ie = earth_rate_enu(self.lat)
        self.g_n = gravity_enu(self.lat, c.height_m)
        self.g = -self.g_n[2]
        sp = c.specs
        self.limit_std = np.sqrt(np.diag(limit_covariance(self.lat, sp, self.g)))
        q_att = sp.gyro_arw ** 2
        if not (self.limit_std[2] < c.heading_max_limit_std_deg * DEG):
            # heading unobservable (MEMS): a gyro bias of degrees per minute turns the level
            # faster than the gyro noise alone lets the filter follow; without bias states
            # it would lag, be gated and diverge. The bias enters as attitude noise that
            # reaches its own size over BIAS_TRACK_TIME.
            q_att += sp.gyro_bias ** 2 * BIAS_TRACK_TIME
        self.Qc = np.diag([q_att] * 3 + [sp.accel_vrw ** 2] * 3)
        self._bias_var = np.array([sp.accel_bias ** 2] * 3 + [sp.gyro_bias ** 2] * 3)
        self.Gamma = bias_input_matrix(c.model)
        self._Fconst = system_matrix("constant", self.w_ie, self.g_n)
        self._K, self._W = earth_poly(self.w_ie)
        self._K2 = self._K @ self._K
        # (3, 9): column 3 k + i holds column i of M_k, M = I, K, K^2 (see _advance_segments)
        self._g_col = self.g_n[:, None]
        self._Gv = np.stack([np.eye(3), self._K, self._K2]).transpose(1, 0, 2).reshape(3, 9)
        self._cache: dict = {}
        self._scratch: dict = {}       # the fast path's large temporaries, reused (scratch_array)
        self.on_update = None          # fast path: called with the sample index after updates
        self._rerun = False
        self._cfg_key = (c.model, self.w_ie.tobytes(), self.g_n.tobytes(), self.Qc.tobytes(),
                         self._bias_var.tobytes())
        self.fast = False
        C0 = np.asarray(C0, dtype=float).reshape(-1, 3, 3)
        self.n = len(C0)
        self._start_pass(C0, fine=False, std=c.coarse_initial_std_deg,
                         R=np.eye(3)[None] * c.coarse_velocity_noise ** 2)
        self.stage = "coarse"
        self.backtracked = False
        self.fine_R_std: np.ndarray | None = None
        self.fine_period = c.fine_update_period
        self._steady_start = None
        self._steady_std = None
        self._buf = _SampleBuffer(self.n) if c.backtrack else None
        self._B = np.broadcast_to(np.eye(3), (self.n, 3, 3)).copy()
        self.reinflations = np.zeros(self.n, dtype=int)
        self.gated_updates = np.zeros(self.n, dtype=int)
        # the fine pass started from the inertial-frame alignment (inertial.py)
        self.started_inertial = np.zeros(self.n, dtype=bool)

    # ------------------------------------------------------------------ state
    def _start_pass(self, C0, fine: bool, std, R, v0=None):
        """``std``: (level, heading) deg shared by all runs, or the initial (attitude E, N,
        U rad; velocity E, N, U m/s) std per run, (N, 6). ``v0``: initial velocity (N, 3)."""
        if isinstance(std, np.ndarray) and std.ndim == 2:
            P = np.zeros((len(std), 6, 6))
            P[:, range(6), range(6)] = std ** 2
        else:
            lv, hd = std[0] * DEG, std[1] * DEG
            P = np.zeros((1, 6, 6))
            P[0, :3, :3] = np.diag([lv ** 2, lv ** 2, hd ** 2])
            P[0, 3:, 3:] = np.eye(3) * self.config.initial_velocity_std ** 2
        self.C = np.array(C0, dtype=float)
        self.v = np.zeros((self.n, 3)) if v0 is None else np.array(v0, dtype=float)
        self.P0 = P
        self.P = P                     # noise covariance, (1|N, 6, 6): what the gain uses
        self.S = np.zeros((1, 6, 6))   # sensitivity of the error to ENU biases [accel; gyro]
        self.R = R                     # measurement noise, (1|N, 3, 3)
        self.fine = fine
        self.v_sum = np.zeros((self.n, 3))
        self.t_acc = 0.0               # time since the last fine update
        self.t_int = 0.0               # integrated time since this pass started
        self.nis_mean = np.zeros(self.n)
        self.updates = 0
        self.last_reinflate = np.zeros(self.n)
        self.gate_start = np.full(self.n, np.nan)   # t_int of the first gated update in a row
        self._gated = None             # runs whose last update was gated (None: none)
        self._absorb = None            # runs whose last update absorbs a velocity error
        self._inflate = None           # runs to re-inflate after the last update (fine pass)
        self._z = None                 # innovation of the last update out of the gate
        self._node = None              # position in the gain-schedule cache (None: unknown)

    def total_covariance(self) -> np.ndarray:
        """Noise covariance plus the bias-induced part ``S Sigma_b S^T``, (1|N, 6, 6)."""
        return self._with_bias(self.P, self.S)

    def _with_bias(self, P, S):
        """P + S Sigma_b S^T (Sigma_b diagonal: the bias variances of the specs)."""
        return P + (S * self._bias_var) @ S.mT

    # ------------------------------------------------------------------ one sample
    def step(self, dt: float, w: np.ndarray, f: np.ndarray, gap: float = 0.0, dR=None,
             hole=(0.0, 0.0), bridge=None):
        """One accepted IMU sample for every run: w, f (N, 3); dt, gap shared (s).
        ``dR``: exp(w dt) (N, 3, 3), when the caller has it already. ``hole``: (attitude
        rad^2, velocity (m/s)^2) variance per axis of what the motion could have done in
        ``gap`` seconds of missing samples (added to the covariance, see :meth:`_advance`).
        ``bridge``: (rate, specific force) in body axes (3,) each that stand in for the gap's
        missing samples (the recent means; None: the state is held)."""
        if dR is None:
            dR = so3_exp(w * dt)
        if self._buf is not None and not self.backtracked:
            self._buf.append(dt, w, f, gap, hole, bridge)
            if gap > 0.0 and bridge is not None:
                self._B = self._B @ so3_exp(np.asarray(bridge[0], float) * gap)
            self._B = self._B @ dR
        self._advance(dt, w, f, gap, dR, hole, bridge)
        if self._backtrack_due(dt):
            self.backtrack()

    def _backtrack_due(self, dt: float) -> bool:
        return (self._buf is not None and not self.backtracked
                and self.t_int >= self.config.backtrack_time - 0.5 * dt)

    def run(self, dt, w: np.ndarray, f: np.ndarray):
        """Many samples through :meth:`step` one by one (the reference path).

        dt scalar or (T,), w and f (T, N, 3) (or (T, 3) when N = 1).
        """
        w = np.asarray(w, dtype=float).reshape(len(w), self.n, 3)
        f = np.asarray(f, dtype=float).reshape(len(f), self.n, 3)
        dts = np.broadcast_to(np.asarray(dt, dtype=float), (len(w),))
        for k in range(len(w)):
            self.step(float(dts[k]), w[k], f[k])

    # ------------------------------------------------------------------ fast path
    def run_fast(self, dt, w: np.ndarray, f: np.ndarray):
        """Many samples: same result as :meth:`run`, much faster.

        ``dt`` is one interval for all samples, or one per sample (T,) for jittered stamps
        (each within 40 % of their mean). Between updates the mechanization is integrated in
        closed form from vectorised sums (:mod:`sins_align.core.preint`) and the covariance jumps
        over the whole interval, so the Python work is per update, not per sample. The
        update schedule, the backtrack and every update are those of :meth:`run`; the
        results agree to rounding (test_fast_path). Models other than 'constant' (whose F
        depends on the state at every sample) go through :meth:`run`.
        """
        w = np.asarray(w, dtype=float).reshape(len(w), self.n, 3)
        f = np.asarray(f, dtype=float).reshape(len(f), self.n, 3)
        dts = np.broadcast_to(np.asarray(dt, dtype=float), (len(w),))
        if self.config.model != "constant" or len(w) == 0:
            self.run(dts, w, f)
            return
        mean = float(dts.mean())
        if np.all(np.abs(dts - mean) <= 1e-9 * mean):
            # uniform: the cached m-step schedule applies; 12 significant digits make the
            # mean of stamp differences the same number from one block to the next
            dts = float(f"{mean:.12g}")
        elif not np.all(np.abs(dts - mean) <= 0.4 * mean):
            raise ValueError("run_fast: sample intervals vary by more than 40 %")
        self.fast = True
        k, T = 0, len(w)
        while k < T:
            end = T
            if self._buf is not None and not self.backtracked:
                end = k + self._samples_until(self.config.backtrack_time - self.t_int,
                                              _part(dts, k, T))
                self._buf.extend(_part(dts, k, end), w[k:end], f[k:end])
            self._advance_block(_part(dts, k, end), w[k:end], f[k:end],
                                track_B=not self.backtracked and self._buf is not None,
                                offset=k)
            k = end
            if self._backtrack_due(_last(dts, end)):
                self.backtrack()
                if self.on_update is not None:
                    self.on_update(end - 1)

    @staticmethod
    def _samples_until(left: float, dts) -> int:
        """How many samples until an accumulated time reaches ``left`` (the per-sample
        rule: t + dt_j >= left - dt_j / 2), at least 1, at most all of them."""
        if np.ndim(dts) == 0:
            return max(1, int(math.ceil((left - 0.5 * dts) / dts - 1e-9)))
        key = np.cumsum(dts) + 0.5 * dts            # increasing: intervals within 40 %
        return min(len(dts), int(np.searchsorted(key, left - 1e-12)) + 1)

    def _period(self) -> float:
        return self.fine_period if self.fine else self.config.coarse_update_period

    def _advance_block(self, dt, w, f, track_B: bool = False, offset: int | None = None):
        """Samples through the mechanization and the updates they contain.

        ``dt``: one interval (float) or one per sample (T,).
        """
        period = self._period()
        T = len(w)
        left = period - self.t_acc
        if np.ndim(dt) == 0:                # uniform: every interval after the first is alike
            m0 = min(T, self._samples_until(left, dt))
            mp = self._samples_until(period, dt)
            full, rest = divmod(T - m0, mp)
            lengths = [m0] + [mp] * full + ([rest] if rest else [])
        else:
            lengths, k = [], 0
            while k < T:
                m = min(T - k, self._samples_until(left, _part(dt, k, T)))
                lengths.append(m)
                k += m
                left = period
        # pieces of about _PIECE_SAMPLE_RUNS sample-runs keep the pre-integrated sums small
        per = max(1, _PIECE_SAMPLE_RUNS // self.n)
        starts = np.concatenate([[0], np.cumsum(lengths)])
        a = 0
        while a < len(lengths):
            b = int(np.searchsorted(starts, starts[a] + per, side="right")) - 1
            b = min(len(lengths), max(b, a + 1))
            i0, i1 = int(starts[a]), int(starts[b])
            self._advance_segments(_part(dt, i0, i1), w[i0:i1], f[i0:i1],
                                   np.array(lengths[a:b]), track_B,
                                   None if offset is None else offset + i0)
            a = b

    def _advance_segments(self, dt, w, f, lengths, track_B: bool, offset: int | None):
        """Samples cut into update intervals (``lengths``): pre-integration of all of them,
        then the intervals one by one (mechanization in closed form, update when due).

        In the loop the state is component-major, the attitude transposed:
        ``Ct[k, i, n] = C[i, k, n]`` and ``v[:, n]`` for run n, so that each product of
        per-run 3x3 matrices is one einsum over contiguous rows of the N runs (a plain
        matrix product for one run), and each product with a matrix shared by all runs is
        one GEMM. Every array of N runs is written into a reused scratch array (no page
        faults per update).
        """
        period = self._period()
        uniform = np.ndim(dt) == 0
        sc = self._scratch
        B, segT, sdt = preintegrate(dt, w, f, lengths, self._W, self.fine, sc)
        if uniform:
            self._prefetch_schedule(lengths, dt)
        # P = C0 B[i] row by row: P[k] = C0 times column k of B[i] (Qm, then A0 Aa Ab, then
        # V0 Va Vb); the velocity increment sum_k M_k C0 A_k is G @ P[3:6] as (9, N) rows
        G = self._Gv
        H = measurement_matrix("constant")
        ends = np.cumsum(lengths).tolist()
        n = self.n
        P = scratch_array(sc, "P", (B.shape[2], 3, n))
        Ct, X = (scratch_array(sc, name, (3, 3, n)) for name in ("C", "X"))
        v, vs, inc = (scratch_array(sc, name, (3, n)) for name in ("v", "v_sum", "inc"))
        x = scratch_array(sc, "x", (6, n))
        Ct[...] = self.C.transpose(2, 1, 0)
        v[...] = self.v.T
        vs[...] = self.v_sum.T
        if track_B:
            Bt, BX = (scratch_array(sc, name, (3, 3, n)) for name in ("Bt", "BX"))
            Bt[...] = self._B.transpose(2, 1, 0)
        P_Qm, P_A = P[:3], P[3:6].reshape(9, n)
        P_V = P[6:9].reshape(9, n) if self.fine else None
        earth = {}                                   # uniform: E and g T of each length m
        for i, m in enumerate(lengths.tolist()):
            if uniform:
                Ti, dti = m * dt, dt
                E, gT = earth.get(m) or earth.setdefault(
                    m, (self._earth_rot(m, dt), self._g_col * Ti))
            else:
                Ti, dti = float(segT[i]), float(dt[ends[i] - 1])
                E, gT = so3_exp(-self.w_ie * Ti), self._g_col * Ti
            _rows_times(Ct, B[i], P)
            np.matmul(E, P_Qm, out=X)                        # (E C0 Qm)^T
            if track_B:
                _rows_times(Bt, B[i, :, :3], BX)
                Bt, BX = BX, Bt
            if self.fine:
                vs += v * Ti
                vs += np.matmul(G, P_V, out=inc)
                vs += self._g_col * (dt * dt * m * (m + 1) / 2.0 if uniform else float(sdt[i]))
            v += np.matmul(G, P_A, out=inc)
            v += gT
            self.t_int += Ti
            self.t_acc += Ti
            jumps = (lambda: self._disc_m(m, dt)) if uniform else (
                lambda: self._disc_var(_part(dt, ends[i] - m, ends[i])))
            Hu, scale = self._update_due(self.t_acc, period, dti, H, uniform)
            if Hu is None:                          # partial interval: no update yet
                self._cov_block(m, dt, None, 0.0, jumps)
                Ct, X = X, Ct
                continue
            before = self.P, self.S, self._node
            Kg, Sinv = self._cov_block(m, dt, Hu, scale, jumps)
            if self.fine:
                self._innovate(vs / self.t_acc, Kg, Sinv, out=x)
                vs[...] = 0.0
            else:
                self._innovate(v, Kg, Sinv, out=x)
            self._settle(lambda: self._coast(before, m, dt, jumps), Hu, scale, x)
            # feedback (models.apply_correction, constant model): C <- exp(phi x) C, v -= dv
            if n == 1:                                        # nine floats
                R = np.array(so3_exp_entries(*x[:3, 0].tolist()))
            else:
                R = np.stack(so3_exp_entries(x[0], x[1], x[2]), out=scratch_array(sc, "R", (9, n)))
            _times_rows(R.reshape(3, 3, n), X, Ct)
            if self.fine:                       # the velocity turns with the attitude
                v[...] = np.einsum("ijn,jn->in", R.reshape(3, 3, n), v)
            v -= x[3:]
            self.t_acc = 0.0
            if self.on_update is not None and offset is not None:
                self.C, self.v = Ct.transpose(2, 1, 0).copy(), v.T.copy()   # the state now
                self.on_update(offset + ends[i] - 1)
        self.C = np.ascontiguousarray(Ct.transpose(2, 1, 0))
        self.v = v.T.copy()              # copies: v and vs are scratch, reused next call
        self.v_sum = vs.T.copy()
        if track_B:
            self._B = np.ascontiguousarray(Bt.transpose(2, 1, 0))

    def _coast(self, before, m: int, dt, jumps):
        """P and S propagated over the interval from ``before`` (P, S, cache node) with no
        update: what a gated update leaves (fast path)."""
        self.P, self.S, self._node = before
        self._cov_block(m, dt, None, 0.0, jumps)
        return self.P, self.S

    def _update_due(self, t_acc: float, period: float, dt: float, H, cache: bool = True):
        """(H, R scale) of the fast path's update after ``t_acc`` s of the current interval
        (last sample interval ``dt``), or (None, 0.0) when none is due yet: the coarse
        pass's instantaneous velocity (``H``, R scaled to the interval), the fine pass's
        mean velocity over it."""
        if t_acc < period - 0.5 * dt:
            return None, 0.0
        if self.fine:
            return self._averaged_H(t_acc, cache), 1.0
        return H, 0.01 / t_acc

    def _averaged_H(self, period: float, cache: bool):
        """H of the fine pass's mean-velocity measurement over ``period`` s (constant model)."""
        Ha = self._cache.get(("Ha", period))
        if Ha is None:
            Ha = averaged_measurement_matrix(measurement_matrix("constant"), self._Fconst, period)
            if cache:
                self._cache[("Ha", period)] = Ha
        return Ha

    def _prefetch_schedule(self, lengths: np.ndarray, dt: float, most: int = 4096):
        """Put the gain schedule of the coming intervals (uniform ``dt``) into the cache.

        :meth:`_advance_segments` then finds every step there, as in a warm run. The steps
        already cached are walked over; from the first missing one, each run of identical
        steps (same length, H and R) is computed at once: the covariance and gain by
        :func:`kalman.riccati_steps`, the bias sensitivity S by :func:`kalman.affine_scan`,
        the NIS covariance batched. This replaces about 30 us of Python and numpy calls per
        step; the values agree with the step-by-step recursion to about 1e-9 (relative to
        sqrt(P_ii P_jj), see riccati_steps; the attitude to about 1e-12 rad). At most
        ``most`` steps a call: the loop computes any others step by step, as before.
        """
        node = self._node if self._node is not None else self._schedule_root()
        if node is None:
            return
        global _SCHEDULE_SIZE
        if _SCHEDULE_SIZE + min(len(lengths), most) > _SCHEDULE_CACHE_MAX:
            _SCHEDULE_CACHE.clear()         # before the walk, and a root the loop will find
            _SCHEDULE_SIZE = 0
            node = self._node if self._node is not None else self._schedule_root()
        period, t_acc = self._period(), self.t_acc
        H0 = measurement_matrix("constant")
        plan = []
        for m in lengths.tolist()[:most]:
            t_acc += m * dt
            plan.append((m, *self._update_due(t_acc, period, dt, H0)))
            if plan[-1][1] is not None:
                t_acc = 0.0
        keys = [(m, dt, sc, None if H is None else H.tobytes()) for m, H, sc in plan]
        P, S, i = self.P[0], self.S[0], 0
        while i < len(keys):                        # the part of the chain already built
            hit = node.get(keys[i])
            if hit is None:
                break
            P, S, node = hit[0][0], hit[1][0], hit[4]
            i += 1
        while i < len(keys):
            j = i + 1
            while j < len(keys) and keys[j] == keys[i]:
                j += 1
            m, H, scale = plan[i]
            Phi, Qd, Gm = self._disc_m(m, dt)
            if H is None:
                steps = []
                for _ in range(j - i):
                    P, S = Phi @ P @ Phi.T + Qd, Phi @ S + Gm
                    steps.append((P[None], S[None], None, None))
            else:
                Ps, Ks, Sn = riccati_steps(P, Phi, Qd, H, self.R[0] * scale, j - i)
                IKH = np.eye(6) - Ks @ H
                Ss = affine_scan(IKH @ Phi, IKH @ Gm, S)
                HS = H @ (Phi @ np.concatenate([S[None], Ss[:-1]]) + Gm)  # H S before update
                Ns = inv3(Sn + (HS * self._bias_var) @ HS.mT)
                P, S = Ps[-1], Ss[-1]
                # entries of shape (1, ...): iterating over (n, 1, ...) arrays gives them
                steps = zip(Ps[:, None], Ss[:, None], Ks[:, None], Ns[:, None])
            for key, step in zip(keys[i:j], steps):
                nxt = {}
                node[key] = (*step, nxt)
                node = nxt
            _SCHEDULE_SIZE += j - i
            i = j

    def _disc_var(self, dts: np.ndarray):
        """Transition, process noise and bias input over samples of varying interval: what
        the per-sample recursion composes to (Phi and Qd exactly, the bias input as its
        Riemann sum, both to fourth order in F)."""
        T = float(dts.sum())
        Phi, Qd = discretize(self._Fconst, self.Qc, T)
        r = T - np.cumsum(dts)                      # time left after each sample
        F, G = self._Fconst, self.Gamma
        FG = F @ G
        F2G = F @ FG
        Gm = G * T + FG * float(r @ dts) + F2G * float((r * r) @ dts / 2.0) \
            + F @ F2G * float((r ** 3) @ dts / 6.0)
        return Phi, Qd, Gm

    def _cov_block(self, m: int, dt, H, scale: float, jumps=None):
        """Propagate P and S over m samples and, unless H is None, do the covariance part
        of an update (returns its gain and inverse innovation covariance).

        With one covariance shared by all runs (the constant model: it does not depend on
        the data) the result only depends on the covariance at the start of the pass and
        on the steps since, so the schedule is kept as a chain in a bounded module-level
        cache: a second run of the same configuration (the next bag, the next Monte Carlo
        batch) reuses the whole gain schedule, and a step costs one dictionary look-up.
        """
        node = None
        if not isinstance(dt, np.ndarray):           # uniform intervals: cacheable
            node = self._node if self._node is not None else self._schedule_root()
        self._node = None                            # P and S are about to move on
        if node is not None:
            key = (m, dt, scale, None if H is None else H.tobytes())
            hit = node.get(key)
            if hit is not None:
                self.P, self.S, K, Sinv, self._node = hit
                return K, Sinv
        Phi, Qd, Gm = jumps() if jumps is not None else self._disc_m(m, dt)
        self.P = Phi @ self.P @ Phi.T + Qd
        self.S = Phi @ self.S + Gm
        K = Sinv = None
        if H is not None:
            K, Sinv = self._gain(H, scale)
        if node is not None:
            global _SCHEDULE_SIZE
            _SCHEDULE_SIZE += 1
            if _SCHEDULE_SIZE > _SCHEDULE_CACHE_MAX:
                _SCHEDULE_CACHE.clear()
                _SCHEDULE_SIZE = 0
            self._node = {}
            node[key] = (self.P, self.S, K, Sinv, self._node)
        return K, Sinv

    def _schedule_root(self):
        """The cache chain of the current pass (None when the covariance is per run)."""
        if self.P.shape[0] != 1 or self.S.shape[0] != 1 or self.R.shape[0] != 1:
            return None
        key = (self._cfg_key, self.P.tobytes(), self.S.tobytes(), self.R.tobytes())
        return _SCHEDULE_CACHE.setdefault(key, {})

    def _earth_rot(self, m: int, dt: float):
        key = ("Em", m, dt)
        E = self._cache.get(key)
        if E is None:
            E = self._cache[key] = so3_exp(-self.w_ie * (m * dt))
        return E

    def _disc_m(self, m: int, dt: float):
        """m-step transition, process noise and bias input of the constant model."""
        steps = self._cache.setdefault(("Dm", dt), [])    # steps[k-1]: the k-step triple
        if len(steps) < m:
            Phi1, Qd1 = self._disc(self._Fconst, dt)
            G1 = self.Gamma * dt
            Phi, Qd, Gm = steps[-1] if steps else (np.eye(6), np.zeros((6, 6)), np.zeros((6, 6)))
            while len(steps) < m:
                Phi, Qd, Gm = Phi1 @ Phi, Phi1 @ Qd @ Phi1.T + Qd1, Phi1 @ Gm + G1
                steps.append((Phi, Qd, Gm))
        return steps[m - 1]

    def _earth_step(self, dt):
        key = ("E", dt)
        E = self._cache.get(key)
        if E is None:
            E = so3_exp(-self.w_ie * dt)
            if len(self._cache) < 256:
                self._cache[key] = E
        return E

    def _disc(self, F, dt):
        if F.ndim == 3:
            return discretize(F, self.Qc, dt)
        key = ("D", dt)
        hit = self._cache.get(key)
        if hit is None:
            hit = discretize(F, self.Qc, dt)
            if len(self._cache) < 256:
                self._cache[key] = hit
        return hit

    def _F(self, fn):
        model = self.config.model
        if model == "constant":
            return self._Fconst
        return system_matrix(model, self.w_ie, self.g_n, fn, self.v)

    def _propagate(self, F, dt):
        Phi, Qd = self._disc(F, dt)
        self.P = Phi @ self.P @ np.swapaxes(Phi, -1, -2) + Qd
        self._node = None
        self.S = Phi @ self.S + self.Gamma * dt

    def _advance(self, dt, w, f, gap, dR=None, hole=(0.0, 0.0), bridge=None):
        """Mechanization (paper eq. 1), covariance propagation, and an update when due.
        ``dR``: exp(w dt), when the caller has it already."""
        if gap > 0.0:
            # bridged as static: the errors grow over the gap, and when the recent mean rate
            # and specific force are given the state is mechanized with them over the gap as
            # one step (the velocity then carries the level error's signal C f + g as the
            # error model says; a velocity held still would contradict the model's coupling
            # of velocity and attitude errors and bias the heading)
            self._propagate(self._F(-self.g_n + 0.0 * self.v), gap)
            if bridge is not None:
                wb, fb = (np.asarray(b, float) for b in bridge)
                self.C = self._earth_step(gap) @ self.C @ so3_exp(wb * gap)
                self.v = self.v + ((self.C @ fb) + self.g_n) * gap
                self.t_int += gap
        va, vv = hole
        if va > 0.0 or vv > 0.0:
            # samples were missing: what the motion could have done meanwhile (Aligner)
            self.P = self.P + np.diag([va] * 3 + [vv] * 3)
            self._node = None
        self.C = self._earth_step(dt) @ self.C @ (so3_exp(w * dt) if dR is None else dR)
        fn = (self.C @ f[..., None])[..., 0]
        self.v = self.v + (fn + self.g_n) * dt
        self.t_int += dt
        F = self._F(fn)
        self._propagate(F, dt)
        if not self.fine:
            # coarse pass: the paper's instantaneous zero-velocity update, at every sample or
            # every coarse_update_period; R scaled so the noise density does not depend on it
            period = self.config.coarse_update_period
            self.t_acc += dt
            if self.t_acc >= period - 0.5 * dt:
                H = measurement_matrix(self.config.model, self.v)
                self._correct(self.v, H, scale=0.01 / self.t_acc)
                self.t_acc = 0.0
            return
        self.v_sum += self.v * dt
        self.t_acc += dt
        if self.t_acc >= self.fine_period - 0.5 * dt:
            H = measurement_matrix(self.config.model, self.v)
            Ha = averaged_measurement_matrix(H, F, self.t_acc)
            self._correct(self.v_sum / self.t_acc, Ha)
            self.v_sum = np.zeros((self.n, 3))
            self.t_acc = 0.0

    def _correct(self, z, H, scale: float = 1.0):
        prior = (self.P, self.S)
        K, Sinv = self._gain(H, scale)
        x = self._innovate(z.T, K, Sinv)
        self._settle(lambda: prior, H, scale, x)
        self.C, self.v = apply_correction(self.config.model, self.C, self.v, x.T,
                                          turn_velocity=self.fine)

    def _gain(self, H, scale: float):
        """Covariance part of an update: gain K and the inverse innovation covariance
        (with the bias part) for the NIS. Updates P and S."""
        R = self.R * scale
        HS = H @ self.S
        self.P, K, Sn = joseph_update(self.P, H, R)
        self._node = None
        self.S = self.S - K @ HS
        # innovation covariance with the bias part: H (P + S Sb S^T) H^T + R
        return K, inv3(Sn + (HS * self._bias_var) @ HS.mT)

    def _innovate(self, z, K, Sinv, out=None):
        """The correction ``x = K z`` of an update and its NIS bookkeeping, component-major:
        z (3, N), returns x (6, N) (in ``out`` if given).

        Coarse pass: runs whose running mean NIS exceeds ``reinflate_nis`` are re-inflated
        here. Fine pass: runs whose NIS exceeds ``gate_nis`` are gated (their x is zero and
        they are marked in ``_gated``: the caller's :meth:`_settle` gives them back their
        prior covariance); runs gated persistently are marked in ``_inflate``."""
        self.updates += 1
        a = 0.1 if self.updates > 10 else 1.0 / self.updates
        c = self.config
        self._gated = self._absorb = self._inflate = None
        if K.shape[0] == 1:                 # one gain for all runs: plain 2-D products
            x = np.matmul(K[0], z, out=out)
            if z.shape[1] == 1:             # one run (the node, replay): scalar arithmetic
                z0, z1, z2 = z.ravel().tolist()
                (s00, s01, s02), (s10, s11, s12), (s20, s21, s22) = Sinv[0].tolist()
                r = (z0 * (s00 * z0 + s01 * z1 + s02 * z2)
                     + z1 * (s10 * z0 + s11 * z1 + s12 * z2)
                     + z2 * (s20 * z0 + s21 * z1 + s22 * z2)) / 3.0
                m = float(self.nis_mean[0])
                if self.fine:
                    if 3.0 * r <= c.gate_nis:
                        self.nis_mean = np.array([m + a * (r - m)])
                        if self.gate_start[0] == self.gate_start[0]:      # not NaN
                            self.gate_start = np.full(1, np.nan)
                        return x
                    r = np.array([r])
                else:
                    m += a * (r - m)
                    self.nis_mean = np.array([m])
                    if m <= c.reinflate_nis:
                        return x
                    r = None                # already in the mean
            else:
                r = _THIRDS @ ((Sinv[0] @ z) * z)
        else:
            x = np.einsum("nij,jn->in", K, z, out=out)
            r = nis(z.T, Sinv) / 3.0
        if self.fine:
            self._gate(r, a, x, z)
            return x
        if r is not None:
            self.nis_mean = self.nis_mean + a * (r - self.nis_mean)
        if self.nis_mean.max() > c.reinflate_nis:
            bad = (self.nis_mean > c.reinflate_nis) & (
                self.t_int - self.last_reinflate >= c.reinflate_holdoff - 1e-6)
            if bad.any():
                self._reinflate(bad)
        return x

    def _gate(self, r, a: float, x, z):
        """Fine-pass gating (chi-square on the NIS, robot_localization style).

        An update whose NIS ``3 r`` exceeds ``gate_nis`` is not applied: a shove or a door
        slam is not evidence about the attitude (and its velocity returns). Its NIS still
        enters the running mean (capped at 100 per dof, so one jolt does not read as
        'disturbed' for minutes). When the next update is out of the gate too, the
        velocity error is lasting (a lost velocity increment, a push that did not return):
        the update is applied with the velocity variance grown by the innovation
        (``_absorb``), so the velocity state takes it instead of the attitude. Updates out
        of the gate for ``reinflate_gated_time`` in a row mean the attitude really changed
        (re-levelled, moved): the run is marked for re-inflation (``_inflate``).
        """
        c = self.config
        self.nis_mean = self.nis_mean + a * (np.minimum(r, 100.0) - self.nis_mean)
        g = 3.0 * r > c.gate_nis
        if not g.any():
            self.gate_start = np.full(self.n, np.nan)
            return
        again = g & ~np.isnan(self.gate_start)
        self.gate_start = np.where(g, np.where(again, self.gate_start, self.t_int), np.nan)
        self.gated_updates += g
        self._z = z.copy()
        first = g & ~again
        if first.any():
            x[:, first] = 0.0
            self._gated = first
        if again.any():
            self._absorb = again
        persist = g & (self.t_int - self.gate_start >= c.reinflate_gated_time - 1e-6)
        if persist.any():
            self._inflate = persist

    def _settle(self, prior, H=None, scale: float = 1.0, x=None):
        """After an update (before its feedback): runs that were gated get back their prior
        covariance (``prior()`` returns it: P, S of the propagation alone); runs that absorb
        a lasting velocity error are updated again from that prior with the velocity
        variance grown by the innovation (``x`` rewritten); runs whose gating persisted are
        re-inflated (fine pass). Nothing to do (the usual case): returns at once."""
        g, ab = self._gated, self._absorb
        if g is not None or ab is not None:
            self._gated = self._absorb = None
            post = self.P, self.S
            Pp, Sp = prior()
            if ab is None and g.all():      # every run coasts: the prior, still shared (the
                self.P, self.S = Pp, Sp     # fast path's prior() set the cache node to it)
            else:
                shape = (self.n, 6, 6)
                P, S = (np.broadcast_to(q, shape) for q in post)
                if g is not None:
                    P, S = _where_runs(g, Pp, P), _where_runs(g, Sp, S)
                if ab is not None:
                    self.P = _grow_velocity(np.broadcast_to(Pp, shape), ab, self._z)
                    self.S = np.broadcast_to(Sp, shape).copy()
                    K, _ = self._gain(H, scale)
                    x[:, ab] = np.einsum("nij,jn->in", K, self._z)[:, ab]
                    P, S = _where_runs(ab, self.P, P), _where_runs(ab, self.S, S)
                self.P, self.S, self._node = P, S, None
        if self._inflate is not None:
            mask, self._inflate = self._inflate, None
            self._reinflate(mask, self._z)

    def _reinflate(self, mask: np.ndarray, z=None):
        """Reset the covariance of the runs in ``mask`` to the pass's initial value.

        Coarse pass: the innovations say the error is far larger than the covariance claims
        (a large-angle transient stuck near a 180 deg flip): restarting the gain schedule
        lets the filter move again instead of crawling with a collapsed covariance. Fine
        pass (``z``, the last innovation, given): the attitude really changed; the velocity
        variance also covers the velocity error accumulated while updates were gated.
        """
        P = np.broadcast_to(self.P, (self.n, 6, 6)).copy()
        S = np.broadcast_to(self.S, (self.n, 6, 6)).copy()
        P[mask] = np.broadcast_to(self.P0, P.shape)[mask]
        if z is not None:
            P = _grow_velocity(P, mask, z)
        S[mask] = 0.0
        self.P, self.S = P, S
        self._node = None
        self.nis_mean = np.where(mask, 0.0, self.nis_mean)
        self.gate_start = np.where(mask, np.nan, self.gate_start)
        self.last_reinflate = np.where(mask, self.t_int, self.last_reinflate)
        self.reinflations += mask

    # ------------------------------------------------------------------ backtrack
    def backtrack(self):
        """Carry the estimate back to the first sample and rerun the buffer in the fine pass.

        Without feedback the damped mechanization gives ``C(T) = exp(-W T) C(0) B(T)`` where
        ``B`` is the body rotation integrated from the gyro, so the current estimate implies
        ``C(0) = exp(W T) C(T) B(T)^T`` exactly, whatever the corrections were.
        """
        c = self.config
        C0 = so3_exp(self.w_ie * self.t_int) @ self.C @ np.swapaxes(self._B, -1, -2)
        dt, w, f, gap, hole, bridge = self._buf.arrays()
        # the analyses of the buffer see a gap as one sample of its bridging means (the time
        # line stays whole: Earth rate and gravity are matched against time)
        adt, aw, af = _bridged(dt, w, f, gap, bridge)
        u = start_frame_increments(adt, aw, af)     # shared by the two analyses
        C0, std0, v0 = self._fine_start(C0, adt, aw, af, u)
        r_std, self.fine_period = self._sway_velocity_std(C0, adt, aw, af, u)
        self.fine_R_std = r_std
        R = np.zeros((self.n, 3, 3))
        R[:, [0, 1, 2], [0, 1, 2]] = r_std ** 2
        self._start_pass(C0, fine=True, std=std0, R=R, v0=v0)
        self._steady_start = (self.P.copy(), self.S.copy())
        self.stage = "fine"
        self.backtracked = True
        self._buf = None
        # runs of regular samples (no gap or hole, interval within 15 % of the median) take
        # the fast path, the others go one by one: the callback never stalls on a few odd
        # stamps (without the fast path, everything goes one by one)
        pieces = [(0, len(dt), False)]
        if self.fast_backtrack and c.model == "constant" and len(dt):
            med = float(np.median(dt))
            odd = (gap > 0.0) | (hole > 0.0).any(axis=1) | (np.abs(dt - med) > 0.15 * med)
            pieces = _runs(odd, FAST_MIN_BLOCK)
        for a, b, regular in pieces:
            if not regular:
                for k in range(a, b):
                    self._advance(float(dt[k]), w[k], f[k], float(gap[k]), None,
                                  tuple(hole[k]),
                                  (bridge[k, :3], bridge[k, 3:]) if gap[k] > 0.0 else None)
                continue
            d = dt[a:b]
            mean = float(d.mean())
            uniform = np.all(np.abs(d - mean) <= 1e-9 * mean)
            self._advance_block(mean if uniform else d, w[a:b], f[a:b])

    def _fine_start(self, C0, dt, w, f, u=None):
        """Where the fine pass starts: attitude (N, 3, 3), initial std (N, 6), velocity (N, 3).

        The coarse pass's estimate carried back (``C0``) is checked against the inertial-frame
        alignment of the same buffer (:mod:`sins_align.estimators.quasi_static.inertial`, immune to
        sway): when it lies outside 3 sigma of that solution on some axis (the coarse pass was
        thrown off by sway), the fine pass starts from the inertial-frame attitude instead. The
        initial std is the configured ``fine_initial_std_deg``, widened to 3 sigma of the
        inertial-frame solution (the buffer is used twice, so the prior stays wide); the initial
        velocity is the sway velocity of the first sample, which the mechanization, starting at
        zero, would otherwise carry as a constant offset.
        """
        c = self.config
        sp = c.specs
        fit = inertial_alignment(dt, w, f, self.w_ie, self.g_n, self.limit_std,
                                 sp.gyro_arw, sp.accel_vrw, increments=u)
        lv, hd = (a * DEG for a in c.fine_initial_std_deg)
        cap = max(hd, c.coarse_initial_std_deg[1] * DEG)
        att = np.minimum(np.maximum(np.array([lv, lv, hd]), 3.0 * fit.std), cap)
        diff = np.abs(so3_log(fit.C0 @ np.swapaxes(C0, -1, -2)))
        off = np.any(diff > 3.0 * fit.std, axis=1)
        self.started_inertial = off
        C0 = np.where(off[:, None, None], fit.C0, C0)
        vel = np.maximum(c.initial_velocity_std, 3.0 * fit.v0_std)
        return C0, np.concatenate([att, vel], axis=1), fit.v0

    def force_block_means(self, k: int, most: int = 10) -> np.ndarray | None:
        """Before the backtrack: the mean specific force (m, N, 3) of the last ``most``
        complete blocks of ``k`` buffered samples (None once the buffer is gone)."""
        if self._buf is None:
            return None
        return self._buf.force_means(k, most)

    @property
    def steady_std(self) -> np.ndarray | None:
        """Attitude std (N, 3), rad, the fine pass tends to (None before the backtrack);
        computed on first use."""
        if self._steady_std is None and self._steady_start is not None:
            self._steady_std = self._steady_state_std()
        return self._steady_std

    def _steady_state_std(self, horizon: float = 1800.0) -> np.ndarray:
        """Attitude std (N, 3), rad, the fine pass tends to on a static base: the covariance
        recursion alone (no data), iterated over ``horizon`` seconds of fine updates.

        For navigation and tactical grades this is the limit accuracy; for MEMS gyros the
        gyro bias adds a tracking lag to the level axes that no filter without bias states
        can remove, so the aligned flag compares against whichever is larger.
        """
        T = self.fine_period
        F = self._Fconst if self.config.model == "constant" else system_matrix(
            self.config.model, self.w_ie, self.g_n, -self.g_n, np.zeros(3))
        Phi, Qd = discretize(F, self.Qc, T)
        H = averaged_measurement_matrix(measurement_matrix(self.config.model, np.zeros(3)), F, T)
        P, S = self._steady_start
        key = ("steady", self._cfg_key, P.tobytes(), S.tobytes(), self.R.tobytes(), T)
        hit = _SCHEDULE_CACHE.get(key)
        if hit is not None:
            return hit
        Gd = self.Gamma * T
        prev = None
        PhiT, R = Phi.T, self.R
        if P.shape[0] == S.shape[0] == R.shape[0] == 1:      # one covariance: 2-D arrays
            P, S, R = P[0], S[0], R[0]
        for i in range(int(horizon / T)):
            P = Phi @ P @ PhiT + Qd                           # the fine pass's recursion
            S = Phi @ S + Gd
            P, K, _ = joseph_update(P, H, R)
            S = S - K @ (H @ S)
            if i % 25 == 24:                      # stop once the attitude std has settled
                d = np.diagonal(self._with_bias(P, S), axis1=-2, axis2=-1)[..., :3]
                if prev is not None and np.all(np.abs(d - prev) <= 1e-6 * d):
                    break
                prev = d
        P, S = P.reshape(-1, 6, 6), S.reshape(-1, 6, 6)
        tot = self._with_bias(P, S)
        out = np.broadcast_to(np.sqrt(np.diagonal(tot[:, :3, :3], axis1=1, axis2=2)),
                              (self.n, 3))
        _SCHEDULE_CACHE[key] = out
        return out

    def _sway_velocity_std(self, C0, dt, w, f, u=None):
        """Measure the sway velocity; pick the fine update period and its noise.

        Open-loop damped mechanization from ``C0`` over the buffer; a cubic per axis removes
        the drift due to the remaining attitude error; what is left is sway velocity plus
        VRW wander. For each candidate period (``fine_update_period`` times 1, 2, 5, 10, 20)
        the interval means are differenced; the first period whose differences look white
        (lag-1 autocorrelation below 0.4 on every axis: slow ship-like sway is averaged over)
        is used, with half their mean square as the measurement noise (per run, per axis),
        floored by the VRW term and ``fine_min_velocity_noise``.

        Returns
        -------
        r_std : ndarray (N, 3), m/s ; period : float, s
        """
        c = self.config
        vs = open_loop_velocity(dt, w, f, C0, self.w_ie, self.g_n, increments=u)
        t = np.cumsum(dt)
        tn = (t - t.mean()) / (t.std() + 1e-12)
        A = np.vander(tn, 4)
        Y = vs.reshape(len(dt), -1)
        coef, *_ = np.linalg.lstsq(A, Y, rcond=None)
        # running sum of the residuals: any interval's sum is a difference of two rows
        csum = np.cumsum(Y - A @ coef, axis=0)
        csum = np.concatenate([np.zeros((1, csum.shape[1])), csum])
        period = base = c.fine_update_period
        r_std = None
        for mult in (1, 2, 5, 10, 20):
            p = base * mult
            idx = np.floor((t - 0.5 * dt) / p).astype(int)   # sample midpoints: no ties
            n_int = int(idx[-1])
            if n_int < 8:
                break
            # idx never decreases: interval j holds the samples edges[j] .. edges[j+1] - 1
            edges = np.searchsorted(idx, np.arange(n_int + 1))
            counts = np.diff(edges)
            means = (csum[edges[1:]] - csum[edges[:-1]]) / np.maximum(counts, 1)[:, None]
            d = np.diff(means, axis=0)
            # half the mean square difference (blind to a slow wander), but never below the
            # variance of the means themselves: a sway that is not white (a slow tone) has
            # differences smaller than its spread, and gating would then take every other
            # interval for a shove
            var = np.maximum(0.5 * np.mean(d ** 2, axis=0), np.mean(means ** 2, axis=0))
            # differences of white means are MA(1): lag 1 -0.5, nothing beyond; a tone shows
            # at some lag up to 5 (0.2 Hz in 1 s means: lag 5), alternating means at lag 1 -1
            dd = np.maximum(np.sum(d * d, axis=0), 1e-300)
            lags = [np.sum(d[k:] * d[:-k], axis=0) / dd for k in range(1, min(6, len(d) // 2))]
            r1 = lags[0]
            white = (r1 < 0.4) & (r1 > -0.75)
            for rk in lags[1:]:
                white &= np.abs(rk) < 0.4
            floor2 = c.specs.accel_vrw ** 2 * p / 3.0 + c.fine_min_velocity_noise ** 2
            var = var.reshape(self.n, 3)
            # the sway's direction in the estimated frame moves with the heading error: a
            # horizontal axis is as noisy as the noisier one
            var[:, :2] = var[:, :2].max(axis=1, keepdims=True)
            period, r_std = p, np.sqrt(np.maximum(var, floor2))
            if np.all(white):
                break
        if r_std is None:
            floor2 = c.specs.accel_vrw ** 2 * base / 3.0 + c.fine_min_velocity_noise ** 2
            r_std = np.full((self.n, 3), math.sqrt(floor2))
        return r_std, period


class Aligner:
    """Streaming SINS self-alignment on a quasi-static base (one IMU).

    Feed samples with :meth:`update` (one sample or a block); read the result at any time
    from :attr:`quaternion`, :attr:`covariance`, :attr:`aligned` and friends. Invalid
    samples are rejected with a reason (:data:`REJECT_REASONS`) and never touch the state.

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
        self.lat = config.latitude_deg * DEG
        self.g = -gravity_enu(self.lat, config.height_m)[2]
        self.limit_cov = limit_covariance(self.lat, config.specs, self.g)
        self.limit_std = np.sqrt(np.diag(self.limit_cov))
        self.heading_observable = bool(
            np.isfinite(self.limit_std[2])
            and self.limit_std[2] < config.heading_max_limit_std_deg * DEG)
        self.reset()

    # ------------------------------------------------------------------ lifecycle
    def subscribe(self, callback: Callable[[AlignmentEvent], None]) -> None:
        """Call ``callback(event)`` for every :class:`AlignmentEvent` from now on (the
        aligned flag changed, a restart, a rejected sample), in the order they happen, on
        the per-sample and the block path alike. Subscriptions survive :meth:`reset`."""
        self._listeners.append(callback)

    def _emit(self, kind: str, stamp: float | None, value) -> None:
        if self._listeners:
            event = AlignmentEvent(kind, stamp, value)
            for callback in self._listeners:
                callback(event)

    def reset(self, reason: str = "reset"):
        """Forget the alignment and the time line (``samples_used`` counts this run's
        samples); keep the configuration, the subscriptions and the counters ``rejected``
        and ``events``, which count over the Aligner's life: a restart never wipes them.
        Subscribers are told (event 'restarted' with ``reason``; 'aligned' false first when
        it was true)."""
        c = self.config
        if not hasattr(self, "rejected"):
            self.rejected: Counter = Counter()
            self.events: Counter = Counter()
            self._listeners: list[Callable[[AlignmentEvent], None]] = []
            self._aligned = False
        elif self._aligned:
            self._aligned = False
            self._emit("aligned", self.t_last, False)
        self.samples_used = 0
        self.last_reject: str | None = None
        self.t_first: float | None = None
        self.t_last: float | None = None
        self._t_prev_raw: float | None = None
        self._jump: tuple[float, int] | None = None    # pending time jump: (stamp, samples)
        self._force_ok: float | None = None    # stamp of the last force within range
        self._dt_seen: list[float] = []
        self.nominal_dt = 1.0 / c.rate_hz if c.rate_hz else None
        self._units = _UnitsMonitor(self) if c.units_check_window > 0 else None
        self._recent = _Recent()
        self.units_suspect = False
        self._restart_filter()
        self._emit("restarted", None, reason)

    def _restart_filter(self, stamp: float | None = None):
        """A new filter from the initial attitude (the time line is kept); the flag drops
        (event 'aligned' at ``stamp`` when it was true)."""
        c = self.config
        C0 = np.eye(3) if c.initial_rpy_deg is None else dcm_from_rpy(
            np.array(c.initial_rpy_deg) * DEG)
        self.filter = AlignmentFilter(c, C0[None])
        if self._aligned:
            self._aligned = False
            self._emit("aligned", stamp, False)
        self.time_to_aligned: float | None = None

    # ------------------------------------------------------------------ results
    @property
    def stage(self) -> str:
        """'coarse' (paper filter on live data) or 'fine' (after the backtrack)."""
        return self.filter.stage

    @property
    def dcm(self) -> np.ndarray:
        """C_b^n estimate, (3, 3): rotates IMU-frame vectors into ENU."""
        return self.filter.C[0]

    @property
    def quaternion(self) -> np.ndarray:
        """Orientation of the IMU frame in ENU, [x, y, z, w] (C_b^n, as imu_filter_madgwick)."""
        return quat_from_dcm(self.dcm)

    @property
    def rpy_deg(self) -> np.ndarray:
        """REP-103 [roll, pitch, yaw], deg (yaw 0 = x axis East, counter-clockwise)."""
        return rpy_from_dcm(self.dcm) / DEG

    @property
    def heading_deg(self) -> float:
        """True heading of the IMU x axis, deg clockwise from North, [0, 360)."""
        return float(heading_from_dcm(self.dcm) / DEG)

    @property
    def covariance(self) -> np.ndarray:
        """Published attitude-error covariance (E/N/U, rad^2, phi of paper eq. 15).

        Filter covariance plus the bias-induced part ``S Sigma_b S^T`` for biases drawn from
        the specs (consider analysis). Before the backtrack the coarse pass is a starting
        point, not a result: its own covariance can be far too small in large-angle
        transients, so until the fine pass runs the published level std is at least
        ``fine_initial_std_deg`` and at least the angle between the estimated up and the
        last second's specific force (the level error the accelerometer sees), and the
        heading std at least ``coarse_initial_std_deg``. When heading is
        unobservable the U row/column is cleared and its variance set to pi^2.
        """
        P = self.filter.total_covariance()[0, :3, :3].copy()
        c = self.config
        if c.backtrack and not self.filter.backtracked:
            level = c.fine_initial_std_deg[0] * DEG
            fm = self._recent.mean_force(1.0)
            if fm is not None:
                # the accelerometer's own view of the level error: the angle between the
                # estimated up and the specific force of the last second (large in the
                # first seconds from a start far off, e.g. upside down)
                up = self.dcm[2] @ fm / max(float(np.linalg.norm(fm)), 1e-12)
                level = max(level, math.acos(max(-1.0, min(1.0, up))))
            if self.nominal_dt is not None:
                # ... and at least the largest angle to the 1 s means of the last 10 s: on a
                # swaying base the estimate follows the apparent vertical, and the last second
                # alone can agree with it while the true vertical is degrees away
                k = max(1, int(round(1.0 / self.nominal_dt)))
                fb = self.filter.force_block_means(k, 10)
                if fb is not None and len(fb) < 2:
                    # the first two seconds: nothing yet tells a sway from the vertical
                    level = max(level, c.coarse_initial_std_deg[0] * DEG)
                elif fb is not None:
                    fb = fb[:, 0]
                    cosang = (fb @ self.dcm[2]) / np.maximum(np.linalg.norm(fb, axis=1), 1e-12)
                    level = max(level, math.acos(max(-1.0, min(1.0, float(cosang.min())))))
            floor = np.array([level, level, c.coarse_initial_std_deg[1] * DEG])
            sd = np.sqrt(np.diag(P))
            scale = np.maximum(floor, sd) / sd
            P = P * np.outer(scale, scale)
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
        """Running mean normalised innovation squared per degree of freedom."""
        return float(self.filter.nis_mean[0])

    @property
    def disturbed(self) -> bool:
        """True when the fine-pass innovations no longer fit a quasi-static base (motion)."""
        f = self.filter
        return bool(f.fine and f.updates >= 5 and f.nis_mean[0] > self.config.disturbance_nis)

    @property
    def aligned(self) -> bool:
        """Aligned flag: :meth:`aligned_now` as of the last update (the published std only
        shrinks at an update; it is re-checked after every update, hole and restart)."""
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
        if np.ndim(stamp) == 0 and np.shape(gyro) == (3,) and np.shape(accel) == (3,):
            return self._sample(float(stamp), np.asarray(gyro, dtype=float),
                                np.asarray(accel, dtype=float))
        t = np.atleast_1d(np.asarray(stamp, dtype=float))
        w = np.asarray(gyro, dtype=float).reshape(-1, 3)
        f = np.asarray(accel, dtype=float).reshape(-1, 3)
        if not (len(t) == len(w) == len(f)):
            raise ValueError(f"stamp, gyro and accel lengths differ: {len(t)}, {len(w)}, {len(f)}")
        n, k = 0, 0
        while k < len(t):
            j = self._clean_run(t, w, f, k)
            if j - k >= FAST_MIN_BLOCK:
                used = self._accept_block(t[k:j], w[k:j], f[k:j])
                n += used
                k += used
                if k == j:
                    continue
                # else sample k closes a units-check window that flags the rates: below
            n += self._sample(float(t[k]), w[k], f[k])
            k += 1
        return n

    def _clean_run(self, t, w, f, k) -> int:
        """End index of the run of samples from k that the per-sample checks would all accept
        as ordinary samples (intervals within 40 % of nominal, no gap, no rejection): those
        can take the filter's fast path with the same results (a units-check window that
        would flag the rates is cut off later, in _accept_block)."""
        c = self.config
        if (c.model != "constant" or self.t_last is None or self.nominal_dt is None
                or self.units_suspect or self._t_prev_raw != self.t_last
                or len(t) - k < FAST_MIN_BLOCK):
            return k
        tt = t[k:k + FAST_MAX_BLOCK]
        dts = np.diff(tt, prepend=self.t_last)
        nom = self.nominal_dt
        fn = np.linalg.norm(f[k:k + len(tt)], axis=1)
        wn = np.linalg.norm(w[k:k + len(tt)], axis=1)
        ok = (np.isfinite(tt) & np.isfinite(w[k:k + len(tt)]).all(1)
              & np.isfinite(f[k:k + len(tt)]).all(1)
              & (dts >= c.min_dt_ratio * nom) & (dts <= c.gap_ratio * nom) & (dts <= c.max_gap)
              & (np.abs(dts - nom) <= 0.4 * nom)
              & (fn >= 0.25 * self.g) & (np.abs(fn - self.g) <= c.specific_force_tolerance * self.g)
              & (wn <= c.max_angular_rate))
        m = len(tt) if ok.all() else int(np.argmin(ok))
        return k + m

    def _accept_block(self, t, w, f) -> int:
        """Clean samples through the fast path: all of them, or those before the first
        units-check window closing that would flag the rates. Returns how many."""
        dts = np.diff(t, prepend=self.t_last)
        if self._units is not None:
            m = self._units.add_block(dts, w, f)
            if m < len(t):
                if m == 0:
                    return 0
                t, w, f, dts = t[:m], w[:m], f[:m], dts[:m]
        self.t_last = self._t_prev_raw = self._force_ok = float(t[-1])
        self.samples_used += len(t)
        self._recent.extend(dts, w, f)

        def check(i):                     # after every live update, as after every sample
            self.t_last = float(t[i])
            self._refresh_aligned()

        self.filter.on_update = check
        try:
            self.filter.run_fast(dts, w, f)
        finally:
            self.filter.on_update = None
        self.t_last = float(t[-1])
        self._refresh_aligned()
        return len(t)

    def _reject(self, reason: str, stamp: float | None = None) -> int:
        self.rejected[reason] += 1
        self.last_reject = reason
        self._emit("rejected", stamp, reason)
        return 0

    def reject_undecodable(self):
        """Count an input message that could not be decoded into a sample at all (reason
        ``undecodable``); the state is not touched."""
        self._reject("undecodable")

    def _static_reason(self, w: np.ndarray, f: np.ndarray) -> str | None:
        """The reason to reject a sample on its own values (no time line needed), or None."""
        c = self.config
        fn = math.sqrt(float(f @ f))
        if fn < 0.25 * self.g:
            return "gravity_removed"
        if abs(fn - self.g) > c.specific_force_tolerance * self.g:
            return "specific_force_out_of_range"
        return None

    def _units_verdict(self, bad: bool, t: float) -> None:
        """A units-check window closed at the sample stamped ``t``: rates flagged as deg/s
        restart the filter (status 'fault' until a window clears them)."""
        if bad and not self.units_suspect:
            self.units_suspect = True
            self._restart_filter(t)
            self._emit("restarted", t, "rates_look_like_deg_per_s")
        elif not bad:
            self.units_suspect = False

    def _shock_reference(self, t: float) -> np.ndarray | None:
        """The last second's mean force, against which an out-of-range reading at ``t`` is
        measured, while the last reading within range is at most FORCE_SHOCK_TIME old; else None
        (the sample is rejected: wrong units or a broken accelerometer, not a shock)."""
        if self._force_ok is None or t - self._force_ok > FORCE_SHOCK_TIME:
            return None
        return self._recent.mean_force(1.0)

    def _time_jump(self, t: float) -> int:
        """A stamp more than ``max_gap`` after the last one seen: rejected. The time line is
        re-anchored only once JUMP_CONFIRM samples in a row agree on the new one; a single
        wild stamp is an outlier (events 'stamp_outlier' when the old line resumes)."""
        j = self._jump
        if j is not None and 0.0 < t - j[0] <= self.config.max_gap:
            j = (t, j[1] + 1)
        else:
            j = (t, 1)
        self._jump = j
        if j[1] >= JUMP_CONFIRM:
            self._jump = None
            self.t_last = self._t_prev_raw = t
            self.events["time_jump"] += 1
        return self._reject("time_jump", t)

    def _sample(self, t: float, w: np.ndarray, f: np.ndarray) -> int:
        c = self.config
        if not (math.isfinite(t) and np.isfinite(w).all() and np.isfinite(f).all()):
            return self._reject("nonfinite", t)
        if self.t_last is None:
            # the first accepted sample anchors time; it has no interval to integrate over
            why = self._static_reason(w, f)
            if why is None and math.sqrt(float(w @ w)) > c.max_angular_rate:
                why = "rate_too_high"
            if why is not None:
                return self._reject(why, t)
            self.t_first = self.t_last = self._t_prev_raw = self._force_ok = t
            self._recent.push(0.0, w, f)
            self.events["first_sample"] += 1
            return 0
        dt = t - self.t_last
        if dt == 0.0:
            return self._reject("duplicate_stamp", t)
        if dt < 0.0:
            return self._reject("stamp_backwards", t)
        raw_dt = t - self._t_prev_raw
        if raw_dt > c.max_gap:
            return self._time_jump(t)
        if self._jump is not None:          # the old time line goes on: that was one stamp
            self._jump = None
            self.events["stamp_outlier"] += 1
        if raw_dt <= 0.0:                   # behind a rejected sample's stamp, not the line's
            raw_dt = dt
        self._t_prev_raw = t
        if self.nominal_dt is None:
            # message interval, measured between consecutive samples whatever their fate
            self._dt_seen.append(raw_dt)
            if len(self._dt_seen) >= 20:
                # statistics.median: the same value, without numpy.ma (12 ms to import)
                self.nominal_dt = float(statistics.median(self._dt_seen))
        nom = self.nominal_dt
        if nom is not None and dt < c.min_dt_ratio * nom:
            return self._reject("dt_too_small", t)
        why = self._static_reason(w, f)
        force_var = 0.0
        if why == "specific_force_out_of_range":
            f_ref = self._shock_reference(t)
            if f_ref is not None:
                # a shock (a door slam, a bump) turns the attitude too, so the sample is used:
                # a hole would lose the gyro's share of it. Its force is integrated as read,
                # and the velocity may err by its distance from the recent mean force (a
                # glitch of the accelerometer), which its covariance takes; a true reading
                # errs by nothing
                d = f - f_ref
                force_var = float(d @ d) * dt * dt
                why = None
                self.events["force_out_of_range"] += 1
        elif why is None:
            self._force_ok = t
        if why is not None:
            return self._reject(why, t)
        dR = None
        if self._units is not None:
            dR = self._units.add(raw_dt, w, f)
            verdict, self._units.verdict = self._units.verdict, None
            if verdict is not None:
                self._units_verdict(verdict, t)
            if self.units_suspect:
                self.t_last = t
                return self._reject("rates_look_like_deg_per_s", t)
        if math.sqrt(float(w @ w)) > c.max_angular_rate:
            return self._reject("rate_too_high", t)
        gap, hole, bridge = 0.0, (0.0, 0.0), None
        w_in, f_in = w, f
        if nom is not None and dt > HOLE_RATIO * nom:
            # samples are missing (lost, or rejected). Up to gap_ratio intervals this one is
            # integrated over the whole interval (see below what stands in for the missing
            # samples); beyond, it covers one nominal interval and the rest is bridged as
            # static with the recent means. Either way the covariance grows by the error
            # that bridge makes on the motion seen before (Aligner._recent)
            missing = dt - nom
            rec = self._recent
            if dt > c.gap_ratio * nom:
                gap, dt = missing, nom
                self.events["gap"] += 1
                hole, _, bridge = rec.bridge_errors(missing, nom, w, f, held=False)
            else:
                # a short hole: for the rate and the specific force each, the next sample held
                # over it or the recent mean standing in for the missing samples, whichever
                # errs less on the recent motion (held for a smooth sway, the mean when noise
                # dominates: holding one noisy sample multiplies its noise by the hole's
                # length). The step then integrates the interval's mean of the two.
                means, held, (wm, fm) = rec.bridge_errors(missing, nom, w, f)
                hole = list(held)
                if means[0] < held[0]:
                    w, hole[0], dR = (wm * missing + w * nom) / dt, means[0], None
                if means[1] < held[1]:
                    f, hole[1] = (fm * missing + f * nom) / dt, means[1]
                hole = tuple(hole)
            self.events["missing_samples"] += max(1, int(round(missing / nom)))
        if force_var > 0.0:
            hole = (hole[0], hole[1] + force_var)
        self.t_last = t
        self.samples_used += 1
        self._recent.push(dt, w_in, f_in)
        fl = self.filter
        before = (fl.updates, fl.stage, id(fl))
        fl.step(dt, w[None], f[None], gap, dR if dt == raw_dt else None, hole, bridge)
        if (fl.updates, fl.stage, id(fl)) != before or hole != (0.0, 0.0):
            # the flag is re-evaluated where the covariance jumps (an update, the backtrack,
            # a hole); between updates it only grows by the process noise (the fast path
            # checks at the same points, so node and replay agree)
            self._refresh_aligned()
        return 1

    # ------------------------------------------------------------------ aligned flag
    def aligned_now(self) -> bool:
        """Criteria: no fault, the fine pass running (unless backtrack is off), and the
        published std of every observable axis at most
        ``max(aligned_std_ratio x reachable std, aligned_min_*_std_deg)``, where the reachable
        std is the larger of the limit accuracy and the fine pass's steady-state std.

        A disturbance (motion the model cannot explain: ``disturbed``) does not withdraw a
        good alignment by itself: its updates are gated, and the flag drops when the std
        grows past the criterion (a real change of attitude re-inflates the covariance)."""
        c = self.config
        if self.units_suspect:
            return False
        if c.backtrack and not self.filter.backtracked:
            return False
        std = np.sqrt(np.diag(self.covariance))
        ok = self._within(std, self.limit_std)
        if not ok and self.filter.backtracked:
            # the steady-state std can only raise the bound: computed (once, 1800 s of
            # covariance recursion) only when the limit alone does not decide
            steady = self.filter.steady_std
            if steady is not None:
                ok = self._within(std, np.maximum(self.limit_std, steady[0]))
        return bool(ok)

    def _within(self, std: np.ndarray, lim: np.ndarray) -> bool:
        c = self.config
        lvl = c.aligned_min_level_std_deg * DEG
        ok = (std[0] <= max(c.aligned_std_ratio * lim[0], lvl)
              and std[1] <= max(c.aligned_std_ratio * lim[1], lvl))
        if self.heading_observable:
            ok = ok and std[2] <= max(c.aligned_std_ratio * lim[2],
                                      c.aligned_min_heading_std_deg * DEG)
        return bool(ok)

    def _refresh_aligned(self):
        """Re-evaluate the flag (after an update, the backtrack, a hole, a restart): true
        exactly while :meth:`aligned_now` holds."""
        now = self.aligned_now()
        if now != self._aligned:
            self._aligned = now
            if now and self.time_to_aligned is None:
                self.time_to_aligned = self.elapsed
            self._emit("aligned", self.t_last, now)

    # ------------------------------------------------------------------ summary
    def summary(self) -> dict:
        """A JSON-ready snapshot of the result (node diagnostics, replay summary)."""
        r = self.filter.fine_R_std
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
            "fine_velocity_noise_mps": None if r is None else r[0].tolist(),
            "nis": self.nis,
        }


def _where_runs(mask: np.ndarray, a, b) -> np.ndarray:
    """(N, 6, 6): ``a`` for the runs in ``mask``, ``b`` for the others (either (1|N, 6, 6))."""
    return np.where(mask[:, None, None], a, b)


def _grow_velocity(P: np.ndarray, mask: np.ndarray, z: np.ndarray) -> np.ndarray:
    """P (N, 6, 6) with the velocity variances of the runs in ``mask`` grown by z^2 (z (3, N),
    an innovation the model could not explain): a new array."""
    P = P.copy()
    i = np.arange(3, 6)
    P[:, i, i] += np.where(mask[:, None], (z * z).T, 0.0)
    return P


def _runs(odd: np.ndarray, least: int):
    """(start, end, regular) pieces covering ``odd``'s indices in order: runs of at least
    ``least`` samples that are not odd are regular, everything between them is not."""
    ok = np.concatenate(([False], ~odd, [False]))
    edges = np.flatnonzero(np.diff(ok.astype(np.int8)))
    starts, ends = edges[0::2], edges[1::2]
    keep = ends - starts >= least
    out, k = [], 0
    for a, b in zip(starts[keep].tolist(), ends[keep].tolist()):
        if a > k:
            out.append((k, a, False))
        out.append((a, b, True))
        k = b
    if k < len(odd):
        out.append((k, len(odd), False))
    return out


def _rows_times(Ct, M, out):
    """``out[k, i, n] = sum_j Ct[j, i, n] M[j, k, n]``: C M for each run n, component-major
    with C transposed (``Ct[j, i, n] = C[i, j, n]``), so out is (C M) transposed. One einsum
    over the runs; for a single run a plain matrix product (half the call overhead)."""
    if out.shape[-1] == 1:
        np.matmul(M[..., 0].T, Ct[..., 0], out=out[..., 0])
    else:
        np.einsum("jin,jkn->kin", Ct, M, out=out)


def _times_rows(R, Xt, out):
    """``out[k, r, n] = sum_j R[r, j, n] Xt[k, j, n]``: R X for each run n, with X and the
    result transposed as in :func:`_rows_times`."""
    if out.shape[-1] == 1:
        np.matmul(Xt[..., 0], R[..., 0].T, out=out[..., 0])
    else:
        np.einsum("rjn,kjn->krn", R, Xt, out=out)


def _part(dt, a: int, b: int):
    """dt for samples a:b (a float stays a float)."""
    return dt if np.ndim(dt) == 0 else dt[a:b]


def _last(dt, end: int) -> float:
    return float(dt) if np.ndim(dt) == 0 else float(dt[end - 1])


def _bridged(dt, w, f, gap, bridge):
    """dt, w, f with a sample of the bridging means (rate, specific force) and the gap's
    length put before each sample that follows a gap (the buffer as the filter ran it)."""
    k = np.flatnonzero(gap > 0.0)
    if not len(k):
        return dt, w, f
    n = w.shape[1]
    dt = np.insert(dt, k, gap[k])
    w = np.insert(w, k, np.broadcast_to(bridge[k, None, :3], (len(k), n, 3)), axis=0)
    f = np.insert(f, k, np.broadcast_to(bridge[k, None, 3:], (len(k), n, 3)), axis=0)
    return dt, w, f


class _SampleBuffer:
    """Growable store of accepted samples for the backtrack: dt, gap, the hole variances
    (attitude, velocity) (M,) and a gap's bridging rate and specific force (M, 6), w, f
    (M, N, 3)."""

    def __init__(self, n: int):
        self._t = np.empty((1024, 10))
        self._wf = np.empty((1024, n, 6))
        self._n = 0
        self._blocks = None            # (k, block means) of force_means

    def append(self, dt, w, f, gap, hole=(0.0, 0.0), bridge=None):
        if self._n == len(self._t):
            self._t = np.concatenate([self._t, np.empty_like(self._t)])
            self._wf = np.concatenate([self._wf, np.empty_like(self._wf)])
        self._t[self._n, :4] = (dt, gap, hole[0], hole[1])
        self._t[self._n, 4:] = 0.0 if bridge is None else np.concatenate(bridge)
        self._wf[self._n, :, :3] = w
        self._wf[self._n, :, 3:] = f
        self._n += 1

    def extend(self, dt, w, f):
        """Append a block of samples (no gaps): w, f (M, N, 3)."""
        m = len(w)
        while self._n + m > len(self._t):
            self._t = np.concatenate([self._t, np.empty_like(self._t)])
            self._wf = np.concatenate([self._wf, np.empty_like(self._wf)])
        self._t[self._n:self._n + m, 0] = dt
        self._t[self._n:self._n + m, 1:] = 0.0
        self._wf[self._n:self._n + m, :, :3] = w
        self._wf[self._n:self._n + m, :, 3:] = f
        self._n += m

    def force_means(self, k: int, most: int) -> np.ndarray:
        """Mean specific force of the last ``most`` complete blocks of ``k`` samples (counted
        from the first sample, so the same blocks whatever the feeding), (m, N, 3). Each block
        is averaged once (the buffer holds a minute: tens of blocks)."""
        if self._blocks is None or self._blocks[0] != k:
            self._blocks = (k, [])
        means = self._blocks[1]
        for j in range(len(means), self._n // k):
            means.append(self._wf[j * k:(j + 1) * k, :, 3:].mean(axis=0))
        got = means[-most:]
        return np.array(got) if got else np.zeros((0, self._wf.shape[1], 3))

    def arrays(self):
        """dt, w, f, gap, hole (M, 2), bridge (M, 6): rate, specific force."""
        t = self._t[: self._n]
        wf = self._wf[: self._n]
        return t[:, 0], wf[..., :3], wf[..., 3:], t[:, 1], t[:, 2:4], t[:, 4:]


class _Recent:
    """The last accepted samples (a ring of fixed size): how much the platform moves.

    Read when samples are missing (how far the attitude and velocity could have moved in
    the hole) and while the coarse pass runs (the specific force of the last second, the
    accelerometer's own view of the level error). Fed sample by sample (the node) or in
    blocks (replay), it holds the same numbers either way.
    """

    SIZE = 16384
    WINDOW = 20.0                       # s of samples the motion statistics look at

    def __init__(self):
        self._a = np.zeros((self.SIZE, 7))       # dt, w, f
        self._i = 0                              # next row to write
        self._n = 0                              # rows filled

    def push(self, dt: float, w, f):
        row = self._a[self._i]
        row[0] = dt
        row[1:4] = w
        row[4:7] = f
        self._i = (self._i + 1) % self.SIZE
        self._n = min(self._n + 1, self.SIZE)

    def extend(self, dts, w, f):
        m = len(w)
        if m >= self.SIZE:
            dts, w, f = dts[-self.SIZE:], w[-self.SIZE:], f[-self.SIZE:]
            m = self.SIZE
        idx = (self._i + np.arange(m)) % self.SIZE
        self._a[idx, 0] = dts
        self._a[idx, 1:4] = w
        self._a[idx, 4:7] = f
        self._i = (self._i + m) % self.SIZE
        self._n = min(self._n + m, self.SIZE)

    def last(self, seconds: float) -> np.ndarray:
        """Rows (dt, w, f) of the last samples spanning at most ``seconds``, oldest first."""
        if self._n == 0:
            return self._a[:0]
        dt = self._a[self._i - 1, 0]
        # read back only as far as the span needs: guessed from the newest interval, doubled
        # while it falls short
        m = self._n if dt <= 0.0 else min(self._n, int(1.25 * seconds / dt) + 2)
        while True:
            rows = self._tail(m)
            span = np.cumsum(rows[::-1, 0])
            if m == self._n or span[-1] > seconds:
                break
            m = min(2 * m, self._n)
        k = max(1, int(np.searchsorted(span, seconds, side="right")))
        return rows[m - k:]

    def _tail(self, m: int) -> np.ndarray:
        """The newest m rows, oldest first (two slices when they wrap round the ring)."""
        a, i = self._a, self._i
        if m <= i:
            return a[i - m:i]
        return np.concatenate((a[self.SIZE - (m - i):], a[:i]))

    def mean_force(self, seconds: float = 1.0) -> np.ndarray | None:
        """Mean specific force over the last ``seconds`` (None before any sample)."""
        rows = self.last(seconds)
        if not len(rows):
            return None
        return rows[:, 4:7].mean(axis=0)

    def bridge_errors(self, hole: float, nom: float, w_next, f_next, held: bool = True):
        """The bridges of a hole of ``hole`` seconds before the sample (w_next, f_next) and
        their errors: ``(means, held, (w_mean, f_mean))`` with ``means`` and ``held`` the
        (attitude rad^2, velocity (m/s)^2) variance per axis of each bridge (``held`` None
        when not asked for) and the last second's mean rate and specific force, the means
        bridge itself. The errors are measured on the motion of the last WINDOW seconds (the
        largest axis counts for all three, the body axes not being the ENU ones).

        Each bridge is replayed at every position of the window, and the RMS of its error
        there, times sqrt(2) (a tone's peak over its RMS), is one sigma:

        - ``held`` (m = hole / nom missing samples): the next sample's rate and specific
          force stand in for the missing ones, so the error is
          ``nom sum_i (x_next - x_i)`` over the m samples it replaces. At the hole itself
          the change from the last sample to the next one is seen: a ramp between them
          makes ``|x_next - x_last| nom m / 2``, taken when larger (a shove in the hole).
        - bridged with the recent means: the rate's (specific force's) deviation from its
          mean over the window, integrated over m samples; a hole longer than the window is
          bounded by the range of that integral (a bounded sway cannot move further than its
          own range), grown with the hole's length beyond the window for a wander that is
          not stationary. At the hole itself, the mean of the samples on either side less
          the last second's mean, over the hole, is taken when larger.

        Noise counts as motion here (the bridge's error against the complete data), which
        errs on the safe side: the truth has no sensor noise in it.
        """
        second = self.last(1.0)[:, 1:7].mean(axis=0)        # the means bridge
        rows = self.last(self.WINDOW)
        n = len(rows)
        if n < 3:
            return (0.0, 0.0), ((0.0, 0.0) if held else None), (second[:3], second[3:])
        T = float(rows[:, 0].sum())
        m = max(1, int(round(hole / nom)))
        means, holds = [], []
        for x, nxt in ((rows[:, 1:4], w_next), (rows[:, 4:7], f_next)):
            d = x - (x * rows[:, :1]).sum(0) / T
            wander = np.cumsum(d * rows[:, :1], axis=0)
            spread = float((wander.max(0) - wander.min(0)).max())
            bound = spread * math.sqrt(1.0 + hole / T)
            if m < n:
                Sd = np.concatenate((np.zeros((1, 3)), wander))
                e = Sd[m:] - Sd[:-m]
                rms = float(np.sqrt(np.mean(e * e, axis=0)).max())
                bound = min(bound, math.sqrt(2.0) * rms)
            # at the hole itself: the samples on either side of it away from the mean of the
            # last 1 / nom samples say the missing ones were too (a sway's peak)
            edge = 0.5 * (np.asarray(nxt) + x[-1]) - x[-min(n, int(round(1.0 / nom))):].mean(0)
            means.append(max(bound, float(np.abs(edge).max()) * nom * m) ** 2)
            if held:
                # at position k the held sample is x[k+m+1], the replaced ones x[k+1..k+m];
                # a hole as long as the window: what the means bridge would err
                if m + 1 < n:
                    S = np.concatenate((np.zeros((1, 3)), np.cumsum(x, axis=0)))
                    e = nom * (m * x[m + 1:] - (S[m + 1:n] - S[1:n - m]))
                    rms = float(np.sqrt(np.mean(e * e, axis=0)).max())
                    ramp = float(np.abs(np.asarray(nxt) - x[-1]).max()) * nom * m / 2.0
                    holds.append(max(math.sqrt(2.0) * rms, ramp) ** 2)
                else:
                    holds.append(means[-1])
        return tuple(means), (tuple(holds) if held else None), (second[:3], second[3:])


class _UnitsMonitor:
    """Detects gyro rates that are not rad/s (deg/s is 57.3x too large).

    Statistic: over each window (``units_check_window``, 30 s) every specific-force sample
    is rotated into the window's start frame with the gyro-integrated rotation B
    (``u = B f``) and averaged over 1 s bins; the body-frame samples ``f`` are binned the
    same way. The scatter of a set of bin means is the RMS angle between each of them and
    their (time-weighted) mean direction.

    - With rad/s rates all u point along gravity (fixed in the start frame) up to linear
      acceleration ``a / g`` and the slow drift of Earth rate and gyro bias. Linear
      acceleration shows in the body-frame f just as much (rotation does not change its
      size), so the u scatter stays below about the f scatter: sway, heave, surge and a
      shove raise both together.
    - With rates 57.3x too large B turns the wrong way: the u wander by the rotation error
      (tens of degrees in sway; on a static base Earth rate's horizontal component x 57.3,
      about 0.2 deg/s at 34 deg N and 0.12 deg/s at 60 deg N, i.e. a ramp of 3.6-6 deg in
      30 s, 1-1.7 deg RMS), while f does not move.

    The rates are flagged when ``scatter(u) > RATIO x scatter(f) + allow T / sqrt(12) + TOL``:
    ``allow T / sqrt(12)`` is the RMS of the largest genuine drift over the window (Earth
    rate plus 3x the gyro bias spec), TOL a margin for the rest (noise, the second-order
    terms of sway). A window is discarded without a verdict at a gap or a time jump (an
    interval above ``gap_ratio`` x nominal, or above ``max_gap``): the rate of one sample
    cannot be integrated over the hole.
    """

    RATIO = 2.0
    TOL = 0.25 * DEG

    def __init__(self, al: Aligner):
        self.al = al
        self.window = al.config.units_check_window
        self.allow = OMEGA_IE + 3.0 * al.config.specs.gyro_bias
        self.bins = int(math.ceil(self.window)) + 1
        self.last_mismatch_deg = None       # scatter of u of the last judged window, deg
        self.last_limit_deg = None          # and the limit it was compared with, deg
        self.verdict: bool | None = None    # of the window add() closed; the Aligner takes it
        self._start()

    def _start(self):
        self.T = 0.0
        self.B = np.eye(3)
        self.acc = np.zeros((self.bins, 7))     # per 1 s bin: sum dt, sum f dt, sum u dt

    def _gap(self, dt) -> float:
        """Largest interval that is not a gap (the Aligner's rule; max_gap while the
        nominal interval is not known yet)."""
        c, nom = self.al.config, self.al.nominal_dt
        return c.max_gap if nom is None else min(c.gap_ratio * nom, c.max_gap)

    def add_block(self, dts, w, f) -> int:
        """Samples of a run. Windows that close inside it are judged as :meth:`add` would
        (a gap or a non-positive interval discards the window, as there); the block stops
        before the closing sample of a window that would flag the rates (that sample goes
        through :meth:`add`). Returns how many samples were taken."""
        dts = np.asarray(dts, dtype=float)
        n = len(dts)
        bad = np.flatnonzero(~((dts > 0.0) & (dts <= self._gap(None))))
        k = 0
        for b in list(bad) + [n]:
            m = self._add_run(dts[k:b], w[k:b], f[k:b])
            if m < b - k:
                return k + m
            if b < n:
                self._start()                 # a gap: no verdict, a new window after it
            k = b + 1
        return n

    def _add_run(self, dts, w, f) -> int:
        """add_block for a run without gaps."""
        k, n = 0, len(dts)
        while k < n:
            # window times as add() sums them (one addition after the other)
            T = np.cumsum(np.concatenate([[self.T], dts[k:]]))[1:]
            closing = np.nonzero(T >= self.window)[0]
            end = k + int(closing[0]) + 1 if len(closing) else n
            state = self._accumulated(dts[k:end], w[k:end], f[k:end], T[:end - k])
            if not len(closing):
                self.B, self.acc, self.T = state
                return n
            verdict = self._verdict(*state)
            if verdict is not None and verdict[0] and not self.al.units_suspect:
                if end - 1 > k:                   # everything before the closing sample
                    self.B, self.acc, self.T = self._accumulated(
                        dts[k:end - 1], w[k:end - 1], f[k:end - 1], T[:end - 1 - k])
                return end - 1
            if verdict is not None:
                self.last_mismatch_deg, self.last_limit_deg = verdict[1] / DEG, verdict[2] / DEG
            self._start()
            k = end
        return n

    def _accumulated(self, dts, w, f, T):
        """(B, bin sums, T) after samples with window times T (not stored)."""
        from sins_align.core.preint import prefix_rotations
        q = prefix_rotations(dts[None], w[None])       # exp(w_1 dt_1) ... exp(w_k dt_k)
        Q = dcm_from_quat(np.stack([c[0] for c in q], axis=-1))
        u = np.einsum("ij,kjl,kl->ki", self.B, Q, f)
        acc = self.acc.copy()
        j = np.minimum(T.astype(int), self.bins - 1)
        for col, x in ((0, dts[:, None]), (1, f * dts[:, None]), (4, u * dts[:, None])):
            for i in range(x.shape[1]):
                acc[:, col + i] += np.bincount(j, x[:, i], minlength=self.bins)
        return self.B @ Q[-1], acc, float(T[-1])

    @staticmethod
    def _scatter(m: np.ndarray, wt: np.ndarray) -> float:
        """RMS angle (rad, weights wt) between vectors m (k, 3) and their weighted mean."""
        d = wt @ m
        d = d / np.linalg.norm(d)
        ang = np.arctan2(np.linalg.norm(np.cross(m, d), axis=1), m @ d)
        return math.sqrt(float(wt @ (ang * ang)) / float(wt.sum()))

    def _verdict(self, B, acc, T):
        """(flag the rates?, scatter of u, limit), rad, of a closed window; None without
        data (fewer than two bins, or a zero mean)."""
        wt = acc[:, 0]
        use = wt > 0.0
        if use.sum() < 2:
            return None
        wt = wt[use]
        mf = acc[use, 1:4] / wt[:, None]
        mu = acc[use, 4:7] / wt[:, None]
        if not (np.linalg.norm(wt @ mf) > 0.0 and np.linalg.norm(wt @ mu) > 0.0):
            return None
        su, sf = self._scatter(mu, wt), self._scatter(mf, wt)
        limit = self.RATIO * sf + self.allow * T / math.sqrt(12.0) + self.TOL
        return su > limit, su, limit

    def add(self, dt, w, f):
        """One sample; returns exp(w dt), which the filter can reuse (None if skipped: a
        gap or a time jump, which also discards the window). A window closing here leaves
        its verdict in :attr:`verdict` (True: the rates look like deg/s)."""
        if not 0.0 < dt <= self._gap(None):
            self._start()
            return None
        dR = so3_exp(w * dt)
        self.B = self.B @ dR
        self.T += dt
        j = min(int(self.T), self.bins - 1)
        a = self.acc[j]
        a[0] += dt
        a[1:4] += f * dt
        a[4:7] += (self.B @ f) * dt
        if self.T >= self.window:
            verdict = self._verdict(self.B, self.acc, self.T)
            if verdict is not None:
                bad, su, limit = verdict
                self.verdict = bool(bad)
                self.last_mismatch_deg, self.last_limit_deg = su / DEG, limit / DEG
            self._start()
        return dR
