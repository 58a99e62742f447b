"""Streaming self-alignment estimator: damped mechanization + error-state Kalman filter.

This is the numpy core shared by the ROS node, the bag replay and the benchmarks. It knows
nothing about ROS. Time comes only from the sample stamps: each accepted sample is
integrated up to its instant on the IMU's steady clock (the stamp itself unless the stamps
jitter: :mod:`sins_align.core.clock`, on the per-sample and the block path alike).
This module holds the :class:`Aligner` (input checks, holes and shocks, the time line, the
aligned flag, events);
the filter it drives is :class:`~sins_align.estimators.quasi_static.filter.AlignmentFilter`.

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

import dataclasses
import math
import statistics
from collections import Counter
from collections.abc import Callable

from dataclasses import dataclass, field

import numpy as np

from sins_align.core.clock import SampleClock
from sins_align.core.earth import gravity_enu
from sins_align.estimators.quasi_static.config import AlignConfig
from sins_align.estimators.base import AlignmentEvent, AttitudeReadout, EventSource
from sins_align.estimators.quasi_static.fast_path import FAST_MIN_BLOCK, uniform_interval
from sins_align.estimators.quasi_static.filter import AlignmentFilter
from sins_align.estimators.quasi_static.monitors import RecentMotion, UnitsMonitor
from sins_align.core.rotation import dcm_from_rpy, quat_values_from_dcm
from sins_align.core.specs import DEG, limit_covariance

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

FAST_MAX_BLOCK = 65536
_FLOAT = np.dtype(float)
#: samples _clean_run checks at once (arrays of 64 kB: below malloc's mmap threshold)
CLEAN_PIECE = 8192
#: samples in a row that must agree on a new time line before it is taken (a time jump)
JUMP_CONFIRM = 3
#: an interval above this multiple of the nominal one means samples are missing
HOLE_RATIO = 1.5
#: s: a specific force out of range for at most this long is a shock: the sample is used, its
#: velocity increment with a variance (event 'force_out_of_range'); longer, they are rejected
FORCE_SHOCK_TIME = 1.0
#: the gyro's white-noise floor at the backtrack (a flat spectrum at 0.1-0.4 of the sample
#: rate, backtrack.GyroNoiseFit) this many times the configured gyro_arw or more says the IMU
#: is worse than its specs (a tactical MEMS as 'navigation': 100x; navigation data 1.0-1.3x
#: on still, car and ship bases; the real ring-laser log's 25-35x is not a flat floor)
NOISE_BEYOND_SPEC = 50.0


STATES = ("waiting", "aligning", "aligned", "disturbed", "fault")
_UNKNOWN_VALUES = [math.pi ** 2, 0.0, 0.0, 0.0, math.pi ** 2, 0.0, 0.0, 0.0, math.pi ** 2]

#: What an Aligner tells its subscribers (:meth:`Aligner.subscribe`).
EVENT_KINDS = (
    "aligned",      # the aligned flag changed; value: the new flag
    "restarted",    # the alignment started over; value: why
    "rejected",     # a sample was rejected; value: the reason (REJECT_REASONS)
)


@dataclass
class SampleStates:
    """What :meth:`Aligner.update_states` returns: the estimator's outputs after each sample
    of the call, as :attr:`Aligner.dcm`, :attr:`Aligner.covariance` and
    :attr:`Aligner.aligned` read right after that sample was fed alone."""

    #: (N,) bool: the sample was not rejected (the first one, which anchors time, counts)
    accepted: np.ndarray
    #: (N, 3, 3) C_b^n after the sample
    dcm: np.ndarray
    #: (N, 3, 3) the published attitude covariance after the sample (rad^2)
    covariance: np.ndarray
    #: (N,) bool: the aligned flag after the sample
    aligned: np.ndarray
    #: (N,) bool: a time line exists after the sample (``t_last`` is not None)
    started: np.ndarray
    #: how many samples were used (what :meth:`Aligner.update` returns)
    used: int = 0
    #: sample index -> :class:`StateView` after it, for the samples asked for
    #: (``update_states(views=...)``)
    views: dict = field(default_factory=dict)

    def record(self, i: int, est: "Aligner", accepted: bool, view: bool = False) -> None:
        """Sample i's outputs read from ``est`` right after it was fed alone."""
        self.accepted[i] = accepted
        self.dcm[i] = est.dcm
        self.covariance[i] = est.covariance
        self.aligned[i] = est.aligned
        self.started[i] = est.t_last is not None
        if view:
            self.views[i] = est.view()

    @classmethod
    def empty(cls, n: int) -> "SampleStates":
        return cls(np.ones(n, dtype=bool), np.empty((n, 3, 3)), np.empty((n, 3, 3)),
                   np.zeros(n, dtype=bool), np.ones(n, dtype=bool))


@dataclass(frozen=True)
class StateView:
    """The read-outs of an :class:`Aligner` that a status report takes (align_node's
    diagnostics), as they were after one sample: same names and values as the Aligner's
    attributes then (the counters are copies)."""

    status: str
    stage: str
    aligned: bool
    heading_observable: bool
    elapsed: float
    std_enu_deg: np.ndarray
    limit_std_deg: np.ndarray
    samples_used: int
    rejected: dict
    last_reject: str | None
    nis: float
    time_to_aligned: float | None
    events: dict
    nominal_dt: float | None
    gyro_noise_ratio: float | None = None
    specs_consistent: bool = True


class Aligner(EventSource, AttitudeReadout):
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
            self.t_last: float | None = None
        last = self.t_last                  # where a dropped flag is reported
        self.samples_used = 0
        self.last_reject: str | None = None
        self.t_first: float | None = None
        self.t_last = None
        self._t_prev_raw: float | None = None
        # the time line: each accepted sample's instant on the IMU's steady clock (the stamp
        # itself unless the stamps jitter: core/clock.py); t_last is the last instant,
        # _stamp_last the last accepted stamp (the stamp checks' reference)
        self._stamp_last: float | None = None
        self._new_clock()
        self._jump: tuple[float, int] | None = None    # pending time jump: (stamp, samples)
        self._force_ok: float | None = None    # stamp of the last force within range
        self._dt_seen: list[float] = []
        self.nominal_dt = 1.0 / c.rate_hz if c.rate_hz else None
        self._units = UnitsMonitor(self) if c.units_check_window > 0 else None
        # gyro_noise_ratio of the filter's GyroNoiseFit, kept with the fit it was taken from
        # (read after every sample, it changes only at a backtrack)
        self._noise = (None, None)
        self._recent = RecentMotion()
        self._fb_source = self._fb_floats = None     # _force_blocks' conversion
        self.units_suspect = False
        self._restart_filter(last)
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

        Computed by :meth:`covariance_values` (running means); equal to
        :meth:`covariance_reference` (everything from scratch) to rounding.
        """
        return np.array(self.covariance_values()).reshape(3, 3)

    def orientation_values(self) -> list[float]:
        """:attr:`quaternion` then :attr:`covariance` (row-major): 13 floats, what the node
        publishes after every sample."""
        return quat_values_from_dcm(self.filter.C[0]) + self.covariance_values()

    def covariance_values(self) -> list[float]:
        """:attr:`covariance`'s nine values, row-major, as floats. The coarse pass's level
        floor reads the last second's mean specific force as a running mean
        (``RecentMotion.second_mean_force``) and the 1 s block means of the buffer once
        per block; the arithmetic is that of :meth:`covariance_reference` on floats."""
        if not self.specs_consistent:
            return list(_UNKNOWN_VALUES)
        p = self.filter.attitude_covariance(0).tolist()
        c = self.config
        if c.backtrack and not self.filter.backtracked:
            level = c.fine_initial_std_deg[0] * DEG
            u0, u1, u2 = self.filter.C[0, 2].tolist()
            fm = self._recent.second_mean_force()
            if fm is not None:
                # the accelerometer's own view of the level error: the angle between the
                # estimated up and the specific force of the last second (large in the
                # first seconds from a start far off, e.g. upside down)
                f0, f1, f2 = fm
                up = (u0 * f0 + u1 * f1 + u2 * f2) / max(math.sqrt(f0 * f0 + f1 * f1 + f2 * f2),
                                                         1e-12)
                level = max(level, math.acos(max(-1.0, min(1.0, up))))
            if self.nominal_dt is not None:
                # ... and at least the largest angle to the 1 s means of the last 10 s: on a
                # swaying base the estimate follows the apparent vertical, and the last second
                # alone can agree with it while the true vertical is degrees away
                blocks = self._force_blocks(max(1, int(round(1.0 / self.nominal_dt))))
                if blocks is not None and len(blocks) < 2:
                    # the first two seconds: nothing yet tells a sway from the vertical
                    level = max(level, c.coarse_initial_std_deg[0] * DEG)
                elif blocks is not None:
                    cosmin = min((u0 * f0 + u1 * f1 + u2 * f2) / fn for f0, f1, f2, fn in blocks)
                    level = max(level, math.acos(max(-1.0, min(1.0, cosmin))))
            (p00, p01, p02), (p10, p11, p12), (p20, p21, p22) = p
            d0, d1, d2 = math.sqrt(p00), math.sqrt(p11), math.sqrt(p22)
            s0 = max(level, d0) / d0
            s1 = max(level, d1) / d1
            s2 = max(c.coarse_initial_std_deg[1] * DEG, d2) / d2
            p = [[p00 * (s0 * s0), p01 * (s0 * s1), p02 * (s0 * s2)],
                 [p10 * (s1 * s0), p11 * (s1 * s1), p12 * (s1 * s2)],
                 [p20 * (s2 * s0), p21 * (s2 * s1), p22 * (s2 * s2)]]
        if not self.heading_observable:
            p[2] = [0.0, 0.0, math.pi ** 2]
            p[0][2] = p[1][2] = 0.0
        (p00, p01, p02), (p10, p11, p12), (p20, p21, p22) = p
        # 0.5 (P + P^T), element by element as numpy computes it
        a01, a02, a12 = 0.5 * (p01 + p10), 0.5 * (p02 + p20), 0.5 * (p12 + p21)
        b01, b02, b12 = 0.5 * (p10 + p01), 0.5 * (p20 + p02), 0.5 * (p21 + p12)
        return [0.5 * (p00 + p00), a01, a02, b01, 0.5 * (p11 + p11), a12, b02, b12,
                0.5 * (p22 + p22)]

    def _force_blocks(self, k: int) -> list | None:
        """The buffer's last ten 1 s block means (:meth:`force_block_means`) as
        (f0, f1, f2, max(|f|, 1e-12)) floats, converted once per new block (the buffer hands
        back the same array until a block completes); None once the buffer is gone."""
        fb = self.filter.force_block_means(k, 10)
        if fb is None:
            return None
        if fb is not self._fb_source:
            self._fb_source = fb
            self._fb_floats = [(f0, f1, f2, max(math.sqrt(f0 * f0 + f1 * f1 + f2 * f2), 1e-12))
                               for f0, f1, f2 in fb[:, 0].tolist()]
        return self._fb_floats

    def covariance_reference(self) -> np.ndarray:
        """:attr:`covariance` computed from scratch with numpy (the mean specific force of
        the last second summed anew, the block means read anew): the reference the running
        computation is tested against."""
        if not self.specs_consistent:
            return np.eye(3) * math.pi ** 2
        P = self.filter.attitude_covariance(0)
        c = self.config
        if c.backtrack and not self.filter.backtracked:
            level = c.fine_initial_std_deg[0] * DEG
            u0, u1, u2 = self.dcm[2].tolist()
            fm = self._recent.mean_force(1.0)
            if fm is not None:
                # the accelerometer's own view of the level error: the angle between the
                # estimated up and the specific force of the last second (large in the
                # first seconds from a start far off, e.g. upside down)
                f0, f1, f2 = fm.tolist()
                up = (u0 * f0 + u1 * f1 + u2 * f2) / max(math.sqrt(f0 * f0 + f1 * f1 + f2 * f2),
                                                         1e-12)
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
                    cosmin = min((u0 * f0 + u1 * f1 + u2 * f2)
                                 / max(math.sqrt(f0 * f0 + f1 * f1 + f2 * f2), 1e-12)
                                 for f0, f1, f2 in fb[:, 0].tolist())
                    level = max(level, math.acos(max(-1.0, min(1.0, cosmin))))
            floor = (level, level, c.coarse_initial_std_deg[1] * DEG)
            p = P.tolist()
            scale = []
            for i in range(3):
                sd = math.sqrt(p[i][i])
                scale.append(max(floor[i], sd) / sd)
            P = np.array([[p[i][j] * (scale[i] * scale[j]) for j in range(3)] for i in range(3)])
        if not self.heading_observable:
            P[2, :] = 0.0
            P[:, 2] = 0.0
            P[2, 2] = math.pi ** 2
        return 0.5 * (P + P.T)

    @property
    def stamp_clock(self) -> SampleClock:
        """The steady clock the accepted samples' instants are taken from (read only:
        ``jittering`` while it replaces the stamps, ``rms`` their scatter about it, s)."""
        return self._clock

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
    def gyro_noise_ratio(self) -> float | None:
        """The gyro's white-noise floor the backtrack measured (the lower of its two
        octaves' levels) over the configured ``gyro_arw`` (both as densities' roots); None
        before the backtrack, where the spectrum shows no flat floor (motion, tones, a
        rising quantization noise), where the floor is within 4x (in density) of what the
        angle increments' own quantum gives (a navigation gyro's 4-arcsec counts read 80x
        the preset's noise), or gyro_arw is 0."""
        fit = self.filter.gyro_noise
        if fit is not self._noise[0]:
            arw = self.config.specs.gyro_arw
            ratio = None
            if fit is not None and fit.flat and arw > 0.0:
                floor = min(fit.q_top, fit.q_next)
                if floor > 4.0 * fit.q_quant:   # else the increments' quantization explains it
                    ratio = math.sqrt(floor) / arw
            self._noise = (fit, ratio)
        return self._noise[1]

    @property
    def specs_consistent(self) -> bool:
        """False once the gyro's noise floor is NOISE_BEYOND_SPEC times the configured one or
        more (:attr:`gyro_noise_ratio`): the IMU is worse than its specs, so their biases,
        which no data on a still base can check, cannot be trusted either; the attitude is
        then published as unknown (pi^2 per axis, never aligned, status 'fault'). A
        restart with the same specs runs the coarse pass again (its own wide floors) and
        trips at the next backtrack; the right ``grade`` or specs end it."""
        r = self.gyro_noise_ratio
        return r is None or r < NOISE_BEYOND_SPEC

    @property
    def aligned(self) -> bool:
        """Aligned flag: :meth:`aligned_now` as of the last update (the published std only
        shrinks at an update; it is re-checked after every update, hole and restart)."""
        return self._aligned

    @property
    def status(self) -> str:
        """One of :data:`STATES`."""
        if self.units_suspect or not self.specs_consistent:
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

    def view(self, partial: bool = False) -> StateView:
        """The read-outs of a status report now (:class:`StateView`); ``partial``: without
        the two that change at every sample (``elapsed``, ``std_enu_deg``: None)."""
        return StateView(
            status=self.status, stage=self.stage, aligned=bool(self.aligned),
            heading_observable=self.heading_observable,
            elapsed=None if partial else self.elapsed,
            std_enu_deg=None if partial else self.std_enu_deg,
            limit_std_deg=self.limit_std_deg, samples_used=self.samples_used,
            rejected=dict(self.rejected), last_reject=self.last_reject, nis=self.nis,
            time_to_aligned=self.time_to_aligned, events=dict(self.events),
            nominal_dt=self.nominal_dt, gyro_noise_ratio=self.gyro_noise_ratio,
            specs_consistent=self.specs_consistent)

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
        if (stamp.__class__ is float and gyro.__class__ is np.ndarray
                and accel.__class__ is np.ndarray and gyro.shape == accel.shape == (3,)
                and gyro.dtype is accel.dtype is _FLOAT):
            return self._sample(stamp, gyro, accel)        # one sample as the node has it
        if np.ndim(stamp) == 0 and np.shape(gyro) == (3,) and np.shape(accel) == (3,):
            return self._sample(float(stamp), np.asarray(gyro, dtype=float),
                                np.asarray(accel, dtype=float))
        t, w, f = _sample_arrays(stamp, gyro, accel)
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

    def update_states(self, stamp, gyro, accel, want=None, views=None) -> SampleStates:
        """:meth:`update` on a block, returning the outputs after every sample
        (:class:`SampleStates`): the attitude, the published covariance and the aligned
        flag that reading :attr:`dcm`, :attr:`covariance` and :attr:`aligned` after feeding
        the samples one at a time gives (the same state, to rounding), at the block path's
        speed: between two updates the state coasts in closed form
        (:meth:`AlignmentFilter.coast_states`) and the coarse pass's floors are evaluated
        for all samples at once. Runs that the fast path does not take, or whose intervals
        are not uniform, go one sample at a time. ``want``: (N,) bool, the samples whose
        outputs are needed (default all; the others' dcm and covariance are left unset).
        ``views``: (N,) bool, the samples after which :meth:`view` is wanted too (in
        ``out.views``; between two updates only the time, the samples used and the
        covariance change, so a fast block's views are those of its updates with these
        three taken at the sample)."""
        t, w, f = _sample_arrays(stamp, gyro, accel)
        out = SampleStates.empty(len(t))
        want = np.ones(len(t), dtype=bool) if want is None else np.asarray(want, dtype=bool)
        if views is not None:
            views = np.asarray(views, dtype=bool)
            want = want | views
            if not views.any():
                views = None
        k = 0
        while k < len(t):
            j = self._clean_run(t, w, f, k)
            if j - k >= FAST_MIN_BLOCK and uniform_interval(np.diff(
                    self._instants_ahead(t, k, j), prepend=self.t_last)) is not None:
                used = self._accept_block(t[k:j], w[k:j], f[k:j], states=out, at=k,
                                          want=want, views=views)
                out.used += used
                k += used
                if k == j:
                    continue
            else:
                j = k + 1
            for i in range(k, j):           # one by one (j - k = 1 after a cut block)
                r = sum(self.rejected.values())
                out.used += self._sample(float(t[i]), w[i], f[i])
                out.record(i, self, sum(self.rejected.values()) == r,
                           views is not None and views[i])
            k = j
        return out

    def _clean_run(self, t, w, f, k) -> int:
        """End index of the run of samples from k that the per-sample checks would all accept
        as ordinary samples (intervals within 40 % of nominal, no gap, no rejection): those
        can take the filter's fast path with the same results (a units-check window that
        would flag the rates is cut off later, in _accept_block)."""
        c = self.config
        if (c.model != "constant" or self.t_last is None or self.nominal_dt is None
                or self.units_suspect or self._t_prev_raw != self._stamp_last
                or len(t) - k < FAST_MIN_BLOCK):
            return k
        nom, g = self.nominal_dt, self.g
        end, prev = min(len(t), k + FAST_MAX_BLOCK), self._stamp_last
        last = self.t_last
        # piece by piece (small temporaries: no fresh memory to fault in), up to the first
        # sample a check would take out
        for a in range(k, end, CLEAN_PIECE):
            b = min(end, a + CLEAN_PIECE)
            tt = t[a:b]
            dts = np.diff(tt, prepend=prev)
            # the norms as np.linalg.norm sums them, by columns (a third of its time); a NaN
            # or an infinity in a sample makes its norm fail the range checks below
            fn, wn = (np.sqrt(x[:, 0] * x[:, 0] + x[:, 1] * x[:, 1] + x[:, 2] * x[:, 2])
                      for x in (f[a:b], w[a:b]))
            ok = (np.isfinite(tt)
                  & (dts >= c.min_dt_ratio * nom) & (dts <= c.max_gap)
                  & (fn >= 0.25 * g) & (np.abs(fn - g) <= c.specific_force_tolerance * g)
                  & (wn <= c.max_angular_rate))
            if not self._clock.jittering:
                # (stamps on the IMU's clock are their instants: no hole, as below)
                ok &= (dts <= c.gap_ratio * nom) & (np.abs(dts - nom) <= 0.4 * nom)
            cut = b if ok.all() else a + int(np.argmin(ok))
            # every sample up to ``cut`` will be accepted, here or one by one: their instants
            # (kept for the samples that take the per-sample path), then no hole among them
            x = self._instants_ahead(t, k, cut)[a - k:]
            dx = np.diff(x, prepend=last)
            ok = (dx <= c.gap_ratio * nom) & (np.abs(dx - nom) <= 0.4 * nom)
            if not ok.all():
                end = a + int(np.argmin(ok))
                break
            if cut < b:
                end = cut
                break
            prev, last = tt[-1], x[-1]
        if end - k >= FAST_MIN_BLOCK and self._clock.jittering:
            # the fast path takes intervals within 40 % of their mean
            dx = np.diff(self._ahead_x[self._ahead_i:self._ahead_i + end - k],
                         prepend=self.t_last)
            if not np.all(np.abs(dx - dx.mean()) <= 0.4 * dx.mean()):
                return k
        return end

    def _new_clock(self) -> None:
        """A new steady clock (a new time line), and no instants computed ahead."""
        self._clock = SampleClock()
        self._ahead_t = self._ahead_x = np.empty(0)
        self._ahead_i = 0

    def _instants_ahead(self, t, a: int, b: int) -> np.ndarray:
        """The instants of the stamps ``t[a:b]`` (``a``: the next sample to be fed, whose
        instant is the first computed ahead, if any), samples that will all be accepted in order
        (by a block or one by one: :meth:`_instant` takes them from here), those not
        computed yet from the clock."""
        i = self._ahead_i
        p = len(self._ahead_x) - i
        if b - a > p:
            new = self._clock.times(t[a + p:b])
            if p:
                self._ahead_t = np.concatenate((self._ahead_t[i:], t[a + p:b]))
                self._ahead_x = np.concatenate((self._ahead_x[i:], new))
            else:
                self._ahead_t, self._ahead_x = t[a:b], new
            self._ahead_i = i = 0
        return self._ahead_x[i:i + b - a]

    def _instant(self, t: float) -> float:
        """The instant of the accepted stamp ``t`` (the next one computed ahead, or the
        clock's)."""
        i = self._ahead_i
        if i < len(self._ahead_x):
            self._ahead_i = i + 1
            return float(self._ahead_x[i])
        return self._clock.time(t)

    def _take_instants(self, t) -> np.ndarray:
        """The instants computed ahead of the accepted stamps ``t`` (a block's)."""
        i = self._ahead_i
        self._ahead_i = i + len(t)
        return self._ahead_x[i:i + len(t)]

    def _accept_block(self, t, w, f, states: SampleStates | None = None, at: int = 0,
                      want=None, views=None) -> int:
        """Clean samples through the fast path: all of them, or those before the first
        units-check window closing that would flag the rates. Returns how many.
        ``states``: filled from ``at`` with the outputs after each sample (uniform
        intervals only, :meth:`update_states`)."""
        if self._units is not None:
            # (the units check over the stamps' intervals, as one by one)
            m = self._units.add_block(np.diff(t, prepend=self._stamp_last), w, f)
            if m < len(t):
                if m == 0:
                    return 0
                t, w, f = t[:m], w[:m], f[:m]
        self._stamp_last = self._t_prev_raw = self._force_ok = float(t[-1])
        t = self._take_instants(t)          # from here on, the samples' instants
        dts = np.diff(t, prepend=self.t_last)
        self.t_last = float(t[-1])
        used0 = self.samples_used
        self.samples_used += len(t)
        vsel = (np.flatnonzero(views[at:at + len(t)]) if states is not None
                and views is not None else np.empty(0, dtype=np.int64))
        vsnaps: dict = {}
        self._recent.extend(dts, w, f)

        fl = self.filter
        snaps: dict = {}
        if states is not None:
            snaps[-1] = self._snapshot()
            if len(vsel):
                vsnaps[-1] = self.view(partial=True)
            hist = fl.buffered_forces()
            coarse_model = None
            if not fl.backtracked:
                dt = uniform_interval(dts)
                period = fl.fine_period if fl.fine else self.config.coarse_update_period
                coarse_model = fl.coast_model(dt, min(len(t), int(period / dt) + 2))

        def check(i):                     # after every live update, as after every sample
            self.t_last = float(t[i])
            self._refresh_aligned()
            if states is not None:
                snaps[i] = self._snapshot()
                if len(vsel):
                    vsnaps[i] = self.view(partial=True)

        fl.on_update = check
        try:
            fl.run_fast(dts, w, f)
        finally:
            fl.on_update = None
        self.t_last = float(t[-1])
        self._refresh_aligned()
        if states is not None:
            self._fill_states(states, at, dts, w, f, snaps, coarse_model, hist,
                              np.flatnonzero(want[at:at + len(t)]))
            if len(vsel):
                self._fill_views(states, at, t, vsel, vsnaps, used0)
        return len(t)

    def _fill_views(self, out: SampleStates, at: int, t, sel, vsnaps: dict, used0: int):
        """:meth:`view` after the samples ``sel`` of a fast block: that of the last update
        before (``vsnaps``, -1 before the block) with the sample's time, count and
        covariance; the block's last sample reads the Aligner itself (its flag is
        refreshed there, as :meth:`_fill_states` takes it)."""
        idx = np.array(sorted(vsnaps))
        g = idx[np.searchsorted(idx, sel, side="right") - 1]
        std = np.sqrt(np.einsum("nii->ni", out.covariance[at + sel])) / DEG
        t0 = self.t_first
        for k, (i, gi) in enumerate(zip(sel.tolist(), g.tolist())):
            if i == len(t) - 1:
                out.views[at + i] = self.view()
                continue
            v = vsnaps[gi]
            out.views[at + i] = dataclasses.replace(
                v, elapsed=0.0 if t0 is None else float(t[i]) - t0, std_enu_deg=std[k],
                samples_used=used0 + i + 1)

    def _snapshot(self) -> tuple:
        fl = self.filter
        return (fl.C[0].copy(), fl.P[0], fl.S[0], self._aligned, fl.backtracked)

    def _fill_states(self, out: SampleStates, at: int, dts, w, f, snaps: dict, coarse_model,
                     hist, sel: np.ndarray) -> None:
        """The outputs after each sample of a fast block (see :meth:`update_states`) from the
        states after its updates (``snaps``: sample index -> (C, P, S, aligned flag,
        backtracked), -1 before the block): coasted in between, then the published
        covariance's floors (before the backtrack) and the heading rule of
        :attr:`covariance`, for the samples ``sel`` of the block."""
        fl, c = self.filter, self.config
        L = len(dts)
        dt = uniform_interval(dts)
        idx = sorted(snaps)
        C, Pa = np.empty((len(sel), 3, 3)), np.empty((len(sel), 3, 3))
        # stretches of one model: before and after the backtrack (it changes the noise)
        groups: list[list[int]] = []
        for i in idx:
            if groups and snaps[groups[-1][0]][4] == snaps[i][4]:
                groups[-1].append(i)
            else:
                groups.append([i])
        for gi, grp in enumerate(groups):
            lo = max(grp[0], 0)
            hi = groups[gi + 1][0] if gi + 1 < len(groups) else L
            if snaps[grp[0]][4]:                 # backtracked: the model in force now
                steps = max(np.diff(grp + [hi]).max() if len(grp) else 0, 1)
                model = fl.coast_model(dt, int(steps))
            else:
                model = coarse_model
            st = [snaps[i] for i in grp]
            a, b = np.searchsorted(sel, [lo, hi])
            if b > a:
                C[a:b], Pa[a:b] = fl.coast_states(
                    model, dts[lo:hi], w[lo:hi], np.array(grp) - lo,
                    np.array([x[0] for x in st]), np.array([x[1] for x in st]),
                    np.array([x[2] for x in st]), sel[a:b] - lo)
        g = np.searchsorted(np.array(idx), np.arange(L), side="right") - 1
        flags = np.array([snaps[i][3] for i in idx])[g]
        flags[-1] = self._aligned
        if c.backtrack:
            coarse = np.array([not snaps[i][4] for i in idx])[g][sel]
            n = int(np.argmin(coarse)) if not coarse.all() else len(sel)  # the coarse ones
            if n:
                Pa[:n] = self._coarse_floors(C[:n], Pa[:n], sel[:n], f, hist, L)
        if not self.heading_observable:
            Pa[:, 2, :] = 0.0
            Pa[:, :, 2] = 0.0
            Pa[:, 2, 2] = math.pi ** 2
        if not self.specs_consistent:
            # known at the backtrack, for the filter's life: every state after it
            after = np.array([snaps[i][4] for i in idx])[g][sel]
            Pa[after] = np.eye(3) * math.pi ** 2
        sl = slice(at, at + L)
        out.dcm[at + sel] = C
        out.covariance[at + sel] = 0.5 * (Pa + Pa.transpose(0, 2, 1))
        out.aligned[sl] = flags
        out.accepted[sl] = True
        out.started[sl] = True

    def _coarse_floors(self, C, Pa, pos, f, hist, L: int):
        """:attr:`covariance`'s floors before the backtrack, for n samples at once: the
        attitudes C (n, 3, 3) and covariances Pa (n, 3, 3) after the samples ``pos`` (n,
        increasing) of a fast block of L (forces f), whose buffered forces before it were
        ``hist``."""
        c = self.config
        n = len(C)
        up = C[:, 2, :]

        def angle(cos):
            return np.arccos(np.clip(cos, -1.0, 1.0))

        level = np.full(n, c.fine_initial_std_deg[0] * DEG)
        fm = self._recent.window_mean_forces(1.0, L)[pos]
        level = np.maximum(level, angle(np.einsum("ij,ij->i", up, fm) / np.maximum(
            np.linalg.norm(fm, axis=1), 1e-12)))
        if self.nominal_dt is not None and hist is not None:
            k = max(1, int(round(1.0 / self.nominal_dt)))
            n0 = len(hist)
            cnt = (n0 + pos + 1) // k                          # complete blocks after each
            b0, b1 = max(0, int(cnt[0]) - 10), int(cnt[-1])
            if b1 > b0:
                allf = np.concatenate([hist[b0 * k:], f[:max(0, b1 * k - n0)]])
                # (hist may be shorter than b0 k: then the block's own forces start later)
                allf = allf if b0 * k <= n0 else f[b0 * k - n0:b1 * k - n0]
                means = allf[:(b1 - b0) * k].reshape(b1 - b0, k, 3).mean(axis=1)
                cos = (up @ means.T) / np.maximum(np.linalg.norm(means, axis=1), 1e-12)
                blk = np.arange(b0, b1)
                inside = (blk[None, :] >= cnt[:, None] - 10) & (blk[None, :] < cnt[:, None])
                cosmin = np.where(inside, cos, np.inf).min(axis=1)
                level = np.where(cnt >= 2, np.maximum(level, angle(cosmin)), level)
            level = np.where(cnt < 2, np.maximum(level, c.coarse_initial_std_deg[0] * DEG),
                             level)
        floor = np.stack([level, level, np.full(n, c.coarse_initial_std_deg[1] * DEG)], 1)
        sd = np.sqrt(np.einsum("nii->ni", Pa))
        scale = np.maximum(floor, sd) / sd
        return Pa * (scale[:, :, None] * scale[:, None, :])

    def _static_reason(self, f0: float, f1: float, f2: float) -> str | None:
        """The reason to reject a sample on its own values (no time line needed), or None:
        the specific force's components as floats."""
        c = self.config
        fn = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
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
            self.t_last = self._t_prev_raw = self._stamp_last = t
            self._new_clock()               # a new time line
            self._clock.time(t)
            self.events["time_jump"] += 1
        return self._reject("time_jump", t)

    def _sample(self, t: float, w: np.ndarray, f: np.ndarray) -> int:
        c = self.config
        w0, w1, w2 = w.tolist()
        f0, f1, f2 = f.tolist()
        isfinite = math.isfinite
        if not (isfinite(t) and isfinite(w0) and isfinite(w1) and isfinite(w2)
                and isfinite(f0) and isfinite(f1) and isfinite(f2)):
            return self._reject("nonfinite", t)
        w_norm = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        if self.t_last is None:
            # the first accepted sample anchors time; it has no interval to integrate over
            why = self._static_reason(f0, f1, f2)
            if why is None and w_norm > c.max_angular_rate:
                why = "rate_too_high"
            if why is not None:
                return self._reject(why, t)
            self.t_first = self.t_last = self._instant(t)
            self._stamp_last = self._t_prev_raw = self._force_ok = t
            self._recent.push(0.0, w, f)
            self.events["first_sample"] += 1
            return 0
        dt = t - self._stamp_last
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
        if nom is not None and dt < c.min_dt_ratio * nom and not self._clock.jittering:
            # (stamps that jitter come that close: the clock gives the sample its instant.
            # A block stops before such a stamp, so the clock is where this sample finds it)
            return self._reject("dt_too_small", t)
        why = self._static_reason(f0, f1, f2)
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
                force_var = float(d @ d)    # (times the interval squared, below)
                why = None
        elif why is None:
            self._force_ok = t
        if why is not None:
            return self._reject(why, t)
        dR = None
        if self._units is not None:
            dR = self._units.add(raw_dt, w, f)
            verdict = self._units.take_verdict()
            if verdict is not None:
                self._units_verdict(verdict, t)
            if self.units_suspect:
                self._stamp_last, self.t_last = t, self._instant(t)
                return self._reject("rates_look_like_deg_per_s", t)
        if w_norm > c.max_angular_rate:
            return self._reject("rate_too_high", t)
        # the sample's instant on the IMU's clock: its interval from the last one is
        # integrated (the stamps' interval unless they jitter)
        x = self._instant(t)
        dt = x - self.t_last
        force_var = force_var * dt * dt
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
                # over it or the means bridge (the recent mean, or the mean of the samples on
                # either side) standing in for the missing samples, whichever errs less on the
                # recent motion (held for a smooth sway, a mean when noise dominates: holding
                # one noisy sample multiplies its noise by the hole's length). The step then
                # integrates the interval's mean of the two.
                means, held, (wm, fm) = rec.bridge_errors(missing, nom, w, f)
                err_m, err_h = means, held
                if x != t:
                    # (a jittering stamp: the clock bridges a lost sample at a stamp after
                    # the one it was lost before, once the stamps after it show it, and the
                    # samples between took the lost ones' places, early: the bridge's error
                    # over as many intervals more, one at least)
                    more = max(1, self._clock.lag(x)) * nom
                    err_m, err_h, _ = rec.bridge_errors(missing + more, nom, w, f)
                hole = list(err_h)
                if means[0] < held[0]:
                    w, hole[0], dR = (wm * missing + w * nom) / dt, err_m[0], None
                if means[1] < held[1]:
                    f, hole[1] = (fm * missing + f * nom) / dt, err_m[1]
                hole = tuple(hole)
            self.events["missing_samples"] += max(1, int(round(missing / nom)))
        if force_var > 0.0:
            hole = (hole[0], hole[1] + force_var)
            self.events["force_out_of_range"] += 1
        self.t_last = x
        self._stamp_last = t
        self.samples_used += 1
        self._recent.push(dt, w_in, f_in)
        fl = self.filter
        before = (fl.updates, fl.stage, id(fl))
        if gap == 0.0 and hole == (0.0, 0.0) and fl.n == 1:
            fl.step_one(dt, w, f, dR if dt == raw_dt else None)     # the ordinary sample
        else:
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
        if self.units_suspect or not self.specs_consistent:
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
        vrw = self.filter.accel_vrw_used
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
            # the accelerometer noise density the fine pass uses: the configured accel_vrw,
            # or what the data showed when significantly more (then accel_noise_above_spec)
            "accel_noise_density": None if vrw is None else float(vrw[0]),
            "accel_noise_above_spec": (None if vrw is None
                                       else bool(vrw[0] > self.config.specs.accel_vrw)),
            "nis": self.nis,
            # the gyro's white-noise floor over the configured gyro_arw (None: no flat
            # floor seen, or before the backtrack); specs_consistent False from 50x on
            "gyro_noise_ratio": self.gyro_noise_ratio,
            "specs_consistent": self.specs_consistent,
        }


def _sample_arrays(stamp, gyro, accel):
    """Stamps (N,), rates and forces (N, 3) as float arrays; their lengths checked."""
    t = np.atleast_1d(np.asarray(stamp, dtype=float))
    w = np.asarray(gyro, dtype=float).reshape(-1, 3)
    f = np.asarray(accel, dtype=float).reshape(-1, 3)
    if not (len(t) == len(w) == len(f)):
        raise ValueError(f"stamp, gyro and accel lengths differ: {len(t)}, {len(w)}, {len(f)}")
    return t, w, f
