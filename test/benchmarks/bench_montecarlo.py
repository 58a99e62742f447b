"""Monte Carlo throughput (a script, not a test).

Usage: python test/benchmarks/bench_montecarlo.py

1. ``sins_align.montecarlo`` end to end, constant model: sample-runs per second of the
   filter alone (IMU samples x runs / filter wall time) and of the whole tool (simulation
   included), with the paper's one-pass schedule (one gain shared by all runs) and with the
   package default pipeline.
2. The bare vectorised filter (AlignmentFilter.run, constant model, one-pass) for large N on
   one simulated run's samples repeated N times (the cost does not depend on the values).

The issue's target is 20,000,000 sample-runs/s for the constant model; the figures printed
are what this machine does, whatever they are.
"""
from __future__ import annotations

import os
import time

import numpy as np

from sins_align.estimator import AlignConfig, AlignmentFilter
from sins_align.montecarlo import ONE_PASS, Scenario, make_curves, run_montecarlo
from sins_align.sim import simulate

TARGET = 20e6


def tool(runs: int, duration: float, pipeline: str) -> dict:
    scn = Scenario(runs=runs, duration=duration, every=duration, fixed_biases=True)
    curves = make_curves(scn, "constant", one_pass=(pipeline == "one-pass"), paper=False)
    t0 = time.perf_counter()
    res = run_montecarlo(scn, curves)
    wall = time.perf_counter() - t0
    c = res["curves"][0]
    return dict(filt=c["sample_runs_per_s"], e2e=scn.samples * runs / wall,
                sim=res["simulation_wall_time_s"], shared=c["shared_gain"])


def bare(runs: int, steps: int = 300) -> float:
    s = simulate(steps / 100.0, 100.0, 34.0, specs="navigation", seed=1)
    W = np.repeat(s.gyro[:, None], runs, axis=1)
    F = np.repeat(s.accel[:, None], runs, axis=1)
    fl = AlignmentFilter(AlignConfig(latitude_deg=34.0, **ONE_PASS),
                         np.repeat(np.eye(3)[None], runs, axis=0))
    fl.run_fast(0.01, W[:10], F[:10])                 # warm-up (caches)
    t0 = time.perf_counter()
    fl.run_fast(0.01, W, F)
    return steps * runs / (time.perf_counter() - t0)


def main():
    print(f"1. montecarlo tool, constant model, 100 Hz, {os.cpu_count()} CPUs "
          f"(target {TARGET / 1e6:.0f} M sample-runs/s)")
    print(f"   {'pipeline':<10}{'runs':>7}{'duration':>10}{'filter':>14}{'of target':>11}"
          f"{'end to end':>14}{'sim s':>8}{'shared gain':>13}")
    for runs, duration, pipeline in ((100, 60.0, "one-pass"), (1000, 10.0, "one-pass"),
                                     (100, 90.0, "default")):
        m = tool(runs, duration, pipeline)
        print(f"   {pipeline:<10}{runs:>7}{duration:>9g}s{m['filt']:>14,.0f}"
              f"{100 * m['filt'] / TARGET:>10.1f}%{m['e2e']:>14,.0f}{m['sim']:>8.2f}"
              f"{str(m['shared']):>13}")
    print("   (sample-runs/s; 'end to end' includes sins_align.sim.simulate, one call per run)")
    print("2. bare AlignmentFilter.run, constant model, one-pass schedule")
    for runs in (1000, 10000, 30000):
        r = bare(runs)
        print(f"   N = {runs:>6}: {r:>12,.0f} sample-runs/s ({100 * r / TARGET:.1f}% of target)")


if __name__ == "__main__":
    main()
