"""Core estimator throughput: IMU samples per second for each model (a script, not a test).

Usage: python test/benchmarks/bench_core.py [--duration 600] [--runs 100]

Streams a 100 Hz simulated navigation-grade data set (static, from [89, 89, 179] deg)
through Aligner (input checks + filter, one IMU) for each model, and through
AlignmentFilter vectorised over --runs Monte Carlo runs (sample-runs per second).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from sins_align.estimator import Aligner, AlignConfig, AlignmentFilter
from sins_align.rotation import dcm_from_rpy
from sins_align.sim import simulate
from sins_align.specs import DEG

TARGET_CORE = 1_000_000      # issue 5: samples/s, constant model
TARGET_MC = 20_000_000       # issue 5: sample-runs/s


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=600.0, help="data length, s")
    ap.add_argument("--runs", type=int, default=100, help="Monte Carlo runs for the batch figure")
    a = ap.parse_args(argv)
    s = simulate(a.duration, 100.0, 34.0, specs="navigation", seed=1)
    n = len(s.t)
    print(f"core benchmark: {a.duration:.0f} s at 100 Hz = {n} samples, from [89, 89, 179] deg")
    print(f"{'model':<14}{'path':<26}{'samples/s':>14}{'target':>12}")
    for model in ("constant", "conventional", "se3"):
        al = Aligner(AlignConfig(latitude_deg=34.0, model=model, initial_rpy_deg=(89, 89, 179)))
        t0 = time.perf_counter()
        al.update(s.t, s.gyro, s.accel)
        rate = n / (time.perf_counter() - t0)
        tgt = f"{TARGET_CORE:,}" if model == "constant" else ""
        print(f"{model:<14}{'Aligner (streaming)':<26}{rate:>14,.0f}{tgt:>12}")
    m = a.runs
    sims = [simulate(min(a.duration, 300.0), 100.0, 34.0, specs="navigation", seed=10 + i)
            for i in range(m)]
    W = np.stack([x.gyro for x in sims], 1)
    F = np.stack([x.accel for x in sims], 1)
    C0 = np.stack([x.C0 @ dcm_from_rpy(np.array([89, 89, 179]) * DEG).T for x in sims])
    fl = AlignmentFilter(AlignConfig(latitude_deg=34.0), C0)
    t0 = time.perf_counter()
    fl.run(0.01, W, F)
    rate = W.shape[0] * m / (time.perf_counter() - t0)
    print(f"{'constant':<14}{f'AlignmentFilter x{m} runs':<26}{rate:>14,.0f}{TARGET_MC:>12,}"
          "  (sample-runs/s)")


if __name__ == "__main__":
    main()
