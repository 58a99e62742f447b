"""BulkWriter writes the file rosbags' own Writer writes for the same messages (byte for
byte, the header's library name and zstd level aside), through write and write_many in any mix, with
and without zstd chunks, over several chunks; rosbags and the project's MCAP reader read it."""
from __future__ import annotations

from importlib.metadata import version

import numpy as np
import pytest
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

from sins_align.io import mcapwrite
from sins_align.io.bagio import Messages, TopicBlocks, open_reader, qos_profile, read_messages
from sins_align.io.mcapwrite import BulkMcapStorage, BulkWriter


def _messages(n, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        ch = int(rng.integers(0, 3))
        size = 20 + int(rng.integers(0, 400)) if ch == 2 else 300
        out.append((ch, 10**9 + 10**7 * i - int(rng.integers(0, 3)) * 10**6,
                    rng.integers(0, 256, size, dtype=np.uint8).tobytes()))
    return out


def _write(cls, path, msgs, compress, batches):
    M = Messages()
    w = cls(path, version=9, storage_plugin=StoragePlugin.MCAP)
    if compress:
        w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    w.open()
    conns = [w.add_connection(t, ty, typestore=M.store, offered_qos_profiles=[qos_profile()])
             for t, ty in (("/a", Messages.IMU), ("/b", Messages.BOOL), ("/c", Messages.IMU))]
    k = 0
    for b in batches:
        part = msgs[k:k + b]
        if cls is Writer or b == 1:
            for ch, ts, d in part:
                w.write(conns[ch], ts, d)
        else:
            w.write_many([conns[ch] for ch, _, _ in part], [ts for _, ts, _ in part],
                         [d for _, _, d in part])
        k += b
    w.close()


@pytest.mark.parametrize("compress", [False, True])
def test_bulk_writer_writes_rosbags_file(tmp_path, monkeypatch, compress):
    monkeypatch.setattr(BulkMcapStorage, "library", f"rosbags-{version('rosbags')}")
    monkeypatch.setattr(BulkMcapStorage, "level", None)
    msgs = _messages(12000)
    batches = [1, 5000, 1, 1, 3000, 3997]
    for d in ("ref", "bulk"):
        (tmp_path / d).mkdir()
    _write(Writer, tmp_path / "ref" / "bag", msgs, compress, [len(msgs)])
    _write(BulkWriter, tmp_path / "bulk" / "bag", msgs, compress, batches)
    ref = (tmp_path / "ref" / "bag" / "bag.mcap").read_bytes()
    bulk = (tmp_path / "bulk" / "bag" / "bag.mcap").read_bytes()
    assert ref.count(b"\x06") > 0 and len(ref) > 3 * mcapwrite.CHUNK_SIZE // (10 if compress
                                                                           else 1)
    assert bulk == ref
    assert ((tmp_path / "ref" / "bag" / "metadata.yaml").read_text()
            == (tmp_path / "bulk" / "bag" / "metadata.yaml").read_text())


def test_bulk_writer_bag_reads_back(tmp_path):
    msgs = _messages(5000, seed=2)
    _write(BulkWriter, tmp_path / "bulk", msgs, True, [2000, 3000])
    r = open_reader(tmp_path / "bulk")
    try:
        got = [(c.topic, ns, bytes(raw)) for c, ns, raw in read_messages(r, r.connections, "b")]
        a = [c for c in r.connections if c.topic == "/a"]
        blocks = TopicBlocks(r, a, "b")
        fast = [(int(ns), mb.raw(i)) for mb in blocks for i, ns in enumerate(mb.log_ns)]
        assert blocks.fallback_reason is None
    finally:
        r.close()
    want = sorted(((("/a", "/b", "/c")[ch], ts, d) for ch, ts, d in msgs),
                  key=lambda x: x[1])
    assert sorted(got, key=lambda x: x[1]) == want
    assert fast == [(ts, d) for t, ts, d in got if t == "/a"]
