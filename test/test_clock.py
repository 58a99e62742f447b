"""core/clock.py over five minutes of jittering stamps: the samples' count holds. Before,
the count was decided by each stamp against a line over the last second, whose period was
free: a stamp 2.5 sigma late looked like a lost sample, that line took the made-up count
in, its period shortened and made up more (Gaussian 20 %: the period 1.6 % short after
300 s, seed 1; +-40 %: 15 % short and 3,700 made-up samples, seed 1; received 3 ms late on
average: 14 % short, 3,500 made-up samples). All four runs below fail there (the period
0.006-15 % off, the instants 1.1-4.5 ms RMS off); measured with the fix: the period within
1e-6, the instants 0.11-0.20 ms RMS, 0.01-0.03 % of them beyond 1.5 ms."""
import numpy as np
import pytest

from sins_align.core.clock import SampleClock

T = 0.01


def _stamps(model, n, seed):
    """True instants (100 Hz, epoch stamps) and their stamps: Gaussian sigma N % of the
    interval (gN), uniform +-N % (uN), received N ms late on average (dN, exponential, in
    order)."""
    t = 1.7e9 + np.arange(1, n + 1) * T
    rng = np.random.default_rng(seed)
    p = float(model[1:])
    if model[0] == "g":
        return t, t + rng.normal(0.0, p / 100.0, n) * T
    if model[0] == "u":
        return t, t + rng.uniform(-p / 100.0, p / 100.0, n) * T
    s = t + rng.exponential(p * 1e-3, n)
    for k in range(1, n):
        s[k] = max(s[k], s[k - 1] + 1e-6)
    return t, s


@pytest.mark.parametrize("model,seed", [("g20", 0), ("g20", 1), ("u40", 1), ("d3", 0)])
def test_the_count_holds_over_five_minutes(model, seed):
    """300 s at 100 Hz, fed in blocks of 10: the clock's period within 1e-5 of the true
    one, its instants within 0.3 ms RMS of the true ones plus the stamps' mean offset after
    the first second, at least 99.9 % of them within 1.5 ms (a stamp late by over half an
    interval may be taken for a lost sample until the stamps after it say otherwise: the
    interval is given back over the next ones)."""
    n = 30_000
    t, s = _stamps(model, n, seed)
    c = SampleClock()
    x = np.concatenate([c.times(s[b:b + 10]) for b in range(0, n, 10)])
    err = (x - t - np.mean(s - t))[100:]
    assert abs(c.period / T - 1.0) < 1e-5, c.period / T - 1.0
    assert np.sqrt(np.mean(err ** 2)) < 0.3e-3, np.sqrt(np.mean(err ** 2))
    assert (np.abs(err) < 1.5e-3).mean() >= 0.999, (np.abs(err) < 1.5e-3).mean()


@pytest.mark.parametrize("block", [10, 16384])
def test_stamps_back_on_the_imu_clock_within_a_block(block):
    """Stamps from the IMU's own clock, one of them received 3 ms late: the fit starts there
    and ends some hundred stamps later (back on the clock, untouched again). Fed in blocks,
    the stamps after that end within the block are given as one by one (they crashed:
    the fit's sums were gone while the block's loop went on); and the same with jittering
    stamps that turn exact."""
    rng = np.random.default_rng(0)
    one_late = 1.7e9 + np.arange(5000) * T
    one_late[1000] += 3e-3
    turning = 100.0 + np.arange(8000) * T           # (see the review's note on epoch stamps)
    turning[:2000] += rng.uniform(-0.4, 0.4, 2000) * T
    for s in (one_late, turning):
        c = SampleClock()
        single = np.array([c.time(float(x)) for x in s])
        assert not c.jittering                      # (the fit did end)
        c = SampleClock()
        x = np.concatenate([c.times(s[b:b + block]) for b in range(0, len(s), block)])
        assert not c.jittering
        np.testing.assert_array_equal(x, single)


def test_the_period_settles_on_exact_epoch_stamps_after_jitter():
    """Epoch stamps (1.7e9 s: 0.24 us apart in floats), +-40 % jitter for 20 s, then the
    IMU's exact stamps: the period settles on the stamps' (within 1e-8 after 280 s). The
    lines' origin moved by the counting line's value while the origin itself moved by what
    it rounded to: that difference came back at every stamp and held the period 1.1e-5
    off for good (the instants then lean on the slow pull, below float resolution there)."""
    rng = np.random.default_rng(0)
    s = 1.7e9 + np.arange(30_000) * T
    s[:2000] += rng.uniform(-0.4, 0.4, 2000) * T
    c = SampleClock()
    c.times(s)
    assert abs(c.period / T - 1.0) < 1e-8, c.period / T - 1.0
