"""The comparison studies (sins_align.studies) and ``montecarlo --study``: a short seed004
run gives the JSON schema of issue 13 and sane numbers."""
import json

import numpy as np
import pytest

from study_helpers import assert_filter_schema

from sins_align.studies import STUDIES, seed004, summary_text
from sins_align.tools.montecarlo import main as montecarlo_main


@pytest.fixture(scope="module")
def short_run():
    return STUDIES["seed004"](runs=2, duration=240.0, particles=40, cases=("clean",))


def test_seed004_schema(short_run):
    res = short_run
    assert res["study"] == "seed004" and res["axes"] == ["E", "N", "U"]
    fl = res["cases"]["clean"]["filters"]
    assert set(fl) == {"ours", "ukf", "upf", "aupf"}
    assert_filter_schema(fl, 240)
    assert res["paper"]["clean"]["aupf"]["mean_pitch_roll_heading_deg"][2] == -0.8609
    json.dumps(res, allow_nan=False)
    assert "ours" in summary_text(res)


def test_seed004_every_filter_converges(short_run):
    """From 30 deg of heading error, in 240 s: every filter is within a few degrees of
    heading and 0.2 deg of level; ours and the UKF near the limit (0.04 deg heading)."""
    fl = short_run["cases"]["clean"]["filters"]
    for name, r in fl.items():
        rmse = r["final_error_deg"]["rmse"]
        assert rmse[2] < 3.0, (name, rmse)
        assert max(rmse[:2]) < 0.2, (name, rmse)
        assert r["time_to_heading_s"] is not None, name
    assert fl["ours"]["final_error_deg"]["rmse"][2] < 0.15
    assert fl["ukf"]["final_error_deg"]["rmse"][2] < 0.3


def test_seed004_noise_case_adds_the_mean_to_the_limit():
    data = seed004.simulate_case("noise_si", [0], 30.0)
    clean = seed004.simulate_case("clean", [0], 30.0)
    # 2 mg more on every axis: the accelerometer mean shows it, the limit level error too
    d = (data["accel"] - clean["accel"]).mean(axis=0)[0]
    np.testing.assert_allclose(d, 0.02, atol=0.01)   # 3000 samples of std 0.14
    assert abs(data["limit"][0, 0] - clean["limit"][0, 0]) > 1e-3    # ~0.02 / g rad


def test_montecarlo_study_cli(tmp_path, capsys):
    out = tmp_path / "s.json"
    assert montecarlo_main(["--study", "seed004", "--runs", "1", "--duration", "30",
                            "--json", str(out), "--quiet"]) == 0
    res = json.loads(out.read_text())
    assert set(res["cases"]) == {"clean", "noise_mg", "noise_si"}
    assert res["scenario"]["duration_s"] == 30.0
    assert montecarlo_main(["--study", "nope", "--quiet"]) != 0
    assert "unknown study" in capsys.readouterr().err
