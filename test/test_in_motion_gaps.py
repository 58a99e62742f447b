"""Lost IMU samples in the in-motion filter: the holes are bridged (gaps.py), the bridge is
the same however the stream is fed, and the published covariance stays honest on a
vibrating IMU that loses samples (it was not: 28-40 % of the instants beyond 3 sigma after
three samples lost once)."""
import numpy as np

from sins_align.core.rotation import attitude_error
from sins_align.estimators.in_motion import MotionAligner, MotionConfig
from sins_align.estimators.in_motion.gaps import FILL_WINDOW, GAP_RATIO, bridge_gaps
from sins_align.estimators.in_motion.jitter import VelocityJitter
from sins_align.sim.trajectory import (SEED003_SPECS, Vibration, car_with_turn,
                                       simulate_trajectory, uav_seed003)

#: the accelerometer's vibration of a rotor UAV (the one that made lost samples dishonest)
ACCEL_VIBRATION = Vibration(accel_rms=3.0, gyro_rms=0.0, band=(20.0, 80.0), tones=3)


def _held(t, w, f, keep=5.0):
    vj = VelocityJitter(keep)
    vj.add(t, f, w)
    return vj


def test_a_stream_without_holes_comes_back_as_it_is():
    """Stamps jittered by +-20 % of the interval (intervals of 0.6-1.4 nominal) hold no
    hole: no made-up sample, the intervals are the stamps' differences."""
    rng = np.random.default_rng(1)
    t = np.arange(1, 501) * 0.01 + rng.uniform(-0.002, 0.002, 500)
    w, f = rng.normal(0, 0.1, (500, 3)), rng.normal(0, 3.0, (500, 3)) + [0, 0, 9.8]
    b = bridge_gaps(float(t[0]), t[1:], w[1:], f[1:], 0.01, _held(t, w, f).before)
    assert b.fills == []
    np.testing.assert_array_equal(b.t, t[1:])
    np.testing.assert_allclose(b.dts, np.diff(t))


def test_a_hole_is_bridged_by_the_mean_before_it():
    """Five samples lost after sample 300 of a 100 Hz stream: a made-up sample one nominal
    interval before the sample after the hole, holding the mean of the samples of the
    FILL_WINDOW s before the hole; the sample after the hole keeps one interval; the
    intervals still add up to the stamps' span. The variance: zero for a constant motion,
    and for a vibrating one at least the step the sample after the hole shows times the
    hole."""
    rng = np.random.default_rng(2)
    t = np.arange(1, 601) * 0.01
    keep = np.ones(600, bool)
    keep[301:306] = False
    w0 = np.tile([0.01, -0.02, 0.3], (600, 1))
    f0 = np.tile([0.5, 0.2, 9.8], (600, 1))
    for w, f, vibrating in ((w0, f0, False),
                            (w0 + rng.normal(0, 0.03, (600, 3)),
                             f0 + rng.normal(0, 2.0, (600, 3)), True)):
        tk, wk, fk = t[keep], w[keep], f[keep]
        held = _held(tk, wk, fk)
        b = bridge_gaps(float(tk[200]), tk[201:], wk[201:], fk[201:], 0.01, held.before)
        assert len(b.fills) == 1
        i = b.fills[0]
        assert b.t[i] == t[306] - 0.01 and b.t[i + 1] == t[306]
        np.testing.assert_allclose(b.dts[i + 1], 0.01)
        np.testing.assert_allclose(b.dts[i], t[306] - t[300] - 0.01)
        np.testing.assert_allclose(b.dts.sum(), tk[-1] - tk[200])
        window = (t >= t[300] - FILL_WINDOW) & (t <= t[300])
        np.testing.assert_allclose(b.w[i], w[window].mean(axis=0))
        np.testing.assert_allclose(b.f[i], f[window].mean(axis=0))
        # the real samples are where they were
        np.testing.assert_array_equal(np.delete(b.f, i, axis=0), fk[201:])
        g = 0.05
        if vibrating:
            assert np.all(b.var_f[0] >= (g * (f[306] - f[window].mean(axis=0))) ** 2)
            assert np.all(b.var_w[0] >= (g * (w[306] - w[window].mean(axis=0))) ** 2)
            assert b.var_f[0].min() > 1e-4
        else:
            np.testing.assert_allclose(b.var_f, 0.0, atol=1e-20)
            np.testing.assert_allclose(b.var_w, 0.0, atol=1e-20)
    assert GAP_RATIO * 0.01 < 0.02          # (one lost sample is a hole)


def test_one_lost_sample_of_a_tonal_vibration_is_predicted_from_its_neighbours():
    """A rotor's vibration (three tones per axis at 20-80 Hz, 3 m/s^2 RMS, sampled at
    100 Hz): one lost sample is predicted from the 6 samples before it and the one after it
    (a least-squares fit over the last second): within 2 % of the vibration's RMS on every
    axis at 40 places, where the mean before the hole errs by about the whole RMS (it did,
    and the hovering bank of headings took that error for heading evidence). The variance
    stays that of the mean (it covers the prediction many times over). With a hole among
    the 6 samples before it, the mean."""
    rng = np.random.default_rng(4)
    t = np.arange(1, 1201) * 0.01
    freq = rng.uniform(20.0, 80.0, (3, 3))
    phase = rng.uniform(0.0, 2.0 * np.pi, (3, 3))
    f = (np.sqrt(2.0 / 3.0) * 3.0 * np.sin(2.0 * np.pi * freq[None] * t[:, None, None]
                                            + phase[None])).sum(axis=2) + [0.0, 0.0, 9.8]
    w = rng.normal(0.0, 1e-3, (1200, 3))
    worst, mean_err = 0.0, []
    for k in range(200, 1200, 25):
        keep = np.ones(1200, bool)
        keep[k] = False
        tk, wk, fk = t[keep], w[keep], f[keep]
        j = k - 150                                 # the block starts 1.5 s before the hole
        b = bridge_gaps(float(tk[j - 1]), tk[j:], wk[j:], fk[j:], 0.01, _held(tk, wk, fk).before)
        assert len(b.fills) == 1
        i = b.fills[0]
        worst = max(worst, float(np.abs(b.f[i] - f[k]).max()))
        before = f[k - 25:k].mean(axis=0)
        mean_err.append(np.abs(before - f[k])[:2])
        assert np.all(b.var_f[0] >= (0.01 * (f[k + 1] - before)) ** 2)
        assert np.all(b.var_f[0] >= (0.01 * (b.f[i] - f[k])) ** 2)
    assert worst < 0.02 * 3.0 and np.mean(mean_err) > 1.0
    # a hole among the samples before: the mean of the window
    keep = np.ones(1200, bool)
    keep[[600, 603]] = False
    tk, wk, fk = t[keep], w[keep], f[keep]
    b = bridge_gaps(float(tk[450]), tk[451:], wk[451:], fk[451:], 0.01, _held(tk, wk, fk).before)
    i = b.fills[1]
    assert b.t[i + 1] == t[604]
    window = tk[(tk >= t[602] - FILL_WINDOW) & (tk <= t[602])]
    np.testing.assert_allclose(b.f[i], fk[np.isin(tk, window)].mean(axis=0))


def test_a_hole_right_after_another_is_bridged_by_the_samples_before_both():
    """Losses in a burst: 0.3 s lost, one sample, 0.19 s lost. The second hole's window
    holds one sample; it is bridged by the last samples held before it (reaching back over
    the first hole) and its variance holds the step the sample after it shows (it was
    bridged by that sample with no variance at all: 36-37 % of the instants beyond 3 sigma
    on the vibrating UAV below)."""
    rng = np.random.default_rng(0)
    t = np.arange(1, 1001) * 0.01
    w = rng.normal(0, 0.03, (1000, 3))
    f = rng.normal(0, 3.0, (1000, 3)) + [0, 0, 9.8]
    keep = np.ones(1000, bool)
    keep[300:330] = False
    keep[331:350] = False
    tk, wk, fk = t[keep], w[keep], f[keep]
    b = bridge_gaps(float(tk[250]), tk[251:], wk[251:], fk[251:], 0.01, _held(tk, wk, fk).before)
    assert len(b.fills) == 2
    i = b.fills[1]
    assert b.t[i + 1] == t[350]
    last = slice(None, 300)             # the samples before the first hole (up to t[299])
    full = int(FILL_WINDOW / 0.01)
    used = np.concatenate([f[last][-(full - 1):], f[330:331]])
    np.testing.assert_allclose(b.f[i], used.mean(axis=0))
    g = t[350] - t[330] - 0.01
    assert np.all(b.var_f[1] >= (g * (f[350] - used.mean(axis=0))) ** 2)
    assert b.var_f[1].min() > 1e-2 and b.var_w[1].min() > 1e-5


def test_velocity_jitter_bridges_a_hole_as_the_filter_does():
    """Across a hole, the IMU velocity the jitter is taken from has the sample after the
    hole for one nominal interval and the window's mean force for the rest: the
    definition (polyfit of that velocity) and the closed form agree; without the nominal
    interval, the hole's sample counts over the whole hole."""
    rng = np.random.default_rng(5)
    t = np.arange(1, 401) * 0.01
    keep = np.ones(400, bool)
    keep[[200, 201, 202, 250]] = False
    t = t[keep]
    f = rng.normal(0.0, 3.0, (len(t), 3)) + [0.0, 0.0, 9.8]
    vj = VelocityJitter(5.0)
    vj.add(t, f)
    checked = 0
    for k in range(150, 300):
        # the window from the sample nearest to t - 0.1 (a tie, in a hole: the later one)
        d = np.abs(t[:k + 1] - (t[k] - 0.1))
        i0 = int(np.flatnonzero(d <= d.min() + 1e-9)[-1])
        tw = t[i0:k + 1]
        dt = np.diff(tw)
        fw = f[i0 + 1:k + 1]
        dv = fw * dt[:, None]
        h = dt > 0.015
        if not h.any():
            continue
        dv[h] = 0.01 * fw[h] + (dt[h, None] - 0.01) * fw.mean(axis=0)
        V = np.concatenate([[np.zeros(3)], np.cumsum(dv, axis=0)])
        line = [np.polyval(np.polyfit(tw - tw[-1], V[:, c], 1), 0.0) for c in range(3)]
        jit, f_mean = vj.at(t[k], 0.1, 0.01)
        np.testing.assert_allclose(jit, V[-1] - line, rtol=0, atol=1e-12)
        np.testing.assert_allclose(f_mean, V[-1] / (tw[-1] - tw[0]), rtol=1e-13)
        assert np.abs(vj.at(t[k], 0.1)[0] - jit).max() > 1e-4
        checked += 1
    assert checked > 10


def test_holes_are_bridged_the_same_in_blocks_one_by_one_and_after_late_measurements():
    """A car stream that loses single samples and runs of them: fed in one block, one by
    one, and one by one with every velocity measurement 0.12 s late (rewinds through the
    holes), the same attitude and covariance; each hole counted once."""
    r = simulate_trajectory(car_with_turn(), 100.0, "consumer", seed=3, gnss_rate=10.0,
                            gnss_sigma=0.05)
    n = 3000
    keep = np.ones(n, bool)
    keep[[450, 900, 901, 902, 1703, 2222]] = False
    keep[1300:1340] = False
    keep[2500:2530] = False                 # a burst: the second hole reaches over the first
    keep[2531:2545] = False
    idx = np.flatnonzero(keep)

    def cfg():
        return MotionConfig(latitude_deg=34.0, longitude_deg=108.0, height_m=400.0,
                            specs="consumer", velocity_noise=0.05)

    a, b, c = MotionAligner(cfg()), MotionAligner(cfg()), MotionAligner(cfg())
    for al in (a, b):
        for tg, vg in zip(r.gnss_t, r.gnss_v):
            al.add_velocity(tg, vg)
    a.update(r.t[idx + 1], r.gyro[idx], r.accel[idx])
    for k in idx:
        b.update(r.t[k + 1], r.gyro[k], r.accel[k])
    early = r.gnss_t < 1.0
    for tg, vg in zip(r.gnss_t[early], r.gnss_v[early]):
        c.add_velocity(tg, vg)
    queue = list(zip(r.gnss_t[~early] + 0.12, r.gnss_t[~early], r.gnss_v[~early]))
    for k in idx:
        while queue and queue[0][0] <= r.t[k + 1]:
            _, tg, vg = queue.pop(0)
            assert c.add_velocity(tg, vg)
        c.update(r.t[k + 1], r.gyro[k], r.accel[k])
    while queue and queue[0][1] <= r.t[n]:
        _, tg, vg = queue.pop(0)
        c.add_velocity(tg, vg)
    assert c.events["rewinds"] > 100
    for x in (a, b, c):
        assert x.events["holes_bridged"] == 7 and x.events.get("started") == 1
    # equal to the closed form's approximations (runs of other lengths; over these 30 s:
    # 2e-7 rad and 1.3e-5 relative with the holes, 6e-8 rad and 3e-6 without)
    for x in (b, c):
        assert np.abs(attitude_error(a.dcm, x.dcm)).max() < 1e-6
        assert np.allclose(a.covariance, x.covariance, rtol=1e-4, atol=1e-15)


def _lossy_run(seed, keep_of):
    """Seed 003's UAV with the accelerometer vibrating, 60 s, samples lost per ``keep_of``;
    fed 10 at a time. Returns the stamps and the attitude error / published std (ENU) after
    each block, from the start."""
    traj = uav_seed003()
    r = simulate_trajectory(traj, 100.0, SEED003_SPECS, seed=seed, gnss_rate=10.0,
                            gnss_sigma=0.05, vibration=ACCEL_VIBRATION, duration=60.0)
    keep = keep_of(len(r.gyro), seed)
    al = MotionAligner(MotionConfig(latitude_deg=traj.lat_deg, longitude_deg=traj.lon_deg,
                                    height_m=traj.height_m, specs=SEED003_SPECS,
                                    velocity_noise=0.05))
    for tg, vg in zip(r.gnss_t, r.gnss_v):
        al.add_velocity(tg, vg)
    idx = np.flatnonzero(keep)
    t, z = [], []
    for b in range(0, len(idx), 10):
        k = idx[b:b + 10]
        al.update(r.t[k + 1], r.gyro[k], r.accel[k])
        if al.initialized:
            e = attitude_error(r.C[k[-1] + 1], al.dcm)
            t.append(r.t[k[-1] + 1])
            z.append(e / np.sqrt(np.diag(al.covariance)))
    assert al.events["holes_bridged"] >= 1 and not al.rejected
    return np.array(t), np.array(z), al


def _three_at_30(n, seed):
    keep = np.ones(n, bool)
    keep[3000:3003] = False
    return keep


def _random_2_percent(n, seed):
    return np.random.default_rng(100 + seed).random(n) >= 0.02


def _bursts_at_30(n, seed):
    keep = np.ones(n, bool)
    for s in (3000, 3031, 3062):            # three 0.3 s holes, one sample between them
        keep[s:s + 30] = False
    return keep


def _hole_in_the_bank(n, seed):
    keep = np.ones(n, bool)
    keep[1000:1035] = False                 # 0.35 s at 10 s: the bank of headings runs
    return keep


#: s: the bank of heading hypotheses has collapsed by then on this flight (its first
#: horizontal acceleration is at 18-24 s)
AFTER_BANK = 25.0


def test_a_vibrating_imu_that_loses_samples_stays_honest():
    """Seed 003's UAV, the accelerometer vibrating (3 m/s^2 RMS at 20-80 Hz), 60 s: three
    samples lost at 30 s, a 0.35 s hole at 10 s (while the bank of headings runs), 2 % lost
    at random (2 seeds), three 0.3 s holes one sample apart at 30 s. From 25 s on, the
    attitude error is beyond 3 sigma at no more than 6 % of the instants and its mean
    (e/sigma)^2 stays below 3 on every axis: what the same runs give with nothing lost
    (seeds 0-5: 0-5.5 % beyond, mean up to 2.6). Measured: 0, 0, 0 and 0-0 % beyond.
    Before the bridging: 28-40 % (three lost), 84 % (the hole), 96 % (2 % at random), and
    'aligned' at most of those instants; 74-75 % for the bursts while their second and
    third holes did not look back over the first."""
    for keep_of, seeds in ((_three_at_30, (0,)), (_hole_in_the_bank, (0,)),
                           (_bursts_at_30, (0,)),
                           (_random_2_percent, (0, 1))):
        for seed in seeds:
            t, z, al = _lossy_run(seed, keep_of)
            late = z[t >= AFTER_BANK]
            beyond = (np.abs(late) > 3.0).any(axis=1).mean()
            worst = (late ** 2).mean(axis=0).max()
            assert beyond <= 0.06 and worst < 3.0, (keep_of.__name__, seed, beyond, worst)
            assert al.hypotheses == 1


def test_the_hovering_bank_stays_honest_when_samples_are_lost_at_random():
    """The bank of heading hypotheses while the UAV hovers (before 18 s), 2 % of the samples
    lost at random, seed 1: heading (e/sigma)^2 at most 3 on average. Measured 1.94 (0 % of
    the instants beyond 3 sigma); 1.70 with nothing lost. While a lost sample was bridged by
    the mean before the hole: 7.74 (38 % beyond 3 sigma; 8.7 and 49 % with a bank of 12), the
    mean's error (the lost sample's vibration) read as heading evidence by the bank's
    weights (README Limitations)."""
    t, z, _ = _lossy_run(1, _random_2_percent)
    assert (z[t < 18.0, 2] ** 2).mean() <= 3.0
