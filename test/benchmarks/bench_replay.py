"""Benchmark: end-to-end replay throughput on a 100 Hz bag (bag on disk -> summary JSON).

Script, not a test: prints figures, never fails on a slow machine. Run::

    .venv/bin/python test/benchmarks/bench_replay.py [--duration 300] [--repeat 3]

It simulates a static navigation-grade 100 Hz bag (``sins_align.simulate``, mcap + zstd) into
a temporary directory, then times ``sins_align.replay`` in this process (the CLI's ``main``,
so argument handling, bag reading, deserialisation, the estimator and the JSON are all in),
reporting the best of ``--repeat`` runs. For orientation it also times the pieces:
reading + deserialising only, the estimator alone on the same samples, and replay with the
--output bag and --csv written.

Decode only (bag on disk -> stamp/gyro/accel arrays of the Imu topic): the container read
alone (raw bytes, the ceiling), rosbags' per-message deserialisation (before) and the bulk
decoder of ``sins_align.cdr`` in chunks of ``replay.READ_CHUNK`` (after); and the decoding
alone on raw messages already in memory.
"""
from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sins_align import replay, simulate
from sins_align.bagio import deserialize, open_reader, read_message_chunks, read_messages
from sins_align.cdr import decode_imu_batch, reader_imu_layout
from sins_align.estimator import AlignConfig, Aligner
from sins_align.outputs import StampClock, imu_sample

IMU = "sensor_msgs/msg/Imu"


def best_of(repeat: int, fn) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=300.0, help="bag length, s (100 Hz)")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="bench_replay_") as tmp:
        d = Path(tmp)
        bag = d / "static_nav"
        t0 = time.perf_counter()
        simulate.main(["--latitude", "34", "--duration", str(args.duration), "--rate", "100",
                       "--compression", "zstd", "--seed", "1", str(bag)])
        t_sim = time.perf_counter() - t0
        n = int(round(args.duration * 100))
        size = sum(f.stat().st_size for f in bag.rglob("*") if f.is_file())

        k = [0]

        def run_replay(extra=()):
            k[0] += 1
            js = d / f"summary{k[0]}.json"
            rc = replay.main([str(bag), "--latitude", "34", "--summary-json", str(js), "--quiet",
                              *[a.format(i=k[0], d=d) for a in extra]])
            assert rc == 0
            return json.loads(js.read_text())

        t_e2e = best_of(args.repeat, run_replay)
        t_out = best_of(1, lambda: run_replay(["--output", "{d}/out{i}", "--csv", "{d}/a{i}.csv"]))

        samples = []

        def read_only():
            samples.clear()
            reader = open_reader(bag)
            try:
                conns = [c for c in reader.connections if c.topic == "/imu/data_raw"]
                clock = StampClock()
                for c, ns, raw in read_messages(reader, conns, bag):
                    samples.append(imu_sample(deserialize(reader, raw, c.msgtype, bag, ns),
                                              clock))
            finally:
                reader.close()

        t_read = best_of(args.repeat, read_only)

        # ---- decode only: bag on disk -> arrays (sec, nanosec, gyro, accel) ----
        raws = []

        def imu_reader():
            reader = open_reader(bag)
            return reader, [c for c in reader.connections if c.topic == "/imu/data_raw"]

        def raw_only():
            raws.clear()
            reader, conns = imu_reader()
            try:
                raws.extend(raw for _, _, raw in read_messages(reader, conns, bag))
            finally:
                reader.close()

        def to_arrays_rosbags(reader, items):
            m = [deserialize(reader, raw, c.msgtype, bag, ns) for c, ns, raw in items]
            return (np.array([x.header.stamp.sec for x in m], np.int64),
                    np.array([x.header.stamp.nanosec for x in m], np.int64),
                    np.array([(x.angular_velocity.x, x.angular_velocity.y,
                               x.angular_velocity.z) for x in m]),
                    np.array([(x.linear_acceleration.x, x.linear_acceleration.y,
                               x.linear_acceleration.z) for x in m]))

        decoded = {}

        def decode_from_bag(bulk: bool):
            def run():
                reader, conns = imu_reader()
                layout = reader_imu_layout(reader)
                assert layout == "ros2"
                parts = []
                try:
                    for chunk in read_message_chunks(reader, conns, bag, replay.READ_CHUNK):
                        if bulk:
                            b = decode_imu_batch([raw for _, _, raw in chunk], layout)
                            parts.append((b.sec, b.nanosec, b.gyro, b.accel))
                        else:
                            parts.append(to_arrays_rosbags(reader, chunk))
                finally:
                    reader.close()
                decoded[bulk] = [np.concatenate(p) for p in zip(*parts)]
            return run

        t_raw = best_of(args.repeat, raw_only)
        t_dec_before = best_of(args.repeat, decode_from_bag(False))
        t_dec_after = best_of(args.repeat, decode_from_bag(True))
        for a, b in zip(decoded[False], decoded[True]):
            assert np.array_equal(a, b), "bulk decoding differs from rosbags"
        assert len(decoded[True][0]) == n

        ts = open_reader(bag)
        try:
            store = ts.typestore
        finally:
            ts.close()
        t_mem_before = best_of(args.repeat, lambda: [store.deserialize_cdr(r, IMU)
                                                     for r in raws])
        t_mem_after = best_of(args.repeat, lambda: [
            decode_imu_batch(raws[k:k + replay.READ_CHUNK])
            for k in range(0, len(raws), replay.READ_CHUNK)])

        def estimator_only():
            al = Aligner(AlignConfig(latitude_deg=34.0))
            for t, w, f in samples:
                al.update(t, w, f)

        t_est = best_of(args.repeat, estimator_only)
        summary = run_replay()

    print(f"bench_replay: {platform.python_implementation()} {platform.python_version()}, "
          f"{platform.machine()}, numpy {np.__version__}")
    print(f"  bag: {n} sensor_msgs/Imu + {n} truth messages, 100 Hz, {args.duration:g} s, "
          f"mcap+zstd {size / 1e6:.2f} MB (simulate took {t_sim:.2f} s, "
          f"{2 * n / t_sim:,.0f} msg/s written)")
    print(f"  replay end to end (bag -> summary JSON), best of {args.repeat}: {t_e2e:.2f} s = "
          f"{n / t_e2e:,.0f} Imu msg/s = {n / t_e2e / 100:.0f}x real time")
    print(f"  replay with --output bag and --csv:            {t_out:.2f} s = "
          f"{n / t_out:,.0f} msg/s")
    print(f"  pieces: read + deserialise {n / t_read:,.0f} msg/s ({t_read:.2f} s), "
          f"estimator alone {n / t_est:,.0f} samples/s ({t_est:.2f} s)")
    print(f"  decode only, bag -> arrays (sec, nanosec, gyro, accel), best of {args.repeat}:")
    print(f"    container read, raw bytes only:   {n / t_raw:>12,.0f} msg/s ({t_raw:.3f} s)")
    print(f"    rosbags deserialize (before):     {n / t_dec_before:>12,.0f} msg/s "
          f"({t_dec_before:.3f} s)")
    print(f"    bulk decode_imu_batch (after):    {n / t_dec_after:>12,.0f} msg/s "
          f"({t_dec_after:.3f} s), identical arrays")
    print(f"  decoding alone, raw messages in memory: rosbags {n / t_mem_before:,.0f} msg/s, "
          f"bulk {n / t_mem_after:,.0f} msg/s ({t_mem_before / t_mem_after:.0f}x)")
    print(f"  result: aligned={summary['aligned']} after {summary['time_to_aligned_s']} s, "
          f"std E/N/U {', '.join(f'{x:.4f}' for x in summary['final']['std_enu_deg'])} deg")
    return 0


if __name__ == "__main__":
    sys.exit(main())
