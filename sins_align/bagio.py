"""Bag plumbing shared by the command-line tools (replay, simulate, import_imu).

- one-line user errors (:class:`CliError`, :func:`cli_main`): no tracebacks for bad input;
- outputs that appear only when complete (:class:`AtomicOutput`): written under a temporary
  name in the destination directory and renamed at the end, removed on any failure;
- rosbag2 writing with the ROS 2 Jazzy typestore (:func:`open_writer`, :class:`Messages`);
- rosbag1/rosbag2 reading with errors turned into one line (:func:`open_reader`,
  :func:`read_messages`, :func:`read_message_chunks`, :func:`deserialize`);
- a progress line on stderr, only when stderr is a terminal (:class:`Progress`).

Bags are read and written with the ``rosbags`` library (ternaris/rosbags); no ROS install
is needed. Timestamps are integer nanoseconds.
"""
from __future__ import annotations

import os
import shutil
import sys
import time
from pathlib import Path
from typing import Callable, Iterator, Sequence

from .imu_fields import ImuCovariances, ImuFields, TruthFields

#: rosbag2 storage plugins and the --compression values each one supports with rosbags:
#: mcap compresses its chunks (zstd, what ros2 bag and Foxglove use); sqlite3 compresses
#: each message (rosbag2 'message' mode).
STORAGES = ("mcap", "sqlite3")
COMPRESSIONS = ("none", "zstd")

DEBUG_ENV = "SINS_ALIGN_DEBUG"


class CliError(Exception):
    """A user error: printed as one line on stderr, exit status 2 (no traceback)."""


def cli_main(prog: str, run: Callable[[Sequence[str] | None], int],
             argv: Sequence[str] | None = None) -> int:
    """Run a tool's ``run(argv)`` and turn user errors into one line on stderr.

    Exit status: what ``run`` returns, 2 for a :class:`CliError`, 130 on Ctrl-C, 1 for an
    unexpected exception (one line too; set ``SINS_ALIGN_DEBUG=1`` for the traceback).
    """
    try:
        return run(argv)
    except CliError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 1
    except Exception as e:   # noqa: BLE001 - last resort, keep stderr to one line
        if os.environ.get(DEBUG_ENV):
            raise
        print(f"{prog}: internal error: {type(e).__name__}: {one_line(e)} "
              f"(set {DEBUG_ENV}=1 for a traceback)", file=sys.stderr)
        return 1


def one_line(e: BaseException | str) -> str:
    """The text of an exception on one line."""
    text = str(e) if not isinstance(e, BaseException) or e.args else type(e).__name__
    return " ".join(text.split()) or type(e).__name__


# ----------------------------------------------------------------------------- outputs
def check_new_output(path: str | os.PathLike, what: str) -> Path:
    """Validate an output path before any work: it must not exist, its directory must."""
    p = Path(path)
    if p.exists() or p.is_symlink():
        raise CliError(f"{what} {p} already exists (remove it or choose another path)")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise CliError(f"{what} {p}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise CliError(f"{what} {p}: directory {parent} is not writable")
    return p


class AtomicOutput:
    """A file or directory that appears at ``path`` only when complete.

    ``tmp`` is where to write: for a file, a hidden name in the same directory; for a
    directory (a rosbag2 bag), ``<hidden dir>/<name>`` so the bag's files keep their final
    names. :meth:`commit` renames it to ``path`` (an existing ``path`` is an error, never
    overwritten); :meth:`discard` removes everything. Used as a context manager, any
    exception discards.
    """

    def __init__(self, path: str | os.PathLike, is_dir: bool = False):
        self.path = Path(path)
        self.is_dir = is_dir
        parent = self.path.parent if str(self.path.parent) else Path(".")
        self._hidden = parent / f".{self.path.name}.partial-{os.getpid()}"
        self.tmp = self._hidden / self.path.name if is_dir else self._hidden
        self.done = False

    def __enter__(self) -> "AtomicOutput":
        if self.is_dir:
            self._hidden.mkdir()
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None or not self.done:
            self.discard()
        return False

    def commit(self):
        if self.path.exists() or self.path.is_symlink():
            raise CliError(f"{self.path} appeared while writing; not overwritten "
                           f"(the result is discarded)")
        os.rename(self.tmp, self.path)
        if self.is_dir:
            os.rmdir(self._hidden)
        self.done = True

    def discard(self):
        if self.done:
            return
        if self._hidden.is_dir() and not self._hidden.is_symlink():
            shutil.rmtree(self._hidden, ignore_errors=True)
        elif self._hidden.exists():
            self._hidden.unlink()


# ----------------------------------------------------------------------------- writing
_TYPESTORE = None


def typestore():
    """The rosbags typestore for ROS 2 Jazzy (standard message definitions)."""
    global _TYPESTORE
    if _TYPESTORE is None:
        from rosbags.typesys import Stores, get_typestore
        _TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
    return _TYPESTORE


def check_storage(storage: str, compression: str):
    """Validate a --storage/--compression pair (both are supported by rosbags)."""
    if storage not in STORAGES:
        raise CliError(f"unknown storage {storage!r}; choose one of {', '.join(STORAGES)}")
    if compression not in COMPRESSIONS:
        raise CliError(f"unknown compression {compression!r}; choose one of "
                       f"{', '.join(COMPRESSIONS)}")


def open_writer(path: Path, storage: str = "mcap", compression: str = "none"):
    """An open rosbag2 ``Writer`` (format version 9) at ``path`` (must not exist).

    ``compression='zstd'``: mcap compresses its chunks (storage mode, readable by Foxglove
    and ros2 bag); sqlite3 compresses each message (rosbag2 'message' mode).
    """
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    check_storage(storage, compression)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    writer = Writer(path, version=9, storage_plugin=plugin)
    if compression == "zstd":
        mode = CompressionMode.STORAGE if storage == "mcap" else CompressionMode.MESSAGE
        writer.set_compression(mode, CompressionFormat.ZSTD)
    writer.open()
    return writer


def qos_profile(reliable: bool = True, transient_local: bool = False, depth: int = 10):
    """A rosbags QoS profile for a topic's ``offered_qos_profiles`` (ros2 bag play uses it)."""
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness,
                                    QosReliability, QosTime)

    infinite = QosTime(9223372036, 854775807)
    return Qos(QosHistory.KEEP_LAST, depth,
               QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
               infinite, infinite, QosLiveliness.AUTOMATIC, infinite, False)


class Messages:
    """Builds ROS 2 Jazzy messages (rosbags objects) and serialises them to CDR."""

    IMU = "sensor_msgs/msg/Imu"
    QUATERNION_STAMPED = "geometry_msgs/msg/QuaternionStamped"
    VECTOR3_STAMPED = "geometry_msgs/msg/Vector3Stamped"
    BOOL = "std_msgs/msg/Bool"
    DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"

    def __init__(self):
        import numpy as np

        self._np = np
        self.store = ts = typestore()
        t = ts.types
        self.Time = t["builtin_interfaces/msg/Time"]
        self.Header = t["std_msgs/msg/Header"]
        self.Quaternion = t["geometry_msgs/msg/Quaternion"]
        self.Vector3 = t["geometry_msgs/msg/Vector3"]
        self.Imu = t[self.IMU]
        self.QuaternionStamped = t[self.QUATERNION_STAMPED]
        self.Vector3Stamped = t[self.VECTOR3_STAMPED]
        self.Bool = t[self.BOOL]
        self.DiagnosticArray = t[self.DIAGNOSTIC_ARRAY]
        self.DiagnosticStatus = t["diagnostic_msgs/msg/DiagnosticStatus"]
        self.KeyValue = t["diagnostic_msgs/msg/KeyValue"]
        self._cov_cache: dict[tuple, object] = {}

    def serialize(self, msg) -> bytes:
        return self.store.serialize_cdr(msg, msg.__msgtype__)

    def header(self, sec: int, nanosec: int, frame_id: str):
        return self.Header(stamp=self.Time(sec=int(sec), nanosec=int(nanosec)),
                           frame_id=frame_id)

    def _cov(self, values):
        key = tuple(values)
        arr = self._cov_cache.get(key)
        if arr is None:
            arr = self._np.array(key, dtype=self._np.float64)
            if len(self._cov_cache) < 64:
                self._cov_cache[key] = arr
        return arr

    def imu(self, header, orientation_xyzw, orientation_cov, angular_velocity, gyro_cov,
            linear_acceleration, accel_cov):
        """``sensor_msgs/Imu`` from plain values (3-/4-tuples, 9-value covariances)."""
        q = orientation_xyzw
        w = angular_velocity
        a = linear_acceleration
        return self.Imu(
            header=header,
            orientation=self.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                        w=float(q[3])),
            orientation_covariance=self._cov(orientation_cov),
            angular_velocity=self.Vector3(x=float(w[0]), y=float(w[1]), z=float(w[2])),
            angular_velocity_covariance=self._cov(gyro_cov),
            linear_acceleration=self.Vector3(x=float(a[0]), y=float(a[1]), z=float(a[2])),
            linear_acceleration_covariance=self._cov(accel_cov))

    def raw_imu(self, f: ImuFields):
        """``sensor_msgs/Imu`` of a raw sample (see :mod:`sins_align.imu_fields`)."""
        c: ImuCovariances = f.covariances
        return self.imu(self.header(f.sec, f.nanosec, f.frame_id), f.orientation_xyzw,
                        c.orientation, f.angular_velocity, c.angular_velocity,
                        f.linear_acceleration, c.linear_acceleration)

    def truth(self, f: TruthFields):
        """``geometry_msgs/QuaternionStamped`` of a truth sample."""
        q = f.quaternion_xyzw
        return self.QuaternionStamped(
            header=self.header(f.sec, f.nanosec, f.frame_id),
            quaternion=self.Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))

    def vector3_stamped(self, header, xyz):
        return self.Vector3Stamped(header=header, vector=self.Vector3(
            x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])))

    def bool(self, value: bool):
        return self.Bool(data=bool(value))

    def diagnostic_array(self, header, statuses):
        """``statuses``: iterable of (level, name, message, hardware_id, [(key, value)])."""
        st = [self.DiagnosticStatus(
            level=int(level), name=name, message=message, hardware_id=hw,
            values=[self.KeyValue(key=k, value=v) for k, v in values])
            for level, name, message, hw, values in statuses]
        return self.DiagnosticArray(header=header, status=st)


# ----------------------------------------------------------------------------- reading
_BAG_KINDS = "a rosbag2 bag (directory with metadata.yaml, .mcap or .db3 file) or a ROS 1 .bag"


def open_reader(path: str | os.PathLike):
    """An open ``AnyReader`` for a rosbag2 bag (dir, .mcap, .db3) or a ROS 1 ``.bag``.

    Bags without embedded message definitions fall back to the ROS 2 Jazzy typestore.

    Raises
    ------
    CliError — missing path, not a bag, unreadable, corrupt or truncated bag.
    """
    from rosbags.highlevel import AnyReader

    p = Path(path)
    if not p.exists():
        raise CliError(f"bag {p} does not exist")
    if p.is_dir():
        if not (p / "metadata.yaml").is_file():
            raise CliError(f"{p} is a directory without metadata.yaml: not a rosbag2 bag")
    elif p.suffix not in (".bag", ".mcap", ".db3"):
        raise CliError(f"{p} is not {_BAG_KINDS}")
    reader = None
    try:
        reader = AnyReader([p], default_typestore=typestore())
        reader.open()
    except Exception as e:  # noqa: BLE001 - rosbags raises many kinds on corrupt input
        raise CliError(f"cannot read bag {p}: {one_line(e)}") from None
    return reader


def read_messages(reader, connections, path) -> Iterator[tuple[object, int, bytes]]:
    """``reader.messages(connections)`` with read errors (corrupt/truncated data) as CliError."""
    it = reader.messages(connections=connections)
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except Exception as e:  # noqa: BLE001
            raise CliError(f"cannot read bag {path}: {one_line(e)} "
                           f"(corrupt or truncated?)") from None
        yield item


def read_message_chunks(reader, connections, path, size: int = 4096
                        ) -> Iterator[list[tuple[object, int, bytes]]]:
    """:func:`read_messages` in lists of at most ``size`` items, in bag order.

    For bulk decoding (:mod:`sins_align.cdr`); memory stays bounded by ``size`` messages.
    """
    if size < 1:
        raise ValueError(f"chunk size must be >= 1, got {size}")
    chunk: list[tuple[object, int, bytes]] = []
    for item in read_messages(reader, connections, path):
        chunk.append(item)
        if len(chunk) >= size:
            yield chunk
            chunk = []
    if chunk:
        yield chunk


def deserialize(reader, raw: bytes, msgtype: str, path, timestamp: int):
    """Deserialize one message; a malformed one is a CliError naming its timestamp."""
    try:
        return reader.deserialize(raw, msgtype)
    except Exception as e:  # noqa: BLE001
        raise CliError(f"cannot decode a {msgtype} message at {timestamp} ns in {path}: "
                       f"{one_line(e)}") from None


# ----------------------------------------------------------------------------- progress
class Progress:
    """A one-line progress bar on stderr, shown only when stderr is a terminal."""

    def __init__(self, total: int, label: str, enabled: bool | None = None):
        self.total = max(int(total), 1)
        self.label = label
        self.enabled = sys.stderr.isatty() if enabled is None else enabled
        self._last = 0.0
        self._t0 = time.monotonic()

    def update(self, done: int):
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last < 0.2:
            return
        self._last = now
        frac = min(done / self.total, 1.0)
        bar = "#" * int(30 * frac)
        rate = done / max(now - self._t0, 1e-9)
        sys.stderr.write(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}% "
                         f"{done}/{self.total} msgs {rate:8.0f} msg/s")
        sys.stderr.flush()

    def close(self):
        if self.enabled:
            sys.stderr.write("\r" + " " * 100 + "\r")
            sys.stderr.flush()
