"""Convert IMU logs to a rosbag2 bag of ``sensor_msgs/Imu`` (for replay and align_node).

Usage::

    python -m sins_align.tools.import_imu INPUT OUT [--format auto|psins|psins-mat|text]
        [--topic /imu/data_raw] [--frame-id imu_link] [--max-duration S | --max-samples N]
        [--columns t,gx,gy,gz,ax,ay,az] [--delimiter auto|,|;|tab|space] [--skip-rows N]
        [--time-units s|ms|us|ns] [--gyro-units rad/s|deg/s|rad|deg]
        [--accel-units m/s2|g|m/s] [--g M/S2] [--grade NAME]
        [--storage mcap|sqlite3] [--compression none|zstd] [--force]
        [--t0 S] [--master-odom-topic T] [--master-velocity-topic T] [--master-fix-topic T]
        [--truth-topic T] [--world-frame F] [--master-frame-id F] [--master-attitude-std DEG]
        [--master-velocity-std M/S] [--master-position-std M]      (psins-mat only)

Inputs
------
- ``psins``: the PSINS compact-SIMU text log (``.imu``; read by
  :func:`sins_align.io.psins.read_psins`).
  Increments are turned into mean rate and specific force per sample; sample k is stamped
  ``t0 + k*ts``. The body axes stay the file's own: **X-Right, Y-Forward, Z-Up** (RFU). The
  messages carry ``frame_id`` imu_link (``--frame-id``); the alignment estimates C_b^n for
  whatever axes the frame has, so the result is the attitude of the RFU frame in ENU.
- ``psins-mat``: a PSINS transfer-alignment MATLAB file (``.mat``, or a file that starts
  with a MATLAB v5 header; read by :func:`sins_align.io.psins.read_psins_mat`, e.g.
  :data:`sins_align.data.TRANSFER_FOG_MEMS`): a slave IMU's increments (``mimu``) and a
  master INS (``fogavp``). Written:

  - the Imu topic as for ``psins``: mean rate and specific force per sample, RFU body axes,
    stamped with the file's time column + ``--t0`` (default 0);
  - ``/master/odom`` (``nav_msgs/Odometry``): ``header.frame_id`` ``enu``
    (``--world-frame``: a local-level frame with ENU axes), ``child_frame_id`` ``master_link``
    (``--master-frame-id``: the master's RFU body). pose.orientation = the master's C_b^n;
    pose.position = its east/north/up offset from the first master record (flat Earth with
    the WGS-84 radii there; the orientation is relative to the local ENU where the vehicle
    is, which turns from the origin's by distance / Earth radius: 0.013 deg per 1.4 km).
    twist in the child frame (REP-105): linear = ``C_b^n^T v^n``, angular = the body rate
    relative to ENU from neighbouring attitude records;
  - ``/master/velocity`` (``geometry_msgs/TwistWithCovarianceStamped``): the master's
    velocity in ENU (``header.frame_id`` the world frame), angular = the same rate in ENU;
  - ``/master/fix`` (``sensor_msgs/NavSatFix``): latitude and longitude in degrees, the
    file's height as altitude, ``frame_id`` the master's;
  - ``/imu_sim/truth`` (``geometry_msgs/QuaternionStamped``, as simulate and imu_sim_node):
    the slave IMU's true C_b^n at the master times, ``C_master^n exp((mu0 x))``
    (:func:`sins_align.io.psins.slave_attitude`), ``frame_id`` the Imu's (``--frame-id``),
    so ``replay --truth-topic /imu_sim/truth`` compares against it.

  The file states no accuracy of the master; the covariances are diagonal from assumed
  standard deviations: attitude 0.01 deg (``--master-attitude-std``), velocity 0.01 m/s
  (``--master-velocity-std``), position 1 m (``--master-position-std``); the body rate's
  follows from the attitude's (``sqrt(2) * std / (t_k+1 - t_k-1)``). Master records after the
  last imported IMU sample are left out. The reference biases and mounting angles (``eb0``,
  ``db0``, ``mu0``) go into the bag's custom data (``sins_align.psins_mat.*``).
- ``text``: CSV or whitespace-separated columns of time + gyro(3) + accel(3) in declared units.
  Column order from ``--columns`` (names t, gx, gy, gz, ax, ay, az; ``_`` skips a column), else
  from a header line (names like time/stamp, gyro_x/wx/angular_velocity_x, acc_x/ax/
  linear_acceleration_x), else the default order ``t gx gy gz ax ay az``. Blank lines and
  lines starting with ``#`` or ``%`` are skipped, as are the first ``--skip-rows`` lines.
  Units written in the header names are honoured: ``time [ms]``, ``gx (deg/s)``, ``az [g]``
  (time s/ms/us/ns, gyro rad/s/deg/s/rad/deg, accel m/s2/g/m/s); an unknown unit, columns of
  one sensor with different units, or a unit that contradicts ``--time-units``,
  ``--gyro-units`` or ``--accel-units`` is refused in one line. Without units in the header
  the flags apply (defaults s, rad/s, m/s2). A UTF-8 byte-order mark is ignored.
  Increment units (``rad``/``deg``, ``m/s``) are divided by the sample interval (the first
  sample uses the second interval). Time must increase strictly.

Covariances are "unknown" (zeros) unless ``--grade`` gives specs (then as imu_sim_node);
orientation is "not provided" (covariance[0] = -1). Malformed input gives one line on stderr
with the file name and line number, and no output (nor on Ctrl-C, SIGTERM, SIGHUP). An
existing OUT is refused unless ``--force`` (a previous bag is then replaced once the new one
is complete); OUT must not end in ``.bag`` (replay would take it for a ROS 1 bag file).
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import lzma
import re
import sys
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from sins_align.io.bagio import (AtomicOutput, CliError, COMPRESSIONS, Messages, STORAGES,
                    check_bag_dir_name, check_new_output, check_storage, cli_main, open_writer,
                    qos_profile)
from sins_align.io.imu_fields import (IMU_FRAME, MAX_STAMP_S, RAW_TOPIC, TRUTH_TOPIC,
                                      ImuCovariances, ImuFields, TruthFields,
                                      imu_covariances, split_stamp)
from sins_align.io.psins import open_text
from sins_align.io import reference_msgs as ref
from sins_align.core.specs import DEG, GRADES, grade_specs

PROG = "import_imu"
ROLES = ("t", "gx", "gy", "gz", "ax", "ay", "az")
TIME_UNITS = {"s": 10 ** 9, "ms": 10 ** 6, "us": 10 ** 3, "ns": 1}
GYRO_UNITS = {"rad/s": (1.0, False), "deg/s": (DEG, False), "rad": (1.0, True),
              "deg": (DEG, True)}
ACCEL_UNITS = {"m/s2": (1.0, False), "m/s^2": (1.0, False), "g": (None, False),
               "m/s": (1.0, True)}
DELIMITERS = {"auto": None, ",": ",", ";": ";", "tab": "\t", "space": None}
DEFAULT_UNITS = {"time": "s", "gyro": "rad/s", "accel": "m/s2"}
#: Units as written in header names (lower case, spaces removed) -> the --*-units value.
HEADER_UNITS = {
    "time": {"s": "s", "sec": "s", "secs": "s", "second": "s", "seconds": "s", "ms": "ms",
             "msec": "ms", "us": "us", "µs": "us", "μs": "us", "usec": "us", "ns": "ns",
             "nsec": "ns"},
    "gyro": {"rad/s": "rad/s", "rad/sec": "rad/s", "rad*s^-1": "rad/s", "rad.s^-1": "rad/s",
             "deg/s": "deg/s", "deg/sec": "deg/s", "°/s": "deg/s", "dps": "deg/s",
             "rad": "rad", "deg": "deg", "°": "deg"},
    "accel": {"m/s2": "m/s2", "m/s^2": "m/s2", "m/s²": "m/s2", "m/s/s": "m/s2",
              "m*s^-2": "m/s2", "m.s^-2": "m/s2", "g": "g", "m/s": "m/s"},
}
_KIND = {"t": "time", "gx": "gyro", "gy": "gyro", "gz": "gyro", "ax": "accel", "ay": "accel",
         "az": "accel"}
MAX_STAMP_NS = (MAX_STAMP_S - 1) * 10 ** 9   # builtin_interfaces/Time.sec is int32

_ALIASES = {
    "t": ("t", "time", "times", "stamp", "timestamp", "time_s", "t_s", "sec", "seconds"),
    "gx": ("gx", "wx", "gyro_x", "gyr_x", "gyrox", "omega_x", "angular_velocity_x", "dthx",
           "dtheta_x", "rate_x"),
    "gy": ("gy", "wy", "gyro_y", "gyr_y", "gyroy", "omega_y", "angular_velocity_y", "dthy",
           "dtheta_y", "rate_y"),
    "gz": ("gz", "wz", "gyro_z", "gyr_z", "gyroz", "omega_z", "angular_velocity_z", "dthz",
           "dtheta_z", "rate_z"),
    "ax": ("ax", "fx", "acc_x", "accel_x", "accx", "acc_x", "linear_acceleration_x", "dvx",
           "dv_x", "specific_force_x"),
    "ay": ("ay", "fy", "acc_y", "accel_y", "accy", "linear_acceleration_y", "dvy", "dv_y",
           "specific_force_y"),
    "az": ("az", "fz", "acc_z", "accel_z", "accz", "linear_acceleration_z", "dvz", "dv_z",
           "specific_force_z"),
}
_NAME_TO_ROLE = {a: r for r, names in _ALIASES.items() for a in names}

#: options of the psins-mat format and their defaults (None in argparse: refused with the
#: other formats when given)
MAT_OPTIONS = {
    "t0": 0.0,
    "master_odom_topic": "/" + ref.MASTER_ODOM_TOPIC,
    "master_velocity_topic": "/" + ref.MASTER_VELOCITY_TOPIC,
    "master_fix_topic": "/" + ref.MASTER_FIX_TOPIC,
    "truth_topic": "/" + TRUTH_TOPIC,
    "world_frame": ref.WORLD_FRAME,
    "master_frame_id": ref.MASTER_FRAME,
    "master_attitude_std": 0.01,
    "master_velocity_std": 0.01,
    "master_position_std": 1.0,
}
#: std (rad/s) of the master's body rate when a single record gives none
UNKNOWN_RATE_STD = 1e3
#: first bytes of a MATLAB v5 (v6, v7) .mat file: its 116-byte text header
MAT_MAGIC = b"MATLAB 5.0 MAT-file"


def _norm(name: str) -> str:
    """Header name to a lookup key: lower case, units in brackets dropped, '.'/' ' -> '_'."""
    n = re.sub(r"[\(\[].*?[\)\]]", "", name.strip().strip('"').strip("'").lower())
    return re.sub(r"[\s.\-/]+", "_", n).strip("_")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG, description="Convert an IMU log (PSINS .imu, or CSV/whitespace text of "
        "time + gyro + accel) into a rosbag2 bag of sensor_msgs/Imu; a PSINS transfer-"
        "alignment .mat also gives its master INS (Odometry, velocity, NavSatFix) and the "
        "IMU's true attitude.")
    p.add_argument("input", metavar="INPUT", help="log file")
    p.add_argument("out", metavar="OUT", help="output bag directory (must not exist, nor end "
                   "in .bag)")
    p.add_argument("--format", default="auto", choices=("auto", "psins", "psins-mat", "text"),
                   help="auto: psins-mat for .mat files or a MATLAB v5 header, psins for .imu "
                   "files or a leading '%%' header, else text")
    p.add_argument("--topic", default="/" + RAW_TOPIC, help="default /imu/data_raw")
    p.add_argument("--frame-id", default=IMU_FRAME, help="default imu_link")
    lim = p.add_mutually_exclusive_group()
    lim.add_argument("--max-duration", type=float, metavar="S",
                     help="keep the first S seconds of data (samples stamped less than S "
                     "after the first one; PSINS: the first S/ts samples)")
    lim.add_argument("--max-samples", type=int, metavar="N", help="keep the first N samples")
    p.add_argument("--grade", choices=sorted(GRADES),
                   help="fill the REP-145 covariances from this grade (default: unknown)")
    t = p.add_argument_group("text input")
    t.add_argument("--columns", help="column roles in order, comma-separated: t,gx,gy,gz,ax,ay,az "
                   "(_ skips a column)")
    t.add_argument("--delimiter", default="auto", choices=sorted(DELIMITERS),
                   help="auto: ',' or ';' if present in the first row, else whitespace")
    t.add_argument("--skip-rows", type=int, default=0, help="lines to skip at the top")
    t.add_argument("--time-units", choices=sorted(TIME_UNITS),
                   help="default: from the header (time [ms]), else s")
    t.add_argument("--gyro-units", choices=list(GYRO_UNITS),
                   help="rates (rad/s, deg/s) or increments per sample (rad, deg); default: "
                   "from the header (gx [deg/s]), else rad/s")
    t.add_argument("--accel-units", choices=list(ACCEL_UNITS),
                   help="specific force (m/s2, g) or velocity increments per sample (m/s); "
                   "default: from the header (az [g]), else m/s2")
    t.add_argument("--g", type=float, default=9.80665, help="value of 1 g, m/s^2 (default "
                   "9.80665)")
    m = p.add_argument_group("psins-mat input (master INS and truth)")
    m.add_argument("--t0", type=float, metavar="S",
                   help="seconds added to the file's time column for the stamps (default 0)")
    for opt, what in (("master_odom_topic", "nav_msgs/Odometry of the master INS"),
                      ("master_velocity_topic", "geometry_msgs/TwistWithCovarianceStamped, "
                       "master velocity in ENU"),
                      ("master_fix_topic", "sensor_msgs/NavSatFix of the master position"),
                      ("truth_topic", "geometry_msgs/QuaternionStamped, the IMU's true "
                       "C_b^n")):
        m.add_argument("--" + opt.replace("_", "-"), metavar="TOPIC",
                       help=f"{what} (default {MAT_OPTIONS[opt]})")
    m.add_argument("--world-frame", metavar="FRAME", help="frame_id of the odometry and "
                   f"velocity: local level, ENU axes (default {MAT_OPTIONS['world_frame']})")
    m.add_argument("--master-frame-id", metavar="FRAME", help="the master's body frame "
                   f"(default {MAT_OPTIONS['master_frame_id']})")
    m.add_argument("--master-attitude-std", type=float, metavar="DEG",
                   help="assumed master attitude std per axis (default "
                   f"{MAT_OPTIONS['master_attitude_std']} deg)")
    m.add_argument("--master-velocity-std", type=float, metavar="M/S",
                   help="assumed master velocity std per axis (default "
                   f"{MAT_OPTIONS['master_velocity_std']} m/s)")
    m.add_argument("--master-position-std", type=float, metavar="M",
                   help="assumed master position std per axis (default "
                   f"{MAT_OPTIONS['master_position_std']} m)")
    p.add_argument("--storage", default="mcap", choices=STORAGES)
    p.add_argument("--compression", default="none", choices=COMPRESSIONS)
    p.add_argument("--force", action="store_true",
                   help="replace OUT if it is a previous bag (once the new one is complete)")
    return p


# ----------------------------------------------------------------------------- PSINS
def psins_samples(path: Path, args) -> Iterator[tuple[int, tuple, tuple]]:
    """(stamp ns, gyro rad/s, accel m/s^2) of a PSINS log (file body axes, RFU)."""
    from sins_align.io.psins import read_psins

    max_samples = args.max_samples
    if args.max_duration is not None:
        # the header gives ts; read it cheaply through a one-sample read
        ts = read_psins(path, max_samples=1).ts
        max_samples = max(1, int(math.floor(args.max_duration / ts + 1e-9)))
    try:
        log = read_psins(path, max_samples=max_samples)
    except ValueError as e:
        raise CliError(str(e)) from None
    t_ns = np.rint(log.t * 1e9).astype(np.int64)
    for ns, w, f in zip(t_ns.tolist(), log.gyro.tolist(), log.accel.tolist()):
        yield ns, tuple(w), tuple(f)


# ----------------------------------------------------------------------------- PSINS .mat
def _is_mat(path: Path) -> bool:
    """A MATLAB file by its name (``.mat``) or by its first bytes (the v5 text header)."""
    if path.suffix.lower() == ".mat":
        return True
    try:
        with open(path, "rb") as fh:
            return fh.read(len(MAT_MAGIC)) == MAT_MAGIC
    except OSError:
        return False


def _mat_options(args, fmt: str):
    """Fill the psins-mat options' defaults; refuse them (one line) with another format."""
    given = [f"--{k.replace('_', '-')}" for k in MAT_OPTIONS if getattr(args, k) is not None]
    if fmt != "psins-mat":
        if given:
            raise CliError(f"{', '.join(given)}: only for --format psins-mat (a .mat with a "
                           f"master INS)")
        return
    for k, v in MAT_OPTIONS.items():
        if getattr(args, k) is None:
            setattr(args, k, v)
    topics = {"--topic": args.topic, "--master-odom-topic": args.master_odom_topic,
              "--master-velocity-topic": args.master_velocity_topic,
              "--master-fix-topic": args.master_fix_topic, "--truth-topic": args.truth_topic}
    for opt, topic in topics.items():
        if not topic.startswith("/") or len(topic) < 2:
            raise CliError(f"{opt} must be absolute (start with /), got {topic!r}")
    if len(set(topics.values())) != len(topics):
        raise CliError(f"topics must differ: {', '.join(f'{k} {v}' for k, v in topics.items())}")
    if not args.world_frame or not args.master_frame_id:
        raise CliError("--world-frame and --master-frame-id must be non-empty")
    for opt in ("master_attitude_std", "master_velocity_std", "master_position_std"):
        v = getattr(args, opt)
        if not (math.isfinite(v) and v > 0):
            raise CliError(f"--{opt.replace('_', '-')} must be > 0, got {v}")
    if not math.isfinite(args.t0):
        raise CliError(f"--t0 must be finite, got {args.t0}")


def read_mat_for_import(path: Path, args):
    """The .mat (:class:`sins_align.io.psins.PsinsMat`), the number of IMU samples and of
    master records to write (``--max-samples``/``--max-duration``), and the stamps (ns) of
    both, checked against a ROS stamp's range."""
    from sins_align.io.psins import read_psins_mat

    try:
        mat = read_psins_mat(path)
    except ValueError as e:
        raise CliError(str(e)) from None
    except OSError as e:
        raise CliError(f"cannot read {path}: {e.strerror or e}") from None
    n = mat.n
    if args.max_samples is not None:
        n = min(n, args.max_samples)
    if args.max_duration is not None:
        n = min(n, int(np.count_nonzero(mat.t - mat.t[0] < args.max_duration - 0.5e-9)))
    n = max(n, 1)
    t0_ns = round(args.t0 * 1e9)
    imu_ns = t0_ns + np.rint(mat.t[:n] * 1e9).astype(np.int64)
    master_ns = t0_ns + np.rint(mat.master_t * 1e9).astype(np.int64)
    m = int(np.count_nonzero(master_ns <= imu_ns[-1]))
    master_ns = master_ns[:m]
    lo = int(min(imu_ns[0], master_ns[0] if m else imu_ns[0]))
    if lo < 0 or int(imu_ns[-1]) > MAX_STAMP_NS:
        raise CliError(f"{path}: time {mat.t[0]:g} .. {mat.t[n - 1]:g} s + --t0 {args.t0:g} s "
                       f"is outside a ROS stamp's range (0 .. 2^31 s); choose another --t0")
    return mat, n, m, imu_ns, master_ns


def write_psins_mat_bag(out: Path, mat, n: int, m: int, imu_ns: np.ndarray,
                        master_ns: np.ndarray, args, covs: ImuCovariances) -> None:
    """Write the Imu samples, the master INS topics and the truth (module doc) to ``out``."""
    msgs = Messages()
    store = msgs.store
    writer = open_writer(out, args.storage, args.compression)
    try:
        c_imu = writer.add_connection(args.topic, Messages.IMU, typestore=store,
                                      offered_qos_profiles=[qos_profile(reliable=False,
                                                                        depth=5)])
        c_odom = writer.add_connection(args.master_odom_topic, ref.ODOMETRY, typestore=store,
                                       offered_qos_profiles=[qos_profile()])
        c_vel = writer.add_connection(args.master_velocity_topic,
                                      ref.TWIST_WITH_COVARIANCE_STAMPED, typestore=store,
                                      offered_qos_profiles=[qos_profile()])
        c_fix = writer.add_connection(args.master_fix_topic, ref.NAV_SAT_FIX, typestore=store,
                                      offered_qos_profiles=[qos_profile()])
        c_truth = writer.add_connection(args.truth_topic, Messages.QUATERNION_STAMPED,
                                        typestore=store, offered_qos_profiles=[qos_profile()])
        origin = (mat.master_lat[0], mat.master_lon[0], mat.master_height[0])
        for key, val in (("imported_from", Path(args.input).name), ("format", args.format),
                         ("psins_mat.eb0_rad_s", mat.eb0.tolist()),
                         ("psins_mat.db0_m_s2", mat.db0.tolist()),
                         ("psins_mat.mu0_rad", mat.mu0.tolist()),
                         ("psins_mat.mounting", "C_slave^n = C_master^n exp((mu0 x))"),
                         ("psins_mat.t0_s", args.t0),
                         ("psins_mat.origin_lat_lon_rad_h_m", [float(x) for x in origin]),
                         ("psins_mat.assumed_std", {
                             "attitude_deg": args.master_attitude_std,
                             "velocity_m_s": args.master_velocity_std,
                             "position_m": args.master_position_std})):
            writer.set_custom_data(f"sins_align.{key}",
                                   val if isinstance(val, str) else json.dumps(val))
        # master records: everything from the whole file, then cut to the m written
        C = mat.master_dcm
        rate_b = ref.body_rates(mat.master_t, C)
        rate_n = np.einsum("kij,kj->ki", C, rate_b)
        v_b = ref.body_velocity(C, mat.master_vel)
        pos = ref.local_enu(mat.master_lat, mat.master_lon, mat.master_height, origin)
        lo = np.maximum(np.arange(mat.n_master) - 1, 0)
        hi = np.minimum(np.arange(mat.n_master) + 1, mat.n_master - 1)
        att_sd = args.master_attitude_std * math.pi / 180.0
        # one record alone has no rate: zero, with a std standing for "unknown"
        rate_sd = np.full(mat.n_master, UNKNOWN_RATE_STD)
        both = hi > lo
        rate_sd[both] = math.sqrt(2.0) * att_sd / (mat.master_t[hi] - mat.master_t[lo])[both]
        pose_cov = ref.covariance6(args.master_position_std, att_sd)
        fix_cov = ref.covariance3(args.master_position_std)
        items: list[tuple[int, int, object, bytes]] = []
        for ns, w, f in zip(imu_ns.tolist(), mat.gyro[:n].tolist(), mat.accel[:n].tolist()):
            sec, nsec = split_stamp(ns)
            items.append((ns, 0, c_imu, msgs.serialize(
                msgs.raw_imu(ImuFields(sec, nsec, args.frame_id, tuple(w), tuple(f), covs)))))
        for k, ns in enumerate(master_ns.tolist()):
            twist_cov = ref.covariance6(args.master_velocity_std, rate_sd[k])
            ser = store.serialize_cdr
            items.append((ns, 1, c_odom, ser(ref.odometry(
                store, ns, args.world_frame, args.master_frame_id, pos[k], mat.master_quat[k],
                pose_cov, v_b[k], rate_b[k], twist_cov), ref.ODOMETRY)))
            items.append((ns, 2, c_vel, ser(ref.twist_with_covariance_stamped(
                store, ns, args.world_frame, mat.master_vel[k], rate_n[k], twist_cov),
                ref.TWIST_WITH_COVARIANCE_STAMPED)))
            items.append((ns, 3, c_fix, ser(ref.nav_sat_fix(
                store, ns, args.master_frame_id, math.degrees(mat.master_lat[k]),
                math.degrees(mat.master_lon[k]), mat.master_height[k], fix_cov),
                ref.NAV_SAT_FIX)))
            sec, nsec = split_stamp(ns)
            items.append((ns, 4, c_truth, msgs.serialize(msgs.truth(TruthFields(
                sec, nsec, args.frame_id, tuple(mat.slave_quat[k].tolist()))))))
        items.sort(key=lambda it: (it[0], it[1]))
        for ns, _, conn, data in items:
            writer.write(conn, ns, data)
    except BaseException:
        writer.abort()
        raise
    writer.close()


def run_psins_mat(src: Path, out: Path, args) -> int:
    """The psins-mat import (module doc): read, write atomically, print one summary line."""
    mat, n, m, imu_ns, master_ns = read_mat_for_import(src, args)
    covs = ImuCovariances()
    if args.grade:
        covs = imu_covariances(grade_specs(args.grade), 1.0 / mat.ts)
    with AtomicOutput(out, is_dir=True, force=args.force) as tmp:
        write_psins_mat_bag(tmp.tmp, mat, n, m, imu_ns, master_ns, args, covs)
        tmp.commit()
    dur = (int(imu_ns[-1]) - int(imu_ns[0])) * 1e-9
    rate = f", {(n - 1) / dur:.2f} Hz" if n > 1 and dur > 0 else ""
    print(f"wrote {out}: {n} samples on {args.topic}, {dur:.3f} s{rate}, frame_id "
          f"{args.frame_id} (body axes X-Right Y-Forward Z-Up (PSINS RFU)), from psins-mat "
          f"{src.name}; master INS: {m} records on {args.master_odom_topic} (frame "
          f"{args.world_frame} -> {args.master_frame_id}), {args.master_velocity_topic}, "
          f"{args.master_fix_topic}; slave truth on {args.truth_topic}")
    return 0


# ----------------------------------------------------------------------------- text
class TextLog:
    """Streaming parser of time + gyro(3) + accel(3) text columns (see module doc)."""

    def __init__(self, path: Path, args):
        self.path = path
        self.name = str(path)
        self.args = args
        #: units in use: kind -> (value, where from: "header", "option" or "default")
        self.units = {k: (getattr(args, f"{k}_units") or v,
                          "option" if getattr(args, f"{k}_units") else "default")
                      for k, v in DEFAULT_UNITS.items()}
        self._set_scales()
        self.sep = DELIMITERS[args.delimiter]
        self.sep_fixed = args.delimiter != "auto"
        self.index: list[int] | None = (self._parse_columns(args.columns)
                                        if args.columns else None)

    def _set_scales(self):
        self.t_scale = TIME_UNITS[self.units["time"][0]]
        self.g_scale, self.g_inc = GYRO_UNITS[self.units["gyro"][0]]
        a_scale, self.a_inc = ACCEL_UNITS[self.units["accel"][0]]
        self.a_scale = self.args.g if a_scale is None else a_scale

    def _header_units(self, fields: list[str], lineno: int):
        """Units written in the header names of the used columns (``gx [deg/s]``): each
        sensor's columns must agree, with each other and with an explicit --*-units."""
        found: dict[str, tuple[str, str]] = {}     # kind -> (unit value, column text)
        for role, i in zip(ROLES, self.index):
            if i >= len(fields):
                continue
            m = re.search(r"[\(\[]\s*([^\)\]]*?)\s*[\)\]]", fields[i])
            if not m:
                continue
            kind = _KIND[role]
            written = m.group(1)
            unit = HEADER_UNITS[kind].get(written.lower().replace(" ", ""))
            if unit is None:
                raise self._err(lineno, f"column {fields[i]!r}: unknown {kind} unit "
                                f"{written!r} (known: {', '.join(_known_units(kind))}); "
                                f"rename the column or convert the data")
            if kind in found and found[kind][0] != unit:
                raise self._err(lineno, f"columns {found[kind][1]!r} and {fields[i]!r} have "
                                f"different {kind} units")
            found.setdefault(kind, (unit, fields[i]))
        for kind, (unit, col) in found.items():
            given, source = self.units[kind]
            if source == "option" and given != unit:
                raise self._err(lineno, f"column {col!r} says {unit}, --{kind}-units says "
                                f"{given}; drop one of them")
            self.units[kind] = (unit, "header")
        self._set_scales()

    def _err(self, lineno: int, msg: str) -> CliError:
        return CliError(f"{self.name}:{lineno}: {msg}")

    @staticmethod
    def _parse_columns(spec: str) -> list[int]:
        names = [c.strip() for c in spec.split(",")]
        idx: dict[str, int] = {}
        for i, n in enumerate(names):
            if n == "_":
                continue
            role = _NAME_TO_ROLE.get(_norm(n))
            if role is None:
                raise CliError(f"--columns: unknown column name {n!r} (use t, gx, gy, gz, ax, "
                               f"ay, az or _)")
            if role in idx:
                raise CliError(f"--columns: {role} given twice")
            idx[role] = i
        missing = [r for r in ROLES if r not in idx]
        if missing:
            raise CliError(f"--columns: missing {', '.join(missing)} (need t,gx,gy,gz,ax,ay,az)")
        return [idx[r] for r in ROLES]

    def _split(self, line: str) -> list[str]:
        if self.sep is None:
            return line.split()
        return [x.strip() for x in line.split(self.sep)]

    def _header_index(self, fields: list[str], lineno: int) -> list[int]:
        idx: dict[str, int] = {}
        for i, n in enumerate(fields):
            role = _NAME_TO_ROLE.get(_norm(n))
            if role is not None and role not in idx:
                idx[role] = i
        missing = [r for r in ROLES if r not in idx]
        if missing:
            raise self._err(lineno, f"header {fields!r} has no column for "
                            f"{', '.join(missing)}; name them or pass --columns")
        return [idx[r] for r in ROLES]

    def rows(self) -> Iterator[tuple[int, int, list[float]]]:
        """(line number, stamp ns, [gx, gy, gz, ax, ay, az] as given) per data line."""
        try:
            # utf-8-sig: a byte-order mark (spreadsheet exports) is not part of the header
            fh = open_text(self.path, encoding="utf-8-sig")
        except OSError as e:
            raise CliError(f"cannot read {self.name}: {e.strerror}") from None
        with fh:
            first = True
            for lineno, line in enumerate(_lines(fh, self.name), start=1):
                if lineno <= self.args.skip_rows:
                    continue
                s = line.strip()
                if not s or s[0] in "#%":
                    continue
                if first and not self.sep_fixed:
                    self.sep = "," if "," in s else (";" if ";" in s else None)
                fields = self._split(s)
                if first:
                    first = False
                    if not _all_numeric(fields):
                        if self.index is None:
                            self.index = self._header_index(fields, lineno)
                        self._header_units(fields, lineno)
                        continue
                    if self.index is None:
                        self.index = list(range(7))
                need = max(self.index) + 1
                if len(fields) < need:
                    raise self._err(lineno, f"expected at least {need} columns, got "
                                    f"{len(fields)}: {s[:80]!r}")
                yield lineno, self._stamp(fields[self.index[0]], lineno), \
                    self._values(fields, lineno)

    def _stamp(self, text: str, lineno: int) -> int:
        try:
            d = Decimal(text)
        except InvalidOperation:
            raise self._err(lineno, f"time {text!r} is not a number") from None
        if not d.is_finite():
            raise self._err(lineno, f"time {text!r} is not finite")
        ns = int((d * self.t_scale).to_integral_value())
        if not 0 <= ns <= MAX_STAMP_NS:
            raise self._err(lineno, f"time {text!r} {self.units['time'][0]} is outside a ROS "
                            f"stamp's range (0 .. 2^31 s)")
        return ns

    def _values(self, fields: list[str], lineno: int) -> list[float]:
        out = []
        for role, i in zip(ROLES[1:], self.index[1:]):
            try:
                v = float(fields[i])
            except ValueError:
                raise self._err(lineno, f"{role} value {fields[i]!r} (column {i + 1}) is not "
                                f"a number") from None
            if not math.isfinite(v):
                raise self._err(lineno, f"{role} value {fields[i]!r} (column {i + 1}) is not "
                                f"finite")
            out.append(v)
        return out

    def samples(self) -> Iterator[tuple[int, tuple, tuple]]:
        """(stamp ns, gyro rad/s, accel m/s^2) in SI, increments divided by the interval."""
        pending = None          # first row waits for the second interval when increments
        prev_ns = None
        for lineno, ns, v in self.rows():
            if prev_ns is not None and ns <= prev_ns:
                raise self._err(lineno, f"time does not increase ({ns - prev_ns} ns step)")
            dt = None if prev_ns is None else (ns - prev_ns) * 1e-9
            prev_ns = ns
            if pending is not None:
                yield self._si(*pending, dt)
                pending = None
            if dt is None and (self.g_inc or self.a_inc):
                pending = (ns, v)
                continue
            yield self._si(ns, v, dt)
        if pending is not None:
            raise CliError(f"{self.name}: increments need at least 2 samples to know the "
                           f"interval")
        if prev_ns is None:
            raise CliError(f"{self.name}: no data lines")

    def _si(self, ns, v, dt):
        gs = self.g_scale / dt if self.g_inc else self.g_scale
        as_ = self.a_scale / dt if self.a_inc else self.a_scale
        return ns, (v[0] * gs, v[1] * gs, v[2] * gs), (v[3] * as_, v[4] * as_, v[5] * as_)


def _known_units(kind: str) -> list[str]:
    return list(dict.fromkeys(HEADER_UNITS[kind].values()))


def _all_numeric(fields: list[str]) -> bool:
    try:
        for f in fields:
            float(f)
    except ValueError:
        return False
    return True


def _lines(fh, name: str) -> Iterator[str]:
    """The lines of fh; a truncated or corrupt xz stream is one CliError."""
    try:
        yield from fh
    except (lzma.LZMAError, EOFError) as e:
        raise CliError(f"{name}: not a readable xz file ({e})") from None


def _is_psins(path: Path) -> bool:
    """A PSINS log by its name (``.imu``, ``.imu.xz``) or by a first line starting with
    ``%`` (read through xz when the file starts with the xz magic bytes)."""
    suffixes = [x.lower() for x in path.suffixes[-2:]]
    if suffixes[-1:] == [".imu"] or suffixes == [".imu", ".xz"]:
        return True
    try:
        with open_text(path, encoding="utf-8-sig") as fh:
            for line in fh:
                if line.strip():
                    return line.lstrip().startswith("%")
    except (OSError, lzma.LZMAError, EOFError):
        return False
    return False


def _limited(samples, args):
    first = None
    for k, (ns, w, f) in enumerate(samples):
        if args.max_samples is not None and k >= args.max_samples:
            return
        if first is None:
            first = ns
        if args.max_duration is not None and (ns - first) >= args.max_duration * 1e9 - 0.5:
            return
        yield ns, w, f


def write_imu_bag(out: Path, samples, args, covs: ImuCovariances) -> tuple[int, int, int]:
    """Write samples to a bag at ``out``. Returns (count, first ns, last ns)."""
    msgs = Messages()
    writer = open_writer(out, args.storage, args.compression)
    n, first, last = 0, None, None
    try:
        conn = writer.add_connection(args.topic, Messages.IMU, typestore=msgs.store,
                                     offered_qos_profiles=[qos_profile(reliable=False,
                                                                       depth=5)])
        writer.set_custom_data("sins_align.imported_from", Path(args.input).name)
        writer.set_custom_data("sins_align.format", args.format)
        for ns, w, f in samples:
            sec, nsec = split_stamp(ns)
            msg = msgs.raw_imu(ImuFields(sec, nsec, args.frame_id, w, f, covs))
            writer.write(conn, ns, msgs.serialize(msg))
            n += 1
            first = ns if first is None else first
            last = ns
        if n == 0:
            raise CliError(f"{args.input}: no samples to write")
    except BaseException:
        writer.abort()
        raise
    writer.close()
    return n, first, last


def run(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    check_storage(args.storage, args.compression)
    src = Path(args.input)
    if not src.is_file():
        raise CliError(f"input {src} does not exist" if not src.exists()
                       else f"input {src} is not a file")
    if args.max_duration is not None and not (math.isfinite(args.max_duration)
                                              and args.max_duration > 0):
        raise CliError(f"--max-duration must be > 0 s, got {args.max_duration}")
    if args.max_samples is not None and args.max_samples < 1:
        raise CliError(f"--max-samples must be >= 1, got {args.max_samples}")
    if args.skip_rows < 0:
        raise CliError(f"--skip-rows must be >= 0, got {args.skip_rows}")
    if not (math.isfinite(args.g) and args.g > 0):
        raise CliError(f"--g must be > 0, got {args.g}")
    if not args.topic.startswith("/") or not args.frame_id:
        raise CliError("--topic must be absolute (start with /) and --frame-id non-empty")
    fmt = args.format
    if fmt == "auto":
        fmt = "psins-mat" if _is_mat(src) else "psins" if _is_psins(src) else "text"
    args.format = fmt
    _mat_options(args, fmt)
    out = check_new_output(check_bag_dir_name(args.out, "output"), "output", force=args.force,
                           is_dir=True)

    text = None
    if fmt in ("psins", "psins-mat"):
        given = [f"--{k}-units" for k in DEFAULT_UNITS if getattr(args, f"{k}_units")]
        if given:
            what = "a PSINS .mat states its own units (rad, m/s, s)" if fmt == "psins-mat" \
                else "a PSINS log states its own units (header and scale factors)"
            raise CliError(f"{', '.join(given)}: {what}; these options are for text input")
    if fmt == "psins-mat":
        return run_psins_mat(src, out, args)
    if fmt == "psins":
        samples = psins_samples(src, args)
        axes = "X-Right Y-Forward Z-Up (PSINS RFU)"
    else:
        text = TextLog(src, args)
        samples = _limited(text.samples(), args)
        axes = "as in the file"
    covs = ImuCovariances()
    if args.grade:
        # the per-sample noise variance needs the rate: median interval of the first samples
        head = list(itertools.islice(samples, 21))
        dts = np.diff([s[0] for s in head]) * 1e-9
        rate = 1.0 / float(np.median(dts)) if len(dts) else 100.0
        covs = imu_covariances(grade_specs(args.grade), rate)
        samples = itertools.chain(head, samples)
    with AtomicOutput(out, is_dir=True, force=args.force) as tmp:
        n, first, last = write_imu_bag(tmp.tmp, samples, args, covs)
        tmp.commit()
    dur = (last - first) * 1e-9
    rate = f", {(n - 1) / dur:.2f} Hz" if n > 1 and dur > 0 else ""
    units = "" if text is None else ", units " + ", ".join(
        f"{k} {u}{' (header)' if src_ == 'header' else ''}" for k, (u, src_) in text.units.items())
    print(f"wrote {out}: {n} samples on {args.topic}, {dur:.3f} s{rate}, frame_id "
          f"{args.frame_id} (body axes {axes}), from {fmt} {src.name}{units}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return cli_main(PROG, run, argv)


if __name__ == "__main__":
    sys.exit(main())
