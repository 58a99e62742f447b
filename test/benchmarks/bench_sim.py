"""Simulation throughput of the Monte Carlo tool (a script, not a test).

Usage: python test/benchmarks/bench_sim.py [--repeat K]

Sample-runs per second (IMU samples x runs / wall time, 100 Hz, navigation grade) of

- the per-run loop: ``sins_align.sim.simulator.simulate`` once per run (seed = i), stacked into W, F
  (T, n, 3) -- what ``montecarlo.simulate_chunk`` did before the batch;
- the batch: ``sins_align.sim.simulator.simulate_runs`` (what ``simulate_chunk`` does now);

on a static base with the truth shared by all runs (fixed attitude) or one per run (random
attitude, drawn biases), and with the car sway, for 1000 runs x 10 s and 100 runs x 60 s. Also
printed: the largest difference between the two (the batch is meant to be bit for bit), and
numpy's float64 ``standard_normal`` rate over the 6 normals a sample-run needs, the bound of
the simulation. Best of K repetitions (the first touch of fresh memory is slow on some
machines).
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from sins_align.sim.simulator import simulate, simulate_runs


def best(f, repeat: int):
    """(best wall time, last result) of ``repeat`` calls of f()."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t0)
    return min(times), out


def loop(n: int, duration: float, rpy, **kw):
    """The per-run loop: (W, F)."""
    W = np.empty((int(duration * 100), n, 3))
    F = np.empty_like(W)
    for i in range(n):
        s = simulate(duration, seed=i, rpy_deg=rpy[i] if rpy.ndim == 2 else rpy, **kw)
        W[:, i], F[:, i] = s.gyro, s.accel
    return W, F


def batch(n: int, duration: float, rpy, **kw):
    r = simulate_runs(duration, range(n), rpy_deg=rpy, **kw)
    return r.gyro, r.accel


def normal_rate(repeat: int) -> float:
    """float64 standard normals per second, filled into a reused (4096, 3) buffer."""
    g = np.random.default_rng(0)
    buf = np.empty((4096, 3))
    t, _ = best(lambda: [g.standard_normal(out=buf) for _ in range(200)], repeat)
    return 200 * buf.size / t


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="repetitions, best kept (default 3)")
    args = ap.parse_args()
    rate = normal_rate(args.repeat)
    print(f"simulation of n runs, 100 Hz, navigation grade, {os.cpu_count()} CPUs; numpy "
          f"standard_normal {rate / 1e6:.0f} M/s -> bound {rate / 6e6:.1f} M sample-runs/s")
    print(f"   {'base':<14}{'runs':>6}{'duration':>10}{'per-run loop':>15}{'batch':>11}"
          f"{'speed-up':>10}{'max |diff|':>12}   (M sample-runs/s)")
    rng = np.random.default_rng(1)
    fixed = dict(gyro_bias=np.full(3, 1e-7), accel_bias=np.full(3, 1e-3))
    for label, sway, per_run_truth, bias in (("static", "none", False, fixed),
                                             ("static random", "none", True, {}),
                                             ("car sway", "car", True, {})):
        for n, duration in ((1000, 10.0), (100, 60.0)):
            rpy = rng.uniform(-180.0, 180.0, (n, 3)) if per_run_truth else np.zeros(3)
            kw = dict(sway=sway, **bias)
            reps = args.repeat if sway == "none" else 1
            t_loop, (W0, F0) = best(lambda: loop(n, duration, rpy, **kw), reps)
            t_batch, (W1, F1) = best(lambda: batch(n, duration, rpy, **kw), args.repeat)
            diff = max(np.max(np.abs(W1 - W0)), np.max(np.abs(F1 - F0)))
            sr = n * duration * 100.0
            print(f"   {label:<14}{n:>6}{duration:>9g}s{sr / t_loop / 1e6:>15.2f}"
                  f"{sr / t_batch / 1e6:>11.2f}{t_loop / t_batch:>9.1f}x{diff:>12.1e}")


if __name__ == "__main__":
    main()
