"""Write a bag of what imu_sim_node publishes, directly (no DDS), fast.

Usage::

    python -m sins_align.tools.simulate [--latitude DEG] [--height M] [--rpy R P Y]
        [--grade NAME] [--gyro-bias DEG/H] [--gyro-arw DEG/SQRT(H)] [--accel-bias UG]
        [--accel-vrw UG/SQRT(HZ)]
        [--sway none|car|ship] [--sway-amplitude K] [--rate HZ] [--duration S] [--seed N]
        [--t0 S] [--storage mcap|sqlite3] [--compression none|zstd] [--force] OUT
    python -m sins_align.tools.simulate --trajectory NAME [--gnss-rate HZ] [--gnss-noise M/S]
        [--gnss-latency S] [--lever-arm X Y Z] [--gnss-position-noise M]
        [--gnss-dropout START END]... [--no-gnss-vertical] [--gyro-scale PPM]
        [--accel-scale PPM] [--vibration ACCEL_RMS GYRO_RMS] [...] OUT

The bag (rosbag2, a directory OUT/ with metadata.yaml) holds

- ``/imu/data_raw`` — ``sensor_msgs/Imu``: angular rate (rad/s) and specific force (m/s^2)
  of the simulated IMU in its own axes (``frame_id`` imu_link), REP-145 covariances from the
  specs, orientation not provided (covariance[0] = -1);
- ``/imu_sim/truth`` — ``geometry_msgs/QuaternionStamped``: quaternion of the true C_b^n
  (IMU frame in ENU), same header (stamp and frame_id) as the IMU sample.

Message fields come from :mod:`sins_align.io.imu_fields`, as in imu_sim_node; samples from
:class:`sins_align.sim.simulator.ImuSimulator` (sample k stamped t0 + (k+1)/rate). Generated in
blocks, so memory does not grow with the duration.

With ``--trajectory NAME`` (a preset of :mod:`sins_align.sim.trajectory`: car_city,
car_straight, ship_under_way, car_with_turn, uav_seed003) the vehicle moves: the preset
starts at ``--latitude``/``--height`` and runs its own duration unless ``--duration`` is
given (longer continues its last commands). The bag then also holds, at ``--gnss-rate``
(fields from :mod:`sins_align.io.gnss_fields`, messages built by
:mod:`sins_align.io.reference_msgs`):

- ``/gnss/fix_velocity`` — ``geometry_msgs/TwistWithCovarianceStamped``: antenna velocity
  in ENU (lever arm ``--lever-arm``, body axes), noise ``--gnss-noise`` m/s per axis,
  covariance diag(sigma^2) (ublox_gps style);
- ``/gnss/fix`` — ``sensor_msgs/NavSatFix``: antenna position (noise
  ``--gnss-position-noise`` m per ENU axis).

Their header stamp is the measurement time; their log time is the stamp plus
``--gnss-latency``. The truth topic is the same as without a trajectory. The whole run is
simulated in memory (about 1.1 kB per IMU sample: 0.4 GB for an hour at 100 Hz).

The simulation settings are stored in the bag's ``custom_data`` (keys ``sins_align.*``). The
bag appears only when complete (Ctrl-C, SIGTERM or SIGHUP leave nothing behind); an existing
OUT is refused unless ``--force`` (then a previous bag is replaced once the new one is
complete). OUT must not end in ``.bag`` (the ROS 1 suffix: replay would take the directory for
a ROS 1 bag file).
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
from sins_align.io.gnss_fields import (GNSS_FIX_TOPIC, GNSS_FRAME, GNSS_VELOCITY_TOPIC,
                                       epoch_stamps_ns, gnss_fields)
from sins_align.io import reference_msgs as ref
from sins_align.io.imu_fields import stamp_ns
from sins_align.core.specs import DEG, DPH, DPSH, GRADES, UG, UG_PSHZ, grade_specs
from sins_align.sim.trajectory import PRESETS

PROG = "simulate"
_BLOCK = 4096

#: --option -> (SensorSpecs field, unit factor to SI); units as params.py
SPEC_OPTIONS = {"gyro_bias": ("gyro_bias", DPH), "gyro_arw": ("gyro_arw", DPSH),
                "accel_bias": ("accel_bias", UG), "accel_vrw": ("accel_vrw", UG_PSHZ)}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG, description="Simulate a quasi-static IMU (or, with --trajectory, a moving "
        "vehicle with GNSS) and write a rosbag2 bag of /imu/data_raw (sensor_msgs/Imu) and "
        "/imu_sim/truth (geometry_msgs/QuaternionStamped), plus with --trajectory "
        "/gnss/fix_velocity (geometry_msgs/TwistWithCovarianceStamped) and /gnss/fix "
        "(sensor_msgs/NavSatFix), as imu_sim_node would publish them.")
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
    p.add_argument("--duration", type=float, default=None,
                   help="duration, s (default 150; with --trajectory the preset's)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--t0", type=float, default=0.0,
                   help="time origin, s; the first sample is stamped t0 + 1/rate (default 0)")
    p.add_argument("--frame-id", default=IMU_FRAME, help=f"IMU frame_id (default {IMU_FRAME})")
    p.add_argument("--storage", default="mcap", choices=STORAGES, help="default mcap")
    p.add_argument("--compression", default="none", choices=COMPRESSIONS,
                   help="zstd: mcap chunk compression / sqlite3 per-message (default none)")
    p.add_argument("--force", action="store_true",
                   help="replace OUT if it is a previous bag (once the new one is complete)")
    m = p.add_argument_group("moving vehicle (--trajectory)")
    m.add_argument("--trajectory", choices=sorted(PRESETS), default=None,
                   help="a moving-vehicle preset; adds /gnss/fix_velocity and /gnss/fix")
    m.add_argument("--gnss-rate", type=float, default=None,
                   help="GNSS rate, Hz; rate / gnss-rate must be whole (default 10)")
    m.add_argument("--gnss-noise", type=float, default=None,
                   help="GNSS velocity noise 1-sigma per ENU axis, m/s (default 0.05)")
    m.add_argument("--gnss-latency", type=float, default=None,
                   help="GNSS delivery delay, s: log time = stamp + latency (default 0)")
    m.add_argument("--lever-arm", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="IMU to GNSS antenna, m, IMU axes (default 0 0 0)")
    m.add_argument("--gnss-position-noise", type=float, default=None,
                   help="GNSS position noise 1-sigma per ENU axis, m (default 0)")
    m.add_argument("--gnss-dropout", type=float, nargs=2, action="append", default=None,
                   metavar=("START", "END"),
                   help="no GNSS for START <= t < END s from the start (repeatable)")
    m.add_argument("--no-gnss-vertical", action="store_true",
                   help="no vertical GNSS velocity (NaN, as NMEA receivers)")
    m.add_argument("--gyro-scale", type=float, default=None,
                   help="gyro scale-factor error 1-sigma per axis, ppm (default 0)")
    m.add_argument("--accel-scale", type=float, default=None,
                   help="accelerometer scale-factor error 1-sigma per axis, ppm (default 0)")
    m.add_argument("--vibration", type=float, nargs=2, default=None,
                   metavar=("ACCEL_RMS", "GYRO_RMS"),
                   help="rotor vibration, m/s^2 and deg/s RMS per axis (3 tones in 20-80 Hz)")
    return p


#: Moving-vehicle options (dest) and their defaults; refused without --trajectory.
MOVING_DEFAULTS = {"gnss_rate": 10.0, "gnss_noise": 0.05, "gnss_latency": 0.0,
                   "lever_arm": [0.0, 0.0, 0.0], "gnss_position_noise": 0.0,
                   "gnss_dropout": [], "gyro_scale": 0.0, "accel_scale": 0.0,
                   "vibration": None}


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


def _check_moving_args(args):
    """Resolve the moving-vehicle options (defaults) and check them; refuse them without
    --trajectory, and refuse the static base's --rpy and --sway with it."""
    given = [k for k in MOVING_DEFAULTS if getattr(args, k) is not None]
    if args.no_gnss_vertical:
        given.append("no_gnss_vertical")
    if args.trajectory is None:
        if given:
            raise CliError(f"--{given[0].replace('_', '-')} needs --trajectory")
        return
    if any(args.rpy) or args.sway != "none" or args.sway_amplitude != 1.0:
        raise CliError("--rpy, --sway and --sway-amplitude do not apply with --trajectory "
                       "(the preset sets the motion)")
    for k, v in MOVING_DEFAULTS.items():
        if getattr(args, k) is None:
            setattr(args, k, v)
    for name, val in (("--gnss-rate", args.gnss_rate), ("--gnss-noise", args.gnss_noise),
                      ("--gnss-latency", args.gnss_latency),
                      ("--gnss-position-noise", args.gnss_position_noise),
                      ("--gyro-scale", args.gyro_scale), ("--accel-scale", args.accel_scale),
                      *(("--lever-arm", x) for x in args.lever_arm),
                      *(("--gnss-dropout", x) for w in args.gnss_dropout for x in w),
                      *(("--vibration", x) for x in (args.vibration or ()))):
        if not math.isfinite(val):
            raise CliError(f"{name} must be a finite number, got {val}")
    if not 1.0 <= args.gnss_rate <= 20.0:
        raise CliError(f"--gnss-rate must be within [1, 20] Hz, got {args.gnss_rate:g}")
    step = args.rate / args.gnss_rate
    if abs(step - round(step)) > 1e-9:
        raise CliError(f"--rate / --gnss-rate must be a whole number, got {args.rate:g} / "
                       f"{args.gnss_rate:g}")
    for name, val in (("--gnss-noise", args.gnss_noise), ("--gnss-latency", args.gnss_latency),
                      ("--gnss-position-noise", args.gnss_position_noise),
                      ("--gyro-scale", args.gyro_scale), ("--accel-scale", args.accel_scale),
                      *(("--vibration", x) for x in (args.vibration or ()))):
        if val < 0.0:
            raise CliError(f"{name} must be >= 0, got {val:g}")
    for a, b in args.gnss_dropout:
        if not a < b:
            raise CliError(f"--gnss-dropout needs START < END, got {a:g} {b:g}")


def _check_args(args):
    if args.duration is None:
        args.duration = (150.0 if args.trajectory is None
                         else _preset(args.trajectory, args).duration)
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
    if args.trajectory is not None and abs(args.latitude) > 85.0:
        raise CliError(f"--latitude must be within [-85, 85] deg with --trajectory (local ENU "
                       f"is undefined at the poles), got {args.latitude:g}")


def _imu_and_truth_connections(writer, msgs: Messages) -> tuple:
    """The IMU topic (sensor-data QoS, as imu_sim_node offers it) and the truth topic."""
    c_imu = writer.add_connection("/" + RAW_TOPIC, Messages.IMU, typestore=msgs.store,
                                  offered_qos_profiles=[qos_profile(reliable=False, depth=5)])
    c_truth = writer.add_connection("/" + TRUTH_TOPIC, Messages.QUATERNION_STAMPED,
                                    typestore=msgs.store, offered_qos_profiles=[qos_profile()])
    return c_imu, c_truth


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
        c_imu, c_truth = _imu_and_truth_connections(writer, msgs)
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


def _preset(name: str, args):
    """The preset ``name`` starting at --latitude and --height."""
    from sins_align.sim.trajectory import trajectory_preset

    return trajectory_preset(name, lat_deg=args.latitude, height_m=args.height)


def simulate_moving(args, specs):
    """The :class:`~sins_align.sim.trajectory.TrajectoryResult` of the moving-vehicle
    options."""
    from sins_align.sim.trajectory import Vibration, simulate_trajectory

    vib = None
    if args.vibration is not None and any(args.vibration):
        vib = Vibration(accel_rms=args.vibration[0], gyro_rms=args.vibration[1] * DEG)
    return simulate_trajectory(
        _preset(args.trajectory, args), args.rate, specs=specs, seed=args.seed,
        gnss_rate=args.gnss_rate, gnss_sigma=args.gnss_noise, lever_arm=args.lever_arm,
        duration=args.duration, gyro_scale_ppm=args.gyro_scale,
        accel_scale_ppm=args.accel_scale, vibration=vib, gnss_latency=args.gnss_latency,
        gnss_dropouts=[tuple(w) for w in args.gnss_dropout],
        gnss_vertical=not args.no_gnss_vertical, gnss_pos_sigma=args.gnss_position_noise)


def write_moving_bag(out: Path, args, specs) -> int:
    """Simulate the trajectory and write the bag at ``out`` (must not exist): IMU, truth and
    GNSS in log-time order (at equal times the IMU sample first). Returns the sample count."""
    from sins_align.core.rotation import quat_from_dcm

    r = simulate_moving(args, specs)
    n_total = len(r.gyro)
    covs = imu_covariances(specs, args.rate)
    t0_ns = stamp_ns(args.t0)
    g_stamps = epoch_stamps_ns(t0_ns, args.rate, r.gnss_index)
    g_arrival = g_stamps + stamp_ns(args.gnss_latency)
    gnss = list(gnss_fields(g_stamps, g_arrival, r.gnss_v, r.gnss_llh, args.gnss_noise,
                            args.gnss_position_noise, r.gnss_vertical, GNSS_FRAME))
    msgs = Messages()
    writer = open_writer(out, args.storage, args.compression)
    try:
        c_imu, c_truth = _imu_and_truth_connections(writer, msgs)
        c_vel = writer.add_connection("/" + GNSS_VELOCITY_TOPIC,
                                      ref.TWIST_WITH_COVARIANCE_STAMPED, typestore=msgs.store,
                                      offered_qos_profiles=[qos_profile()])
        c_fix = writer.add_connection("/" + GNSS_FIX_TOPIC, ref.NAV_SAT_FIX,
                                      typestore=msgs.store, offered_qos_profiles=[qos_profile()])
        for key, val in (("trajectory", args.trajectory), ("latitude_deg", args.latitude),
                         ("height_m", args.height), ("grade", args.grade),
                         ("specs_si", [specs.gyro_bias, specs.gyro_arw, specs.accel_bias,
                                       specs.accel_vrw]),
                         ("rate_hz", args.rate), ("seed", args.seed), ("t0_s", args.t0),
                         ("duration_s", n_total / args.rate),
                         ("gnss_rate_hz", args.gnss_rate), ("gnss_noise_m_s", args.gnss_noise),
                         ("gnss_latency_s", args.gnss_latency),
                         ("gnss_position_noise_m", args.gnss_position_noise),
                         ("gnss_dropouts_s", [list(w) for w in args.gnss_dropout]),
                         ("gnss_vertical", not args.no_gnss_vertical),
                         ("lever_arm_m", list(args.lever_arm)),
                         ("vibration_rms", args.vibration),
                         ("gyro_bias_body_rad_s", r.gyro_bias.tolist()),
                         ("accel_bias_body_m_s2", r.accel_bias.tolist()),
                         ("gyro_scale", r.gyro_scale.tolist()),
                         ("accel_scale", r.accel_scale.tolist())):
            writer.set_custom_data(f"sins_align.{key}",
                                   val if isinstance(val, str) else json.dumps(val))
        quat = quat_from_dcm(r.C[1:])
        j = 0
        for done in range(0, n_total, _BLOCK):
            n = min(_BLOCK, n_total - done)
            stamps = sample_stamps_ns(args.t0, args.rate, done, n)
            for fi, ft in zip(imu_fields(stamps, r.gyro[done:done + n], r.accel[done:done + n],
                                         covs, args.frame_id),
                              truth_fields(stamps, quat[done:done + n], args.frame_id)):
                ns = fi.stamp_ns
                while j < len(gnss) and gnss[j].arrival_ns < ns:
                    j = _write_gnss(writer, msgs, c_vel, c_fix, gnss[j], j)
                writer.write(c_imu, ns, msgs.serialize(msgs.raw_imu(fi)))
                writer.write(c_truth, ns, msgs.serialize(msgs.truth(ft)))
        while j < len(gnss):
            j = _write_gnss(writer, msgs, c_vel, c_fix, gnss[j], j)
    except BaseException:
        writer.abort()
        raise
    writer.close()
    return n_total


def _write_gnss(writer, msgs, c_vel, c_fix, f, j) -> int:
    """Write GNSS epoch ``f`` (:class:`~sins_align.io.gnss_fields.GnssFields`) at its arrival
    time: velocity (ENU; angular rate 0, not provided) and fix. Returns j + 1."""
    store = msgs.store
    vel = ref.twist_with_covariance_stamped(store, f.stamp_ns, f.frame_id, f.velocity_enu,
                                            (0.0, 0.0, 0.0), f.velocity_covariance)
    fix = ref.nav_sat_fix(store, f.stamp_ns, f.frame_id, f.latitude_deg, f.longitude_deg,
                          f.altitude_m, f.position_covariance, f.position_covariance_type,
                          ref.STATUS_FIX, ref.SERVICE_GPS)
    writer.write(c_vel, f.arrival_ns, msgs.serialize(vel))
    writer.write(c_fix, f.arrival_ns, msgs.serialize(fix))
    return j + 1


def run(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    check_storage(args.storage, args.compression)
    _check_moving_args(args)
    _check_args(args)
    try:
        specs = specs_from_args(args)
    except ValueError as e:
        raise CliError(str(e)) from None
    out = check_new_output(check_bag_dir_name(args.out, "output"), "output", force=args.force,
                           is_dir=True)
    with AtomicOutput(out, is_dir=True, force=args.force) as tmp:
        try:
            n = (write_sim_bag if args.trajectory is None else write_moving_bag)(
                tmp.tmp, args, specs)
        except ValueError as e:
            raise CliError(str(e)) from None
        tmp.commit()
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    motion = (f"sway {args.sway}" if args.trajectory is None else
              f"trajectory {args.trajectory} with GNSS at {args.gnss_rate:g} Hz")
    print(f"wrote {out}: {n} samples, {n / args.rate:.2f} s at {args.rate:g} Hz, "
          f"{args.grade} grade, {motion}, {args.storage}"
          f"{'+zstd' if args.compression == 'zstd' else ''}, {size / 1e6:.2f} MB")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return cli_main(PROG, run, argv)


if __name__ == "__main__":
    sys.exit(main())
