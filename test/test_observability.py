"""The observability tool (seed 001's PWCS analysis) against the seed's three conclusions and
against the in-motion filter's covariance on the same runs.

Body axes of the scenarios: the vehicle heads North, level, REP-103 IMU (x forward, y left,
z up): body x = North, y = West, z = Up. So ``ba_x`` is the forward (North) accelerometer
bias, ``ba_y`` the lateral (West) one, and ``bg_y`` the gyro bias on the east-west axis.
"""
from __future__ import annotations

import functools
import json
import subprocess
import sys

import numpy as np
import pytest

from sins_align.analysis.observability import (STATES, Scales, analyze, coupling_groups,
                                               error_model, pieces_from_trajectory, scenario,
                                               verdict)
from sins_align.core.rotation import rpy_from_dcm
from sins_align.core.specs import DEG
from sins_align.estimators.in_motion import MotionAligner, MotionConfig
from sins_align.estimators.in_motion.filter import IBA, IBG
from sins_align.sim.trajectory import SEED003_SPECS, simulate_trajectory

SIGMA_V = 0.02
RATE = 50.0
DURATION = 400.0
IDX = {n: i for i, n in enumerate(STATES)}


def _phase_end(phases, label):
    return [e for lab, e in phases if lab == label][0]


def _at(steps, t):
    return [s for s in steps if s.t <= t + 1e-6][-1]


def _verdicts(step):
    return {n: verdict(u, d) for n, u, d in zip(STATES, step.unresolved, step.degree)}


@pytest.fixture(scope="module")
def exact():
    """The analysis of each scenario (exact trajectory data), 400 s, default priors."""
    out = {}
    for name in ("static", "forward", "turn"):
        traj, phases = scenario(name)
        phases = [(lab, min(e, DURATION)) for lab, e in phases if e <= DURATION] or \
            [(phases[0][0], DURATION)]
        r = simulate_trajectory(traj, RATE, None, gnss_rate=10.0, duration=DURATION)
        pieces = pieces_from_trajectory(r, 1.0, breaks=[e for _, e in phases])
        steps = analyze(pieces, Scales(velocity=SIGMA_V, velocity_noise=SIGMA_V,
                                       gyro_bias=SEED003_SPECS.gyro_bias,
                                       accel_bias=SEED003_SPECS.accel_bias))
        out[name] = (steps, phases)
    return out


def test_error_model_blocks():
    """F and H: level couples gravity into horizontal velocity, biases enter through C."""
    C = np.eye(3)
    F, H = error_model(C, [0, 0, 9.8], [0, 7e-5, 3e-5])
    assert F.shape == (12, 12) and H.shape == (3, 12)
    assert F[3, 1] == pytest.approx(-9.8) and F[4, 0] == pytest.approx(9.8)  # f x phi
    assert np.allclose(F[3:6, 9:12], C) and np.allclose(F[0:3, 6:9], -C)
    assert np.allclose(H[:, 3:6], np.eye(3)) and np.allclose(H[:, [0, 1, 2, 6, 7, 8]], 0)
    F, H = error_model(C, [0, 0, 9.8], [0, 0, 0], w_nb=[0, 0, 0.1], lever_arm=[1, 0, 0],
                       lever_states=True)
    assert F.shape == (15, 15)
    # a yaw rate makes the velocity see the lever arm perpendicular to it, not along it
    assert np.abs(H[:, 12:14]).max() > 0.09 and np.allclose(H[:, 14], 0)


def test_static_rank_and_unobservable_states(exact):
    """Seed 001 experiment 1 (and the classic static result): rank 9 of 12; heading is
    unobservable (coupled with the east gyro bias), the horizontal accelerometer biases are
    unobservable (coupled with level), the vertical one observable."""
    steps, _ = exact["static"]
    s = steps[-1]
    assert s.rank == 9 and s.tom_rank == 9
    v = _verdicts(s)
    assert v["phi_U"] == "unobservable" and v["ba_x"] == "unobservable" \
        and v["ba_y"] == "unobservable"
    assert v["ba_z"] == "observable" and v["phi_E"] == v["phi_N"] == "observable"
    assert v["bg_y"] == "coupled"            # east gyro bias, tied to heading
    # level keeps only the accelerometer-bias part of its prior: (100 ug / g) / 1 deg
    lim = SEED003_SPECS.accel_bias / 9.79 / DEG
    assert s.unresolved[IDX["phi_E"]] == pytest.approx(lim, rel=0.02)
    groups = [set(g) for g in coupling_groups(s, STATES)]
    assert {"phi_E", "ba_x"} in groups                     # North bias with east level
    assert any({"phi_N", "ba_y", "phi_U", "bg_y"} <= g for g in groups)
    assert not any("dv_E" in g for g in groups)


def test_forward_acceleration(exact):
    """Seed 001 experiment 2 / conclusion 2: after accelerating forward heading is
    observable, the forward accelerometer bias is no longer unobservable but only weakly
    observable, the lateral one stays unobservable (tied to level)."""
    steps, phases = exact["forward"]
    before = _verdicts(_at(steps, _phase_end(phases, "static")))
    s = _at(steps, _phase_end(phases, "accelerate"))
    v = _verdicts(s)
    assert before["phi_U"] == "unobservable" and v["phi_U"] == "observable"
    assert before["ba_x"] == "unobservable" and v["ba_x"] == "weak"
    assert v["ba_y"] == "unobservable"
    assert s.effective_rank == 11
    assert any({"phi_N", "ba_y"} <= set(g) for g in coupling_groups(s, STATES))
    # cruising straight adds nothing new
    end = _verdicts(steps[-1])
    assert end["ba_y"] == "unobservable" and end["phi_U"] == "observable"


def test_turn_makes_horizontal_biases_observable(exact):
    """Seed 001 experiment 3 / conclusion 3: the 90 deg turn makes both horizontal
    accelerometer biases observable; every state is then observable (weakly: the up gyro
    bias)."""
    steps, phases = exact["turn"]
    s0 = _at(steps, _phase_end(phases, "cruise N"))
    s = _at(steps, _phase_end(phases, "turn left 90"))
    assert _verdicts(s0)["ba_y"] == "unobservable"
    v = _verdicts(s)
    assert s.effective_rank == 12 and s.rank == 12
    assert v["ba_x"] == v["ba_y"] == "observable"
    assert all(x in ("observable", "weak") for x in v.values())


@functools.lru_cache(maxsize=None)
def _filter_run(name):
    """MotionAligner on the scenario (seed 003's MEMS biases, no IMU white noise: see
    test_filter_covariance_agrees), with the tool's analysis at the filter's own priors.
    Returns [(label, verdicts, unresolved, filter std / its std at the start)]."""
    traj, phases = scenario(name)
    phases = [(lab, e) for lab, e in phases if e <= DURATION] or [(phases[0][0], DURATION)]
    specs = SEED003_SPECS.with_(gyro_arw=0.0, accel_vrw=0.0)
    r = simulate_trajectory(traj, RATE, specs, seed=5, gnss_rate=10.0, gnss_sigma=SIGMA_V,
                            duration=DURATION)
    cfg = MotionConfig(latitude_deg=traj.lat_deg, longitude_deg=traj.lon_deg,
                       height_m=traj.height_m, specs=SEED003_SPECS,
                       initial_rpy_deg=tuple(rpy_from_dcm(r.C[0]) / DEG),
                       initial_heading_std_deg=10.0, velocity_noise=SIGMA_V)
    al = MotionAligner(cfg)
    for tg, vg in zip(r.gnss_t, r.gnss_v):
        al.add_velocity(tg, vg)

    def stds():
        P = al.ekf.P[0]
        return np.concatenate([np.sqrt(np.diag(al.covariance)), np.sqrt(np.diag(P[IBG, IBG])),
                               np.sqrt(np.diag(P[IBA, IBA]))])

    k0 = int(RATE)
    al.update(r.t[1:k0 + 1], r.gyro[:k0], r.accel[:k0])
    s0 = stds()
    scales = Scales(level=float(np.sqrt(al.covariance[0, 0])), heading=10.0 * DEG,
                    velocity=SIGMA_V, velocity_noise=SIGMA_V,
                    gyro_bias=SEED003_SPECS.gyro_bias, accel_bias=SEED003_SPECS.accel_bias)
    steps = analyze(pieces_from_trajectory(r, 1.0, breaks=[e for _, e in phases]), scales)
    out = []
    for lab, te in phases:
        k1 = int(round(te * RATE))
        al.update(r.t[k0 + 1:k1 + 1], r.gyro[k0:k1], r.accel[k0:k1])
        k0 = k1
        s = _at(steps, te)
        out.append((lab, _verdicts(s), s.unresolved, stds() / s0))
    return out


FILTER_STATES = ("phi_E", "phi_N", "phi_U", "bg_x", "bg_y", "bg_z", "ba_x", "ba_y", "ba_z")


@pytest.mark.parametrize("name", ["static", "forward", "turn"])
def test_filter_covariance_agrees(name):
    """The filter's std over its prior std at the end of every phase, against the tool:
    unobservable keeps > 0.9 of it; coupled ends near the unresolved fraction (the limit a
    perfect filter reaches); observable shrinks (< 0.9; < 0.15 for attitude and gyro biases);
    weak does not get far (> 0.1).

    The IMU has biases but no white noise: with noise the filter's Jacobian takes the noise
    in the measured specific force for motion and gains heading information on a standing
    vehicle that is not there (its heading std fell from 10 to 6.2 deg in 400 s static with
    noise, to 9.5 without; the tool, and a linear filter on the tool's model, say 9.8)."""
    for lab, v, unres, ratio in _filter_run(name):
        for j, n in enumerate(FILTER_STATES):
            x, u, what = ratio[j], unres[IDX[n]], f"{name}/{lab}/{n}: {v[n]}, filter {ratio[j]:.3f}"
            if v[n] == "unobservable":
                assert x > 0.9, what
            elif v[n] == "coupled":
                assert 0.7 * u < x < 1.5 * u + 0.01, what + f", unresolved {u:.3f}"
            elif v[n] == "observable":
                assert x < (0.9 if n.startswith("ba") else 0.15), what
            else:
                assert x > 0.1, what


def test_turn_biases_shrink_more_than_forward():
    """The same filter: the lateral accelerometer bias barely moves in the forward run
    (unobservable) and clearly shrinks after the turn (observable)."""
    fwd = _filter_run("forward")[-1][3][FILTER_STATES.index("ba_y")]
    turn = [r for r in _filter_run("turn") if r[0] == "cruise W"][0][3]
    assert fwd > 0.95 and turn[FILTER_STATES.index("ba_y")] < fwd - 0.1


# ----------------------------------------------------------------------------- the CLI
def _cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "sins_align.observability", *args],
                          capture_output=True, text=True, cwd=cwd, timeout=120)


def test_cli_scenario_json_and_table(tmp_path):
    out = tmp_path / "static.json"
    p = _cli("--scenario", "static", "--json", str(out))
    assert p.returncode == 0, p.stderr
    assert "rank" in p.stdout and "phi_U" in p.stdout and "UNOB" in p.stdout
    res = json.loads(out.read_text())
    seg = res["segments"][-1]
    assert seg["rank"] == 9 and seg["states"] == 12
    assert seg["per_state"]["phi_U"]["verdict"] == "unobservable"
    assert len(res["timeline"]["t_s"]) == len(res["timeline"]["degree"]["phi_U"]) >= 800


@pytest.mark.parametrize("args, msg", [
    ((), "either a BAG or --scenario"),
    (("nonexistent_bag", "--latitude", "30", "--velocity-topic", "/v"), "does not exist"),
    (("--scenario", "static", "--window", "0"), "--window"),
    (("--scenario", "static", "--grade", "bogus"), "unknown grade"),
])
def test_cli_bad_input_one_line(tmp_path, args, msg):
    out = tmp_path / "o.json"
    p = _cli(*args, "--json", str(out))
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and msg in lines[0], p.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_cli_existing_output_needs_force(tmp_path):
    out = tmp_path / "o.json"
    out.write_text("keep")
    p = _cli("--scenario", "static", "--json", str(out))
    assert p.returncode == 2 and "already exists" in p.stderr
    assert out.read_text() == "keep"


def test_cli_bag(tmp_path):
    """A simulated bag (car_with_turn: stands 10 s, accelerates, turns 90 deg): standing,
    the horizontal accelerometer biases are unobservable; after the turn they are
    observable, and so is heading."""
    bag = tmp_path / "car"
    p = subprocess.run([sys.executable, "-m", "sins_align.simulate", "--trajectory",
                        "car_with_turn", "--grade", "tactical", "--seed", "1", str(bag)],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    out = tmp_path / "bag.json"
    p = _cli(str(bag), "--latitude", "34", "--height", "400", "--velocity-topic",
             "/gnss/fix_velocity", "--grade", "tactical", "--json", str(out))
    assert p.returncode == 0, p.stderr
    segs = json.loads(out.read_text())["segments"]
    first = segs[0]["per_state"]
    assert segs[0]["t_s"] == pytest.approx(10.0, abs=0.05)
    assert first["ba_x"]["verdict"] == first["ba_y"]["verdict"] == "unobservable"
    assert first["phi_U"]["verdict"] != "observable"
    last = segs[-1]["per_state"]
    assert last["ba_x"]["verdict"] == last["ba_y"]["verdict"] == "observable"
    assert last["phi_U"]["verdict"] == "observable"
    # without --latitude, the first fix on --navsat-topic gives it (as the replay does):
    # the simulated fixes are at the trajectory's 34 deg; the same verdicts
    fixed = tmp_path / "fix.json"
    q = _cli(str(bag), "--navsat-topic", "/gnss/fix", "--velocity-topic",
             "/gnss/fix_velocity", "--grade", "tactical", "--json", str(fixed))
    assert q.returncode == 0, q.stderr
    got = json.loads(fixed.read_text())
    assert got["source"]["latitude_deg"] == pytest.approx(34.0, abs=1e-6), got["source"]

    def verdicts(res):
        return [{k: v["verdict"] for k, v in x["per_state"].items()} for x in res["segments"]]
    assert verdicts(got) == verdicts(json.loads(out.read_text()))
    q = _cli(str(bag), "--velocity-topic", "/gnss/fix_velocity", "--json",
             str(tmp_path / "none.json"))
    assert q.returncode == 2 and "--navsat-topic" in q.stderr, q.stderr
