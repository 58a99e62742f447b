"""Tests for the simulator's disturbances (sins_align.sim.simulator): tones and their combination,
transient events (shove, door slam, re-level), the new ship presets, and stream faults
(corrupt). The kinematics must stay exact: the samples re-integrate to the truth."""
from __future__ import annotations

import numpy as np
import pytest

from sins_align.core.earth import earth_rate_enu, gravity_enu
from sins_align.core.rotation import dcm_from_rpy, so3_exp, so3_log
from sins_align.sim.simulator import (SWAY_PRESETS, Event, SimResult, SwayProfile, Tone, combine,
                                      corrupt, door_slam, relevel, shove, simulate, simulate_runs,
                                      tone, with_events)
from sins_align.core.specs import DEG

RPY = (30.0, -50.0, 120.0)
ZERO = np.zeros(3)


def _clean(duration: float, sway, **kw) -> SimResult:
    return simulate(duration, rpy_deg=RPY, sway=sway, noise=False, gyro_bias=ZERO,
                    accel_bias=ZERO, **kw)


def _reintegrate(r: SimResult):
    """Damped mechanization from the true initial state: worst attitude error (rad) and worst
    velocity error (m/s) against the truth."""
    E = so3_exp(-earth_rate_enu(r.lat_rad) * r.dt)
    steps = so3_exp(r.gyro * r.dt)
    C = r.C0.copy()
    Cs = np.empty_like(r.C_true)
    for k in range(len(r)):
        C = E @ C @ steps[k]
        Cs[k] = C
    att = float(np.max(np.linalg.norm(so3_log(r.C_true @ np.swapaxes(Cs, -1, -2)), axis=-1)))
    g_n = gravity_enu(r.lat_rad, r.height_m)
    v = r.v0 + np.cumsum((np.einsum("kij,kj->ki", Cs, r.accel) + g_n) * r.dt, axis=0)
    return att, float(np.max(np.abs(v - r.v_true)))


EVENTFUL = {
    "tones": combine(tone("angular", 0, 0.7, 0.1), tone("linear", 2, 2.2, 0.5),
                     tone("linear", 0, 2.5, 0.3), tone("angular", 0, 5.0, 0.05),
                     SwayProfile(lever_arm=(0.5, 0.3, 0.4))),
    "events": with_events(SwayProfile(lever_arm=(0.5, -0.3, 0.4)),
                          shove(10.0, accel=3.0, duration=0.4, direction=(1.0, 1.0, 0.0),
                                jolt_deg=0.3, jolt_axis=1),
                          door_slam(20.0), relevel(30.0, 2.0, axis=0, duration=1.5),
                          relevel(40.0, -3.0, axis=2, duration=1.0)),
    "ship_heave": "ship_heave",
    "moored_ship": "moored_ship",
    "car+events": with_events("car", shove(15.0), door_slam(25.0), relevel(35.0, 1.0, 1)),
}


@pytest.mark.parametrize("name", list(EVENTFUL))
def test_disturbed_samples_reintegrate_truth(name):
    """Through the damped mechanization, the error-free samples reproduce the true attitude to
    1e-9 rad and the true velocity to 1e-9 m/s, whatever the disturbance."""
    r = _clean(60.0, EVENTFUL[name])
    att, vel = _reintegrate(r)
    assert att < 1e-9 and vel < 1e-9
    # there is something to reproduce
    assert np.max(np.linalg.norm(so3_log(r.C0.T @ r.C_true), axis=-1)) > 5e-4
    assert np.max(np.abs(r.v_true)) > 1e-3


def test_tone_amplitudes():
    """tone(): angular amplitude in deg about a body axis, linear amplitude given as peak
    acceleration (displacement a/(2 pi f)^2)."""
    p = tone("linear", 1, 2.0, 1.0)
    assert p.lin_amp[1] == pytest.approx(1.0 / (4.0 * np.pi) ** 2) and p.lin_freq[1] == 2.0
    r = _clean(20.0, p, rate=1000.0)
    acc = np.diff(r.v_true[:, 1]) * r.rate
    assert np.max(np.abs(acc)) == pytest.approx(1.0, rel=2e-3)
    r = _clean(20.0, tone("angular", 2, 0.5, 3.0))
    th = so3_log(dcm_from_rpy(np.radians(RPY)).T @ r.C_true)
    assert np.degrees(np.max(np.abs(th[:, 2]))) == pytest.approx(3.0, rel=1e-3)
    assert np.max(np.abs(th[:, :2])) < 1e-12
    with pytest.raises(ValueError, match="kind"):
        tone("spin", 0, 1.0, 1.0)
    with pytest.raises(ValueError, match="axis"):
        tone("angular", 3, 1.0, 1.0)


def test_combine_same_axis_two_frequencies():
    """Two tones on the same axis add up: the second becomes a Tone, and the motion is the sum
    (the second one's phase is 0, the first keeps its seeded phase)."""
    a = tone("angular", 0, 0.5, 1.0)
    b = tone("angular", 0, 3.0, 0.2)
    c = combine(a, b)
    assert c.ang_amp[0] == a.ang_amp[0] and c.ang_freq[0] == 0.5
    assert c.tones == (Tone("angular", 0, 3.0, 0.2 * DEG),)
    C_ref = dcm_from_rpy(np.radians(RPY))
    ra, rc = _clean(10.0, a), _clean(10.0, c)
    th_a = so3_log(C_ref.T @ ra.C_true)[:, 0]
    th_c = so3_log(C_ref.T @ rc.C_true)[:, 0]
    expect = th_a + 0.2 * DEG * np.sin(2.0 * np.pi * 3.0 * (ra.t - 0.0))
    assert np.max(np.abs(th_c - expect)) < 1e-12
    lin = combine(tone("linear", 2, 2.0, 0.5), tone("angular", 1, 1.0, 0.1))
    assert lin.lin_amp[2] > 0 and lin.ang_amp[1] > 0 and lin.tones == ()
    with pytest.raises(ValueError, match="bursts"):
        combine("car", "car")
    with pytest.raises(ValueError, match="lever"):
        combine("car", "ship")


def test_shove_velocity_returns_to_zero():
    """A shove accelerates the base with the requested peak (+ then -) along its direction,
    the velocity returns to zero and the displacement stays bounded; the jolt returns the
    attitude to where it was."""
    ev = shove(5.0, accel=3.0, duration=0.4, direction=(0.0, 1.0, 0.0), jolt_deg=0.3,
               jolt_axis=0)
    r = _clean(10.0, with_events(SwayProfile(), ev), rate=1000.0)
    acc = np.diff(r.v_true, axis=0) * r.rate
    assert np.max(acc[:, 1]) == pytest.approx(3.0, rel=1e-3)
    assert np.min(acc[:, 1]) == pytest.approx(-3.0, rel=1e-3)
    assert np.max(np.abs(acc[:, [0, 2]])) < 1e-9
    during = (r.t > 5.0) & (r.t < 5.4)
    after = r.t >= 5.4
    assert np.max(np.abs(r.v_true[during, 1])) > 0.2
    assert np.max(np.abs(r.v_true[after])) == 0.0
    assert np.all(np.abs(r.p_true[:, 1]) < 0.1)
    assert r.p_true[-1, 1] == pytest.approx(3.0 * 0.16 / 7.5131884, rel=1e-6)
    C_ref = dcm_from_rpy(np.radians(RPY))
    th = so3_log(C_ref.T @ r.C_true)
    assert np.degrees(np.max(np.abs(th[:, 0]))) == pytest.approx(0.3, rel=1e-3)
    assert np.max(np.abs(so3_log(C_ref.T @ r.C_true[after]))) == 0.0


def test_door_slam_is_short_and_returns():
    """A door slam is a ~0.1 s pulse: peak angle and peak acceleration as requested, and the
    base is back where it was afterwards."""
    ev = door_slam(2.0, angle_deg=0.5, accel=5.0, duration=0.1, axis=0, direction=(1, 0, 0))
    r = _clean(4.0, with_events(SwayProfile(), ev), rate=1000.0)
    acc = np.diff(r.v_true, axis=0) * r.rate
    assert np.max(np.abs(acc[:, 0])) == pytest.approx(5.0, rel=3e-3)
    C_ref = dcm_from_rpy(np.radians(RPY))
    th = so3_log(C_ref.T @ r.C_true)
    assert np.degrees(np.max(np.abs(th[:, 0]))) == pytest.approx(0.5, rel=1e-6)
    moving = np.flatnonzero(np.abs(th[:, 0]) > 0)
    assert r.t[moving[0]] > 2.0 and r.t[moving[-1]] < 2.1
    assert np.all(r.p_true[r.t >= 2.1] == 0.0) and np.all(r.C_true[-1] == C_ref)


@pytest.mark.parametrize("axis,angle", [(0, 2.0), (1, -1.0), (2, 3.0)])
def test_relevel_changes_attitude_for_good(axis, angle):
    """A re-level turns the true attitude by the requested angle about the body axis and it
    stays there: C_after = C_before exp(angle e_axis)."""
    r = _clean(10.0, with_events(SwayProfile(), relevel(3.0, angle, axis, duration=1.5)))
    C_ref = dcm_from_rpy(np.radians(RPY))
    rot = np.zeros(3)
    rot[axis] = angle * DEG
    before, after = r.t <= 3.0, r.t >= 4.5
    assert np.all(r.C_true[before] == C_ref)
    assert np.max(np.abs(r.C_true[after] - C_ref @ so3_exp(rot))) < 1e-15
    ang = np.linalg.norm(so3_log(C_ref.T @ r.C_true[-1]))
    assert np.degrees(ang) == pytest.approx(abs(angle), rel=1e-12)
    # the rate profile is smooth: sample-to-sample gyro steps stay within the peak angular
    # acceleration (angle max|S''| / T^2) times dt, far below the peak rate (2.19 angle / T)
    dg = np.max(np.abs(np.diff(r.gyro, axis=0)))
    assert dg < 1.01 * abs(angle) * DEG * 7.5131884 / 1.5 ** 2 * r.dt
    assert np.max(np.abs(r.gyro)) > 2.18 * abs(angle) * DEG / 1.5


def test_events_and_presets_scale_and_keep_old_presets():
    """Amplitude 0 makes an event profile static; presets 'ship_heave' and 'moored_ship' move
    as advertised; the old presets are unchanged objects of the old fields."""
    p = with_events("none", shove(1.0), relevel(2.0))
    assert not p.is_static and p.scaled(0.0).is_static
    assert SWAY_PRESETS["ship"].tones == () and SWAY_PRESETS["ship"].events == ()
    C_ref = dcm_from_rpy(np.radians(RPY))
    for name, peak in (("ship_heave", [4.0, 2.0, 0.7]), ("moored_ship", [1.0, 0.4, 0.2])):
        r = _clean(120.0, name)
        th = np.degrees(np.max(np.abs(so3_log(C_ref.T @ r.C_true)), axis=0))
        assert np.allclose(th, peak, rtol=0.02)
    heave = _clean(120.0, "ship_heave")
    assert 0.3 < np.max(np.abs(heave.p_true[:, 2])) < 6.0
    with pytest.raises(ValueError, match="duration"):
        Event(duration=0.0)
    with pytest.raises(ValueError, match="events"):
        SwayProfile(events=(1,))


def test_events_in_simulate_runs_match_simulate():
    """Events flow through simulate_runs like any sway: run i is simulate(seed=seeds[i])."""
    p = with_events("car", shove(3.0), relevel(6.0, 1.5, 1))
    runs = simulate_runs(10.0, seeds=[1, 2], sway=p, rpy_deg=RPY, truth_at=[999])
    for i, s in enumerate((1, 2)):
        r = simulate(10.0, sway=p, rpy_deg=RPY, seed=s)
        assert np.array_equal(runs.gyro[:, i], r.gyro)
        assert np.array_equal(runs.C_true[0, i], r.C_true[999])


def test_corrupt_drops_and_shifts():
    """corrupt() loses and re-stamps exactly what it says, keeps the data of kept samples and
    slices the truth along; it is deterministic with a seed and pure."""
    r = simulate(100.0, sway="car", seed=4)
    t0 = r.t.copy()
    s = corrupt(r.t, r.gyro, r.accel, r, rng=7, drop_bursts=[(10.0, 5)], gap=[(20.0, 3.0)],
                drop_samples=[30.0], time_jump=[(50.0, 2.5)],
                wild_stamp=[(60.0, 1000.0), (70.0, -1000.0)])
    assert np.array_equal(r.t, t0)
    lost = np.setdiff1d(np.arange(len(r)), s.index)
    k10 = int(np.searchsorted(r.t, 10.0))
    expect = set(range(k10, k10 + 5)) | set(np.flatnonzero((r.t >= 20.0) & (r.t < 23.0)))
    expect |= {int(np.searchsorted(r.t, 30.0))}
    assert set(lost.tolist()) == expect and s.dropped == len(expect) == 5 + 300 + 1
    assert np.array_equal(s.gyro, r.gyro[s.index]) and np.array_equal(s.t_true, r.t[s.index])
    assert np.array_equal(s.truth["C_true"], r.C_true[s.index])
    shift = s.t - s.t_true
    assert np.flatnonzero(s.wild).tolist() == [int(np.searchsorted(s.t_true, 60.0)),
                                              int(np.searchsorted(s.t_true, 70.0))]
    expect_shift = np.where(s.t_true >= 50.0, 2.5, 0.0)
    expect_shift[s.wild] += np.array([1000.0, -1000.0])
    assert np.allclose(shift, expect_shift, rtol=0, atol=1e-9)
    # random loss: about the fraction asked, deterministic with the seed
    a = corrupt(r.t, r.gyro, r.accel, None, rng=3, drop_fraction=0.1)
    b = corrupt(r.t, r.gyro, r.accel, None, rng=3, drop_fraction=0.1)
    c = corrupt(r.t, r.gyro, r.accel, None, rng=4, drop_fraction=0.1)
    assert np.array_equal(a.index, b.index) and not np.array_equal(a.index, c.index)
    assert 0.08 < a.dropped / len(r) < 0.12 and a.truth is None
    assert np.array_equal(a.t, a.t_true)
    with pytest.raises(ValueError, match="drop_fraction"):
        corrupt(r.t, r.gyro, r.accel, drop_fraction=1.5)
