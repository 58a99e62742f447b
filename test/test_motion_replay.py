"""replay with a velocity reference (issue 12): the in-motion estimator on moving bags.

- the GNSS messages are merged with the IMU by header stamp, not by log time: a bag whose
  GNSS is logged 0.3 s late replays exactly as one logged on time;
- the summary keeps every key it had and adds ``final.heading_observable``,
  ``final.bias_gyro_dph``, ``final.bias_accel_mg`` and ``velocity_reference``;
- the block path (summary only) and the per-sample path (``--output``, the node's) agree;
- a receiver without vertical velocity (-1 variance, NaN) is used horizontally;
- real data (PSINS MEMS + master FOG INS): the master's Odometry, whose twist is in its body
  frame (REP-105), gives the same alignment as its ENU velocity, within 3 sigma of the truth.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from sins_align.data import TRANSFER_FOG_MEMS
from sins_align.tools import import_imu, replay, simulate

LEVER = ("0.5", "0.2", "1.0")
MOTION = ["--topic", "/imu/data_raw", "--latitude", "34", "--grade", "tactical",
          "--velocity-topic", "/gnss/fix_velocity", "--lever-arm", *LEVER, "--quiet"]
#: the keys of a quasi-static replay summary (and of its "final"), which stay
KEYS = {"bag", "topic", "truth_topic", "samples", "samples_used", "rejected", "events",
        "duration_s", "aligned", "time_to_aligned_s", "status", "resets", "stage",
        "heading_observable", "aligned_changes", "final", "config", "limit_std_enu_deg",
        "fine_velocity_noise_mps", "nis", "wall_time_s", "messages_per_s"}
FINAL = {"stamp_s", "frame_id", "orientation_xyzw", "rpy_deg", "heading_deg", "std_enu_deg",
         "covariance_enu_rad2"}


def _bag(path, *extra):
    assert simulate.main(["--trajectory", "car_with_turn", "--rate", "50", "--grade",
                          "tactical", "--seed", "3", "--lever-arm", *LEVER, *extra,
                          str(path)]) == 0
    return path


def _summary(tmp_path, bag, *args):
    out = tmp_path / f"s{len(list(tmp_path.glob('s*.json')))}.json"
    assert replay.main([str(bag), *MOTION, *args, "--summary-json", str(out)]) == 0
    return json.loads(out.read_text())


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("motion_replay")
    return {"on_time": _bag(d / "on_time"),
            "late": _bag(d / "late", "--gnss-latency", "0.3")}


def test_gnss_is_merged_by_header_stamp_not_log_time(bags, tmp_path):
    a = _summary(tmp_path, bags["on_time"])
    b = _summary(tmp_path, bags["late"])
    assert a["final"]["orientation_xyzw"] == b["final"]["orientation_xyzw"]
    assert a["aligned_changes"] == b["aligned_changes"]


def test_summary_keeps_its_keys_and_adds_the_in_motion_ones(bags, tmp_path):
    s = _summary(tmp_path, bags["late"], "--truth-topic", "/imu_sim/truth", "--vehicle",
                 "ground")
    assert KEYS <= set(s) and FINAL <= set(s["final"]), set(s) ^ KEYS
    fin = s["final"]
    assert fin["heading_observable"] is True and s["heading_observable"] is True
    assert len(fin["bias_gyro_dph"]) == 3 and len(fin["bias_accel_mg"]) == 3
    ref = s["velocity_reference"]
    assert ref["velocity_used"] == ref["velocity_received"] == 501, ref
    assert (ref["topic"], ref["type"], ref["frame"]) == ("/gnss/fix_velocity",
                                                         "twist_with_covariance", "enu")
    assert s["aligned"] is True and s["time_to_aligned_s"] is not None
    assert s["config"]["vehicle"] == "ground" and s["config"]["lever_arm_m"] == [0.5, 0.2, 1.0]
    assert s["config"]["model"] is None and s["stage"] == "in_motion"
    sigma = np.abs(fin["error_enu_deg"]) / np.array(fin["std_enu_deg"])
    assert sigma.max() < 3.0, (fin["error_enu_deg"], fin["std_enu_deg"])


def test_block_path_agrees_with_the_per_sample_path(bags, tmp_path):
    """Summary only: the IMU in blocks cut at each GNSS stamp; --output: one sample at a
    time, as the node. The estimator's closed-form propagation over a block rounds
    differently from one sample at a time, nothing more."""
    a = _summary(tmp_path, bags["late"])
    b = _summary(tmp_path, bags["late"], "--output", str(tmp_path / "out"))
    dq = np.abs(np.array(a["final"]["orientation_xyzw"]) - b["final"]["orientation_xyzw"])
    assert dq.max() < 1e-8, dq
    assert a["aligned_changes"] == b["aligned_changes"]
    np.testing.assert_allclose(a["final"]["std_enu_deg"], b["final"]["std_enu_deg"],
                               rtol=1e-6)


def test_a_receiver_without_vertical_velocity_is_used_horizontally(tmp_path):
    bag = _bag(tmp_path / "novert", "--no-gnss-vertical")
    s = _summary(tmp_path, bag)
    assert s["velocity_reference"]["velocity_used"] == 501, s["velocity_reference"]
    assert s["aligned"] is True, s["status"]


def test_navsat_positions_are_given_to_the_estimator(bags, tmp_path, monkeypatch):
    monkeypatch.setenv("SINS_ALIGN_DEBUG", "1")       # the estimator's exception, not rc 1
    s = _summary(tmp_path, bags["late"], "--navsat-topic", "/gnss/fix")
    assert s["velocity_reference"]["position_used"] == 501
    assert s["aligned"] is True


@pytest.fixture(scope="module")
def transfer_bag(tmp_path_factory):
    bag = tmp_path_factory.mktemp("transfer") / "tf"
    assert import_imu.main([str(TRANSFER_FOG_MEMS), str(bag)]) == 0
    y = bag.parent / "tf.yaml"
    y.write_text("/**:\n  ros__parameters:\n    latitude: 34.43\n    longitude: 111.43\n"
                 "    height: 172.6\n    velocity_noise: 0.05\n    grade: consumer\n"
                 "    gyro_bias: 300.0\n    gyro_arw: 1.0\n    accel_bias: 10000.0\n"
                 "    accel_vrw: 300.0\n    velocity_averaging: 0.0\n")
    return bag, y


def test_real_master_odometry_is_rotated_from_its_body_frame(transfer_bag, tmp_path):
    """The master's Odometry twist is in master_link axes; rotated by its orientation it is
    the master's ENU velocity: both topics give the same alignment, which is within 3 sigma
    of the slave's truth. (velocity_averaging 0, the master-INS setting, for both: its
    default, -1, picks 0 for the Odometry topic only.)"""
    bag, y = transfer_bag
    common = [str(bag), "--params", str(y), "--truth-topic", "/imu_sim/truth", "--quiet"]
    out = [tmp_path / "enu.json", tmp_path / "odom.json"]
    assert replay.main(common + ["--velocity-topic", "/master/velocity",
                                 "--summary-json", str(out[0])]) == 0
    assert replay.main(common + ["--velocity-topic", "/master/odom", "--velocity-type",
                                 "odometry", "--summary-json", str(out[1])]) == 0
    a, b = (json.loads(p.read_text()) for p in out)
    np.testing.assert_allclose(b["final"]["orientation_xyzw"], a["final"]["orientation_xyzw"],
                               rtol=0, atol=1e-12)
    assert b["velocity_reference"]["velocity_used"] == 1000
    fin = b["final"]
    sigma = np.abs(fin["error_enu_deg"]) / np.array(fin["std_enu_deg"])
    assert sigma.max() < 3.0, (fin["error_enu_deg"], fin["std_enu_deg"])
    assert b["aligned"] is True
