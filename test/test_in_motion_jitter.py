"""The attitude jitter of a vibrating IMU (in-motion honesty): the monitor's measurement
against known signals, its stream invariance, and a rotor UAV whose published attitude
covariance covers its error only with the jitter in it."""
import math

import numpy as np
import pytest

from sins_align.core.rotation import attitude_error, skew, so3_exp
from sins_align.core.specs import DEG, DPSH
from sins_align.estimators.in_motion import MotionAligner, MotionConfig
from sins_align.core.strapdown import NavState
from sins_align.estimators.in_motion.filter import (IBA, IBG, INU, IPHI, InvariantEKF,
                                                    NoiseModel, sample_transition)
from sins_align.estimators.in_motion.jitter import JitterMonitor, VelocityJitter, fit_tones
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


def _vibrating_uav(seed, seconds=120.0, vibration=UAV_VIBRATION, clean=False, **cfg):
    """(e / sigma with the jitter, without it, the jitter's std) at every 0.1 s once the
    heading is acquired; ``clean``: the same run with the accelerometer's vibration taken
    out of the samples (every other error drawn the same)."""
    traj = uav_seed003()
    r = simulate_trajectory(traj, RATE, SEED003_SPECS, seed=seed, gnss_rate=10.0,
                            gnss_sigma=0.05, vibration=vibration, duration=seconds)
    if clean:
        r.accel = r.accel - (1.0 + r.accel_scale) * r.accel_vibration
    al = MotionAligner(MotionConfig(latitude_deg=traj.lat_deg, longitude_deg=traj.lon_deg,
                                    height_m=traj.height_m, specs=SEED003_SPECS,
                                    velocity_noise=0.05, **cfg))
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


@pytest.mark.xfail(strict=True, reason="not the vibration: seed 1 is beyond 3 sigma 4.8 % of "
                   "the time with the accelerometer's vibration taken out of the samples too "
                   "(3.7 % with it, corrected; 6.5 % uncorrected): north level near 35-40 s "
                   "and 65-85 s, cause open (its y accelerometer bias is a 2.7-sigma draw)")
def test_vibrating_accelerometer_is_honest():
    a, _, _ = _vibrating_uav(1, vibration=ACCEL_VIBRATION)
    over = (a > 3.0).any(axis=1).mean()
    assert over <= 0.015, over


def _accel_tone(t, amp, freq, axis=0):
    f = _tone_rates(t, amp, freq, axis)
    f[:, 2] += 9.8
    return f


def test_velocity_jitter_of_a_tone():
    """A 2 m/s^2 tone on the x accelerometer (interval means, as an IMU gives): the IMU
    velocity jitters by J = -amp / (2 pi f) cos(2 pi f t). The jitter at each sample (the
    velocity less its straight line over T = 0.1 s) leaves at most 40 % of J's amplitude
    for every tone of 15-80 Hz, whatever its frequency against 10 Hz: tones halfway
    between two multiples (25, 45 Hz), which the ends'-mean form left whole, included;
    the least is left of the fastest (a line over 0.1 s spans 2-8 of their cycles). The
    sign counts: reversed, 2 J would be left. With stamps jittered by +-20 % of the
    interval what is left stays below 80 %. Nothing on the other axes; the mean specific
    force is gravity (within the two ends' jitter over T). Real motion: a 1 Hz motion
    loses at most 4 % of its velocity swing ((2 pi f T)^2 / 12 = 3.3 %), 2 Hz 13 %."""
    T = 0.1
    halfway = {}
    for jitter, worst in ((0.0, 0.40), (0.2, 0.80)):
        for freq in (15.0, 20.3, 25.0, 33.3, 40.2, 45.0, 79.7, 1.0, 2.0):
            t = _stamps(5.0, jitter=jitter, seed=1)
            slow = freq <= 2.0
            amp_f = 1.0 if slow else 2.0
            f = _accel_tone(t, amp_f, freq)
            vj = VelocityJitter(1.0)
            vj.add(t[:100], f[:100])
            amp = amp_f / (2 * math.pi * freq)
            bound = {1.0: 0.04, 2.0: 0.14}.get(freq, worst)
            left = []
            for k in range(100, len(t)):
                vj.add(t[k:k + 1], f[k:k + 1])
                jit, f_mean = vj.at(t[k], T)
                J = 0.0 if slow else -amp * math.cos(2 * math.pi * freq * t[k])
                left.append(J - jit[0])
                assert abs(jit[1]) < 1e-9 and abs(jit[2]) < 1e-6
                assert np.abs(f_mean - [0.0, 0.0, 9.8]).max() < (
                    1.01 * amp_f if slow else 2.0 * amp / T + 0.01)
            left = np.abs(np.array(left)) / amp
            assert left.max() < bound, (freq, jitter, left.max(), bound)
            if not jitter and freq in (25.0, 45.0):
                halfway[freq] = left.max()
    # the fastest tones are the best taken out
    assert halfway[45.0] < 0.3 and halfway[25.0] < 0.3, halfway
    # no figure without two intervals before the sample, nor at a stamp it does not hold
    vj = VelocityJitter(1.0)
    vj.add(t[:2], f[:2])
    assert vj.at(t[1], T) is None and vj.at(t[1] + 1e-4, T) is None
    vj.add(t[2:3], f[2:3])
    assert vj.at(t[2], T) is not None


def test_velocity_jitter_equals_its_definition():
    """The closed form (one weight per sample interval) equals the definition: the
    integrated velocity at the sample less the least-squares straight line through the
    velocities at the samples from the one nearest to t - T to t (numpy's polyfit),
    evaluated at t; jittered stamps. The mean force is the velocity's change over the
    window's length."""
    t = _stamps(3.0, jitter=0.3, seed=7)
    rng = np.random.default_rng(7)
    f = rng.normal(0.0, 3.0, (len(t), 3)) + [0.0, 0.0, 9.8]
    vj = VelocityJitter(5.0)
    vj.add(t, f)
    for k in range(20, len(t), 13):
        for T in (0.05, 0.1, 0.23):
            i0 = int(np.argmin(np.abs(t[:k + 1] - (t[k] - T))))
            tw = t[i0:k + 1]
            V = np.concatenate([[np.zeros(3)], np.cumsum(f[i0 + 1:k + 1] * np.diff(tw)[:, None],
                                                         axis=0)])
            line = [np.polyval(np.polyfit(tw - tw[-1], V[:, c], 1), 0.0) for c in range(3)]
            jit, f_mean = vj.at(t[k], T)
            np.testing.assert_allclose(jit, V[-1] - line, rtol=0, atol=1e-12)
            np.testing.assert_allclose(f_mean, V[-1] / (tw[-1] - tw[0]), rtol=1e-13)


def test_velocity_jitter_blocks_and_one_by_one_agree():
    t = _stamps(4.0, jitter=0.3, seed=4)
    f = _accel_tone(t, 3.0, 47.0) + _accel_tone(t, 1.0, 23.0, axis=1) - [0, 0, 9.8]
    a, b = VelocityJitter(0.7 + 0.1 + 0.02), VelocityJitter(0.7 + 0.1 + 0.02)
    asked = 0
    for k in range(0, len(t), 37):
        a.add(t[k:k + 37], f[k:k + 37])
        for j in range(k, min(k + 37, len(t))):
            b.add(t[j:j + 1], f[j:j + 1])
        # questions about the samples of the last 0.7 s (a rewind goes back so far; keep:
        # that, the 0.1 s interval and a sample)
        e = min(k + 37, len(t))
        for j in range(int(np.searchsorted(t, t[e - 1] - 0.7)), e, 3):
            ra, rb = a.at(t[j], 0.1), b.at(t[j], 0.1)
            assert (ra is None) == (rb is None)
            if ra is not None:
                asked += 1
                np.testing.assert_array_equal(ra[0], rb[0])
                np.testing.assert_array_equal(ra[1], rb[1])
    assert asked > 100


def _over(runs):
    a = np.concatenate([r[0] for r in runs])
    return (a > 3.0).any(axis=1).mean()


def test_vibrating_accelerometer_is_as_honest_as_without_vibration(monkeypatch):
    """Seed 003's UAV with strong accelerometer vibration (3 m/s^2 RMS, 20-80 Hz): the
    velocity updates compare the reference with the IMU velocity less its jitter
    (VelocityJitter), and the attitude error is then beyond 3 sigma no more often than in
    the same runs with the vibration taken out of the samples (+0.5 %). The test's teeth:
    without the correction, or with its sign reversed, it is. Measured for seeds 0-2,
    pooled: 2.0 % corrected, 2.3 % without vibration, 3.3 % uncorrected; 16 seeds: 1.07 %,
    1.27 %, 1.77 %. (The 1.5 % of the test above is out of reach for seeds 0-2 without
    any vibration.) The teeth are measured with a bank of 12 heading hypotheses (the
    default until session 15): with the 24 of now the uncorrected runs of seeds 0-2 are
    2.6 % against 2.35 % clean, inside the margin, as the smaller spread of each hypothesis
    leaves less linearisation error for the vibration to add to."""
    seeds = (0, 1, 2)
    clean = _over([_vibrating_uav(s, vibration=ACCEL_VIBRATION, clean=True) for s in seeds])
    ours = _over([_vibrating_uav(s, vibration=ACCEL_VIBRATION) for s in seeds])
    assert ours <= clean + 0.005, (ours, clean)
    twelve = dict(heading_hypotheses=12)
    clean = _over([_vibrating_uav(s, vibration=ACCEL_VIBRATION, clean=True, **twelve)
                   for s in seeds])
    ours = _over([_vibrating_uav(s, vibration=ACCEL_VIBRATION, **twelve) for s in seeds])
    assert ours <= clean + 0.005, (ours, clean)
    at = VelocityJitter.at
    for name, patched in (("none", lambda self, t, T, nominal=None, tone=None: None),
                          ("reversed", lambda self, t, T, nominal=None, tone=None:
                           (lambda r: r and (-r[0], r[1]))(at(self, t, T, nominal, tone)))):
        monkeypatch.setattr(VelocityJitter, "at", patched)
        # (every update applied: the hold after a step in the reference's error catches
        # some of what the reversed correction does, 1.55 % against 2.44 % clean)
        bad = _over([_vibrating_uav(s, vibration=ACCEL_VIBRATION, step_hold=False, **twelve)
                     for s in seeds])
        assert bad > clean + 0.005, (name, bad, clean)
    monkeypatch.undo()


@pytest.mark.parametrize("K", [2, 1])
def test_excluding_the_jitter_is_the_transition_without_it(K):
    """InvariantEKF.exclude_velocity_jitter after a sample equals the sample's transition
    built with its velocity increment less the jitter's change d (in the sample's start
    axes; ``-(dV x)`` becomes ``-((dV - d) x)``): with no process noise and no bias
    uncertainty the two covariances agree to rounding, for a bank of two filters with
    different attitudes and for one filter (its own 2-D path), a fast rotation (so the
    frames differ) and a jitter carried from a
    previous update in ENU. It fails with the sign of d reversed or in the wrong axes."""
    rng = np.random.default_rng(3)
    n = 12
    A = rng.normal(size=(2, n, n))
    P0 = A @ np.swapaxes(A, 1, 2) * 1e-4
    P0[:, IBG, :] = P0[:, :, IBG] = P0[:, IBA, :] = P0[:, :, IBA] = 0.0
    Cs = np.array([so3_exp(rng.normal(size=3)) for _ in range(2)])
    noise = NoiseModel(0.0, 0.0, 0.0, 0.0)
    dt = 0.01
    gyro, accel = np.array([0.9, -2.1, 1.3]), np.array([3.0, -1.5, 9.6])
    ekf = InvariantEKF(NavState(Cs[0], np.zeros(3), 0.6, 0.2, 50.0), P0[:K], noise, C=Cs[:K])
    prev = np.array([0.004, -0.002, 0.003])                     # body, at the last update
    ekf.jitter_enu = Cs[:K] @ prev
    Phi = sample_transition(ekf, dt, gyro, accel)               # (the same for both)
    rho = so3_exp(gyro * dt)
    ekf.propagate(np.array([dt]), gyro[None], accel[None])
    now = np.array([-0.006, 0.005, 0.001])                      # body, now
    ekf.exclude_velocity_jitter(now)
    for k in range(K):
        d_now = now - ekf.C[k].T @ (Cs[k] @ prev)               # the change, body axes now
        Phi_d = Phi.copy()
        Phi_d[INU, IPHI] += rho.T @ skew(rho @ d_now)           # -(dV - d) x, start axes
        expect = Phi_d @ P0[k] @ Phi_d.T
        np.testing.assert_allclose(ekf.P[k], expect, rtol=0, atol=1e-12 * np.abs(expect).max())
    np.testing.assert_allclose(ekf.jitter_enu, ekf.C @ now, atol=1e-15)


def _early_heading(seed, seconds=30.0):
    """Mean (error / sigma)^2 per ENU axis over the first ``seconds`` of seed 003's UAV
    with the accelerometer's vibration (heading unknown: the bank of hypotheses runs)."""
    traj = uav_seed003()
    r = simulate_trajectory(traj, RATE, SEED003_SPECS, seed=seed, gnss_rate=10.0,
                            gnss_sigma=0.05, vibration=ACCEL_VIBRATION, duration=seconds)
    al = MotionAligner(MotionConfig(latitude_deg=traj.lat_deg, longitude_deg=traj.lon_deg,
                                    height_m=traj.height_m, specs=SEED003_SPECS,
                                    velocity_noise=0.05))
    for tg, vg in zip(r.gnss_t, r.gnss_v):
        al.add_velocity(tg, vg)
    z = []
    for k in range(0, len(r.gyro), 10):
        e = min(k + 10, len(r.gyro))
        al.update(r.t[k + 1:e + 1], r.gyro[k:e], r.accel[k:e])
        if al.initialized:
            z.append(attitude_error(r.C[e], al.dcm) ** 2 / np.diag(al.covariance))
    return np.mean(z, axis=0)


def test_heading_is_honest_while_the_bank_runs_under_accelerometer_vibration(monkeypatch):
    """Seed 003's UAV with 3 m/s^2 of accelerometer vibration, its first 30 s (hovering
    while the bank of heading hypotheses runs), seeds 0-7: the heading's mean (error /
    sigma)^2 stays within 1.6 (1 = honest; measured 1.20). The IMU velocity's jitter is
    taken out of the updates in full (the straight-line form of VelocityJitter) and out of
    the transition (InvariantEKF.exclude_velocity_jitter). Before (the ends'-mean form,
    in the updates only) it was 2.90; without any correction 5.66, which the test checks."""
    z = np.mean([_early_heading(s) for s in range(8)], axis=0)
    assert z[2] <= 1.6 and np.all(z[:2] <= 1.6), z
    monkeypatch.setattr(VelocityJitter, "at", lambda self, t, T, nominal=None, tone=None: None)
    bare = np.mean([_early_heading(s) for s in range(8)], axis=0)
    assert bare[2] > 2.0, bare


def test_a_tone_below_ten_hz_is_found_and_its_velocity_is_the_jitter():
    """jitter.fit_tones: a 5.3 Hz tone of 1.5 m/s^2 on one axis over a vehicle's motion (a
    cubic trend and a 1 Hz swing of 0.8 m/s^2) and white noise: found at its frequency, its
    value at the last sample within 3 % of the amplitude; VelocityJitter.at with it gives
    the tone's velocity at the sample within 5 % (beside what the line gives of the same
    samples without the tone: 3 % of the swing's velocity; the line alone leaves most of
    the tone's: over 80 % of its amplitude here). The other axes, the motion and the noise
    alone, have no tone; nor has a 1 Hz swing alone, and white noise seldom (0.8 % of the
    axes over 6000 draws; here of 100 draws of three axes, at most 5 with a tone)."""
    rng = np.random.default_rng(5)
    dt = 0.01
    t = np.arange(1, 301) * dt
    f0, amp, ph = 5.3, 1.5, 0.7
    mid = t - 0.5 * dt
    motion = 0.3 + 0.4 * mid - 0.05 * mid ** 2 + 0.8 * np.sin(2 * np.pi * 1.0 * mid)
    still = np.column_stack([motion, motion, 9.8 + 0.0 * mid]) \
        + rng.normal(0.0, 0.05, (len(t), 3))
    f = still.copy()
    f[:, 0] += amp * np.sin(2 * np.pi * f0 * mid + ph)
    w = rng.normal(0.0, 0.002, (len(t), 3))
    vj = VelocityJitter(5.0)
    vj.add(t, f, w)
    calm = VelocityJitter(5.0)          # the same without the tone: what the line leaves
    calm.add(t, still, w)               # of the motion and the noise
    tn = float(t[-1])
    ft, _ = vj.tones(tn)
    assert abs(ft.omega[0] / (2 * np.pi) - f0) <= 0.05, ft.omega / (2 * np.pi)
    assert not ft.omega[1:].any(), ft.omega
    true_now = amp * np.sin(2 * np.pi * f0 * (tn - 0.5 * dt) + ph)
    assert abs(ft.value([tn - 0.5 * dt])[0, 0] - true_now) < 0.03 * amp
    # the tone's velocity (zero mean) at the sample: the jitter
    true_vel = -amp / (2 * np.pi * f0) * np.cos(2 * np.pi * f0 * tn + ph)
    rest = calm.at(tn, 0.1, dt)[0][0]
    line = vj.at(tn, 0.1, dt)[0][0] - rest
    full = vj.at(tn, 0.1, dt, ft)[0][0] - rest
    v_amp = amp / (2 * np.pi * f0)
    assert abs(full - true_vel) < 0.05 * v_amp, (full, true_vel)
    assert abs(line - true_vel) > 0.8 * v_amp, (line, true_vel)
    # no tone in a 1 Hz swing; in white noise, in 1 % of the axes
    found = fit_tones(t, np.column_stack([motion] * 3), tn)
    assert not found.omega.any(), found.omega / (2 * np.pi)
    false = [fit_tones(t[100:], rng.normal(0.0, 0.3, (200, 3)), tn).omega.any()
             for _ in range(100)]
    assert np.mean(false) <= 0.05, np.mean(false)


def test_tone_searches_kept_between_calls_change_nothing():
    """fit_tones' ``kept``: the searches of the last windows kept for the next calls (a
    VelocityJitter keeps its own: one search's window is, to the bit, the next search's
    window before). Searches one second apart over a stream with a 5.3 Hz tone that comes
    and goes and a vehicle's motion give the same Tones, to the bit, with and without it,
    and the windows kept are taken again (fewer searches)."""
    rng = np.random.default_rng(9)
    dt = 0.01
    t = np.arange(1, 1201) * dt
    mid = t - 0.5 * dt
    x = np.column_stack([0.3 + 0.8 * np.sin(2 * np.pi * 1.0 * mid)] * 6) \
        + rng.normal(0.0, 0.05, (len(t), 6))
    x[(mid > 4.0) & (mid < 9.0), 0] += 1.5 * np.sin(2 * np.pi * 5.3 * mid[(mid > 4.0)
                                                                        & (mid < 9.0)])
    kept: dict = {}
    searched = []
    for k in range(200, len(t), 100):                # every second, 2 s of samples
        tw, xw, t0 = t[k - 200:k + 1], x[k - 200:k + 1], float(t[k])
        before = dict(kept)
        a = fit_tones(tw, xw, t0)
        b = fit_tones(tw, xw, t0, kept=kept)
        searched.append(sum(key not in before for key in kept))
        for name in ("omega", "a", "b", "freq"):
            np.testing.assert_array_equal(getattr(b, name), getattr(a, name), err_msg=name)
    assert sum(searched) < 2 * len(searched) - 3, searched       # windows taken again
    assert len(kept) <= 4
