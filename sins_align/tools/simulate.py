"""Write a bag of what imu_sim_node publishes, directly (no DDS), fast.

Usage::

    python -m sins_align.tools.simulate [--latitude DEG] [--height M] [--rpy R P Y]
        [--grade NAME] [--gyro-bias DEG/H] [--gyro-arw DEG/SQRT(H)] [--accel-bias UG]
        [--accel-vrw UG/SQRT(HZ)]
        [--sway none|car|ship] [--sway-amplitude K] [--rate HZ] [--duration S] [--seed N]
        [--t0 S] [--storage mcap|sqlite3] [--compression none|zstd] [--force] OUT

The bag (rosbag2, a directory OUT/ with metadata.yaml) holds

- ``/imu/data_raw`` — ``sensor_msgs/Imu``: angular rate (rad/s) and specific force (m/s^2)
  of the simulated IMU in its own axes (``frame_id`` imu_link), REP-145 covariances from the
  specs, orientation not provided (covariance[0] = -1);
- ``/imu_sim/truth`` — ``geometry_msgs/QuaternionStamped``: quaternion of the true C_b^n
  (IMU frame in ENU), same header (stamp and frame_id) as the IMU sample.

Message fields come from :mod:`sins_align.io.imu_fields`, as in imu_sim_node; samples from
:class:`sins_align.sim.simulator.ImuSimulator` (sample k stamped t0 + (k+1)/rate). Generated in
blocks, so memory does not grow with the duration. The simulation settings are stored in the bag's
``custom_data`` (keys ``sins_align.*``). The bag appears only when complete (Ctrl-C, SIGTERM or
SIGHUP leave nothing behind); an existing OUT is refused unless ``--force`` (then a previous bag is
replaced once the new one is complete). OUT must not end in ``.bag`` (the ROS 1 suffix: replay would
take the directory for a ROS 1 bag file).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Sequence

from sins_align.io.bagio import (AtomicOutput, CliError, COMPRESSIONS, Messages, STORAGES,
                    check_bag_dir_name, check_new_output, check_storage, cli_main, open_writer,
                    qos_profile)
from sins_align.io.imu_fields import (IMU_FRAME, MAX_STAMP_S, RAW_TOPIC, TRUTH_TOPIC,
                                      imu_covariances, imu_fields, sample_stamps_ns, truth_fields)
from sins_align.core.specs import DPH, DPSH, GRADES, UG, UG_PSHZ, grade_specs

PROG = "simulate"
_BLOCK = 4096

#: --option -> (SensorSpecs field, unit factor to SI); units as params.py
SPEC_OPTIONS = {"gyro_bias": ("gyro_bias", DPH), "gyro_arw": ("gyro_arw", DPSH),
                "accel_bias": ("accel_bias", UG), "accel_vrw": ("accel_vrw", UG_PSHZ)}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG, description="Simulate a quasi-static IMU and write a rosbag2 bag of "
        "/imu/data_raw (sensor_msgs/Imu) and /imu_sim/truth (geometry_msgs/QuaternionStamped), "
        "as imu_sim_node would publish them.")
    p.add_argument("out", metavar="OUT", help="output bag directory (must not exist, nor end "
                   "in .bag)")
    p.add_argument("--latitude", type=float, default=34.0, help="latitude, deg (default 34)")
    p.add_argument("--height", type=float, default=0.0, help="height, m (default 0)")
    p.add_argument("--rpy", type=float, nargs=3, default=(0.0, 0.0, 0.0),
                   metavar=("ROLL", "PITCH", "YAW"),
                   help="true mean attitude, REP-103 deg in ENU (yaw 0 = x East, CCW)")
    p.add_argument("--grade", default="navigation", choices=sorted(GRADES),
                   help="sensor grade preset (default navigation)")
    p.add_argument("--gyro-bias", type=float, help="gyro bias 1-sigma, deg/h (overrides grade)")
    p.add_argument("--gyro-arw", type=float, help="gyro ARW, deg/sqrt(h)")
    p.add_argument("--accel-bias", type=float, help="accelerometer bias 1-sigma, micro-g")
    p.add_argument("--accel-vrw", type=float, help="accelerometer noise, micro-g/sqrt(Hz)")
    p.add_argument("--sway", default="none", choices=("none", "car", "ship"),
                   help="base motion preset (default none)")
    p.add_argument("--sway-amplitude", type=float, default=1.0,
                   help="factor on the sway amplitudes (default 1)")
    p.add_argument("--rate", type=float, default=100.0, help="sample rate, Hz (default 100)")
    p.add_argument("--duration", type=float, default=150.0, help="duration, s (default 150)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--t0", type=float, default=0.0,
                   help="time origin, s; the first sample is stamped t0 + 1/rate (default 0)")
    p.add_argument("--frame-id", default=IMU_FRAME, help=f"IMU frame_id (default {IMU_FRAME})")
    p.add_argument("--storage", default="mcap", choices=STORAGES, help="default mcap")
    p.add_argument("--compression", default="none", choices=COMPRESSIONS,
                   help="zstd: mcap chunk compression / sqlite3 per-message (default none)")
    p.add_argument("--force", action="store_true",
                   help="replace OUT if it is a previous bag (once the new one is complete)")
    return p


def specs_from_args(args, grade: str | None = None):
    """Grade preset (``grade`` or ``args.grade``) with the per-sensor overrides given as
    --gyro-bias etc. in params.py units."""
    specs = grade_specs(args.grade if grade is None else grade)
    over = {}
    for opt, (fld, unit) in SPEC_OPTIONS.items():
        v = getattr(args, opt)
        if v is not None:
            if not (math.isfinite(v) and v >= 0.0):
                raise CliError(f"--{opt.replace('_', '-')} must be finite and >= 0, got {v}")
            over[fld] = v * unit
    return specs.with_(**over) if over else specs


def _check_args(args):
    for name, ok in (("--latitude", abs(args.latitude) <= 90.0),
                     ("--height", True),
                     ("--rate", args.rate > 0.0), ("--duration", args.duration > 0.0),
                     ("--sway-amplitude", args.sway_amplitude >= 0.0)):
        v = getattr(args, name[2:].replace("-", "_"))
        if not math.isfinite(v):
            raise CliError(f"{name} must be a finite number, got {v}")
        if not ok:
            raise CliError(f"{name} out of range: {v}")
    if not all(math.isfinite(a) for a in args.rpy):
        raise CliError(f"--rpy must be finite angles, got {' '.join(map(str, args.rpy))}")
    # stamps are builtin_interfaces/Time: sec is an int32, and negative times are not stamps
    last = args.t0 + args.duration + 1.0 / args.rate
    if not (math.isfinite(args.t0) and args.t0 >= 0.0 and last < MAX_STAMP_S):
        raise CliError(f"--t0 must be >= 0 s and the last stamp (t0 + duration) below 2^31 s "
                       f"(a ROS stamp's seconds are int32), got --t0 {args.t0:.12g} with "
                       f"--duration {args.duration:.12g}")
    if int(math.floor(args.duration * args.rate + 1e-9)) < 1:
        raise CliError(f"--duration {args.duration} s is shorter than one sample")
    if args.seed < 0:
        raise CliError(f"--seed must be >= 0, got {args.seed}")
    if not args.frame_id:
        raise CliError("--frame-id must not be empty")


def write_sim_bag(out: Path, args, specs) -> int:
    """Simulate and write the bag at ``out`` (must not exist). Returns the sample count."""
    from sins_align.sim.simulator import ImuSimulator

    sim = ImuSimulator(rate=args.rate, lat_deg=args.latitude, height_m=args.height,
                       rpy_deg=args.rpy, specs=specs, sway=args.sway,
                       sway_amplitude=args.sway_amplitude, seed=args.seed, t0=args.t0)
    n_total = int(math.floor(args.duration * sim.rate + 1e-9))
    covs = imu_covariances(specs, sim.rate)
    msgs = Messages()
    writer = open_writer(out, args.storage, args.compression)
    try:
        c_imu = writer.add_connection("/" + RAW_TOPIC, Messages.IMU, typestore=msgs.store,
                                      offered_qos_profiles=[qos_profile(reliable=False, depth=5)])
        c_truth = writer.add_connection("/" + TRUTH_TOPIC, Messages.QUATERNION_STAMPED,
                                        typestore=msgs.store,
                                        offered_qos_profiles=[qos_profile()])
        for key, val in (("latitude_deg", args.latitude), ("height_m", args.height),
                         ("rpy_deg", list(args.rpy)), ("grade", args.grade),
                         ("specs_si", [specs.gyro_bias, specs.gyro_arw, specs.accel_bias,
                                       specs.accel_vrw]),
                         ("sway", args.sway), ("sway_amplitude", args.sway_amplitude),
                         ("rate_hz", args.rate), ("seed", args.seed), ("t0_s", args.t0),
                         ("gyro_bias_body_rad_s", sim.gyro_bias.tolist()),
                         ("accel_bias_body_m_s2", sim.accel_bias.tolist())):
            writer.set_custom_data(f"sins_align.{key}",
                                   val if isinstance(val, str) else json.dumps(val))
        done = 0
        while done < n_total:
            n = min(_BLOCK, n_total - done)
            blk = sim.next_block(n)
            stamps = sample_stamps_ns(args.t0, sim.rate, done, n)
            for fi, ft in zip(imu_fields(stamps, blk.gyro, blk.accel, covs, args.frame_id),
                              truth_fields(stamps, blk.quat_true, args.frame_id)):
                ns = fi.stamp_ns
                writer.write(c_imu, ns, msgs.serialize(msgs.raw_imu(fi)))
                writer.write(c_truth, ns, msgs.serialize(msgs.truth(ft)))
            done += n
    except BaseException:
        writer.abort()
        raise
    writer.close()
    return n_total


def run(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    check_storage(args.storage, args.compression)
    _check_args(args)
    try:
        specs = specs_from_args(args)
    except ValueError as e:
        raise CliError(str(e)) from None
    out = check_new_output(check_bag_dir_name(args.out, "output"), "output", force=args.force,
                           is_dir=True)
    with AtomicOutput(out, is_dir=True, force=args.force) as tmp:
        try:
            n = write_sim_bag(tmp.tmp, args, specs)
        except ValueError as e:
            raise CliError(str(e)) from None
        tmp.commit()
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    print(f"wrote {out}: {n} samples, {n / args.rate:.2f} s at {args.rate:g} Hz, "
          f"{args.grade} grade, sway {args.sway}, {args.storage}"
          f"{'+zstd' if args.compression == 'zstd' else ''}, {size / 1e6:.2f} MB")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return cli_main(PROG, run, argv)


if __name__ == "__main__":
    sys.exit(main())
