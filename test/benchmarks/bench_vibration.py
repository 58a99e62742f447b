"""In-motion honesty under a soft-mounted IMU's tone (README, Limitations: an IMU vibrating at
3-10 Hz with the latency and lever arm estimated).

The ``car_city`` scenarios of :mod:`bench_in_motion` with one tone per axis added to the
IMU's samples (:class:`~sins_align.sim.trajectory.Vibration` with ``band=(f, f)`` and
``tones=1``: the truth and the GNSS do not vibrate) and the node's defaults for the
velocity reference (``lever_arm_std`` 1 m, ``velocity_latency_std`` 0.1 s), fed in the
benchmark's blocks. Each line: the share of the published instants with an attitude error
beyond 3 sigma on any ENU axis, that share after the flag first rose, the instants flagged
aligned while beyond, the largest |error| / sigma per axis, the final error and std (deg).

    python test/benchmarks/bench_vibration.py             # the README's matrix, ~4 min
    python test/benchmarks/bench_vibration.py --tones "5,1,0.5" --seeds 2

``--tones``: ``;``-separated ``f,accel_rms,gyro_rms`` (Hz, m/s^2, deg/s RMS per axis);
``0,0,0`` is the run without vibration (a tone of zero amplitude). The script measures
the sins_align beside it.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_in_motion as b  # noqa: E402
from sins_align.core.rotation import attitude_error  # noqa: E402
from sins_align.core.specs import DEG  # noqa: E402
from sins_align.estimators.in_motion import MotionAligner  # noqa: E402
from sins_align.sim.trajectory import Vibration  # noqa: E402

TONES = "5,1,0.5;7,1,0.5;10,1,0.5;20,2,1;3,1,0;5,1,0;8,1,0;0,0,0"
NODE_DEFAULTS = {"lever_arm_std": 1.0, "velocity_latency_std": 0.1}


def run(name: str, f: float, a: float, g: float, seed: int) -> str:
    sc = next(s for s in b.SCENARIOS if s.name == name)
    vib = Vibration(accel_rms=a, gyro_rms=g * DEG, band=(max(f, 1.0),) * 2, tones=1)
    sc = dataclasses.replace(sc, cfg={**sc.cfg, **NODE_DEFAULTS},
                             sim={**sc.sim, "vibration": vib})
    r, cfg = b.setup(sc, seed)
    al = MotionAligner(cfg)
    for tg, vg in zip(r.gnss_t, r.gnss_v):
        al.add_velocity(tg, vg)
    n = len(r.gyro)
    rows = []
    for k in range(0, n, b.BLOCK):
        e = min(k + b.BLOCK, n)
        al.update(r.t[k + 1:e + 1], r.gyro[k:e], r.accel[k:e])
        if al.initialized:
            E = attitude_error(r.C[e], al.dcm) / DEG
            S = np.sqrt(np.diag(al.covariance)) / DEG
            rows.append((r.t[e], *E, *S, al.aligned))
    R = np.array(rows, float)
    z = np.abs(R[:, 1:4] / R[:, 4:7])
    over = (z > 3.0).any(axis=1)
    first = np.flatnonzero(R[:, 7] > 0)
    late = 100.0 * over[first[0]:].mean() if len(first) else float("nan")
    wrong = int((over & (R[:, 7] > 0)).sum())
    return (f"{name} {f:4.1f} Hz a {a} g {g} seed {seed}: beyond 3 sigma "
            f"{100 * over.mean():5.1f} % (after aligned {late:4.1f} %), aligned while beyond "
            f"{wrong:4d}, max z {z.max(axis=0).round(1)}, final err {R[-1, 1:4].round(3)} std "
            f"{R[-1, 4:7].round(3)}, aligned at {al.time_to_aligned}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenarios", default="car_city/air,car_city/ground")
    ap.add_argument("--tones", default=TONES)
    ap.add_argument("--seeds", default="0,1,2")
    args = ap.parse_args(argv)
    print("python test/benchmarks/bench_vibration.py " + " ".join(
        f"--{k} '{v}'" for k, v in vars(args).items()), flush=True)
    for name in args.scenarios.split(","):
        for spec in args.tones.split(";"):
            f, a, g = (float(x) for x in spec.split(","))
            for seed in (int(s) for s in args.seeds.split(",")):
                print(run(name, f, a, g, seed), flush=True)


if __name__ == "__main__":
    main()
