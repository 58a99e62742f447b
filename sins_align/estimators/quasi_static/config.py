"""The configuration of the quasi-static estimator (:class:`AlignConfig`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace


from sins_align.core.models import check_model
from sins_align.core.specs import SensorSpecs, grade_specs


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
