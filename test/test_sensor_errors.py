"""Sensor errors the filters' models leave out, configured as a datasheet gives them.

Bias instability (a first-order Gauss-Markov wander of the biases): the quasi-static filter
has no accelerometer bias states, so the accelerometer-levelled tilt follows the wander, and
the filter read that tilt drift as an east gyro rate, i.e. as heading. Navigation grade with
a datasheet's 0.3x instability (30 ug, 0.003 deg/h) at tau = 300 s: up to 8.7 sigma of
heading, hundreds of instants flagged aligned while beyond 3 sigma (10 seeds). The specs'
instability is now considered as one more bias, and the accelerometer's wander is level
process noise. Increment quantisation (nav grade, 4 arcsec and 5 mm/s) costs nothing.

The trajectory simulator (in-motion) draws the same errors from the specs: checked here.
"""
from __future__ import annotations

import numpy as np
import pytest

from sins_align.core.specs import grade_specs
from sins_align.sim.honesty import CASES, Case, run_case
from sins_align.sim.trajectory import car_city, simulate_trajectory

NAV = grade_specs("navigation")
TAC = grade_specs("tactical")


def _wander(base, ratio: float, tau: float):
    return base.with_(gyro_bias_instability=ratio * base.gyro_bias,
                      accel_bias_instability=ratio * base.accel_bias,
                      bias_correlation_time=tau)


@pytest.mark.parametrize("seed", [0, 2, 4])
def test_accelerometer_wander_is_covered_and_never_flagged_wrong(seed):
    """Nav grade, instability 0.3x the biases, tau 300 s, 600 s still (before the fix: seed
    0 had 5 instants beyond 4 sigma and 15 aligned while wrong, seed 2 15 and 120, seed 4 83
    and 207; heading up to 4.6 sigma)."""
    r = run_case(Case("wander", 600.0, specs=_wander(NAV, 0.3, 300.0)), seed=seed)
    assert r["n_viol_4sigma"] == 0, r
    assert r["aligned_wrong"] == 0, r
    assert r["frac_over_3sigma"] <= 0.01, r
    assert r["t_aligned_first"] is not None    # still aligns: the wander is small here


@pytest.mark.parametrize("name", ["wander_nav_1x_30s", "wander_tactical_1x_30s",
                                  "quantized_nav"])
def test_sensor_error_cases_are_honest(name):
    r = run_case(CASES[name], seed=1)
    assert r["n_viol_4sigma"] == 0, r
    assert r["aligned_wrong"] == 0, r
    assert r["frac_over_3sigma"] <= 0.01, r


def test_gyro_wander_alone_changes_nothing_the_consider_part_does_not_cover():
    """Gyro-only instability (1x, tau 300 s) was honest before; it stays honest and aligns."""
    sp = NAV.with_(gyro_bias_instability=NAV.gyro_bias, bias_correlation_time=300.0)
    r = run_case(Case("gyro_wander", 600.0, specs=sp), seed=3)
    assert r["n_viol_4sigma"] == 0 and r["aligned_wrong"] == 0, r
    assert r["t_aligned_first"] is not None


# ------------------------------------------------------------------ the trajectory simulator
def _pair(**kw):
    tr = car_city()
    base = simulate_trajectory(tr, 100.0, TAC, seed=5, duration=400.0)
    other = simulate_trajectory(tr, 100.0, kw.pop("specs", TAC), seed=5, duration=400.0, **kw)
    return base, other


def test_trajectory_bias_wander_is_gauss_markov_and_leaves_the_rest():
    sp = TAC.with_(accel_bias_instability=TAC.accel_bias, bias_correlation_time=50.0)
    base, r = _pair(specs=sp)
    np.testing.assert_array_equal(r.gyro, base.gyro)            # gyro untouched
    d = r.accel - base.accel                                    # the wander alone
    assert np.all(np.abs(d.std(0) / TAC.accel_bias - 1.0) < 0.6)
    a = np.exp(-0.01 / 50.0)                                    # its step: a d + drive
    drive = d[1:] - a * d[:-1]
    np.testing.assert_allclose(drive.std(0) / (TAC.accel_bias * np.sqrt(1 - a * a)), 1.0,
                               atol=0.03)
    assert abs(np.corrcoef(drive[:-1, 0], drive[1:, 0])[0, 1]) < 0.03   # white drive


def test_trajectory_quantisation_keeps_the_sum():
    sp = TAC.with_(gyro_quantization=1e-5, accel_quantization=1e-3)
    base, r = _pair(specs=sp)
    inc = r.gyro * 0.01 / 1e-5
    np.testing.assert_allclose(inc, np.round(inc), atol=1e-6)
    err = np.abs(np.cumsum((r.gyro - base.gyro) * 0.01, axis=0))
    assert err.max() <= 0.5e-5 * (1 + 1e-6)
    err = np.abs(np.cumsum((r.accel - base.accel) * 0.01, axis=0))
    assert err.max() <= 0.5e-3 * (1 + 1e-6)


def test_trajectory_warm_up_settles_exponentially():
    base, r = _pair(specs=TAC.with_(gyro_warmup=3.0 * TAC.gyro_bias, warmup_time=100.0))
    np.testing.assert_array_equal(r.accel, base.accel)
    d = r.gyro - base.gyro
    assert np.all(np.abs(d[0]) > 0.0) and np.all(np.abs(d[0]) < 12.0 * TAC.gyro_bias)
    np.testing.assert_allclose(d[10000 - 1], d[0] * np.exp(-(10000 - 1) / 10000.0),
                               rtol=1e-6)
    with pytest.raises(ValueError):
        TAC.with_(warmup_time=0.0)


def test_quasi_static_simulator_warm_up():
    """simulate(): the same warm-up, drawn from its own streams (the rest unchanged)."""
    from sins_align.sim.simulator import simulate

    sp = NAV.with_(accel_warmup=3.0 * NAV.accel_bias, warmup_time=50.0)
    a = simulate(200.0, specs=NAV, seed=3, t0=1000.0)
    b = simulate(200.0, specs=sp, seed=3, t0=1000.0)
    np.testing.assert_array_equal(a.gyro, b.gyro)
    d = b.accel - a.accel
    np.testing.assert_allclose(d[-1], d[0] * np.exp(-(200.0 - 0.01) / 50.0), rtol=1e-6)
    assert np.all(np.abs(d[0]) > 0.0) and np.all(np.abs(d[0]) < 15.0 * NAV.accel_bias)


def test_warm_up_in_the_specs_is_covered():
    """Navigation grade, a warm-up of 3x the biases over 300 s in the specs (simulated and
    configured): the estimator ignored it (seed 1: 90 % of the instants beyond 3 sigma,
    heading 8.4 sigma, 540 flagged aligned while wrong); it is now one more wander."""
    r = run_case(CASES["warmup_nav_3x_300s"], seed=1)
    assert r["n_viol_4sigma"] == 0, r
    assert r["aligned_wrong"] == 0, r
    assert r["frac_over_3sigma"] <= 0.01, r


# ------------------------------------------------------------------ the node's parameters
def test_the_node_parameters_carry_the_instability():
    """align_node / replay / imu_sim_node take the datasheet's instability (deg/h, micro-g)
    and correlation time; -1 keeps the grade's (none, 300 s)."""
    from sins_align.core.specs import DPH, UG
    from sins_align.ros.params import check_param, config_from_params, defaults, sensor_specs

    v = defaults()
    v["grade"] = "navigation"
    assert sensor_specs(v) == NAV
    v.update(latitude=34.0, gyro_bias_instability=0.003, accel_bias_instability=30.0,
             bias_correlation_time=300.0)
    sp = sensor_specs(v)
    assert sp.gyro_bias_instability == pytest.approx(0.003 * DPH)
    assert sp.accel_bias_instability == pytest.approx(30.0 * UG)
    assert sp.bias_correlation_time == 300.0
    assert config_from_params(v).specs == sp
    assert check_param("bias_correlation_time", 0.0) is not None
    assert check_param("bias_correlation_time", -1.0) is None
    assert check_param("accel_bias_instability", -2.0) is not None
    v.update(gyro_warmup=0.03, accel_warmup=300.0, warmup_time=120.0)
    sp = sensor_specs(v)
    assert (sp.gyro_warmup, sp.accel_warmup, sp.warmup_time) == pytest.approx(
        (0.03 * DPH, 300.0 * UG, 120.0))
    assert check_param("warmup_time", 0.0) is not None
    v.update(grade="", gyro_bias=0.01, gyro_arw=0.001, accel_bias=100.0, accel_vrw=10.0)
    sp = sensor_specs(v)                         # no grade: the four and the extras
    assert sp.accel_bias_instability == pytest.approx(30.0 * UG) and sp.warmup_time == 120.0
    with pytest.raises(ValueError):
        sensor_specs({**v, "gyro_arw": -1.0})    # the four are still required


# ------------------------------------------------------------------ in motion
def test_in_motion_warm_up_covered_by_the_configured_instability():
    """car_city, consumer MEMS (the in-motion benchmark's), node defaults: a warm-up of 3x
    the biases settling over 300 s, configured as an instability of 3x at tau 300 s. The
    bias states started from the turn-on bias's variance alone (the wander's value at the
    start left out): 4.0 % of the instants beyond 3 sigma, 20 flagged aligned while wrong;
    now started from both."""
    from sins_align.core.specs import DPH, DPSH, UG_PSHZ, SensorSpecs, UG

    sp = SensorSpecs(gyro_bias=10.0 * DPH, gyro_arw=0.3 * DPSH, accel_bias=1000 * UG,
                     accel_vrw=100 * UG_PSHZ)
    tr = car_city()
    r = simulate_trajectory(tr, 100.0, sp.with_(gyro_warmup=3.0 * sp.gyro_bias,
                                                accel_warmup=3.0 * sp.accel_bias,
                                                warmup_time=300.0),
                            seed=2, gnss_rate=10.0, gnss_sigma=0.05)
    configured = sp.with_(gyro_bias_instability=3.0 * sp.gyro_bias,
                          accel_bias_instability=3.0 * sp.accel_bias,
                          bias_correlation_time=300.0)
    _motion_honest(tr, r, configured)


def test_in_motion_warm_up_in_the_specs_is_covered():
    """The same warm-up given as such in the specs (simulated and configured): ignored
    before (4.0 % beyond 3 sigma, 20 aligned while wrong on this run; 36-43 % on seeds 0-2
    at 3x over 60-300 s), now one more wander."""
    from sins_align.core.specs import DPH, DPSH, UG_PSHZ, SensorSpecs, UG

    sp = SensorSpecs(gyro_bias=10.0 * DPH, gyro_arw=0.3 * DPSH, accel_bias=1000 * UG,
                     accel_vrw=100 * UG_PSHZ, gyro_warmup=30.0 * DPH,
                     accel_warmup=3000.0 * UG, warmup_time=300.0)
    tr = car_city()
    r = simulate_trajectory(tr, 100.0, sp, seed=2, gnss_rate=10.0, gnss_sigma=0.05)
    _motion_honest(tr, r, sp)


def _motion_honest(tr, r, specs):
    from sins_align.core.rotation import attitude_error
    from sins_align.estimators.in_motion import MotionAligner, MotionConfig

    cfg = MotionConfig(latitude_deg=tr.lat_deg, longitude_deg=tr.lon_deg,
                       height_m=tr.height_m, initial_heading_std_deg=180.0,
                       velocity_noise=0.05, vehicle="ground", nhc_axis=1,
                       lever_arm_std=1.0, velocity_latency_std=0.1, specs=specs)
    al = MotionAligner(cfg)
    for tg, vg in zip(r.gnss_t, r.gnss_v):
        al.add_velocity(tg, vg)
    over, wrong, n = 0, 0, len(r.gyro)
    for k in range(0, n, 10):
        e = min(k + 10, n)
        al.update(r.t[k + 1:e + 1], r.gyro[k:e], r.accel[k:e])
        if al.initialized:
            z = np.abs(attitude_error(r.C[e], al.dcm)) / np.sqrt(np.diag(al.covariance))
            over += bool(np.any(z > 3.0))
            wrong += bool(np.any(z > 3.0)) and al.aligned
    assert wrong == 0 and over <= 0.01 * (n // 10), (over, wrong)
    assert al.time_to_aligned is not None


# ------------------------------------------------------------------ in motion: the specs check
@pytest.mark.parametrize("seed", [1, 2])
def test_in_motion_specs_check_counts_a_configured_warm_up(seed):
    """car_city's MEMS (10 deg/h, 1 mg) with a warm-up of 3x its biases over 300 s,
    simulated and configured alike: the bias states start from the bias, instability and
    warm-up variances together, and the specs check measures the estimates in that prior's
    std. Measured in the turn-on bias's std alone, seeds 1 and 2 reached 6.0 and 5.3 (the
    accelerometer's) and were called worse than their specs: the attitude published as
    unknown, never aligned at the end, for an IMU that fits its configured specs."""
    from sins_align.core.specs import DPH, DPSH, UG, UG_PSHZ, SensorSpecs
    from sins_align.estimators.in_motion import MotionAligner, MotionConfig

    mems = SensorSpecs(gyro_bias=10.0 * DPH, gyro_arw=0.3 * DPSH, accel_bias=1000 * UG,
                       accel_vrw=100 * UG_PSHZ)
    sp = mems.with_(gyro_warmup=3.0 * mems.gyro_bias, accel_warmup=3.0 * mems.accel_bias,
                    warmup_time=300.0)
    tr = car_city()
    r = simulate_trajectory(tr, 100.0, sp, seed=seed, gnss_rate=10.0, gnss_sigma=0.05)
    cfg = MotionConfig(latitude_deg=tr.lat_deg, longitude_deg=tr.lon_deg, height_m=tr.height_m,
                       specs=sp, initial_heading_std_deg=180.0, velocity_noise=0.05,
                       vehicle="ground", nhc_axis=1, lever_arm_std=1.0,
                       velocity_latency_std=0.1)
    al = MotionAligner(cfg)
    for tg, vg in zip(r.gnss_t, r.gnss_v):
        al.add_velocity(tg, vg)
    n = len(r.gyro)
    for k in range(0, n, 10):
        e = min(k + 10, n)
        al.update(r.t[k + 1:e + 1], r.gyro[k:e], r.accel[k:e])
    assert al.specs_consistent and al.aligned, al.bias_spec_ratio
    # (the biases were found: their estimates of the order of the prior's std)
    assert 1.0 < max(al.bias_spec_ratio) < 5.0, al.bias_spec_ratio
