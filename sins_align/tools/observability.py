"""Observability of in-motion alignment with a velocity reference (seed 001's PWCS analysis).

Usage::

    python -m sins_align.observability --scenario {static,forward,turn} [--window S]
        [--velocity-noise M/S] [--level-std DEG] [--heading-std DEG] [--grade NAME]
        [--lever-states] [--json OUT] [--plot OUT.png] [--force] [--quiet]
    python -m sins_align.observability BAG --latitude DEG --grade NAME --velocity-topic TOPIC
        [--topic IMU] [--velocity-type T] [--velocity-frame F] [--navsat-topic T]
        (--latitude may be left out with --navsat-topic: the first fix gives it)
        [--lever-arm X Y Z] [--report S] ... (the same analysis options)

A scenario is one of seed 001's manoeuvres (:func:`sins_align.analysis.observability.scenario`:
800 s static; 100 s still, 1 m/s^2 forward for 10 s, then North at 10 m/s; the same then a
90 deg left turn at 2 deg/s, West, and a stop), simulated without sensor errors: the analysis
uses its exact specific force, rates and attitude. A BAG (rosbag2 or ROS 1) needs a
sensor_msgs/Imu topic and a velocity reference; the attitude that rotates the specific force
into ENU is the in-motion estimator's, from a replay of the bag
(:func:`sins_align.tools.replay.replay`), so it is only as good as that alignment.

The run is cut into pieces of ``--window`` s (also at the phase boundaries); the stripped
observability matrix grows piece by piece (:mod:`sins_align.analysis.observability`). The
table has one row per phase (a scenario) or per ``--report`` s (a bag): the analysis of
everything up to the row's end time: numerical rank of the SOM and the TOM, the effective
rank (singular values above the floor), the singular values, and per state its verdict,
its unresolved fraction (the posterior/prior std a perfect filter reaches) and its degree.

Outputs appear only when complete (``--json``, ``--plot``; an existing path is an error
unless ``--force``); bad input is one line on stderr and exit status 2.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from sins_align.analysis.observability import (DEGREE_WEAK, LEVER_STATES, RANK_RTOL, SCENARIOS,
                                               STATES, SV_FLOOR, UNRESOLVED_OBSERVABLE,
                                               UNRESOLVED_UNOBSERVABLE, Scales, analyze,
                                               coupling_groups, pieces_from_series,
                                               pieces_from_trajectory, scenario, verdict)
from sins_align.core.rotation import dcm_from_rpy, so3_exp
from sins_align.core.specs import DEG, DPH, UG, grade_specs
from sins_align.io.bagio import (AtomicOutput, CliError, atomic_outputs, check_new_output,
                                 cli_main,
                                 finite_or_none, need_matplotlib, one_line, pyplot)

PROG = "observability"
#: the singular-value floor of a bag's analysis: sensor noise in the measured specific force
#: and rates survives the piece means as small spurious motion (a few 1e-4 in noise units
#: on a standing car)
BAG_SV_FLOOR = 1e-3
_ABBREV = {"observable": "obs", "weak": "weak", "coupled": "coup", "unobservable": "UNOB"}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG, description="Piece-wise constant system observability analysis (seed 001) "
        "of alignment with a velocity reference: SOM rank, singular values and the degree of "
        "observability of each error state against time.")
    p.add_argument("bag", nargs="?", metavar="BAG", help="rosbag2 bag (dir, .mcap, .db3) or "
                   "ROS 1 .bag with an Imu topic and a velocity reference")
    p.add_argument("--scenario", choices=SCENARIOS, help="one of seed 001's manoeuvres "
                   "instead of a bag")
    a = p.add_argument_group("analysis")
    a.add_argument("--window", type=float, default=1.0, metavar="S",
                   help="length of the constant pieces, s (default 1)")
    a.add_argument("--velocity-noise", type=float, default=0.02, metavar="M/S",
                   help="1-sigma of the velocity reference (default 0.02)")
    a.add_argument("--level-std", type=float, default=1.0, metavar="DEG",
                   help="prior std of roll/pitch error (default 1)")
    a.add_argument("--heading-std", type=float, default=10.0, metavar="DEG",
                   help="prior std of the heading error (default 10)")
    a.add_argument("--grade", help="bias priors and, on a bag, the estimator's specs: "
                   "navigation, tactical or consumer (required on a bag, as for replay; "
                   "scenarios default to seed 001's 100 ug accelerometer with a 10 deg/h "
                   "gyro)")
    a.add_argument("--lever-states", action="store_true", help="add the lever-arm errors")
    a.add_argument("--lever-std", type=float, default=0.1, metavar="M",
                   help="prior std of the lever-arm error (default 0.1)")
    a.add_argument("--floor", type=float, default=None, help="singular values below this "
                   f"(noise units) are unobservable directions (default {SV_FLOOR:g} for a "
                   f"scenario, {BAG_SV_FLOOR:g} for a bag: measured noise leaks into the "
                   "model)")
    b = p.add_argument_group("bag")
    b.add_argument("--topic", help="sensor_msgs/Imu topic (default: the only one)")
    b.add_argument("--latitude", type=float, metavar="DEG", help="latitude, deg (or the first "
                   "fix on --navsat-topic)")
    b.add_argument("--height", type=float, metavar="M", help="height, m")
    b.add_argument("--velocity-topic", metavar="TOPIC", help="velocity reference topic")
    b.add_argument("--velocity-type", help="twist_with_covariance, twist or odometry")
    b.add_argument("--velocity-frame", help="enu or ned")
    b.add_argument("--navsat-topic", metavar="TOPIC", help="sensor_msgs/NavSatFix topic")
    b.add_argument("--lever-arm", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="IMU to antenna lever arm in the IMU frame, m")
    b.add_argument("--report", type=float, default=10.0, metavar="S",
                   help="a table row every S s of a bag (default 10)")
    p.add_argument("--json", metavar="OUT", help="write the results as JSON")
    p.add_argument("--plot", metavar="OUT.png", help="plot the degree and unresolved "
                   "fraction of each state against time (matplotlib)")
    p.add_argument("--force", action="store_true", help="replace existing outputs")
    p.add_argument("--quiet", action="store_true", help="no table on stdout")
    return p


def _positive(name: str, x: float):
    if not (math.isfinite(x) and x > 0):
        raise CliError(f"--{name} must be a finite number > 0, got {x}")


def scales_from_args(args) -> Scales:
    for name in ("window", "velocity_noise", "level_std", "heading_std", "lever_std",
                 "report"):
        _positive(name.replace("_", "-"), getattr(args, name))
    if args.floor is None:
        args.floor = SV_FLOOR if args.scenario else BAG_SV_FLOOR
    if not (math.isfinite(args.floor) and args.floor >= 0):
        raise CliError(f"--floor must be a finite number >= 0, got {args.floor}")
    kw = dict(level=args.level_std * DEG, heading=args.heading_std * DEG,
              velocity=args.velocity_noise, velocity_noise=args.velocity_noise,
              lever=args.lever_std)
    if args.grade is None:
        # seed 001's accelerometer bias (its figure 3: 9.8e-4 m/s^2) with the MEMS gyro of
        # seed 003 (10 deg/h)
        return Scales(gyro_bias=10.0 * DPH, accel_bias=100.0 * UG, **kw)
    try:
        return Scales.from_specs(grade_specs(args.grade), **kw)
    except ValueError as e:
        raise CliError(one_line(e)) from None


# ----------------------------------------------------------------------------- inputs
def body_track(t, gyro, C_end) -> np.ndarray:
    """(N, 3, 3) C_b^n at each sample: ``C_end`` at the last one, the others from the gyro's
    rotation between them (each sample's rate over the interval before it)."""
    dt = np.diff(t, prepend=t[0])
    steps = so3_exp(gyro * dt[:, None])
    out = np.empty((len(t), 3, 3))
    R = np.eye(3)
    for k in range(len(t)):          # body k -> body 0
        R = R @ steps[k]
        out[k] = R
    return np.einsum("ij,kjl->kil", C_end @ out[-1].T, out)


def scenario_pieces(name: str, window: float, lever_states: bool):
    """Seed 001's manoeuvre ``name`` simulated without sensor errors: (pieces, phases)."""
    from sins_align.sim.trajectory import simulate_trajectory
    traj, phases = scenario(name)
    result = simulate_trajectory(traj, 100.0, None, gnss_rate=10.0)
    pieces = pieces_from_trajectory(result, window, lever_states=lever_states,
                                    breaks=[t for _, t in phases])
    return pieces, phases, {"scenario": name, "latitude_deg": traj.lat_deg,
                            "duration_s": traj.duration}


def bag_pieces(args, window: float, lever_states: bool):
    """The pieces of a bag: its Imu samples, its velocity reference and the in-motion
    estimator's attitude (a replay of the bag). Raises CliError on bad input."""
    from sins_align.io.bagio import open_reader, read_message_chunks
    from sins_align.io.velocity import Refused, from_navsat, velocity_from_message
    from sins_align.tools import replay as rp
    if not Path(args.bag).exists():
        raise CliError(f"bag {args.bag} does not exist")
    if args.velocity_topic is None:
        raise CliError("a bag needs --velocity-topic (the velocity reference)")
    if args.latitude is not None and not math.isfinite(args.latitude):
        raise CliError("--latitude must be a finite number")
    if args.latitude is None and args.navsat_topic is None:
        raise CliError("a bag needs --latitude DEG, or --navsat-topic TOPIC to take it from "
                       "the first fix")
    values: dict[str, Any] = {"latitude": math.nan if args.latitude is None else args.latitude,
                              "velocity_topic": args.velocity_topic}
    for flag in ("height", "velocity_type", "velocity_frame", "navsat_topic"):
        v = getattr(args, flag)
        if v is not None:
            values[flag] = v
    if args.grade is not None:
        values["grade"] = args.grade
    if args.lever_arm is not None:
        if not all(math.isfinite(x) for x in args.lever_arm):
            raise CliError("--lever-arm must be finite numbers")
        values["lever_arm"] = [float(x) for x in args.lever_arm]
    config = rp.config_or_error(values)
    reference = rp.reference_or_error(values)
    # the estimator's attitude over the bag (10 Hz rows: t since the first sample, rpy deg)
    _, session = rp.replay(args.bag, config, topic=args.topic, keep_plot=True,
                           progress=False, reference=reference)
    rows = np.array(session.series.rows, dtype=float).reshape(-1, 11)
    reader = open_reader(args.bag)
    try:
        topic, conns = rp.select_imu_connections(reader, args.topic, args.bag)
        stamps, gyro, accel = [], [], []
        for chunk in read_message_chunks(reader, conns, args.bag, rp.READ_CHUNK):
            for msg in rp.imu_messages(reader, chunk, None, args.bag):
                st = msg.header.stamp
                stamps.append(st.sec + 1e-9 * st.nanosec)
                w, f = msg.angular_velocity, msg.linear_acceleration
                gyro.append((w.x, w.y, w.z))
                accel.append((f.x, f.y, f.z))
        refs = rp.read_references(reader, reference, args.bag)
    finally:
        reader.close()
    t = np.array(stamps)
    gyro, accel = np.array(gyro, dtype=float), np.array(accel, dtype=float)
    keep = np.isfinite(t) & np.all(np.isfinite(gyro), 1) & np.all(np.isfinite(accel), 1)
    t, gyro, accel = t[keep], gyro[keep], accel[keep]
    order = np.argsort(t, kind="stable")
    t, gyro, accel = t[order], gyro[order], accel[order]
    uniq = np.concatenate([[True], np.diff(t) > 0])
    t, gyro, accel = t[uniq], gyro[uniq], accel[uniq]
    if len(t) < 2:
        raise CliError(f"topic {topic} in {args.bag} has fewer than 2 usable samples")
    vt, vv = [], []
    for _, kind, msg in refs:
        if kind != "velocity":
            continue
        try:
            vel, _ = velocity_from_message(reference.type, msg, reference.frame,
                                           lambda s, ns: s + 1e-9 * ns)
        except Refused:
            continue
        vt.append(vel.stamp)
        vv.append(np.nan_to_num(vel.v_enu, nan=0.0))
    if len(vt) < 2:
        raise CliError(f"velocity topic {reference.topic} in {args.bag} has fewer than 2 "
                       f"usable messages")
    vt, vv = np.array(vt), np.array(vv)
    v = np.stack([np.interp(t, vt, vv[:, i]) for i in range(3)], -1)
    if len(rows) == 0:
        raise CliError(f"the estimator produced no attitude for {args.bag}")
    # the attitude: the estimator's final one (the best it knows), carried back through the
    # gyro (the estimator's own attitude early on is a bank of heading hypotheses whose best
    # one jumps, which the analysis would take for turns). The Earth's rotation of the
    # navigation frame over the bag is left out.
    C = body_track(t, gyro, dcm_from_rpy(rows[-1, 1:4] * DEG))
    lat, h = config.latitude_deg * DEG, config.height_m
    if math.isnan(lat):                    # (no --latitude: the first fix's, as the replay)
        fix = None
        for _, kind, msg in refs:
            if kind == "navsat":
                try:
                    fix = from_navsat(msg, lambda s, ns: s + 1e-9 * ns)
                    break
                except Refused:
                    continue
        if fix is None:
            raise CliError(f"no fix on {reference.navsat_topic} in {args.bag} to take the "
                           f"latitude from (give --latitude)")
        lat, h = fix.lat_deg * DEG, fix.height_m
    pieces = pieces_from_series(t - t[0], C, accel, gyro, v, lat, h, window,
                                lever_arm=config.lever_arm, lever_states=lever_states,
                                deadband=3.0)
    span = float(t[-1] - t[0])
    ends = list(np.arange(args.report, span, args.report)) + [span]
    phases = [(f"{e:.0f} s", float(e)) for e in ends]
    return pieces, phases, {"bag": str(args.bag), "topic": topic,
                            "velocity_topic": reference.topic,
                            "latitude_deg": lat / DEG, "duration_s": span}


# ----------------------------------------------------------------------------- results
def step_dict(step, names) -> dict[str, Any]:
    return {
        "t_s": step.t, "rank": step.rank, "effective_rank": step.effective_rank,
        "tom_rank": step.tom_rank, "states": len(names),
        "singular_values": step.singular_values.tolist(),
        "per_state": {n: {"verdict": verdict(u, d), "unresolved": float(u), "degree": float(d)}
                      for n, u, d in zip(names, step.unresolved, step.degree)},
        "coupled_groups": coupling_groups(step, names),
    }


def run_analysis(args) -> tuple[dict[str, Any], list, list]:
    scales = scales_from_args(args)
    if args.scenario:
        pieces, phases, source = scenario_pieces(args.scenario, args.window, args.lever_states)
    else:
        pieces, phases, source = bag_pieces(args, args.window, args.lever_states)
    if not pieces:
        raise CliError("nothing to analyse (no samples)")
    steps = analyze(pieces, scales, args.lever_states, floor=args.floor)
    names = STATES + (LEVER_STATES if args.lever_states else ())
    rows = []
    start = 0.0
    for label, end in phases:
        done = [s for s in steps if s.t <= end + 1e-6]
        if not done:
            continue
        rows.append({"phase": label, "t_start_s": start, **step_dict(done[-1], names)})
        start = end
    out = {
        "source": source,
        "states": list(names),
        "settings": {
            "window_s": args.window, "velocity_noise_mps": scales.velocity_noise,
            "prior_std": dict(zip(names, scales.vector(args.lever_states).tolist())),
            "rank_rtol": RANK_RTOL, "sv_floor": args.floor,
            "unresolved_observable": UNRESOLVED_OBSERVABLE,
            "unresolved_unobservable": UNRESOLVED_UNOBSERVABLE, "degree_weak": DEGREE_WEAK,
        },
        "segments": rows,
        "timeline": {
            "t_s": [s.t for s in steps],
            "rank": [s.rank for s in steps],
            "effective_rank": [s.effective_rank for s in steps],
            "degree": {n: [float(s.degree[i]) for s in steps] for i, n in enumerate(names)},
            "unresolved": {n: [float(s.unresolved[i]) for s in steps]
                           for i, n in enumerate(names)},
        },
    }
    return finite_or_none(out), steps, list(names)


def format_table(res: dict[str, Any]) -> str:
    names = res["states"]
    src = res["source"]
    head = (f"scenario {src['scenario']}" if "scenario" in src else f"bag {src['bag']}")
    lines = [f"{head}: {len(names)} states, pieces of {res['settings']['window_s']:g} s, "
             f"velocity noise {res['settings']['velocity_noise_mps']:g} m/s",
             "", f"{'segment':<14} {'t_end':>7} {'rank':>5} {'eff':>4} {'TOM':>4}  "
             "singular values (noise units, descending)"]
    for r in res["segments"]:
        sv = " ".join(f"{x:.2g}" for x in r["singular_values"])
        lines.append(f"{r['phase']:<14} {r['t_s']:7.1f} {r['rank']:>2}/{r['states']:<2} "
                     f"{r['effective_rank']:>4} {r['tom_rank']:>4}  {sv}")
    lines += ["", "per state: verdict, unresolved fraction of the prior std / degree"]
    w = 17
    for i, block in enumerate((names[:6], names[6:12], names[12:])):
        if not block:
            continue
        lines.append(f"{'segment' if i == 0 else '':<14} " + " ".join(f"{n:>{w}}" for n in block))
        for r in res["segments"]:
            cells = []
            for n in block:
                s = r["per_state"][n]
                deg = "-" if s["verdict"] == "unobservable" else f"{s['degree']:.2g}"
                cells.append(f"{_ABBREV[s['verdict']]} {s['unresolved']:.2g}/{deg}")
            lines.append(f"{r['phase']:<14} " + " ".join(f"{c:>{w}}" for c in cells))
    lines += ["", "coupled (seen only in combination):"]
    for r in res["segments"]:
        groups = "; ".join("{" + ", ".join(g) + "}" for g in r["coupled_groups"]) or "none"
        lines.append(f"  {r['phase']:<14} {groups}")
    return "\n".join(lines)


def write_plot(path: Path, res: dict[str, Any]):
    plt = pyplot()
    tl = res["timeline"]
    t = np.array(tl["t_s"])
    names = res["states"]
    fig, axes = plt.subplots(3, 1, figsize=(10, 10), sharex=True)
    groups = [("attitude", [n for n in names if n.startswith("phi")]),
              ("gyro bias", [n for n in names if n.startswith("bg")]),
              ("accel bias", [n for n in names if n.startswith("ba")]),
              ("lever arm", [n for n in names if n.startswith("lever")])]
    styles = ["-", "--", ":"]
    colors = {"attitude": "C0", "gyro bias": "C1", "accel bias": "C2", "lever arm": "C3"}
    for label, ns in groups:
        for i, n in enumerate(ns):
            d = np.array(tl["degree"][n], dtype=float)
            u = np.array(tl["unresolved"][n], dtype=float)
            # the degree of an unobservable state's small observable part is not drawn
            d = np.where((d > 0) & (u < UNRESOLVED_UNOBSERVABLE), d, np.nan)
            axes[0].semilogy(t, d, styles[i % 3], color=colors[label],
                             label=n)
            axes[1].plot(t, tl["unresolved"][n], styles[i % 3], color=colors[label], label=n)
    axes[0].set_ylabel("degree (noise units)")
    axes[0].legend(ncol=5, fontsize=7)
    axes[1].set_ylabel("unresolved fraction of prior std")
    axes[1].set_ylim(-0.02, 1.05)
    axes[2].step(t, tl["rank"], where="post", label="SOM rank")
    axes[2].step(t, tl["effective_rank"], where="post", label="effective rank")
    axes[2].set_ylabel("rank")
    axes[2].set_xlabel("t (s)")
    axes[2].legend()
    for r in res["segments"]:
        for ax in axes:
            ax.axvline(r["t_s"], color="0.8", lw=0.5)
    src = res["source"]
    fig.suptitle(f"observability: {src.get('scenario') or src.get('bag')}")
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)


def run(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if (args.bag is None) == (args.scenario is None):
        raise CliError("give either a BAG or --scenario NAME")
    if args.plot:
        need_matplotlib()
    outs = {}
    for what, p in (("json", args.json), ("plot", args.plot)):
        if p:
            outs[what] = check_new_output(p, f"--{what}", force=args.force)
    if len({str(p.resolve()) for p in outs.values()}) != len(outs):
        raise CliError("the output paths must differ")
    if args.bag and any(p.resolve() == Path(args.bag).resolve() for p in outs.values()):
        raise CliError("an output path is the input bag")
    try:
        res, _, _ = run_analysis(args)
    except ValueError as e:
        raise CliError(one_line(e)) from None
    with atomic_outputs({w: AtomicOutput(p, force=args.force)
                         for w, p in outs.items()}) as atomic:
        if "json" in atomic:
            atomic["json"].tmp.write_text(json.dumps(res, indent=1, allow_nan=False) + "\n")
        if "plot" in atomic:
            write_plot(atomic["plot"].tmp, res)
    if not args.quiet:
        print(format_table(res))
        for what, p in outs.items():
            print(f"  wrote {what} {p}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return cli_main(PROG, run, argv)


if __name__ == "__main__":
    sys.exit(main())
