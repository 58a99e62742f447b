"""Honesty under the sensor errors a datasheet lists beside bias and noise (a script, not a test).

Usage: python test/benchmarks/bench_sensor_errors.py [--seeds N] [--quasi-static] [--in-motion]
           [--grades navigation,tactical] [--sways none,car] [--errors PATTERN[,PATTERN...]]
           [--blind]

Each error is given as a multiple of the grade's (or scenario's) biases, simulated and
configured alike unless ``--blind`` (the estimator is then told the specs without the
instability and the warm-up: a datasheet that leaves them out):

- ``bi<r>_tau<T>``: bias instability r x the biases (gyro and accelerometer), correlation T s;
- ``warm<r>_<T>``: warm-up r x the biases settling over T s;
- ``q_<g>_<a>``: increment quanta g rad and a m/s.

Quasi-static: :func:`sins_align.sim.honesty.run_case` (600 s, 34 deg N, the Aligner fed in
blocks of 100). In motion: ``bench_in_motion.setup`` (car_city/ground, seed003/+3+4+45) with
the node's defaults ``lever_arm_std`` 1.0 and ``velocity_latency_std`` 0.1, published every
0.1 s. Per case over seeds 0..N-1: % of published instants with some observable axis beyond
3 sigma (mean and worst seed), the largest |error|/sigma per axis E N U, instants flagged
aligned while beyond 3 sigma (summed), runs that ever aligned.
"""
from __future__ import annotations

import argparse
import dataclasses
import fnmatch
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from sins_align.core.rotation import attitude_error  # noqa: E402
from sins_align.core.specs import grade_specs  # noqa: E402
from sins_align.estimators.quasi_static import Aligner  # noqa: E402
from sins_align.sim.honesty import Case, run_case  # noqa: E402

ERRORS = ["none"] + [f"bi{r}_tau{t}" for r in ("0.3", "1") for t in (30, 300, 1000)] + [
    f"warm{r}_{t}" for r, t in (("1", 60), ("3", 60), ("3", 300), ("3", 600))] + [
    "q_2e-05_0.005", "q_1.33e-06_5.9e-05"]
IN_MOTION = ("car_city/ground", "seed003/+3+4+45")


def with_error(sp, name: str):
    """``sp`` with the error ``name`` (see the module docstring)."""
    if name == "none":
        return sp
    if name.startswith("bi"):
        r, t = name[2:].split("_tau")
        return sp.with_(gyro_bias_instability=float(r) * sp.gyro_bias,
                        accel_bias_instability=float(r) * sp.accel_bias,
                        bias_correlation_time=float(t))
    if name.startswith("warm"):
        r, t = name[4:].split("_")
        return sp.with_(gyro_warmup=float(r) * sp.gyro_bias,
                        accel_warmup=float(r) * sp.accel_bias, warmup_time=float(t))
    _, g, a = name.split("_")
    return sp.with_(gyro_quantization=float(g), accel_quantization=float(a))


def blind(sp):
    """What a datasheet without instability and warm-up tells the estimator."""
    return sp.with_(gyro_bias_instability=0.0, accel_bias_instability=0.0, gyro_warmup=0.0,
                    accel_warmup=0.0)


def quasi_static(grade: str, sway: str, err: str, seed: int, is_blind: bool):
    sp = with_error(grade_specs(grade), err)
    factory = ((lambda c: Aligner(c.with_(specs=blind(c.specs)))) if is_blind else Aligner)
    r = run_case(Case(err, 600.0, sway, specs=sp), seed=seed, aligner_factory=factory)
    z = [0.0 if x is None else x for x in r["max_ratio"]]
    return 100.0 * r["frac_over_3sigma"], z, r["aligned_wrong"], r["t_aligned_first"] is not None


def in_motion(name: str, err: str, seed: int, is_blind: bool):
    import bench_in_motion as b
    from sins_align.estimators.in_motion import MotionAligner

    sc = next(s for s in b.SCENARIOS if s.name == name)
    sp = with_error(sc.specs, err)
    r, cfg = b.setup(dataclasses.replace(sc, specs=sp), seed)
    cfg = dataclasses.replace(cfg, lever_arm_std=1.0, velocity_latency_std=0.1,
                              specs=blind(sp) if is_blind else sp)
    al = MotionAligner(cfg)
    for tg, vg in zip(r.gnss_t, r.gnss_v):
        al.add_velocity(tg, vg)
    n, zs, over, wrong = len(r.gyro), [], [], 0
    for k in range(0, n, b.BLOCK):
        e = min(k + b.BLOCK, n)
        al.update(r.t[k + 1:e + 1], r.gyro[k:e], r.accel[k:e])
        if al.initialized:
            z = np.abs(attitude_error(r.C[e], al.dcm)) / np.sqrt(np.diag(al.covariance))
            zs.append(z)
            over.append(bool(np.any(z > 3.0)))
            wrong += over[-1] and al.aligned
    return (100.0 * float(np.mean(over)), np.max(zs, axis=0).tolist(), wrong,
            al.time_to_aligned is not None)


def table(title: str, rows):
    print(title)
    print(f"{'case':44s} {'%>3s':>6s} {'worst':>6s} {'max |err|/sigma E N U':>22s} "
          f"{'alW':>5s} {'aligned':>7s}")
    for name, res in rows:
        pct = [x[0] for x in res]
        z = np.max([x[1] for x in res], axis=0)
        print(f"{name:44s} {np.mean(pct):6.1f} {max(pct):6.1f} "
              f"{z[0]:7.2f} {z[1]:6.2f} {z[2]:6.2f}   {sum(x[2] for x in res):5d} "
              f"{sum(x[3] for x in res):3d}/{len(res)}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--quasi-static", action="store_true")
    ap.add_argument("--in-motion", action="store_true")
    ap.add_argument("--grades", default="navigation,tactical")
    ap.add_argument("--sways", default="none,car")
    ap.add_argument("--errors", default="*", help="shell-style patterns over " + ",".join(ERRORS))
    ap.add_argument("--blind", action="store_true",
                    help="tell the estimator the specs without instability and warm-up")
    a = ap.parse_args()
    both = not (a.quasi_static or a.in_motion)
    errs = [e for e in ERRORS if any(fnmatch.fnmatchcase(e, p) for p in a.errors.split(","))]
    seeds = range(a.seeds)
    print("python test/benchmarks/bench_sensor_errors.py " + " ".join(sys.argv[1:]))
    wall = time.perf_counter()
    if a.quasi_static or both:
        rows = []
        for g in a.grades.split(","):
            for sw in a.sways.split(","):
                rows += [(f"{g}/{sw}/{e}", [quasi_static(g, sw, e, s, a.blind) for s in seeds])
                         for e in errs]
        table(f"quasi-static, 600 s, seeds 0-{a.seeds - 1}" + (", blind" if a.blind else ""),
              rows)
    if a.in_motion or both:
        rows = [(f"{sc}/{e}", [in_motion(sc, e, s, a.blind) for s in seeds])
                for sc in IN_MOTION for e in errs]
        table(f"in motion, node defaults, seeds 0-{a.seeds - 1}" + (", blind" if a.blind else ""),
              rows)
    print(f"elapsed {time.perf_counter() - wall:.0f} s")


if __name__ == "__main__":
    main()
