"""Study ``feedback`` (seed 002): how the estimated errors are fed back into the
mechanization, on seed 003's UAV flight (the data of :mod:`sins_align.studies.seed003`).

Variants of our in-motion filter (:class:`~sins_align.estimators.in_motion.MotionAligner`,
everything else as shipped):

- ``full``: full reset after every update (the default);
- ``lqr``: seed 002's LQR-designed feedback (``MotionConfig(feedback="lqr")``, time constant
  5 s: :mod:`~sins_align.estimators.in_motion.feedback`);
- ``frac50``, ``frac20``: a constant fraction (50 %, 20 %) of the carried error estimate fed
  back after every update (``feedback="fraction"``).

Cases: ``guess_25``: start off by [3, 4, 25] deg with a 30 deg heading guess (one filter,
the feedback loop alone); ``unknown_95``: start off by [3, 4, 95] deg, heading unknown
(the bank of hypotheses, as shipped).

Metrics per variant over the runs (the published state after each 10 Hz update): heading
overshoot (per run, how far the yaw error swings past zero, opposite to its sign when it
comes within 8 deg for good, max over the runs, deg); settling time (|yaw error| <= 1 deg and
level <= 0.1 deg to the end, median); final error (``final_error_deg``, phi E/N/U); RMSE
after 100 s (roll, pitch, heading); honesty: % of instants with the error beyond 3 sigma
of the published covariance on some axis; CPU time.
"""
from __future__ import annotations

import time
from typing import Any, Sequence

import numpy as np

from sins_align.studies import seed003
from sins_align.studies.common import check_names, median_or_none, settle_time

__all__ = ["run", "summary_text", "write_plot", "VARIANTS", "CASES"]

VARIANTS = {"full": dict(feedback="full"), "lqr": dict(feedback="lqr"),
            "frac50": dict(feedback="fraction", feedback_fraction=0.5),
            "frac20": dict(feedback="fraction", feedback_fraction=0.2)}
#: case: (start error rpy deg, heading std told, deg)
CASES = {"guess_25": ((3.0, 4.0, 25.0), 30.0), "unknown_95": ((3.0, 4.0, 95.0), 180.0)}


def _overshoot(yaw: np.ndarray, band: float) -> np.ndarray:
    """Per run (columns of yaw (T, R), deg): max swing past zero once the error has entered
    the band for good (a bank of hypotheses may publish another hypothesis before), opposite
    to the sign the error had there (0 if it never stays in the band)."""
    out = np.zeros(yaw.shape[1])
    for r in range(yaw.shape[1]):
        y = yaw[:, r]
        outside = np.flatnonzero(~(np.abs(np.nan_to_num(y, nan=1e9)) <= band))
        k = 0 if not len(outside) else outside[-1] + 1
        if k >= len(y):
            continue
        s = np.sign(y[k]) or 1.0
        out[r] = max(0.0, float(np.nanmax(-s * y[k:])))
    return out


def run(runs: int = 4, seed: int = 0, duration: float | None = None,
        variants: Sequence[str] = tuple(VARIANTS), cases: Sequence[str] = tuple(CASES),
        progress=None) -> dict[str, Any]:
    """Run the study. Returns a JSON-ready dict."""
    duration = float(seed003.SCENARIO["duration_s"] if duration is None else duration)
    if runs < 1 or not (2.0 <= duration <= 1000.0):
        raise ValueError("feedback: runs >= 1 and 2 s <= duration <= 1000 s")
    check_names("feedback", "variant", variants, VARIANTS)
    check_names("feedback", "case", cases, CASES)
    rms_after = min(seed003.SCENARIO["rms_after_s"], 0.5 * duration)
    t_wall = time.perf_counter()
    data = seed003.simulate_runs([seed + i for i in range(runs)], duration)
    gi = data["gnss_index"]
    out = {}
    for case in cases:
        err, std = CASES[case]
        res_v = {}
        for v in variants:
            if progress:
                progress(f"feedback {case}: {v}")
            times, C, P, cpu = seed003.run_filter("ours", data, err, config=VARIANTS[v],
                                                  heading_std_deg=std)
            m = seed003.metrics(times, data["C"][gi[1:]], C, P, rms_after, 0.1, 1.0)
            de = m.pop("_de")
            yaw = de[..., 2]
            lvl_ok = np.nan_to_num(np.max(np.abs(de[..., :2]), axis=-1), nan=1e9) <= 0.1
            hdg_ok = np.nan_to_num(np.abs(yaw), nan=1e9) <= 1.0
            settle = settle_time(lvl_ok & hdg_ok, times)
            ov = _overshoot(yaw, 8.0)
            step = 10
            with np.errstate(all="ignore"):
                rms_t = np.sqrt(np.nanmean(de[step - 1::step] ** 2, axis=1))
            res_v[v] = {**m, "overshoot_heading_deg": {"max": float(ov.max()),
                                                        "median": float(np.median(ov))},
                        "settling_time_s": median_or_none(settle),
                        "settled_runs": int(np.isfinite(settle).sum()),
                        "config": VARIANTS[v], "cpu_s": cpu, "cpu_s_per_run": cpu / runs,
                        "series": {"time_s": times[step - 1::step].tolist(),
                                   "rms_roll_pitch_yaw_deg": rms_t.tolist()}}
        out[case] = {"initial_error_rpy_deg": list(err), "heading_std_deg": std,
                     "filters": res_v}
    return {
        "study": "feedback",
        "schema_version": 1,
        "scenario": {**seed003.SCENARIO, "duration_s": duration, "rms_after_s": rms_after,
                     "runs": runs, "seed": seed},
        "axes": ["E", "N", "U"],
        "bands_deg": {"level": 0.1, "heading": 1.0, "overshoot_entry": 8.0},
        "cases": out,
        "wall_time_s": time.perf_counter() - t_wall,
    }


def summary_text(res: dict[str, Any]) -> str:
    s = res["scenario"]

    def t(x):
        return "   -  " if x is None else f"{x:6.1f}"

    lines = [f"feedback: {s['runs']} runs x {s['duration_s']:g} s of uav_seed003; settle: "
             f"yaw <= 1 deg and level <= 0.1 deg to the end (median); overshoot: max over "
             f"runs of the heading swing past zero; RMSE over t >= {s['rms_after_s']:g} s"]
    for case, c in res["cases"].items():
        lines.append(f"[{case}] start error {c['initial_error_rpy_deg']} deg, heading std "
                     f"told {c['heading_std_deg']:g} deg")
        lines.append(f"  {'variant':<8} {'overshoot':>9} {'settle':>6} {'final hdg':>9} "
                     f"{'RMSE r':>7} {'p':>6} {'hdg':>6} {'%>3sig':>7} {'cpu s':>6}")
        for v, r in c["filters"].items():
            q = r["rmse_after_deg"]
            fin = r["final_error_deg"]["rmse"][2]
            lines.append(f"  {v:<8} {r['overshoot_heading_deg']['max']:9.3f} "
                         f"{t(r['settling_time_s'])} {fin:9.3f} {q['roll']:7.3f} "
                         f"{q['pitch']:6.3f} {q['heading']:6.3f} "
                         f"{r['beyond_3sigma_pct']:7.2f} {r['cpu_s']:6.1f}")
    lines.append(f"wall time {res['wall_time_s']:.1f} s")
    return "\n".join(lines)


def write_plot(path, res: dict[str, Any]) -> None:
    """RMS error over the runs against time: rows = cases, columns = roll, pitch, heading."""
    seed003.write_plot(path, {**res, "bands_deg": {"heading": 1.0},
                              "scenario": {**res["scenario"]}})
