"""The one parameter schema of align_node, the replay tool and imu_sim_node.

Every parameter is a :class:`ParamSpec` (name, default, text, range or choices, read-only or
settable at run time) in one of three scopes: ``align`` (:data:`PARAMS`, the estimator's
:class:`AlignConfig`), ``node`` (:data:`NODE_PARAMS`, align_node's own) and ``sim``
(:data:`SIM_PARAMS`, imu_sim_node's). The nodes declare theirs from it
(:func:`sins_align.ros.runtime.declare_params`) and list them in ``--help``
(:func:`param_help`); every value is checked by :func:`check_param`. The replay tool reads the
node's YAML file through :func:`load_params_yaml`; node and replay turn the values into an
:class:`AlignConfig` with :func:`config_from_params`. No ROS imports here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

from sins_align.estimators.quasi_static import AlignConfig
from sins_align.io.velocity import VELOCITY_FRAMES, VELOCITY_TYPES
from sins_align.core.models import MODELS
from sins_align.core.specs import DPH, DPSH, GRADES, UG, UG_PSHZ, SensorSpecs, grade_specs
from sins_align.sim.simulator import SWAY_PRESETS
from sins_align.sim.trajectory import PRESETS as TRAJECTORY_PRESETS

#: The node's name: its executable's (``ros2 param list /align_node``). The shipped
#: config/align.yaml is keyed ``/**`` so that it applies to a renamed node too.
NODE_NAME = "align_node"
#: The node's name before 0.1.0 left it (a params file keyed with it no longer applies).
OLD_NODE_NAME = "sins_align"

#: The scopes of :class:`ParamSpec`: the estimator's, align_node's own, imu_sim_node's.
SCOPES = ("align", "node", "sim")


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: ROS name, default (its type is the parameter type: bool, str, float,
    int or a list of floats), text, range or choices, read-only or [runtime], scope.

    A float parameter whose default is NaN is required (the node refuses to start without
    it). A list is 3 finite numbers, or empty when ``allow_empty``; a string is one of the
    ``choices`` (when given), or empty when ``allow_empty``. ``rule`` is a further
    check beyond type and range (a one-line reason, or None).
    """

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = True
    scope: str = "align"
    allow_empty: bool = False
    rule: Callable[[Any], str | None] | None = None

    @property
    def required(self) -> bool:
        return isinstance(self.default, float) and math.isnan(self.default)


def _scoped(scope: str, *specs: ParamSpec) -> tuple[ParamSpec, ...]:
    return tuple(replace(p, scope=scope) for p in specs)


#: ``vehicle`` values of the in-motion estimator (ground: non-holonomic constraint).
VEHICLES = ("ground", "air", "marine")
#: Largest lever-arm component accepted, m.
MAX_LEVER_ARM = 1000.0


def _check_lever_arm(value) -> str | None:
    if max(abs(x) for x in value) > MAX_LEVER_ARM:
        return f"lever_arm components must be within [-{MAX_LEVER_ARM:g}, {MAX_LEVER_ARM:g}] m"
    return None


#: s — velocity_averaging of -1 (auto) with a GNSS velocity (0 with a master INS)
GNSS_VELOCITY_AVERAGING = 0.1


def _check_averaging(value) -> str | None:
    if value != -1.0 and not 0.0 <= value <= 1.0:
        return "velocity_averaging must be -1 (auto) or within [0, 1] s"
    return None


#: ppm — scale-factor std of -1 (auto), by the gyro bias in use: (bias bound deg/h, ppm);
#: above the last bound the MEMS figure
AUTO_SCALE_PPM = ((0.1, 0.0), (10.0, 300.0))
MEMS_SCALE_PPM = 3000.0


def _check_scale(value) -> str | None:
    if value != -1.0 and not 0.0 <= value <= 1e5:
        return "gyro_scale_std and accel_scale_std must be -1 (auto) or within [0, 1e5] ppm"
    return None


def _check_correlation_time(value) -> str | None:
    if value != -1.0 and not value > 0.0:
        return "bias_correlation_time and warmup_time must be -1 (from grade) or > 0 s"
    return None


def scale_factor_stds(values: dict[str, Any]) -> tuple[float, float]:
    """(gyro, accel) scale-factor 1-sigma as fractions, -1 (auto) resolved by the gyro bias
    in use (:func:`sensor_specs`): none below 0.1 deg/h (a navigation-grade IMU's few ppm
    do not show), 300 ppm below 10 deg/h (tactical: fibre-optic gyros, the better MEMS),
    else 3000 ppm (0.3 %, MEMS: a turning vehicle's hundreds of degrees put its attitude
    beyond 3 sigma unless the filter knows)."""
    bias_dph = sensor_specs(values).gyro_bias / DPH
    auto = next((ppm for bound, ppm in AUTO_SCALE_PPM if bias_dph < bound), MEMS_SCALE_PPM)
    return tuple((auto if float(values[k]) == -1.0 else float(values[k])) * 1e-6
                 for k in ("gyro_scale_std", "accel_scale_std"))


def velocity_averaging(values: dict[str, Any]) -> float:
    """``velocity_averaging`` in s, -1 (auto) resolved: 0 when the reference is a master INS
    (``velocity_type`` odometry: its velocity sees the motion the IMU does, vibration
    included), :data:`GNSS_VELOCITY_AVERAGING` otherwise."""
    v = float(values["velocity_averaging"])
    if v != -1.0:
        return v
    return 0.0 if values["velocity_type"] == "odometry" else GNSS_VELOCITY_AVERAGING


PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("latitude", math.nan, "Geodetic latitude of the IMU, deg (required; in motion "
              "with a navsat_topic it may be left out: the first fix gives it).", -90.0, 90.0),
    ParamSpec("height", 0.0, "Height above the WGS-84 ellipsoid, m.", -10000.0, 100000.0),
    ParamSpec("model", "constant", "Error model: constant (paper Model 3), conventional "
              "(Model 1) or se3 (Model 2).", choices=MODELS),
    ParamSpec("initial_rpy", [0.0, 0.0, 0.0], "Initial REP-103 roll, pitch, yaw of the IMU frame "
              "in ENU, deg. Any value converges; it only shortens the transient.",
              allow_empty=True),
    ParamSpec("grade", "", "Sensor grade preset for the specs below: navigation (0.01 deg/h, "
              "100 ug), tactical (1 deg/h, 1 mg) or consumer (MEMS: 0.1 deg/s, 5 mg; level "
              "only). Required unless gyro_bias, gyro_arw, accel_bias and accel_vrw are all "
              "given: the data cannot tell a grade's biases, and an IMU run as a better grade "
              "than it is gets a covariance that lies.", choices=tuple(GRADES),
              allow_empty=True),
    ParamSpec("gyro_bias", -1.0, "Gyro bias 1-sigma, deg/h (-1 = from grade).", -1.0, 1e6),
    ParamSpec("gyro_arw", -1.0, "Gyro angle random walk, deg/sqrt(h) (-1 = from grade).",
              -1.0, 1e6),
    ParamSpec("accel_bias", -1.0, "Accelerometer bias 1-sigma, micro-g (-1 = from grade).",
              -1.0, 1e6),
    ParamSpec("accel_vrw", -1.0, "Accelerometer white noise, micro-g/sqrt(Hz) (-1 = from grade).",
              -1.0, 1e6),
    ParamSpec("gyro_bias_instability", -1.0, "Gyro bias instability (first-order Gauss-Markov "
              "wander) 1-sigma, deg/h (-1 = from grade: none).", -1.0, 1e6),
    ParamSpec("accel_bias_instability", -1.0, "Accelerometer bias instability 1-sigma, "
              "micro-g (-1 = from grade: none).", -1.0, 1e6),
    ParamSpec("bias_correlation_time", -1.0, "Correlation time of the bias instability, s "
              "(-1 = from grade: 300).", -1.0, 1e6, rule=_check_correlation_time),
    ParamSpec("gyro_warmup", -1.0, "Gyro warm-up: 1-sigma extra bias at power-on that settles "
              "over warmup_time, deg/h (-1 = from grade: none).", -1.0, 1e6),
    ParamSpec("accel_warmup", -1.0, "Accelerometer warm-up 1-sigma, micro-g (-1 = from grade: "
              "none).", -1.0, 1e6),
    ParamSpec("warmup_time", -1.0, "Time constant of the warm-up, s (-1 = from grade: 300).",
              -1.0, 1e6, rule=_check_correlation_time),
    ParamSpec("coarse_velocity_noise", 0.01, "Zero-velocity measurement noise of the coarse "
              "pass, m/s for updates 0.01 s apart (scaled to the update interval).", 1e-6, 10.0),
    ParamSpec("coarse_update_period", 0.1, "Coarse-pass update interval, s (0 = every sample, "
              "as in the paper).", 0.0, 10.0),
    ParamSpec("backtrack", True, "Re-run the buffered data in the fine pass once a first "
              "estimate exists (False = the paper's one-pass filter)."),
    ParamSpec("backtrack_time", 60.0, "Data time after which the fine pass starts, s.",
              5.0, 3600.0),
    ParamSpec("fine_update_period", 1.0, "Shortest fine-pass update period, s (lengthened "
              "automatically for slow sway).", 0.01, 60.0),
    ParamSpec("rate", 0.0, "Nominal IMU rate, Hz (0 = estimate from the stamps).", 0.0, 100000.0),
    ParamSpec("max_gap", 5.0, "Stamp gaps above this are time jumps: sample rejected, time "
              "re-anchored, s.", 0.001, 3600.0, read_only=False),
    ParamSpec("max_angular_rate", 1.0, "Reject samples whose |angular rate| exceeds this, rad/s.",
              1e-3, 100.0, read_only=False),
    ParamSpec("specific_force_tolerance", 0.5, "Reject samples with ||f| - g| above this "
              "fraction of g for more than 1 s (shorter: a shock, used).", 0.01, 5.0,
              read_only=False),
    ParamSpec("units_check_window", 30.0, "Window of the deg/s-versus-rad/s check, s "
              "(0 = off).", 0.0, 3600.0),
    ParamSpec("aligned_std_ratio", 1.5, "Aligned when each observable axis std <= this x its "
              "limit accuracy ...", 1.0, 100.0, read_only=False),
    ParamSpec("aligned_min_level_std", 0.01, "... or <= this level std, deg.", 0.0, 90.0,
              read_only=False),
    ParamSpec("aligned_min_heading_std", 0.1, "... or <= this heading std, deg.", 0.0, 180.0,
              read_only=False),
    ParamSpec("heading_max_limit_std", 10.0, "Heading counts as observable when its limit "
              "accuracy is below this, deg (else level-only).", 0.0, 180.0),
    ParamSpec("disturbance_nis", 3.0, "Mean normalised innovation per axis above which the "
              "platform counts as moving (disturbed).", 0.1, 1e6, read_only=False),
    # --- in-motion alignment with a velocity reference (issue 12) ---
    ParamSpec("velocity_topic", "", "Velocity reference topic ('' = none: quasi-static "
              "self-alignment; set: in-motion alignment).", allow_empty=True),
    ParamSpec("velocity_type", "twist_with_covariance", "Message type of velocity_topic: "
              "twist_with_covariance (geometry_msgs/TwistWithCovarianceStamped), twist "
              "(geometry_msgs/TwistStamped, horizontal only) or odometry (nav_msgs/Odometry, "
              "twist in child_frame_id).", choices=tuple(VELOCITY_TYPES)),
    ParamSpec("velocity_frame", "enu", "Axis convention of the velocity message's world "
              "frame: enu or ned (never guessed from frame_id).", choices=VELOCITY_FRAMES),
    ParamSpec("lever_arm", [0.0, 0.0, 0.0], "Lever arm from the IMU to the GNSS antenna (or "
              "master INS), m, in the IMU frame.", rule=_check_lever_arm),
    ParamSpec("lever_arm_std", 1.0, "1-sigma of lever_arm per axis, m; > 0 estimates it (an "
              "antenna a metre or two from an IMU told [0, 0, 0] put most instants beyond 3 "
              "sigma in turns); 0 takes lever_arm as exact.", 0.0, 100.0),
    ParamSpec("velocity_noise", 0.1, "Velocity reference noise 1-sigma, m/s, for messages "
              "without a covariance.", 1e-4, 100.0),
    ParamSpec("velocity_latency", 0.0, "How much later than the instant it measured the "
              "velocity reference is stamped, s (a driver that stamps at reception).", -1.0,
              1.0),
    ParamSpec("velocity_latency_std", 0.1, "1-sigma of velocity_latency, s; > 0 estimates it "
              "while the vehicle accelerates (50 ms unaccounted for put a third of a city "
              "drive beyond 3 sigma); 0 takes it as exact.", 0.0, 1.0),
    ParamSpec("velocity_averaging", -1.0, "Interval over which the velocity reference is "
              "compared with the IMU velocity less its vibration jitter, s: the interval "
              "between velocity messages (0.1 at 10 Hz); 0 compares with the IMU velocity at "
              "the message's sample as it is (the setting for a master INS, whose velocity "
              "sees the same motion); -1: 0 with velocity_type odometry, else 0.1.",
              -1.0, 1.0, rule=_check_averaging),
    ParamSpec("gyro_scale_std", -1.0, "Gyro scale-factor error 1-sigma per axis, ppm (in "
              "motion): > 0 estimates the three scale factors (3 more states), 0 none; -1: "
              "by the gyro bias in use, 0 below 0.1 deg/h, 300 below 10 deg/h, else 3000.",
              -1.0, 1e5, rule=_check_scale),
    ParamSpec("accel_scale_std", -1.0, "Accelerometer scale-factor error 1-sigma per axis, "
              "ppm (in motion), as gyro_scale_std (-1: the same rule, by the gyro bias).",
              -1.0, 1e5, rule=_check_scale),
    ParamSpec("max_measurement_lag", 0.5, "Velocity messages may arrive this much after the "
              "IMU passed their stamp, s (later ones are rejected).", 0.0, 60.0),
    ParamSpec("vehicle", "air", "Vehicle kind: ground (adds the non-holonomic constraint of a "
              "wheeled vehicle), air or marine.", choices=VEHICLES),
    ParamSpec("lateral_axis", 1, "vehicle ground: the IMU axis that points to the vehicle's "
              "side, 0 = x, 1 = y, 2 = z (1 for an IMU mounted x forward, y left; 0 for a "
              "right-forward-up IMU). A number: YAML reads a bare y as true.", 0, 2),
    ParamSpec("nhc_lever_arm", [0.0, 0.0, 0.0], "vehicle ground: lever arm from the IMU to "
              "the point with no sideways velocity (a car's rear-axle centre), m, in the IMU "
              "frame.", rule=_check_lever_arm),
    ParamSpec("nhc_lever_arm_std", 2.0, "vehicle ground: 1-sigma of nhc_lever_arm per axis, "
              "m; > 0 estimates it in turns (0: taken as exact).", 0.0, 100.0),
    ParamSpec("nhc_mount_std", 2.0, "vehicle ground: 1-sigma of the rotation between the "
              "IMU's axes and the vehicle's, deg (an IMU bolted a little askew); > 0 estimates "
              "it (0: the IMU's lateral_axis is the vehicle's side exactly).", 0.0, 45.0),
    ParamSpec("nhc_slip_deg", 1.0, "vehicle ground: tyre sideslip bound, deg per m/s^2 of "
              "lateral acceleration (the constraint's noise grows in turns to cover it; 0: "
              "none).", 0.0, 10.0),
    ParamSpec("attitude_matching", False, "velocity_type odometry: also match the master "
              "INS attitude (its body axes taken as the IMU's; off: its velocity only)."),
    ParamSpec("navsat_topic", "", "sensor_msgs/NavSatFix topic for latitude, longitude and "
              "height ('' = none: the parameters).", allow_empty=True),
    ParamSpec("longitude", 0.0, "Geodetic longitude, deg (in-motion alignment; a navsat_topic "
              "overrides it).", -180.0, 180.0),
)

PARAMS_BY_NAME = {p.name: p for p in PARAMS}

#: align_node's own parameters (not the estimator's); replay takes euler_rate from the YAML.
NODE_PARAMS: tuple[ParamSpec, ...] = _scoped(
    "node",
    ParamSpec("euler_rate", 10.0, "Publishing rate of alignment/euler_deg, Hz.", 0.1, 1000.0,
              read_only=False),
    ParamSpec("queue_size", 1000, "History depth of the imu/data_raw subscription (sensor-data "
              "QoS otherwise): covers the pause of the backtrack pass; also the history depth "
              "of the imu/data publisher.", 5, 100000),
)

#: Every parameter align_node declares, in its order (the estimator's, then its own).
ALIGN_NODE_PARAMS = PARAMS + NODE_PARAMS


def _check_t0(value) -> str | None:
    return "t0 must be -1 (node clock) or >= 0 s" if -1 < value < 0 else None


#: imu_sim_node's parameters, all read-only (set at startup). Site and sensor ones share the
#: estimator's ranges.
SIM_PARAMS: tuple[ParamSpec, ...] = _scoped(
    "sim",
    ParamSpec("rate", 100.0, "IMU sample rate, Hz (data time).", 0.1, 100000.0),
    replace(PARAMS_BY_NAME["latitude"], default=34.0, description="Geodetic latitude, deg."),
    PARAMS_BY_NAME["height"],
    ParamSpec("rpy", [0.0, 0.0, 0.0], "True mean attitude: REP-103 roll, pitch, yaw of the IMU "
              "frame in ENU, deg."),
    replace(PARAMS_BY_NAME["grade"], default="navigation", allow_empty=False,
            description="Sensor grade preset of the simulated IMU."),
    *(PARAMS_BY_NAME[n] for n in ("gyro_bias", "gyro_arw", "accel_bias", "accel_vrw",
                                  "gyro_bias_instability", "accel_bias_instability",
                                  "bias_correlation_time", "gyro_warmup", "accel_warmup",
                                  "warmup_time")),
    ParamSpec("sway", "none", "Sway preset: none, car (parked car being boarded), ship (moored "
              "ship).", choices=tuple(SWAY_PRESETS)),
    ParamSpec("sway_amplitude", 1.0, "Factor on the sway preset amplitudes.", 0.0, 100.0),
    ParamSpec("seed", 0, "Random seed (-1 = fresh entropy).", -1, 2**31 - 1),
    ParamSpec("speed", 1.0, "Data seconds published per wall second.", 0.001, 1000.0),
    ParamSpec("duration", 0.0, "Seconds of data to publish (0 = forever).", 0.0, 1e9),
    ParamSpec("exit_when_done", False, "Exit once duration seconds of data were published."),
    ParamSpec("frame_id", "imu_link", "header.frame_id of the IMU messages."),
    ParamSpec("t0", -1.0, "Data time of the start, s since the epoch (-1 = the node clock at "
              "startup).", -1.0, 4e9, rule=_check_t0),
    ParamSpec("batch_rate", 50.0, "Wall-clock rate of the publishing timer, Hz; each tick "
              "publishes the samples that are due.", 1.0, 1000.0),
    ParamSpec("publish_truth", True, "Publish imu_sim/truth."),
    ParamSpec("wait_for_subscribers", False, "Start the data clock only once imu/data_raw (and "
              "imu_sim/truth, when published, and gnss/fix_velocity with a trajectory) have a "
              "subscriber."),
    ParamSpec("trajectory", "", "Moving-vehicle preset, one of "
              f"{', '.join(sorted(TRAJECTORY_PRESETS))} (empty = the static base): the vehicle "
              "starts at latitude and height and moves; duration 0 = the preset's own; rpy and "
              "sway must stay at their defaults. Publishes gnss/fix_velocity and gnss/fix.",
              choices=tuple(sorted(TRAJECTORY_PRESETS)), allow_empty=True),
    ParamSpec("gnss_rate", 10.0, "GNSS rate with a trajectory, Hz (rate / gnss_rate must be a "
              "whole number).", 1.0, 20.0),
    ParamSpec("gnss_noise", 0.05, "GNSS velocity noise 1-sigma per ENU axis, m/s.", 0.0, 100.0),
    ParamSpec("gnss_position_noise", 0.0, "GNSS position noise 1-sigma per ENU axis, m.",
              0.0, 1000.0),
    ParamSpec("gnss_latency", 0.0, "GNSS delivery delay, s of data time: a measurement is "
              "published that late, stamped with its measurement time.", 0.0, 10.0),
    ParamSpec("lever_arm", [0.0, 0.0, 0.0], "IMU to GNSS antenna, m, in IMU axes."),
)

#: The whole schema: every parameter of every scope.
SCHEMA: tuple[ParamSpec, ...] = ALIGN_NODE_PARAMS + SIM_PARAMS
_BY_SCOPE = {(p.scope, p.name): p for p in SCHEMA}

_TO_CONFIG = {
    "height": "height_m", "model": "model", "coarse_velocity_noise": "coarse_velocity_noise",
    "coarse_update_period": "coarse_update_period",
    "backtrack": "backtrack", "backtrack_time": "backtrack_time",
    "fine_update_period": "fine_update_period", "max_gap": "max_gap",
    "max_angular_rate": "max_angular_rate", "specific_force_tolerance": "specific_force_tolerance",
    "units_check_window": "units_check_window", "aligned_std_ratio": "aligned_std_ratio",
    "aligned_min_level_std": "aligned_min_level_std_deg",
    "aligned_min_heading_std": "aligned_min_heading_std_deg",
    "heading_max_limit_std": "heading_max_limit_std_deg", "disturbance_nis": "disturbance_nis",
}
_SPEC_UNITS = {"gyro_bias": DPH, "gyro_arw": DPSH, "accel_bias": UG, "accel_vrw": UG_PSHZ}
#: The optional figures: -1 (or absent) = the grade's, or the SensorSpecs default (none,
#: 300 s) without a grade.
_EXTRA_SPEC_UNITS = {"gyro_bias_instability": DPH, "accel_bias_instability": UG,
                     "bias_correlation_time": 1.0, "gyro_warmup": DPH, "accel_warmup": UG,
                     "warmup_time": 1.0}

#: Why a configuration without a grade is refused (one line).
GRADE_REQUIRED = ("grade is required: navigation (0.01 deg/h gyro), tactical (1 deg/h) or "
                  "consumer (a MEMS IMU: level only), or all four of gyro_bias, gyro_arw, "
                  "accel_bias, accel_vrw; a grade better than the IMU's makes the published "
                  "covariance lie")


def param_spec(name: str, scope: str = "align") -> ParamSpec | None:
    """The :class:`ParamSpec` of ``name`` in ``scope`` (one of :data:`SCOPES`), or None."""
    return _BY_SCOPE.get((scope, name))


def check_param(name: str, value: Any, scope: str = "align") -> str | None:
    """Return a one-line reason why ``value`` is not acceptable for parameter ``name`` of
    ``scope`` (one of :data:`SCOPES`), or None."""
    spec = param_spec(name, scope)
    if spec is None:
        return f"unknown parameter '{name}'"
    d = spec.default
    if isinstance(d, bool):
        return None if isinstance(value, bool) else f"{name} must be true or false"
    if isinstance(d, str):
        if not isinstance(value, str):
            return f"{name} must be a string"
        if not value:
            return None if spec.allow_empty else f"{name} must be a non-empty string"
        if spec.choices and value not in spec.choices:
            empty = " (or empty)" if spec.allow_empty else ""
            return f"{name} must be one of {', '.join(spec.choices)}{empty}, got '{value}'"
        return None
    if isinstance(d, list):
        try:
            vals = [float(x) for x in value]
        except (TypeError, ValueError):
            return f"{name} must be a list of numbers"
        if len(vals) not in ((0, 3) if spec.allow_empty else (3,)) \
                or not all(math.isfinite(x) for x in vals):
            empty = " (or empty)" if spec.allow_empty else ""
            what = "angles in deg" if name.endswith("rpy") else "numbers"
            return f"{name} must be 3 finite {what}{empty}, got {list(value)}"
        return spec.rule(vals) if spec.rule else None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"{name} must be a number"
    v = float(value)
    if not math.isfinite(v):
        if spec.required and math.isnan(v):
            return f"{name} is required"
        return f"{name} must be finite, got {v:g}"
    if isinstance(d, int) and not v.is_integer():
        return f"{name} must be an integer"
    if (spec.low is not None and v < spec.low) or (spec.high is not None and v > spec.high):
        fmt = "d" if isinstance(d, int) else "g"     # integers in full (seed)
        low, high, v = (type(d)(x) for x in (spec.low, spec.high, v))
        return f"{name} must be within [{low:{fmt}}, {high:{fmt}}], got {v:{fmt}}"
    return spec.rule(v) if spec.rule else None


def param_help(specs: tuple[ParamSpec, ...], heading: str) -> str:
    """The parameters' lines of a node's ``--help``: name, default, [runtime], text."""
    lines = [heading]
    for p in specs:
        runtime = "" if p.read_only else " [runtime]"
        lines.append(f"  {p.name} (default {p.default!r}){runtime}: {p.description}")
    return "\n".join(lines)


def defaults() -> dict[str, Any]:
    """Default value of every parameter (latitude is NaN: required)."""
    return {p.name: (list(p.default) if isinstance(p.default, list) else p.default)
            for p in PARAMS}


def sensor_specs(values: dict[str, Any]):
    """The :class:`~sins_align.core.specs.SensorSpecs` of parameter values: the ``grade``
    preset with ``gyro_bias``, ``gyro_arw``, ``accel_bias``, ``accel_vrw`` where >= 0 (all
    four without a grade), and the bias instabilities, the warm-ups and their times where
    >= 0 (absent = from the grade)."""
    over = {k: float(values[k]) * unit for k, unit in _SPEC_UNITS.items() if values[k] >= 0.0}
    over.update({k: float(values[k]) * unit for k, unit in _EXTRA_SPEC_UNITS.items()
                 if values.get(k, -1.0) >= 0.0})
    if not values["grade"]:
        if not all(k in over for k in _SPEC_UNITS):
            raise ValueError(GRADE_REQUIRED)
        return SensorSpecs(**over)
    specs = grade_specs(values["grade"])
    return specs.with_(**over) if over else specs


def config_from_params(values: dict[str, Any]) -> AlignConfig:
    """Build an :class:`AlignConfig` from parameter values (missing ones take defaults).

    Raises
    ------
    ValueError
        With a one-line reason for the first bad value (unknown names included).
    """
    merged = checked_values(values)
    specs = sensor_specs(merged)
    kw = {cfg: merged[name] for name, cfg in _TO_CONFIG.items()}
    rate = float(merged["rate"])
    return AlignConfig(latitude_deg=float(merged["latitude"]), specs=specs,
                       initial_rpy_deg=_initial_rpy(merged),
                       rate_hz=rate if rate > 0 else None, **kw)


def checked_values(values: dict[str, Any]) -> dict[str, Any]:
    """Every parameter value (the defaults, ``values`` on top), each checked, and the
    combinations: a ``navsat_topic`` needs a ``velocity_topic``.

    Raises
    ------
    ValueError
        With a one-line reason for the first bad value (unknown names included).
    """
    merged = defaults()
    merged.update(values)
    # in motion with a NavSatFix topic the latitude may be left out: the first fix gives it
    from_fix = bool(merged["velocity_topic"] and merged["navsat_topic"])
    for name, value in merged.items():
        if name == "latitude" and from_fix and isinstance(value, float) and math.isnan(value):
            continue
        reason = check_param(name, value)
        if reason:
            raise ValueError(reason)
    if merged["navsat_topic"] and not merged["velocity_topic"]:
        raise ValueError("navsat_topic needs a velocity_topic (only the in-motion alignment "
                         "takes positions; without one the latitude and height parameters "
                         "are used)")
    sensor_specs(merged)            # GRADE_REQUIRED without a grade or all four specs
    return merged


def _initial_rpy(merged: dict[str, Any]) -> tuple[float, float, float] | None:
    rpy = [float(x) for x in merged["initial_rpy"]]
    return (rpy[0], rpy[1], rpy[2]) if rpy else None


@dataclass(frozen=True)
class VelocityReference:
    """The velocity reference of an in-motion alignment, from the parameters: its topic (''
    = none), message type (:data:`sins_align.io.velocity.VELOCITY_TYPES`), axis convention
    (enu | ned) and the NavSatFix topic ('' = none)."""

    topic: str
    type: str
    frame: str
    navsat_topic: str

    @property
    def enabled(self) -> bool:
        return bool(self.topic)


def velocity_reference(values: dict[str, Any]) -> VelocityReference:
    """The :class:`VelocityReference` of parameter values (checked as
    :func:`checked_values`; raises ValueError)."""
    m = checked_values(values)
    return VelocityReference(m["velocity_topic"], m["velocity_type"], m["velocity_frame"],
                             m["navsat_topic"])


#: s — in motion, IMU gaps above this restart the alignment whatever max_gap says
MOTION_MAX_GAP = 1.0
#: rad/s — in motion, max_angular_rate is at least this (a car yaws at 0.5, a UAV at 3)
MOTION_MIN_RATE_LIMIT = 10.0


def motion_config_from_params(values: dict[str, Any]):
    """The in-motion estimator's ``MotionConfig`` from parameter values (missing ones take
    defaults): site (latitude, longitude, height), sensor specs, initial attitude, lever arm,
    velocity noise, measurement lag, vehicle, attitude matching, ``max_gap`` (at most
    :data:`MOTION_MAX_GAP`) and ``max_angular_rate`` (at least
    :data:`MOTION_MIN_RATE_LIMIT`). The other input checks (``specific_force_tolerance``,
    ``units_check_window``, ``rate``), the quasi-static filter's and its aligned-flag
    thresholds do not apply to it. Raises ValueError."""
    from sins_align.estimators.in_motion import MotionConfig

    m = checked_values(values)
    gyro_sf, accel_sf = scale_factor_stds(m)
    return MotionConfig(
        latitude_deg=float(m["latitude"]), longitude_deg=float(m["longitude"]),
        height_m=float(m["height"]), specs=sensor_specs(m),
        lever_arm=tuple(float(x) for x in m["lever_arm"]),
        lever_arm_std=float(m["lever_arm_std"]),
        velocity_noise=float(m["velocity_noise"]),
        velocity_latency=float(m["velocity_latency"]),
        velocity_latency_std=float(m["velocity_latency_std"]),
        velocity_averaging=velocity_averaging(m),
        gyro_scale_std=gyro_sf, accel_scale_std=accel_sf,
        max_measurement_lag=float(m["max_measurement_lag"]), vehicle=m["vehicle"],
        nhc_axis=int(m["lateral_axis"]),
        nhc_lever_arm=tuple(float(x) for x in m["nhc_lever_arm"]),
        nhc_lever_arm_std=float(m["nhc_lever_arm_std"]),
        nhc_mount_std_deg=float(m["nhc_mount_std"]),
        nhc_slip_deg=float(m["nhc_slip_deg"]),
        attitude_matching=bool(m["attitude_matching"]),
        initial_rpy_deg=_initial_rpy(m),
        # a moving vehicle turns and rolls faster than a parked base sways, and an IMU hole
        # is bridged by holding a sample: the quasi-static defaults do not fit
        max_gap=min(float(m["max_gap"]), MOTION_MAX_GAP),
        max_angular_rate=max(float(m["max_angular_rate"]), MOTION_MIN_RATE_LIMIT))


def estimator_config(values: dict[str, Any]):
    """The estimator's configuration for parameter values: a ``MotionConfig`` (in-motion
    alignment) when ``velocity_topic`` is set, else the quasi-static :class:`AlignConfig`.
    Raises ValueError with a one-line reason."""
    if checked_values(values)["velocity_topic"]:
        return motion_config_from_params(values)
    return config_from_params(values)


def make_estimator(config):
    """A new estimator for ``config`` (from :func:`estimator_config`): the quasi-static
    :class:`~sins_align.estimators.quasi_static.Aligner` for an :class:`AlignConfig`, the
    in-motion ``MotionAligner`` otherwise."""
    if isinstance(config, AlignConfig):
        from sins_align.estimators.quasi_static import Aligner

        return Aligner(config)
    from sins_align.estimators.in_motion import MotionAligner

    return MotionAligner(config)


def node_key_matches(key: str, node_name: str = NODE_NAME, namespace: str = "/") -> bool:
    """Whether a ROS 2 params-file key names the node ``namespace/node_name``, as rcl matches
    it: ``/**`` (any), ``*`` (one name token), ``**`` (any number of tokens), the leading ``/``
    optional."""
    fqn = [t for t in f"{namespace}/{node_name}".split("/") if t]
    pattern = [t for t in str(key).split("/") if t]

    def match(pi: int, ni: int) -> bool:
        if pi == len(pattern):
            return ni == len(fqn)
        tok = pattern[pi]
        if tok == "**":
            return any(match(pi + 1, k) for k in range(ni, len(fqn) + 1))
        if ni < len(fqn) and tok in ("*", fqn[ni]):
            return match(pi + 1, ni + 1)
        return False

    return bool(pattern) and match(0, 0)


def load_params_yaml(path: str | Path, node_name: str = NODE_NAME) -> dict[str, Any]:
    """Read the ``ros__parameters`` that apply to node ``node_name`` (at the root namespace)
    from a ROS 2 params file: the sections keyed ``/**``, ``node_name``, ``/node_name`` or
    any wildcard key that matches it, in file order (later ones win, as in rcl).

    Raises
    ------
    ValueError
        If the file cannot be parsed or holds no parameters for the node.
    """
    import yaml

    try:
        doc = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as e:
        raise ValueError(f"cannot read parameters file {path}: {e}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: not a ROS 2 parameters file (expected a mapping)")
    out: dict[str, Any] = {}
    for key, block in doc.items():
        if node_key_matches(key, node_name) and isinstance(block, dict) \
                and isinstance(block.get("ros__parameters"), dict):
            out.update(block["ros__parameters"])
    if not out:
        hint = ""
        if node_name == NODE_NAME and any(node_key_matches(k, OLD_NODE_NAME) for k in doc):
            hint = (f" (the node is named {NODE_NAME} now, after its executable: key the "
                    f"section '{NODE_NAME}:' or '/**:' instead of '{OLD_NODE_NAME}:')")
        raise ValueError(f"{path}: no '/**:' or '{node_name}:' section with ros__parameters"
                         + hint)
    return out
