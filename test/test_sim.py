"""Tests for the IMU simulator (sins_align.sim.simulator): exactness, statistics, determinism,
streaming, and the batch of runs (simulate_runs) equal to simulate() run by run."""
from __future__ import annotations

import numpy as np
import pytest

from sins_align.core.earth import OMEGA_IE, earth_rate_enu, gravity, gravity_enu
from sins_align.core.rotation import dcm_from_quat, dcm_from_rpy, so3_exp, so3_log
from sins_align.sim import simulator as sim_module
from sins_align.sim.simulator import (_STREAMS, SWAY_PRESETS, ImuSimulator, SimResult, SwayProfile,
                            _ar1_scan, _stream, simulate, simulate_runs, sway_profile)
from sins_align.core.specs import DEG, grade_specs

RPY = (30.0, -50.0, 120.0)      # a deliberately non-trivial mean attitude, deg
ZERO = np.zeros(3)


def _clean(duration: float, sway: str, **kw) -> SimResult:
    return simulate(duration, rpy_deg=RPY, sway=sway, noise=False, gyro_bias=ZERO,
                    accel_bias=ZERO, **kw)


@pytest.fixture(scope="module", params=["car", "ship"])
def swaying(request) -> SimResult:
    """10 minutes at 100 Hz of error-free data on a swaying base."""
    return _clean(600.0, request.param)


def test_error_free_gyro_reintegrates_attitude(swaying):
    """Re-integrating the error-free gyro from C0 with the damped attitude update
    C_k = exp(-w_ie dt) C_{k-1} exp(w_k dt) reproduces C_true within 1e-9 rad over 10 min."""
    r = swaying
    assert len(r) == 60000
    E = so3_exp(-earth_rate_enu(r.lat_rad) * r.dt)
    steps = so3_exp(r.gyro * r.dt)
    C = r.C0.copy()
    worst = 0.0
    for k in range(len(r)):
        C = E @ C @ steps[k]
        if k % 100 == 0 or k == len(r) - 1:
            worst = max(worst, float(np.linalg.norm(so3_log(r.C_true[k] @ C.T))))
        if k == 0:
            assert np.linalg.norm(so3_log(r.C_true[0] @ C.T)) < 1e-12
    assert worst < 1e-9
    # the test can fail: the sway is real and the Earth rate matters at this level
    assert np.max(np.linalg.norm(so3_log(r.C0.T @ r.C_true), axis=-1)) > 1e-4


def test_error_free_accel_reintegrates_velocity(swaying):
    """The damped velocity update v_k = v_{k-1} + (C_k f_k + g^n) dt driven by the error-free
    specific force reproduces the true (bounded) velocity within 1e-9 m/s over 10 min."""
    r = swaying
    g_n = gravity_enu(r.lat_rad, r.height_m)
    dv = (np.einsum("kij,kj->ki", r.C_true, r.accel) + g_n) * r.dt
    v = r.v0 + np.cumsum(dv, axis=0)
    assert np.max(np.abs(v - r.v_true)) < 1e-9
    assert np.max(np.abs(r.v_true)) > 1e-3        # there is motion to reproduce


def test_displacement_and_velocity_stay_bounded(swaying):
    """Sway displacement and velocity stay bounded over 10 min (no drift), with the magnitudes
    the presets promise: mm-level for the car, tenths of a metre for the ship."""
    r = swaying
    p = np.max(np.linalg.norm(r.p_true, axis=-1))
    v = np.max(np.linalg.norm(r.v_true, axis=-1))
    if r.sway.name == "car":
        assert 1e-4 < p < 0.02 and v < 0.2
    else:
        assert 0.1 < p < 1.5 and v < 1.5
    # no secular growth: the least-squares trend of the displacement over the 10 minutes is
    # below 5 % of its peak. A bounded oscillation of period P has a trend over T of at most
    # 12 / (2 pi) P / T of its amplitude (4.5 % for the ship's longest period, 14 s); a drift
    # of the rotation centre shows as a trend of its own size (for the car, 3e-7 m/s is
    # enough to fail). (Before: the last minute's peak <= the whole run's, true of anything.)
    t = r.t - r.t.mean()
    trend = (t @ (r.p_true - r.p_true.mean(axis=0))) / (t @ t) * (r.t[-1] - r.t[0])
    assert np.all(np.abs(trend) < 0.05 * p), (trend, p)


@pytest.mark.parametrize("sway", ["car", "ship"])
def test_velocity_is_derivative_of_displacement(sway):
    """v_true is the time derivative of p_true (linear vibration + lever-arm effect):
    central differences at 1 kHz agree to 0.1 % of the peak velocity."""
    r = _clean(60.0, sway, rate=1000.0)
    fd = (r.p_true[2:] - r.p_true[:-2]) / (2.0 * r.dt)
    err = np.max(np.abs(fd - r.v_true[1:-1]))
    assert err < 1e-3 * np.max(np.abs(r.v_true))


def test_lever_arm_displacement():
    """With angular sway only, the IMU displacement is exactly the lever-arm effect
    p = (C_true - C_ref) l^b, so a rotation about the centre moves the IMU."""
    prof = SwayProfile(ang_amp=(2 * DEG, 1 * DEG, 0.5 * DEG), ang_freq=(0.1, 0.15, 0.07),
                       lever_arm=(1.0, -2.0, 3.0))
    r = simulate(100.0, rpy_deg=RPY, sway=prof, noise=False)
    C_ref = dcm_from_rpy(np.radians(RPY))
    expect = (r.C_true - C_ref) @ np.array(prof.lever_arm)
    assert np.max(np.abs(r.p_true - expect)) < 1e-12
    assert np.max(np.abs(r.p_true)) > 0.05


def test_static_case_exact():
    """Static base, no errors: gyro == C^T w_ie^n to 1e-15 rad/s, accel == -C^T g^n and
    |f| == g(lat, h); the truth is constant and equal to dcm_from_rpy(rpy)."""
    r = simulate(10.0, lat_deg=34.0, height_m=500.0, rpy_deg=RPY, sway="none", noise=False,
                 gyro_bias=ZERO, accel_bias=ZERO)
    C = dcm_from_rpy(np.radians(RPY))
    assert np.max(np.abs(r.C_true - C)) == 0.0 and np.max(np.abs(r.C0 - C)) == 0.0
    assert np.max(np.abs(r.gyro - C.T @ earth_rate_enu(r.lat_rad))) < 1e-15
    assert np.max(np.abs(r.accel - (-C.T @ gravity_enu(r.lat_rad, 500.0)))) < 1e-12
    assert np.allclose(np.linalg.norm(r.accel, axis=-1), gravity(r.lat_rad, 500.0),
                       rtol=0, atol=1e-12)
    assert np.all(r.v_true == 0.0) and np.all(r.p_true == 0.0)


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("lat", [90.0, 34.0, -50.0])
def test_tone_about_the_earth_axis_is_closed_form(lat):
    """Body z along the Earth's axis, an angular tone theta(s) = A sin(2 pi f s + phi) about
    it, no lever arm: the Earth rate and the sway are rotations about one axis, so everything
    is closed form, written here without the simulator's code. C_true = C_ref Rz(theta), the
    gyro increment of sample k is [0, 0, theta(s_k) - theta(s_k-1) + Omega dt], the specific
    force is C_true^T [0, 0, g]; the IMU does not move."""
    A, f, phi, rate = 0.7 * DEG, 0.37, 0.4, 200.0
    L = np.radians(lat)
    # columns: body x East, body z along the Earth's axis (North and up by the latitude)
    z = np.array([0.0, np.cos(L), np.sin(L)])
    x = np.array([1.0, 0.0, 0.0])
    C_ref = np.column_stack([x, np.cross(z, x), z])
    prof = SwayProfile(tones=(sim_module.Tone("angular", 2, f, A, phi),))
    r = simulate(20.0, rate=rate, lat_deg=lat, rpy_deg=np.degrees(
        [np.arctan2(C_ref[2, 1], C_ref[2, 2]), -np.arcsin(C_ref[2, 0]),
         np.arctan2(C_ref[1, 0], C_ref[0, 0])]), sway=prof, noise=False, gyro_bias=ZERO,
        accel_bias=ZERO)
    s = np.arange(len(r) + 1) / rate                    # times since t0 of samples -1 .. N-1
    theta = A * np.sin(2 * np.pi * f * s + phi)
    C_true = C_ref @ np.stack([_rz(a) for a in theta[1:]])
    assert np.max(np.abs(r.C_true - C_true)) < 1e-14
    expect = np.zeros((len(r), 3))
    expect[:, 2] = np.diff(theta) / r.dt + OMEGA_IE
    # round-off: a 1e-16 rad increment error over 5 ms is 2e-14 rad/s
    assert np.max(np.abs(r.gyro - expect)) < 1e-14
    g = gravity(L, 0.0)
    f_true = np.einsum("kji,j->ki", C_true, [0.0, 0.0, g])
    assert np.max(np.abs(r.accel - f_true)) < 1e-13
    assert np.all(r.v_true == 0.0) and np.all(r.p_true == 0.0)
    # the sway is real: theta spans most of +-A over 20 s
    assert np.ptp(theta) > 1.9 * A


def test_linear_tone_integrates_to_its_velocity():
    """A pure linear tone d(s) = A sin(2 pi f s + phi) along North, level IMU at yaw psi, no
    rotation: p_true and v_true are the tone and its derivative, and the specific force,
    rotated to ENU and freed of gravity, integrates to v(s_k) - v(0) exactly (the velocity of
    the tone, not of any scheme), with the Up component g."""
    A, f, phi, psi, rate = 0.02, 0.8, -1.1, 0.9, 100.0
    prof = SwayProfile(tones=(sim_module.Tone("linear", 1, f, A, phi),))
    r = simulate(30.0, rate=rate, lat_deg=34.0, rpy_deg=(0.0, 0.0, np.degrees(psi)), sway=prof,
                 noise=False, gyro_bias=ZERO, accel_bias=ZERO)
    w = 2 * np.pi * f
    s = np.arange(1, len(r) + 1) / rate
    C = _rz(psi)
    assert np.max(np.abs(r.C_true - C)) < 1e-15
    np.testing.assert_allclose(r.p_true[:, 1], A * np.sin(w * s + phi), rtol=0, atol=1e-15)
    np.testing.assert_allclose(r.v_true[:, 1], A * w * np.cos(w * s + phi), rtol=0, atol=1e-15)
    assert np.all(r.p_true[:, [0, 2]] == 0.0) and np.all(r.v_true[:, [0, 2]] == 0.0)
    f_n = r.accel @ C.T                                   # C f^b, ENU
    v = np.cumsum(f_n[:, 1]) * r.dt
    np.testing.assert_allclose(v, A * w * (np.cos(w * s + phi) - np.cos(phi)), rtol=0,
                               atol=1e-13)
    np.testing.assert_allclose(f_n[:, 2], gravity(np.radians(34.0)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(f_n[:, 0], 0.0, atol=1e-15)
    # the motion is real: peak acceleration A w^2 = 0.5 m/s^2
    assert np.max(np.abs(np.diff(v))) / r.dt > 0.9 * A * w ** 2


@pytest.mark.parametrize("lat", [-90.0, -60.0, 0.0, 34.0, 61.0, 89.999, 90.0])
def test_earth_rate_magnitude_any_latitude(lat):
    """At any latitude, poles included, a static error-free gyro measures |w| == OMEGA_IE,
    and in ENU the rate is [0, w cos L, w sin L]."""
    r = simulate(1.0, lat_deg=lat, rpy_deg=(170.0, 80.0, -135.0), noise=False,
                 gyro_bias=ZERO, accel_bias=ZERO)
    assert np.allclose(np.linalg.norm(r.gyro, axis=-1), OMEGA_IE, rtol=1e-12, atol=0)
    w_n = np.einsum("kij,kj->ki", r.C_true, r.gyro)
    assert np.allclose(w_n, [0.0, OMEGA_IE * np.cos(np.radians(lat)),
                             OMEGA_IE * np.sin(np.radians(lat))], rtol=0, atol=1e-18)


def test_time_stamps_and_quaternions():
    """t[k] = t0 + (k+1)/rate; quat_true is the [x, y, z, w] quaternion of C_true."""
    r = simulate(3.0, rate=200.0, t0=1.7e9, sway="ship", noise=False)
    k = np.arange(len(r))
    assert len(r) == 600
    assert np.array_equal(r.t, 1.7e9 + (k + 1) / 200.0)
    assert np.allclose(dcm_from_quat(r.quat_true), r.C_true, atol=1e-14)


def test_sway_presets_amplitudes():
    """The presets move the attitude as advertised: ship roll ~3 deg, pitch ~1 deg about the
    body axes; car bursts between 0.02 and 0.3 deg; amplitude scales the motion linearly."""
    C_ref = dcm_from_rpy(np.radians(RPY))
    ship = _clean(60.0, "ship")
    th = so3_log(C_ref.T @ ship.C_true)
    peak = np.degrees(np.max(np.abs(th), axis=0))
    assert np.allclose(peak, [3.0, 1.0, 0.5], rtol=0.02)
    car = _clean(600.0, "car")
    peak = np.degrees(np.max(np.linalg.norm(so3_log(C_ref.T @ car.C_true), axis=-1)))
    assert 0.02 < peak < 0.3 * np.sqrt(2.0) + 0.05
    car2 = _clean(600.0, "car", sway_amplitude=2.0)
    th1 = so3_log(C_ref.T @ car.C_true)
    th2 = so3_log(C_ref.T @ car2.C_true)
    assert np.allclose(th2, 2.0 * th1, atol=1e-12)
    none = _clean(10.0, "car", sway_amplitude=0.0)
    assert np.all(none.C_true == C_ref)


def test_white_noise_statistics():
    """Gyro/accel white noise has per-sample std arw/sqrt(dt) and vrw/sqrt(dt) (within 3 %),
    zero mean, and the constant biases show up as the mean error."""
    sp = grade_specs("tactical")
    r = simulate(600.0, specs=sp, sway="car", seed=3)
    eg = r.gyro - r.gyro_ideal
    ea = r.accel - r.accel_ideal
    n = len(r)
    sg, sa = sp.gyro_arw * np.sqrt(r.rate), sp.accel_vrw * np.sqrt(r.rate)
    assert np.allclose(np.std(eg, axis=0), sg, rtol=0.03)
    assert np.allclose(np.std(ea, axis=0), sa, rtol=0.03)
    assert np.all(np.abs(np.mean(eg, axis=0) - r.gyro_bias) < 4 * sg / np.sqrt(n))
    assert np.all(np.abs(np.mean(ea, axis=0) - r.accel_bias) < 4 * sa / np.sqrt(n))
    # white: neighbouring samples uncorrelated
    x = eg - eg.mean(axis=0)
    rho = np.sum(x[1:] * x[:-1], axis=0) / np.sum(x * x, axis=0)
    assert np.all(np.abs(rho) < 4 / np.sqrt(n))


def test_bias_draws_follow_specs():
    """Constant biases are drawn N(0, spec) per axis: over 400 seeds the sample std is within
    10 % of the spec and the mean is near zero; explicit biases override the draw."""
    sp = grade_specs("consumer")
    gb = np.array([simulate(0.01, specs=sp, seed=s).gyro_bias for s in range(400)])
    ab = np.array([simulate(0.01, specs=sp, seed=s).accel_bias for s in range(400)])
    assert abs(np.std(gb) / sp.gyro_bias - 1.0) < 0.1
    assert abs(np.std(ab) / sp.accel_bias - 1.0) < 0.1
    assert abs(np.mean(gb)) < 4 * sp.gyro_bias / np.sqrt(gb.size)
    assert abs(np.mean(ab)) < 4 * sp.accel_bias / np.sqrt(ab.size)
    r = simulate(1.0, specs=sp, gyro_bias=(1e-3, 2e-3, 3e-3), accel_bias=(0.1, 0.2, 0.3),
                 noise=False)
    assert np.array_equal(r.gyro_bias, [1e-3, 2e-3, 3e-3])
    assert np.allclose(r.gyro - r.gyro_ideal, [1e-3, 2e-3, 3e-3], rtol=0, atol=1e-15)
    assert np.allclose(r.accel - r.accel_ideal, [0.1, 0.2, 0.3], rtol=0, atol=1e-14)


def test_gauss_markov_bias_wander():
    """Bias instability is a first-order Gauss-Markov process: stationary std equal to the
    spec (within 15 %) and autocorrelation exp(-1) at a lag of one correlation time."""
    sp = grade_specs("tactical").with_(gyro_bias_instability=1e-4, accel_bias_instability=1e-3,
                                       bias_correlation_time=1.0)
    r = simulate(600.0, specs=sp, seed=5)
    for drift, sigma in ((r.gyro_drift, 1e-4), (r.accel_drift, 1e-3)):
        assert np.allclose(np.std(drift, axis=0), sigma, rtol=0.15)
        x = drift - drift.mean(axis=0)
        lag = int(round(1.0 * r.rate))
        rho = np.sum(x[lag:] * x[:-lag], axis=0) / np.sum(x * x, axis=0)
        assert np.allclose(rho, np.exp(-1.0), atol=0.08)
    assert np.allclose(r.gyro - r.gyro_ideal - r.gyro_bias - r.gyro_drift, 0.0, atol=0.02)
    off = simulate(10.0, specs=sp, seed=5, noise=False)
    assert np.all(off.gyro_drift == 0.0) and np.all(off.gyro == off.gyro_ideal + off.gyro_bias)


def test_gauss_markov_recursion_every_sample():
    """The wander obeys b_k = a b_{k-1} + sqrt(1 - a^2) sigma w_k at every sample, internal
    chunk boundaries included: the innovations are white with the right std, none is an outlier."""
    tau, sigma = 100.0, 1e-4
    sp = grade_specs("tactical").with_(gyro_bias_instability=sigma, bias_correlation_time=tau)
    r = simulate(600.0, specs=sp, seed=8)
    a = np.exp(-r.dt / tau)
    c = np.sqrt(1.0 - a * a) * sigma
    e = r.gyro_drift[1:] - a * r.gyro_drift[:-1]
    assert np.allclose(np.std(e, axis=0), c, rtol=0.03)
    assert np.max(np.abs(e)) < 6.0 * c


@pytest.mark.parametrize("a", [0.0, 0.5, 0.999])
def test_ar1_scan_matches_recursion(a):
    """The vectorised Gauss-Markov scan equals the plain recursion y_j = a y_{j-1} + u_j,
    also when it must split the block to avoid overflow (small a)."""
    rng = np.random.default_rng(1)
    u = rng.standard_normal((4096, 3))
    y0 = rng.standard_normal(3)
    ref = np.empty_like(u)
    y = y0
    for j in range(len(u)):
        y = a * y + u[j]
        ref[j] = y
    assert np.allclose(_ar1_scan(y0, u, a), ref, rtol=1e-12, atol=1e-12)


def test_quantization_carries_residual():
    """Quantised increments are integer multiples of the quantum, and the running sum of the
    quantised increments stays within half a quantum of the unquantised one: nothing is lost."""
    qg, qa = 1e-6, 1e-3
    sp = grade_specs("navigation").with_(gyro_quantization=qg, accel_quantization=qa)
    kw = dict(specs=sp, sway="car", noise=False, seed=2)
    r = simulate(100.0, **kw)
    raw = simulate(100.0, **dict(kw, specs=grade_specs("navigation")))
    for out, ref, q in ((r.gyro, raw.gyro, qg), (r.accel, raw.accel, qa)):
        counts = out * r.dt / q
        assert np.allclose(counts, np.round(counts), rtol=0, atol=1e-6)
        diff = np.cumsum(out * r.dt, axis=0) - np.cumsum(ref * r.dt, axis=0)
        assert np.max(np.abs(diff)) <= 0.5 * q * (1 + 1e-6) + 1e-9
        assert np.max(np.abs(out - ref)) > 0.1 * q / r.dt      # quantisation is applied


def test_seed_determinism():
    """Same seed => bit-identical samples and truth; a different seed => different noise,
    biases and sway realisation."""
    kw = dict(duration=60.0, specs="tactical", sway="car")
    a, b, c = simulate(seed=11, **kw), simulate(seed=11, **kw), simulate(seed=12, **kw)
    for name in ("gyro", "accel", "C_true", "v_true", "gyro_bias", "accel_bias"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert not np.array_equal(a.gyro, c.gyro)
    assert not np.array_equal(a.gyro_bias, c.gyro_bias)
    assert not np.array_equal(a.C_true, c.C_true)


def test_streaming_equals_batch():
    """ImuSimulator.next_block calls of varying sizes, concatenated, are bit-identical to
    simulate() with the same arguments (noise, wander, quantisation and bursts included)."""
    sp = grade_specs("tactical").with_(gyro_bias_instability=1e-5, accel_bias_instability=1e-4,
                                       bias_correlation_time=2.0, gyro_quantization=1e-7,
                                       accel_quantization=1e-4)
    args = dict(rate=100.0, lat_deg=-20.0, height_m=30.0, rpy_deg=(5.0, 170.0, -60.0),
                specs=sp, sway="car", sway_amplitude=1.5, seed=99, t0=12.5)
    batch = simulate(200.0, **args)
    sim = ImuSimulator(**args)
    sizes = [1, 7, 0, 100, 4095, 3, 5000, 1, 4096, 2500]
    sizes.append(len(batch) - sum(sizes))
    blocks = [sim.next_block(n) for n in sizes]
    assert [len(b) for b in blocks] == sizes
    for name in ("t", "gyro", "accel", "C_true", "quat_true", "v_true", "p_true"):
        joined = np.concatenate([getattr(b, name) for b in blocks])
        assert np.array_equal(joined, getattr(batch, name)), name
    assert np.array_equal(blocks[-1].C0, batch.C0)
    assert np.array_equal(blocks[0].gyro_bias, batch.gyro_bias)


def test_presets_exist_and_bad_arguments_raise():
    """The 'none', 'car' and 'ship' presets exist; unknown names and bad numbers raise
    ValueError with a message naming the problem."""
    assert {"none", "car", "ship"} <= set(SWAY_PRESETS)
    assert sway_profile("none").is_static
    assert sway_profile("ship", 0.5).ang_amp[0] == pytest.approx(1.5 * DEG)
    bad_profiles = [(("boat",), "unknown sway"), (("car", -1.0), "amplitude"),
                    (("car", float("nan")), "amplitude")]
    for args, msg in bad_profiles:
        with pytest.raises(ValueError, match=msg):
            sway_profile(*args)
    bad_sims = [
        (dict(duration=0.0), "duration"), (dict(duration=-1.0), "duration"),
        (dict(duration=1.0, rate=0.0), "rate"), (dict(duration=1.0, rate=float("inf")), "rate"),
        (dict(duration=1.0, lat_deg=90.5), "lat_deg"),
        (dict(duration=1.0, lat_deg=float("nan")), "lat_deg"),
        (dict(duration=1.0, height_m=float("nan")), "height_m"),
        (dict(duration=1.0, rpy_deg=(0.0, 0.0)), "rpy_deg"),
        (dict(duration=1.0, specs="spacegrade"), "grade"),
        (dict(duration=1.0, sway="boat"), "sway"),
        (dict(duration=1.0, sway_amplitude=-2.0), "amplitude"),
        (dict(duration=1.0, gyro_bias=(0.0, np.inf, 0.0)), "gyro_bias"),
        (dict(duration=0.001, rate=100.0), "shorter than one sample"),
    ]
    for kw, msg in bad_sims:
        with pytest.raises(ValueError, match=msg):
            simulate(**kw)
    with pytest.raises(ValueError, match="n must be"):
        ImuSimulator().next_block(-1)
    with pytest.raises(ValueError, match="burst_damping"):
        SwayProfile(burst_damping=1.5)


def test_child_streams_are_the_spawned_ones():
    """Each child stream a run makes on its own is the generator default_rng(seed).spawn(8)
    gives at that position, so 'everything comes from default_rng(seed)' stays true."""
    for seed in (0, 7, 2 ** 40 + 3):
        spawned = np.random.default_rng(seed).spawn(len(_STREAMS))
        for i, name in enumerate(_STREAMS):
            own = _stream(np.random.SeedSequence(seed), name)
            assert np.array_equal(own.standard_normal(50), spawned[i].standard_normal(50)), name
    assert not np.array_equal(_stream(np.random.SeedSequence(1), "gyro_noise").random(5),
                              _stream(np.random.SeedSequence(1), "accel_noise").random(5))


WANDER = grade_specs("tactical").with_(gyro_bias_instability=1e-5, accel_bias_instability=1e-4,
                                       bias_correlation_time=2.0, gyro_quantization=1e-7,
                                       accel_quantization=1e-4)
_RUNS_CASES = {
    # name: (duration, sway, random truth, fixed biases, extra simulate() arguments)
    "static": (50.0, "none", False, False, {}),
    "static-fixed-biases": (50.0, "none", False, True, {}),
    "static-random-truth": (50.0, "none", True, False, {}),
    "static-random-truth-fixed-biases": (50.0, "none", True, True, {}),
    "car": (45.0, "car", False, False, {}),
    "car-fixed-biases": (45.0, "car", False, True, {}),
    "car-random-truth": (45.0, "car", True, False, {}),
    "ship-random-truth-fixed-biases": (45.0, "ship", True, True, {"specs": "consumer"}),
    "wander-quantised-200hz": (30.0, "car", True, False,
                               {"specs": WANDER, "rate": 200.0, "lat_deg": -20.0, "t0": 12.5}),
    "static-wander-quantised": (45.0, "none", False, True, {"specs": WANDER}),
    "noise-free": (45.0, "ship", False, False, {"noise": False, "height_m": 300.0}),
}


@pytest.mark.parametrize("case", list(_RUNS_CASES))
def test_simulate_runs_is_simulate_run_by_run(case, monkeypatch):
    """simulate_runs(seeds) gives every run bit for bit what simulate(seed=seeds[i]) gives:
    samples (over more than one internal chunk), C0, biases, C_true at the requested samples;
    with shared or per-run attitude and biases, with and without sway, with wander and
    quantisation. Small vectorisation blocks make several blocks of runs per chunk."""
    duration, sway, random_truth, fixed, extra = _RUNS_CASES[case]
    monkeypatch.setattr(sim_module, "_BLOCK", 3 * 4096)
    monkeypatch.setattr(sim_module, "_BLOCK_SWAY", 3 * 4096)
    seeds = [5, 6, 7, 8, 9, 10, 11]
    rng = np.random.default_rng(3)
    rpy = rng.uniform(-180.0, 180.0, (len(seeds), 3)) if random_truth else RPY
    bias = dict(gyro_bias=rng.normal(0.0, 1e-6, (len(seeds), 3)), accel_bias=(1e-3, -2e-3, 5e-4)
                ) if fixed else {}
    kw = dict(sway=sway, **extra)
    n_samples = int(duration * kw.get("rate", 100.0))
    truth_at = [0, 1, 4095, 4096, n_samples - 1]
    r = simulate_runs(duration, seeds, rpy_deg=rpy, truth_at=truth_at, **bias, **kw)
    assert r.gyro.shape == r.accel.shape == (n_samples, len(seeds), 3) and n_samples > 4096
    assert r.C_true.shape == (len(truth_at), len(seeds), 3, 3)
    for i, seed in enumerate(seeds):
        one = simulate(duration, seed=seed, rpy_deg=rpy[i] if random_truth else rpy,
                       **{k: np.broadcast_to(v, (len(seeds), 3))[i] for k, v in bias.items()},
                       **kw)
        pairs = [("gyro", r.gyro[:, i], one.gyro), ("accel", r.accel[:, i], one.accel),
                 ("C0", r.C0[i], one.C0), ("C_true", r.C_true[:, i], one.C_true[truth_at]),
                 ("gyro_bias", r.gyro_bias[i], one.gyro_bias),
                 ("accel_bias", r.accel_bias[i], one.accel_bias), ("t", r.t, one.t)]
        for name, got, want in pairs:
            assert np.array_equal(got, want), (name, i)
    # the runs differ (own noise or biases, own sway)
    assert not np.array_equal(r.gyro[:, 0], r.gyro[:, 1])
    if sway != "none":
        assert not np.array_equal(r.C_true[:, 0], r.C_true[:, 1])


def test_simulate_runs_bad_arguments():
    """No seeds, wrong shapes, truth_at out of range and the usual bad numbers raise."""
    bad = [(dict(seeds=[]), "seeds"), (dict(rpy_deg=np.zeros((3, 3))), "rpy_deg"),
           (dict(gyro_bias=np.zeros((2, 2))), "gyro_bias"), (dict(truth_at=[100]), "truth_at"),
           (dict(truth_at=[-1]), "truth_at"), (dict(seeds=[1, 1.5]), "seed"),
           (dict(rate=0.0), "rate"), (dict(duration=0.001), "shorter than one sample")]
    for kw, msg in bad:
        args = dict(duration=1.0, seeds=[1, 2]) | kw
        with pytest.raises(ValueError, match=msg):
            simulate_runs(**args)
