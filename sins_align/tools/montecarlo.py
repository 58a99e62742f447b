"""Monte Carlo accuracy of the alignment filter: N simulated runs, one vectorised filter.

Usage::

    python -m sins_align.tools.montecarlo [--runs N] [--duration S] [--rate HZ] [--latitude DEG]
        [--height M] [--grade NAME] [--gyro-bias DEG/H] [--gyro-arw DEG/SQRT(H)]
        [--accel-bias UG] [--accel-vrw UG/SQRT(HZ)] [--fixed-biases] [--noise-free]
        [--sway none|car|ship] [--sway-amplitude K]
        [--initial-error R P Y | --random-initial] [--true-rpy R P Y | --random-truth]
        [--model constant|conventional|se3|all] [--one-pass | --no-backtrack] [--paper]
        [--seed N] [--every S] [--chunk RUNS] [--json FILE] [--csv FILE]
        [--plot FILE.png]
    python -m sins_align.tools.montecarlo --study NAME [--runs N] [--seed N] [--duration S]
        [--json FILE] [--plot FILE.png]

``--study NAME`` runs a comparison study of :data:`sins_align.studies.STUDIES` instead (the
seeds' methods beside ours; the scenario is the study's, ``--duration`` shortens it).

Run ``i`` is ``sins_align.sim.simulator.simulate(..., seed=seed + i)``; the runs are stacked and fed
to **one** :class:`~sins_align.estimators.quasi_static.AlignmentFilter` per curve (``C0`` of shape
(N, 3, 3)), so all runs share one time line (and, for the constant model, one gain schedule). Big N
is processed in chunks of runs (``--chunk``, default: as many as fit in about 512 MB, at most 4096).

Initial estimate
----------------
``--initial-error R P Y`` (deg, default 89 89 179): the initial estimate of run ``i`` is
``C_true(0) · dcm_from_rpy(err)^T`` — the truth "plus" the error, as
``test/benchmarks/bench_accuracy.py`` does. ``--random-initial``: uniform on SO(3),
independent of the truth. ``--random-truth``: the true mean attitude is uniform on SO(3).

Statistics (per curve, at t = 0, every, 2 every, ..., duration)
----------------------------------------------------------------
phi (ALGORITHM.md, paper eq. 15: ``C_true = exp(phi x) C_est``) on E, N, U, in degrees:
mean, RMS and max |phi| over the runs; mean published std (``sqrt`` of the diagonal of
``total_covariance()``, the bias floor included) and mean noise-only std (``fl.P``); mean
NEES ``phi^T P^-1 phi`` (3 dof per run) with its 95 % bounds ``chi2(0.025|0.975, 3N) / N``.
Limit accuracy per run: ``limit_error`` of the run's biases projected on ENU at the true
initial attitude. Settling: per run and axis, the first output time after which
``|phi| <= tolerance x |limit|`` holds to the end (null = never within the duration); the
JSON gives its median and maximum over the runs.

``--paper``: the reference scenario of ALGORITHM.md (34 deg N, navigation grade with fixed
biases 0.01 deg/h and 100 ug on every axis, 100 Hz, truth [0, 0, 0], error [89, 89, 179] deg),
the three models with the paper's one-pass schedule (``backtrack=False,
coarse_update_period=0``) plus the package default pipeline as a fourth curve. Options given
explicitly override the paper values.

Outputs (each appears only when complete; an existing path is an error): ``--json`` the
statistics, ``--csv`` the time series (one row per curve and time), ``--plot`` the paper's
figures (|phi| against time, log scale, one panel per E/N/U axis, limit lines; matplotlib).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from sins_align.io.bagio import (AtomicOutput, CliError, atomic_outputs, check_new_output,
                                 cli_main, finite_or_none, need_matplotlib, pyplot)
from sins_align.tools.simulate import specs_from_args
from sins_align.core.earth import gravity
from sins_align.core.models import MODELS
from sins_align.estimators.quasi_static import AlignConfig, AlignmentFilter
from sins_align.core.rotation import attitude_error, dcm_from_quat, dcm_from_rpy, rpy_from_dcm
from sins_align.core.specs import (DEG, DPH, DPSH, GRADES, UG, UG_PSHZ, SensorSpecs, grade_specs,
                                   limit_error, limit_std)

PROG = "montecarlo"
AXES = ("E", "N", "U")
#: Paper reference scenario (ALGORITHM.md, paper section 3.1).
PAPER = dict(latitude=34.0, height=0.0, rate=100.0, grade="navigation", true_rpy=(0.0, 0.0, 0.0),
             initial_error=(89.0, 89.0, 179.0), fixed_biases=True, model="all", one_pass=True)
DEFAULTS = dict(latitude=34.0, height=0.0, rate=100.0, grade="navigation",
                true_rpy=(0.0, 0.0, 0.0), initial_error=(89.0, 89.0, 179.0), fixed_biases=False,
                model="constant", one_pass=False, sway="none", sway_amplitude=1.0)
#: The paper's one-pass filter: update at every sample, no backtrack.
ONE_PASS = dict(backtrack=False, coarse_update_period=0.0)
#: Memory budget of one chunk of runs (IMU samples + the filter's backtrack buffer), bytes.
CHUNK_BYTES = 512 * 2 ** 20
CHECKPOINTS = (10.0, 30.0, 60.0, 100.0, 150.0, 300.0, 600.0)
#: At most this many runs per filter: the per-update arrays (runs x 9 floats) then stay below
#: malloc's mmap threshold; measured here, 16000 runs at once were 2.5x slower than 4000.
MAX_CHUNK_RUNS = 4096


# ----------------------------------------------------------------------------- statistics
def _gammainc_lower(a: float, x: float) -> float:
    """Regularised lower incomplete gamma function P(a, x) (series / continued fraction)."""
    if x <= 0.0:
        return 0.0
    log_pre = -x + a * math.log(x) - math.lgamma(a)
    if x < a + 1.0:
        ap, term, total = a, 1.0 / a, 1.0 / a
        for _ in range(1_000_000):
            ap += 1.0
            term *= x / ap
            total += term
            if abs(term) < abs(total) * 1e-16:
                break
        return min(1.0, total * math.exp(log_pre))
    tiny = 1e-300
    b = x + 1.0 - a
    c, d = 1.0 / tiny, 1.0 / b
    h = d
    for i in range(1, 1_000_000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-16:
            break
    return max(0.0, 1.0 - math.exp(log_pre) * h)


def chi2_ppf(p: float, dof: float) -> float:
    """Quantile of the chi-square distribution with ``dof`` degrees of freedom (bisection on
    the exact CDF, relative accuracy ~1e-12; no scipy needed)."""
    if not (0.0 < p < 1.0) or not dof > 0:
        raise ValueError(f"chi2_ppf needs 0 < p < 1 and dof > 0, got p={p!r}, dof={dof!r}")
    a = 0.5 * dof
    lo, hi = 0.0, max(2.0 * dof, dof + 10.0 * math.sqrt(2.0 * dof) + 10.0)
    while _gammainc_lower(a, 0.5 * hi) < p:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _gammainc_lower(a, 0.5 * mid) < p:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-13 * hi:
            break
    return 0.5 * (lo + hi)


def nees_bounds(runs: int, dim: int = 3, confidence: float = 0.95) -> tuple[float, float]:
    """Two-sided bounds of the mean NEES over ``runs`` runs of ``dim`` dof each: the sum of
    the NEES is chi-square with ``dim * runs`` dof, so the mean lies in
    ``[chi2((1-c)/2, dim N), chi2((1+c)/2, dim N)] / N`` with probability ``confidence``."""
    k = dim * runs
    q = 0.5 * (1.0 - confidence)
    return chi2_ppf(q, k) / runs, chi2_ppf(1.0 - q, k) / runs


def nees(err: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared ``e^T P^-1 e``.

    err : (N, d); cov : (N | 1, d, d) -> (N,).
    """
    err = np.asarray(err, dtype=float)
    cov = np.broadcast_to(np.asarray(cov, dtype=float), err.shape + err.shape[-1:])
    return np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[..., None])[..., 0])


def settle_times(ok: np.ndarray, times: np.ndarray) -> np.ndarray:
    """First time after which ``ok`` stays true to the end; inf if it is false at the end.

    ok : (T, ...) bool over the output times ``times`` (T,) -> (...) float.
    """
    ok = np.asarray(ok, dtype=bool)
    bad = ~ok
    last_bad = np.where(bad.any(axis=0), len(ok) - 1 - np.argmax(bad[::-1], axis=0), -1)
    t_ext = np.append(np.asarray(times, dtype=float), np.inf)
    return t_ext[last_bad + 1]


class CurveStats:
    """Statistics of one curve (a filter configuration) over all runs, per output time.

    Feed chunks of runs with :meth:`add` (errors, published covariance and noise covariance at
    every output time, and each run's limit error); read :meth:`result`.

    Parameters
    ----------
    times : (T,) s — output times.
    tolerance : settling tolerance on |phi| / |limit|.
    """

    def __init__(self, times: np.ndarray, tolerance: float = 1.2):
        self.times = np.asarray(times, dtype=float)
        self.tol = tolerance
        T = len(self.times)
        self.n = 0
        self.sum_e = np.zeros((T, 3))
        self.sum_e2 = np.zeros((T, 3))
        self.max_abs = np.zeros((T, 3))
        self.sum_std = np.zeros((T, 3))
        self.sum_noise_std = np.zeros((T, 3))
        self.sum_nees = np.zeros(T)
        self.settle = []            # (n, 4) per chunk: E, N, U, all axes
        self.filter_time = 0.0
        self.samples = 0            # sample-runs processed by the filter
        self.reinflated_runs = 0    # runs whose covariance was re-inflated at least once
        self.shared_gain = True     # the filter kept one covariance/gain for all runs

    def add(self, err: np.ndarray, cov: np.ndarray, noise_cov: np.ndarray, limit: np.ndarray):
        """err (T, n, 3) rad; cov, noise_cov (T, n|1, 3, 3) rad^2; limit (n, 3) rad."""
        err = np.asarray(err, dtype=float)
        n = err.shape[1]
        cov = np.broadcast_to(cov, err.shape + (3,))
        noise_cov = np.broadcast_to(noise_cov, err.shape + (3,))
        self.n += n
        self.sum_e += err.sum(axis=1)
        self.sum_e2 += (err ** 2).sum(axis=1)
        self.max_abs = np.maximum(self.max_abs, np.abs(err).max(axis=1))
        self.sum_std += np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1)).sum(axis=1)
        self.sum_noise_std += np.sqrt(np.diagonal(noise_cov, axis1=-2, axis2=-1)).sum(axis=1)
        for k in range(len(err)):
            self.sum_nees[k] += nees(err[k], cov[k]).sum()
        ok = np.abs(err) <= self.tol * np.abs(limit)[None]
        st = settle_times(ok, self.times)
        st_all = settle_times(ok.all(axis=2), self.times)
        self.settle.append(np.column_stack([st, st_all]))

    def settle_array(self) -> np.ndarray:
        """(N, 4) settle times of every run: E, N, U, all axes (inf = never)."""
        return np.concatenate(self.settle) if self.settle else np.zeros((0, 4))

    def result(self) -> dict[str, Any]:
        """JSON-ready statistics, degrees (see the module docstring)."""
        n = max(self.n, 1)
        st = self.settle_array()
        d = 1.0 / DEG
        return {
            "runs": self.n,
            "time_s": self.times.tolist(),
            "mean_deg": (self.sum_e / n * d).tolist(),
            "rms_deg": (np.sqrt(self.sum_e2 / n) * d).tolist(),
            "max_abs_deg": (self.max_abs * d).tolist(),
            "std_mean_deg": (self.sum_std / n * d).tolist(),
            "noise_std_mean_deg": (self.sum_noise_std / n * d).tolist(),
            "nees_mean": (self.sum_nees / n).tolist(),
            "settle": {
                "tolerance": self.tol,
                "axes": ["E", "N", "U", "all"],
                "median_s": [finite_or_none(v) for v in np.median(st, axis=0)] if len(st) else None,
                "max_s": [finite_or_none(v) for v in st.max(axis=0)] if len(st) else None,
                "settled_runs": np.isfinite(st).sum(axis=0).tolist(),
            },
            "reinflated_runs": self.reinflated_runs,
            "shared_gain": self.shared_gain,
            "filter_wall_time_s": self.filter_time,
            "sample_runs_per_s": (self.samples / self.filter_time
                                  if self.filter_time > 0 else None),
        }


# ----------------------------------------------------------------------------- scenario
@dataclass(frozen=True)
class Scenario:
    """What is simulated. Angles in degrees, SI otherwise.

    true_rpy_deg None = uniform random true attitude per run; initial_error_deg None =
    uniform random initial estimate per run. fixed_biases: every axis at +1 sigma of the
    specs (the paper); otherwise drawn per run by the simulator.
    """

    runs: int = 100
    duration: float = 300.0
    rate: float = 100.0
    latitude_deg: float = 34.0
    height_m: float = 0.0
    specs: SensorSpecs = field(default_factory=lambda: grade_specs("navigation"))
    grade: str = "navigation"
    fixed_biases: bool = False
    noise: bool = True
    sway: str = "none"
    sway_amplitude: float = 1.0
    true_rpy_deg: tuple[float, float, float] | None = (0.0, 0.0, 0.0)
    initial_error_deg: tuple[float, float, float] | None = (89.0, 89.0, 179.0)
    seed: int = 0
    every: float = 1.0

    @property
    def samples(self) -> int:
        return int(math.floor(self.duration * self.rate + 1e-9))

    def output_indices(self) -> np.ndarray:
        """Sample counts at the output times (0 = before the first sample)."""
        step = max(1, int(round(self.every * self.rate)))
        idx = np.arange(0, self.samples + 1, step)
        if idx[-1] != self.samples:
            idx = np.append(idx, self.samples)
        return idx

    def to_json(self) -> dict[str, Any]:
        sp = self.specs
        return {
            "runs": self.runs, "duration_s": self.duration, "rate_hz": self.rate,
            "latitude_deg": self.latitude_deg, "height_m": self.height_m, "grade": self.grade,
            "specs": {"gyro_bias_deg_h": sp.gyro_bias / DPH,
                      "gyro_arw_deg_sqrt_h": sp.gyro_arw / DPSH,
                      "accel_bias_ug": sp.accel_bias / UG,
                      "accel_vrw_ug_sqrt_hz": sp.accel_vrw / UG_PSHZ},
            "biases": "fixed +1 sigma on every axis" if self.fixed_biases else "drawn per run",
            "noise": self.noise, "sway": self.sway, "sway_amplitude": self.sway_amplitude,
            "true_rpy_deg": list(self.true_rpy_deg) if self.true_rpy_deg else "random",
            "initial_error_rpy_deg": (list(self.initial_error_deg) if self.initial_error_deg
                                      else "random"),
            "initial_error_convention": "C_est(0) = C_true(0) dcm_from_rpy(error)^T",
            "seed": self.seed, "every_s": self.every,
        }


@dataclass(frozen=True)
class Curve:
    """One filter configuration to evaluate: name, label, AlignConfig."""

    name: str
    label: str
    config: AlignConfig

    def to_json(self) -> dict[str, Any]:
        c = self.config
        return {"name": self.name, "label": self.label, "model": c.model,
                "backtrack": c.backtrack, "coarse_update_period_s": c.coarse_update_period}


def make_curves(scn: Scenario, model: str, one_pass: bool, paper: bool,
                backtrack: bool = True) -> list[Curve]:
    """The curves to run: the model(s) with the chosen pipeline; --paper adds the default.

    one_pass: the paper's filter (update at every sample, no backtrack); backtrack=False:
    the coarse pass alone (update every coarse_update_period, one gain for all runs)."""
    base = AlignConfig(latitude_deg=scn.latitude_deg, height_m=scn.height_m, specs=scn.specs)
    models = MODELS if model == "all" else (model,)
    curves = []
    for m in models:
        if one_pass:
            curves.append(Curve(m, f"{m} (paper one-pass)", base.with_(model=m, **ONE_PASS)))
        elif not backtrack:
            curves.append(Curve(m, f"{m} (coarse pass, no backtrack)",
                                base.with_(model=m, backtrack=False)))
        else:
            curves.append(Curve(m, f"{m} (default pipeline)", base.with_(model=m)))
    if paper:
        curves.append(Curve("default", "default pipeline (constant, backtrack)", base))
    return curves


def _uniform_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return dcm_from_quat(q / np.linalg.norm(q))


def simulate_chunk(scn: Scenario, first: int, count: int) -> dict[str, np.ndarray]:
    """Simulate runs ``first .. first+count-1`` together
    (:func:`sins_align.sim.simulator.simulate_runs`;
    run ``i`` is ``simulate(..., seed=scn.seed + i)`` bit for bit).

    Returns
    -------
    dict with W, F (T, n, 3) rad/s, m/s^2; C_out (K, n, 3, 3) true C_b^n at the output
    times; C_est0 (n, 3, 3) initial estimates; limit (n, 3) rad, limit error of each run.
    """
    from sins_align.sim.simulator import simulate_runs

    runs = range(first, first + count)
    if scn.true_rpy_deg is None:
        rpy = rpy_from_dcm(np.array([_uniform_rotation(np.random.default_rng([scn.seed, i, 1]))
                                     for i in runs])) / DEG
    else:
        rpy = scn.true_rpy_deg
    sp = scn.specs
    bias = (dict(gyro_bias=np.full(3, sp.gyro_bias), accel_bias=np.full(3, sp.accel_bias))
            if scn.fixed_biases else {})
    s = simulate_runs(scn.duration, [scn.seed + i for i in runs], scn.rate, scn.latitude_deg,
                      scn.height_m, rpy_deg=rpy, specs=sp, sway=scn.sway,
                      sway_amplitude=scn.sway_amplitude, noise=scn.noise,
                      truth_at=scn.output_indices()[1:] - 1, **bias)
    if scn.initial_error_deg is None:
        C_est0 = np.array([_uniform_rotation(np.random.default_rng([scn.seed, i, 2]))
                           for i in runs])
    else:
        C_est0 = s.C0 @ dcm_from_rpy(np.array(scn.initial_error_deg) * DEG).T
    g = gravity(scn.latitude_deg * DEG, scn.height_m)
    limit = limit_error(scn.latitude_deg * DEG, (s.C0 @ s.accel_bias[..., None])[..., 0],
                        (s.C0 @ s.gyro_bias[..., None])[..., 0], g)
    return dict(W=s.gyro, F=s.accel, C_out=np.concatenate([s.C0[None], s.C_true]),
                C_est0=C_est0, limit=limit)


def chunk_runs(scn: Scenario, curves: Sequence[Curve], budget: int = CHUNK_BYTES) -> int:
    """Runs per chunk so that one chunk's arrays fit ``budget`` bytes: the stacked samples
    (6 floats per sample), the truth and the per-curve results at the output times (about 30
    floats per output) and the filter's backtrack buffer (grown by doubling)."""
    per_run = (scn.samples * 6 + len(scn.output_indices()) * 30) * 8
    if any(c.config.backtrack for c in curves):
        buffered = min(scn.samples, int(max(c.config.backtrack_time for c in curves)
                                        * scn.rate) + 1)
        per_run += 2 * buffered * 6 * 8
    return max(1, min(scn.runs, budget // per_run, MAX_CHUNK_RUNS))


def run_filter(curve: Curve, data: dict[str, np.ndarray], scn: Scenario, stats: CurveStats):
    """Run one curve's filter over a chunk of runs and add its statistics."""
    idx = scn.output_indices()
    n = data["C_est0"].shape[0]
    dt = 1.0 / scn.rate
    fl = AlignmentFilter(curve.config, data["C_est0"])
    K = len(idx)
    err = np.empty((K, n, 3))
    cov = np.empty((K, n, 3, 3))      # published (bias floor included)
    noise = np.empty((K, n, 3, 3))    # the filter's noise-only covariance

    def record(k):
        err[k] = attitude_error(data["C_out"][k], fl.C)
        cov[k] = fl.total_covariance()[:, :3, :3]
        noise[k] = np.asarray(fl.P)[:, :3, :3]

    record(0)
    t0 = time.perf_counter()
    for k in range(1, K):
        a, b = idx[k - 1], idx[k]
        fl.run_fast(dt, data["W"][a:b], data["F"][a:b])
        record(k)
    stats.filter_time += time.perf_counter() - t0
    stats.samples += scn.samples * n
    stats.reinflated_runs += int(np.count_nonzero(fl.reinflations))
    stats.shared_gain = stats.shared_gain and np.asarray(fl.P).shape[0] == 1
    stats.add(err, cov, noise, data["limit"])


def run_montecarlo(scn: Scenario, curves: Sequence[Curve], chunk: int | None = None,
                   tolerance: float = 1.2) -> dict[str, Any]:
    """Simulate ``scn.runs`` runs and evaluate every curve on them; JSON-ready result."""
    t_wall = time.perf_counter()
    idx = scn.output_indices()
    times = idx / scn.rate
    stats = {c.name: CurveStats(times, tolerance) for c in curves}
    chunk = chunk or chunk_runs(scn, curves)
    limits = []
    sim_time = 0.0
    for first in range(0, scn.runs, chunk):
        count = min(chunk, scn.runs - first)
        t0 = time.perf_counter()
        data = simulate_chunk(scn, first, count)
        sim_time += time.perf_counter() - t0
        limits.append(data["limit"])
        for c in curves:
            run_filter(c, data, scn, stats[c.name])
        del data
    lim = np.concatenate(limits)
    g = gravity(scn.latitude_deg * DEG, scn.height_m)
    d = 1.0 / DEG
    lo, hi = nees_bounds(scn.runs)
    wall = time.perf_counter() - t_wall
    total_samples = sum(s.samples for s in stats.values())
    filt_time = sum(s.filter_time for s in stats.values())
    return finite_or_none({
        "tool": "sins_align.tools.montecarlo",
        "schema_version": 1,
        "scenario": scn.to_json(),
        "axes": list(AXES),
        "angle_convention": "phi on E/N/U, C_true = exp(phi x) C_est (paper eq. 15), deg",
        "limit": {
            "mean_deg": (lim.mean(axis=0) * d).tolist(),
            "rms_abs_deg": (np.sqrt((lim ** 2).mean(axis=0)) * d).tolist(),
            "std_specs_deg": (limit_std(scn.latitude_deg * DEG, scn.specs, g) * d).tolist(),
        },
        "nees": {"dof_per_run": 3, "dof_total": 3 * scn.runs, "confidence": 0.95,
                 "bounds": [lo, hi]},
        "chunk_runs": chunk,
        "curves": [{**c.to_json(), **stats[c.name].result()} for c in curves],
        "simulation_wall_time_s": sim_time,
        "wall_time_s": wall,
        "sample_runs_per_s": total_samples / filt_time if filt_time > 0 else None,
    })


# ----------------------------------------------------------------------------- outputs
CSV_COLUMNS = (["curve", "t_s"] + [f"{s}_{a}_deg" for s in ("mean", "rms", "max_abs",
                                                              "std_mean", "noise_std_mean")
                                    for a in AXES] + ["nees_mean", "nees_lo", "nees_hi"])


def write_csv(path: Path, res: dict[str, Any]):
    lo, hi = res["nees"]["bounds"]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_COLUMNS)
        for c in res["curves"]:
            for k, t in enumerate(c["time_s"]):
                row = [c["name"], f"{t:.6g}"]
                for key in ("mean_deg", "rms_deg", "max_abs_deg", "std_mean_deg",
                            "noise_std_mean_deg"):
                    row += [_fmt(v) for v in c[key][k]]
                row += [_fmt(c["nees_mean"][k]), _fmt(lo), _fmt(hi)]
                w.writerow(row)


def _fmt(v) -> str:
    return "" if v is None else f"{v:.9g}"


def write_json(path: Path, res: dict[str, Any]):
    with open(path, "w") as fh:
        json.dump(res, fh, indent=1, allow_nan=False)
        fh.write("\n")


def write_plot(path: Path, res: dict[str, Any]):
    """The paper's figures 1-3: |phi| against time for each curve, one panel per E/N/U axis
    (log scale), RMS over the runs (solid) and the max over the runs (faint), with the
    limit accuracy (dashed) and the settling band 1.2 x limit (dotted)."""
    plt = pyplot()

    s = res["scenario"]
    lim = res["limit"]["rms_abs_deg"]
    tol = res["curves"][0]["settle"]["tolerance"] if res["curves"] else 1.2
    titles = ("phi_E: level error about East", "phi_N: level error about North",
              "phi_U: heading error (about Up)")
    fig, axes = plt.subplots(3, 1, figsize=(9, 10), sharex=True)
    for i, ax in enumerate(axes):
        for j, c in enumerate(res["curves"]):
            t = np.array(c["time_s"])
            rms = np.array([r[i] for r in c["rms_deg"]], dtype=float)
            mx = np.array([r[i] for r in c["max_abs_deg"]], dtype=float)
            col = f"C{j}"
            ax.semilogy(t, rms, color=col, lw=1.4, label=c["label"])
            if c["runs"] > 1:
                ax.semilogy(t, mx, color=col, lw=0.7, alpha=0.35)
        if lim[i]:
            ax.axhline(lim[i], color="k", ls="--", lw=1.0,
                       label=f"limit accuracy {lim[i]:.4f} deg")
            ax.axhline(tol * lim[i], color="k", ls=":", lw=0.8, label=f"{tol:g} x limit")
        ax.set_ylabel("|error|, deg")
        ax.set_title(titles[i], fontsize="medium")
        ax.grid(True, which="major", alpha=0.3)
    axes[0].legend(loc="upper right", fontsize="small")
    axes[-1].set_xlabel("time, s")
    init = s["initial_error_rpy_deg"]
    truth = s["true_rpy_deg"]
    fig.suptitle(
        f"Alignment error, {s['runs']} runs (RMS solid, max faint): {s['latitude_deg']:g} deg N, "
        f"{s['grade']}, sway {s['sway']},\ntruth "
        f"{truth if isinstance(truth, str) else [round(a, 2) for a in truth]}, initial error "
        f"{init if isinstance(init, str) else [round(a, 2) for a in init]} deg (R, P, Y)",
        fontsize="medium")
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=100)
    plt.close(fig)


def summary_text(res: dict[str, Any]) -> str:
    """One screen: final errors against the limit, NEES, settling, speed."""
    s = res["scenario"]
    lim = res["limit"]["mean_deg"]
    lo, hi = res["nees"]["bounds"]

    def v3(v, fmt="{:+.4f}"):
        return " ".join("   -   " if x is None else fmt.format(x) for x in v)

    truth = s["true_rpy_deg"]
    truth = "uniform random" if isinstance(truth, str) else f"{list(truth)} deg"
    init = s["initial_error_rpy_deg"]
    init = ("initial estimate uniform random" if isinstance(init, str)
            else f"initial error {list(init)} deg")
    lines = [
        f"montecarlo: {s['runs']} runs x {s['duration_s']:g} s at {s['rate_hz']:g} Hz, "
        f"{s['latitude_deg']:g} deg N, {s['grade']} ({s['biases']}"
        f"{'' if s['noise'] else ', noise-free'}), sway {s['sway']}, truth {truth}, {init}, "
        f"seed {s['seed']}",
        f"limit accuracy E/N/U (mean over runs) {v3(lim)} deg; |limit| RMS "
        f"{v3(res['limit']['rms_abs_deg'], '{:.4f}')} deg",
        f"at t = {s['duration_s']:g} s: RMS error, mean published std, mean NEES "
        f"(95 % bounds for {res['nees']['dof_total']} dof: {lo:.2f}..{hi:.2f})",
    ]
    for c in res["curves"]:
        lines.append(f"  {c['label']:<40} RMS {v3(c['rms_deg'][-1], '{:.4f}')}  std "
                     f"{v3(c['std_mean_deg'][-1], '{:.4f}')}  NEES {c['nees_mean'][-1]:.2f}")
    st = res["curves"][0]["settle"]["tolerance"] if res["curves"] else 1.2
    lines.append(f"time to reach and stay within {st:g} x |limit|, median / max over runs, s "
                 f"(- = not within {s['duration_s']:g} s)")
    lines.append(f"  {'':<40} {'E':>13} {'N':>13} {'U':>13} {'all':>13}")

    def ts(x):
        return "-" if x is None else f"{x:.0f}"

    for c in res["curves"]:
        se = c["settle"]
        cells = [f"{ts(m)} / {ts(x)}" for m, x in zip(se["median_s"], se["max_s"])]
        lines.append(f"  {c['label']:<40} " + " ".join(f"{x:>13}" for x in cells))
    t = np.array(res["curves"][0]["time_s"]) if res["curves"] else np.zeros(0)
    cps = [cp for cp in CHECKPOINTS if cp <= s["duration_s"] + 1e-9]
    if cps:
        lines.append("heading RMS error, deg, at t = " + ", ".join(f"{cp:g}" for cp in cps)
                     + " s")
        for c in res["curves"]:
            vals = []
            for cp in cps:
                k = int(np.argmin(np.abs(t - cp)))
                vals.append(f"{c['rms_deg'][k][2]:.4f}")
            lines.append(f"  {c['label']:<40} " + " ".join(f"{v:>8}" for v in vals))
    lines.append("speed: " + ", ".join(
        f"{c['name']} {c['sample_runs_per_s'] / 1e6:.3f} M" for c in res["curves"]
        if c["sample_runs_per_s"]) + " sample-runs/s (filter only); "
        f"simulation {res['simulation_wall_time_s']:.1f} s, total {res['wall_time_s']:.1f} s")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- CLI
class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (CliError) instead of usage + exit."""

    def error(self, message):
        raise CliError(message)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description=(
        "Monte Carlo accuracy of the alignment filter: N simulated runs of a quasi-static "
        "scenario through one filter vectorised over the runs; per-axis error statistics "
        "against time, NEES, time to the limit accuracy, speed."))
    sc = p.add_argument_group("scenario (defaults: 34 deg N, navigation grade, static)")
    sc.add_argument("--runs", type=int, help="number of runs (default 100; --study: 4)")
    sc.add_argument("--duration", type=float, help="s per run (default 300; --study: the "
                    "study's)")
    sc.add_argument("--rate", type=float, help="IMU rate, Hz (default 100)")
    sc.add_argument("--latitude", type=float, help="deg (default 34)")
    sc.add_argument("--height", type=float, help="m (default 0)")
    sc.add_argument("--grade", choices=sorted(GRADES), help="sensor grade (default navigation)")
    sc.add_argument("--gyro-bias", type=float, help="gyro bias 1-sigma, deg/h (overrides grade)")
    sc.add_argument("--gyro-arw", type=float, help="gyro ARW, deg/sqrt(h)")
    sc.add_argument("--accel-bias", type=float, help="accelerometer bias 1-sigma, micro-g")
    sc.add_argument("--accel-vrw", type=float, help="accelerometer noise, micro-g/sqrt(Hz)")
    sc.add_argument("--fixed-biases", action="store_true", default=None,
                    help="biases at +1 sigma on every axis (paper) instead of drawn per run")
    sc.add_argument("--noise-free", action="store_true",
                    help="no white noise (biases stay): the filter's own convergence")
    sc.add_argument("--sway", choices=("none", "car", "ship"), help="base motion (default none)")
    sc.add_argument("--sway-amplitude", type=float, help="factor on the sway (default 1)")
    g = sc.add_mutually_exclusive_group()
    g.add_argument("--initial-error", type=float, nargs=3, metavar=("R", "P", "Y"),
                   help="initial error, REP-103 roll pitch yaw deg, applied to the truth: "
                   "C_est = C_true dcm_from_rpy(err)^T (default 89 89 179)")
    g.add_argument("--random-initial", action="store_true",
                   help="initial estimate uniform on SO(3), per run")
    g = sc.add_mutually_exclusive_group()
    g.add_argument("--true-rpy", type=float, nargs=3, metavar=("R", "P", "Y"),
                   help="true mean attitude, REP-103 deg in ENU (default 0 0 0)")
    g.add_argument("--random-truth", action="store_true",
                   help="true attitude uniform on SO(3), per run")
    sc.add_argument("--seed", type=int, default=0, help="run i uses seed + i (default 0)")
    fi = p.add_argument_group("filter")
    fi.add_argument("--model", choices=(*MODELS, "all"),
                    help="error model (default constant; --paper: all)")
    fi.add_argument("--one-pass", action="store_true", default=None,
                    help="the paper's one-pass filter (backtrack=False, coarse_update_period=0)"
                    " instead of the package default pipeline")
    fi.add_argument("--no-backtrack", action="store_true",
                    help="the coarse pass alone: updates every 0.1 s, one gain shared by all "
                    "runs (the fastest configuration)")
    fi.add_argument("--paper", action="store_true",
                    help="the ALGORITHM.md reference scenario: 34 deg N, navigation grade with "
                    "fixed biases, 100 Hz, truth 0 0 0, error 89 89 179, the three models "
                    "one-pass plus the default pipeline (explicit options override)")
    fi.add_argument("--tolerance", type=float, default=1.2,
                    help="settling band, multiple of |limit| (default 1.2)")
    ou = p.add_argument_group("output")
    ou.add_argument("--every", type=float, default=1.0, help="output sampling, s (default 1)")
    ou.add_argument("--chunk", type=int, help="runs per chunk (default: fit about 512 MB)")
    ou.add_argument("--json", metavar="FILE", help="statistics (JSON)")
    ou.add_argument("--csv", metavar="FILE", help="time series (CSV)")
    ou.add_argument("--plot", metavar="FILE.png",
                    help="error against time, one panel per axis (needs matplotlib)")
    ou.add_argument("--quiet", action="store_true", help="no summary on stdout")
    p.add_argument("--study", help="run a comparison study instead (sins_align.studies: "
                   "seed003, seed004, feedback); takes --runs, --seed, --duration, --json, "
                   "--plot, --quiet")
    return p


def scenario_from_args(args) -> tuple[Scenario, list[Curve]]:
    """Resolve defaults (--paper or the package defaults), validate, build the curves."""
    base = PAPER if args.paper else DEFAULTS
    if args.duration is None:
        args.duration = 300.0
    if args.runs is None:
        args.runs = 100

    def pick(name, key=None):
        v = getattr(args, name)
        return base.get(key or name, DEFAULTS.get(key or name)) if v is None else v

    rate, lat, height = pick("rate"), pick("latitude"), pick("height")
    sway, amp = pick("sway"), pick("sway_amplitude")
    grade = pick("grade")
    checks = (("--runs", args.runs, args.runs >= 1), ("--duration", args.duration,
                                                       args.duration > 0),
              ("--rate", rate, rate > 0), ("--latitude", lat, abs(lat) <= 90),
              ("--height", height, -1e4 < height < 1e5),
              ("--sway-amplitude", amp, amp >= 0), ("--every", args.every, args.every > 0),
              ("--tolerance", args.tolerance, args.tolerance > 0))
    for name, v, ok in checks:
        if not (math.isfinite(v) and ok):
            raise CliError(f"{name} out of range: {v}")
    if args.seed < 0:
        raise CliError(f"--seed must be >= 0, got {args.seed}")
    if args.chunk is not None and args.chunk < 1:
        raise CliError(f"--chunk must be >= 1, got {args.chunk}")
    if int(math.floor(args.duration * rate + 1e-9)) < 1:
        raise CliError(f"--duration {args.duration} s is shorter than one sample at {rate} Hz")
    if args.every * rate < 0.5:
        raise CliError(f"--every {args.every} s is shorter than one sample at {rate} Hz")
    if args.random_truth:
        truth = None
    else:
        truth = tuple(args.true_rpy) if args.true_rpy is not None else base["true_rpy"]
    if args.random_initial:
        init = None
    else:
        init = (tuple(args.initial_error) if args.initial_error is not None
                else base["initial_error"])
    for name, v in (("--true-rpy", truth), ("--initial-error", init)):
        if v is not None and not all(math.isfinite(a) for a in v):
            raise CliError(f"{name} must be 3 finite angles, got {list(v)}")
    fixed = args.fixed_biases if args.fixed_biases is not None else base["fixed_biases"]
    scn = Scenario(runs=args.runs, duration=args.duration, rate=rate, latitude_deg=lat,
                   height_m=height, specs=specs_from_args(args, grade), grade=grade,
                   fixed_biases=fixed,
                   noise=not args.noise_free, sway=sway, sway_amplitude=amp,
                   true_rpy_deg=truth, initial_error_deg=init, seed=args.seed, every=args.every)
    model = pick("model")
    one_pass = pick("one_pass")
    try:
        if one_pass and args.no_backtrack:
            raise CliError("--one-pass and --no-backtrack exclude each other")
        curves = make_curves(scn, model, one_pass, args.paper, backtrack=not args.no_backtrack)
    except ValueError as e:
        raise CliError(str(e)) from None
    return scn, curves


def run_study(args) -> int:
    """``--study NAME``: a study of :data:`sins_align.studies.STUDIES`."""
    from sins_align import studies

    if args.study not in studies.STUDIES:
        raise CliError(f"--study: unknown study {args.study!r}; choose from "
                       f"{sorted(studies.STUDIES)}")
    if args.csv:
        raise CliError("--study writes --json and --plot only")
    if args.runs is None:
        args.runs = 4
    if args.runs < 1 or args.seed < 0:
        raise CliError("--runs must be >= 1 and --seed >= 0")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise CliError(f"--duration out of range: {args.duration}")
    if args.plot:
        need_matplotlib()
        if Path(args.plot).suffix.lower() != ".png":
            raise CliError(f"--plot writes PNG: give a .png file name, got {args.plot}")
    outs = {w: check_new_output(getattr(args, w), f"--{w}") for w in ("json", "plot")
            if getattr(args, w)}
    try:
        res = studies.STUDIES[args.study](runs=args.runs, seed=args.seed,
                                          duration=args.duration)
    except ValueError as e:
        raise CliError(str(e)) from None
    writers = {"json": write_json, "plot": studies.write_plot}
    with atomic_outputs({w: AtomicOutput(p) for w, p in outs.items()}) as tmps:
        for w, tmp in tmps.items():
            writers[w](tmp.tmp, finite_or_none(res))
    if not args.quiet:
        print(studies.summary_text(res))
        for w, p in outs.items():
            print(f"wrote {w} {p}")
    return 0


def run(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.study is not None:
        return run_study(args)
    scn, curves = scenario_from_args(args)
    if args.plot:
        need_matplotlib()
        if Path(args.plot).suffix.lower() != ".png":
            raise CliError(f"--plot writes PNG: give a .png file name, got {args.plot}")
    outs: dict[str, Path] = {}
    for what in ("json", "csv", "plot"):
        p = getattr(args, what)
        if p:
            path = check_new_output(p, f"--{what}")
            if any(path.resolve() == q.resolve() for q in outs.values()):
                raise CliError(f"--{what} {path} is also used by another output")
            outs[what] = path
    res = run_montecarlo(scn, curves, chunk=args.chunk, tolerance=args.tolerance)
    writers = {"json": write_json, "csv": write_csv, "plot": write_plot}
    with atomic_outputs({w: AtomicOutput(p) for w, p in outs.items()}) as tmps:
        for w, tmp in tmps.items():
            writers[w](tmp.tmp, res)
    if not args.quiet:
        print(summary_text(res))
        for w, p in outs.items():
            print(f"wrote {w} {p}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return cli_main(PROG, run, argv)


if __name__ == "__main__":
    sys.exit(main())
