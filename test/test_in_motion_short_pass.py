"""The short-pass sums of one filter (runs.short_run_sums: Python floats, each run in its own
start frame) against the vectorised run_sums they replace for passes of up to SHORT_PASS
samples (a live stream's rewinds): every field, run by run, to 1e-12 of that run's field;
then the filter and a live MotionAligner with the float path against the same forced onto
run_sums."""
import numpy as np
import pytest

from sins_align.core.rotation import so3_exp
from sins_align.core.strapdown import NavState
from sins_align.estimators.in_motion import InvariantEKF, MotionAligner, MotionConfig, NoiseModel
from sins_align.estimators.in_motion import filter as filter_mod
from sins_align.estimators.in_motion.runs import (SHORT_PASS, run_sums, short_run_sums,
                                                 white_noise_rate)
from sins_align.sim.trajectory import SEED003_SPECS, simulate_trajectory, uav_seed003

NOISE = NoiseModel(1e-3, 1e-2, 1e-5, 1e-4)
RTOL = 1e-12
#: the optional states: (n, i_sf, i_sa)
LAYOUTS = {"core": (12, None, None), "gyro_scale": (15, slice(12, 15), None),
           "accel_scale": (15, None, slice(12, 15)),
           "both": (21, slice(15, 18), slice(18, 21))}


def _fields(s, n):
    """Every field of a RunSums as (name, (1, R, ...) array); the noise's gyro part (Q less
    its white-noise diagonal, the D sums) on its own, so it is not lost beside the rest."""
    out = [(k, getattr(s, k)) for k in ("Gm", "S", "M", "V", "Vt", "Pm", "Q", "Sw", "Mw",
                                        "Sa") if getattr(s, k) is not None]
    out.append(("Q_gyro", s.Q - white_noise_rate(NOISE, n) * s.T[:, None, None]))
    out.append(("T", s.T[None]))
    return out


def _pass(rng, N, rate):
    """A pass of N samples: dt varying +-40 % about 0.01 s, rates of order ``rate`` rad/s
    (up to a radian a sample at the largest), specific forces with gravity, cut into runs."""
    dt = 0.01 * (1.0 + 0.4 * rng.uniform(-1.0, 1.0, N))
    w = rng.normal(0.0, rate, (1, N, 3)) + rng.normal(0.0, rate, 3)
    f = rng.normal(0.0, 4.0, (1, N, 3)) + [0.3, -0.2, 9.8]
    cuts = sorted(set(rng.integers(1, N, rng.integers(0, min(N, 4))).tolist()))
    return dt, w, f, cuts + [N]


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_short_pass_sums_equal_the_vectorised_sums(layout):
    n, i_sf, i_sa = LAYOUTS[layout]
    rng = np.random.default_rng(sorted(LAYOUTS).index(layout))
    checked = set()
    for N in list(range(2, 17)) + [SHORT_PASS]:
        for rate in (1e-3, 0.3, 5.0, 60.0):
            dt, w, f, ends = _pass(rng, N, rate)
            a = run_sums(dt, w, f, ends, NOISE, n, i_sf, i_sa)
            b = short_run_sums(dt, w, f, ends, NOISE, n, i_sf, i_sa)
            assert (b.w_max, b.f_max) == (a.w_max, a.f_max)
            assert b.packed.shape == a.packed.shape == (1, len(ends), 36)
            fa, fb = _fields(a, n), _fields(b, n)
            assert [k for k, _ in fa] == [k for k, _ in fb]
            for (k, x), (_, y) in zip(fa, fb):
                assert x.shape == y.shape, k
                for r in range(len(ends)):
                    scale = np.abs(x[0, r]).max()
                    if scale == 0.0:               # (the D sums of a one-sample run)
                        assert np.abs(y[0, r]).max() == 0.0, (k, N, r)
                        continue
                    err = np.abs(x[0, r] - y[0, r]).max()
                    assert err <= RTOL * scale, (k, N, rate, r, err / scale)
                    checked.add(k)
    expected = {"Gm", "S", "M", "V", "Vt", "Pm", "Q", "Q_gyro", "T"}
    expected |= {"Sw", "Mw"} if i_sf is not None else set()
    expected |= {"Sa"} if i_sa is not None else set()
    assert checked == expected


def _filter(extra, seed=5):
    rng = np.random.default_rng(seed)
    st = NavState(so3_exp(rng.normal(0, 1, 3)), [8.0, -3.0, 0.5], 0.7, 2.0, 250.0)
    n = 12 + 3 * len(extra)
    A = rng.normal(0, 1, (n, n))
    P0 = 1e-3 * (A @ A.T) + np.diag(np.r_[np.full(3, 1e-2), np.full(3, 0.1), np.full(3, 1e-6),
                                          np.full(3, 1e-3), np.full(n - 12, 1e-2)])
    return InvariantEKF(st, P0, NOISE, lever_arm=(0.4, -0.2, 0.9), C=st.C[None],
                        extra=extra)


def _float_then_vectorised(monkeypatch):
    """Yield (short, calls) twice: the filter on its float short-pass sums, then with
    SHORT_PASS forced to 0 (run_sums); calls: the lengths of the passes the float path
    summed since that yield."""
    for short in (True, False):
        if not short:
            monkeypatch.setattr(filter_mod, "SHORT_PASS", 0)
        calls = []

        def counted(*args, calls=calls, **kw):
            calls.append(len(args[0]))
            return short_run_sums(*args, **kw)
        monkeypatch.setattr(filter_mod, "short_run_sums", counted)
        yield short, calls


@pytest.mark.parametrize("extra", [(), ("lever", "gyro_scale", "accel_scale")])
def test_filter_on_short_passes_equals_the_vectorised_passes(extra, monkeypatch):
    """Passes of 2 to 16 samples in two or three runs, a velocity update after each run:
    the filter's states with the float sums and with run_sums (SHORT_PASS forced to 0)."""
    rng = np.random.default_rng(7)
    lengths = rng.integers(2, 17, 40)
    data = []
    for N in lengths:
        dt, w, f, ends = _pass(rng, int(N), 0.5)
        data.append((dt, w[0], f[0], ends, rng.normal(0, 0.3, (len(ends), 3))))
    out = []
    for short, calls in _float_then_vectorised(monkeypatch):
        e = _filter(extra)
        for dt, w, f, ends, noise in data:
            for r in e.propagate_runs(dt, w, f, ends):
                e.update_velocity(e.v[0] + noise[r], np.diag([0.04, 0.05, 0.06]))
        assert (len(calls) >= len(data)) if short else not calls   # (+ re-linearisations)
        out.append(e)
    a, b = out
    for k in ("C", "v", "lat", "lon", "h", "P", "bg", "ba", "lever", "sf", "sa", "w_last"):
        x, y = getattr(a, k), getattr(b, k)
        assert np.abs(x - y).max() <= 1e-11 * max(np.abs(y).max(), 1e-300), k
    assert np.abs(a.bg).max() > 1e-4          # the updates moved the state: this has teeth


def test_live_aligner_equals_its_vectorised_self(monkeypatch):
    """seed 003's UAV with scale-factor states, one sample per call, each GNSS velocity
    0.1 s late (rewound): the float sums of the rewinds against run_sums."""
    traj = uav_seed003()
    r = simulate_trajectory(traj, 100.0, SEED003_SPECS, seed=2, gnss_rate=10.0,
                            gnss_sigma=0.05, gyro_scale_ppm=3000.0, accel_scale_ppm=3000.0)
    cfg = MotionConfig(latitude_deg=traj.lat_deg, longitude_deg=traj.lon_deg,
                       height_m=traj.height_m, specs=SEED003_SPECS, velocity_noise=0.05,
                       gyro_scale_std=0.003, accel_scale_std=0.003,
                       initial_rpy_deg=(0.0, 0.0, 30.0), initial_heading_std_deg=20.0)
    n = 1500
    out = []
    for short, calls in _float_then_vectorised(monkeypatch):
        al = MotionAligner(cfg)
        j = 0
        for k in range(n):
            tk = r.t[k + 1]
            while j < len(r.gnss_t) and r.gnss_t[j] + 0.1 <= tk + 1e-9:
                al.add_velocity(r.gnss_t[j], r.gnss_v[j])
                j += 1
            al.update(tk, r.gyro[k], r.accel[k])
        assert al.events["rewinds"] > 100
        assert (len(calls) > 100) if short else not calls
        out.append(al)
    a, b = out
    assert np.abs(a.dcm - b.dcm).max() < 1e-11
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-9, atol=1e-20)
    np.testing.assert_allclose(a.ekf.sf, b.ekf.sf, rtol=1e-8, atol=1e-14)
    assert a.aligned == b.aligned
