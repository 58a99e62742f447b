"""The attitude jitter of a vibrating IMU (in-motion honesty): the monitor's measurement
against known signals, its stream invariance, and a rotor UAV whose published attitude
covariance covers its error only with the jitter in it."""
import math

import numpy as np
import pytest

from sins_align.core.rotation import attitude_error
from sins_align.core.specs import DEG, DPSH
from sins_align.estimators.in_motion import MotionAligner, MotionConfig
from sins_align.estimators.in_motion.jitter import JitterMonitor
from sins_align.sim.trajectory import (SEED003_SPECS, UAV_VIBRATION, Vibration,
                                       simulate_trajectory, uav_seed003)

RATE = 100.0


def _stamps(seconds, rate=RATE, jitter=0.0, seed=0):
    n = int(seconds * rate)
    t = np.arange(1, n + 1) / rate
    if jitter:
        t = t + np.random.default_rng(seed).uniform(-jitter, jitter, n) / rate
    return t


def _tone_rates(t, amp, freq, axis=0):
    """Interval means of amp sin(2 pi f t) over each sample's interval (as an IMU gives)."""
    dt = np.diff(np.concatenate(([0.0], t)))
    w = np.zeros((len(t), 3))
    w[:, axis] = (amp / (2 * math.pi * freq) * (np.cos(2 * math.pi * freq * (t - dt))
                                                - np.cos(2 * math.pi * freq * t))) / dt
    return w


def test_a_tone_gives_the_rms_of_its_angle():
    """A 2 deg/s tone at 30 Hz and at 70 Hz (aliased to 30 Hz at 100 Hz): the angle it puts
    on the integrated attitude has an RMS of amp / (2 pi f sqrt 2) at the sample instants."""
    t = _stamps(10.0, jitter=0.2)
    for freq in (30.0, 70.0, 12.0):
        m = JitterMonitor()
        amp = 2.0 * DEG
        m.add(t, _tone_rates(t, amp, freq, axis=1))
        expected = amp / (2 * math.pi * freq) / math.sqrt(2.0)
        got = math.sqrt(m.covariance[1, 1])
        assert abs(got / expected - 1.0) < 0.1, (freq, got / expected)
        assert m.covariance[0, 0] < 1e-6 * m.covariance[1, 1]


def test_white_noise_and_manoeuvres_add_little():
    """A 0.1 deg/sqrt(h) gyro's white noise adds < 0.0005 deg; a yaw turn ramping to 30 deg/s
    in 0.5 s and back, a +-10 deg roll at 0.5 Hz or a 1 deg one at 2 Hz leak < 0.005 deg
    through the window's taper at any time (the vibration of interest is 0.008 deg)."""
    t = _stamps(20.0)
    rng = np.random.default_rng(3)
    zero = np.zeros_like(t)
    ramp = 30 * DEG * np.clip((t - 5.0) / 0.5, 0.0, 1.0) * np.clip((12.5 - t) / 0.5, 0.0, 1.0)
    cases = {
        "noise": (rng.normal(0.0, 0.1 * DPSH * math.sqrt(RATE), (len(t), 3)), 0.0005),
        "turn": (np.column_stack([zero, zero, ramp]), 0.005),
        "roll": (np.column_stack([10 * DEG * math.pi * np.cos(math.pi * t), zero, zero]), 0.005),
        "roll 2 Hz": (np.column_stack([4 * math.pi * DEG * np.cos(4 * math.pi * t), zero, zero]),
                      0.005),
    }
    for name, (w, bound) in cases.items():
        m = JitterMonitor()
        worst = np.zeros(3)
        for k in range(0, len(t), 10):
            m.add(t[k:k + 10], w[k:k + 10])
            worst = np.maximum(worst, np.diag(m.covariance))
        assert np.sqrt(worst).max() / DEG < bound, (name, np.sqrt(worst) / DEG)


def test_blocks_and_one_by_one_give_the_same_jitter():
    t = _stamps(7.3, jitter=0.3, seed=2)
    w = _tone_rates(t, 3 * DEG, 40.0, axis=0) + _tone_rates(t, 1 * DEG, 25.0, axis=2)
    a, b = JitterMonitor(), JitterMonitor()
    a.add(t, w)
    seen = []
    for k in range(len(t)):
        b.add(t[k:k + 1], w[k:k + 1])
        seen.append(b.covariance.copy())
    np.testing.assert_array_equal(a.covariance, b.covariance)
    c = JitterMonitor()
    for k in range(0, len(t), 37):
        c.add(t[k:k + 37], w[k:k + 37])
        np.testing.assert_array_equal(c.covariance, seen[min(k + 37, len(t)) - 1])
    # the first window's figure appears once it is complete (1 s of stamps)
    assert not seen[50].any() and seen[-1].any()


def _vibrating_uav(seed, seconds=120.0, vibration=UAV_VIBRATION):
    traj = uav_seed003()
    r = simulate_trajectory(traj, RATE, SEED003_SPECS, seed=seed, gnss_rate=10.0,
                            gnss_sigma=0.05, vibration=vibration, duration=seconds)
    al = MotionAligner(MotionConfig(latitude_deg=traj.lat_deg, longitude_deg=traj.lon_deg,
                                    height_m=traj.height_m, specs=SEED003_SPECS,
                                    velocity_noise=0.05))
    for tg, vg in zip(r.gnss_t, r.gnss_v):
        al.add_velocity(tg, vg)
    with_j, without_j, jit = [], [], []
    for k in range(0, len(r.gyro), 10):
        al.update(r.t[k + 1:k + 11], r.gyro[k:k + 10], r.accel[k:k + 10])
        j = min(k + 10, len(r.gyro))
        if al.hypotheses == 1:
            e = np.abs(attitude_error(r.C[j], al.dcm))
            P = al.covariance
            J = al.dcm @ al.jitter_covariance @ al.dcm.T
            with_j.append(e / np.sqrt(np.diag(P)))
            without_j.append(e / np.sqrt(np.diag(P - J)))
            jit.append(np.sqrt(np.diag(J)))
    return np.array(with_j), np.array(without_j), np.array(jit)


#: rotor vibration of the gyro alone (2 deg/s RMS at 20-80 Hz, three tones per axis)
GYRO_VIBRATION = Vibration(accel_rms=0.0, gyro_rms=2.0 * DEG, band=(20.0, 80.0), tones=3)
#: ... and of the accelerometer alone (3 m/s^2 RMS)
ACCEL_VIBRATION = Vibration(accel_rms=3.0, gyro_rms=0.0, band=(20.0, 80.0), tones=3)


def test_vibrating_gyro_is_honest_with_the_jitter_and_not_without():
    """Seed 003's UAV with strong rotor vibration on the gyro, the filter told nothing of
    it: the published covariance (filter + jitter) covers the attitude error; the filter's
    covariance alone does not (the test's teeth). Measured: 0.1 / 2.3 / 0.1 % of instants
    beyond 3 sigma for seeds 0-2 (the filter alone: 2.2 / 10.4 / 11.8 %); an honest filter
    without vibration shows ~0.9 % on this flight (bench_in_motion, 16 seeds)."""
    ours, bare, jit = [], [], []
    for seed in (0, 1, 2):
        a, b, j = _vibrating_uav(seed, vibration=GYRO_VIBRATION)
        ours.append(a)
        bare.append(b)
        jit.append(j)
    ours, bare, jit = (np.concatenate(x) for x in (ours, bare, jit))
    over = (ours > 3.0).any(axis=1).mean()
    over_bare = (bare > 3.0).any(axis=1).mean()
    assert over <= 0.015 and over <= over_bare / 5.0 and ours.max() < 4.5, (
        over, over_bare, ours.max(axis=0))
    # the jitter it publishes is the vibration's angle: 0.005-0.015 deg per level axis
    lvl = np.median(jit[:, :2], axis=0) / DEG
    assert np.all((lvl > 0.004) & (lvl < 0.02)), lvl


@pytest.mark.xfail(strict=True, reason="accelerometer vibration: the IMU velocity's jitter "
                   "(~0.012 m/s), sampled by the 10 Hz velocity updates, aliases to slow "
                   "errors the filter takes for tilt (seed 1: 0.04 deg of north level)")
def test_vibrating_accelerometer_is_honest():
    a, _, _ = _vibrating_uav(1, vibration=ACCEL_VIBRATION)
    over = (a > 3.0).any(axis=1).mean()
    assert over <= 0.015, over
