"""Writing rosbag2 MCAP bags in bulk: rosbags' ``Writer`` with a storage that takes many
messages per call.

rosbags' MCAP storage writer builds every message record with several small writes (about
5 us per message, which alone caps a replay near 200,000 messages/s).
:class:`BulkWriter` is rosbags' ``Writer`` (connections, metadata.yaml, counts: all
rosbags') whose MCAP storage, :class:`BulkMcapStorage`, writes the same file as rosbags'
``McapWriter`` (the same records, chunks closed at the same sizes, the same indexes and
summary; only the header's library name and the zstd level differ, test_mcapwrite) and
also takes a list of messages at once (:meth:`BulkWriter.write_many`): their record
headers are built with numpy and joined with the data in one call.
"""
from __future__ import annotations

import struct
from collections import defaultdict
from importlib.metadata import version
from pathlib import Path
from typing import Sequence

import numpy as np

try:
    from compression import zstd        # Python >= 3.14
except ImportError:                      # pragma: no cover - as rosbags imports it
    from backports import zstd

from rosbags.rosbag2 import CompressionMode, StoragePlugin, Writer

MAGIC = b"\x89MCAP0\r\n"
#: rosbags closes a chunk after the message that takes it past this size (bytes)
CHUNK_SIZE = 1 << 20
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
#: Message record head: opcode, record length, channel, sequence, log time, publish time
_HEAD = np.dtype({"names": ["op", "len", "channel", "seq", "log", "pub"],
                  "formats": ["u1", "<u8", "<u2", "<u4", "<u8", "<u8"],
                  "offsets": [0, 1, 9, 11, 15, 23], "itemsize": 31})


def _string(s: str) -> bytes:
    b = s.encode()
    return _U32.pack(len(b)) + b


def _record(op: int, body: bytes) -> bytes:
    return bytes((op,)) + _U64.pack(len(body)) + body


class BulkMcapStorage:
    """rosbags' MCAP storage writer interface (``add_msgtype``, ``add_connection``,
    ``write``, ``close``, ``abort``) plus :meth:`write_many`; the file rosbags writes."""

    #: the MCAP header's library field
    library = f"sins_align (rosbags-{version('rosbags')} layout)"
    #: zstd level of the chunks (None: the library's default, as rosbags); 1 compresses
    #: about twice as fast (replay --output: ~0.2 s of a 600 s 100 Hz bag), ~1 % larger
    level: int | None = 1

    def __init__(self, path: Path, compression: CompressionMode):
        self.path = path / f"{path.name}.mcap"
        self.f = self.path.open("xb")
        self.f.write(MAGIC + _record(0x01, _string("ros2") + _string(self.library)))
        self.pos = self.f.tell()
        self.schemas: list[tuple[int, str, bytes]] = []      # (id, name, record body)
        self.channels: list[tuple[int, bytes]] = []           # (id, record body)
        self.chunk_indexes: list[bytes] = []
        self.zstd = compression == CompressionMode.STORAGE
        self.start, self.end = 2 ** 63 - 1, 0
        self.stats: dict[int, int] = {}
        self._new_chunk()

    def _new_chunk(self):
        self.parts: list[bytes] = []
        self.size = 0
        self.c_start, self.c_end = 2 ** 63 - 1, 0
        self.index: dict[int, list] = defaultdict(list)      # channel -> [ts array, offs]

    def _put(self, b: bytes):
        self.parts.append(b)
        self.size += len(b)

    def add_msgtype(self, connection) -> None:
        sid = len(self.schemas) + 1
        fmt = "ros2msg" if connection.msgdef.format.name == "MSG" else "ros2idl"
        body = (_U16.pack(sid) + _string(connection.msgtype) + _string(fmt)
                + _string(connection.msgdef.data))
        self.schemas.append((sid, connection.msgtype, body))
        self._put(_record(0x03, body))

    def add_connection(self, connection, offered_qos_profiles: str) -> None:
        meta = _string("offered_qos_profiles") + _string(offered_qos_profiles)
        sid = next(i for i, name, _ in self.schemas if name == connection.msgtype)
        body = (_U16.pack(connection.id) + _U16.pack(sid) + _string(connection.topic)
                + _string(connection.ext.serialization_format) + _U32.pack(len(meta)) + meta)
        self.channels.append((connection.id, body))
        self.stats[connection.id] = 0
        self._put(_record(0x04, body))

    def write(self, connection, timestamp: int, data) -> None:
        self.write_many(np.array([connection.id], np.uint16),
                        np.array([timestamp], np.uint64), [bytes(data)])

    def write_many(self, channels: np.ndarray, timestamps: np.ndarray,
                   datas: Sequence[bytes]) -> None:
        """Messages in order: channel ids (n,), log (= publish) times (n,) ns, data."""
        n = len(datas)
        if n == 0:
            return
        sizes = np.fromiter(map(len, datas), np.int64, n)
        head = np.zeros(n, _HEAD)
        head["op"] = 0x05
        head["len"] = sizes + 22
        head["channel"] = channels
        head["log"] = timestamps
        head["pub"] = timestamps
        ends = np.cumsum(sizes + 31)
        hb = head.tobytes()
        k = 0
        while k < n:
            base = int(ends[k - 1]) if k else 0
            # the chunk closes after the first message that takes it past CHUNK_SIZE
            over = np.flatnonzero(ends[k:] - base + self.size > CHUNK_SIZE)
            j = k + int(over[0]) + 1 if len(over) else n
            offs = np.concatenate(([base], ends[k:j - 1])) - base + self.size
            ch, ts = channels[k:j], np.asarray(timestamps[k:j], np.uint64)
            for c in dict.fromkeys(ch.tolist()):          # first-write order, as rosbags
                sel = ch == c
                self.index[c].append((ts[sel], offs[sel]))
                self.stats[c] += int(sel.sum())
            lo, hi = int(ts.min()), int(ts.max())
            self.c_start, self.c_end = min(self.c_start, lo), max(self.c_end, hi)
            self.start, self.end = min(self.start, lo), max(self.end, hi)
            parts: list = [None] * (2 * (j - k))
            parts[0::2] = [hb[i:i + 31] for i in range(31 * k, 31 * j, 31)]
            parts[1::2] = datas[k:j]
            self._put(b"".join(parts))
            k = j
            if len(over):
                self._close_chunk()

    def _close_chunk(self):
        data = b"".join(self.parts)
        comp = (data if not self.zstd else zstd.compress(data) if self.level is None
                else zstd.compress(data, level=self.level))
        name = _string("zstd" if self.zstd else "")
        body = (_U64.pack(self.c_start) + _U64.pack(self.c_end) + _U64.pack(len(data))
                + _U32.pack(0) + name + _U64.pack(len(comp)))
        chunk_start = self.pos
        self._out(b"\x06" + _U64.pack(len(body) + len(comp)) + body)
        self._out(comp)
        chunk_end = self.pos
        offsets = []
        for c, parts in self.index.items():
            offsets.append((c, self.pos))
            ts = np.concatenate([p[0] for p in parts])
            off = np.concatenate([p[1] for p in parts])
            pairs = np.empty((len(ts), 2), "<u8")
            pairs[:, 0], pairs[:, 1] = ts, off
            self._out(_record(0x07, _U16.pack(c) + _U32.pack(16 * len(ts)) + pairs.tobytes()))
        self.chunk_indexes.append(
            _U64.pack(self.c_start) + _U64.pack(self.c_end) + _U64.pack(chunk_start)
            + _U64.pack(chunk_end - chunk_start) + _U32.pack(10 * len(offsets))
            + b"".join(_U16.pack(c) + _U64.pack(o) for c, o in offsets)
            + _U64.pack(self.pos - chunk_end) + name + _U64.pack(len(comp))
            + _U64.pack(len(data)))
        self._new_chunk()

    def _out(self, b: bytes):
        self.f.write(b)
        self.pos += len(b)

    def close(self, version: int, metadata: str) -> None:
        if self.size:
            self._close_chunk()
        meta_start = self.pos
        sub = _string("serialized_metadata") + _string(metadata)
        self._out(_record(0x0C, _string("rosbag2") + _U32.pack(len(sub)) + sub))
        meta_end = self.pos
        self._out(_record(0x0F, _U32.pack(0)))
        schema_start = self.pos
        for _, _, body in self.schemas:
            self._out(_record(0x03, body))
        channel_start = self.pos
        for _, body in self.channels:
            self._out(_record(0x04, body))
        chunk_start = self.pos
        for body in self.chunk_indexes:
            self._out(_record(0x08, body))
        mi_start = self.pos
        self._out(_record(0x0D, _U64.pack(meta_start) + _U64.pack(meta_end - meta_start)
                          + _string("rosbag2")))
        st_start = self.pos
        self._out(_record(0x0B, _U64.pack(sum(self.stats.values())) + _U16.pack(len(self.schemas))
                          + _U32.pack(len(self.channels)) + _U32.pack(0) + _U32.pack(1)
                          + _U32.pack(len(self.chunk_indexes)) + _U64.pack(self.start)
                          + _U64.pack(self.end) + _U32.pack(10 * len(self.stats))
                          + b"".join(_U16.pack(c) + _U64.pack(k)
                                     for c, k in sorted(self.stats.items()))))
        so_start = self.pos
        for op, a, b in ((0x03, schema_start, channel_start), (0x04, channel_start, chunk_start),
                         (0x08, chunk_start, mi_start)):
            if a != b:
                self._out(_record(0x0E, bytes((op,)) + _U64.pack(a) + _U64.pack(b - a)))
        self._out(_record(0x0E, b"\x0d" + _U64.pack(mi_start) + _U64.pack(st_start - mi_start)))
        self._out(_record(0x0E, b"\x0b" + _U64.pack(st_start) + _U64.pack(so_start - st_start)))
        self._out(_record(0x02, _U64.pack(schema_start) + _U64.pack(so_start) + _U32.pack(0)))
        self._out(MAGIC)
        self.f.close()

    def abort(self) -> None:
        self.f.close()


class BulkWriter(Writer):
    """rosbags' rosbag2 ``Writer`` whose MCAP storage is :class:`BulkMcapStorage`, with
    :meth:`write_many`."""

    STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: BulkMcapStorage}

    def write_many(self, connections: Sequence, timestamps: Sequence[int],
                   datas: Sequence[bytes]) -> None:
        """``write(connections[i], timestamps[i], datas[i])`` for every i, in order."""
        n = len(datas)
        if not n:
            return
        if not isinstance(self.storage, BulkMcapStorage) or \
                self.compression_mode == CompressionMode.MESSAGE:
            for c, ts, d in zip(connections, timestamps, datas):
                self.write(c, int(ts), d)
            return
        known = {id(c): c.id for c in self.connections}
        # the objects' ids in C (map), then the few distinct ones looked up
        objs, inverse = np.unique(np.fromiter(map(id, connections), np.int64, n),
                                  return_inverse=True)
        try:
            ids = np.array([known[o] for o in objs.tolist()], np.uint16)[inverse]
        except KeyError:
            bad = next(c for c in connections if id(c) not in known)
            raise ValueError(f"Tried to write to unknown connection {bad!r}.") from None
        ts = np.asarray(timestamps, np.int64)
        if ts.min() < 0:
            raise ValueError("negative timestamp")
        self.storage.write_many(ids, ts.astype(np.uint64), datas)
        for c, k in zip(*np.unique(ids, return_counts=True)):
            self.counts[int(c)] += int(k)
        self.min_timestamp = min(self.min_timestamp, int(ts.min()))
        self.max_timestamp = max(self.max_timestamp, int(ts.max()))
