"""The in-motion parameters (issue 12) and replay's velocity-reference flags, without DDS.

- ``velocity_topic`` picks the estimator: '' = the quasi-static Aligner (as before), set = the
  in-motion MotionAligner, built from the parameters by one function for node and replay;
- every new parameter is checked as the existing ones are (type, choices, range, list);
- ``velocity_noise`` is the velocity reference's noise now; the coarse pass's zero-velocity
  noise is ``coarse_velocity_noise`` (AlignConfig's name);
- replay: bad flags and a velocity topic that is missing, of another type or empty end in one
  line on stderr, a non-zero exit and no output.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from cli_helpers import cli, listing
from sins_align.estimators.in_motion import MotionAligner, MotionConfig
from sins_align.estimators.quasi_static import AlignConfig, Aligner
from sins_align.ros import params as P
from sins_align.tools import replay, simulate

BASE = {"latitude": 34.0, "grade": "navigation"}


# ---------------------------------------------------------------- the schema
@pytest.mark.parametrize("name, value, words", [
    ("velocity_topic", 3.0, "velocity_topic must be a string"),
    ("velocity_type", "imu", "velocity_type must be one of twist_with_covariance, twist, "
                             "odometry, got 'imu'"),
    ("velocity_frame", "nwu", "velocity_frame must be one of enu, ned, got 'nwu'"),
    ("velocity_frame", "", "velocity_frame must be a non-empty string"),
    ("lever_arm", [0.1, 0.2], "lever_arm must be 3 finite numbers, got [0.1, 0.2]"),
    ("lever_arm", [0.1, math.nan, 0.0], "lever_arm must be 3 finite numbers"),
    ("lever_arm", [], "lever_arm must be 3 finite numbers, got []"),
    ("lever_arm", [0.0, 0.0, -1500.0], "lever_arm components must be within [-1000, 1000] m"),
    ("lever_arm_std", -0.1, "lever_arm_std must be within [0, 100]"),
    ("nhc_mount_std", 50.0, "nhc_mount_std must be within [0, 45]"),
    ("velocity_latency_std", 2.0, "velocity_latency_std must be within [0, 1]"),
    ("velocity_latency", math.inf, "velocity_latency must be"),
    ("velocity_noise", 0.0, "velocity_noise must be within [0.0001, 100], got 0"),
    ("max_measurement_lag", -0.1, "max_measurement_lag must be within [0, 60]"),
    ("velocity_averaging", 1.5, "velocity_averaging must be within [-1, 1]"),
    ("velocity_averaging", -0.5, "velocity_averaging must be -1 (auto) or within [0, 1] s"),
    ("vehicle", "car", "vehicle must be one of ground, air, marine, got 'car'"),
    ("gyro_scale_std", -0.5, "gyro_scale_std and accel_scale_std must be -1 (auto)"),
    ("accel_scale_std", 2e5, "accel_scale_std must be within [-1, 100000]"),
    ("navsat_topic", True, "navsat_topic must be a string"),
    ("longitude", 181.0, "longitude must be within [-180, 180], got 181"),
    ("attitude_matching", 1.0, "attitude_matching must be true or false"),
    ("coarse_velocity_noise", 20.0, "coarse_velocity_noise must be within [1e-06, 10]"),
])
def test_new_parameters_are_checked_with_a_reason(name, value, words):
    reason = P.check_param(name, value)
    assert reason is not None and words in reason, reason
    with pytest.raises(ValueError, match=None) as e:
        P.estimator_config({**BASE, "velocity_topic": "gnss/fix_velocity", name: value}
                           if name != "velocity_topic" else {**BASE, name: value})
    assert words in str(e.value)


def test_empty_topics_are_allowed_and_mean_none():
    for name in ("velocity_topic", "navsat_topic"):
        assert P.check_param(name, "") is None
        assert P.param_spec(name).default == ""
    assert P.check_param("velocity_topic", "/gnss/fix_velocity") is None


def test_without_a_velocity_topic_the_quasi_static_aligner_is_built_as_before():
    cfg = P.estimator_config(BASE)
    assert isinstance(cfg, AlignConfig) and cfg == P.config_from_params(BASE)
    assert isinstance(P.make_estimator(cfg), Aligner)
    assert not P.velocity_reference(BASE).enabled


def test_coarse_velocity_noise_is_the_renamed_coarse_parameter():
    """velocity_noise no longer touches the quasi-static filter; coarse_velocity_noise does."""
    cfg = P.config_from_params({**BASE, "coarse_velocity_noise": 0.003, "velocity_noise": 2.0})
    assert cfg.coarse_velocity_noise == 0.003
    assert P.config_from_params(BASE).coarse_velocity_noise == 0.01
    assert P.param_spec("velocity_noise").default == 0.1


def test_a_velocity_topic_builds_the_in_motion_estimator_from_the_parameters():
    values = {**BASE, "velocity_topic": "gnss/fix_velocity", "velocity_type": "odometry",
              "velocity_frame": "ned", "lever_arm": [0.5, -0.2, 1.25], "velocity_noise": 0.3,
              "max_measurement_lag": 0.8, "vehicle": "ground", "longitude": 108.5,
              "velocity_averaging": 0.2,
              "height": 412.0, "grade": "consumer", "initial_rpy": [1.0, 2.0, 30.0],
              "max_gap": 2.0, "max_angular_rate": 5.0, "attitude_matching": True}
    cfg = P.estimator_config(values)
    assert isinstance(cfg, MotionConfig)
    assert (cfg.latitude_deg, cfg.longitude_deg, cfg.height_m) == (34.0, 108.5, 412.0)
    assert cfg.lever_arm == (0.5, -0.2, 1.25)
    assert (cfg.velocity_noise, cfg.max_measurement_lag, cfg.vehicle) == (0.3, 0.8, "ground")
    assert cfg.velocity_averaging == 0.2
    assert cfg.initial_rpy_deg == (1.0, 2.0, 30.0)
    # in motion: max_gap at most 1 s, max_angular_rate at least 10 rad/s
    assert (cfg.max_gap, cfg.max_angular_rate, cfg.attitude_matching) == (1.0, 10.0, True)
    # velocity_averaging -1 (the default): 0 with a master INS (odometry), 0.1 with GNSS
    auto = {**values, "velocity_averaging": P.param_spec("velocity_averaging").default}
    assert auto["velocity_averaging"] == -1.0
    assert P.estimator_config(auto).velocity_averaging == 0.0
    for kind in ("twist_with_covariance", "twist"):
        assert P.estimator_config({**auto, "velocity_type": kind}).velocity_averaging == 0.1
    tight = P.estimator_config({**values, "max_gap": 0.3, "max_angular_rate": 20.0})
    assert (tight.max_gap, tight.max_angular_rate) == (0.3, 20.0)
    assert cfg.nhc_axis == 1
    assert P.estimator_config({**values, "lateral_axis": 0}).nhc_axis == 0
    for bad in (3, "y"):
        with pytest.raises(ValueError, match="lateral_axis"):
            P.estimator_config({**values, "lateral_axis": bad})
    assert cfg.specs == P.sensor_specs(P.checked_values(values))
    assert isinstance(P.make_estimator(cfg), MotionAligner)
    ref = P.velocity_reference(values)
    assert ref == P.VelocityReference("gnss/fix_velocity", "odometry", "ned", "")
    assert ref.enabled


def test_scale_factor_states_follow_the_gyro_in_use_unless_given():
    """-1 (the default): none for a navigation-grade gyro, 300 ppm for a tactical one,
    0.3 % for a MEMS one (its turns would otherwise put the attitude beyond 3 sigma), the
    class decided by the gyro bias in use, a grade's or a given one; explicit values kept."""
    base = {**BASE, "velocity_topic": "gnss/fix_velocity"}
    assert P.param_spec("gyro_scale_std").default == P.param_spec("accel_scale_std").default
    assert P.param_spec("gyro_scale_std").default == -1.0
    for grade, want in (("navigation", 0.0), ("tactical", 3e-4), ("consumer", 3e-3)):
        cfg = P.estimator_config({**base, "grade": grade})
        assert (cfg.gyro_scale_std, cfg.accel_scale_std) == (want, want), grade
    mems = P.estimator_config({**base, "grade": "navigation", "gyro_bias": 10.0})
    assert mems.gyro_scale_std == 3e-3
    given = P.estimator_config({**base, "grade": "consumer", "gyro_scale_std": 0.0,
                                "accel_scale_std": 500.0})
    assert (given.gyro_scale_std, given.accel_scale_std) == (0.0, 5e-4)
    # the quasi-static estimator has no such states: nothing changes there
    assert "gyro_scale_std" not in vars(P.estimator_config({**BASE, "grade": "consumer"}))


def test_lever_arm_mounting_and_latency_are_estimated_unless_given_as_exact():
    """The node's defaults estimate the antenna's lever arm (1 m 1-sigma), on a ground
    vehicle the rotation between the IMU's axes and the vehicle's (2 deg), and the velocity
    reference's latency (0.1 s): an antenna, a mounting or stamps that the user did not give
    exactly would otherwise be taken as exact
    (test_in_motion.py, test_in_motion_nhc.py show what that does); 0 keeps them exact."""
    base = {**BASE, "velocity_topic": "gnss/fix_velocity", "vehicle": "ground"}
    cfg = P.estimator_config(base)
    assert (cfg.lever_arm_std, cfg.nhc_mount_std_deg) == (1.0, 2.0)
    assert (cfg.velocity_latency, cfg.velocity_latency_std) == (0.0, 0.1)
    exact = P.estimator_config({**base, "lever_arm_std": 0.0, "nhc_mount_std": 0.0,
                                "velocity_latency": 0.12, "velocity_latency_std": 0.0})
    assert (exact.lever_arm_std, exact.nhc_mount_std_deg) == (0.0, 0.0)
    assert (exact.velocity_latency, exact.velocity_latency_std) == (0.12, 0.0)


def test_a_navsat_topic_needs_a_velocity_topic():
    with pytest.raises(ValueError, match="navsat_topic needs a velocity_topic"):
        P.estimator_config({**BASE, "navsat_topic": "gnss/fix"})
    ref = P.velocity_reference({**BASE, "velocity_topic": "v", "navsat_topic": "gnss/fix"})
    assert ref.navsat_topic == "gnss/fix"


def test_the_shipped_yaml_with_a_velocity_topic_is_a_valid_motion_config():
    import sins_align

    path = Path(sins_align.__file__).parent / "config" / "align.yaml"
    values = {k: v for k, v in P.load_params_yaml(path).items()
              if P.param_spec(k, "align") is not None}
    assert values["velocity_topic"] == "" and values["coarse_velocity_noise"] == 0.01
    assert isinstance(P.estimator_config({**values, "velocity_topic": "gnss/fix_velocity"}),
                      MotionConfig)


# ---------------------------------------------------------------- replay's flags
@pytest.fixture(scope="module")
def imu_bag(tmp_path_factory):
    """20 s of a static IMU: no velocity topic in it."""
    bag = tmp_path_factory.mktemp("vel_params") / "imu_only"
    assert simulate.main(["--duration", "20", "--rate", "50", str(bag)]) == 0
    return bag


def _refused(rc, err, words, out_dir: Path, code: int = 2):
    lines = err.strip().splitlines()
    assert rc == code, err
    assert len(lines) == 1 and lines[0].startswith("replay: error: "), err
    assert words in lines[0], lines[0]
    assert listing(out_dir) == set(), listing(out_dir)          # nothing written, no .partial


@pytest.mark.parametrize("args, words", [
    (["--velocity-type", "imu"], "argument --velocity-type: invalid choice: 'imu'"),
    (["--velocity-frame", "nwu"], "argument --velocity-frame: invalid choice: 'nwu'"),
    (["--vehicle", "car"], "argument --vehicle: invalid choice: 'car'"),
    (["--lever-arm", "1", "2"], "argument --lever-arm: expected 3 arguments"),
], ids=["type", "frame", "vehicle", "lever-arm-2"])
def test_replay_velocity_flags_are_parsed_by_argparse(args, words, imu_bag, tmp_path, capsys):
    """Choices and counts: argparse's usage and one error line, exit status 2, as the other
    flags of the tools."""
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(SystemExit) as e:
        replay.main([str(imu_bag), "--latitude", "34", "--grade", "navigation", *args,
                     "--summary-json", str(out / "s.json")])
    err = capsys.readouterr().err
    assert e.value.code == 2
    assert err.strip().splitlines()[-1].startswith(f"replay: error: {words}"), err
    assert listing(out) == set()


@pytest.mark.parametrize("args, words", [
    (["--lever-arm", "1", "nan", "0"], "--lever-arm must be finite numbers, got 1.0 nan 0.0"),
    (["--lever-arm", "0", "0", "2000"], "lever_arm components must be within [-1000, 1000] m"),
    (["--navsat-topic", "/gnss/fix"], "navsat_topic needs a velocity_topic"),
    (["--velocity-topic", "/gnss/fix_velocity"], "velocity topic /gnss/fix_velocity not in"),
    (["--velocity-topic", "/imu/data_raw"], "velocity topic /imu/data_raw in"),
    (["--velocity-topic", "/imu/data_raw", "--velocity-type", "odometry"],
     "is sensor_msgs/msg/Imu, not nav_msgs/msg/Odometry (set --velocity-type)"),
], ids=["lever-arm-nan", "lever-arm-far", "navsat-alone", "missing-topic", "wrong-type",
        "wrong-type-odometry"])
def test_replay_refuses_bad_velocity_flags_in_one_line(args, words, imu_bag, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    rc, _, err = cli(replay, [imu_bag, "--latitude", "34", "--grade", "navigation", *args,
                              "--summary-json", out / "s.json", "--csv", out / "s.csv"], capsys)
    _refused(rc, err, words, out)


def test_a_missing_velocity_topic_names_the_bag_topics(imu_bag, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    rc, _, err = cli(replay, [imu_bag, "--latitude", "34", "--grade", "navigation",
                              "--velocity-topic", "/vel", "--output", out / "bag"], capsys)
    _refused(rc, err, "(topics: /imu/data_raw (sensor_msgs/msg/Imu), /imu_sim/truth "
             "(geometry_msgs/msg/QuaternionStamped); choose it with --velocity-topic)", out)


def test_a_relative_velocity_topic_in_the_params_file_is_resolved_at_root(imu_bag, tmp_path,
                                                                          capsys):
    """The node's relative name gnss/fix_velocity is /gnss/fix_velocity in a bag recorded at
    root; replay looks for that, and --velocity-topic '' turns the reference off again."""
    y = tmp_path / "p.yaml"
    y.write_text("/**:\n  ros__parameters:\n    latitude: 34.0\n    grade: navigation\n"
                 "    velocity_topic: gnss/fix_velocity\n")
    out = tmp_path / "out"
    out.mkdir()
    rc, _, err = cli(replay, [imu_bag, "--params", y, "--summary-json", out / "s.json"], capsys)
    _refused(rc, err, "velocity topic /gnss/fix_velocity not in", out)
    rc, _, err = cli(replay, [imu_bag, "--params", y, "--velocity-topic", "",
                              "--summary-json", out / "s.json", "--quiet"], capsys)
    assert rc == 0, err
    s = json.loads((out / "s.json").read_text())
    assert "velocity_reference" not in s and s["config"]["model"] == "constant"


# ---------------------------------------------------------------- latitude from the first fix
def test_in_motion_with_a_navsat_topic_the_latitude_may_be_left_out():
    """The issue's 'latitude and height from a NavSatFix topic when present': with both
    topics the latitude can be omitted (NaN: the first fix gives it); without the NavSatFix
    topic, or without a velocity topic, it stays required."""
    values = {k: v for k, v in BASE.items() if k != "latitude"}
    cfg = P.estimator_config({**values, "velocity_topic": "v", "navsat_topic": "gnss/fix"})
    assert isinstance(cfg, MotionConfig) and math.isnan(cfg.latitude_deg)
    for extra in ({"velocity_topic": "v"}, {}):
        with pytest.raises(ValueError, match="latitude is required"):
            P.estimator_config({**values, **extra})


def test_without_a_position_the_in_motion_estimator_refuses_imu_samples_until_one_comes():
    """latitude_deg NaN: every IMU sample is refused ('no_position') until add_position;
    from then on the run is the one configured with that position, bit for bit."""
    import numpy as np

    from sins_align.sim.trajectory import PRESETS, simulate_trajectory

    traj = PRESETS["car_with_turn"]()
    r = simulate_trajectory(traj, 100.0, "tactical", seed=3, gnss_sigma=0.05, duration=40.0)
    site = (traj.lat_deg, traj.lon_deg, traj.height_m)

    def run(latitude, early):
        al = MotionAligner(MotionConfig(latitude_deg=latitude, longitude_deg=site[1],
                                        height_m=site[2], specs="tactical",
                                        velocity_noise=0.05))
        refused = al.update(r.t[1:early + 1], r.gyro[:early], r.accel[:early])
        assert al.add_position(r.t[early], *site)
        for tg, vg in zip(r.gnss_t, r.gnss_v):
            if tg > r.t[early]:
                al.add_velocity(tg, vg)
        al.update(r.t[early + 1:], r.gyro[early:], r.accel[early:])
        return al, refused

    blind, refused = run(math.nan, 50)
    assert refused == 0 and blind.rejected["no_position"] == 50, blind.rejected
    given = MotionAligner(MotionConfig(latitude_deg=site[0], longitude_deg=site[1],
                                       height_m=site[2], specs="tactical", velocity_noise=0.05))
    for tg, vg in zip(r.gnss_t, r.gnss_v):
        if tg > r.t[50]:
            given.add_velocity(tg, vg)
    given.update(r.t[51:], r.gyro[50:], r.accel[50:])
    assert blind.initialized and np.array_equal(blind.dcm, given.dcm)
    assert np.array_equal(blind.covariance, given.covariance)
    # a restart keeps the last position (it does not wait for another fix)
    blind.reset("test")
    assert blind.position == given.position
    assert blind.update(r.t[-1] + 0.01, r.gyro[-1], r.accel[-1]) == 1


def test_replay_takes_the_latitude_from_the_navsat_topic(tmp_path, capsys):
    """replay without --latitude but with --navsat-topic: the simulated fixes give the
    position; the same attitude as with --latitude (the first fix comes before the first
    IMU sample's; the simulated trajectory's site is the default latitude 34 deg)."""
    bag = tmp_path / "car"
    assert simulate.main(["--trajectory", "car_with_turn", "--grade", "tactical", "--duration",
                          "30", str(bag)]) == 0
    out = {}
    for name, flags in (("fix", ["--navsat-topic", "/gnss/fix"]),
                        ("given", ["--navsat-topic", "/gnss/fix", "--latitude", "34"])):
        rc, _, err = cli(replay, [bag, "--grade", "tactical", "--velocity-topic",
                                       "/gnss/fix_velocity", *flags, "--summary-json",
                                       tmp_path / f"{name}.json"], capsys)
        assert rc == 0, err
        out[name] = json.loads((tmp_path / f"{name}.json").read_text())
        # (the summary's configuration: no latitude given, null)
        assert out[name]["config"]["latitude_deg"] == (None if name == "fix" else 34.0)
    assert out["fix"]["final"]["orientation_xyzw"] == out["given"]["final"]["orientation_xyzw"]
    assert out["fix"]["rejected"] == {}, out["fix"]["rejected"]
    rc, _, err = cli(replay, [bag, "--velocity-topic", "/gnss/fix_velocity"], capsys)
    assert rc == 2 and "latitude is required" in err and "--navsat-topic" in err, err


def test_every_in_motion_rejection_reason_has_a_warning_text():
    """align_node's throttled warning names what a rejection means; 'no_position' (the
    latitude left out, no fix yet) had none: 'rejected 250 sample(s): no_position (?)'."""
    from sins_align.estimators.in_motion import MOTION_REJECT_REASONS
    from sins_align.ros.align_node import MOTION_REASON_TEXT, REASON_TEXT

    missing = [r for r in MOTION_REJECT_REASONS
               if r not in MOTION_REASON_TEXT and r not in REASON_TEXT]
    assert not missing, missing


def test_a_reference_whose_imu_samples_are_refused_does_not_pile_up():
    """Velocities that keep coming while every IMU sample is refused for want of a position
    are kept only as far back as a start could use them (given ahead of any IMU sample,
    they are all kept: replay-like callers do that)."""
    import numpy as np

    al = MotionAligner(MotionConfig(latitude_deg=math.nan, specs="tactical"))
    for k in range(3000):                           # 300 s at 10 Hz
        t = 100.0 + 0.1 * k
        assert al.add_velocity(t, [1.0, 0.0, 0.0])
        al.update(t, np.zeros(3), np.array([0.0, 0.0, 9.8]))
    c = al.config
    assert al.rejected["no_position"] == 3000
    assert al.pending_measurements <= 10 * (c.init_time + c.max_measurement_lag + 1.0) + 1
    ahead = MotionAligner(MotionConfig(latitude_deg=34.0, specs="tactical"))
    for k in range(3000):
        ahead.add_velocity(100.0 + 0.1 * k, [1.0, 0.0, 0.0])
    assert ahead.pending_measurements == 3000
