"""Honesty harness: does the published covariance cover the true attitude error?

Runs the :class:`~sins_align.estimators.quasi_static.Aligner` on simulated disturbances (the
"disturbance matrix" :data:`CASES`) and compares, at every fed block, the true attitude error with
the published standard deviation. numpy only, no ROS.

Error convention
----------------
The published covariance is that of the ENU attitude error ``phi`` with
``C_true = exp(phi x) C_est`` (paper eq. 15). The harness computes exactly that,
``phi = so3_log(C_true C_est^T)``: a world-frame (ENU) error whose third component is the
heading error. The body-frame error ``so3_log(C_est^T C_true)`` is the same rotation seen in
body axes (``C_est^T phi``); comparing it with the ENU covariance would be wrong as soon as
the IMU is tilted or turned (upside down, heading 30 deg), so it is never used.
When heading is not observable its error can be anything (tens of degrees), and then the E
and N components of ``so3_log`` no longer measure the tilt (a large heading error mixes into
them): the harness then uses the heading-free tilt of :func:`tilt_heading_error` for E and N.

The truth at a published state is the truth of the last sample the Aligner accepted (each
block is fed as its first ``block - 1`` samples, then its last sample alone, so the harness
knows whether that last sample was used). The heading axis (U) counts only when
``Aligner.heading_observable``.

Use
---
>>> r = run_case("static", seed=0)
>>> r["max_ratio"], r["frac_over_3sigma"], r["n_viol_4sigma"], r["aligned_wrong"]
"""
from __future__ import annotations

import fnmatch
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from sins_align.core.specs import SensorSpecs, grade_specs
from sins_align.estimators.quasi_static import AlignConfig, Aligner
from sins_align.core.rotation import so3_exp, so3_log
from sins_align.sim.simulator import (SwayProfile, combine, corrupt, door_slam, relevel, shove,
                                      simulate, tone, with_events)

__all__ = ["Case", "CASES", "run_case", "select_cases", "check_expectations",
           "attitude_error_enu", "tilt_heading_error",
           "LATITUDE_DEG", "RATE_HZ", "T0"]

_DEG = np.pi / 180.0
LATITUDE_DEG = 34.0
RATE_HZ = 100.0
#: epoch of the simulated stamps (a ROS-like wall-clock stamp), s
T0 = 1.7e9
#: the 4-sigma test allows this much on top (rad): 0.01 deg
_SLACK = 0.01 * _DEG
#: published heading std (rad) above which E and N are measured as the heading-free tilt
_HEADING_KNOWN = 30.0 * _DEG
#: mean attitude of the truth unless a case says otherwise, deg
DEFAULT_RPY = (1.0, -0.5, 30.0)


@dataclass
class Case:
    """One entry of the disturbance matrix.

    Attributes
    ----------
    name : str.
    duration : s of data.
    sway : SwayProfile or preset name (events are part of it).
    specs : grade name or SensorSpecs of the IMU (simulated and configured alike).
    rpy_deg : mean true attitude, REP-103 deg.
    initial_rpy_deg : the Aligner's initial attitude (None = identity).
    faults : keyword arguments of :func:`sins_align.sim.simulator.corrupt`, times in s since the
    start.
    block : samples per :meth:`Aligner.update` call.
    expectations : names checked by :func:`check_expectations` ('honest', 'no_aligned_wrong',
        'aligns', 'aligns_by:<s>', 'rejects:<reason>', 'no_rejects', 'heading_within:<deg>').
    note : free text.
    """

    name: str
    duration: float
    sway: SwayProfile | str = "none"
    specs: SensorSpecs | str = "navigation"
    rpy_deg: tuple[float, float, float] = DEFAULT_RPY
    initial_rpy_deg: tuple[float, float, float] | None = None
    faults: dict = field(default_factory=dict)
    block: int = 100
    expectations: tuple[str, ...] = ()
    note: str = ""


def fault_stamps(faults: dict) -> dict:
    """corrupt() keyword arguments with the times moved from 's since start' to stamps."""
    out = dict(faults)
    for key in ("drop_bursts", "gap", "time_jump", "wild_stamp", "force_spikes"):
        if key in out:
            out[key] = [(T0 + a, b) for a, b in out[key]]
    if "drop_samples" in out:
        out["drop_samples"] = [T0 + a for a in out["drop_samples"]]
    return out


def tilt_heading_error(C_true: np.ndarray, C_est: np.ndarray) -> np.ndarray:
    """Error split as ``C_true = Rz(psi) exp(tau x) C_est`` with a horizontal tilt ``tau`` (E, N)
    and a heading error ``psi`` about U: returns ``[tau_E, tau_N, psi]``, rad.

    The tilt is the rotation taking the estimated "up" to the true one, ``C_est C_true^T e_U =
    exp(-tau x) e_U``: it does not depend on the heading error at all, whereas the E and N
    components of ``so3_log`` mix tilt and heading once the heading error is large. To first
    order both equal phi.
    """
    w = C_est @ C_true.T[:, 2]
    s = np.hypot(w[0], w[1])
    ang = np.arctan2(s, w[2])
    tau = np.zeros(3) if s == 0.0 else ang / s * np.array([w[1], -w[0], 0.0])
    psi = so3_log(C_true @ C_est.T @ so3_exp(-tau))[2]
    return np.array([tau[0], tau[1], psi])


def attitude_error_enu(C_true: np.ndarray, C_est: np.ndarray, heading: bool = True):
    """The harness's error (rad, E N U): ``phi = so3_log(C_true C_est^T)`` (C_true =
    exp(phi x) C_est, the published convention); when heading is not known (not observable,
    or its published std is tens of degrees: its error can then be anything) the E and N
    components are the heading-free tilt of :func:`tilt_heading_error` instead, which is
    what the published level std is about. (Near a 180 deg heading error the axis of
    ``so3_log`` swings by the tilt over cos(psi / 2): a 0.5 deg tilt reads as 8 deg of "E".)"""
    phi = so3_log(C_true @ C_est.T)
    if heading:
        return phi
    th = tilt_heading_error(C_true, C_est)
    return np.array([th[0], th[1], phi[2]])


def run_case(case: Case | str, seed: int = 0,
             aligner_factory: Callable[[AlignConfig], Aligner] = Aligner,
             series: bool = False) -> dict:
    """Simulate ``case`` with ``seed``, feed it to an Aligner block by block, and measure how
    well the published covariance covers the true error.

    Parameters
    ----------
    case : Case or a name in :data:`CASES`.
    seed : simulation seed (the stream faults use ``seed`` too).
    aligner_factory : builds the Aligner from its AlignConfig (tests inject subclasses).
    series : also return the per-block time series (key 'series').

    Returns
    -------
    dict with (angles in deg unless named otherwise, axes E, N, U):
      name, seed, duration, n_published, heading_observable,
      max_ratio (3,) — max over published states of |err|/sigma per axis (U None when
        heading is unobservable),
      frac_over_3sigma — fraction of published states with some observable axis |err| > 3 sigma,
      frac_over_3sigma_axis (3,),
      n_viol_4sigma, frac_viol_4sigma — states with some observable axis
        |err| > 4 sigma + 0.01 deg,
      aligned_wrong — states with ``aligned`` true while some observable axis |err| > 3 sigma,
      t_aligned_first (s since the start, None if never), frac_aligned,
      final_err_deg (3,), final_std_deg (3,), final_status, final_aligned,
      max_stale_s — largest lag of the published state behind the last received sample
        (true time, s): the state stops moving while samples are rejected,
      rejected (reason -> count), events (Aligner events), status_counts,
      samples_in, samples_received, samples_used, elapsed_s (wall clock),
      failed_expectations (list of str).
    """
    if isinstance(case, str):
        case = CASES[case]
    wall = time.perf_counter()
    r = simulate(case.duration, rate=RATE_HZ, lat_deg=LATITUDE_DEG, rpy_deg=case.rpy_deg,
                 specs=case.specs, sway=case.sway, seed=seed, t0=T0)
    s = corrupt(r.t, r.gyro, r.accel, r.C_true, rng=seed, **fault_stamps(case.faults))
    C_true = s.truth
    al = aligner_factory(AlignConfig(latitude_deg=LATITUDE_DEG, specs=case.specs,
                                     initial_rpy_deg=case.initial_rpy_deg))
    obs = np.array([True, True, bool(al.heading_observable)])

    n = len(s)
    B = max(1, int(case.block))
    nb = (n + B - 1) // B
    t_state = np.full(nb, np.nan)
    err = np.full((nb, 3), np.nan)
    std = np.full((nb, 3), np.nan)
    aligned = np.zeros(nb, dtype=bool)
    status: list[str] = []
    stale = np.zeros(nb)
    idx = -1                                  # index (into s) of the state's last sample
    for j, k in enumerate(range(0, n, B)):
        e = min(n, k + B)
        if e - 1 > k:
            used = al.update(s.t[k:e - 1], s.gyro[k:e - 1], s.accel[k:e - 1])
            if used > 0:
                idx = e - 2                   # exact when every sample was used
        if al.update(float(s.t[e - 1]), s.gyro[e - 1], s.accel[e - 1]) == 1:
            idx = e - 1
        if al.t_last is not None and idx < 0:
            idx = 0                           # the first sample anchors time: initial state
        status.append(al.status)
        aligned[j] = al.aligned
        if idx < 0:
            continue
        P = al.covariance
        std[j] = np.sqrt(np.maximum(np.diag(P), 0.0))
        known = bool(obs[2]) and std[j, 2] < _HEADING_KNOWN
        err[j] = attitude_error_enu(C_true[idx], al.dcm, heading=known)
        t_state[j] = s.t_true[idx] - T0
        stale[j] = s.t_true[e - 1] - s.t_true[idx]

    ok = np.isfinite(t_state)
    e_abs, sd = np.abs(err[ok]), std[ok]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(sd > 0.0, e_abs / sd, np.where(e_abs > 0.0, np.inf, 0.0))
    over3 = (e_abs > 3.0 * sd) & obs
    viol4 = (e_abs > 4.0 * sd + _SLACK) & obs
    any3 = over3.any(axis=1)
    al_ok = aligned[ok]
    npub = int(ok.sum())
    t_al = t_state[ok][al_ok]
    max_ratio = [float(np.max(ratio[:, i])) if npub and obs[i] else None for i in range(3)]
    out = {
        "name": case.name,
        "seed": seed,
        "duration": case.duration,
        "n_published": npub,
        "heading_observable": bool(obs[2]),
        "max_ratio": max_ratio,
        "frac_over_3sigma": float(any3.mean()) if npub else 0.0,
        "frac_over_3sigma_axis": [float(x) for x in over3.mean(axis=0)] if npub else [0.0] * 3,
        "n_viol_4sigma": int(viol4.any(axis=1).sum()),
        "frac_viol_4sigma": float(viol4.any(axis=1).mean()) if npub else 0.0,
        "aligned_wrong": int((al_ok & any3).sum()),
        "t_aligned_first": float(t_al[0]) if len(t_al) else None,
        "frac_aligned": float(al_ok.mean()) if npub else 0.0,
        "final_err_deg": (err[ok][-1] / _DEG).tolist() if npub else [None] * 3,
        "final_std_deg": (std[ok][-1] / _DEG).tolist() if npub else [None] * 3,
        "max_stale_s": float(stale.max()) if nb else 0.0,
        "final_status": al.status,
        "final_aligned": bool(al.aligned),
        "rejected": dict(al.rejected),
        "events": dict(al.events),
        "status_counts": dict(Counter(status)),
        "samples_in": int(s.n_in),
        "samples_received": int(n),
        "samples_used": int(al.samples_used),
        "elapsed_s": time.perf_counter() - wall,
    }
    out["failed_expectations"] = check_expectations(case, out)
    if series:
        out["series"] = {"t": t_state, "err": err, "std": std, "aligned": aligned,
                         "status": np.array(status)}
    return out


def check_expectations(case: Case, result: dict) -> list[str]:
    """The expectations of ``case`` that ``result`` (of :func:`run_case`) does not meet."""
    failed = []
    for x in case.expectations:
        key, _, arg = x.partition(":")
        if key == "honest":
            ok = result["n_viol_4sigma"] == 0
        elif key == "no_aligned_wrong":
            ok = result["aligned_wrong"] == 0
        elif key == "aligns":
            ok = result["t_aligned_first"] is not None
        elif key == "aligns_by":
            ok = result["t_aligned_first"] is not None and result["t_aligned_first"] <= float(arg)
        elif key == "rejects":
            ok = result["rejected"].get(arg, 0) > 0
        elif key == "no_rejects":
            ok = sum(result["rejected"].values()) == 0
        elif key == "heading_within":
            h = result["final_err_deg"][2]
            ok = h is not None and abs(h) <= float(arg)
        else:
            raise ValueError(f"unknown expectation {x!r} of case {case.name!r}")
        if not ok:
            failed.append(x)
    return failed


def select_cases(patterns: Sequence[str] | str | None = None) -> list[Case]:
    """Cases whose name matches any of the shell-style ``patterns`` (all when None)."""
    if patterns is None:
        return list(CASES.values())
    if isinstance(patterns, str):
        patterns = [p for p in patterns.split(",") if p]
    return [c for name, c in CASES.items() if any(fnmatch.fnmatchcase(name, p) for p in patterns)]


# ----------------------------------------------------------------------------------------------
# The disturbance matrix
# ----------------------------------------------------------------------------------------------
_HONEST = ("honest", "no_aligned_wrong")
_AXES = "xyz"
_ENU = "ENU"
#: angular tone amplitude (deg) by frequency (Hz): rates stay below ~35 deg/s
_ANG_TONES = {0.1: 5.0, 0.5: 2.0, 1.0: 1.0, 2.0: 0.5, 5.0: 0.2, 10.0: 0.1}
_LIN_FREQS = (0.2, 0.5, 2.0)
_LIN_ACCELS = (0.3, 1.0)
_CAR_LEVER = (0.5, 0.3, 0.4)


def _build_cases() -> dict[str, Case]:
    cases: list[Case] = [Case("static", 300.0, expectations=_HONEST + ("aligns", "no_rejects"))]
    for axis in range(3):
        for f, a in _ANG_TONES.items():
            cases.append(Case(f"ang_{_AXES[axis]}_{f:g}Hz_{a:g}deg", 300.0,
                              tone("angular", axis, f, a), expectations=_HONEST))
    for axis in range(3):
        for f in _LIN_FREQS:
            for a in _LIN_ACCELS:
                cases.append(Case(f"lin_{_ENU[axis]}_{f:g}Hz_{a:g}mps2", 300.0,
                                  tone("linear", axis, f, a), expectations=_HONEST))
    cases.append(Case("car_vib_lo", 300.0, combine(
        tone("angular", 0, 0.5, 0.05), tone("linear", 2, 2.0, 0.3), tone("linear", 0, 2.5, 0.3),
        SwayProfile(lever_arm=_CAR_LEVER), name="car_vib_lo"), expectations=_HONEST,
        note="roll 0.05 deg @ 0.5 Hz + U 0.3 m/s^2 @ 2 Hz + E 0.3 m/s^2 @ 2.5 Hz"))
    cases.append(Case("car_vib_hi", 300.0, combine(
        tone("angular", 0, 1.1, 0.1), tone("angular", 1, 0.8, 0.1),
        tone("linear", 2, 2.5, 0.7), tone("linear", 1, 2.0, 0.7),
        SwayProfile(lever_arm=_CAR_LEVER), name="car_vib_hi"), expectations=_HONEST,
        note="roll 0.1 deg @ 1.1 Hz, pitch 0.1 deg @ 0.8 Hz + U 0.7 m/s^2 @ 2.5 Hz + "
             "N 0.7 m/s^2 @ 2 Hz"))
    cases.append(Case("shove_E_300s", 450.0, with_events(
        "none", shove(300.0, accel=3.0, duration=0.4, direction=(1.0, 0.0, 0.0), jolt_deg=0.3,
                      jolt_axis=0)), expectations=_HONEST))
    cases.append(Case("shove_N_300s", 450.0, with_events(
        "none", shove(300.0, accel=-3.0, duration=0.4, direction=(0.0, 1.0, 0.0), jolt_deg=0.3,
                      jolt_axis=1)), expectations=_HONEST))
    cases.append(Case("door_slam_300s", 450.0, with_events(
        "car", door_slam(300.0, angle_deg=0.5, accel=5.0, duration=0.1)),
        expectations=_HONEST))
    cases.append(Case("door_slam_hard_300s", 450.0, with_events(
        "car", door_slam(300.0, angle_deg=2.0, accel=15.0, duration=0.2, axis=1,
                         direction=(0.0, 1.0, 0.0))), expectations=_HONEST,
        note="0.2 s, 15 m/s^2 north, 2 deg of pitch that returns: |f| off g by up to 1.5 g"))
    cases.append(Case("bumps_every_20s", 450.0, with_events(
        "car", *(door_slam(float(t), angle_deg=1.0, accel=8.0, duration=0.15, axis=k % 3,
                           direction=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))[k % 3])
                 for k, t in enumerate(range(40, 440, 20)))), expectations=_HONEST,
        note="a 0.15 s, 8 m/s^2, 1 deg bump every 20 s, turning through the axes"))
    cases.append(Case("relevel_roll_2deg_300s", 600.0, with_events(
        "none", relevel(300.0, 2.0, axis=0, duration=1.5)), expectations=_HONEST,
        note="the true attitude changes for good by 2 deg of roll at 300 s"))
    cases.append(Case("relevel_yaw_2deg_300s", 600.0, with_events(
        "none", relevel(300.0, 2.0, axis=2, duration=1.5)), expectations=_HONEST,
        note="the true heading changes for good by 2 deg at 300 s"))
    cases.append(Case("ship_heave", 600.0, "ship_heave", expectations=_HONEST))
    cases.append(Case("moored_ship", 600.0, "moored_ship", expectations=_HONEST))
    faults = {
        "car": {},
        "car_lost_single": {"drop_samples": [float(x) + 0.005 for x in range(20, 300, 20)]},
        "car_loss_1pct": {"drop_fraction": 0.01},
        "car_loss_10pct": {"drop_fraction": 0.10},
        "car_bursts5_every10s": {"drop_bursts": [(float(x), 5) for x in range(10, 300, 10)]},
        "car_gap_3s": {"gap": [(150.0, 3.0)]},
        "car_time_jump_+10s": {"time_jump": [(150.0, 10.0)]},
        "car_time_jump_-2s": {"time_jump": [(150.0, -2.0)]},
        "car_wild_future": {"wild_stamp": [(150.0, 1000.0)]},
        "car_wild_past": {"wild_stamp": [(150.0, -1000.0)]},
        "car_force_glitches": {"force_spikes": [(float(x) + 0.005, (2.0, 0.4, -1.0)[x // 30 % 3])
                                                for x in range(30, 300, 30)]},
    }
    for name, fl in faults.items():
        cases.append(Case(name, 300.0, "car", faults=fl, expectations=_HONEST))
    cases.append(Case("engine_ang_lost_single", 300.0, combine(
        tone("angular", 0, 43.0, 0.01), tone("angular", 1, 29.0, 0.01), name="engine_ang"),
        faults=faults["car_lost_single"], expectations=_HONEST,
        note="roll 0.01 deg @ 43 Hz, pitch 0.01 deg @ 29 Hz (2.7 deg/s); one sample lost "
             "every 20 s, 5 ms before a fine update"))
    cases.append(Case("static_consumer", 300.0, specs="consumer", expectations=_HONEST,
                      note="consumer grade: heading unobservable, only E and N count"))
    cases.append(Case("upside_down_from_identity", 300.0, rpy_deg=(180.0, 0.0, 30.0),
                      initial_rpy_deg=None, expectations=_HONEST,
                      note="truth roll 180 deg, the Aligner starts from identity"))
    # sensor errors a datasheet lists beside the biases and noise densities, configured as
    # the datasheet gives them: bias instability (first-order Gauss-Markov wander) and the
    # quantum of the increments
    nav, tac = grade_specs("navigation"), grade_specs("tactical")
    for name, base, ratio, tau in (("wander_nav_0.3x_300s", nav, 0.3, 300.0),
                                   ("wander_nav_1x_30s", nav, 1.0, 30.0),
                                   ("wander_tactical_1x_30s", tac, 1.0, 30.0)):
        cases.append(Case(name, 600.0, specs=base.with_(
            gyro_bias_instability=ratio * base.gyro_bias,
            accel_bias_instability=ratio * base.accel_bias, bias_correlation_time=tau),
            expectations=_HONEST, note=f"bias instability {ratio:g}x the biases, correlation "
                                       f"time {tau:g} s"))
    cases.append(Case("warmup_nav_3x_300s", 600.0, specs=nav.with_(
        gyro_warmup=3.0 * nav.gyro_bias, accel_warmup=3.0 * nav.accel_bias, warmup_time=300.0),
        expectations=_HONEST, note="power-on biases of 3x the biases settling over 300 s"))
    cases.append(Case("quantized_nav", 600.0, specs=nav.with_(gyro_quantization=2e-5,
                                                              accel_quantization=5e-3),
                      expectations=_HONEST, note="increments quantised: 4 arcsec, 5 mm/s"))
    return {c.name: c for c in cases}


#: The disturbance matrix: name -> Case.
CASES: dict[str, Case] = _build_cases()
