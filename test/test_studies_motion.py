"""Seed 003's baselines (conventional EKF, UKF on the same errors) and the ``seed003`` and
``feedback`` studies on short runs."""
import json

import numpy as np
import pytest

from sins_align.core.rotation import attitude_error, dcm_from_rpy
from sins_align.core.specs import DEG
from sins_align.estimators.baselines.velocity_aided import (NavBatch, apply_error,
                                                            error_model_F, nav_step,
                                                            state_error)
from sins_align.estimators.in_motion import MotionConfig
from sins_align.estimators.in_motion.feedback import FractionalFeedback
from study_helpers import assert_filter_schema

from sins_align.studies import STUDIES, seed003, summary_text


def test_ekf_transition_matches_finite_differences():
    """Phi = prod (I + F dt) over 10 samples equals the Jacobian of the nonlinear error
    propagation (both states mechanized with the same raw samples, each with its own bias
    estimates), to the first-order discretisation's accuracy."""
    rng = np.random.default_rng(1)
    true = NavBatch(dcm_from_rpy(np.array([0.1, -0.2, 1.0]))[None], [[5.0, -3.0, 1.0]], [0.5],
                    [1.9], [60.0], [[1e-4, -2e-4, 5e-5]], [[1e-3, 2e-3, -1e-3]])
    m, dt = 10, 0.01
    gyro = np.array([0.1, -0.05, 0.2]) + true.bg + rng.normal(0, 0.01, (1, m, 3))
    acc = np.array([1.0, 0.5, 9.8]) + true.ba + rng.normal(0, 0.1, (1, m, 3))

    def prop(s):
        for j in range(m):
            s = nav_step(s, dt, gyro[:, j], acc[:, j])
        return s

    end = prop(true.copy())
    Phi = np.eye(15)
    s = true.copy()
    for j in range(m):
        Phi = Phi + dt * error_model_F(s, gyro[:, j], acc[:, j])[0] @ Phi
        s = nav_step(s, dt, gyro[:, j], acc[:, j])
    scale = np.array([1e-5] * 3 + [1e-3] * 3 + [1.0] * 3 + [1e-6] * 3 + [1e-4] * 3)
    J = np.zeros((15, 15))
    for i in range(15):
        d = np.zeros(15)
        d[i] = scale[i]
        # the estimate whose error against the truth is +-d
        np.testing.assert_allclose(state_error(apply_error(true, -d), true)[0], d,
                                   atol=1e-9 * scale[i])
        J[:, i] = (state_error(prop(apply_error(true, -d)), end)[0]
                   - state_error(prop(apply_error(true, d)), end)[0]) / (2 * scale[i])
    # in the units of the perturbations: every entry within 2e-5 of the largest (1)
    err = np.abs(J - Phi) * scale[None, :] / scale[:, None]
    assert err.max() < 2e-5, np.unravel_index(err.argmax(), err.shape)
    # the heading-from-specific-force coupling is there and right
    assert abs(Phi[3, 2]) > 1e-3


@pytest.fixture(scope="module")
def short_data():
    return seed003.simulate_runs([0], 60.0)


def test_ukf_equals_ekf_near_linear(short_data):
    """From a 0.05 deg misalignment (told as much) the model is linear to within noise: the
    UKF and the EKF give the same attitude and covariance."""
    err = (0.05, 0.05, 0.1)
    d = {k: (v[:, :3001] if k in ("gyro", "accel") else v) for k, v in short_data.items()}
    d["gnss_index"] = short_data["gnss_index"][:301]
    d["gnss_v"] = short_data["gnss_v"][:, :301]
    _, Ce, Pe, _ = seed003.run_filter("ekf", d, err)
    _, Cu, Pu, _ = seed003.run_filter("ukf", d, err)
    diff = attitude_error(Ce[-1], Cu[-1]) / DEG
    assert np.abs(diff).max() < 2e-3, diff
    se, su = np.sqrt(np.diagonal(Pe[-1, 0])), np.sqrt(np.diagonal(Pu[-1, 0]))
    np.testing.assert_allclose(su, se, rtol=0.03)


def test_seed003_short_study_schema():
    res = STUDIES["seed003"](runs=1, duration=60.0, cases=("3_4_45",))
    assert res["study"] == "seed003" and res["axes"] == ["E", "N", "U"]
    fl = res["cases"]["3_4_45"]["filters"]
    assert set(fl) == set(seed003.FILTERS)
    assert_filter_schema(fl, 60)
    for name, r in fl.items():
        # 45 deg off, one minute of flight with the climb and the first leg: every filter
        # has the heading within a few degrees and level within 0.5 deg
        assert abs(r["final_yaw_error_deg"][0]) < 5.0, (name, r["final_yaw_error_deg"])
        assert max(r["final_error_deg"]["rmse"][:2]) < 0.5, name
    assert fl["ours"]["time_to_heading_s"] is not None
    json.dumps(res, allow_nan=False)
    assert "ours" in summary_text(res)


def test_feedback_fraction_option():
    assert MotionConfig(latitude_deg=30.0, feedback="fraction",
                        feedback_fraction=0.2).feedback_fraction == 0.2
    with pytest.raises(ValueError):
        MotionConfig(latitude_deg=30.0, feedback="fraction", feedback_fraction=0.0)
    G = FractionalFeedback(12, 0.3)(0.1)
    np.testing.assert_allclose(G, 0.3 * np.eye(12))


def test_feedback_short_study():
    res = STUDIES["feedback"](runs=1, duration=40.0, cases=("guess_25",),
                              variants=("full", "frac50"))
    fl = res["cases"]["guess_25"]["filters"]
    for v, r in fl.items():
        assert r["config"]["feedback"] in ("full", "fraction")
        assert np.isfinite(r["overshoot_heading_deg"]["max"])
        assert abs(r["final_yaw_error_deg"][0]) < 5.0, (v, r["final_yaw_error_deg"])
    json.dumps(res, allow_nan=False)
    assert "frac50" in summary_text(res)
