"""IMU simulator for a quasi-static base (numpy only, no ROS).

Generates gyro and accelerometer samples of a strapdown IMU sitting at a fixed latitude and
height, optionally swaying (a parked car being boarded, a moored ship), with sensor errors.

Frames and conventions (ALGORITHM.md)
-------------------------------------
- n = ENU, fixed to the Earth, so it rotates with ``omega_ie^n`` relative to inertial space.
- b = the IMU's own axes. ``C_b^n`` rotates body vectors into ENU.
- True attitude: ``C_b^n(t) = C_ref · exp((theta(t) x))`` where ``C_ref = dcm_from_rpy(rpy)``
  is the mean (undisturbed) attitude and ``theta(t)`` (rad, about the body axes) is the sway,
  a smooth bounded analytic function of the time since ``t0``. ``C0 = C_b^n(t0)``, so the truth
  is also ``C0 · (exp(theta(t0)) ^T exp(theta(t)))``.
- True position of the IMU (ENU, m, relative to its mean position):
  ``p(t) = d(t) + C_ref (exp((theta(t) x)) - I) l^b`` — linear vibration ``d(t)`` of the rotation
  centre plus the lever-arm effect of the angular sway, lever arm ``l^b`` from the rotation
  centre to the IMU in body axes. ``v_true = dp/dt`` analytically.

Sensor model (exact for the damped mechanization of ALGORITHM.md)
-----------------------------------------------------------------
The error-free gyro sample ``k`` is the rotation-vector increment of the body w.r.t. inertial
space over ``(t[k-1], t[k]]`` divided by ``dt``::

    dC_k = C_{k-1}^T exp((omega_ie^n x) dt) C_k,       w_k = log(dC_k) / dt

so ``C_k = exp(-(omega_ie^n x) dt) C_{k-1} exp((w_k x) dt)`` reproduces the truth to round-off.
The error-free specific force makes ``v_k = v_{k-1} + (C_k f_k + g^n) dt`` reproduce ``v_true``::

    f_k = C_k^T ((v_true[k] - v_true[k-1]) / dt - g^n)

(the damped mechanization has no Coriolis or transport terms, and neither has this model).
Errors added: constant bias, white noise (``arw / sqrt(dt)``, ``vrw / sqrt(dt)`` per sample),
optional first-order Gauss-Markov bias wander, optional quantisation of the increments with the
residual carried forward.

Determinism
-----------
Everything random comes from ``np.random.default_rng(seed)`` split into independent child
streams (sway, biases, gyro noise, accel noise, gyro wander, accel wander); a run makes only
the streams it uses. Samples are produced in fixed chunks of ``_CHUNK`` samples aligned to
sample 0, so :class:`ImuSimulator` streaming ``next_block`` calls of any sizes give
bit-identical samples to :func:`simulate`.

Many runs
---------
:func:`simulate_runs` simulates n runs on one time line with the same engine, vectorised
across runs: run ``i`` is bit for bit ``simulate(..., seed=seeds[i])``. Without sway the truth
does not depend on time, so the error-free samples are computed for one interval only (shared
by the runs unless the attitude is per run) and broadcast, and each run only adds its biases
and noise, drawn straight into a reused buffer; with sway each run's truth is computed, for
blocks of runs at a time.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from sins_align.core.earth import earth_rate_enu, gravity_enu
from sins_align.core.rotation import dcm_from_rpy, quat_from_dcm, skew, so3_exp, so3_log
from sins_align.core.specs import SensorSpecs, grade_specs

__all__ = ["SwayProfile", "SWAY_PRESETS", "sway_profile", "SimResult", "simulate",
           "ImuSimulator", "RunsResult", "simulate_runs", "Tone", "Event", "tone", "combine",
           "with_events", "shove", "door_slam", "relevel", "Stream", "corrupt"]

_DEG = np.pi / 180.0
#: Samples generated per internal chunk (fixed so that streaming == batch bit for bit).
_CHUNK = 4096
#: Burst envelopes are cut where ``exp(-sigma s)`` falls below ``exp(-_BURST_CUT)`` (~1e-14).
_BURST_CUT = 32.0


def _vec3(x, name: str) -> tuple[float, float, float]:
    a = np.asarray(x, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers, got {x!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


_KINDS = ("angular", "linear")


@dataclass(frozen=True)
class Tone:
    """One extra sinusoid of a :class:`SwayProfile` (beyond its one per axis and kind).

    ``theta_axis(t) += amp sin(2 pi freq t + phase)`` (kind 'angular', amp in rad, body axis)
    or ``d_axis(t) += amp sin(2 pi freq t + phase)`` (kind 'linear', amp in m, ENU axis).
    The phase is fixed (not drawn from the seed).
    """

    kind: str
    axis: int
    freq: float
    amp: float
    phase: float = 0.0

    def __post_init__(self):
        if self.kind not in _KINDS:
            raise ValueError(f"Tone.kind must be one of {_KINDS}, got {self.kind!r}")
        if isinstance(self.axis, bool) or self.axis not in (0, 1, 2):
            raise ValueError(f"Tone.axis must be 0, 1 or 2, got {self.axis!r}")
        for nm in ("freq", "amp", "phase"):
            object.__setattr__(self, nm, _finite(getattr(self, nm), f"Tone.{nm}"))
        if self.freq <= 0.0 or self.amp < 0.0:
            raise ValueError(f"Tone needs freq > 0 and amp >= 0, got {self.freq!r}, {self.amp!r}")


def _smoothstep(x: np.ndarray):
    """7th-order smoothstep S(x) on [0, 1] (0 before, 1 after) and dS/dx; C3 at both ends."""
    x = np.clip(x, 0.0, 1.0)
    y = x * (1.0 - x)
    return x ** 4 * (35.0 - 84.0 * x + 70.0 * x * x - 20.0 * x ** 3), 140.0 * y ** 3


def _bump(x: np.ndarray):
    """Bump ``256 (x (1 - x))^4`` on [0, 1] (0 outside, peak 1 at x = 1/2) and its derivative;
    C3 at both ends."""
    x = np.clip(x, 0.0, 1.0)
    y = x * (1.0 - x)
    return 256.0 * y ** 4, 1024.0 * y ** 3 * (1.0 - 2.0 * x)


@functools.cache
def _peak_second_derivative(kind: str) -> float:
    x = np.linspace(0.0, 1.0, 200001)
    y = x * (1.0 - x)
    d2 = (420.0 * y * y * (1.0 - 2.0 * x) if kind == "step"
          else 1024.0 * (3.0 * y * y * (1.0 - 2.0 * x) ** 2 - 2.0 * y ** 3))
    return float(np.max(np.abs(d2)))


# max |S''| of the smoothstep (about 7.513) and max |b''| of the bump (32, at the centre),
# ``_peak_second_derivative("step" | "bump")``, computed when first needed (7 ms of every
# import otherwise, align_node's included): a profile ``D S(s / T)`` has peak acceleration
# ``D max|S''| / T^2``.


@dataclass(frozen=True)
class Event:
    """A transient of the base, starting ``onset`` s after t0 and lasting ``duration`` s.

    Over ``x = (s - onset) / duration`` in [0, 1] it adds to the sway rotation vector (body
    axes, rad) and to the displacement of the rotation centre (ENU, m)::

        theta += ang_pulse b(x) + ang_step S(x)      d += lin_pulse b(x) + lin_step S(x)

    with the bump ``b`` (returns to 0, peak 1 at x = 1/2) and the smoothstep ``S`` (0 -> 1 and
    stays), both C3: angle, rate, displacement, velocity and acceleration stay continuous, the
    velocity returns to zero, and an ``ang_step`` changes the true attitude for good.
    Build them with :func:`shove`, :func:`door_slam` and :func:`relevel`.
    """

    kind: str = "custom"
    onset: float = 0.0
    duration: float = 1.0
    ang_pulse: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ang_step: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lin_pulse: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lin_step: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        object.__setattr__(self, "onset", _finite(self.onset, "Event.onset"))
        object.__setattr__(self, "duration", _finite(self.duration, "Event.duration"))
        if self.duration <= 0.0:
            raise ValueError(f"Event.duration must be > 0 s, got {self.duration!r}")
        for nm in ("ang_pulse", "ang_step", "lin_pulse", "lin_step"):
            object.__setattr__(self, nm, _vec3(getattr(self, nm), f"Event.{nm}"))

    def scaled(self, amplitude: float) -> Event:
        """Copy with every amplitude multiplied by ``amplitude``."""
        def s(v):
            return tuple(amplitude * x for x in v)
        return replace(self, ang_pulse=s(self.ang_pulse), ang_step=s(self.ang_step),
                       lin_pulse=s(self.lin_pulse), lin_step=s(self.lin_step))

    @property
    def is_null(self) -> bool:
        """True if the event moves nothing."""
        return max(np.abs(self.ang_pulse + self.ang_step + self.lin_pulse
                          + self.lin_step)) == 0.0

    def evaluate(self, s: np.ndarray):
        """(theta, theta_dot, d, d_dot) increments (M, 3) at times ``s`` (M,) since t0."""
        x = (np.asarray(s, dtype=float) - self.onset) / self.duration
        b, bd = _bump(x)
        S, Sd = _smoothstep(x)
        inside = (x > 0.0) & (x < 1.0)
        bd, Sd = bd * inside / self.duration, Sd * inside / self.duration
        ap, ast = np.array(self.ang_pulse), np.array(self.ang_step)
        lp, lst = np.array(self.lin_pulse), np.array(self.lin_step)
        return (b[:, None] * ap + S[:, None] * ast, bd[:, None] * ap + Sd[:, None] * ast,
                b[:, None] * lp + S[:, None] * lst, bd[:, None] * lp + Sd[:, None] * lst)


def _unit(direction, name: str) -> np.ndarray:
    u = np.array(_vec3(direction, name))
    nrm = np.linalg.norm(u)
    if nrm == 0.0:
        raise ValueError(f"{name} must not be zero")
    return u / nrm


def _axis(axis) -> int:
    if isinstance(axis, bool) or axis not in (0, 1, 2):
        raise ValueError(f"axis must be 0, 1 or 2, got {axis!r}")
    return int(axis)


def shove(onset: float, accel: float = 3.0, duration: float = 0.4,
          direction: Sequence[float] = (1.0, 0.0, 0.0), jolt_deg: float = 0.3,
          jolt_axis: int = 0) -> Event:
    """A horizontal push: the rotation centre accelerates along ``direction`` (ENU) with peak
    ``accel`` m/s^2 (+accel, then -accel) for ``duration`` s; the velocity returns to zero and
    the base ends ``accel duration^2 / 7.513`` m further (bounded displacement). Optional
    angular jolt of peak ``jolt_deg`` about body axis ``jolt_axis`` that returns to the
    original attitude."""
    accel, duration = _finite(accel, "accel"), _finite(duration, "duration")
    if duration <= 0.0:
        raise ValueError(f"duration must be > 0 s, got {duration!r}")
    jolt = np.zeros(3)
    jolt[_axis(jolt_axis)] = _finite(jolt_deg, "jolt_deg") * _DEG
    return Event("shove", onset, duration, ang_pulse=jolt,
                 lin_step=_unit(direction, "direction") * accel * duration ** 2
                 / _peak_second_derivative("step"))


def door_slam(onset: float, angle_deg: float = 0.5, accel: float = 5.0, duration: float = 0.1,
              axis: int = 0, direction: Sequence[float] = (1.0, 0.0, 0.0)) -> Event:
    """A door slam: a short (``duration`` s) angular pulse of peak ``angle_deg`` about body axis
    ``axis`` and a linear pulse of peak acceleration ``accel`` m/s^2 along ``direction`` (ENU);
    attitude and position return to where they were."""
    duration = _finite(duration, "duration")
    if duration <= 0.0:
        raise ValueError(f"duration must be > 0 s, got {duration!r}")
    ang = np.zeros(3)
    ang[_axis(axis)] = _finite(angle_deg, "angle_deg") * _DEG
    return Event("door_slam", onset, duration, ang_pulse=ang,
                 lin_pulse=_unit(direction, "direction") * _finite(accel, "accel")
                 * duration ** 2 / _peak_second_derivative("bump"))


def relevel(onset: float, angle_deg: float = 2.0, axis: int = 0,
            duration: float = 1.5) -> Event:
    """A lasting re-level: the attitude turns by ``angle_deg`` about body axis ``axis`` over
    ``duration`` s and stays there (``C_after = C_before exp(angle e_axis)`` without sway)."""
    ang = np.zeros(3)
    ang[_axis(axis)] = _finite(angle_deg, "angle_deg") * _DEG
    return Event("relevel", onset, duration, ang_step=ang)


@dataclass(frozen=True)
class SwayProfile:
    """Angular sway and linear vibration of a quasi-static base.

    Two kinds of motion, which may be combined:

    - steady sinusoids (a moored ship): ``theta_i(t) = ang_amp_i sin(2 pi ang_freq_i t + phase)``,
      ``d_i(t) = lin_amp_i sin(2 pi lin_freq_i t + phase)``, random phases from the seed;
    - random bursts (a parked car being boarded): onsets form a Poisson process of rate
      ``burst_rate``; each burst is a damped oscillation with smooth (C2) onset,
      ``x(s) = a (1 - exp(-s/burst_onset))^2 exp(-sigma s) sin(omega_d s)``, ``s`` time since onset,
      natural frequency drawn uniformly in ``burst_freq``, damping ratio ``burst_damping``,
      per-axis amplitudes ``a_i = amp_i * U(-1, 1)``.

    Attributes
    ----------
    name : str — label.
    ang_amp : (3,) rad — sinusoid amplitudes about body x, y, z (roll, pitch, yaw for FLU/RFU).
    ang_freq : (3,) Hz — sinusoid frequencies.
    lin_amp : (3,) m — sinusoid displacement amplitudes of the rotation centre on E, N, U.
    lin_freq : (3,) Hz — their frequencies.
    lever_arm : (3,) m, body axes — IMU position relative to the rotation centre.
    burst_rate : 1/s — mean number of bursts per second (0 = no bursts).
    burst_ang_amp : (3,) rad — largest burst angle amplitude about body x, y, z.
    burst_lin_amp : (3,) m — largest burst displacement amplitude on E, N, U.
    burst_freq : (2,) Hz — range of the burst natural frequency.
    burst_damping : — damping ratio zeta of the bursts, in (0, 1).
    burst_onset : s — onset time constant of a burst (> 0).
    tones : extra sinusoids (:class:`Tone`, fixed phases), e.g. a second one on an axis that
        already has one (see :func:`combine`).
    events : transients (:class:`Event`: :func:`shove`, :func:`door_slam`, :func:`relevel`),
        onsets in s since t0.
    """

    name: str = "custom"
    ang_amp: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ang_freq: tuple[float, float, float] = (0.1, 0.1, 0.1)
    lin_amp: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lin_freq: tuple[float, float, float] = (0.1, 0.1, 0.1)
    lever_arm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    burst_rate: float = 0.0
    burst_ang_amp: tuple[float, float, float] = (0.0, 0.0, 0.0)
    burst_lin_amp: tuple[float, float, float] = (0.0, 0.0, 0.0)
    burst_freq: tuple[float, float] = (1.0, 3.0)
    burst_damping: float = 0.2
    burst_onset: float = 0.05
    tones: tuple[Tone, ...] = ()
    events: tuple[Event, ...] = ()

    def __post_init__(self):
        for nm in ("ang_amp", "ang_freq", "lin_amp", "lin_freq", "lever_arm",
                   "burst_ang_amp", "burst_lin_amp"):
            object.__setattr__(self, nm, _vec3(getattr(self, nm), f"SwayProfile.{nm}"))
        for nm in ("ang_amp", "lin_amp", "burst_ang_amp", "burst_lin_amp"):
            if min(getattr(self, nm)) < 0.0:
                raise ValueError(f"SwayProfile.{nm} must be >= 0, got {getattr(self, nm)}")
        for nm in ("ang_freq", "lin_freq"):
            if min(getattr(self, nm)) <= 0.0:
                raise ValueError(f"SwayProfile.{nm} must be > 0 Hz, got {getattr(self, nm)}")
        fr = np.asarray(self.burst_freq, dtype=float)
        if fr.shape != (2,) or not np.all(np.isfinite(fr)) or not 0.0 < fr[0] <= fr[1]:
            raise ValueError(f"SwayProfile.burst_freq must be (lo, hi) Hz with 0 < lo <= hi, "
                             f"got {self.burst_freq!r}")
        object.__setattr__(self, "burst_freq", (float(fr[0]), float(fr[1])))
        if not np.isfinite(self.burst_rate) or self.burst_rate < 0.0:
            raise ValueError(f"SwayProfile.burst_rate must be finite and >= 0, got "
                             f"{self.burst_rate!r}")
        if not 0.0 < self.burst_damping < 1.0:
            raise ValueError(f"SwayProfile.burst_damping must be in (0, 1), got "
                             f"{self.burst_damping!r}")
        if not np.isfinite(self.burst_onset) or self.burst_onset <= 0.0:
            raise ValueError(f"SwayProfile.burst_onset must be > 0 s, got {self.burst_onset!r}")
        object.__setattr__(self, "tones", tuple(self.tones))
        object.__setattr__(self, "events", tuple(self.events))
        if not all(isinstance(x, Tone) for x in self.tones):
            raise ValueError("SwayProfile.tones must hold Tone instances")
        if not all(isinstance(x, Event) for x in self.events):
            raise ValueError("SwayProfile.events must hold Event instances")

    def scaled(self, amplitude: float) -> SwayProfile:
        """Copy with every angular and linear amplitude multiplied by ``amplitude`` (>= 0)."""
        amplitude = _check_amplitude(amplitude)
        if amplitude == 1.0:
            return self

        def s(v: tuple[float, ...]) -> tuple[float, ...]:
            return tuple(amplitude * x for x in v)

        return replace(self, ang_amp=s(self.ang_amp), lin_amp=s(self.lin_amp),
                       burst_ang_amp=s(self.burst_ang_amp), burst_lin_amp=s(self.burst_lin_amp),
                       tones=tuple(replace(x, amp=amplitude * x.amp) for x in self.tones),
                       events=tuple(e.scaled(amplitude) for e in self.events))

    @property
    def is_static(self) -> bool:
        """True if the profile produces no motion at all."""
        bursts = self.burst_rate > 0.0 and max(self.burst_ang_amp + self.burst_lin_amp) > 0.0
        return (not bursts and max(self.ang_amp + self.lin_amp) == 0.0
                and all(x.amp == 0.0 for x in self.tones)
                and all(e.is_null for e in self.events))


def _check_amplitude(amplitude: float) -> float:
    try:
        a = float(amplitude)
    except (TypeError, ValueError):
        raise ValueError(f"sway amplitude must be a number, got {amplitude!r}") from None
    if not np.isfinite(a) or a < 0.0:
        raise ValueError(f"sway amplitude must be finite and >= 0, got {amplitude!r}")
    return a


#: Sway presets. 'car': parked car being boarded (bursts of damped 1-3 Hz oscillations,
#: up to 0.3 deg roll/pitch, mm-level displacement). 'ship': moored ship (roll 3 deg / 8 s,
#: pitch 1 deg / 6 s, yaw 0.5 deg / 12 s; sway/surge/heave 0.3/0.2/0.4 m). 'ship_heave':
#: ship at sea (roll 4 deg / 9 s, pitch 2 deg / 7 s, yaw 0.7 deg / 13 s; E/N/U 0.4/0.3/0.5 m at
#: 11/15/8 s). 'moored_ship': gentler (roll 1 deg / 10 s, pitch 0.4 deg / 8 s, yaw 0.2 deg /
#: 14 s; E/N/U 0.1/0.1/0.2 m at 13/15/9 s).
SWAY_PRESETS: dict[str, SwayProfile] = {
    "none": SwayProfile(name="none"),
    "car": SwayProfile(
        name="car",
        lever_arm=(0.5, 0.3, 0.4),
        burst_rate=0.1,
        burst_ang_amp=(0.3 * _DEG, 0.3 * _DEG, 0.05 * _DEG),
        burst_lin_amp=(1.0e-3, 1.0e-3, 3.0e-3),
        burst_freq=(1.0, 3.0),
        burst_damping=0.2,
        burst_onset=0.05,
    ),
    "ship": SwayProfile(
        name="ship",
        ang_amp=(3.0 * _DEG, 1.0 * _DEG, 0.5 * _DEG),
        ang_freq=(1.0 / 8.0, 1.0 / 6.0, 1.0 / 12.0),
        lin_amp=(0.3, 0.2, 0.4),
        lin_freq=(1.0 / 10.0, 1.0 / 14.0, 1.0 / 7.0),
        lever_arm=(2.0, 0.5, 3.0),
    ),
    # ship at sea with heave, surge and sway (periods 5-15 s)
    "ship_heave": SwayProfile(
        name="ship_heave",
        ang_amp=(4.0 * _DEG, 2.0 * _DEG, 0.7 * _DEG),
        ang_freq=(1.0 / 9.0, 1.0 / 7.0, 1.0 / 13.0),
        lin_amp=(0.4, 0.3, 0.5),
        lin_freq=(1.0 / 11.0, 1.0 / 15.0, 1.0 / 8.0),
        lever_arm=(3.0, 1.0, 5.0),
    ),
    # ship moored in a harbour: gentle
    "moored_ship": SwayProfile(
        name="moored_ship",
        ang_amp=(1.0 * _DEG, 0.4 * _DEG, 0.2 * _DEG),
        ang_freq=(1.0 / 10.0, 1.0 / 8.0, 1.0 / 14.0),
        lin_amp=(0.1, 0.1, 0.2),
        lin_freq=(1.0 / 13.0, 1.0 / 15.0, 1.0 / 9.0),
        lever_arm=(2.0, 0.5, 3.0),
    ),
}


def tone(kind: str, axis: int, freq_hz: float, amplitude: float,
         lever_arm: Sequence[float] = (0.0, 0.0, 0.0)) -> SwayProfile:
    """A pure tone as a SwayProfile (random phase from the seed, as every sinusoid).

    Parameters
    ----------
    kind : 'angular' (``amplitude`` in deg, about body axis ``axis``) or 'linear'
        (``amplitude`` = peak ACCELERATION in m/s^2 along ENU axis ``axis``; the displacement
        amplitude is ``amplitude / (2 pi freq_hz)^2``).
    axis : 0, 1, 2.
    freq_hz : Hz (> 0).
    lever_arm : (3,) m, body — IMU position relative to the rotation centre.
    """
    if kind not in _KINDS:
        raise ValueError(f"kind must be one of {_KINDS}, got {kind!r}")
    axis = _axis(axis)
    f = _finite(freq_hz, "freq_hz")
    a = _finite(amplitude, "amplitude")
    if f <= 0.0 or a < 0.0:
        raise ValueError(f"tone needs freq_hz > 0 and amplitude >= 0, got {freq_hz!r}, "
                         f"{amplitude!r}")
    amp, freq = [0.0, 0.0, 0.0], [0.1, 0.1, 0.1]
    freq[axis] = f
    if kind == "angular":
        amp[axis] = a * _DEG
        return SwayProfile(name=f"tone_ang{axis}_{f:g}Hz", ang_amp=amp, ang_freq=freq,
                           lever_arm=lever_arm)
    amp[axis] = a / (2.0 * np.pi * f) ** 2
    return SwayProfile(name=f"tone_lin{axis}_{f:g}Hz", lin_amp=amp, lin_freq=freq,
                       lever_arm=lever_arm)


def combine(*profiles: SwayProfile | str, name: str | None = None) -> SwayProfile:
    """One profile doing all of ``profiles`` at once (motions add up).

    A sinusoid on an axis (and kind) still free in the result keeps its place and its random
    phase; one on an axis already taken becomes a :class:`Tone` with phase 0. Tones and events
    are concatenated. At most one profile may have bursts, and the non-zero lever arms must
    agree (ValueError otherwise).
    """
    ps = [sway_profile(p) if isinstance(p, str) else p for p in profiles]
    if not ps or not all(isinstance(p, SwayProfile) for p in ps):
        raise ValueError("combine needs at least one SwayProfile (or preset name)")
    out = ps[0]
    for p in ps[1:]:
        kw: dict = {}
        tones = list(out.tones) + list(p.tones)
        for kind, amp_nm, freq_nm in (("angular", "ang_amp", "ang_freq"),
                                      ("linear", "lin_amp", "lin_freq")):
            amp, freq = list(getattr(out, amp_nm)), list(getattr(out, freq_nm))
            for i, (a, f) in enumerate(zip(getattr(p, amp_nm), getattr(p, freq_nm))):
                if a == 0.0:
                    continue
                if amp[i] == 0.0:
                    amp[i], freq[i] = a, f
                else:
                    tones.append(Tone(kind, i, f, a))
            kw[amp_nm], kw[freq_nm] = tuple(amp), tuple(freq)
        p_bursts = p.burst_rate > 0.0 and max(p.burst_ang_amp + p.burst_lin_amp) > 0.0
        if p_bursts:
            if out.burst_rate > 0.0 and max(out.burst_ang_amp + out.burst_lin_amp) > 0.0:
                raise ValueError("combine: only one profile may have bursts")
            kw.update(burst_rate=p.burst_rate, burst_ang_amp=p.burst_ang_amp,
                      burst_lin_amp=p.burst_lin_amp, burst_freq=p.burst_freq,
                      burst_damping=p.burst_damping, burst_onset=p.burst_onset)
        if max(np.abs(p.lever_arm)) > 0.0:
            if max(np.abs(out.lever_arm)) > 0.0 and out.lever_arm != p.lever_arm:
                raise ValueError(f"combine: different lever arms {out.lever_arm} and "
                                 f"{p.lever_arm}")
            kw["lever_arm"] = p.lever_arm
        out = replace(out, tones=tuple(tones), events=out.events + p.events, **kw)
    return replace(out, name=name if name is not None else "+".join(p.name for p in ps))


def with_events(profile: SwayProfile | str, *events: Event) -> SwayProfile:
    """``profile`` (or a preset name) with ``events`` added."""
    p = sway_profile(profile) if isinstance(profile, str) else profile
    return replace(p, events=p.events + tuple(events))


def sway_profile(name: str, amplitude: float = 1.0) -> SwayProfile:
    """Preset sway profile ``name`` ('none', 'car', 'ship', 'ship_heave', 'moored_ship') with
    amplitudes scaled by ``amplitude``.

    Raises
    ------
    ValueError
        Unknown name, or amplitude not finite or negative.
    """
    try:
        base = SWAY_PRESETS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown sway profile {name!r}; choose one of "
                         f"{sorted(SWAY_PRESETS)}") from None
    return base.scaled(amplitude)


@dataclass
class SimResult:
    """A block of simulated IMU samples with the truth.

    Attributes
    ----------
    t : (N,) s — sample stamps, ``t[k] = t0 + (k + 1) / rate`` (k counted from the start).
    gyro : (N, 3) rad/s, body — measured ``w_ib^b``: increment rotation vector over
        ``(t[k-1], t[k]]`` divided by ``dt``, with sensor errors.
    accel : (N, 3) m/s^2, body — measured specific force ``f^b`` (velocity increment / dt).
    C_true : (N, 3, 3) — true ``C_b^n`` (body to ENU) at ``t[k]``.
    quat_true : (N, 4) — ``[x, y, z, w]`` quaternion of ``C_true``.
    C0 : (3, 3) — true ``C_b^n`` at ``t0`` (before the first sample).
    gyro_bias : (3,) rad/s, body — constant gyro bias.
    accel_bias : (3,) m/s^2, body — constant accelerometer bias.
    lat_rad : rad; height_m : m; rate : Hz; specs : SensorSpecs; sway : SwayProfile.
    v_true : (N, 3) m/s, ENU — true velocity of the IMU w.r.t. the Earth.
    p_true : (N, 3) m, ENU — true IMU displacement from its mean position.
    v0 : (3,) m/s, ENU — true velocity at ``t0``.
    gyro_ideal, accel_ideal : (N, 3) — the error-free samples (same units as gyro, accel).
    gyro_drift, accel_drift : (N, 3) — Gauss-Markov bias wander added (zeros when off).
    """

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    C_true: np.ndarray
    quat_true: np.ndarray
    C0: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    lat_rad: float
    height_m: float
    rate: float
    specs: SensorSpecs
    sway: SwayProfile
    v_true: np.ndarray
    p_true: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    v0: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_ideal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    accel_ideal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    gyro_drift: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    accel_drift: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def dt(self) -> float:
        """Sample interval, s."""
        return 1.0 / self.rate

    def __len__(self) -> int:
        return len(self.t)


#: Per-sample array fields of SimResult, in the order the engine produces them.
_ARRAY_FIELDS = ("t", "gyro", "accel", "C_true", "quat_true", "v_true", "p_true",
                 "gyro_ideal", "accel_ideal", "gyro_drift", "accel_drift")


# ----------------------------------------------------------------------------------------------
# Sway kinematics
# ----------------------------------------------------------------------------------------------
def _right_jacobian(theta: np.ndarray) -> np.ndarray:
    """Right Jacobian of SO(3): ``d/dt exp(theta) = exp(theta) (J_r(theta) theta_dot x)``."""
    th2 = np.sum(theta * theta, axis=-1)
    th = np.sqrt(th2)
    small = th < 1e-4
    ths = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th2 / 24.0 + th2 * th2 / 720.0, (1.0 - np.cos(ths)) / (ths * ths))
    b = np.where(small, 1.0 / 6.0 - th2 / 120.0 + th2 * th2 / 5040.0,
                 (ths - np.sin(ths)) / (ths * ths * ths))
    K = skew(theta)
    return np.eye(3) - a[..., None, None] * K + b[..., None, None] * (K @ K)


class _Sway:
    """Deterministic realisations of a SwayProfile for n runs, one sway stream each: angle, rate,
    displacement and velocity at any s (time since t0, s), vectorised across runs.

    Each run's bursts are drawn lazily, in onset order, from its stream, so a realisation does
    not depend on how far ahead it was evaluated. Evaluation times only move forward.
    """

    def __init__(self, profile: SwayProfile, rngs: list[np.random.Generator]):
        self.p = profile
        self.rngs = rngs
        ph = np.array([rng.uniform(0.0, 2.0 * np.pi, size=6) for rng in rngs])
        self.ang_phase, self.lin_phase = ph[:, :3], ph[:, 3:]
        self.ang_amp = np.array(profile.ang_amp)
        self.ang_w = 2.0 * np.pi * np.array(profile.ang_freq)
        self.lin_amp = np.array(profile.lin_amp)
        self.lin_w = 2.0 * np.pi * np.array(profile.lin_freq)
        self.lever = np.array(profile.lever_arm)
        self.has_bursts = profile.burst_rate > 0.0 and (
            max(profile.burst_ang_amp) > 0.0 or max(profile.burst_lin_amp) > 0.0)
        # bursts of each run: rows [onset, sigma, omega_d, a_ang(3), a_lin(3)]
        self.bursts = [np.zeros((0, 9)) for _ in rngs]
        if self.has_bursts:
            wn_lo = 2.0 * np.pi * profile.burst_freq[0]
            self.burst_len = _BURST_CUT / (profile.burst_damping * wn_lo)
            # start the Poisson process early so the motion is already stationary at s = 0
            self._next_onset = [-self.burst_len + rng.exponential(1.0 / profile.burst_rate)
                                for rng in rngs]

    def _extend_bursts(self, j: int, s_max: float) -> None:
        p, rng = self.p, self.rngs[j]
        rows = []
        while self._next_onset[j] <= s_max:
            u = rng.random(7)
            fn = p.burst_freq[0] + (p.burst_freq[1] - p.burst_freq[0]) * u[0]
            wn = 2.0 * np.pi * fn
            sigma = p.burst_damping * wn
            wd = wn * np.sqrt(1.0 - p.burst_damping ** 2)
            a_ang = np.array(p.burst_ang_amp) * (2.0 * u[1:4] - 1.0)
            a_lin = np.array(p.burst_lin_amp) * (2.0 * u[4:7] - 1.0)
            rows.append(np.concatenate([[self._next_onset[j], sigma, wd], a_ang, a_lin]))
            self._next_onset[j] += rng.exponential(1.0 / p.burst_rate)
        if rows:
            self.bursts[j] = np.vstack([self.bursts[j]] + rows)

    def _add_bursts(self, j: int, s: np.ndarray, theta, theta_dot, d, d_dot) -> None:
        """Add run ``j``'s bursts at times ``s`` to its (M, 3) views theta, theta_dot, d, d_dot."""
        self._extend_bursts(j, float(s[-1]))
        tau = self.p.burst_onset
        for row in self.bursts[j]:
            onset, sigma, wd = row[0], row[1], row[2]
            if onset + self.burst_len < s[0] or onset >= s[-1]:
                continue
            i0 = np.searchsorted(s, onset, side="right")
            i1 = np.searchsorted(s, onset + self.burst_len, side="right")
            u = s[i0:i1] - onset
            e1 = np.exp(-u / tau)
            ramp = (1.0 - e1) ** 2
            ramp_dot = 2.0 * (1.0 - e1) * e1 / tau
            dec = np.exp(-sigma * u)
            sn, cs = np.sin(wd * u), np.cos(wd * u)
            h = ramp * dec * sn
            h_dot = dec * (ramp_dot * sn + ramp * (wd * cs - sigma * sn))
            theta[i0:i1] += h[:, None] * row[3:6]
            theta_dot[i0:i1] += h_dot[:, None] * row[3:6]
            d[i0:i1] += h[:, None] * row[6:9]
            d_dot[i0:i1] += h_dot[:, None] * row[6:9]
        # evaluation times only move forward: forget bursts that have died out
        b = self.bursts[j]
        self.bursts[j] = b[b[:, 0] + self.burst_len >= s[0]]

    def evaluate(self, s: np.ndarray, runs: slice):
        """Sway of the runs ``runs`` at times ``s`` (M,) s since t0.

        Returns
        -------
        theta : (M, nr, 3) rad, body — sway rotation vector.
        omega : (M, nr, 3) rad/s, body — sway angular rate (``R' = R (omega x)``).
        d : (M, nr, 3) m, ENU — displacement of the rotation centre.
        d_dot : (M, nr, 3) m/s, ENU — its velocity.
        """
        arg = s[:, None, None] * self.ang_w + self.ang_phase[runs]
        theta = self.ang_amp * np.sin(arg)
        theta_dot = self.ang_amp * self.ang_w * np.cos(arg)
        arg = s[:, None, None] * self.lin_w + self.lin_phase[runs]
        d = self.lin_amp * np.sin(arg)
        d_dot = self.lin_amp * self.lin_w * np.cos(arg)
        if self.has_bursts and len(s):
            for c, j in enumerate(range(*runs.indices(len(self.rngs)))):
                self._add_bursts(j, s, theta[:, c], theta_dot[:, c], d[:, c], d_dot[:, c])
        for x in self.p.tones:
            arg = 2.0 * np.pi * x.freq * s + x.phase
            tgt, tgt_dot = (theta, theta_dot) if x.kind == "angular" else (d, d_dot)
            tgt[:, :, x.axis] += (x.amp * np.sin(arg))[:, None]
            tgt_dot[:, :, x.axis] += (x.amp * 2.0 * np.pi * x.freq * np.cos(arg))[:, None]
        for e in self.p.events:
            if len(s) and s[-1] > e.onset:
                th, th_dot, dd, dd_dot = e.evaluate(s)
                theta += th[:, None]
                theta_dot += th_dot[:, None]
                d += dd[:, None]
                d_dot += dd_dot[:, None]
        omega = np.einsum("...ij,...j->...i", _right_jacobian(theta), theta_dot)
        return theta, omega, d, d_dot


# ----------------------------------------------------------------------------------------------
# Error processes
# ----------------------------------------------------------------------------------------------
def _ar1_scan(y0: np.ndarray, drive: np.ndarray, a: float) -> np.ndarray:
    """``y_j = a y_{j-1} + drive_j`` for j = 0..M-1 along axis 0 of ``drive`` (M, ...), starting
    from ``y0`` (shape ``drive.shape[1:]``), vectorised.

    Uses ``y_j = a^(j+1) (y0 + sum_{i<=j} drive_i a^-(i+1))`` on sub-blocks short enough that
    ``a^-L`` stays far from overflow.
    """
    m = len(drive)
    out = np.empty_like(drive)
    if a <= 0.0:
        out[:] = drive
        return out
    L = m if a ** m > 1e-100 else max(1, int(-100.0 * np.log(10.0) / np.log(a)))
    y = y0
    for j0 in range(0, m, L):
        blk = drive[j0:j0 + L]
        pw = (a ** np.arange(1, len(blk) + 1, dtype=float)).reshape((-1,) + (1,) * (blk.ndim - 1))
        seg = pw * (y + np.cumsum(blk / pw, axis=0))
        out[j0:j0 + L] = seg
        y = seg[-1]
    return out


def _quantize(inc: np.ndarray, q: float, residual: np.ndarray):
    """Quantise increments (M, ...) to multiples of ``q`` along axis 0, carrying the residual
    (shape ``inc.shape[1:]``).

    The sum of the outputs equals the sum of the inputs plus the old residual minus the new
    one, so no information is lost over time (|residual| <= q/2).
    """
    acc = residual + np.cumsum(inc, axis=0)
    n = np.round(acc / q)
    out = q * np.diff(n, axis=0, prepend=0.0)
    return out, acc[-1] - q * n[-1]


def _normals(rngs: Sequence[np.random.Generator], buf: np.ndarray, m: int, scale: float):
    """``scale`` x standard normals, run-major (len(rngs), m, 3): each stream fills its own
    run's (m, 3) block of ``buf`` (flat, reused), drawing exactly what
    ``standard_normal((m, 3))`` draws."""
    b = buf[:len(rngs) * m * 3].reshape(len(rngs), m, 3)
    for bj, g in zip(b, rngs):
        g.standard_normal(out=bj)
    np.multiply(b, scale, out=b)
    return b


#: One 3-vector of float64 as a single item.
_VEC3 = np.dtype((np.void, 24))


def _put(out: np.ndarray, b: np.ndarray) -> None:
    """``out`` (m, nr, 3) = run-major ``b`` (nr, m, 3), moving whole 3-vectors (far faster than
    a transposed element-wise copy)."""
    out.view(_VEC3)[..., 0] = b.view(_VEC3)[..., 0].T


class _Errors:
    """Errors of one sensor triad (gyro or accelerometer) of n runs: constant bias, white noise,
    first-order Gauss-Markov wander, warm-up, quantisation of the increments with the residual
    carried.

    Parameters: bias (n, 3); white : noise density; instability, quantum : SensorSpecs figures;
    seqs : the runs' seed sequences; kind : 'gyro' or 'accel' (names the child streams);
    noise : False = no white noise and no wander; warmup, warmup_time : the SensorSpecs
    figures (a power-on bias N(0, warmup^2) per axis settling as exp(-t / warmup_time), t
    since t0; drawn like the bias, with or without noise).
    """

    def __init__(self, bias: np.ndarray, white: float, instability: float, quantum: float,
                 seqs: list[np.random.SeedSequence], kind: str, noise: bool,
                 warmup: float = 0.0, warmup_time: float = 300.0):
        self.bias, self.white, self.instability, self.quantum = bias, white, instability, quantum
        self.warm = (np.array([_stream(q, kind + "_warmup").normal(0.0, warmup, 3) for q in seqs])
                     if warmup > 0.0 else None)
        self.warmup_time = warmup_time
        self.noise = [_stream(q, kind + "_noise") for q in seqs] if noise else None
        wander = noise and instability > 0.0
        self.wander = [_stream(q, kind + "_wander") for q in seqs] if wander else None
        self.state = (np.array([g.normal(0.0, instability, 3) for g in self.wander])
                      if wander else None)
        self.residual = np.zeros_like(bias)

    def add(self, ideal: np.ndarray, runs: slice, out: np.ndarray, buf: np.ndarray, rate: float,
            a: float, t: np.ndarray):
        """``out`` (m, nr, 3) = ``ideal`` + bias + white noise + wander + warm-up of the runs
        ``runs`` at the sample times ``t`` (m,) since t0, quantised; advances the wander and
        the quantisation residual. Returns the wander added (None when off)."""
        m, dt = len(out), 1.0 / rate
        base = ideal + self.bias[runs]
        if self.warm is not None:
            base = base + self.warm[runs] * np.exp(-t / self.warmup_time)[:, None, None]
        drift = None
        if self.noise is None:
            out[...] = base
        else:
            b = _normals(self.noise[runs], buf, m, self.white * np.sqrt(rate))
            _put(out, np.add(b, base.transpose(1, 0, 2), out=b))
            if self.wander is not None:
                c = np.sqrt(1.0 - a ** 2)
                drive = _normals(self.wander[runs], buf, m, c * self.instability)
                drift = _ar1_scan(self.state[runs], drive.transpose(1, 0, 2), a)
                self.state[runs] = drift[-1]
                out += drift
        if self.quantum > 0.0:
            inc, self.residual[runs] = _quantize(out * dt, self.quantum, self.residual[runs])
            np.divide(inc, dt, out=out)
        return drift


# ----------------------------------------------------------------------------------------------
# Simulator
# ----------------------------------------------------------------------------------------------
#: The child streams of a run's seed, in spawn order.
_STREAMS = ("sway", "bias", "gyro_noise", "accel_noise", "gyro_wander", "accel_wander",
            "gyro_warmup", "accel_warmup")


def _stream(seq: np.random.SeedSequence, name: str) -> np.random.Generator:
    """Child stream ``name`` of ``seq``: the generator ``np.random.default_rng(seed).spawn(8)[i]``,
    i = ``_STREAMS.index(name)``, made on its own (a run makes only the streams it uses)."""
    child = np.random.SeedSequence(seq.entropy, spawn_key=seq.spawn_key + (_STREAMS.index(name),),
                                   pool_size=seq.pool_size)
    return np.random.Generator(np.random.PCG64(child))


def _finite(x, name: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number, got {x!r}") from None
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite, got {x!r}")
    return v


def _check_seed(seed) -> None:
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
        raise ValueError(f"seed must be an int or None, got {seed!r}")


def _setup(rate, lat_deg, height_m, t0, specs, sway, sway_amplitude):
    """Checked common arguments: rate, lat_deg, height_m, t0, SensorSpecs, scaled SwayProfile."""
    rate = _finite(rate, "rate")
    if rate <= 0.0:
        raise ValueError(f"rate must be > 0 Hz, got {rate!r}")
    lat_deg = _finite(lat_deg, "lat_deg")
    if abs(lat_deg) > 90.0:
        raise ValueError(f"lat_deg must be within [-90, 90], got {lat_deg!r}")
    if isinstance(specs, str):
        specs = grade_specs(specs)
    elif not isinstance(specs, SensorSpecs):
        raise ValueError(f"specs must be a SensorSpecs or a grade name, got {specs!r}")
    if isinstance(sway, str):
        sway = sway_profile(sway, sway_amplitude)
    elif isinstance(sway, SwayProfile):
        sway = sway.scaled(sway_amplitude)
    else:
        raise ValueError(f"sway must be a SwayProfile or a preset name, got {sway!r}")
    return (rate, lat_deg, _finite(height_m, "height_m"), _finite(t0, "t0"), specs, sway)


class _Runs:
    """The sensor model of n runs on one time line, vectorised across runs: the engine of
    :class:`ImuSimulator` (one run) and :func:`simulate_runs`.

    Run ``i`` draws everything from the child streams of ``np.random.SeedSequence(seeds[i])``,
    so it is the same run whatever the other runs are. ``C_ref`` (3, 3) is shared by all runs or
    (n, 3, 3) one per run; biases (n, 3) or None = drawn from the run's bias stream.
    Without sway the truth does not depend on time (and not on the run if ``C_ref`` is shared):
    it is computed for one interval only and broadcast.
    """

    def __init__(self, seeds: Sequence, rate: float, lat_rad: float, height_m: float,
                 C_ref: np.ndarray, specs: SensorSpecs, sway: SwayProfile, noise: bool,
                 gyro_bias: np.ndarray | None, accel_bias: np.ndarray | None,
                 block: int = _CHUNK):
        seqs = [np.random.SeedSequence(s) for s in seeds]
        n = len(seqs)
        self.rate, self.dt = rate, 1.0 / rate
        self.C_ref = C_ref
        self.w_ie_n = earth_rate_enu(lat_rad)
        self.g_n = gravity_enu(lat_rad, height_m)
        # inertial rotation of n over one interval, seen in the reference body axes:
        # C_ref^T exp(w dt) C_ref = exp(C_ref^T w dt), the latter keeps full relative precision
        E = [so3_exp(C.T @ self.w_ie_n * self.dt) for C in C_ref.reshape(-1, 3, 3)]
        self._E = E[0] if C_ref.ndim == 2 else np.array(E)
        self._sway = None if sway.is_static else _Sway(sway, [_stream(q, "sway") for q in seqs])

        sp = specs
        if gyro_bias is None or accel_bias is None:
            drawn = np.empty((n, 2, 3))
            for q, b in zip(seqs, drawn):
                r = _stream(q, "bias")
                b[0], b[1] = r.normal(0.0, sp.gyro_bias, 3), r.normal(0.0, sp.accel_bias, 3)
            gyro_bias = drawn[:, 0] if gyro_bias is None else gyro_bias
            accel_bias = drawn[:, 1] if accel_bias is None else accel_bias
        self.gyro = _Errors(np.array(gyro_bias, dtype=float), sp.gyro_arw,
                            sp.gyro_bias_instability, sp.gyro_quantization, seqs, "gyro", noise,
                            sp.gyro_warmup, sp.warmup_time)
        self.accel = _Errors(np.array(accel_bias, dtype=float), sp.accel_vrw,
                             sp.accel_bias_instability, sp.accel_quantization, seqs, "accel",
                             noise, sp.accel_warmup, sp.warmup_time)
        self._a = float(np.exp(-self.dt / sp.bias_correlation_time))
        self._buf = np.empty(3 * max(block, _CHUNK))

        # truth at t0 (evaluated on [0, dt]: the stacked formulas of the chunks, bit for bit)
        _, C, _, v = self._truth(np.array([0.0, self.dt]), slice(0, n))
        self.C0 = np.broadcast_to(C[0], (n, 3, 3)).copy()
        self.v0 = np.broadcast_to(v[0], (n, 3)).copy()

    def _truth(self, s: np.ndarray, runs: slice):
        """Sway rotation R, C_b^n, displacement d of the rotation centre and IMU velocity v of
        the runs ``runs`` at times ``s`` since t0: (M, nr, ...) arrays (nr = 1 without sway and
        with a shared C_ref)."""
        C_ref = self.C_ref if self.C_ref.ndim == 2 else self.C_ref[runs]
        if self._sway is None:          # no motion: R = I, no displacement, no velocity
            nr = len(C_ref) if C_ref.ndim == 3 else 1
            theta = omega = d = d_dot = np.zeros((len(s), nr, 3))
            lever = np.zeros(3)
        else:
            theta, omega, d, d_dot = self._sway.evaluate(s, runs)
            lever = self._sway.lever
        R = so3_exp(theta)
        C = C_ref @ R
        v = d_dot + np.einsum("...ij,...j->...i", C, np.cross(omega, lever))
        return R, C, d, v

    def chunk(self, k0: int, m: int, runs: slice, gyro: np.ndarray, accel: np.ndarray) -> dict:
        """Samples ``k0 .. k0+m-1`` of the runs ``runs`` into ``gyro``, ``accel`` (m, nr, 3).

        ``k0`` starts an internal chunk (a multiple of ``_CHUNK``) and ``m <= _CHUNK``; a short
        ``m`` gives exactly the first ``m`` samples of the full chunk, but the error processes
        then continue from sample ``k0 + m``: only the last chunk may be short. Chunks are
        generated in time order for each run.

        Returns the times ``s`` (m + 1,) of samples ``k0-1 .. k0+m-1`` since t0, the truth R, C,
        d, v at those times (one time row without sway), the error-free samples
        ``gyro_ideal``, ``accel_ideal`` (one row without sway) and the wander ``gyro_drift``,
        ``accel_drift`` added (None when off).
        """
        s = np.arange(k0, k0 + m + 1, dtype=float) / self.rate
        R, C, d, v = self._truth(s if self._sway else s[:2], runs)
        E = self._E if self._E.ndim == 2 else self._E[runs]
        dC = np.swapaxes(R[:-1], -1, -2) @ E @ R[1:]
        gyro_ideal = so3_log(dC) / self.dt
        accel_ideal = np.einsum("...ji,...j->...i", C[1:], (v[1:] - v[:-1]) / self.dt - self.g_n)
        gyro_drift = self.gyro.add(gyro_ideal, runs, gyro, self._buf, self.rate, self._a, s[1:])
        accel_drift = self.accel.add(accel_ideal, runs, accel, self._buf, self.rate, self._a,
                                     s[1:])
        return dict(s=s, R=R, C=C, d=d, v=v, gyro_ideal=gyro_ideal, accel_ideal=accel_ideal,
                    gyro_drift=gyro_drift, accel_drift=accel_drift)


class ImuSimulator:
    """Streaming IMU simulator: same physics and seed => same samples as :func:`simulate`.

    Parameters
    ----------
    rate : Hz — sample rate (> 0).
    lat_deg : deg — geodetic latitude, |lat| <= 90.
    height_m : m — height above the ellipsoid.
    rpy_deg : (3,) deg — mean attitude, REP-103 [roll, pitch, yaw] of ``C_b^n`` (ENU).
    specs : SensorSpecs or grade name ('navigation', 'tactical', 'consumer').
    sway : SwayProfile or preset name ('none', 'car', 'ship').
    sway_amplitude : — factor applied to the sway amplitudes (>= 0).
    seed : int or None — seed of ``np.random.default_rng``; None = fresh entropy.
    t0 : s — time origin; the first sample is stamped ``t0 + 1/rate``.
    gyro_bias : (3,) rad/s, body, optional — constant gyro bias (default: drawn N(0, spec)).
    accel_bias : (3,) m/s^2, body, optional — constant accel bias (default: drawn N(0, spec)).
    noise : bool — False switches off the random processes (white noise and bias wander);
        constant biases, the warm-up (``specs.gyro_warmup`` etc.) and quantisation stay.
    """

    def __init__(self, rate: float = 100.0, lat_deg: float = 34.0, height_m: float = 0.0,
                 rpy_deg: Sequence[float] = (0.0, 0.0, 0.0),
                 specs: SensorSpecs | str = "navigation", sway: SwayProfile | str = "none",
                 sway_amplitude: float = 1.0, seed: int | None = 0, t0: float = 0.0,
                 gyro_bias: Sequence[float] | None = None,
                 accel_bias: Sequence[float] | None = None, noise: bool = True):
        rate, lat_deg, self.height_m, self.t0, specs, sway = _setup(
            rate, lat_deg, height_m, t0, specs, sway, sway_amplitude)
        rpy = np.array(_vec3(rpy_deg, "rpy_deg"))
        _check_seed(seed)
        biases = [None if b is None else np.array([_vec3(b, name)])
                  for b, name in ((gyro_bias, "gyro_bias"), (accel_bias, "accel_bias"))]
        self.rate = rate
        self.dt = 1.0 / rate
        self.lat_rad = lat_deg * _DEG
        self.specs = specs
        self.sway = sway
        self.noise = bool(noise)
        self.seed = seed
        self._runs = _Runs([seed], rate, self.lat_rad, self.height_m, dcm_from_rpy(rpy * _DEG),
                           specs, sway, self.noise, *biases)
        self.C_ref, self.w_ie_n, self.g_n = self._runs.C_ref, self._runs.w_ie_n, self._runs.g_n
        self.gyro_bias, self.accel_bias = self._runs.gyro.bias[0], self._runs.accel.bias[0]
        self.C0, self.v0 = self._runs.C0[0], self._runs.v0[0]

        self._chunk_start = 0            # sample index of the next chunk to generate
        self._end: int | None = None     # total samples that will be asked for, when known
        self._buf: dict[str, np.ndarray] | None = None
        self._buf_pos = 0
        self.samples_emitted = 0

    def _generate_chunk(self) -> dict[str, np.ndarray]:
        k0 = self._chunk_start
        m = _CHUNK if self._end is None else min(_CHUNK, self._end - k0)
        gyro, accel = np.empty((m, 1, 3)), np.empty((m, 1, 3))
        c = self._runs.chunk(k0, m, slice(0, 1), gyro, accel)
        self._chunk_start += _CHUNK
        R, C, d, v = (c[k][:, 0] for k in ("R", "C", "d", "v"))
        p = d + (R - np.eye(3)) @ np.array(self.sway.lever_arm) @ self.C_ref.T
        zeros = np.zeros((m, 3))

        def rows(x):                     # without sway: the one row, over the whole chunk
            return np.broadcast_to(x, (m,) + x.shape[1:])

        return {
            "t": self.t0 + c["s"][1:], "gyro": gyro[:, 0], "accel": accel[:, 0],
            "C_true": rows(C[1:]), "quat_true": rows(quat_from_dcm(C[1:])),
            "v_true": rows(v[1:]), "p_true": rows(p[1:]),
            "gyro_ideal": rows(c["gyro_ideal"][:, 0]),
            "accel_ideal": rows(c["accel_ideal"][:, 0]),
            "gyro_drift": zeros if c["gyro_drift"] is None else c["gyro_drift"][:, 0],
            "accel_drift": zeros if c["accel_drift"] is None else c["accel_drift"][:, 0],
        }

    # -- public -------------------------------------------------------------------------------
    def next_block(self, n: int) -> SimResult:
        """The next ``n`` samples (continuing time): identical to slicing :func:`simulate`.

        Parameters
        ----------
        n : int >= 0 — number of samples.

        Returns
        -------
        SimResult with N = n samples.
        """
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"n must be an int >= 0, got {n!r}")
        pieces: list[dict[str, np.ndarray]] = []
        need = int(n)
        while need > 0:
            if self._buf is None or self._buf_pos >= len(self._buf["t"]):
                self._buf = self._generate_chunk()
                self._buf_pos = 0
            take = min(need, len(self._buf["t"]) - self._buf_pos)
            sl = slice(self._buf_pos, self._buf_pos + take)
            pieces.append({k: v[sl] for k, v in self._buf.items()})
            self._buf_pos += take
            need -= take
        if len(pieces) == 1:
            arrays = {k: v.copy() for k, v in pieces[0].items()}
        elif pieces:
            arrays = {k: np.concatenate([p[k] for p in pieces]) for k in _ARRAY_FIELDS}
        else:
            arrays = {"t": np.zeros(0), "C_true": np.zeros((0, 3, 3)),
                      "quat_true": np.zeros((0, 4))}
            arrays.update({k: np.zeros((0, 3)) for k in _ARRAY_FIELDS if k not in arrays})
        self.samples_emitted += int(n)
        return SimResult(
            C0=self.C0.copy(), gyro_bias=self.gyro_bias.copy(),
            accel_bias=self.accel_bias.copy(), lat_rad=self.lat_rad, height_m=self.height_m,
            rate=self.rate, specs=self.specs, sway=self.sway, v0=self.v0.copy(), **arrays)


def _samples(duration: float, rate: float) -> int:
    duration = _finite(duration, "duration")
    if duration <= 0.0:
        raise ValueError(f"duration must be > 0 s, got {duration!r}")
    n = int(np.floor(duration * rate + 1e-9))
    if n < 1:
        raise ValueError(f"duration {duration!r} s is shorter than one sample at {rate} Hz")
    return n


def simulate(duration: float, rate: float = 100.0, lat_deg: float = 34.0, height_m: float = 0.0,
             rpy_deg: Sequence[float] = (0.0, 0.0, 0.0), specs: SensorSpecs | str = "navigation",
             sway: SwayProfile | str = "none", sway_amplitude: float = 1.0,
             seed: int | None = 0, t0: float = 0.0,
             gyro_bias: Sequence[float] | None = None,
             accel_bias: Sequence[float] | None = None, noise: bool = True) -> SimResult:
    """Simulate ``duration`` seconds of IMU data on a quasi-static base.

    Parameters
    ----------
    duration : s (> 0) — N = floor(duration * rate) samples, stamped in (t0, t0 + duration].
    Other parameters : as :class:`ImuSimulator`.

    Returns
    -------
    SimResult — samples, truth (attitude, velocity, displacement), the biases drawn.

    Raises
    ------
    ValueError
        Non-finite or out-of-range arguments, unknown grade or sway preset, duration shorter
        than one sample.
    """
    sim = ImuSimulator(rate=rate, lat_deg=lat_deg, height_m=height_m, rpy_deg=rpy_deg,
                       specs=specs, sway=sway, sway_amplitude=sway_amplitude, seed=seed, t0=t0,
                       gyro_bias=gyro_bias, accel_bias=accel_bias, noise=noise)
    sim._end = _samples(duration, sim.rate)
    return sim.next_block(sim._end)


@dataclass
class RunsResult:
    """n runs on one time line (:func:`simulate_runs`); run ``i`` is ``simulate(seed=seeds[i])``.

    Attributes
    ----------
    t : (N,) s — sample stamps, as :attr:`SimResult.t`.
    gyro : (N, n, 3) rad/s; accel : (N, n, 3) m/s^2 — measured samples of every run.
    C0 : (n, 3, 3) — true ``C_b^n`` of each run at t0.
    gyro_bias : (n, 3) rad/s; accel_bias : (n, 3) m/s^2 — the constant biases, body.
    truth_at : (K,) — sample indices at which the truth is given.
    C_true : (K, n, 3, 3) — true ``C_b^n`` at ``t[truth_at]``.
    """

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    C0: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    truth_at: np.ndarray
    C_true: np.ndarray


#: Sample-runs per vectorised step of simulate_runs: static (noise buffer), swaying (truth).
_BLOCK, _BLOCK_SWAY = 2 ** 17, 2 ** 13


def _per_run(x, n: int, name: str) -> np.ndarray:
    """``x`` as a finite (3,) array (shared by the runs) or (n, 3) array (one row per run)."""
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        a = np.full(0, np.nan)
    if a.shape not in ((3,), (n, 3)) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers or ({n}, 3) of them, got {x!r}")
    return a


def simulate_runs(duration: float, seeds: Sequence[int | None], rate: float = 100.0,
                  lat_deg: float = 34.0, height_m: float = 0.0,
                  rpy_deg: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
                  specs: SensorSpecs | str = "navigation", sway: SwayProfile | str = "none",
                  sway_amplitude: float = 1.0, t0: float = 0.0,
                  gyro_bias: Sequence[float] | np.ndarray | None = None,
                  accel_bias: Sequence[float] | np.ndarray | None = None, noise: bool = True,
                  truth_at: Sequence[int] = ()) -> RunsResult:
    """Simulate n runs at once, vectorised across runs: run ``i`` is, bit for bit, ``simulate(
    duration, ..., seed=seeds[i])`` with run ``i``'s attitude and biases (its samples, C0,
    biases, and C_true at ``truth_at``).

    Without sway the error-free samples are computed for one interval only (shared by the runs
    unless the attitude is per run) and each run only adds its biases and noise; with sway
    each run's truth is computed, for blocks of runs at a time.

    Parameters
    ----------
    duration : s (> 0) — N = floor(duration * rate) samples per run.
    seeds : n ints (or None = fresh entropy) — the seed of each run.
    rpy_deg : (3,) shared or (n, 3) per run, deg — mean attitude (as :class:`ImuSimulator`).
    gyro_bias, accel_bias : None (drawn per run), (3,) shared or (n, 3) per run.
    truth_at : sample indices in [0, N) at which C_true is returned.
    Other parameters : as :class:`ImuSimulator`.

    Returns
    -------
    RunsResult.

    Raises
    ------
    ValueError
        As :func:`simulate`; no seeds, wrong shapes, truth_at out of range.
    """
    rate, lat_deg, height_m, t0, specs, sway = _setup(rate, lat_deg, height_m, t0, specs, sway,
                                                      sway_amplitude)
    N = _samples(duration, rate)
    seeds = list(seeds)
    if not seeds:
        raise ValueError("seeds must hold at least one seed")
    for s in seeds:
        _check_seed(s)
    n = len(seeds)
    rpy = _per_run(rpy_deg, n, "rpy_deg")
    biases = [None if b is None else np.broadcast_to(_per_run(b, n, name), (n, 3))
              for b, name in ((gyro_bias, "gyro_bias"), (accel_bias, "accel_bias"))]
    truth_at = np.asarray(truth_at, dtype=int).reshape(-1)
    if np.any((truth_at < 0) | (truth_at >= N)):
        raise ValueError(f"truth_at must be sample indices in [0, {N}), got {truth_at!r}")
    block = _BLOCK if sway.is_static else _BLOCK_SWAY
    runs = _Runs(seeds, rate, lat_deg * _DEG, height_m, dcm_from_rpy(rpy * _DEG), specs, sway,
                 bool(noise), *biases, block=block)

    gyro, accel = np.empty((N, n, 3)), np.empty((N, n, 3))
    C_true = np.empty((len(truth_at), n, 3, 3))
    for k0 in range(0, N, _CHUNK):
        m = min(_CHUNK, N - k0)
        nb = max(1, block // m)
        want = (truth_at >= k0) & (truth_at < k0 + m)
        for j0 in range(0, n, nb):
            r = slice(j0, min(n, j0 + nb))
            C = runs.chunk(k0, m, r, gyro[k0:k0 + m, r], accel[k0:k0 + m, r])["C"][1:]
            C_true[want, r] = C[truth_at[want] - k0] if len(C) == m else C
    return RunsResult(t=t0 + np.arange(1, N + 1) / rate, gyro=gyro, accel=accel, C0=runs.C0,
                      gyro_bias=runs.gyro.bias, accel_bias=runs.accel.bias, truth_at=truth_at,
                      C_true=C_true)


# ----------------------------------------------------------------------------------------------
# Stream faults
# ----------------------------------------------------------------------------------------------
@dataclass
class Stream:
    """The IMU stream as a node would receive it (:func:`corrupt`).

    Attributes
    ----------
    t : (M,) s — received stamps (time jumps and wild stamps applied).
    gyro, accel : (M, 3) — the received samples' data (unchanged).
    index : (M,) int — index of each received sample in the original stream.
    t_true : (M,) s — the original (true) stamp of each received sample.
    wild : (M,) bool — True where the stamp is a wild one.
    truth : the truth given to :func:`corrupt`, sliced to the received samples (None, an
        array, or a dict of arrays).
    n_in : int — samples before the faults.
    """

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    index: np.ndarray
    t_true: np.ndarray
    wild: np.ndarray
    truth: object
    n_in: int

    def __len__(self) -> int:
        return len(self.t)

    @property
    def dropped(self) -> int:
        """Samples lost."""
        return self.n_in - len(self.t)


def _pairs(x, name: str) -> list[tuple[float, float]]:
    out = []
    for item in x:
        try:
            a, b = item
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a list of (time, value) pairs, got {x!r}") from None
        out.append((_finite(a, name), _finite(b, name)))
    return out


def corrupt(t, gyro, accel, truth=None, rng=None, drop_fraction: float = 0.0,
            drop_bursts: Sequence = (), gap: Sequence = (), time_jump: Sequence = (),
            wild_stamp: Sequence = (), drop_samples: Sequence[float] = (),
            force_spikes: Sequence = ()) -> Stream:
    """The stream ``t, gyro, accel`` with transport faults, as a node would receive it.

    Pure: the inputs are not modified. Times below are original stamps (same epoch as ``t``).

    Parameters
    ----------
    t : (N,) s; gyro, accel : (N, 3) — the clean stream (e.g. from :func:`simulate`).
    truth : None, an (N, ...) array, a dict of (N, ...) arrays, or a :class:`SimResult`
        (its per-sample arrays, as a dict) — sliced along with the kept samples.
    rng : np.random.Generator, int seed or None (seed 0) — only drop_fraction draws from it.
    drop_fraction : each sample is lost independently with this probability.
    drop_bursts : [(t_start, n)] — lose the n samples from the first one stamped >= t_start.
    gap : [(t_start, seconds)] — lose every sample stamped in [t_start, t_start + seconds).
    time_jump : [(t_at, seconds)] — every sample stamped >= t_at gets ``seconds`` added.
    wild_stamp : [(t_at, offset)] — the first received sample stamped >= t_at keeps its data
        but its stamp gets ``offset`` added (on top of any time jump); later stamps are normal.
    drop_samples : [t_at] — lose the one sample first stamped >= t_at.
    force_spikes : [(t_at, factor)] — a glitch of the accelerometer alone: the specific force
        of the one sample first stamped >= t_at is multiplied by ``factor`` (its rate and the
        truth are untouched).

    Returns
    -------
    Stream
    """
    t = np.asarray(t, dtype=float)
    gyro, accel = np.asarray(gyro, dtype=float), np.asarray(accel, dtype=float)
    n = len(t)
    if gyro.shape != (n, 3) or accel.shape != (n, 3):
        raise ValueError(f"gyro and accel must be ({n}, 3), got {gyro.shape}, {accel.shape}")
    if not isinstance(rng, np.random.Generator):
        _check_seed(rng)
        rng = np.random.default_rng(0 if rng is None else rng)
    frac = _finite(drop_fraction, "drop_fraction")
    if not 0.0 <= frac <= 1.0:
        raise ValueError(f"drop_fraction must be within [0, 1], got {drop_fraction!r}")
    keep = np.ones(n, dtype=bool)
    if frac > 0.0:
        keep &= rng.random(n) >= frac
    for ts, m in _pairs(drop_bursts, "drop_bursts"):
        k = int(np.searchsorted(t, ts, side="left"))
        keep[k:k + int(m)] = False
    for ts, sec in _pairs(gap, "gap"):
        keep[(t >= ts) & (t < ts + sec)] = False
    for ts in drop_samples:
        k = int(np.searchsorted(t, _finite(ts, "drop_samples"), side="left"))
        if k < n:
            keep[k] = False
    idx = np.flatnonzero(keep)
    t_true = t[idx]
    stamps = t_true.copy()
    for ta, sec in _pairs(time_jump, "time_jump"):
        stamps[t_true >= ta] += sec
    wild = np.zeros(len(idx), dtype=bool)
    for ta, off in _pairs(wild_stamp, "wild_stamp"):
        k = int(np.searchsorted(t_true, ta, side="left"))
        if k < len(idx):
            stamps[k] += off
            wild[k] = True
    if isinstance(truth, SimResult):
        truth = {k: getattr(truth, k) for k in _ARRAY_FIELDS if len(getattr(truth, k)) == n}
    if isinstance(truth, dict):
        truth = {k: np.asarray(v)[idx] for k, v in truth.items()}
    elif truth is not None:
        truth = np.asarray(truth)[idx]
    accel = accel[idx].copy()
    for ta, factor in _pairs(force_spikes, "force_spikes"):
        k = int(np.searchsorted(t_true, ta, side="left"))
        if k < len(idx):
            accel[k] *= factor
    return Stream(t=stamps, gyro=gyro[idx].copy(), accel=accel, index=idx,
                  t_true=t_true, wild=wild, truth=truth, n_in=n)
