"""replay --output, one-sample path: /imu/data written from the input bytes (the orientation
written in, as align_node republishes) equals the messages built and serialised by rosbags,
byte for byte; every other topic and the order of the bag are unchanged. (The default block
path equals this one to rounding: test_replay_output_block.)"""
from __future__ import annotations

import pytest

from sins_align.io.bagio import open_reader, read_messages
from sins_align.estimators.quasi_static.aligner import AlignConfig
from sins_align.tools import replay
from sins_align.tools import simulate


def _all(bag):
    r = open_reader(bag)
    try:
        return [(c.topic, ns, bytes(raw)) for c, ns, raw in read_messages(r, r.connections, bag)]
    finally:
        r.close()


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_output_bag_from_input_bytes_equals_rosbags_serialisation(tmp_path, storage):
    bag = tmp_path / "sim"
    assert simulate.main(["--latitude", "34", "--duration", "30", "--rate", "100",
                          "--sway", "car", "--frame-id", "imu_frame_x", "--storage", storage,
                          str(bag)]) == 0
    cfg = AlignConfig(latitude_deg=34.0, backtrack_time=10.0)
    out = {}
    for fast in (True, False):
        out[fast] = tmp_path / f"out_{fast}"
        # the reference: rosbags reads the bag and serialises every message
        s, sess = replay.replay(bag, cfg, output=out[fast], progress=False, bytes_output=fast,
                                per_sample=True)
        assert sess.samples == 3000 and (sess.out_layout is not None) == fast
        assert sess.reading[0] == "rosbags"
    a, b = _all(out[True]), _all(out[False])
    assert len([m for m in a if m[0] == "/imu/data"]) > 2900
    assert a == b
