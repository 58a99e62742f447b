"""Dropped samples on the real laser-gyro log (issue 10's proof item).

The whole log (1847 s, 100 Hz) is fed to an Aligner in 1 s blocks, as the node receives it,
once complete and once with 1 %, 5 % and 10 % of its samples missing, at random and in
bursts of 0.02-0.5 s (seeded). A run with holes must end within 3 sigma (its published
std, per axis) of the complete run's result; and its ``aligned`` flag must never be true
while its attitude, compared with the complete run's at the same instant, is off by more
than 3 sigma of its published covariance. The report (``-s``) also gives the difference
in the complete run's sigma: what the holes cost in precision; the heading std at the end
is held to what the estimator reaches (HEADING_STD_MOST).
"""
from __future__ import annotations

import numpy as np
import pytest

from sins_align.data import LASERGYRO
from sins_align.core.earth import earth_rate_enu
from sins_align.estimators.quasi_static.aligner import Aligner, AlignConfig
from sins_align.io.psins import psins_att_to_dcm, read_psins
from sins_align.core.rotation import attitude_error, rpy_from_dcm, so3_exp
from sins_align.core.specs import DEG

BLOCK = 100          # samples per update call: 1 s at 100 Hz


@pytest.fixture(scope="module")
def log():
    return read_psins(LASERGYRO)


def config(log) -> AlignConfig:
    start = psins_att_to_dcm(np.array([0.0, 0.0, -90.6]) * DEG)    # the header's coarse yaw
    return AlignConfig(latitude_deg=log.lat_rad / DEG, height_m=log.height_m,
                       initial_rpy_deg=tuple(rpy_from_dcm(start) / DEG))


def run(log, keep: np.ndarray):
    """Feed the kept samples block by block; after each block record (index of the last
    sample fed, C_b^n, published covariance, aligned). Returns (aligner, records)."""
    al = Aligner(config(log))
    idx = np.flatnonzero(keep)
    cuts = np.searchsorted(idx, np.arange(0, log.n + BLOCK, BLOCK))
    rec = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        if b > a:
            sel = idx[a:b]
            al.update(log.t[sel], log.gyro[sel], log.accel[sel])
            rec.append((int(sel[-1]), al.dcm.copy(), al.covariance.copy(), al.aligned))
        else:
            rec.append(None)
    return al, rec


@pytest.fixture(scope="module")
def full(log):
    return run(log, np.ones(log.n, dtype=bool))


def pattern(n: int, kind: str, fraction: float, seed: int) -> np.ndarray:
    """Mask of the kept samples: ``fraction`` of n dropped, uniformly at random or in
    bursts of 2-50 consecutive samples (0.02-0.5 s) at random places."""
    rng = np.random.default_rng(seed)
    keep = np.ones(n, dtype=bool)
    want = int(round(fraction * n))
    if kind == "random":
        keep[rng.choice(n, want, replace=False)] = False
        return keep
    while n - keep.sum() < want:
        length = int(rng.integers(2, 51))
        start = int(rng.integers(0, n - length))
        keep[start:start + length] = False
    return keep


def full_at(log, full_rec, j: int, k: int) -> np.ndarray:
    """The complete run's attitude after block j carried back to sample k (the dropped
    run's last sample in that block) through the samples after k: the damped attitude
    update C_m = exp(-w_ie dt) C_m-1 exp(w_m dt), inverted."""
    C = full_rec[j][1]
    back_earth = so3_exp(earth_rate_enu(log.lat_rad) * log.ts)
    for m in range(full_rec[j][0], k, -1):
        C = back_earth @ C @ so3_exp(log.gyro[m] * log.ts).T
    return C


CASES = [(kind, frac) for kind in ("random", "bursts") for frac in (0.01, 0.05, 0.10)]
#: deg, heading std at the end: what the holes cost (0.047 deg with every sample), with a
#: margin of about 15 % over what the estimator reaches today
HEADING_STD_MOST = {("random", 0.01): 0.125, ("random", 0.05): 0.27, ("random", 0.10): 0.39,
                    ("bursts", 0.01): 0.14, ("bursts", 0.05): 0.36, ("bursts", 0.10): 1.45}


@pytest.mark.parametrize("kind,fraction", CASES, ids=[f"{k}-{int(f * 100)}pct" for k, f in CASES])
def test_dropped_samples_end_within_3_sigma_and_never_aligned_while_wrong(log, full, kind,
                                                                         fraction):
    seed = 1000 + int(round(fraction * 100)) + (50 if kind == "bursts" else 0)
    keep = pattern(log.n, kind, fraction, seed)
    al, rec = run(log, keep)
    full_al, full_rec = full
    assert al.events.get("missing_samples", 0) > 0.9 * (log.n - keep.sum())
    # while aligned, the error against the complete run stays within 3 sigma (published)
    wrong = []
    aligned_blocks = 0
    for j, r in enumerate(rec):
        if r is None or not r[3]:
            continue
        aligned_blocks += 1
        k, C, P, _ = r
        e = attitude_error(full_at(log, full_rec, j, k), C)
        ratio = np.abs(e) / np.sqrt(np.diag(P))
        if np.any(ratio > 3.0):
            wrong.append((j + 1, np.round(ratio, 2).tolist()))
    assert not wrong, f"aligned while off by > 3 sigma at (s, |e|/sigma E N U): {wrong[:10]}"
    # the end: within 3 sigma of the complete run, by its own std and by the complete run's
    e = attitude_error(full_al.dcm, al.dcm) / DEG
    sd_drop, sd_full = al.std_enu_deg, full_al.std_enu_deg
    report = (f"{kind} {fraction:.0%}: end difference E N U {np.round(e, 5)} deg; "
              f"|e|/sigma_dropped {np.round(np.abs(e) / sd_drop, 2)}, "
              f"|e|/sigma_full {np.round(np.abs(e) / sd_full, 2)}; "
              f"sigma_dropped {np.round(sd_drop, 4)}, sigma_full {np.round(sd_full, 4)} deg; "
              f"aligned at the end {al.aligned}, in {aligned_blocks} of {len(rec)} blocks")
    print(report)
    assert np.all(np.abs(e) <= 3 * sd_drop), report
    assert sd_drop[2] <= HEADING_STD_MOST[kind, fraction], report
