"""IMU stamps that jitter (receipt-time stamps) in the quasi-static Aligner: each sample is
integrated over the interval of a steady clock fitted to the stamps (core/clock.py), on the
per-sample path and the block path alike, not over its stamps' difference. On main (these
tests' draws), the honesty matrix's ``car_vib_hi`` (navigation grade, 300 s) with stamps
+-10 % of the interval was beyond 3 sigma at 15 / 22 % of its published states (seeds 0,
1; clean 0 %), at +-40 % its heading std 11 x the clean one, ``ang_x_1Hz_1deg`` +-40 % 2 %
beyond, and a stream received 1 ms late on average (in order) made the block path raise
(intervals beyond the fast path's 40 %): 7 of these 10 tests fail there (the block path's
equality held where it did not raise, and ``car_loss_1pct`` +-20 % passed)."""
import dataclasses

import numpy as np
import pytest

from sins_align.core.rotation import attitude_error
from sins_align.estimators.quasi_static.aligner import AlignConfig, Aligner
from sins_align.sim.honesty import CASES, RATE_HZ, T0, run_case
from sins_align.sim.simulator import simulate

T = 1.0 / RATE_HZ


def _errors(model, n, seed):
    """Stamp errors (s) of samples 0..n-1: uniform +-N % (uN), Gaussian sigma N % (gN)."""
    rng = np.random.default_rng(100 + seed)
    p = float(model[1:]) / 100.0
    if model[0] == "u":
        return rng.uniform(-p, p, n) * T
    return rng.normal(0.0, p, n) * T


def _jittering(model, seed, n=100_000):
    """An Aligner factory whose stamps are the simulated ones jittered (each sample's error
    drawn by its index on the true 100 Hz grid; ``dN``: received N ms late on average,
    exponential, in order)."""
    e = (np.random.default_rng(200 + seed).exponential(float(model[1:]) * 1e-3, n)
         if model[0] == "d" else _errors(model, n, seed))

    class Jittering(Aligner):
        _last = -np.inf

        def update(self, stamp, gyro, accel):
            one = np.ndim(stamp) == 0
            t = np.atleast_1d(np.asarray(stamp, dtype=float))
            s = t + e[np.rint((t - T0) * RATE_HZ).astype(np.int64)]
            if model[0] == "d":
                for i in range(len(s)):
                    s[i] = self._last = max(s[i], self._last + 1e-6)
            return super().update(float(s[0]) if one else s, gyro, accel)

    return Jittering


@pytest.mark.parametrize("case,model,seed,std_ratio", [
    ("car_vib_hi", "u10", 0, 1.5), ("car_vib_hi", "u10", 1, 1.5), ("car_vib_hi", "u40", 0, 1.5),
    ("car_vib_hi", "d1", 0, 1.5), ("ang_x_1Hz_1deg", "u40", 0, 1.5),
    ("car_loss_1pct", "u20", 0, 2.0)])
def test_jittering_stamps_stay_honest(case, model, seed, std_ratio):
    """The published attitude covers the error under jittering stamps as on clean ones
    (none of the published states beyond 3 sigma, never aligned while beyond), with the
    accuracy of the clean stream (heading std within 1.5 x; with lost samples 2 x: a
    hole's bridge under jitter is budgeted over one interval more, measured 1.84 x)."""
    clean = run_case(case, seed=seed)
    r = run_case(case, seed=seed, aligner_factory=_jittering(model, seed))
    assert r["frac_over_3sigma"] == 0.0, r["frac_over_3sigma"]
    assert r["aligned_wrong"] == 0
    assert r["final_std_deg"][2] <= std_ratio * clean["final_std_deg"][2]
    assert r["final_aligned"] == clean["final_aligned"]


@pytest.mark.parametrize("model", ["u40", "g20"])
def test_a_roll_tone_with_jittering_stamps_stays_honest(model):
    """``ang_x_1Hz_1deg`` (navigation grade, a 6 deg/s roll at 1 Hz), seed 1, 200 s: none
    of the published states beyond 3 sigma, never aligned while beyond; +-40 % as accurate
    as the clean stream (heading std within 1.5 x, aligned at the end). Before (the count
    decided stamp by stamp against a free 1 s line, the instants drawn to the 30 s line over
    8 intervals), on these draws: +-40 % 19 % beyond, 38 states aligned while beyond (the
    instants' error at 1 Hz, or a slipped count, times the roll read as an east gyro bias:
    the heading off); Gaussian 20 % 6.5 %, 6 aligned while beyond. With Gaussian stamps 6
    samples are rejected as stamped backwards (a hole each, under the roll: the run is
    aligned later than the clean one, 138 s against 60 s, not checked here)."""
    case = dataclasses.replace(CASES["ang_x_1Hz_1deg"], duration=200.0)
    r = run_case(case, seed=1, aligner_factory=_jittering(model, 1))
    assert r["frac_over_3sigma"] == 0.0, r["frac_over_3sigma"]
    assert r["aligned_wrong"] == 0
    if model[0] == "u":
        clean = run_case(case, seed=1)
        assert r["final_std_deg"][2] <= 1.5 * clean["final_std_deg"][2]
        assert r["final_aligned"] and clean["final_aligned"]


def _stream(model, seed=4, lost=0.01, duration=120.0):
    s = simulate(duration, RATE_HZ, 34.0, rpy_deg=(1.0, -2.0, 40.0), sway="car", seed=seed)
    n = len(s.t)
    keep = np.random.default_rng(seed).random(n) >= lost
    keep[:50] = True
    t = s.t + 100.0
    if model[0] == "d":
        t = t + np.random.default_rng(seed).exponential(float(model[1:]) * 1e-3, n)
        t = np.maximum.accumulate(t + np.arange(n) * 1e-9)
    else:
        t = t + _errors(model, n, seed)
    t, w, f = t[keep], s.gyro[keep], s.accel[keep]
    return t, w, f


def _one_by_one(cfg, t, w, f):
    al = Aligner(cfg)
    n = len(t)
    C, P, flags = np.empty((n, 3, 3)), np.empty((n, 3, 3)), np.empty(n, bool)
    for i in range(n):
        al.update(float(t[i]), w[i], f[i])
        C[i], P[i], flags[i] = al.dcm, al.covariance, al.aligned
    return al, C, P, flags


@pytest.mark.parametrize("model", ["u40", "g20", "d1"])
def test_block_path_equals_one_by_one_with_jittering_stamps(model):
    """Jittering stamps with 1 % of the samples lost: the block path (update on blocks,
    update_states) gives what the per-sample path gives, to the fast path's rounding (as
    on clean stamps, test_update_states), with the same counts; the stamps are jittering
    (the clock replaced them). On main the 1 ms delays made the block path raise."""
    t, w, f = _stream(model)
    cfg = AlignConfig(latitude_deg=34.0, backtrack_time=40.0)
    ref, C, P, flags = _one_by_one(cfg, t, w, f)
    assert ref.stage == "fine"
    for chunk in (len(t), 997):
        al = Aligner(cfg)
        for k in range(0, len(t), chunk):
            al.update(t[k:k + chunk], w[k:k + chunk], f[k:k + chunk])
        assert np.abs(attitude_error(ref.dcm, al.dcm)).max() < 1e-9
        assert np.abs(ref.covariance - al.covariance).max() < 1e-8 * np.abs(P[-1]).max()
        assert al.aligned == ref.aligned and al.samples_used == ref.samples_used
        assert al.rejected == ref.rejected and al.events == ref.events
        al = Aligner(cfg)
        parts = [al.update_states(t[k:k + chunk], w[k:k + chunk], f[k:k + chunk])
                 for k in range(0, len(t), chunk)]
        err = np.abs(attitude_error(C, np.concatenate([p.dcm for p in parts]))).max()
        assert err < 1e-9, err
        cov = np.concatenate([p.covariance for p in parts])
        rel = (np.abs(P - cov).max(axis=(1, 2)) / np.abs(P).max(axis=(1, 2))).max()
        assert rel < 1e-8, rel
        assert np.array_equal(np.concatenate([p.aligned for p in parts]), flags)
        assert al.rejected == ref.rejected and al.events == ref.events


def test_clean_stamps_with_lost_samples_untouched():
    """Stamps on the IMU's own clock (epoch stamps, 1 % lost): each sample's interval is its
    stamps' difference, bit for bit: the same state as a stream whose holes are given as
    such (the equality tests of the fast path and of the node against the replay hold as
    they were)."""
    t, w, f = _stream("u0")
    cfg = AlignConfig(latitude_deg=34.0, backtrack_time=40.0)
    a, b = Aligner(cfg), Aligner(cfg)
    a.update(t + 1.7e9, w, f)
    for i in range(len(t)):
        b.update(float(t[i] + 1.7e9), w[i], f[i])
    assert a.events["missing_samples"] > 0 and a.rejected == b.rejected == {}
    assert np.abs(attitude_error(a.dcm, b.dcm)).max() < 1e-9
    for al in (a, b):
        assert not al.stamp_clock.jittering and al.stamp_clock.rms == 0.0
    j, _, _ = _stream("u10")
    c = Aligner(cfg)
    c.update(j[:3000], w[:3000], f[:3000])
    assert c.stamp_clock.jittering and 0.0 < c.stamp_clock.rms < T
