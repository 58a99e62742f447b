"""A rosbag2 bag opened without rosbags, for replay's block path (cold starts).

Importing rosbags and building its ROS 2 typestore costs 150-300 ms in a fresh process,
more than reading and decoding a 600 s, 100 Hz bag. :func:`open_fast` opens the bags whose
Imu topic the bulk path reads anyway (a rosbag2 directory of one mcap or one sqlite3 file,
or a lone .mcap file, no rosbag2 compression, the standard ``sensor_msgs/msg/Imu``
definition or none) from ``metadata.yaml`` and the storage file's own index, and returns
None for anything else, which rosbags then opens as before. The :class:`FastBag` it
returns offers what replay's block path takes from rosbags' ``AnyReader``: ``topics`` and
``connections`` (with the message counts of ``metadata.yaml``, as rosbags'
DirectoryReader reports them), the messages of one topic in blocks
(:meth:`FastBag.fast_blocks`: the numpy MCAP reader, or windows of the sqlite3
``messages`` table aggregated by SQLite), and, opened only when needed, rosbags'
reader for everything else (:meth:`FastBag.rosbags`: a block reader that meets something
unusual falls back to it, as :class:`~sins_align.io.bagio.TopicBlocks` does; a message the
bulk decoder refuses is deserialised by it, :meth:`FastBag.deserialize`).

Conditions (anything else: None, rosbags opens the bag):

- a directory with ``metadata.yaml`` (version <= 9) naming one file, storage ``mcap`` or
  ``sqlite3``, no ``compression_mode``, every topic ``cdr``; or a lone ``.mcap`` file
  (its ``cdr`` channels are the connections, as rosbags' McapReader makes them, counted by
  the statistics record or else the chunk indexes);
- mcap: magic, ``ros2`` profile header, footer and a summary section with the schemas and
  channels (the record layout rosbags' McapReader reads); sqlite3: the ``topics`` and
  ``messages`` tables;
- every definition the storage holds (mcap schemas ``ros2msg`` or none; sqlite3
  ``message_definitions``) that defines ``sensor_msgs/msg/Imu`` or one of its member types
  defines them exactly as ROS 2 Jazzy (fields, types, order; comments, blank lines and
  default values aside): the layout :func:`sins_align.io.cdr.reader_imu_layout` calls
  ``"ros2"``;
- for the topic read: one storage channel or topic row of the same topic, type,
  serialisation and QoS (rosbags' DirectoryReader maps them on those), and in sqlite3 no two
  messages of the topic at the same timestamp (rosbags' ``ORDER BY timestamp`` leaves their
  order to SQLite's query plan).
"""
from __future__ import annotations

import os
import re
import struct
from pathlib import Path
from typing import Iterator

import numpy as np

#: Field lists (type, name) of the Imu definition and its member types, as ROS 2 Jazzy.
STANDARD_FIELDS = {
    "sensor_msgs/msg/Imu": (
        ("std_msgs/msg/Header", "header"), ("geometry_msgs/msg/Quaternion", "orientation"),
        ("float64[9]", "orientation_covariance"),
        ("geometry_msgs/msg/Vector3", "angular_velocity"),
        ("float64[9]", "angular_velocity_covariance"),
        ("geometry_msgs/msg/Vector3", "linear_acceleration"),
        ("float64[9]", "linear_acceleration_covariance")),
    "std_msgs/msg/Header": (("builtin_interfaces/msg/Time", "stamp"), ("string", "frame_id")),
    "builtin_interfaces/msg/Time": (("int32", "sec"), ("uint32", "nanosec")),
    "geometry_msgs/msg/Quaternion": (("float64", "x"), ("float64", "y"), ("float64", "z"),
                                     ("float64", "w")),
    "geometry_msgs/msg/Vector3": (("float64", "x"), ("float64", "y"), ("float64", "z")),
}
IMU_TYPE = "sensor_msgs/msg/Imu"
_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16",
               "uint16", "int32", "uint32", "int64", "uint64", "string", "wstring"}


class Unusual(Exception):
    """Something the fast reading does not take (rosbags reads the bag)."""


# ----------------------------------------------------------------------------- definitions
def _full_name(name: str, package: str) -> str:
    """``pkg/msg/Name`` of a type name as written in a .msg definition."""
    base = name.split("[", 1)[0]
    if base in _PRIMITIVES or base.startswith(("string<", "wstring<")):
        return name
    if base == "Header":
        return "std_msgs/msg/Header" + name[len(base):]
    parts = base.split("/")
    if len(parts) == 1:
        full = f"{package}/msg/{base}"
    elif len(parts) == 2:
        full = f"{parts[0]}/msg/{parts[1]}"
    elif len(parts) == 3 and parts[1] == "msg":
        full = base
    else:
        raise Unusual(f"type name {name!r}")
    return full + name[len(base):]


def _fields(text: str, typename: str) -> tuple:
    """(type, name) of each field of one .msg section; constants are Unusual."""
    package = typename.split("/", 1)[0]
    out = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        if "=" in line:
            raise Unusual(f"constant in {typename}")
        tok = line.split()
        if len(tok) not in (2, 3):
            raise Unusual(f"field line {line!r} of {typename}")
        out.append((_full_name(tok[0], package), tok[1]))
    return tuple(out)


def check_definition(msgtype: str, encoding: str, text: str) -> None:
    """Raise :class:`Unusual` unless every section of this definition that defines one of
    :data:`STANDARD_FIELDS` defines it as ROS 2 Jazzy (an Imu definition holds only those)."""
    if encoding == "" and not text:
        return                                 # no definition: rosbags' default typestore
    if encoding != "ros2msg":
        raise Unusual(f"definition encoding {encoding!r}")
    sections = [(msgtype, [])]
    for line in text.splitlines():
        s = line.strip()
        if s and set(s) == {"="} and len(s) >= 3:
            sections.append((None, []))
        elif sections[-1][0] is None:
            if s.startswith("MSG:"):
                sections[-1] = (_full_name(s[4:].strip(), ""), [])
            elif s:
                raise Unusual("definition section without MSG: line")
        else:
            sections[-1][1].append(line)
    for name, lines in sections:
        if name is None:
            raise Unusual("empty definition section")
        if name in STANDARD_FIELDS:
            if _fields("\n".join(lines), name) != STANDARD_FIELDS[name]:
                raise Unusual(f"{name} is not the standard definition")
        elif msgtype == IMU_TYPE:
            raise Unusual(f"{IMU_TYPE} definition holds {name}")


# ----------------------------------------------------------------------------- the bag
class TopicInfo:
    __slots__ = ("msgtype", "msgcount")

    def __init__(self, msgtype: str, msgcount: int):
        self.msgtype, self.msgcount = msgtype, msgcount


class Connection:
    """A topic of ``metadata.yaml`` (what replay takes from rosbags' Connection)."""

    __slots__ = ("id", "topic", "msgtype", "msgcount", "serialization_format", "qos", "digest")

    def __init__(self, id: int, topic: str, msgtype: str, msgcount: int,
                 serialization_format: str, qos, digest: str):
        self.id, self.topic, self.msgtype, self.msgcount = id, topic, msgtype, msgcount
        self.serialization_format, self.qos, self.digest = serialization_format, qos, digest


def _yaml_load(text: str):
    """YAML of a bag (metadata.yaml, QoS profiles): the plain block subset that rosbag2 and
    rosbags write read directly (:func:`block_yaml`; importing PyYAML costs 20 ms of a cold
    start), anything else by PyYAML."""
    try:
        return block_yaml(text)
    except ValueError:
        import yaml
        return yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


#: Keys of metadata.yaml whose values are skipped unread (custom_data: folded long strings).
SKIPPED_KEYS = frozenset({"custom_data", "files", "duration", "starting_time"})
_INT = re.compile(r"[-+]?[0-9]+\Z")
_PLAIN = re.compile(r"[A-Za-z0-9_/.][A-Za-z0-9_/.:+ -]*\Z")


def _scalar(v: str):
    if v in ("[]", "{}"):
        return [] if v == "[]" else {}
    if v in ("", "~", "null"):
        return None
    if v in ("true", "false"):
        return v == "true"
    if len(v) >= 2 and v[0] == v[-1] == "'" and "'" not in v[1:-1].replace("''", ""):
        return v[1:-1].replace("''", "'")
    if len(v) >= 2 and v[0] == v[-1] == '"' and "\\" not in v and '"' not in v[1:-1]:
        return v[1:-1]
    if _INT.match(v) and not (len(v.lstrip("+-")) > 1 and v.lstrip("+-")[0] == "0"):
        return int(v)
    if v[0].isdigit():              # floats, octal, hex, 1_000, dates: PyYAML types them
        raise ValueError(f"scalar {v!r}")
    if not _PLAIN.match(v) or v.endswith((" ", ":")) or ": " in v or " #" in v \
            or v.lower() in ("yes", "no", "on", "off", "true", "false", "null", ".nan",
                             ".inf", "-.inf") or v[0] in "-+." and len(v) > 1:
        raise ValueError(f"scalar {v!r}")
    return v


def block_yaml(text: str):
    """The subset of YAML in block style with one-line scalars (plain, quoted without
    escapes, empty flow collections, ints, booleans, null) as Python objects, the values of
    :data:`SKIPPED_KEYS` skipped unread; ValueError for anything outside it."""
    lines = [(len(ln) - len(ln.lstrip(" ")), ln.strip()) for ln in text.splitlines()
             if ln.strip() and not ln.lstrip().startswith("#")]
    if any("\t" in c for _, c in lines):
        raise ValueError("tab")
    pos = 0

    def node(indent: int):
        nonlocal pos
        ind, c = lines[pos]
        if c.startswith("- ") or c == "-":
            out = []
            while pos < len(lines) and lines[pos][0] == ind and (
                    lines[pos][1].startswith("- ") or lines[pos][1] == "-"):
                rest = lines[pos][1][1:].lstrip(" ")
                if not rest:
                    pos += 1
                    out.append(node(ind + 1))
                elif ":" in rest and (rest.endswith(":") or ": " in rest):
                    # an inline mapping: its first key sits after the dash
                    lines[pos] = (ind + len(lines[pos][1]) - len(rest), rest)
                    out.append(node(ind + 1))
                else:
                    out.append(_scalar(rest))
                    pos += 1
            return out
        out = {}
        while pos < len(lines) and lines[pos][0] == ind and not lines[pos][1].startswith("-"):
            c = lines[pos][1]
            if c.endswith(":"):
                key, val = c[:-1], None
            elif ": " in c:
                key, val = c.split(": ", 1)
                val = val.strip()
            else:
                raise ValueError(f"line {c!r}")
            key = _scalar(key)
            if not isinstance(key, str) or key in out:
                raise ValueError(f"key {key!r}")
            pos += 1
            if key in SKIPPED_KEYS:
                while pos < len(lines) and (lines[pos][0] > ind or (
                        lines[pos][0] == ind and lines[pos][1].startswith("-"))):
                    pos += 1
                out[key] = None
            elif val is None:
                nxt = lines[pos] if pos < len(lines) else None
                if nxt is not None and (nxt[0] > ind or (nxt[0] == ind
                                                         and nxt[1].startswith("- "))):
                    out[key] = node(ind + 1)
                else:
                    out[key] = None
            else:
                out[key] = _scalar(val)
        return out

    if not lines:
        return None
    if lines[0][0] != 0:
        raise ValueError("indented document")
    result = node(0)
    if pos != len(lines):
        raise ValueError(f"line {lines[pos][1]!r}")
    return result


def _qos(value):
    """offered_qos_profiles as parsed YAML (a YAML string in storages and older metadata)."""
    if isinstance(value, str):
        value = _yaml_load(value) if value else []
    return value or []


class FastBag:
    """See the module docstring; made by :func:`open_fast`."""

    def __init__(self, path: Path, storage: str, file: Path, connections: list[Connection]):
        self.path = path
        self.storage = storage
        self.file = file
        self.connections = connections
        self.is2 = True
        self._rosbags = None
        self._db = None
        #: per storage: {topic: [(storage id, type, serialization, qos, digest)]}
        self._channels: dict[str, list] = {}
        #: a bare .mcap file (no metadata.yaml): its channels are the connections
        self.bare = False
        self._channel_list: list[tuple[int, str, str, str]] = []   # (id, topic, type, enc)
        self._counts: dict[int, int] | None = None    # messages per channel (statistics)
        self._chunk_counts: dict[int, int] = {}       # the same from the chunk indexes
        self.definitions: list[tuple[str, str, str]] = []    # (type, encoding, text)

    @property
    def topics(self) -> dict[str, TopicInfo]:
        out: dict[str, TopicInfo] = {}
        for c in sorted(self.connections, key=lambda c: c.topic):
            t = out.get(c.topic)
            if t is None:
                out[c.topic] = TopicInfo(c.msgtype, c.msgcount)
            else:
                t.msgtype = t.msgtype if t.msgtype == c.msgtype else None
                t.msgcount += c.msgcount
        return out

    # -- storage -------------------------------------------------------------------------
    def _open_mcap(self):
        from sins_align.io.bagio import ChunkIndex, mcap_summary, mcap_summary_records
        with open(self.file, "rb") as f:
            _, data = mcap_summary(f, after=25)
            f.seek(0)
            head = f.read(8 + 9 + 4 + 4)
            if head[8] != 0x01:
                raise Unusual("not an MCAP file with a header")
            (k,) = struct.unpack_from("<I", head, 17)
            f.seek(21)
            if f.read(k) != b"ros2":
                raise Unusual("profile is not ros2")
        schemas: dict[int, tuple[str, str, str]] = {}
        try:
            for op, body in mcap_summary_records(data):
                if op == 0x03:
                    (sid,) = struct.unpack_from("<H", body, 0)
                    name, p = _string(body, 2)
                    enc, p = _string(body, p)
                    text, p = _string(body, p)
                    schemas[sid] = (name, enc, text)
                elif op == 0x04:
                    cid, sid = struct.unpack_from("<HH", body, 0)
                    topic, p = _string(body, 4)
                    enc, p = _string(body, p)
                    meta = _string_map(body, p)
                    name = schemas[sid][0] if sid in schemas else "__schemaless__"
                    self._channels.setdefault(topic, []).append(
                        (cid, name, enc, _qos(meta.get("offered_qos_profiles", "")), ""))
                    self._channel_list.append((cid, topic, name, enc))
                elif op == 0x0B and self.bare:
                    # message, schema, channel, attachment, metadata and chunk counts,
                    # start and end time (42 bytes), then channel_message_counts
                    (k,) = struct.unpack_from("<I", body, 42)
                    if k % 10 or 46 + k > len(body):
                        raise Unusual("malformed statistics")
                    self._counts = dict(struct.iter_unpack("<HQ", body[46:46 + k]))
                elif op == 0x08 and self.bare:
                    for cid, c in ChunkIndex(body).counts().items():
                        self._chunk_counts[cid] = self._chunk_counts.get(cid, 0) + c
        except (IndexError, struct.error, UnicodeDecodeError, KeyError) as e:
            raise Unusual(f"malformed summary: {e}") from None
        if not schemas:
            raise Unusual("no schemas in the summary")
        self.definitions = list(schemas.values())

    def _open_sqlite(self):
        import sqlite3
        try:
            db = sqlite3.connect(f"file:{self.file}?immutable=1&mode=ro", uri=True)
        except sqlite3.Error as e:
            raise Unusual(f"sqlite3: {e}") from None
        self._db = db
        try:
            cur = db.cursor()
            tables = {r[0] for r in cur.execute(
                "SELECT name FROM sqlite_master WHERE type='table'")}
            if not {"messages", "topics"} <= tables:
                raise Unusual("tables messages and topics missing")
            cols = {r[1] for r in cur.execute("PRAGMA table_info(topics)")}
            qos = "offered_qos_profiles" in cols
            digest = "type_description_hash" in cols and "schema" in tables
            rows = cur.execute(
                "SELECT id, name, type, serialization_format"
                + (", offered_qos_profiles" if qos else ", ''")
                + (", type_description_hash" if digest else ", ''") + " FROM topics").fetchall()
            for cid, topic, msgtype, fmt, q, dg in rows:
                self._channels.setdefault(topic, []).append((cid, msgtype, fmt, _qos(q), dg))
            if "message_definitions" in tables:
                self.definitions = [tuple(r) for r in cur.execute(
                    "SELECT topic_type, encoding, encoded_message_definition "
                    "FROM message_definitions")]
        except sqlite3.Error as e:
            raise Unusual(f"sqlite3: {e}") from None

    def channel(self, conn: Connection) -> int:
        """The storage's id of ``conn``'s topic (one channel or topic row matching it)."""
        if self.bare:
            return conn.id
        match = [c for c in self._channels.get(conn.topic, ())
                 if c[1] == conn.msgtype and c[2] == conn.serialization_format
                 and c[3] == conn.qos and (not c[4] or not conn.digest or c[4] == conn.digest)]
        if len(match) != 1 or len(self._channels[conn.topic]) != 1:
            raise Unusual(f"topic {conn.topic}: {len(self._channels.get(conn.topic, ()))} "
                          f"storage channels")
        return match[0][0]

    # -- reading -------------------------------------------------------------------------
    def fast_blocks(self, connections, max_messages: int) -> Iterator:
        """MessageBlocks of the messages of ``connections`` (one topic), rosbags' order."""
        from sins_align.io.bagio import McapTopicReader
        ids = frozenset(self.channel(c) for c in connections)
        if self.storage == "mcap":
            yield from McapTopicReader([(self.file, ids)]).blocks(max_messages)
            return
        yield from self._sqlite_blocks(ids, max_messages)

    #: One window of a topic's messages in rowid order, aggregated by SQLite: the stamps
    #: and sizes as text, the data joined (a Python object per window, not per message).
    _SQLITE_WINDOW = (
        "SELECT group_concat(timestamp, ','), group_concat(length(data), ','), "
        "group_concat(data, ''), count(*), max(id), "
        "total(typeof(data) != 'blob' OR typeof(timestamp) != 'integer') "
        "FROM (SELECT timestamp, id, data FROM messages WHERE topic_id = ? AND id > ? "
        "ORDER BY id LIMIT ?)")

    def _sqlite_blocks(self, ids: frozenset[int], size: int) -> Iterator:
        """The topic's messages in windows of ``size`` rows in rowid order; rosbags' order
        (ORDER BY timestamp) when the stamps increase strictly, checked, else Unusual."""
        import sqlite3

        from sins_align.io.bagio import MessageBlock
        if len(ids) != 1:
            raise Unusual("several topic rows")
        (cid,) = ids
        db = self._db
        try:
            if db.execute("PRAGMA encoding").fetchone()[0] != "UTF-8":
                raise Unusual("database encoding is not UTF-8")   # blobs read as text
            db.text_factory = bytes
            last_id, last_ns = -(1 << 63), None
            while True:
                stamps, lengths, data, n, top, odd = db.execute(
                    self._SQLITE_WINDOW, (cid, last_id, size)).fetchone()
                if not n:
                    return
                if odd:
                    raise Unusual("a message that is not a blob with an integer stamp")
                log = np.fromstring(stamps, np.int64, sep=",")
                sizes = np.fromstring(lengths, np.int64, sep=",")
                if len(log) != n or len(sizes) != n or int(sizes.sum()) != len(data):
                    raise Unusual("sqlite3 window does not add up")
                if (n > 1 and not (log[1:] > log[:-1]).all()) or (
                        last_ns is not None and log[0] <= last_ns):
                    raise Unusual("messages of the topic not in strictly increasing "
                                  "timestamp order")
                starts = np.zeros(n, np.int64)
                np.cumsum(sizes[:-1], out=starts[1:])
                last_id, last_ns = int(top), int(log[-1])
                yield MessageBlock(log, np.frombuffer(data, np.uint8), starts, sizes)
        except (sqlite3.Error, ValueError, TypeError) as e:
            raise Unusual(f"sqlite3: {e}") from None

    def rosbags(self, connections):
        """rosbags' reader of the bag (opened once) and its connections matching
        ``connections`` (for a fallback)."""
        from sins_align.io.bagio import open_reader
        if self._rosbags is None:
            self._rosbags = open_reader(self.path)
        want = {(c.topic, c.msgtype) for c in connections}
        return self._rosbags, [c for c in self._rosbags.connections
                               if (c.topic, c.msgtype) in want]

    def deserialize(self, raw: bytes, msgtype: str):
        return self.rosbags(())[0].deserialize(raw, msgtype)

    def close(self):
        if self._db is not None:
            self._db.close()
            self._db = None
        if self._rosbags is not None:
            self._rosbags.close()
            self._rosbags = None


def _string(body: bytes, p: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", body, p)
    if p + 4 + n > len(body):
        raise IndexError("string beyond its record")
    return body[p + 4:p + 4 + n].decode(), p + 4 + n


def _string_map(body: bytes, p: int) -> dict[str, str]:
    (n,) = struct.unpack_from("<I", body, p)
    end = p + 4 + n
    if end > len(body):
        raise IndexError("map beyond its record")
    out, p = {}, p + 4
    while p < end:
        k, p = _string(body, p)
        v, p = _string(body, p)
        out[k] = v
    return out


def open_fast(path: str | os.PathLike) -> FastBag | None:
    """A :class:`FastBag` of ``path``, or None when rosbags must open it (see the module
    docstring; also None for any bag rosbags would refuse: it then reports why)."""
    p = Path(path)
    if p.suffix == ".mcap" and p.is_file():
        return _open_bare_mcap(p)
    try:
        meta_path = p / "metadata.yaml"
        if not p.is_dir() or p.suffix.lower() == ".bag" or not meta_path.is_file():
            return None
        meta = _yaml_load(meta_path.read_text())["rosbag2_bagfile_information"]
        files = meta["relative_file_paths"]
        storage = meta["storage_identifier"]
        if (not isinstance(meta["version"], int) or meta["version"] > 9 or len(files) != 1
                or storage not in ("mcap", "sqlite3")
                or (meta.get("compression_mode") or "").lower() not in ("", "none")):
            return None
        file = p / Path(files[0]).name
        if file.suffix != (".mcap" if storage == "mcap" else ".db3") or not file.is_file():
            return None
        conns = []
        for i, x in enumerate(meta["topics_with_message_count"]):
            tm = x["topic_metadata"]
            if tm["serialization_format"] != "cdr":
                return None
            conns.append(Connection(i + 1, tm["name"], tm["type"], int(x["message_count"]),
                                    "cdr", _qos(tm.get("offered_qos_profiles", [])),
                                    tm.get("type_description_hash", "")))
    except Exception:  # noqa: BLE001 - any doubt: rosbags opens it and reports
        return None
    bag = FastBag(p, storage, file, conns)
    return _opened(bag, bag._open_mcap if storage == "mcap" else bag._open_sqlite)


def _opened(bag: FastBag, open_storage) -> FastBag | None:
    """``bag`` once ``open_storage()`` has read its file and every definition is the
    standard one; None (and closed) on anything unusual or odd."""
    try:
        open_storage()
        for msgtype, enc, text in bag.definitions:
            check_definition(msgtype, enc, text)
    except Exception:  # noqa: BLE001 - Unusual, or anything odd
        bag.close()
        return None
    return bag


def _open_bare_mcap(p: Path) -> FastBag | None:
    """A lone .mcap file, as rosbags' McapReader opens it: its channels are the connections
    (ids, topics, schema names), counted by the statistics record or else the chunk
    indexes."""
    bag = FastBag(p, "mcap", p, [])
    bag.bare = True

    def open_storage():
        bag._open_mcap()
        counts = bag._counts if bag._counts is not None else bag._chunk_counts
        if any(enc != "cdr" for _, _, _, enc in bag._channel_list):
            raise Unusual("a channel that is not cdr")
        bag.connections = [Connection(cid, topic, name, int(counts.get(cid, 0)), "cdr", [], "")
                           for cid, topic, name, _ in bag._channel_list]

    return _opened(bag, open_storage)
