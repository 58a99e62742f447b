"""Core estimator throughput: IMU samples per second (a script, not a test).

Usage: python test/benchmarks/bench_core.py [--duration 600] [--runs 100] [--repeat 5]
       [--cold-runs 7] [--cold-only] [--one-only [--rate 100]]

A 100 Hz simulated navigation-grade data set (static, from [89, 89, 179] deg) through:
- the reference path: the straightforward per-sample filter (AlignmentFilter.run), and
  Aligner fed one sample at a time, as a ROS callback does;
- the fast path (constant model): AlignmentFilter.run_fast and Aligner.update with the whole
  array. 'cold' is the first run of a configuration (it builds the data-independent gain
  schedule), 'warm' a later run of the same configuration (next bag, next batch); best of
  --repeat runs (wall time; this 2-core machine is shared and its speed drifts by +-30 %);
- AlignmentFilter.run_fast vectorised over --runs runs with the default pipeline (per-run
  gains after the backtrack; the Monte Carlo target, one shared gain, is bench_montecarlo.py);
- cold in a fresh process (issue 14): the first Aligner.update(array) of 300 s of data in a new
  interpreter, in microseconds per sample (the package imports are not timed, everything the
  call itself does is: the gain schedule, lazy imports of numpy submodules, first calls);
  best and range of --cold-runs fresh processes. --cold-only prints this row alone.
- --one-only: the one-sample path alone, as align_node calls it (a float stamp, (3,) arrays),
  coarse pass (before the backtrack) and fine pass (after it, the backtrack's own cost
  included) separately, µs per sample, without and with the node's per-sample outputs
  (``orientation_values``); --duration s at --rate Hz, best of --repeat.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

import sins_align
from sins_align.estimators.quasi_static.schedule import SHARED_SCHEDULES
from sins_align.estimators.quasi_static.aligner import Aligner, AlignConfig, AlignmentFilter
from sins_align.core.rotation import dcm_from_rpy
from sins_align.sim.simulator import simulate
from sins_align.core.specs import DEG

TARGET_CORE = 1_000_000      # issue 5: samples/s, constant model
TARGET_ONE_US = 5.0          # issue 14: µs per sample of Aligner.update with one sample
TARGET_COLD_US = 1.0         # issue 14: us per sample, first call in a fresh process, 300 s
# the child: imports untimed, then one timed Aligner.update of the saved samples. The data come
# from an .npz (np.load), not from the simulator, so that nothing has warmed up numpy first.
COLD_CHILD = """
import sys, time
import numpy as np
from sins_align.estimators.quasi_static.aligner import Aligner, AlignConfig
d = np.load(sys.argv[1])
t, w, f = d["t"], d["gyro"], d["accel"]
al = Aligner(AlignConfig(latitude_deg=34.0, initial_rpy_deg=(89, 89, 179)))
t0 = time.perf_counter()
al.update(t, w, f)
print(time.perf_counter() - t0, al.aligned)
"""
ERR = dcm_from_rpy(np.array([89.0, 89.0, 179.0]) * DEG)


def rate_of(fn, n, repeat=1, before=None):
    """n / the best wall time of ``repeat`` calls of fn (``before()`` runs untimed first)."""
    best = float("inf")
    for _ in range(repeat):
        if before is not None:
            before()
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return n / best


def row(model, path, rate, target=""):
    print(f"{model:<14}{path:<34}{rate:>14,.0f}{target:>12}")


def cold_fresh_process(duration: float = 300.0, runs: int = 5) -> list[float]:
    """Seconds per sample of the first Aligner.update(array) in each of ``runs`` fresh
    interpreters (``duration`` s of 100 Hz navigation-grade data)."""
    s = simulate(duration, 100.0, 34.0, specs="navigation", seed=1)
    # the child imports the package this script imported (run from a temporary directory,
    # so that its own working directory cannot shadow it)
    root = os.path.dirname(os.path.dirname(os.path.abspath(sins_align.__file__)))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "imu.npz")
        np.savez(path, t=s.t, gyro=s.gyro, accel=s.accel)
        out = []
        for _ in range(runs):
            r = subprocess.run([sys.executable, "-c", COLD_CHILD, path], check=True,
                               capture_output=True, text=True, cwd=tmp, env=env)
            out.append(float(r.stdout.split()[0]) / len(s.t))
    return out


def cold_row(runs: int):
    us = [x * 1e6 for x in cold_fresh_process(300.0, runs)]
    print(f"{'constant':<14}{'update(array), 300 s, fresh process':<36}"
          f"{min(us):>8.2f} us/sample (range {min(us):.2f}-{max(us):.2f} over {runs})"
          f"   target <= {TARGET_COLD_US:.1f}")


def one_row(duration: float, rate: float, repeat: int):
    """µs per sample of Aligner.update with one sample as align_node calls it, coarse and
    fine pass apart, without and with the node's outputs after every sample."""
    s = simulate(duration, rate, 34.0, specs="navigation", seed=1)
    cfg = AlignConfig(latitude_deg=34.0, initial_rpy_deg=(89, 89, 179))
    t, w, f = s.t.tolist(), list(s.gyro), list(s.accel)
    n, kb = len(t), min(len(t), int(round(cfg.backtrack_time * rate)))
    for outputs in (False, True):
        best = [float("inf")] * 2
        for _ in range(repeat):
            al = Aligner(cfg)
            upd, out = al.update, al.orientation_values
            for i, (a, b) in enumerate(((0, kb), (kb, n))):
                t0 = time.perf_counter()
                for k in range(a, b):
                    upd(t[k], w[k], f[k])
                    if outputs:
                        out()
                best[i] = min(best[i], (time.perf_counter() - t0) / max(b - a, 1) * 1e6)
        what = "update + orientation_values" if outputs else "update"
        print(f"one sample per call, {rate:g} Hz, {duration:g} s, {what:<28} coarse "
              f"{best[0]:6.1f} us  fine {best[1]:6.1f} us  (target <= {TARGET_ONE_US:g} us)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=600.0, help="data length, s")
    ap.add_argument("--runs", type=int, default=100, help="Monte Carlo runs for the batch figure")
    ap.add_argument("--repeat", type=int, default=5,
                    help="fast-path rows: best of this many runs ('cold': cache cleared before "
                         "each)")
    ap.add_argument("--cold-runs", type=int, default=7,
                    help="fresh processes for the cold 300 s row")
    ap.add_argument("--cold-only", action="store_true", help="only the cold 300 s row")
    ap.add_argument("--one-only", action="store_true",
                    help="only the one-sample path (the node's), coarse and fine pass")
    ap.add_argument("--rate", type=float, default=100.0, help="--one-only: IMU rate, Hz")
    a = ap.parse_args(argv)
    if a.cold_only:
        cold_row(a.cold_runs)
        return
    if a.one_only:
        one_row(a.duration, a.rate, a.repeat)
        return
    s = simulate(a.duration, 100.0, 34.0, specs="navigation", seed=1)
    n = len(s.t)
    C0 = (s.C0 @ ERR.T)[None]
    print(f"core benchmark: {a.duration:.0f} s at 100 Hz = {n} samples, from [89, 89, 179] deg")
    print(f"{'model':<14}{'path':<34}{'samples/s':>14}{'target':>12}")
    tgt = f"{TARGET_CORE:,}"
    for model in ("constant", "conventional", "se3"):
        cfg = AlignConfig(latitude_deg=34.0, model=model, initial_rpy_deg=(89, 89, 179))

        def one_by_one():
            al = Aligner(cfg)
            for k in range(n):
                al.update(s.t[k], s.gyro[k], s.accel[k])
        r1 = rate_of(one_by_one, n, 2 if model == "constant" else 1)
        row(model, "Aligner, one sample per call", r1,
            f"{1e6 / r1:.1f} µs (<= {TARGET_ONE_US:g})" if model == "constant" else "")
        row(model, "AlignmentFilter.run (reference)",
            rate_of(lambda: AlignmentFilter(cfg, C0).run(0.01, s.gyro, s.accel), n))
        if model != "constant":
            continue
        R = a.repeat
        for temp in ("cold", "warm"):
            clear = SHARED_SCHEDULES.clear if temp == "cold" else None
            row(model, f"AlignmentFilter.run_fast ({temp})",
                rate_of(lambda: AlignmentFilter(cfg, C0).run_fast(0.01, s.gyro, s.accel), n,
                        R, clear), tgt)
        for temp in ("cold", "warm"):
            clear = SHARED_SCHEDULES.clear if temp == "cold" else None
            row(model, f"Aligner.update(array) ({temp})",
                rate_of(lambda: Aligner(cfg).update(s.t, s.gyro, s.accel), n, R, clear), tgt)
    m = a.runs
    sims = [simulate(min(a.duration, 300.0), 100.0, 34.0, specs="navigation", seed=10 + i)
            for i in range(m)]
    W = np.stack([x.gyro for x in sims], 1)
    F = np.stack([x.accel for x in sims], 1)
    C0s = np.stack([x.C0 @ ERR.T for x in sims])
    cfg = AlignConfig(latitude_deg=34.0)
    rate = rate_of(lambda: AlignmentFilter(cfg, C0s).run_fast(0.01, W, F), W.shape[0] * m)
    # the default pipeline: after the backtrack each run has its own measured R, so its own
    # gain; the Monte Carlo target is for one shared gain (bench_montecarlo.py)
    row("constant", f"run_fast x{m} runs, default pipeline", rate, "(sample-runs/s)")
    cold_row(a.cold_runs)


if __name__ == "__main__":
    main()
