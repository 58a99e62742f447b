"""Convert IMU logs to a rosbag2 bag of ``sensor_msgs/Imu`` (for replay and align_node).

Usage::

    python -m sins_align.tools.import_imu INPUT OUT [--format auto|psins|text]
        [--topic /imu/data_raw] [--frame-id imu_link] [--max-duration S | --max-samples N]
        [--columns t,gx,gy,gz,ax,ay,az] [--delimiter auto|,|;|tab|space] [--skip-rows N]
        [--time-units s|ms|us|ns] [--gyro-units rad/s|deg/s|rad|deg]
        [--accel-units m/s2|g|m/s] [--g M/S2] [--grade NAME]
        [--storage mcap|sqlite3] [--compression none|zstd] [--force]

Inputs
------
- ``psins``: the PSINS compact-SIMU text log (``.imu``; read by
  :func:`sins_align.io.psins.read_psins`).
  Increments are turned into mean rate and specific force per sample; sample k is stamped
  ``t0 + k*ts``. The body axes stay the file's own: **X-Right, Y-Forward, Z-Up** (RFU). The
  messages carry ``frame_id`` imu_link (``--frame-id``); the alignment estimates C_b^n for
  whatever axes the frame has, so the result is the attitude of the RFU frame in ENU.
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
from sins_align.io.imu_fields import (IMU_FRAME, MAX_STAMP_S, RAW_TOPIC, ImuCovariances, ImuFields,
                         imu_covariances, split_stamp)
from sins_align.io.psins import open_text
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


def _norm(name: str) -> str:
    """Header name to a lookup key: lower case, units in brackets dropped, '.'/' ' -> '_'."""
    n = re.sub(r"[\(\[].*?[\)\]]", "", name.strip().strip('"').strip("'").lower())
    return re.sub(r"[\s.\-/]+", "_", n).strip("_")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG, description="Convert an IMU log (PSINS .imu, or CSV/whitespace text of "
        "time + gyro + accel) into a rosbag2 bag of sensor_msgs/Imu.")
    p.add_argument("input", metavar="INPUT", help="log file")
    p.add_argument("out", metavar="OUT", help="output bag directory (must not exist, nor end "
                   "in .bag)")
    p.add_argument("--format", default="auto", choices=("auto", "psins", "text"),
                   help="auto: psins for .imu files or a leading '%%' header, else text")
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
        fmt = "psins" if _is_psins(src) else "text"
    args.format = fmt
    out = check_new_output(check_bag_dir_name(args.out, "output"), "output", force=args.force,
                           is_dir=True)

    text = None
    if fmt == "psins":
        given = [f"--{k}-units" for k in DEFAULT_UNITS if getattr(args, f"{k}_units")]
        if given:
            raise CliError(f"{', '.join(given)}: a PSINS log states its own units (header and "
                           f"scale factors); these options are for text input")
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
