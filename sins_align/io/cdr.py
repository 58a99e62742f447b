"""Bulk decoding of serialised ``sensor_msgs/Imu`` messages with numpy.

rosbags deserialises one message at a time (about 1e5 msgs/s); an Imu message has a fixed
layout apart from its ``header.frame_id``, so a batch of raw messages of one length is
decoded here with a single structured-dtype view over their bytes (several 1e6 msgs/s):
:func:`decode_imu_batch` for a list of messages (joined first), :func:`decode_imu_array`
for messages lying in one buffer (a decompressed MCAP chunk: evenly spaced ones through a
strided view, without copying them).

Layouts
-------
ROS 2 (``"ros2"``, CDR, little-endian only)::

    0   encapsulation  00 01 00 00   (CDR_LE; alignment below is relative to byte 4)
    4   int32  header.stamp.sec
    8   uint32 header.stamp.nanosec
    12  uint32 L = len(frame_id utf-8) + 1, then L bytes (the last one NUL), zero padding
        up to the next multiple of 8 of the body offset
    4+P 37 float64: orientation (x y z w), orientation_covariance (9), angular_velocity
        (x y z), angular_velocity_covariance (9), linear_acceleration (x y z),
        linear_acceleration_covariance (9)             P = 8 * ceil((12 + L) / 8)

ROS 1 (``"ros1"``, packed little-endian, no encapsulation)::

    0   uint32 header.seq   4 int32 stamp.sec   8 uint32 stamp.nanosec
    12  uint32 L = len(frame_id utf-8), then L bytes (no NUL, no padding)
    16+L  the same 37 float64

Anything else is not guessed at: a message whose encapsulation is not CDR_LE (big-endian
CDR, options bytes set), whose length does not match the layout for its string length,
whose string lacks its NUL terminator or is not UTF-8, or with trailing bytes, goes to the
rosbags deserializer (the reference), which decodes it or raises. The fast path therefore
never returns a value that rosbags would not return for the same bytes (test/test_cdr.py).

Whether a bag's ``sensor_msgs/msg/Imu`` has this layout at all (its message definition
could differ) is checked once per reader with :func:`reader_imu_layout`.

One message at a time (align_node's raw subscription), :class:`ImuLayout` recognises the
ROS 2 layout of one frame_id in a message (CDR_LE, NUL-terminated string, nothing after the
floats), reads the sample from it and writes a copy with the orientation fields replaced.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Callable, Iterator, Sequence

import numpy as np

IMU_TYPE = "sensor_msgs/msg/Imu"

#: CDR encapsulation header of a little-endian plain-CDR message (what ROS 2 writes).
CDR_LE = b"\x00\x01\x00\x00"
#: CDR encapsulation header of a big-endian message (valid, decoded by the fallback).
CDR_BE = b"\x00\x00\x00\x00"
_CDR_LE_U4 = int.from_bytes(CDR_LE, "little")

LAYOUTS = ("ros2", "ros1")

#: The 37 float64 that end every Imu message, as column slices.
N_FLOATS = 37
FLOATS_NBYTES = 8 * N_FLOATS
ORIENTATION = slice(0, 4)
ORIENTATION_COV = slice(4, 13)
GYRO = slice(13, 16)
GYRO_COV = slice(16, 25)
ACCEL = slice(25, 28)
ACCEL_COV = slice(28, 37)

#: Types whose definitions fix the layout (checked by :func:`reader_imu_layout`).
LAYOUT_TYPES = (IMU_TYPE, "std_msgs/msg/Header", "builtin_interfaces/msg/Time",
                "geometry_msgs/msg/Quaternion", "geometry_msgs/msg/Vector3")


class ImuDecodeError(ValueError):
    """A message that neither the fast path nor the rosbags deserializer can decode."""

    def __init__(self, index: int, reason: str):
        super().__init__(f"cannot decode {IMU_TYPE} message {index} of the batch: {reason}")
        self.index = index


def imu_nbytes(frame_id_nbytes: int, layout: str = "ros2") -> int:
    """Serialised size of an Imu whose frame_id has ``frame_id_nbytes`` UTF-8 bytes."""
    if layout == "ros2":
        return 4 + _pad8(12 + frame_id_nbytes + 1) + FLOATS_NBYTES
    if layout == "ros1":
        return 16 + frame_id_nbytes + FLOATS_NBYTES
    raise ValueError(f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}")


def _pad8(n: int) -> int:
    return (n + 7) & ~7


# ----------------------------------------------------------------------------- the batch
@dataclass(eq=False)
class ImuBatch:
    """N decoded Imu messages, in input order.

    Arrays are C-contiguous float64 unless noted; ``gyro`` is angular_velocity (x, y, z),
    ``accel`` linear_acceleration, ``orientation`` (x, y, z, w); covariances are row-major.
    ``floats`` is the (N, 37) array the other float arrays are views of.
    """

    sec: np.ndarray            # (N,) int64
    nanosec: np.ndarray        # (N,) int64
    frame_id: list[str]        # N strings (usually N references to one string)
    floats: np.ndarray         # (N, 37) float64
    seq: np.ndarray | None = None          # (N,) int64, ROS 1 only
    #: indices decoded by the rosbags deserializer, and those message objects
    fallback: dict[int, object] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.sec)

    @property
    def orientation(self) -> np.ndarray:
        return self.floats[:, ORIENTATION]

    @property
    def orientation_covariance(self) -> np.ndarray:
        return self.floats[:, ORIENTATION_COV]

    @property
    def gyro(self) -> np.ndarray:
        return self.floats[:, GYRO]

    @property
    def angular_velocity_covariance(self) -> np.ndarray:
        return self.floats[:, GYRO_COV]

    @property
    def accel(self) -> np.ndarray:
        return self.floats[:, ACCEL]

    @property
    def linear_acceleration_covariance(self) -> np.ndarray:
        return self.floats[:, ACCEL_COV]

    def messages(self) -> Iterator[object]:
        """Message-like objects, one per input, with the fields of a rosbags ``Imu``.

        The fast-decoded ones are :class:`ImuMessage` (attribute access as on a rosbags or
        rclpy message, Python ints and floats, numpy (9,) covariances); those decoded by
        the fallback are the rosbags objects themselves.
        """
        fb = self.fallback
        seq = self.seq.tolist() if self.seq is not None else [None] * len(self)
        fl = self.floats
        cols = fl[:, _MSG_COLUMNS].tolist()      # only what the objects hold as floats
        for i, (s, ns, fid, sq, (g0, g1, g2, a0, a1, a2)) in enumerate(zip(
                self.sec.tolist(), self.nanosec.tolist(), self.frame_id, seq, cols)):
            if fb and i in fb:
                yield fb[i]
            else:
                yield ImuMessage(Header(Time(s, ns), fid, sq), Vector3(g0, g1, g2),
                                 Vector3(a0, a1, a2), fl, i)


_MSG_COLUMNS = [GYRO.start, GYRO.start + 1, GYRO.start + 2,
                ACCEL.start, ACCEL.start + 1, ACCEL.start + 2]


class Time:
    __slots__ = ("sec", "nanosec")

    def __init__(self, sec: int, nanosec: int):
        self.sec = sec
        self.nanosec = nanosec


class Header:
    __slots__ = ("stamp", "frame_id", "seq")

    def __init__(self, stamp: Time, frame_id: str, seq: int | None = None):
        self.stamp = stamp
        self.frame_id = frame_id
        self.seq = seq


class Quaternion:
    __slots__ = ("x", "y", "z", "w")

    def __init__(self, x: float, y: float, z: float, w: float):
        self.x, self.y, self.z, self.w = x, y, z, w


class Vector3:
    __slots__ = ("x", "y", "z")

    def __init__(self, x: float, y: float, z: float):
        self.x, self.y, self.z = x, y, z


class ImuMessage:
    """A decoded ``sensor_msgs/Imu`` (read-only use).

    ``orientation`` is built on access, covariances are (9,) views of the batch arrays.
    """

    __slots__ = ("header", "angular_velocity", "linear_acceleration", "_floats", "_i")
    __msgtype__ = IMU_TYPE

    def __init__(self, header: Header, angular_velocity: Vector3,
                 linear_acceleration: Vector3, floats: np.ndarray, i: int):
        self.header = header
        self.angular_velocity = angular_velocity
        self.linear_acceleration = linear_acceleration
        self._floats = floats
        self._i = i

    @property
    def orientation(self) -> Quaternion:
        return Quaternion(*self._floats[self._i, ORIENTATION].tolist())

    @property
    def orientation_covariance(self) -> np.ndarray:
        return self._floats[self._i, ORIENTATION_COV]

    @property
    def angular_velocity_covariance(self) -> np.ndarray:
        return self._floats[self._i, GYRO_COV]

    @property
    def linear_acceleration_covariance(self) -> np.ndarray:
        return self._floats[self._i, ACCEL_COV]


# ----------------------------------------------------------------------------- decoding
Fallback = Callable[[bytes, int], object]


def default_fallback(layout: str = "ros2") -> Fallback:
    """rosbags' own deserializer (ROS 2 Jazzy / ROS 1 Noetic standard definitions)."""
    from rosbags.typesys import Stores, get_typestore

    if layout == "ros2":
        ts = get_typestore(Stores.ROS2_JAZZY)
        return lambda raw, i: ts.deserialize_cdr(raw, IMU_TYPE)
    if layout == "ros1":
        ts = get_typestore(Stores.ROS1_NOETIC)
        return lambda raw, i: ts.deserialize_ros1(raw, IMU_TYPE)
    raise ValueError(f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}")


_FALLBACKS: dict[str, Fallback] = {}


def decode_imu_batch(raws: Sequence[bytes | bytearray | memoryview], layout: str = "ros2",
                     fallback: Fallback | None = None) -> ImuBatch:
    """Decode serialised ``sensor_msgs/Imu`` messages (all of one ``layout``).

    Messages are grouped by length; each group is decoded at once and validated message by
    message (encapsulation, string length vs total length, NUL terminator, UTF-8). Messages
    that fail validation go to ``fallback(raw, index)``, whose message object is used as is
    (and kept in ``ImuBatch.fallback``).

    Default fallback: the rosbags deserializer for ``layout``; when it fails too,
    :class:`ImuDecodeError` names the index (chained to rosbags' error). Exceptions raised
    by a caller's ``fallback`` propagate unchanged (sins_align.tools.replay raises its one-line
    CliError naming the message's timestamp).
    """
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}")
    n = len(raws)
    if n == 0:
        return decode_imu_array(np.empty(0, np.uint8), np.empty(0, np.int64),
                                np.empty(0, np.int64), layout, fallback)
    sizes = np.fromiter(map(len, raws), np.int64, n)
    buf = np.frombuffer(b"".join(raws), np.uint8)
    starts = np.zeros(n, np.int64)
    np.cumsum(sizes[:-1], out=starts[1:])
    return decode_imu_array(buf, starts, sizes, layout, fallback)


def decode_imu_array(buf: np.ndarray, starts: np.ndarray, sizes: np.ndarray,
                     layout: str = "ros2", fallback: Fallback | None = None) -> ImuBatch:
    """Decode the serialised Imu messages ``buf[starts[i]:starts[i] + sizes[i]]``.

    The messages may sit anywhere in ``buf`` (a 1-D uint8 array, e.g. a decompressed MCAP
    chunk): messages of one size whose starts are evenly spaced are read through one strided
    view of ``buf`` (no copy), others are gathered with one fancy index per size. Validation,
    fallback and errors as :func:`decode_imu_batch` (``fallback`` gets ``bytes`` of the
    message and its index in ``starts``).
    """
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}")
    buf = np.asarray(buf)
    if buf.dtype != np.uint8 or buf.ndim != 1:
        raise ValueError("buf must be a 1-D uint8 array")
    starts = np.asarray(starts, np.int64)
    sizes = np.asarray(sizes, np.int64)
    n = len(starts)
    if len(sizes) != n:
        raise ValueError(f"starts and sizes lengths differ: {n}, {len(sizes)}")
    if n and (starts.min() < 0 or sizes.min() < 0 or (starts + sizes).max() > len(buf)):
        raise ValueError("a message lies outside buf")
    sec = np.zeros(n, np.int64)
    nanosec = np.zeros(n, np.int64)
    seq = np.zeros(n, np.int64) if layout == "ros1" else None
    floats = np.empty((n, N_FLOATS), np.float64)
    frame_id: list = [None] * n
    bad: list[int] = []
    if n:
        first = sizes[0]
        if (sizes == first).all():
            groups = [(int(first), None)]
        else:
            groups = [(int(s), np.flatnonzero(sizes == s)) for s in np.unique(sizes)]
        group = _decode_ros2 if layout == "ros2" else _decode_ros1
        for size, idx in groups:
            rows = message_rows(buf, starts if idx is None else starts[idx], size)
            bad_local = group(rows, idx, sec, nanosec, seq, floats, frame_id)
            bad.extend((bad_local if idx is None else idx[bad_local]).tolist())
    batch = ImuBatch(sec, nanosec, frame_id, floats, seq)
    if bad:
        fb = fallback
        if fb is None:
            fb = _FALLBACKS.get(layout)
            if fb is None:
                fb = _FALLBACKS[layout] = default_fallback(layout)
        for i in sorted(bad):
            raw = buf[starts[i]:starts[i] + sizes[i]].tobytes()
            if fallback is not None:
                msg = fb(raw, i)
            else:
                try:
                    msg = fb(raw, i)
                except Exception as e:  # noqa: BLE001 - rosbags raises several kinds
                    raise ImuDecodeError(i, " ".join(str(e).split()) or type(e).__name__) \
                        from e
            _store(batch, i, msg)
    return batch


def message_rows(buf: np.ndarray, starts: np.ndarray, size: int) -> np.ndarray:
    """(m, size) uint8 array of ``buf[starts[i]:starts[i] + size]`` (in bounds, checked by
    the caller): a strided view of ``buf`` when the starts are evenly spaced by at least
    ``size`` bytes (a run of equal records), else a gathered copy."""
    m = len(starts)
    if m == 0:
        return np.empty((0, size), np.uint8)
    s0 = int(starts[0])
    if m == 1:
        return buf[s0:s0 + size][None]
    step = np.diff(starts)
    stride = int(step[0])
    if stride >= size and (step == stride).all():
        return np.lib.stride_tricks.as_strided(buf[s0:], shape=(m, size), strides=(stride, 1),
                                               writeable=False)
    return buf[starts[:, None] + np.arange(size)]


def _store(b: ImuBatch, i: int, msg) -> None:
    """Put a deserialised message into row ``i`` of the batch arrays."""
    h = msg.header
    b.sec[i] = h.stamp.sec
    b.nanosec[i] = h.stamp.nanosec
    b.frame_id[i] = h.frame_id
    if b.seq is not None:
        b.seq[i] = getattr(h, "seq", 0)
    q, w, a = msg.orientation, msg.angular_velocity, msg.linear_acceleration
    f = b.floats[i]
    f[ORIENTATION] = (q.x, q.y, q.z, q.w)
    f[ORIENTATION_COV] = msg.orientation_covariance
    f[GYRO] = (w.x, w.y, w.z)
    f[GYRO_COV] = msg.angular_velocity_covariance
    f[ACCEL] = (a.x, a.y, a.z)
    f[ACCEL_COV] = msg.linear_acceleration_covariance
    b.fallback[i] = msg


def _decode_ros2(u8, idx, sec, nanosec, seq, floats, frame_id) -> np.ndarray:
    """Decode one group of ROS 2 messages, the rows of ``u8`` (m, size); returns the local
    indices to redo."""
    m, size = u8.shape
    body_pad = size - 4 - FLOATS_NBYTES          # P: header + string + padding
    if body_pad < 16 or body_pad % 8:
        return np.arange(m)                       # no valid string length gives this size
    dt = np.dtype({"names": ["enc", "sec", "nanosec", "slen", "f"],
                   "formats": ["<u4", "<i4", "<u4", "<u4", ("<f8", (N_FLOATS,))],
                   "offsets": [0, 4, 8, 12, 4 + body_pad], "itemsize": size})
    rec = u8.view(dt)[:, 0]
    slen = rec["slen"].astype(np.int64)
    # L with 8 * ceil((12 + L) / 8) == P and L >= 1; then its last byte must be NUL
    ok = (rec["enc"] == _CDR_LE_U4) & (slen >= max(1, body_pad - 19)) & (slen <= body_pad - 12)
    nul_at = np.where(ok, 15 + slen, 0)
    ok &= u8[np.arange(m), nul_at] == 0
    _fill(rec, ok, idx, sec, nanosec, floats)
    _strings(u8, ok, slen - 1, idx, frame_id)
    return np.flatnonzero(~ok)


def _decode_ros1(u8, idx, sec, nanosec, seq, floats, frame_id) -> np.ndarray:
    m, size = u8.shape
    nstr = size - 16 - FLOATS_NBYTES
    if nstr < 0:
        return np.arange(m)
    dt = np.dtype({"names": ["seq", "sec", "nanosec", "slen", "f"],
                   "formats": ["<u4", "<i4", "<u4", "<u4", ("<f8", (N_FLOATS,))],
                   "offsets": [0, 4, 8, 12, 16 + nstr], "itemsize": size})
    rec = u8.view(dt)[:, 0]
    ok = rec["slen"] == nstr
    _fill(rec, ok, idx, sec, nanosec, floats)
    if idx is None:
        seq[:] = rec["seq"]
    else:
        seq[idx] = rec["seq"]
    _strings(u8, ok, np.full(m, nstr, np.int64), idx, frame_id)
    return np.flatnonzero(~ok)


def _fill(rec, ok, idx, sec, nanosec, floats) -> None:
    """Copy the numeric fields (rows failing validation are overwritten by the fallback)."""
    if idx is None:
        sec[:] = rec["sec"]
        nanosec[:] = rec["nanosec"]
        floats[:] = rec["f"]
    else:
        sec[idx] = rec["sec"]
        nanosec[idx] = rec["nanosec"]
        floats[idx] = rec["f"]


def _strings(u8: np.ndarray, ok: np.ndarray, nbytes: np.ndarray, idx, frame_id: list) -> None:
    """Decode the frame_ids (UTF-8, from byte 16 of each row, ``nbytes`` each) of valid rows.

    Rows that are not valid UTF-8 are marked not ok (the fallback then raises, as rosbags
    does for them). When every valid row holds the same bytes, they are decoded once.
    """
    rows = np.flatnonzero(ok)
    if len(rows) == 0:
        return
    r0 = int(rows[0])
    k0 = int(nbytes[r0])
    same = bool((nbytes[rows] == k0).all())
    if same and k0 > 0:
        same = bool((u8[rows, 16:16 + k0] == u8[r0, 16:16 + k0]).all())
    if same:
        try:
            s = u8[r0, 16:16 + k0].tobytes().decode()
        except UnicodeDecodeError:
            ok[rows] = False
            return
        if idx is None and len(rows) == len(ok):
            frame_id[:] = [s] * len(rows)
        else:
            for r in rows.tolist():
                frame_id[r if idx is None else int(idx[r])] = s
        return
    cache: dict[bytes, str | None] = {}
    for r, k in zip(rows.tolist(), nbytes[rows].tolist()):
        raw = u8[r, 16:16 + k].tobytes()
        if raw in cache:
            s = cache[raw]
        else:
            try:
                s = raw.decode()
            except UnicodeDecodeError:
                s = None
            cache[raw] = s
        if s is None:
            ok[r] = False
        else:
            frame_id[r if idx is None else int(idx[r])] = s


# ----------------------------------------------------------------------------- one message
_STAMP = struct.Struct("<iI")
_VEC3 = struct.Struct("<3d")
_ORIENTATION = struct.Struct("<13d")     # orientation, then orientation_covariance
_U4 = struct.Struct("<I")


class ImuLayout:
    """The ROS 2 encoding of ``sensor_msgs/Imu`` messages of one ``frame_id`` (CDR_LE).

    A message has this layout when it starts with CDR_LE, is ``size`` bytes long and holds
    ``head`` (string length, UTF-8 frame_id, NUL) at byte 12; the padding bytes after the
    NUL are not looked at (rclpy leaves whatever was in its buffer there). Every stamp and
    float64 bit pattern encodes as itself, so :meth:`read` and :meth:`with_orientation`
    work on the bytes directly.
    """

    __slots__ = ("frame_id", "size", "head", "floats", "_gyro", "_accel", "_prefix")

    def __init__(self, frame_id: str):
        name = frame_id.encode()
        if b"\0" in name:
            raise ValueError("frame_id contains NUL")
        self.frame_id = frame_id
        self.size = imu_nbytes(len(name))
        self.floats = self.size - FLOATS_NBYTES
        self.head = _U4.pack(len(name) + 1) + name + b"\0"
        self._prefix = self.head + bytes(self.floats - 12 - len(self.head))   # zero padding
        self._gyro = self.floats + 8 * GYRO.start
        self._accel = self.floats + 8 * ACCEL.start

    @classmethod
    def of(cls, raw: bytes) -> ImuLayout | None:
        """The layout of ``raw``, or None when it has none (decode it another way)."""
        if len(raw) < 16 or not raw.startswith(CDR_LE):
            return None
        n = _U4.unpack_from(raw, 12)[0]
        if n < 1 or len(raw) != imu_nbytes(n - 1):
            return None
        try:
            layout = cls(raw[16:15 + n].decode())
        except ValueError:                      # not UTF-8 (UnicodeDecodeError), or a NUL
            return None
        return layout if layout.matches(raw) else None

    def matches(self, raw: bytes) -> bool:
        return len(raw) == self.size and raw.startswith(self.head, 12) and raw.startswith(CDR_LE)

    def read(self, raw: bytes) -> tuple[int, int, tuple, tuple]:
        """(stamp sec, stamp nanosec, angular_velocity xyz, linear_acceleration xyz)."""
        sec, nanosec = _STAMP.unpack_from(raw, 4)
        gyro, accel = _VEC3.unpack_from(raw, self._gyro), _VEC3.unpack_from(raw, self._accel)
        return sec, nanosec, gyro, accel

    def with_orientation(self, raw: bytes, values) -> bytes:
        """``raw`` with orientation and orientation_covariance replaced by ``values`` (13
        numbers: x, y, z, w, then the 9 covariances, row-major) and zero padding."""
        if type(values) is list and len(values) == _ORIENTATION.size // 8:
            # 13 Python floats (the node's path): packed directly, the same bytes
            try:
                v = _ORIENTATION.pack(*values)
                return raw[:12] + self._prefix + v + raw[self.floats + len(v):]
            except struct.error:                # not numbers struct takes: numpy's way
                pass
        v = np.asarray(values, "<f8")
        if v.shape != (ORIENTATION_COV.stop,):
            raise ValueError(f"expected {ORIENTATION_COV.stop} values, got shape {v.shape}")
        return raw[:12] + self._prefix + v.tobytes() + raw[self.floats + v.nbytes:]


# ----------------------------------------------------------------------------- readers
def reader_imu_layout(reader) -> str | None:
    """The layout of ``sensor_msgs/msg/Imu`` in an open rosbags ``AnyReader``, or None.

    ``"ros2"`` for rosbag2 bags and ``"ros1"`` for ROS 1 bags when the bag's definitions of
    Imu and its member types are the standard ones (ROS 2 Jazzy / ROS 1 Noetic, which every
    ROS distribution shares); None (use the deserializer) for anything else.
    """
    from rosbags.typesys import Stores, get_typestore

    try:
        is2 = bool(reader.is2)
        have = reader.typestore.fielddefs
    except AttributeError:
        return None
    ref = get_typestore(Stores.ROS2_JAZZY if is2 else Stores.ROS1_NOETIC).fielddefs
    for t in LAYOUT_TYPES:
        if t not in have or _norm(have[t]) != _norm(ref[t]):
            return None
    return "ros2" if is2 else "ros1"


def _norm(x):
    """Field definitions as nested tuples (lists and tuples compare equal)."""
    if isinstance(x, (list, tuple)):
        return tuple(_norm(v) for v in x)
    return x


def imu_with_orientations(buf: np.ndarray, starts: np.ndarray, sizes: np.ndarray,
                          values: np.ndarray) -> list:
    """:meth:`ImuLayout.with_orientation` for many messages at once: message ``i``
    (``buf[starts[i]:starts[i] + sizes[i]]``) with ``values[i]`` (13 numbers) written in,
    as bytes; None for a message without an :class:`ImuLayout` (build it another way).
    Messages of one size and frame_id are written with one numpy assignment each field."""
    values = np.ascontiguousarray(values, "<f8")
    n = len(starts)
    if values.shape != (n, ORIENTATION_COV.stop):
        raise ValueError(f"expected ({n}, {ORIENTATION_COV.stop}) values, got {values.shape}")
    out: list = [None] * n
    if n == 0:
        return out
    starts = np.asarray(starts, np.int64)
    sizes = np.asarray(sizes, np.int64)
    for size in np.unique(sizes).tolist():
        idx = np.flatnonzero(sizes == size)
        rows = np.array(message_rows(buf, starts[idx], size))       # a copy to write into
        lay = ImuLayout.of(rows[0].tobytes())
        ok = np.zeros(len(idx), dtype=bool)
        if lay is not None:
            head = np.frombuffer(CDR_LE + b"\0" * 8 + lay.head, np.uint8)
            ok = (rows[:, :4] == head[:4]).all(1) & (rows[:, 12:12 + len(lay.head)]
                                                     == head[12:]).all(1)
            rows[:, 12:lay.floats] = np.frombuffer(lay._prefix, np.uint8)
            rows[:, lay.floats:lay.floats + values.shape[1] * 8] = \
                values[idx].view(np.uint8).reshape(len(idx), -1)
            data = rows.tobytes()
            for k, i in enumerate(idx.tolist()):
                if ok[k]:
                    out[i] = data[k * size:(k + 1) * size]
        for k in np.flatnonzero(~ok).tolist():          # another frame_id, or no layout
            i = int(idx[k])
            raw = buf[starts[i]:starts[i] + size].tobytes()
            one = ImuLayout.of(raw)
            if one is not None:
                out[i] = one.with_orientation(raw, values[i])
    return out


def vector3_stamped_cdr(sec: int, nanosec: int, frame_id: str, xyz) -> bytes:
    """A ``geometry_msgs/Vector3Stamped`` in ROS 2 CDR (little-endian), as rosbags and rclpy
    serialise it: stamp, frame_id (length with its NUL, zero padding to 8 from byte 4), then
    the three float64."""
    name = frame_id.encode()
    head = _STAMP.pack(int(sec), int(nanosec)) + _U4.pack(len(name) + 1) + name + b"\0"
    return CDR_LE + head + bytes(-len(head) % 8) + _VEC3.pack(*map(float, xyz))


def vector3_stamped_cdr_many(sec, nanosec, frame_id: str, xyz) -> list[bytes]:
    """:func:`vector3_stamped_cdr` of many messages of one ``frame_id`` (sec, nanosec (n,),
    xyz (n, 3)), laid out in one numpy record array: the same bytes."""
    name = frame_id.encode()
    head = 16 + len(name) + 1                     # CDR header, stamp, length, name, NUL
    at = head + (-(head - 4) % 8)                 # the vector, 8-aligned from byte 4
    dt = np.dtype({"names": ["cdr", "sec", "nsec", "len", "name", "xyz"],
                   "formats": ["V4", "<i4", "<u4", "<u4", f"V{at - 16}", ("<f8", 3)],
                   "offsets": [0, 4, 8, 12, 16, at], "itemsize": at + 24})
    n = len(sec)
    rows = np.zeros(n, dt)
    rows["cdr"] = np.void(CDR_LE)
    rows["sec"] = sec
    rows["nsec"] = nanosec
    rows["len"] = len(name) + 1
    rows["name"] = np.void(name + bytes(at - 16 - len(name)))
    rows["xyz"] = np.asarray(xyz, dtype=float)
    data = rows.tobytes()
    size = dt.itemsize
    return [data[i:i + size] for i in range(0, n * size, size)]


#: the CDR bodies (length, bytes, NUL) of strings seen, for :func:`diagnostic_array_cdr`
#: (the keys come back in every message)
_CDR_STRINGS: dict[str, bytes] = {}
_PADS = (b"", b"\0", b"\0\0", b"\0\0\0")


def diagnostic_array_cdr(sec: int, nanosec: int, frame_id: str, statuses) -> bytes:
    """A ``diagnostic_msgs/DiagnosticArray`` in ROS 2 CDR (little-endian), as rosbags and
    rclpy serialise it; ``statuses``: (level, name, message, hardware_id, [(key, value)])."""
    parts = [CDR_LE, _STAMP.pack(int(sec), int(nanosec))]
    n = 8                       # bytes so far after the 4-byte CDR header (the alignment's origin)
    known = _CDR_STRINGS
    if len(known) > 4096:
        known.clear()

    def string(x: str):
        nonlocal n
        b = known.get(x)
        if b is None:
            e = x.encode()
            b = known[x] = _U4.pack(len(e) + 1) + e + b"\0"
        pad = -n % 4
        parts.append(_PADS[pad] + b)
        n += pad + len(b)

    string(frame_id)
    pad = -n % 4
    parts.append(_PADS[pad] + _U4.pack(len(statuses)))
    n += pad + 4
    for level, name, message, hw, values in statuses:
        parts.append(bytes((int(level) & 0xFF,)))
        n += 1
        string(name)
        string(message)
        string(hw)
        pad = -n % 4
        parts.append(_PADS[pad] + _U4.pack(len(values)))
        n += pad + 4
        for k, v in values:
            string(k)
            string(v)
    return b"".join(parts)

