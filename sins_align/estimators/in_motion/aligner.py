"""Streaming in-motion alignment with a velocity reference (:class:`MotionAligner`).

The stream around :class:`~sins_align.estimators.in_motion.filter.InvariantEKF`, behind the
interface every estimator has (:mod:`sins_align.estimators`):

- IMU samples (:meth:`MotionAligner.update`, one or a block) are checked and propagated,
  each at its instant on the IMU's steady clock (the stamp itself, unless the stamps
  jitter: :mod:`~sins_align.core.clock`; ``t_last`` is the last instant);
- measurements (:meth:`~MotionAligner.add_velocity`, :meth:`~MotionAligner.add_attitude`) are
  applied at their own stamps: one stamped ahead of the IMU waits until the IMU reaches it;
  one stamped behind (GNSS velocity arrives ~0.1 s after its stamp) makes the filter go back
  to a stored state before the stamp and run the stored samples again, up to
  ``max_measurement_lag`` s back; older ones are refused;
- a measurement with the stamp of one of its kind already held is refused
  ('measurement_duplicate': a message delivered twice would count as two);
- a step in the velocity reference's error (a receiver's velocity biased by a reflected
  signal for seconds, its covariance as usual; :meth:`MotionAligner._step_check`): once one
  filter is left, the sum of the last second's velocity innovations is tested against its
  covariance; beyond the chi-square quantile of 1e-6 the covariance takes what those updates
  moved the state by, and the velocity updates are held until a window of them agrees with
  the filter again (or for at most :data:`STEP_HOLD_MAX` s);
- a ground vehicle gets the non-holonomic constraint every ``nhc_period`` s;
- the start: roll and pitch from the mean specific force over ``init_time`` s, the velocity
  from the first measurement; their covariance covers the worst case the data allow (tilt
  from the acceleration the velocity reference shows during the averaging, the
  measurement's age). The heading from a guess (``initial_rpy_deg`` with a std up to 30
  deg): one filter; else a bank of ``heading_hypotheses`` filters whose yaws are spread
  around the circle, weighed by the likelihood of every measurement; a hypothesis that
  converges onto the best merges into it, one under 1e-6 is dropped, and the bank collapses
  to the best once it holds 99.9 %. Until then the published attitude is the best one's and
  the covariance the mixture's about it;
- the heading counts as observable once its std is below ``observable_heading_std_deg``
  (seed 001: velocity matching sees heading only through horizontal specific force, so this
  happens at the first acceleration or turn, or never while the vehicle stands or cruises);
  ``aligned`` needs it, the std criteria and consistent recent innovations.
"""
from __future__ import annotations

import bisect
import math
import operator
from collections import Counter, deque
from collections.abc import Callable

import numpy as np

from sins_align.core.earth import normal_gravity
from sins_align.core.rotation import (attitude_error, dcm_from_quat, dcm_from_rpy,
                                      so3_left_jacobian_inv, so3_log)
from sins_align.core.specs import DEG, DPH
from sins_align.core.strapdown import NavState
from sins_align.core.clock import SampleClock
from sins_align.estimators.in_motion.config import MotionConfig
from sins_align.estimators.in_motion.feedback import (FractionalFeedback, LqrFeedback,
                                                      lqr_gain)
from sins_align.estimators.in_motion.filter import (IBA, IBG, INU, IPHI, InvariantEKF,
                                                    NoiseModel, extra_size)
from sins_align.estimators.in_motion.gaps import bridge_gaps
from sins_align.estimators.in_motion.jitter import TONE_WINDOW, JitterMonitor, VelocityJitter
from sins_align.estimators.in_motion.stillness import WINDOW as STILL_WINDOW
from sins_align.estimators.in_motion.stillness import (gyrocompass_limit, imu_at_rest,
                                                      reference_still)
from sins_align.estimators.base import AlignmentEvent, AttitudeReadout, EventSource

__all__ = ["MotionAligner", "MOTION_REJECT_REASONS", "MOTION_STATES"]

#: Reasons an IMU sample or a measurement can be refused.
MOTION_REJECT_REASONS = (
    "nonfinite",                  # NaN or Inf in a stamp or a value
    "duplicate_stamp",            # IMU: same stamp as the previous accepted sample
    "stamp_backwards",            # IMU: stamp earlier than the previous accepted sample
    "time_jump",                  # IMU: gap above max_gap: the alignment starts over
    "gravity_removed",            # IMU: |f| < 0.25 g
    "specific_force_out_of_range",  # IMU: |f| > specific_force_max
    "rate_too_high",              # IMU: |w| > max_angular_rate
    "measurement_too_late",       # a measurement stamped more than max_measurement_lag back
    "measurement_duplicate",      # a measurement of the same kind and stamp as one accepted
    "measurement_invalid",        # a measurement with a bad covariance or shape
    "undecodable",                # (align_node) a message whose bytes could not be decoded
    "no_position",                # IMU: no position yet (latitude_deg NaN: the first
                                  # add_position gives it)
)

MOTION_STATES = ("waiting", "aligning", "aligned")

#: heading std of each hypothesis, as a fraction of their spacing
HYPOTHESIS_SPREAD = 0.6
#: s of history kept beyond max_measurement_lag (for the rewinds)
_HISTORY_MARGIN = 0.2
#: events of the updates a rewind re-applies: the snapshots keep their counts
_REPLAYED_EVENTS = ("velocity", "velocity_inflated", "velocity_parked", "attitude", "nhc",
                    "nhc_parked", "hypotheses_merged", "heading_acquired", "velocity_step")
#: the counts of _REPLAYED_EVENTS in a Counter, as a tuple (0 for those not counted yet)
_replayed_counts = operator.itemgetter(*_REPLAYED_EVENTS)
#: s: the velocity updates whose innovations are summed to look for a step in the
#: reference's error (:meth:`MotionAligner._step_check`)
STEP_WINDOW = 1.0
#: that sum's y^T (sum S)^-1 y above which the reference stepped: the chi-square quantile
#: of 1e-6 for 1, 2, 3 degrees of freedom
STEP_LIMIT = {1: 23.93, 2: 27.63, 3: 30.66}
#: ... and within which, over a window of at least :data:`STEP_RESUME_UPDATES` held updates,
#: it agrees with the filter again: the chi-square quantile of 1 %
STEP_RESUME_LIMIT = {1: 6.63, 2: 9.21, 3: 11.34}
STEP_RESUME_UPDATES = 5
#: s: the longest the velocity updates are held after a step (the reference then believed):
#: a reflection's burst lasts 2-10 s; a step that is the IMU's (a shock clipped by its
#: range) is the reference's only in appearance, and the filter dead-reckons through it
#: (car_city, 0.2 m/s bursts of 10 s / a 50 m/s^2 shock clipped at 4 g, seeds 0-2: % of the
#: instants beyond 3 sigma 0 / 3.7 / 0 and 0 / 6.6 / 0.3 with 15 s; 0 / 7.4 / 0 and
#: 0.1 / 11.3 / 4.7 with 10 s; 0 / 1.8 / 0 and 9.9 / 3.0 / 0.2 with 30 s)
STEP_HOLD_MAX = 15.0
#: a bias estimate this many of its prior's stds from zero (the single filter's, any axis)
#: says the IMU is worse than its configured specs (:meth:`MotionAligner._check_specs`):
#: with specs that fit, the largest seen over the benchmark's car, UAV and ship scenarios
#: (4 seeds each, node defaults) was 2.7
BIAS_BEYOND_SPEC = 5.0
#: a heading guess with a std above this (deg) is no guess: the bank of hypotheses starts
HYPOTHESIS_MAX_STD_DEG = 30.0
#: hypotheses whose weight falls below this are dropped
HYPOTHESIS_MIN_WEIGHT = 1e-6
#: the bank collapses to its best hypothesis once that one holds this weight
HYPOTHESIS_COLLAPSE = 0.999


class MotionAligner(EventSource, AttitudeReadout):
    """Streaming in-motion alignment of one IMU with a velocity reference.

    Examples
    --------
    >>> al = MotionAligner(MotionConfig(latitude_deg=34.0, specs="consumer"))
    >>> al.add_velocity(t_gnss, v_enu)              # any order, up to max_measurement_lag late
    >>> al.update(t, gyro, accel)                   # t (N,) s, gyro (N, 3), accel (N, 3)
    >>> al.quaternion, al.std_enu_deg, al.heading_observable, al.aligned
    """

    def __init__(self, config: MotionConfig):
        self.config = config
        s = config.specs
        # the bias wander's random walk over short times; a warm-up as one more wander
        wg, wa = s.bias_walk_var
        walk_g = math.sqrt(wg) or 0.01 * s.gyro_bias
        walk_a = math.sqrt(wa) or 0.01 * s.accel_bias
        self.noise = NoiseModel(s.gyro_arw, s.accel_vrw, walk_g, walk_a)
        # (gyro, accelerometer) bias prior variance (the bias states' initial variance), and
        # its std (the specs check's unit; the bias itself when there is neither)
        self._bias_prior_var = s.bias_prior_var
        self._bias_prior_std = (
            math.hypot(s.gyro_bias, s.gyro_bias_instability, s.gyro_warmup),
            math.hypot(s.accel_bias, s.accel_bias_instability, s.accel_warmup))
        # (velocity_noise > 0 is checked by the config: valid whatever is measured)
        self._default_R = np.eye(3) * config.velocity_noise ** 2
        # its whitening (_whitened): 1 / sqrt of the diagonal and that one's outer product
        a = 1.0 / np.sqrt(self._default_R.diagonal())
        self._default_white = (a, np.outer(a, a))
        self._jitter_any = (None, False)         # (a jitter covariance, whether nonzero)
        # (the bank's attitudes, the best one's row, each one's attitude_error from it) as
        # _weigh left them, for the covariance after it
        self._bank_errors: tuple | None = None
        self.rejected: Counter = Counter()
        self.events: Counter = Counter()
        self._listeners: list[Callable[[AlignmentEvent], None]] = []
        self._aligned = False
        self.t_last: float | None = None
        self.reset("start")

    # ------------------------------------------------------------------ lifecycle
    def reset(self, reason: str = "reset") -> None:
        """Forget the alignment and the time line; keep the configuration, subscriptions and
        the life counters ``rejected`` and ``events``."""
        c = self.config
        last = self.t_last
        self.ekf: InvariantEKF | None = None
        self._logw = np.zeros(1)
        self._best = 0
        self.t_last = None
        self._stamp_last: float | None = None   # the last accepted stamp (t_last: its instant)
        self._clock = SampleClock()
        self.t_first: float | None = None
        self.last_reject: str | None = None
        self.samples_used = 0
        if not math.isnan(c.latitude_deg) or not hasattr(self, "position"):
            # (latitude NaN: no position until add_position; a restart keeps the last one)
            self.position = (c.latitude_deg * DEG, c.longitude_deg * DEG, c.height_m)
        self._init_buf: deque = deque()          # (t, gyro, accel) before the start
        self._imu_seen: float | None = None      # the newest IMU stamp refused (no position)
        self._pending: list = []                 # sorted (stamp, seq, kind, payload)
        self._seq = 0
        self._applied: deque = deque()           # measurements applied, within the lag
        self._history: deque = deque()           # accepted samples (t, gyro, accel) arrays
        self.nominal_dt: float | None = None     # s, the median interval at the start
        self._jitter = JitterMonitor()
        self._rest_at: tuple | None = None      # (stamp, IMU at rest there) of _parked
        self._vjitter = VelocityJitter(c.max_measurement_lag + _HISTORY_MARGIN
                                       + max(c.velocity_averaging, 2.0 * TONE_WINDOW) + 1.0)
        self._snaps: deque = deque()             # (t, ekf copy, next nhc time)
        self._next_nhc: float | None = None
        self._nis: deque = deque()               # (t, nis per dof, dof, that with R as given)
        self._nis_sum = [0.0, 0, 0.0]            # their sums of nis * dof, dof, nis_ref * dof
        # the velocity updates' innovations against R as given, whitened: (t, c, lam), with
        # y^T (H P H^T + s R)^-1 y = sum(c / (lam + s)) (noise_scale)
        self._vel_win = _InnovationWindow()
        # the single filter's velocity updates for the step test (_step_check): (t, which
        # components, y, H P H^T + s R, the error estimate it made), and the instants the
        # test fired at (the updates up to them are not summed again)
        self._steps: deque = deque()
        # (the instant the reference was found stepped and its updates held, or None; the
        # instant from which the sums run): kept with each stored state
        self._step_mode: tuple = (None, -math.inf)
        #: the factor the velocity references' covariances are multiplied by (>= 1): what
        #: the recent innovations say their noise is (:meth:`_noise_scale`)
        self.noise_scale = 1.0
        self._replaying = False
        self.time_to_aligned: float | None = None
        self.heading_observable = False
        #: False while the velocity reference contradicts the IMU (config.inconsistent_nis):
        #: the attitude is then published as unknown
        self.reference_consistent = True
        self._inconsistent_until = -math.inf
        #: False once a bias estimate went BIAS_BEYOND_SPEC of its prior's stds from zero:
        #: the IMU is worse than its configured specs, and nothing published rests on them
        #: (the attitude is published as unknown) until a restart
        self.specs_consistent = True
        #: (gyro, accelerometer): the largest |bias estimate| / its prior std seen (the
        #: configured bias, bias instability and warm-up together)
        self.bias_spec_ratio = (0.0, 0.0)
        if self._aligned:
            self._aligned = False
            self._emit("aligned", last, False)
        self._emit("restarted", None, reason)

    # ------------------------------------------------------------------ results
    @property
    def initialized(self) -> bool:
        return self.ekf is not None

    @property
    def dcm(self) -> np.ndarray:
        return (np.eye(3) if self.ekf is None
                else self.ekf.corrected_dcms()[self._best].copy())

    @property
    def covariance(self) -> np.ndarray:
        """Attitude error covariance, ENU (C_true = exp(e x) C_est), rad^2: the filter's
        (while the bank of hypotheses runs, the Gaussian sum's about the published one) plus
        the jitter the gyro's high-frequency content puts on the attitude
        (:attr:`jitter_covariance`). Before the start: pi^2 on each axis (nothing known)."""
        if self.ekf is None or not (self.reference_consistent and self.specs_consistent):
            return np.eye(3) * math.pi ** 2
        ekf = self.ekf
        jit = self._jitter.covariance                   # body axes
        if ekf.K == 1:
            Ce = ekf.C[0]
            cov = Ce @ ekf.P[0, IPHI, IPHI] @ Ce.T
            if self._jitter_any[0] is not jit:    # (a new array at each of its windows)
                self._jitter_any = (jit, bool(jit.any()))
            if self._jitter_any[1]:
                C = ekf.corrected_dcms()[0]
                cov = cov + C @ jit @ C.T
            return cov
        covs = ekf.covariance_enu
        Cs = ekf.corrected_dcms()
        C = Cs[self._best]
        jitter = C @ jit @ C.T
        # the Gaussian sum's covariance about the published (best) hypothesis: each
        # hypothesis' error carried to the best one's attitude, d away (the inverse left
        # Jacobian at d: up to 1.57 x on the level axes of one 180 deg off in heading)
        w = np.exp(self._logw)
        known = self._bank_errors
        if known is not None and known[0] is Cs and known[1] == self._best:
            d = known[2]
        else:
            d = attitude_error(Cs, Cs[self._best][None])                 # (K, 3), ENU
        J = so3_left_jacobian_inv(d)
        covs = J @ covs @ np.swapaxes(J, -1, -2)
        return np.einsum("k,kij->ij", w, covs + d[:, :, None] * d[:, None, :]) + jitter

    @property
    def jitter_covariance(self) -> np.ndarray:
        """(3, 3) rad^2, body axes: the attitude jitter measured from the gyro's content at
        5 Hz and above over the last two 1 s windows
        (:class:`~sins_align.estimators.in_motion.jitter.JitterMonitor`), part of
        :attr:`covariance`."""
        return self._jitter.covariance.copy()

    @property
    def hypotheses(self) -> int:
        """Heading hypotheses still alive (1 once the heading is acquired; 0 before the
        start)."""
        return 0 if self.ekf is None else self.ekf.K

    @property
    def velocity(self) -> np.ndarray:
        return np.full(3, np.nan) if self.ekf is None else self.ekf.corrected(self._best)[1]

    @property
    def bias_gyro(self) -> np.ndarray:
        return np.full(3, np.nan) if self.ekf is None else self.ekf.corrected(self._best)[2]

    @property
    def bias_accel(self) -> np.ndarray:
        return np.full(3, np.nan) if self.ekf is None else self.ekf.corrected(self._best)[3]

    @property
    def lever_arm(self) -> np.ndarray:
        return (np.array(self.config.lever_arm) if self.ekf is None
                else self.ekf.corrected(self._best)[4])

    @property
    def nhc_lever_arm(self) -> np.ndarray:
        """m, IMU frame: the estimated (or configured) lever arm from the IMU to the point of
        the non-holonomic constraint (a ground vehicle's rear-axle centre)."""
        return (np.array(self.config.nhc_lever_arm) if self.ekf is None
                else self.ekf.corrected(self._best)[6])

    @property
    def velocity_latency(self) -> float:
        """s: the velocity reference's latency (its stamps later than the instant measured),
        estimated with ``velocity_latency_std`` > 0, else the configured one."""
        return (float(self.config.velocity_latency) if self.ekf is None
                else float(self.ekf.latency[self._best, 0]))

    @property
    def nhc_mount(self) -> np.ndarray:
        """rad, rotation vector in IMU axes: the estimated rotation of the vehicle's axes
        against the IMU's (the vehicle's side is ``exp(eps x) e_nhc_axis``; zeros when not
        estimated, ``nhc_mount_std_deg`` 0)."""
        return (np.zeros(3) if self.ekf is None
                else so3_log(self.ekf.corrected(self._best)[7]))

    @property
    def nis(self) -> float:
        """Mean NIS per degree of freedom over the last ``aligned_nis_window`` s (nan: none),
        the velocity references' covariances scaled by ``noise_scale`` as applied."""
        if not self._nis:
            return math.nan
        return self._nis_sum[0] / self._nis_sum[1]

    @property
    def reference_nis(self) -> float:
        """:attr:`nis` with the velocity references' covariances as given (not scaled): what
        ``inconsistent_nis`` is compared with."""
        if not self._nis:
            return math.nan
        return self._nis_sum[2] / self._nis_sum[1]

    @property
    def aligned(self) -> bool:
        return self._aligned

    @property
    def status(self) -> str:
        if self.ekf is None:
            return "waiting"
        return "aligned" if self._aligned else "aligning"

    @property
    def elapsed(self) -> float:
        if self.t_first is None or self.t_last is None:
            return 0.0
        return self.t_last - self.t_first

    # ------------------------------------------------------------------ IMU
    def update(self, stamp, gyro, accel) -> int:
        """IMU samples: one (float stamp, (3,) rad/s, (3,) m/s^2) or a block ((N,), (N, 3),
        (N, 3)). Returns how many were accepted. A gap above ``max_gap`` rejects the sample
        after it ('time_jump') and starts the alignment over."""
        t = np.atleast_1d(np.asarray(stamp, dtype=float))
        w = np.asarray(gyro, dtype=float).reshape(-1, 3)
        f = np.asarray(accel, dtype=float).reshape(-1, 3)
        if not (len(t) == len(w) == len(f)):
            raise ValueError("stamp, gyro and accel must have the same number of samples")
        if math.isnan(self.position[0]):
            # no position yet (latitude_deg NaN): Earth rate and gravity are unknown
            for x in t.tolist():
                self._reject("no_position", x if math.isfinite(x) else None)
                if math.isfinite(x):
                    self._imu_seen = x if self._imu_seen is None else max(self._imu_seen, x)
            self._trim_waiting()
            return 0
        good, jump = self._check(t, w, f)
        end = len(t) if jump is None else jump
        idx = np.flatnonzero(good[:end])
        if len(idx):
            self._feed(t[idx], w[idx], f[idx])
        if jump is None:
            return len(idx)
        gap = float(t[jump]) - self._stamp_last
        self._reject("time_jump", float(t[jump]))
        # the measurements not applied yet are still good for the new start (the one it
        # takes is weighed by its age there); a caller that gave them ahead loses nothing
        pending, seq = self._pending, self._seq
        self.reset(f"IMU gap of {gap:.3f} s")
        self._pending, self._seq = pending, seq
        return len(idx) + self.update(t[jump + 1:], w[jump + 1:], f[jump + 1:])

    def _check(self, t, w, f):
        """Each sample accepted or rejected (events emitted), in order against the last
        accepted stamp, up to the first time jump; returns (mask, index of the jump or None).
        """
        c = self.config
        n = len(t)
        if n == 1:
            return self._check_one(float(t[0]), w[0].tolist(), f[0].tolist())
        finite = np.isfinite(t) & np.all(np.isfinite(w), 1) & np.all(np.isfinite(f), 1)
        fn = np.linalg.norm(np.where(finite[:, None], f, 0.0), axis=1)
        wn = np.linalg.norm(np.where(finite[:, None], w, 0.0), axis=1)
        reason = np.full(n, "", dtype=object)
        reason[~finite] = "nonfinite"
        reason[finite & (fn < 0.25 * 9.8)] = "gravity_removed"
        reason[finite & (fn > c.specific_force_max)] = "specific_force_out_of_range"
        reason[(reason == "") & (wn > c.max_angular_rate)] = "rate_too_high"
        good = reason == ""
        last = -math.inf if self._stamp_last is None else self._stamp_last
        prior = np.maximum.accumulate(np.concatenate(([last], np.where(good, t, -np.inf)[:-1])))
        dup = good & (t == prior)
        back = good & (t < prior)
        reason[dup] = "duplicate_stamp"
        reason[back] = "stamp_backwards"
        good &= ~(dup | back)
        jump = None
        gj = np.flatnonzero(good & np.isfinite(prior) & (t - prior > c.max_gap))
        if len(gj):
            jump = int(gj[0])
        end = n if jump is None else jump
        for i in np.flatnonzero(~good[:end]):
            self._reject(reason[i], float(t[i]) if np.isfinite(t[i]) else None)
        return good, jump

    def _check_one(self, t, w, f):
        """:meth:`_check` of one sample (a live stream's), in scalar arithmetic: the same
        rules in the same order."""
        c = self.config
        reason = ""
        if not (math.isfinite(t) and all(math.isfinite(x) for x in w + f)):
            reason = "nonfinite"
        else:
            fn = math.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])
            if fn < 0.25 * 9.8:
                reason = "gravity_removed"
            elif fn > c.specific_force_max:
                reason = "specific_force_out_of_range"
            elif math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]) > c.max_angular_rate:
                reason = "rate_too_high"
        last = -math.inf if self._stamp_last is None else self._stamp_last
        if not reason:
            if t == last:
                reason = "duplicate_stamp"
            elif t < last:
                reason = "stamp_backwards"
        if reason:
            self._reject(reason, t if math.isfinite(t) else None)
            return np.zeros(1, dtype=bool), None
        jump = 0 if math.isfinite(last) and t - last > c.max_gap else None
        return np.ones(1, dtype=bool), jump

    def _feed(self, t, w, f):
        """Accepted samples, in order: from here on, each at its instant on the IMU's clock
        (core/clock.py: the stamp itself unless the stamps jitter)."""
        self._stamp_last = float(t[-1])
        t = self._clock.times(t)
        if self.t_first is None:
            self.t_first = float(t[0])
        self._jitter.add(t, w)
        self._vjitter.add(t, f, w)
        k = 0
        if self.ekf is None:
            k = self._initialize(t, w, f)
        prev = float(t[k - 1]) if k > 0 else self.t_last
        self.t_last = float(t[-1])
        self.samples_used += len(t)
        if self.ekf is not None and k < len(t):
            tt, ww, ff = t[k:], w[k:], f[k:]
            self._history.append((tt, ww, ff))
            self._process(prev, tt, ww, ff)
            self._snapshot()
            self._prune()
        self._evaluate(self.t_last)

    # ------------------------------------------------------------------ start
    def _initialize(self, t, w, f) -> int:
        """Collect samples until ``init_time`` s of them and a velocity measurement within
        them; then start the filter at the last collected sample. Returns how many of the
        given samples were used for the start (the rest are to be propagated)."""
        c = self.config
        for i in range(len(t)):
            self._init_buf.append((float(t[i]), w[i], f[i]))
            while self._init_buf and self._init_buf[0][0] < t[i] - c.init_time:
                self._init_buf.popleft()
            if self._init_buf[-1][0] - self._init_buf[0][0] < 0.999 * c.init_time:
                continue
            # the pending list is sorted by stamp: those up to this sample
            reached = self._pending[:bisect.bisect_right(self._pending, (float(t[i]), math.inf))]
            meas = [p for p in reached if p[2] == "velocity"]
            if not meas:
                continue
            self._start(float(t[i]), meas)
            return i + 1
        return len(t)

    def _start(self, t0, meas):
        c = self.config
        buf = list(self._init_buf)
        self._init_buf.clear()
        # the IMU's interval: lost samples later are holes against it (gaps.py)
        self.nominal_dt = float(np.median(np.diff([b[0] for b in buf])))
        fs = np.array([b[2] for b in buf])
        ws = np.array([b[1] for b in buf])
        fm = fs.mean(axis=0)
        # level: the body z of ENU ("up") is along the mean specific force
        up = fm / np.linalg.norm(fm)
        yaw = 0.0 if c.initial_rpy_deg is None else c.initial_rpy_deg[2] * DEG
        guess = (c.initial_rpy_deg is not None
                 and c.initial_heading_std_deg <= HYPOTHESIS_MAX_STD_DEG)
        K = 1 if guess else c.heading_hypotheses
        yaws = yaw + np.arange(K) * (2.0 * math.pi / K)
        Cs = np.array([_level_dcm(up, y) for y in yaws])
        # velocity: the newest measurement up to t0; the older ones go
        stamp, _, _, (z, R) = meas[-1]
        self._pending = [p for p in self._pending if p[0] > t0]
        # horizontal acceleration seen by the reference during the averaging: tilt bound
        vs = [p[3][0] for p in meas if p[0] >= buf[0][0] - 0.5]
        ts = [p[0] for p in meas if p[0] >= buf[0][0] - 0.5]
        if len(vs) >= 2 and ts[-1] > ts[0]:
            dv = np.nan_to_num(np.asarray(vs[-1]) - np.asarray(vs[0]))
            a_h = float(np.hypot(dv[0], dv[1])) / (ts[-1] - ts[0])
        else:
            a_h = 1.0                       # unknown: assume a moderate acceleration
        g = float(normal_gravity(self.position[0], self.position[2]))
        level_std = max(2.0 * DEG, 2.0 * math.atan2(a_h + 0.3, g))
        # vibration / rotation during averaging widens it too
        level_std = max(level_std, float(np.std(fs, axis=0).max()) / g)
        head_std = (c.initial_heading_std_deg if guess
                    else HYPOTHESIS_SPREAD * 360.0 / K) * DEG
        z = np.where(np.isfinite(z), z, 0.0)
        age = t0 - stamp
        lev = np.linalg.norm(c.lever_arm)
        wmax = float(np.linalg.norm(ws, axis=1).max())
        v_var = np.diag(R).copy()
        v_var[~np.isfinite(v_var)] = 4.0
        v_var = v_var + (age * (a_h + 0.5)) ** 2 + (wmax * lev) ** 2 + 0.05 ** 2
        extra = tuple(x for x, on in (("lever", c.lever_arm_std > 0),
                                      ("mount", c.attitude_matching and c.mounting_std_deg > 0),
                                      ("gyro_scale", c.gyro_scale_std > 0),
                                      ("accel_scale", c.accel_scale_std > 0),
                                      ("nhc_lever", c.vehicle == "ground"
                                       and c.nhc_lever_arm_std > 0),
                                      ("nhc_mount", c.vehicle == "ground"
                                       and c.nhc_mount_std_deg > 0),
                                      ("latency", c.velocity_latency_std > 0))
                      if on)
        n = 12 + extra_size(extra)
        P = np.zeros((K, n, n))
        # attitude: ENU covariance diag(level, level, heading) to body axes
        Pn = np.diag([level_std ** 2, level_std ** 2, head_std ** 2])
        Pv = np.diag(v_var)
        for i in range(K):
            P[i][IPHI, IPHI] = Cs[i].T @ Pn @ Cs[i]
            P[i][INU, INU] = Cs[i].T @ Pv @ Cs[i]
        # the bias at the start: the turn-on bias plus the wander's value then (stationary)
        vg, va = self._bias_prior_var
        P[:, IBG, IBG] = np.eye(3) * vg
        P[:, IBA, IBA] = np.eye(3) * va
        i = 12
        for x in extra:
            std = {"lever": c.lever_arm_std, "mount": c.mounting_std_deg * DEG,
                   "gyro_scale": c.gyro_scale_std, "accel_scale": c.accel_scale_std,
                   "nhc_lever": c.nhc_lever_arm_std, "nhc_mount": c.nhc_mount_std_deg * DEG,
                   "latency": c.velocity_latency_std}[x]
            m = extra_size((x,))
            P[:, i:i + m, i:i + m] = np.eye(m) * std ** 2
            i += m
        lat, lon, h = self.position
        self.ekf = InvariantEKF(NavState(Cs[0], z, lat, lon, h), P, self.noise, c.lever_arm, C=Cs,
                                extra=extra, nhc_lever_arm=c.nhc_lever_arm)
        if c.feedback == "lqr":
            self.ekf.schedule = LqrFeedback(lqr_gain(n, lat, g, c.lqr_time_constant))
        elif c.feedback == "fraction":
            self.ekf.schedule = FractionalFeedback(n, c.feedback_fraction)
        self.ekf.latency = np.full((K, 1), c.velocity_latency)
        self.ekf.w_last = np.tile(ws[-1], (K, 1))
        self.ekf.f_last = np.tile(fs[-1], (K, 1))
        self._logw = np.full(K, -math.log(K))
        self._prior_head_std = head_std
        self._best = 0
        if c.vehicle == "ground":
            self._next_nhc = t0 + c.nhc_period
        self.t_start = t0
        self._snaps.clear()
        self._snap_now(t0)
        self.events["started"] += 1

    # ------------------------------------------------------------------ measurements
    def add_velocity(self, stamp, v_enu, cov=None) -> bool:
        """Velocity of the antenna (ENU, m/s) measured at ``stamp``; a NaN component is not
        measured; ``cov`` (3, 3) ENU (m/s)^2 or None for ``velocity_noise``. Applied at its
        stamp (see the module docstring). False (and a 'rejected' event) when refused."""
        z = np.asarray(v_enu, dtype=float).reshape(-1)
        if z.shape != (3,):
            self._reject("measurement_invalid", None)
            return False
        zl = z.tolist()
        ok = [math.isfinite(x) for x in zl]
        if cov is None:
            R = self._default_R
        else:
            R = np.asarray(cov, dtype=float)
            if R.shape != (3, 3):
                self._reject("measurement_invalid", None)
                return False
        if not any(ok):
            self._reject("nonfinite", _fl(stamp))
            return False
        if cov is not None and not _valid_covariance(R.tolist(), ok):
            self._reject("measurement_invalid", _fl(stamp))
            return False
        return self._add("velocity", stamp, (z, R))

    def add_attitude(self, stamp, quaternion_xyzw, cov=None) -> bool:
        """Attitude of a master INS (its body in ENU; axes taken equal to ours) at ``stamp``;
        used only with ``attitude_matching``. ``cov`` (3, 3) rad^2 (body) or None."""
        q = np.asarray(quaternion_xyzw, dtype=float).reshape(-1)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-6:
            self._reject("measurement_invalid", _fl(stamp))
            return False
        if not self.config.attitude_matching:
            self.events["attitude_ignored"] += 1
            return True
        R = (np.eye(3) * (self.config.attitude_noise_deg * DEG) ** 2 if cov is None
             else np.asarray(cov, dtype=float))
        if R.shape != (3, 3) or not np.all(np.isfinite(R)) or np.any(np.diag(R) <= 0):
            self._reject("measurement_invalid", _fl(stamp))
            return False
        return self._add("attitude", stamp, (dcm_from_quat(q), R))

    def add_position(self, stamp, lat_deg, lon_deg, height_m) -> bool:
        """Geodetic position (NavSatFix): replaces the mechanized position of every filter
        on arrival (position is not estimated; it sets the Earth rate, transport rate and
        gravity, for which a fix 0.1 s old, metres off, changes nothing measurable)."""
        vals = (lat_deg, lon_deg, height_m)
        if not all(isinstance(x, (int, float)) and math.isfinite(x) for x in vals) or \
                not -90.0 < lat_deg < 90.0:
            self._reject("measurement_invalid", _fl(stamp))
            return False
        self.position = (lat_deg * DEG, lon_deg * DEG, float(height_m))
        if self.ekf is not None:
            # (new arrays: the stored states share theirs with the filter)
            K = self.ekf.K
            self.ekf.lat, self.ekf.lon, self.ekf.h = (np.full(K, x) for x in self.position)
        self.events["position"] += 1
        return True

    def _add(self, kind, stamp, payload) -> bool:
        try:
            ts = float(stamp)
        except (TypeError, ValueError):
            ts = math.nan
        if not math.isfinite(ts):
            self._reject("nonfinite", None)
            return False
        c = self.config
        if self.t_last is not None and ts < self.t_last - c.max_measurement_lag:
            self._reject("measurement_too_late", ts)
            return False
        if self._duplicate(kind, ts):
            self._reject("measurement_duplicate", ts)
            return False
        self._seq += 1
        item = (ts, self._seq, kind, payload)
        if self.ekf is None or ts > self.t_last:
            bisect.insort(self._pending, item)
            if self.ekf is None:
                self._trim_waiting()
            return True
        # late: go back to a stored state before ts and run the samples again
        if ts <= self.t_start:
            self.events["measurement_before_start"] += 1
            return True
        self._rewind(item)
        self._evaluate(self.t_last)
        return True

    def _trim_waiting(self) -> None:
        """Before the start: the measurements older than any start could use (``init_time``
        and ``max_measurement_lag`` before the newest IMU sample, taken or refused for want
        of a position, and a second) are dropped: a reference that keeps coming while the
        IMU's samples are refused must not pile up (with no IMU sample at all nothing is
        dropped: a caller may give the measurements ahead of the samples)."""
        c = self.config
        p = self._pending
        t = self.t_last if self.t_last is not None else self._imu_seen
        if t is None or not p:
            return                      # (no IMU time yet: a caller may give them ahead)
        lo = t - c.init_time - c.max_measurement_lag - 1.0
        if p[0][0] < lo:
            del p[:bisect.bisect_left(p, (lo,))]

    @property
    def pending_measurements(self) -> int:
        """How many measurements wait to be applied (their stamps not reached yet)."""
        return len(self._pending)

    def _duplicate(self, kind, ts) -> bool:
        """Is a measurement of this kind stamped ts already pending or applied within the
        lag? (A driver or a bag that delivers one message twice: applied twice, it would
        count as two independent measurements, its noise halved; over car_city with every
        GNSS velocity given twice, seeds 0-2, 0.2 / 10.2 / 1.5 % of the instants beyond 3
        sigma against 0 / 6.3 / 0 % once.) Both lists are in stamp order; an older one is
        refused as too late anyway."""
        i = bisect.bisect_left(self._pending, (ts,))
        while i < len(self._pending) and self._pending[i][0] == ts:
            if self._pending[i][2] == kind:
                return True
            i += 1
        for a in reversed(self._applied):
            if a[0] < ts:
                break
            if a[0] == ts and a[2] == kind:
                return True
        return False

    def _rewind(self, item):
        ts = item[0]
        k = len(self._snaps) - 1
        while k > 0 and self._snaps[k][0] >= ts:
            k -= 1
        t_s, ekf, nhc, logw, best, counts, self._step_mode = self._snaps[k]
        while len(self._snaps) > k + 1:
            self._snaps.pop()
        self.ekf = ekf.snapshot()
        self._next_nhc = nhc
        self._logw = logw.copy()
        self._best = best
        # what the samples after t_s did is done again: counted again from there
        for key, count in zip(_REPLAYED_EVENTS, counts):
            if count:
                self.events[key] = count
            else:
                self.events.pop(key, None)
        redo = [a for a in self._applied if a[0] > t_s]
        self._applied = deque(a for a in self._applied if a[0] <= t_s)
        for a in redo + [item]:
            bisect.insort(self._pending, a)
        self._nis = deque(x for x in self._nis if x[0] <= t_s)
        self._nis_resum()
        self._vel_win.truncate(t_s)
        while self._steps and self._steps[-1][0] > t_s:
            self._steps.pop()
        tt, ww, ff = self._history_after(t_s)
        self.events["rewinds"] += 1
        self._replaying = True
        try:
            self._process(t_s, tt, ww, ff)
        finally:
            self._replaying = False
        self._snapshot()

    def _history_after(self, t_s):
        ts, ws, fs = [], [], []
        for t, w, f in self._history:
            if t[-1] <= t_s:
                continue
            m = t > t_s
            ts.append(t[m])
            ws.append(w[m])
            fs.append(f[m])
        if not ts:
            return np.empty(0), np.empty((0, 3)), np.empty((0, 3))
        return np.concatenate(ts), np.concatenate(ws), np.concatenate(fs)

    # ------------------------------------------------------------------ the engine
    def _process(self, prev, t, w, f):
        """Propagate accepted samples t (after ``prev``) and apply the pending measurements
        and constraints whose stamps they reach, each after the sample that reaches it.

        The runs between those events are known before anything is applied (the events'
        times do not depend on the measurements' values), so the filter computes their
        sums ahead, many at once (:meth:`InvariantEKF.propagate_runs`)."""
        c = self.config
        if len(t) == 0:
            return
        # lost samples: each hole bridged by a made-up sample, which ends a run (its
        # variance is added there, before the measurements it reaches)
        b = bridge_gaps(prev, t, w, f, self.nominal_dt, self._vjitter.before)
        t, w, f, dts = b.t, b.w, b.f, b.dts
        n = len(t)
        fills = [float(t[i]) for i in b.fills]
        # the runs: each ends at the first sample reaching an event (or at the last one)
        stamps = [p[0] for p in self._pending]
        nhc = self._next_nhc
        ends, j, k, q = [], 0, 0, 0
        while k < n:
            t_ev = stamps[j] if j < len(stamps) else math.inf
            if nhc is not None:
                t_ev = min(t_ev, nhc)
            while q < len(fills) and fills[q] < float(t[k]):
                q += 1
            if q < len(fills):
                t_ev = min(t_ev, fills[q])
            e = n if t_ev > t[-1] else min(max(int(t.searchsorted(t_ev, "left")) + 1,
                                               k + 1), n)
            ends.append(e)
            t_now = float(t[e - 1])
            while j < len(stamps) and stamps[j] <= t_now:
                j += 1
            if nhc is not None and nhc <= t_now:
                nhc = t_now + c.nhc_period
            k = e
        hole = dict(zip(b.fills, zip(b.var_w, b.var_f))) if b.fills else None
        for r in self.ekf.propagate_runs(dts, w, f, ends):
            e = ends[r]
            t_now = float(t[e - 1])
            if hole is not None and e - 1 in hole:
                self.ekf.add_body_noise(*hole[e - 1])
                if not self._replaying:
                    self.events["holes_bridged"] += 1
            while self._pending and self._pending[0][0] <= t_now:
                item = self._pending.pop(0)
                self._apply(item, t_now)
                self._applied.append(item)
            if self._next_nhc is not None and self._next_nhc <= t_now:
                parked = self._parked_at_nhc(t_now)
                self._weigh(t_now, *self.ekf.update_lateral(
                    c.nhc_axis, c.nhc_noise, c.nis_inflate, slip=c.nhc_slip_deg * DEG,
                    slip_updates=max(1.0, c.nhc_slip_time / c.nhc_period),
                    consider_heading=parked), 1)
                self.events["nhc"] += 1
                if parked:
                    self.events["nhc_parked"] += 1
                self._next_nhc = t_now + c.nhc_period
            if e < n:
                self._snapshot(t_now)
                # (a long block: the stored states no rewind can reach any more go now,
                # not all at its end; _prune does the rest)
                self._drop_snapshots(t_now)

    def _apply(self, item, t_now):
        ts, _, kind, payload = item
        ekf = self.ekf
        if kind == "velocity":
            z, R = payload
            # the reference does not vibrate, the IMU velocity does: compare the reference
            # with the IMU velocity less its jitter at this sample (jitter.py), rotated to
            # ENU by each filter's attitude, and take the jitter's change since the last
            # update out of the transition too (it would couple the attitude error into a
            # velocity error that this comparison cannot see)
            T = self.config.velocity_averaging
            force = rate = hf = None
            young = 0.0
            if T > 0.0:
                # one tone per axis below ~10 Hz (jitter.fit_tones), which the line of
                # VelocityJitter.at takes out only in part: out of the jitter in full, and
                # out of the latency's and lever arm's regressors (filter.velocity_model)
                tones = self._vjitter.tones(t_now)
                if tones is not None and not (tones[0].found or tones[1].found):
                    tones = ()                  # (none found: the samples as they are)
                hf = self._vjitter.at(t_now, T, self.nominal_dt,
                                      tones[0] if tones else None)
                if tones is None:
                    # no tone can be told yet (under TONE_WINDOW s of samples): what the
                    # line may leave of one counts as the reference's noise
                    young = self._vjitter.spread(t_now)
                elif tones:
                    s_last = np.array([t_now - 0.5 * self.nominal_dt])
                    force = ekf.f_last - tones[0].value(s_last) / (1.0 + ekf.sa)
                    rate = ekf.w_last - tones[1].value(s_last) / (1.0 + ekf.sf)
            if hf is not None:
                z = z + ekf.C @ hf[0]                   # (K, 3)
                ekf.exclude_velocity_jitter(hf[0])
            # the measurement is of the instant ts, the state of t_now (>= ts, within a
            # sample): move it by the (low-frequency) acceleration over the difference
            if t_now > ts:
                b = self._best
                f_now = (ekf.f_last[b] if hf is None
                         else (hf[1] - ekf.ba[b]) / (1.0 + ekf.sa[b]))
                acc = ekf.C[b] @ f_now
                acc[2] -= float(normal_gravity(ekf.lat[b], ekf.h[b]))
                z = z + (t_now - ts) * acc
            parked = self._parked(t_now, payload)
            s = self.noise_scale = self._noise_scale(t_now)
            Ru = R if s == 1.0 else s * R
            if young > 0.0:
                Ru = Ru + young * np.eye(3)
            if ekf.K == 1 and self._step_mode[0] is not None and \
                    self._held(t_now, z, R, Ru, force, rate):
                self.events["velocity_held"] += 1
                if not self._replaying:
                    self._evaluate(t_now)
                return
            nis, ll = ekf.update_velocity(z, Ru, self.config.nis_inflate,
                                          consider_heading=parked, force=force, rate=rate)
            self.events["velocity"] += 1
            if parked:
                self.events["velocity_parked"] += 1
            if nis[self._best] > self.config.nis_inflate:
                self.events["velocity_inflated"] += 1
            ok = np.isfinite(payload[0])
            d = int(np.count_nonzero(ok))
            yw, M = _whitened(*ekf.last_innovation(self._best),
                              R if d == 3 else R[np.ix_(ok, ok)], s,
                              self._default_white if R is self._default_R and d == 3
                              else None)
            # y^T (H P H^T + R)^-1 y: the NIS as computed when R was not scaled
            r = (float(nis[self._best]) * d if s == 1.0
                 else float(yw @ np.linalg.solve(M + np.eye(d), yw)))
            self._vel_win.append(t_now, yw, M, d, r)
            if ekf.K == 1 and self.config.step_hold:
                y, S = ekf.last_innovation(0)
                self._step_check(t_now, ok.tobytes(), y, S, ekf.last_correction(0))
            self._weigh(t_now, nis, ll, d, r / d)
        elif kind == "attitude":
            Cm, R = payload
            nis, ll = ekf.update_attitude(Cm, R, self.config.nis_inflate)
            self.events["attitude"] += 1
            self._weigh(t_now, nis, ll, 3)
        self._check_specs(t_now)
        if not self._replaying:
            self._evaluate(t_now)

    def _step_check(self, t, key, y, S, c) -> None:
        """A step in the velocity reference's error (a reflected signal biases a receiver's
        velocity by tenths of a m/s for seconds, its covariance as usual): the filter would
        take it in over a few updates, into the attitude as much as the velocity, and its
        covariance knows nothing of it. The innovations of a filter that models its
        measurements are independent, so the sum of those of the last :data:`STEP_WINDOW` s
        has covariance sum(H P H^T + s R); beyond :data:`STEP_LIMIT` the reference stepped.
        The error estimates those updates made (their sum D, each in the error state's axes
        of its instant, taken as those of now) may then be the step's, not the truth's: each
        block of three states (attitude, velocity, each bias, ...) takes its part of D D^T,
        so that it covers either, and the updates after it are held (:meth:`_held`) until
        the reference agrees with the filter again (``events["velocity_step"]``,
        ``["velocity_held"]``). Without the cross terms: with them (D D^T whole) the updates
        after a hold read the rest of the step through them as more of the same and moved the
        level further (car_city, 0.2 m/s bursts of 10 s, seed 1: 19.5 % of the instants
        beyond 3 sigma against 1.8 %). Not while the bank of hypotheses runs (its heading is
        unknown anyway; the level is learnt within seconds)."""
        self._step_window(t, key, y, S, c)
        Y, SS, D, m = self._step_sums(t, key, False)
        if m < 2 or float(Y @ np.linalg.solve(SS, Y)) <= STEP_LIMIT[len(Y)]:
            return
        P = self.ekf.P.copy()           # (the stored states share the old one)
        for i in range(0, len(D), 3):
            b = slice(i, i + 3)
            P[0][b, b] += np.outer(D[b], D[b])
        self.ekf.P = P
        self._step_mode = (t, t)
        self.events["velocity_step"] += 1

    def _held(self, t, z, R, Ru, force=None, rate=None) -> bool:
        """While the reference is taken as stepped (:meth:`_step_check`): the velocity
        update at t is held (True) unless the sum of the innovations of the last
        :data:`STEP_WINDOW` s of held updates (at least :data:`STEP_RESUME_UPDATES`), against
        the filter as it is now, is within :data:`STEP_RESUME_LIMIT` (the step went away, or
        the filter's own uncertainty grew to cover it: a 1 % quantile, not the test's 1e-6,
        or a 0.2 m/s step passes by chance within a few updates); or the updates have been
        held :data:`STEP_HOLD_MAX` s: the reference is then believed (the step was the
        IMU's: a shock clipped by its range), and the filter forgets its velocity: the
        velocity error's covariance takes the mean innovation's outer product and loses its
        correlations, so the offset goes into the velocity and not, through the correlations
        dead reckoning built, into the attitude (whose covariance, a marginal, stays as it
        is). With the correlations kept, seed 003's UAV with a 50 m/s^2 shock clipped at 4 g
        every ~50 s, seeds 0-2: 0.7 / 4.6 / 11.4 % of the instants beyond 3 sigma (0 / 2.0 /
        2.6 without the hold); forgotten, 0 / 2.3 / 0. The
        held innovations count in the NIS windows (a reference that contradicts the IMU for
        good is still said to); not in the noise scale's."""
        ekf = self.ekf
        z_hat, H = ekf.velocity_model(force, rate)
        zz = z[0] if z.ndim == 2 else z
        ok = np.isfinite(zz)
        y = (zz - z_hat[0])[ok]
        Hk = H[0][ok]
        HPH = Hk @ ekf.P[0] @ Hk.T
        Rk = R[np.ix_(ok, ok)]
        S = HPH + Ru[np.ix_(ok, ok)]
        key = ok.tobytes()
        self._step_window(t, key, y, S, None)
        d = len(y)
        nis = float(y @ np.linalg.solve(S, y)) / d
        self._nis_add(t, nis, d, float(y @ np.linalg.solve(HPH + Rk, y)) / d)
        Y, SS, _, m = self._step_sums(t, key, True)
        since = self._step_mode[0]
        if m >= STEP_RESUME_UPDATES and \
                float(Y @ np.linalg.solve(SS, Y)) <= STEP_RESUME_LIMIT[d]:
            self._step_mode = (None, t)
            return False
        if t - since < STEP_HOLD_MAX:
            return True
        ybar = np.zeros(3)
        ybar[ok] = Y / m
        C = ekf.C[0]
        P = ekf.P.copy()
        Pv = P[0][INU, INU] + C.T @ np.outer(ybar, ybar) @ C
        P[0][INU, :] = 0.0
        P[0][:, INU] = 0.0
        P[0][INU, INU] = Pv
        ekf.P = P
        self._step_mode = (None, t)
        return False

    def _step_window(self, t, key, y, S, c) -> None:
        win = self._steps
        keep = self.t_last - self.config.max_measurement_lag - _HISTORY_MARGIN - STEP_WINDOW
        while win and win[0][0] < keep:
            win.popleft()
        win.append((t, key, y, S, c))

    def _step_sums(self, t, key, held):
        """Sums of the innovations, their covariances and (not held) error estimates of the
        updates (held or applied) within the last :data:`STEP_WINDOW` s since the mode's
        start, with the components ``key`` measured; and how many."""
        lo = max(t - STEP_WINDOW, self._step_mode[1])
        Y = SS = D = None
        m = 0
        for e in reversed(self._steps):
            if e[0] < lo or (e[0] == lo and not held) or e[1] != key \
                    or (e[4] is None) != held:
                break
            Y, SS = (e[2], e[3]) if Y is None else (Y + e[2], SS + e[3])
            if not held:
                D = e[4] if D is None else D + e[4]
            m += 1
        return Y, SS, D, m

    def _check_specs(self, t_now) -> None:
        """After an update of the single filter (the bank collapsed): the bias estimates
        against the configured specs. One BIAS_BEYOND_SPEC of its prior's stds or more from
        zero says the IMU is worse than its specs (a MEMS run as 'navigation', the default
        grade): its attitude and covariance rest on biases the filter cannot reach (in
        motion, car_city's MEMS as navigation or tactical 16-53 % of the instants beyond 3
        sigma, flagged aligned). The attitude is then published as unknown and the flag held
        down (:attr:`specs_consistent`) until a restart."""
        ekf = self.ekf
        if ekf.K > 1:
            return
        sg, sa = self._bias_prior_std
        zg = _abs_max(ekf.bg[0].tolist()) / sg if sg > 0.0 else 0.0
        za = _abs_max(ekf.ba[0].tolist()) / sa if sa > 0.0 else 0.0
        g0, a0 = self.bias_spec_ratio
        self.bias_spec_ratio = (max(g0, zg), max(a0, za))
        if self.specs_consistent and max(zg, za) >= BIAS_BEYOND_SPEC:
            self.specs_consistent = False
            self.events["specs_inconsistent"] += 1
            self._emit("inconsistent", t_now, float(max(zg, za)))

    def _parked(self, t_now, payload) -> bool:
        """Is the heading a consider state of this velocity update? While the vehicle stands
        (:func:`~sins_align.estimators.in_motion.stillness.is_parked`) and gyrocompassing
        cannot improve on the heading the best filter holds (its heading std at or below
        :meth:`_compass_limit`): see :mod:`~sins_align.estimators.in_motion.stillness`."""
        if not reference_still(*payload):             # (the cheapest test first)
            return False
        ekf, b = self.ekf, self._best
        up = ekf.C[b, 2]                        # the up axis in body axes
        heading_var = float(up @ ekf.P[b, IPHI, IPHI] @ up)
        lat = float(ekf.lat[b])
        if self._compass_limit(lat) ** 2 < heading_var:
            return False
        # the samples' part, once per sample (a velocity and a non-holonomic update often
        # share it; it depends on the stamps only, so a rewind finds the same)
        if self._rest_at is None or self._rest_at[0] != t_now:
            t, w, f = self._vjitter.before(t_now, STILL_WINDOW)
            self._rest_at = (t_now, imu_at_rest(t, w, f, self.config.specs,
                                                float(normal_gravity(lat, float(ekf.h[b]))),
                                                self.nominal_dt or 0.01))
        return self._rest_at[1]

    def _compass_limit(self, lat: float) -> float:
        """rad: the heading std gyrocompassing can reach standing (the specs' gyro bias, its
        wander included, over the Earth rate's horizontal component; not the filter's own
        bias std, which standing still only learns together with the heading)."""
        s = self.config.specs
        return gyrocompass_limit(math.hypot(s.gyro_bias, s.gyro_bias_instability), lat)

    def _parked_at_nhc(self, t_now) -> bool:
        """:meth:`_parked` for a non-holonomic update at t_now: standing, the constraint's
        heading regressor (the estimated body velocity) is noise too. The velocity tested
        is the best filter's estimate with its own covariance (what the references applied
        so far say, whatever their rate and the order they came in)."""
        ekf, b = self.ekf, self._best
        C = ekf.C[b]
        return self._parked(t_now, (ekf.v[b], C @ ekf.P[b, INU, INU] @ C.T))

    def _noise_scale(self, t_now) -> float:
        """Covariance matching (Mehra): the factor s >= 1 on the velocity references' R for
        which the velocity innovations of the last ``aligned_nis_window`` s would have had a
        mean NIS per degree of freedom of 1: sum(y^T (H P H^T + s R)^-1 y) = sum(d), with each
        innovation's H P H^T as it was and R as given (the scale in use does not enter: the
        estimate does not feed on itself). 1 until they hold 30 degrees of freedom, at most
        ``inconsistent_nis`` (beyond, the reference contradicts the IMU). The same in a
        rewind: the innovations are those applied before t_now, within the window of t_now."""
        c = self.config
        lo = t_now - c.aligned_nis_window
        win = self._vel_win
        if win.n - win.i0 > 256:
            win.prune(lo - c.max_measurement_lag - _HISTORY_MARGIN - 1.0)
        i = win.start(lo)
        d, r = win.sums(i)
        if d < 30 or r <= d:
            return 1.0
        cs, lam = win.decomposed(i)
        # g(s) = sum(c / (lam + s)) - d: decreasing and convex, g(1) > 0; Newton from the
        # left converges from below
        s_max = c.inconsistent_nis
        s = 1.0
        add = np.add.reduce                     # (ndarray.sum without its wrapper)
        for _ in range(50):
            den = lam + s
            q = cs / den
            g = float(add(q, axis=None)) - d
            if g <= 1e-7 * d:
                break
            s_new = s + g / float(add(q / den, axis=None))
            if s_new >= s_max:
                return float(s_max)
            if s_new - s <= 1e-7 * s:
                s = s_new
                break
            s = s_new
        return float(s)

    def _weigh(self, t, nis, loglik, dof, nis_ref=None):
        """After an update: the hypotheses' weights, pruning, collapse; the NIS record."""
        if self.ekf.K > 1:
            lw = self._logw + loglik
            lw -= lw.max()
            lw -= math.log(np.exp(lw).sum())
            keep = lw >= math.log(HYPOTHESIS_MIN_WEIGHT)
            best = int(np.argmax(lw))
            # hypotheses that converged onto the best one merge into it: within 3 sigma of
            # its own attitude uncertainty on every axis
            # (once the best one has learnt something: its heading std a third of the prior)
            d = attitude_error(self.ekf.C, self.ekf.C[best][None])
            Cb = self.ekf.C[best]                # (covariance_enu of the best one alone)
            sd = np.sqrt(np.diag(Cb @ self.ekf.P[best, IPHI, IPHI] @ Cb.T))
            same = np.all(np.abs(d) <= 3.0 * sd, axis=1) & (sd[2] <= self._prior_head_std / 3.0)
            same[best] = False
            if same.any():
                # moment matching: the best one takes on the merged ones' spread about it
                wm = np.exp(lw[same] - np.logaddexp(lw[best], np.logaddexp.reduce(lw[same])))
                spread = np.einsum("k,ki,kj->ij", wm, d[same], d[same])        # ENU
                Cb = self.ekf.C[best]
                P = self.ekf.P.copy()           # (the stored states share the old one)
                P[best][IPHI, IPHI] += Cb.T @ spread @ Cb
                self.ekf.P = P
                lw[best] = np.logaddexp(lw[best], np.logaddexp.reduce(lw[same]))
                keep &= ~same
                self.events["hypotheses_merged"] += int(same.sum())
            if lw.max() >= math.log(HYPOTHESIS_COLLAPSE):
                keep = lw == lw.max()
            if keep.sum() == 1:
                self.events["heading_acquired"] += 1
            if not keep.all():
                self.ekf.select(keep)
                lw, nis = lw[keep], nis[keep]
                lw -= math.log(np.exp(lw).sum())
                d = d[keep]
                best = int(keep[:best].sum())
            self._logw = lw
            self._best = int(np.argmax(lw))
            # (row by row: the same as attitude_error of the rows kept)
            self._bank_errors = (self.ekf.C, best, d) if self._best == best else None
        nis = float(nis[self._best])
        self._nis_add(t, nis, dof, nis if nis_ref is None else nis_ref)

    def _nis_add(self, t, nis, dof, nis_ref):
        nis, nis_ref = min(nis, 1e6), min(nis_ref, 1e6)
        self._nis.append((t, nis, dof, nis_ref))
        s = self._nis_sum
        s[0] += nis * dof
        s[1] += dof
        s[2] += nis_ref * dof
        w = self.config.aligned_nis_window
        while self._nis and self._nis[0][0] < t - w:
            _, n, d, r = self._nis.popleft()
            s[0] -= n * d
            s[1] -= d
            s[2] -= r * d
        if len(self._nis) == 1 or s[0] < 0.0 or s[2] < 0.0:      # no rounding left behind
            self._nis_resum()

    def _nis_resum(self):
        """The window's sums (nis * dof, dof, nis_ref * dof) computed anew from its entries."""
        self._nis_sum = [sum(n * d for _, n, d, _ in self._nis), sum(x[2] for x in self._nis),
                         sum(r * d for _, _, d, r in self._nis)]

    def _snapshot(self, t=None):
        if self.ekf is None:
            return
        t = self.t_last if t is None else t
        if self._snaps and self._snaps[-1][0] >= t:
            return
        self._snap_now(t)

    def _snap_now(self, t):
        self._snaps.append((t, self.ekf.snapshot(), self._next_nhc, self._logw.copy(),
                            self._best, _replayed_counts(self.events),
                            self._step_mode))

    def _drop_snapshots(self, t_now: float) -> None:
        """The stored states no measurement arriving after ``t_now`` can rewind to (older
        than ``max_measurement_lag`` and a margin) go; the newest of those stays."""
        keep = t_now - self.config.max_measurement_lag - _HISTORY_MARGIN
        snaps = self._snaps
        while len(snaps) > 1 and snaps[1][0] < keep:
            snaps.popleft()

    def _prune(self):
        self._drop_snapshots(self.t_last)
        t_s = self._snaps[0][0]
        while self._history and self._history[0][0][-1] <= t_s:
            self._history.popleft()
        while self._applied and self._applied[0][0] <= t_s:
            self._applied.popleft()

    # ------------------------------------------------------------------ the flag
    def _evaluate(self, stamp):
        c = self.config
        if self.ekf is None:
            return
        nis = self.nis
        if self._nis_sum[1] >= 30 and self.reference_nis > c.inconsistent_nis:
            # the reference contradicts the IMU (a wrong frame, lever arm, latency, noise):
            # nothing published from the filter can be trusted for a while
            if self.reference_consistent:
                self.events["reference_inconsistent"] += 1
                self._emit("inconsistent", stamp, float(self.reference_nis))
            self._inconsistent_until = (stamp if stamp is not None else self.t_last) \
                + c.inconsistent_memory
        t_now = stamp if stamp is not None else self.t_last
        self.reference_consistent = bool(t_now is None or t_now > self._inconsistent_until)
        # (std_enu_deg in floats: NaN where a variance is negative, as numpy's square root)
        std = [math.sqrt(x) / DEG if x >= 0.0 else math.nan
               for x in self.covariance.diagonal().tolist()]
        self.heading_observable = bool(std[2] <= c.observable_heading_std_deg)
        now = bool(self.heading_observable and self.ekf.K == 1 and self.reference_consistent
                   and self.specs_consistent
                   and max(std[0], std[1]) <= c.aligned_level_std_deg
                   and std[2] <= c.aligned_heading_std_deg
                   and (math.isnan(nis) or nis <= c.aligned_nis))
        if now != self._aligned:
            self._aligned = now
            if now and self.time_to_aligned is None:
                # from the stamp it happened at (t_last may be a block's end already)
                self.time_to_aligned = (self.elapsed if stamp is None
                                        else float(stamp) - self.t_first)
            self._emit("aligned", stamp, now)

    # ------------------------------------------------------------------ summary
    def summary(self) -> dict:
        """A JSON-ready snapshot of the result (node diagnostics, replay summary)."""
        ok = self.ekf is not None
        return {
            "status": self.status,
            "stage": "in_motion",
            "aligned": self.aligned,
            "time_to_aligned_s": self.time_to_aligned,
            "elapsed_s": self.elapsed,
            "samples_used": self.samples_used,
            "rejected": dict(self.rejected),
            "events": dict(self.events),
            "heading_observable": self.heading_observable,
            "reference_consistent": self.reference_consistent,
            "specs_consistent": self.specs_consistent,
            "bias_spec_ratio": list(self.bias_spec_ratio),
            "heading_hypotheses": self.hypotheses,
            "orientation_xyzw": self.quaternion.tolist(),
            "rpy_deg": self.rpy_deg.tolist(),
            "heading_deg": self.heading_deg,
            "std_enu_deg": self.std_enu_deg.tolist(),
            "velocity_enu_mps": self.velocity.tolist() if ok else None,
            "bias_gyro_dph": (self.bias_gyro / DPH).tolist() if ok else None,
            "bias_accel_mg": (self.bias_accel / 9.80665e-3).tolist() if ok else None,
            "lever_arm_m": self.lever_arm.tolist(),
            "nhc_lever_arm_m": self.nhc_lever_arm.tolist(),
            "nhc_mount_deg": (self.nhc_mount / DEG).tolist(),
            "velocity_latency_s": self.velocity_latency,
            "mounting_deg": (self.ekf.corrected(self._best)[5] / DEG).tolist() if ok else None,
            "feedback": self.config.feedback,
            "gyro_scale_ppm": (self.ekf.sf[self._best] * 1e6).tolist() if ok else None,
            "accel_scale_ppm": (self.ekf.sa[self._best] * 1e6).tolist() if ok else None,
            "nis": self.nis,
            "reference_nis": self.reference_nis,
            "velocity_noise_scale": self.noise_scale,
        }


def _fl(x):
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _abs_max(xs) -> float:
    """numpy's ``np.abs(x).max()`` of a few floats (NaN if any is NaN)."""
    a = [abs(x) for x in xs]
    return math.nan if any(x != x for x in a) else max(a)


def _whitened(y, S, R, s, white=None):
    """An innovation y (d,) of covariance S = H P H^T + s R, whitened by R as given:
    (L^-1 y, L^-1 H P H^T L^-T) with R = L L^T: y^T (H P H^T + x R)^-1 y is
    yw^T (M + x I)^-1 yw for every x. ``white``: (1 / sqrt(diag R), its outer product) of a
    diagonal R, computed before."""
    if white is not None:
        return white[0] * y, (S - s * R) * white[1]
    r = R.diagonal()
    if not np.any(R - np.diag(r)):              # (the usual diagonal R: L^-1 at once)
        a = 1.0 / np.sqrt(r)
        return a * y, (S - s * R) * np.outer(a, a)
    Li = np.linalg.inv(np.linalg.cholesky(R))
    return Li @ y, Li @ (S - s * R) @ Li.T


class _InnovationWindow:
    """The velocity updates' whitened innovations (:func:`_whitened`) in the order applied,
    in arrays (fewer than 3 degrees of freedom: padded with a zero residual and a unit
    diagonal), with y^T (H P H^T + R)^-1 y of each: those since a time are a slice (no
    copying per update); a rewind cuts the ones after its state off. The decomposition
    M = U diag(lam) U^T, c = (U^T yw)^2, so that y^T (H P H^T + x R)^-1 y = sum(c / (lam + x)),
    is done only when asked for, for all the entries that lack it at once."""

    _NAMES = ("t", "y", "M", "c", "lam", "d", "r")

    def __init__(self, cap: int = 512):
        self.t = np.empty(cap)
        self.y = np.zeros((cap, 3))
        self.M = np.zeros((cap, 3, 3))
        self.c = np.zeros((cap, 3))
        self.lam = np.zeros((cap, 3))
        self.d = np.zeros(cap, dtype=int)
        self.r = np.zeros(cap)
        self.i0 = self.k = self.n = 0           # entries [i0, n), decomposed [i0, k)

    def append(self, t, yw, M, d, r):
        if self.n == len(self.t):
            m = self.n - self.i0                # move the live ones to the front, or grow
            cap = max(len(self.t), 2 * m + 16)
            for name in self._NAMES:
                a = getattr(self, name)
                b = np.zeros((cap,) + a.shape[1:], dtype=a.dtype)
                b[:m] = a[self.i0:self.n]
                setattr(self, name, b)
            self.k -= self.i0
            self.i0, self.n = 0, m
        i = self.n
        self.t[i] = t
        m = len(yw)
        if m == 3:
            self.y[i] = yw
            self.M[i] = M
        else:
            self.y[i] = 0.0
            self.y[i, :m] = yw
            self.M[i] = np.eye(3)
            self.M[i, :m, :m] = M
        self.d[i] = d
        self.r[i] = r
        self.n += 1

    def prune(self, t):
        """Forget the entries before t (none a rewind can reach)."""
        self.i0 += int(np.searchsorted(self.t[self.i0:self.n], t, "left"))
        self.k = max(self.k, self.i0)

    def truncate(self, t):
        """Forget the entries after t (a rewind to t)."""
        self.n = self.i0 + int(np.searchsorted(self.t[self.i0:self.n], t, "right"))
        self.k = min(self.k, self.n)

    def start(self, t) -> int:
        """The index of the first entry at or after t."""
        return self.i0 + int(np.searchsorted(self.t[self.i0:self.n], t, "left"))

    def sums(self, i):
        """From entry i on: their degrees of freedom and sum of y^T (H P H^T + R)^-1 y."""
        add = np.add.reduce                     # (ndarray.sum without its wrapper)
        return int(add(self.d[i:self.n])), float(add(self.r[i:self.n]))

    def decomposed(self, i):
        """(c, lam) (m, 3) of the entries from i on."""
        k, n = max(self.k, i), self.n
        if k < n:
            M = self.M[k:n]
            lam, U = np.linalg.eigh(0.5 * (M + np.swapaxes(M, -1, -2)))
            self.c[k:n] = np.einsum("kij,ki->kj", U, self.y[k:n]) ** 2
            self.lam[k:n] = np.maximum(lam, 0.0)
            self.k = n
        return self.c[i:n], self.lam[i:n]


def _valid_covariance(R: list, ok: list) -> bool:
    """Whether the rows and columns ``ok`` of the 3 x 3 ``R`` (nested lists) are a valid
    covariance: finite, a positive diagonal, symmetric (to numpy.allclose's tolerances) and
    positive definite (a Cholesky factorisation of the lower triangle, as LAPACK's)."""
    idx = [i for i in range(3) if ok[i]]
    for i in idx:
        for j in idx:
            a, b = R[i][j], R[j][i]
            if not math.isfinite(a) or abs(a - b) > 1e-8 + 1e-5 * abs(b):
                return False
        if not R[i][i] > 0.0:
            return False
    L: list = []
    for r, i in enumerate(idx):
        row = []
        for c in range(r):
            j = idx[c]
            row.append((R[i][j] - sum(row[k] * L[c][k] for k in range(c))) / L[c][c])
        d = R[i][i] - sum(x * x for x in row)
        if not d > 0.0:
            return False
        row.append(math.sqrt(d))
        L.append(row)
    return True


def _level_dcm(up_body: np.ndarray, yaw: float) -> np.ndarray:
    """C_b^n whose ENU up is ``up_body`` (a body unit vector) and whose yaw is ``yaw``
    (REP-103, as far as the tilt allows: the roll/pitch/yaw decomposition of the levelled
    attitude gets this yaw)."""
    ux, uy, uz = up_body
    pitch = math.atan2(-ux, math.hypot(uy, uz))
    roll = math.atan2(uy, uz)
    return dcm_from_rpy(np.array([roll, pitch, yaw]))

