"""Configuration of the in-motion aligner (:class:`MotionConfig`)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sins_align.core.specs import SensorSpecs, grade_specs

#: vehicle kinds: 'ground' adds the non-holonomic constraint (no lateral body velocity)
VEHICLES = ("ground", "air", "marine")
#: feedback of the estimated errors into the state
FEEDBACKS = ("full", "lqr", "fraction")


@dataclass(frozen=True)
class MotionConfig:
    """Everything the in-motion aligner needs besides the data.

    Attributes
    ----------
    latitude_deg, longitude_deg : deg; height_m : m — initial position (a NavSatFix given to
        :meth:`MotionAligner.add_position` replaces it). ``latitude_deg`` NaN: none, the
        first position given sets it (and longitude and height): IMU samples before it are
        refused ('no_position').
    specs : SensorSpecs or a grade name ('navigation', 'tactical', 'consumer'): the bias
        priors and noise densities of the filter.
    gyro_scale_std : 1-sigma gyro scale-factor error per axis (fraction, e.g. 0.003 for a
        MEMS gyro of 0.3 %); > 0 estimates the three scale factors (3 more states): a
        vehicle that turns or rolls hard otherwise accumulates their attitude error unseen.
    accel_scale_std : the same for the accelerometers (0.3 % of g is 3 mg on the vertical
        axis, which tilts into the level axes when the vehicle banks).
    lever_arm : (3,) m, IMU frame — from the IMU to the antenna of the velocity reference.
    lever_arm_std : m — its 1-sigma uncertainty per axis; > 0 estimates it (15 states).
    velocity_noise : m/s — 1-sigma of a velocity measurement that comes without covariance.
    velocity_latency : s — how much later than the instant it measured the velocity
        reference is stamped (a driver that stamps at reception: tens to a couple of hundred
        ms); the filter compares it with its velocity that long before its stamp.
    velocity_latency_std : s — its 1-sigma; > 0 estimates it (1 more state, seen while the
        vehicle accelerates: a 2 m/s^2 acceleration and 0.1 s of latency make 0.2 m/s). 0
        takes ``velocity_latency`` as exact (stamped at 50 ms after the fact and taken as
        exact, a city drive's attitude was beyond 3 sigma a third of the time).
    velocity_averaging : s — the reference is compared with the IMU velocity less its jitter
        over this interval before the measurement's sample (the velocity less its
        least-squares straight line over it:
        :class:`~sins_align.estimators.in_motion.jitter.VelocityJitter`), which takes the
        accelerometer's vibration out of the updates (and the jitter's change out of the
        filter's transition); the interval between the reference's measurements (GNSS at
        10 Hz: 0.1); 0: compare with the IMU velocity at the sample as it is (the setting
        for a master INS, whose velocity sees the motion that the jitter would take out).
        > 0 also takes one lasting tone per axis within 2.5-10 Hz, which the line leaves,
        out of the jitter and out of the latency's and lever arm's regressors
        (:func:`~sins_align.estimators.in_motion.jitter.fit_tones`).
    max_measurement_lag : s — a measurement stamped up to this long before the newest IMU
        sample is applied at its stamp (the filter rewinds); older ones are refused.
    vehicle : 'ground' | 'air' | 'marine'; 'ground' applies the non-holonomic constraint.
    nhc_noise : m/s — 1-sigma of the lateral body velocity of a ground vehicle (sideslip).
    nhc_axis : 0, 1, 2 — the IMU axis that points to the vehicle's side (REP-103 IMU mounted
        x forward, y left: 1).
    nhc_period : s — interval of the non-holonomic updates.
    nhc_lever_arm : (3,) m, IMU frame — from the IMU to the point of the vehicle whose
        velocity has no sideways component (a car's rear-axle centre). An IMU ahead of the
        rear axle moves sideways at yaw rate x distance in every turn (0.24 m/s at 9 deg/s
        and 1.5 m); the constraint is applied at that point.
    nhc_slip_deg : deg of tyre sideslip per m/s^2 of lateral acceleration, a bound (typical
        cars 0.2-0.7): in turns the constraint's noise grows to cover a sideways velocity of
        ``slip x a_lat x speed`` lasting ``nhc_slip_time`` s (0: the constraint holds exactly
        in turns too, within nhc_noise).
    nhc_slip_time : s — how long a sideslip lasts (about a turn).
    nhc_lever_arm_std : m — its 1-sigma uncertainty per axis; > 0 estimates it (3 more
        states, observable in turns; in straight driving it does not matter). The default
        2 m covers an IMU anywhere in a car with the default (0, 0, 0); 0 takes
        ``nhc_lever_arm`` as exact.
    nhc_mount_std_deg : deg — 1-sigma of the rotation between the IMU's axes and the
        vehicle's (an IMU bolted a little askew: a 2 deg yaw puts 0.35 m/s of a 10 m/s
        forward speed on the IMU's side axis, which the constraint would otherwise read as
        a heading error of 2 deg with a std of a few hundredths); > 0 estimates it (3 more
        states: the heading from the constraint alone is then no better than this, and the
        turns and accelerations, which the velocity reference sees, tell the two apart);
        0 takes the IMU's ``nhc_axis`` as the vehicle's side exactly.
    initial_rpy_deg : REP-103 roll, pitch, yaw guess, or None. Roll and pitch are always
        taken from the accelerometers at the start (any start converges, upside down too);
        the yaw is the heading guess.
    initial_heading_std_deg : 1-sigma of that guess. Up to 30 deg it is a guess and one
        filter starts from it; above (or without a guess) the heading is unknown, and a bank
        of ``heading_hypotheses`` filters starts, their yaws evenly spread around the circle
        (a Gaussian sum, as PX4's EKF-GSF yaw estimator does), each weighed by how well it
        predicts the measurements; the bank collapses to one filter once one holds 99.9 %.
    heading_hypotheses : size of that bank (>= 2).
    init_time : s — accelerometer averaging for the initial level.
    attitude_matching : use the master attitudes given to :meth:`MotionAligner.add_attitude`.
    attitude_noise_deg : 1-sigma per axis of a master attitude that comes without covariance.
    mounting_std_deg : 1-sigma per axis of the mounting misalignment between the master's
        axes and ours, estimated with ``attitude_matching`` (0: taken as exactly zero).
    feedback : 'full' (the estimated errors are removed from the state after every update:
        the default, and the strapdown practice) or 'lqr' (seed 002: the error estimate is
        carried on and removed gradually through LQR-designed gains,
        :mod:`~sins_align.estimators.in_motion.feedback`) or 'fraction' (carried on, and a
        constant ``feedback_fraction`` of it removed after every update).
    feedback_fraction : the fraction of 'fraction' feedback, within (0, 1].
    lqr_time_constant : s — the time constant the LQR weights aim at.
    nis_inflate : a measurement whose normalised innovation per degree of freedom exceeds this
        has its noise inflated until it equals it (large early transients, skids, outliers).
    step_hold : look for steps in the velocity reference's error (a GNSS velocity biased by a
        reflection for seconds) in the sum of a second of innovations, and hold the velocity
        updates after one until the reference agrees with the filter again
        (:meth:`MotionAligner._step_check`); False applies every update (as before session
        17; for tests that show what another mechanism does on its own).
    max_gap : s — IMU stamp gaps above this restart the alignment; shorter holes (above 1.5
        nominal intervals) are bridged and grow the covariance (``gaps.py``). Stamps that
        jitter are replaced by the instants of a steady clock fitted to them (``core/clock.py``).
    max_angular_rate : rad/s; specific_force_max : m/s^2 — samples above are rejected.
    observable_heading_std_deg : heading counts as observable once its std is below this.
    aligned_level_std_deg, aligned_heading_std_deg : the aligned criterion (with the heading
        observable and the recent innovations consistent).
    aligned_nis : mean NIS per degree of freedom over the last ``aligned_nis_window`` s above
        which the flag is held down (the velocity references' covariances scaled by the
        aligner's ``noise_scale``, as applied).
    inconsistent_nis : that mean, with the velocity references' covariances as given, above
        which the velocity reference contradicts the IMU (a
        wrong ``velocity_frame``, lever arm or latency, a reference far noisier than said;
        an honest filter's stays near 1: at most 1.33 over the benchmark's scenarios): the
        attitude is then published as unknown (pi^2 rad^2 on each axis, as before the start)
        and ``reference_consistent`` is False, until ``inconsistent_memory`` s after the last
        window above it (velocities given in NED to a filter told ENU agree with a heading
        60 deg off while the car drives straight, and contradict it in every turn). Also the
        largest ``noise_scale``.
    """

    latitude_deg: float
    longitude_deg: float = 0.0
    height_m: float = 0.0
    specs: SensorSpecs | str = "consumer"
    gyro_scale_std: float = 0.0
    accel_scale_std: float = 0.0
    lever_arm: tuple = (0.0, 0.0, 0.0)
    lever_arm_std: float = 0.0
    velocity_noise: float = 0.1
    velocity_latency: float = 0.0
    velocity_latency_std: float = 0.0
    velocity_averaging: float = 0.1
    max_measurement_lag: float = 0.5
    vehicle: str = "air"
    nhc_noise: float = 0.1
    nhc_axis: int = 1
    nhc_period: float = 0.1
    nhc_lever_arm: tuple = (0.0, 0.0, 0.0)
    nhc_lever_arm_std: float = 2.0
    nhc_mount_std_deg: float = 2.0
    nhc_slip_deg: float = 1.0
    nhc_slip_time: float = 3.0
    initial_rpy_deg: tuple | None = None
    initial_heading_std_deg: float = 180.0
    heading_hypotheses: int = 24
    init_time: float = 0.5
    attitude_matching: bool = False
    attitude_noise_deg: float = 0.1
    mounting_std_deg: float = 1.0
    nis_inflate: float = 5.0
    step_hold: bool = True
    feedback: str = "full"
    lqr_time_constant: float = 5.0
    feedback_fraction: float = 0.5
    max_gap: float = 1.0
    max_angular_rate: float = 10.0
    specific_force_max: float = 160.0
    observable_heading_std_deg: float = 5.0
    aligned_level_std_deg: float = 0.3
    aligned_heading_std_deg: float = 2.0
    aligned_nis: float = 3.0
    aligned_nis_window: float = 10.0
    inconsistent_nis: float = 10.0
    inconsistent_memory: float = 60.0

    def __post_init__(self):
        if isinstance(self.specs, str):
            object.__setattr__(self, "specs", grade_specs(self.specs))
        if not isinstance(self.specs, SensorSpecs):
            raise ValueError("specs must be a SensorSpecs or a grade name")
        lev = tuple(float(x) for x in np.asarray(self.lever_arm, dtype=float).reshape(3))
        object.__setattr__(self, "lever_arm", lev)
        nhl = tuple(float(x) for x in np.asarray(self.nhc_lever_arm, dtype=float).reshape(3))
        if not all(math.isfinite(x) for x in nhl + lev):
            raise ValueError("lever_arm and nhc_lever_arm must be finite")
        object.__setattr__(self, "nhc_lever_arm", nhl)
        if self.initial_rpy_deg is not None:
            object.__setattr__(self, "initial_rpy_deg", tuple(
                float(x) for x in np.asarray(self.initial_rpy_deg, dtype=float).reshape(3)))
        if self.vehicle not in VEHICLES:
            raise ValueError(f"vehicle must be one of {VEHICLES}, got {self.vehicle!r}")
        if not (isinstance(self.heading_hypotheses, int) and 2 <= self.heading_hypotheses <= 72):
            raise ValueError(f"heading_hypotheses must be an integer 2..72, got "
                             f"{self.heading_hypotheses!r}")
        if self.feedback not in FEEDBACKS:
            raise ValueError(f"feedback must be one of {FEEDBACKS}, got {self.feedback!r}")
        if not (isinstance(self.feedback_fraction, (int, float))
                and 0.0 < self.feedback_fraction <= 1.0):
            raise ValueError(f"feedback_fraction must be within (0, 1], got "
                             f"{self.feedback_fraction!r}")
        if not isinstance(self.step_hold, bool):
            raise ValueError(f"step_hold must be a bool, got {self.step_hold!r}")
        if self.nhc_axis not in (0, 1, 2):
            raise ValueError(f"nhc_axis must be 0, 1 or 2, got {self.nhc_axis!r}")
        if not (-90.0 < self.latitude_deg < 90.0 or (isinstance(self.latitude_deg, float)
                                                     and math.isnan(self.latitude_deg))):
            raise ValueError(f"latitude_deg must be within (-90, 90) (or NaN: from the first "
                             f"position), got {self.latitude_deg!r}")
        positive = ("velocity_noise", "nhc_noise", "nhc_period", "init_time",
                    "inconsistent_nis", "inconsistent_memory",
                    "attitude_noise_deg", "nis_inflate", "max_gap", "max_angular_rate",
                    "specific_force_max", "observable_heading_std_deg",
                    "aligned_level_std_deg", "aligned_heading_std_deg", "aligned_nis",
                    "aligned_nis_window", "initial_heading_std_deg", "lqr_time_constant")
        for name in positive:
            x = getattr(self, name)
            if not (isinstance(x, (int, float)) and math.isfinite(x) and x > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {x!r}")
        for name in ("lever_arm_std", "max_measurement_lag", "longitude_deg", "height_m",
                     "mounting_std_deg", "gyro_scale_std", "accel_scale_std",
                     "nhc_lever_arm_std", "nhc_mount_std_deg", "nhc_slip_deg", "nhc_slip_time",
                     "velocity_latency", "velocity_latency_std",
                     "velocity_averaging"):
            x = getattr(self, name)
            if not (isinstance(x, (int, float)) and math.isfinite(x)):
                raise ValueError(f"{name} must be finite, got {x!r}")
        if min(self.lever_arm_std, self.max_measurement_lag, self.mounting_std_deg,
               self.gyro_scale_std, self.accel_scale_std, self.nhc_lever_arm_std,
               self.nhc_mount_std_deg, self.velocity_latency_std,
               self.nhc_slip_deg, self.nhc_slip_time) < 0:
            raise ValueError("lever_arm_std, nhc_lever_arm_std, nhc_mount_std_deg, "
                             "velocity_latency_std, nhc_slip_deg, "
                             "nhc_slip_time, "
                             "max_measurement_lag, mounting_std_deg and the scale-factor stds "
                             "must be >= 0")
        if not 0.0 <= self.velocity_averaging <= 1.0:
            raise ValueError(f"velocity_averaging must be within [0, 1] s, got "
                             f"{self.velocity_averaging!r}")
