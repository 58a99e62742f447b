"""What stands in for lost samples (``RecentMotion.bridge_errors``) and the error it owns up to.

A hole's missing samples are bridged by the recent mean, by the next sample held over the
hole, or by the mid bridge (the mean of the last sample and the next one); each bridge's
variance is its error replayed on the recent motion. Here the truth of the missing samples is
known, so the error a bridge really makes is compared with the variance it reports.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from sins_align.estimators.quasi_static.monitors import RecentMotion

NOM = 0.01          # s, 100 Hz


def signal(n: int, seed: int, tone: float, noise: float):
    """Rate and specific force (n, 3): a 2 Hz sway of amplitude ``tone`` on every axis
    (phases apart) plus white noise of std ``noise``."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * NOM
    ph = np.array([0.0, 1.0, 2.0])
    x = tone * np.sin(2 * np.pi * 2.0 * t[:, None] + ph) + noise * rng.normal(size=(n, 3))
    return x, x * 10.0


def bridge_at(w, f, k: int, m: int):
    """Fill a RecentMotion with samples 0..k, lose k+1..k+m, call bridge_errors with sample
    k+m+1; returns (means variances, held variances, bridge values) and the errors the
    returned bridge and the held bridge make on the rate (rad), max over the axes."""
    rec = RecentMotion()
    rec.extend(np.full(k + 1, NOM), w[:k + 1], f[:k + 1])
    means, held, (wb, fb) = rec.bridge_errors(m * NOM, NOM, w[k + m + 1], f[k + m + 1])
    miss = w[k + 1:k + m + 1].sum(axis=0) * NOM
    err_bridge = float(np.abs(m * NOM * wb - miss).max())
    err_held = float(np.abs(m * NOM * w[k + m + 1] - miss).max())
    return means, held, (wb, fb), err_bridge, err_held


@pytest.mark.parametrize("m", [1, 3])
def test_smooth_sway_takes_the_mid_bridge_and_covers_its_error(m):
    """A smooth sway (2 Hz, tiny noise): the mid bridge is returned, with a smaller variance
    than the held sample's, and its real error stays within its sigma at every phase (its
    variance is the replayed error's peak, not an average)."""
    w, f = signal(4000, seed=1, tone=0.01, noise=1e-6)
    worst = 0.0
    for k in range(2500, 2550):                    # a whole period of the sway
        means, held, (wb, _), err, err_held = bridge_at(w, f, k, m)
        np.testing.assert_allclose(wb, 0.5 * (w[k] + w[k + m + 1]))
        assert means[0] < held[0]
        worst = max(worst, err / math.sqrt(means[0]))
        assert err <= err_held + 1e-12
    assert worst <= 1.0, worst


def test_white_noise_keeps_the_mean():
    """No motion, only noise: two noisy samples are a worse bridge than the last second's
    mean, which is kept (the mid bridge is not chosen for noise)."""
    w, f = signal(4000, seed=2, tone=0.0, noise=1e-3)
    rec = RecentMotion()
    rec.extend(np.full(3000, NOM), w[:3000], f[:3000])
    _, _, (wb, fb) = rec.bridge_errors(3 * NOM, NOM, w[3003], f[3003])
    second = rec.last(1.0)
    np.testing.assert_allclose(wb, second[:, 1:4].mean(axis=0))
    np.testing.assert_allclose(fb, second[:, 4:7].mean(axis=0))


@pytest.mark.parametrize("where", [0, 2, 4])
def test_a_step_in_the_hole_is_within_sigma(where):
    """The rate steps from the sway's level to 0.05 rad/s somewhere in a hole of 4 samples
    (a shove): the mid bridge errs by at most half the step over the hole, which its
    variance takes."""
    w, f = signal(4000, seed=3, tone=0.001, noise=1e-6)
    k, m = 3000, 4
    w = w.copy()
    w[k + 1 + where:] += 0.05
    means, _, (wb, _), err, _ = bridge_at(w, f, k, m)
    assert err <= math.sqrt(means[0]) * (1 + 1e-9), (err, math.sqrt(means[0]))


@pytest.mark.parametrize("jitter", [False, True])
def test_mean_force_equals_the_window_of_last(jitter):
    """RecentMotion.mean_force (running time per row, component-major force: what the coarse
    pass reads after every sample) equals the mean of the rows last() gives, fed sample by
    sample and in blocks, across the ring's wrap; push and extend leave the same state."""
    rng = np.random.default_rng(7)
    a, b = RecentMotion(), RecentMotion()
    worst, ties = 0.0, 0
    for step in range(400):
        m = int(rng.integers(1, 9000)) if step % 40 == 0 else 1
        dts = (rng.uniform(0.0004, 0.0006, m) if jitter else np.full(m, 0.0005))
        w, f = rng.normal(0.0, 1e-3, (m, 3)), rng.normal(9.8, 0.05, (m, 3))
        for k in range(m):
            a.push(float(dts[k]), w[k], f[k])
        b.extend(dts, w, f)
        for sec in (1.0, 0.0123, 100.0):
            new = a.mean_force(sec)
            assert np.array_equal(new, b.mean_force(sec))
            rows = a.last(sec)
            ref = rows[:, 4:7].mean(axis=0)
            # a window whose span equals `seconds` to rounding may hold one row more or less
            # (uniform stamps): the rows' count then differs by one, nothing else
            n_new = a.window_rows(sec)
            if n_new != len(rows):
                assert abs(n_new - len(rows)) == 1 and not jitter
                ties += 1
                continue
            worst = max(worst, float(np.abs(new - ref).max()))
    assert np.array_equal(a._before, b._before) and a._total == b._total
    assert worst < 1e-12
    assert RecentMotion().mean_force(1.0) is None
