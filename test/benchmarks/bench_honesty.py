"""Honesty of the published covariance across the disturbance matrix (a script, not a test).

Usage: python test/benchmarks/bench_honesty.py [--seeds N] [--cases PATTERN[,PATTERN...]]
                                                [--json OUT] [--jobs J]

Runs every case of :data:`sins_align.sim.honesty.CASES` (or those whose name matches a
shell-style PATTERN) for seeds 0..N-1 and prints, per case (worst or total over the seeds):

- max |err|/sigma per axis E N U (max over seeds; '-' where the axis is unobservable),
- %>3s: % of published states with some observable axis beyond 3 sigma (mean over seeds),
- v4s: states with |err| > 4 sigma + 0.01 deg (total),
- alW: states flagged aligned while some observable axis is beyond 3 sigma (total),
- t_al: first time aligned, s (worst seed; '-' = some seed never aligned), %al: % of states
  aligned (mean),
- final heading error / published std, deg (the seed with the largest |error|),
- stale: largest lag of the published state behind the stream, s (max over seeds),
- exp: expectations of the case not met (total over seeds),
- rejects by reason (total).

No ROS: the harness is numpy only, so no ROS environment variables are set. The script
benchmarks the sins_align beside it (its repository root goes first on sys.path).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from sins_align.sim.honesty import run_case, select_cases  # noqa: E402

_SHORT = {"specific_force_out_of_range": "sf_range", "rates_look_like_deg_per_s": "deg_s",
          "stamp_backwards": "backwards", "duplicate_stamp": "dup", "time_jump": "jump",
          "rate_too_high": "rate_hi", "dt_too_small": "dt_small", "nonfinite": "nan",
          "gravity_removed": "no_g", "undecodable": "undec"}


def _job(args):
    name, seed = args
    return run_case(name, seed)


def _fmt_ratio(x) -> str:
    if x is None:
        return "    -"
    return f"{x:5.2f}" if x < 100 else f"{x:5.0f}"


def _row(name: str, rs: list[dict]) -> str:
    ratio = []
    for i in range(3):
        v = [r["max_ratio"][i] for r in rs if r["max_ratio"][i] is not None]
        ratio.append(max(v) if v else None)
    o3 = 100.0 * sum(r["frac_over_3sigma"] for r in rs) / len(rs)
    v4 = sum(r["n_viol_4sigma"] for r in rs)
    aw = sum(r["aligned_wrong"] for r in rs)
    tal = [r["t_aligned_first"] for r in rs]
    tal_s = "-" if any(t is None for t in tal) else f"{max(tal):.0f}"
    pal = 100.0 * sum(r["frac_aligned"] for r in rs) / len(rs)
    worst = max(rs, key=lambda r: abs(r["final_err_deg"][2] or 0.0))
    h_err, h_std = worst["final_err_deg"][2], worst["final_std_deg"][2]
    head = "-" if h_err is None else f"{h_err:8.3f}/{h_std:<7.3f}"
    exp = sum(len(r["failed_expectations"]) for r in rs)
    stale = max(r["max_stale_s"] for r in rs)
    rej: dict[str, int] = {}
    for r in rs:
        for k, v in r["rejected"].items():
            rej[k] = rej.get(k, 0) + v
    rej_s = " ".join(f"{_SHORT.get(k, k)}:{v}" for k, v in sorted(rej.items())) or "-"
    return (f"{name:<27} {_fmt_ratio(ratio[0])} {_fmt_ratio(ratio[1])} {_fmt_ratio(ratio[2])}"
            f" {o3:5.1f} {v4:5d} {aw:5d} {tal_s:>5} {pal:5.1f} {head:>16} {stale:6.1f}"
            f" {exp:3d}  {rej_s}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1, help="seeds 0..N-1 per case (default 1)")
    ap.add_argument("--cases", default=None,
                    help="comma-separated shell patterns of case names (default: all)")
    ap.add_argument("--json", default=None, help="write every run's metrics to this file")
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                    help="worker processes (default min(2, cores))")
    a = ap.parse_args(argv)
    cases = select_cases(a.cases)
    if not cases or a.seeds < 1:
        print("no cases selected" if not cases else "--seeds must be >= 1", file=sys.stderr)
        return 2
    jobs = [(c.name, s) for c in cases for s in range(a.seeds)]
    t0 = time.perf_counter()
    if a.jobs > 1:
        with ProcessPoolExecutor(max_workers=a.jobs) as ex:
            results = list(ex.map(_job, jobs))
    else:
        results = [_job(j) for j in jobs]
    elapsed = time.perf_counter() - t0

    by_case: dict[str, list[dict]] = {}
    for r in results:
        by_case.setdefault(r["name"], []).append(r)
    print(f"honesty matrix: {len(cases)} cases x {a.seeds} seed(s), 34 deg N, 100 Hz, "
          f"navigation grade unless named")
    print(f"{'case':<27} {'max |err|/sigma':^17} {'%>3s':>5} {'v4s':>5} {'alW':>5} "
          f"{'t_al':>5} {'%al':>5} {'final hdg err/std':>16} {'stale':>6} {'exp':>3}  rejects")
    print(f"{'':<27} {'E':>5} {'N':>5} {'U':>5}")
    for name, rs in by_case.items():
        print(_row(name, rs))
    n_bad = sum(1 for rs in by_case.values()
                if any(r["n_viol_4sigma"] or r["aligned_wrong"] for r in rs))
    print(f"{n_bad} of {len(by_case)} cases with 4-sigma violations or aligned-while-wrong")
    cpu = sum(r["elapsed_s"] for r in results)
    print(f"elapsed {elapsed:.1f} s wall ({cpu:.1f} s in run_case, {a.jobs} job(s))")
    if a.json:
        Path(a.json).write_text(json.dumps({"seeds": a.seeds, "elapsed_s": elapsed,
                                            "runs": results}, indent=1))
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
