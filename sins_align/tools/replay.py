"""Replay an IMU bag through the alignment estimator, exactly as align_node would run it.

Usage (stable interface)::

    python -m sins_align.tools.replay BAG [--topic /imu] [--latitude DEG] [--height M]
        [--model NAME] [--grade NAME] [--initial-rpy ROLL PITCH YAW] [--params align.yaml]
        [--output OUT_DIR] [--csv FILE] [--plot FILE.png] [--summary-json FILE]
        [--truth-topic TOPIC] [--force]

BAG is a rosbag2 bag (directory, .mcap or .db3; sqlite3 or mcap storage) or a ROS 1 ``.bag``.
``--topic`` may be left out when the bag holds exactly one ``sensor_msgs/Imu`` topic.

Same code path as the node: parameters come from the node's YAML file (``--params``, read by
:func:`sins_align.ros.params.load_params_yaml`; flags override it) and become an
:class:`~sins_align.estimators.quasi_static.AlignConfig` through
:func:`~sins_align.ros.params.config_from_params`; each message becomes a sample through
:func:`sins_align.ros.outputs.imu_sample` and one :class:`~sins_align.ros.outputs.StampClock`; every
published value comes from :mod:`sins_align.ros.outputs`. A replay therefore publishes the numbers
the live node publishes.

Outputs (each appears only when complete, nothing on Ctrl-C, SIGTERM or SIGHUP; an existing
path is an error unless ``--force``, which replaces a previous output of the same kind)
------------------------------------------------------------------------------------------
- ``--output``: a rosbag2 bag (mcap storage, zstd chunks) with the node's topics, resolved at
  root, stamped with data time (message time = header stamp, ns):

  * ``/imu/data`` (sensor_msgs/Imu): each input message the estimator did not reject (as the
    node, rejected samples are not republished) with orientation (C_b^n, IMU frame in ENU) and
    its covariance (attitude error phi about E, N, U, rad^2); header copied;
  * ``/alignment/aligned`` (std_msgs/Bool): false at the first sample, then on every change;
  * ``/alignment/euler_deg`` (geometry_msgs/Vector3Stamped): REP-103 roll, pitch, yaw, deg,
    at the first sample of every 0.1 s of data time (the node: a 10 Hz wall timer), with the
    header of the latest accepted sample;
  * ``/diagnostics`` (diagnostic_msgs/DiagnosticArray): at the first sample of every 1 s of
    data time, stamped with it (the node: 1 Hz wall timer, wall stamp), same status values.

  Also as the node: stamps far behind the last accepted one (more than ``max_gap``) three
  times in a row restart the alignment (a looped bag).
- ``--csv``: ``t`` (s since the first sample), ``qx, qy, qz, qw``, ``roll, pitch, yaw`` (deg,
  REP-103), ``heading`` (deg true, clockwise from North, of the IMU x axis), ``std_e, std_n,
  std_u`` (deg), ``aligned`` (0/1), ``stamp`` (header stamp, s); with ``--truth-topic`` also
  ``err_e, err_n, err_u`` (deg, phi of paper eq. 15 vs truth). One row per 0.1 s of data time
  (as /alignment/euler_deg: ``euler_rate`` from --params, default 10 Hz) plus the final sample.
- ``--plot``: PNG of attitude, std (with the limit accuracy) and error vs truth over time.
  Needs matplotlib (``pip install matplotlib``), checked before any work.
- ``--summary-json``: counts, timing, final attitude and std, config echo, limit accuracy,
  error vs truth.

With ``--truth-topic`` (``geometry_msgs/QuaternionStamped`` of the true C_b^n, as
imu_sim_node publishes on imu_sim/truth) the estimate is compared with the truth at the
same stamp (interpolated between neighbouring truth samples when stamps differ).

The bag is streamed: memory does not grow with its length (the estimator buffers at most
``backtrack_time`` seconds of samples; the plot keeps a decimated series). Two paths, same
results (test_bag_tools: attitude to 1e-9 rad, identical counts, times and flag changes):

- with ``--truth-topic`` (or the in-motion estimator, or a non-ROS 2 Imu layout), every
  message goes through :meth:`ReplaySession.on_imu` in bag order, one by one, as the node
  takes it (the Imu ones decoded in bulk by :mod:`sins_align.io.cdr` in chunks of
  :data:`READ_CHUNK`; ``/imu/data`` is the input's bytes with the orientation written in, as
  the node republishes);
- ``--output`` otherwise: :meth:`ReplaySession.on_imu_output_block`, blocks of messages with
  the estimator's outputs after each sample and its diagnostics view at the 1 Hz samples
  (:meth:`~sins_align.estimators.session.AlignmentSession.feed_block_states`), the node's
  messages in its order written in bulk (:class:`sins_align.io.mcapwrite.BulkWriter`);
  equal to the one-sample path to rounding (test_replay_output_block);
- otherwise (summary, ``--csv``, ``--plot``) the usual rosbag2 bags are opened without
  rosbags (:mod:`sins_align.io.fastbag`) and the Imu topic is read in blocks
  (:class:`sins_align.io.bagio.TopicBlocks`: MCAP chunks parsed and sliced with numpy, sqlite3
  windows aggregated by SQLite, rosbags for anything else), decoded in bulk and fed to the
  estimator :data:`READ_CHUNK` samples per
  :meth:`~sins_align.estimators.quasi_static.Aligner.update` (its fast path), cut only where the
  per-sample behaviour needs a sample alone or a boundary: a possible backward jump (the node's
  restart), a frame_id change and, for the CSV and the plot, the 10 Hz rows. With CSV/plot at 100 Hz
  those blocks are too short for the fast path (an order of magnitude slower than summary only;
  values identical to the per-sample path); from ~640 Hz they take it (values then equal to
  rounding).
"""
from __future__ import annotations

import argparse
import bisect
import csv as csv_mod
import itertools
import json
import math
import os
import sys
import time
from collections import deque
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from sins_align.io.bagio import (AtomicOutput, CliError, Messages, Progress, TopicBlocks,
                                 atomic_outputs, check_bag_dir_name, check_new_output,
                                 cli_main, deserialize, finite_or_none, need_matplotlib,
                                 one_line, open_reader, open_writer, pyplot, qos_profile,
                                 read_message_chunks, read_messages)
from sins_align.io.fastbag import FastBag, open_fast
from sins_align.io.msgdefs import DEFINITIONS
from sins_align.io.cdr import (IMU_TYPE, ImuBatch, ImuLayout, decode_imu_array,
                               decode_imu_batch, imu_with_orientations, reader_imu_layout,
                               diagnostic_array_cdr, vector3_stamped_cdr_many)
from sins_align.estimators.quasi_static import AlignConfig
from sins_align.estimators.session import AlignmentSession
from sins_align.ros.outputs import (StampClock, bias_estimates, euler_deg, imu_output,
                                    imu_output_values, imu_sample, motion_diagnostics,
                                    node_diagnostics)
from sins_align.io.velocity import NAVSAT_TYPE, VELOCITY_FRAMES, VELOCITY_TYPES
from sins_align.ros.params import (GRADE_REQUIRED, NODE_NAME, NODE_PARAMS, VEHICLES,
                                   VelocityReference, check_param, defaults, estimator_config,
                                   load_params_yaml, make_estimator, param_spec,
                                   velocity_reference)
from sins_align.ros.reference import VELOCITY_SILENCE, ReferenceFeed
from sins_align.core.rotation import (attitude_error, dcm_from_quat, heading_from_dcm,
                                     quat_from_dcm, rpy_from_dcm, so3_exp, so3_log)
from sins_align.core.specs import DEG, DPH, DPSH, UG, UG_PSHZ

PROG = "replay"

# The node's output topics (relative names in the node, resolved at root here).
IMU_OUT_TOPIC = "/imu/data"
ALIGNED_TOPIC = "/alignment/aligned"
EULER_TOPIC = "/alignment/euler_deg"
DIAG_TOPIC = "/diagnostics"
#: Publication periods in data time, ns (Euler: 1 / euler_rate, default 10 Hz).
EULER_RATE = param_spec("euler_rate", "node").default
EULER_PERIOD_NS = int(round(1e9 / EULER_RATE))
DIAG_PERIOD_NS = 1_000_000_000
#: DiagnosticStatus.name, as the node names it.
DIAG_NAME = f"{NODE_NAME}: alignment"

TRUTH_TYPE = "geometry_msgs/msg/QuaternionStamped"
#: std_msgs/Bool in ROS 2 CDR (little-endian), as rosbags serialises it (test_replay_output_block)
BOOL_CDR = {False: b"\x00\x01\x00\x00\x00", True: b"\x00\x01\x00\x00\x01"}
NS = 1_000_000_000

CSV_COLUMNS = ("t", "qx", "qy", "qz", "qw", "roll", "pitch", "yaw", "heading",
               "std_e", "std_n", "std_u", "aligned", "stamp")
CSV_TRUTH_COLUMNS = ("err_e", "err_n", "err_u")


# ----------------------------------------------------------------------------- arguments
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG, description="Replay a bag of sensor_msgs/Imu through the sins_align "
        "estimator (the same code and parameters as align_node) and write its outputs.")
    p.add_argument("bag", metavar="BAG", help="rosbag2 bag (dir, .mcap, .db3) or ROS 1 .bag")
    p.add_argument("--topic", help="sensor_msgs/Imu topic (default: the only one in the bag)")
    p.add_argument("--latitude", type=float, metavar="DEG", help="latitude, deg (required "
                   "here or in --params; in motion --navsat-topic can give it)")
    p.add_argument("--height", type=float, metavar="M", help="height above the ellipsoid, m")
    p.add_argument("--model", help="error model: constant, conventional or se3")
    p.add_argument("--grade", help="sensor grade preset: navigation, tactical or consumer (a "
                   "MEMS IMU); required, here or in --params, unless the four specs are given")
    p.add_argument("--initial-rpy", type=float, nargs=3, metavar=("ROLL", "PITCH", "YAW"),
                   help="initial REP-103 attitude of the IMU frame in ENU, deg")
    p.add_argument("--params", metavar="YAML", help="align_node parameter file "
                   f"(its '/**:' or '{NODE_NAME}:' section); flags override it")
    p.add_argument("--output", metavar="OUT_DIR", help="write the node's topics to this "
                   "rosbag2 (mcap) bag")
    p.add_argument("--csv", metavar="FILE", help="write the 10 Hz time series as CSV")
    p.add_argument("--plot", metavar="FILE.png", help="plot attitude and std (matplotlib)")
    p.add_argument("--summary-json", metavar="FILE", help="write the summary as JSON")
    p.add_argument("--truth-topic", metavar="TOPIC", help="geometry_msgs/QuaternionStamped "
                   "truth of C_b^n (e.g. /imu_sim/truth) to report the attitude error")
    v = p.add_argument_group(
        "in-motion alignment", "a velocity reference in the bag makes the replay run the "
        "in-motion estimator, as align_node with velocity_topic set (these flags override the "
        "same parameters of --params)")
    v.add_argument("--velocity-topic", metavar="TOPIC", help="velocity reference topic in the "
                   "bag (e.g. /gnss/fix_velocity)")
    v.add_argument("--velocity-type", choices=tuple(VELOCITY_TYPES),
                   help="its message type (default twist_with_covariance)")
    v.add_argument("--velocity-frame", choices=VELOCITY_FRAMES,
                   help="axis convention of its world frame (default enu)")
    v.add_argument("--lever-arm", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="IMU to antenna lever arm in the IMU frame, m")
    v.add_argument("--vehicle", choices=VEHICLES, help="vehicle kind (default air; ground "
                   "adds the non-holonomic constraint)")
    v.add_argument("--navsat-topic", metavar="TOPIC", help="sensor_msgs/NavSatFix topic in "
                   "the bag for latitude, longitude and height")
    p.add_argument("--quiet", action="store_true", help="no summary on stdout")
    p.add_argument("--force", action="store_true", help="replace outputs that exist (a previous "
                   "bag, CSV, plot or summary; each once the new one is complete)")
    return p


def params_from_args(args) -> tuple[dict[str, Any], dict[str, Any]]:
    """Alignment parameter values (node YAML, then the flags on top) and node-only ones.

    The node-only parameters of align_node (``euler_rate``, ``queue_size``) and ROS's
    ``use_sim_time`` may sit in the same YAML file; they are returned apart (``euler_rate``
    sets the data-time rate of /alignment/euler_deg and the CSV rows, as in the node).
    """
    values: dict[str, Any] = {}
    node_only: dict[str, Any] = {}
    if args.params:
        if not Path(args.params).is_file():
            raise CliError(f"parameters file {args.params} does not exist")
        try:
            loaded = load_params_yaml(args.params)
        except ValueError as e:
            raise CliError(one_line(e)) from None
        node_names = {p.name for p in NODE_PARAMS} | {"use_sim_time"}
        for k, v in loaded.items():
            (node_only if k in node_names else values)[k] = v
        lat = values.get("latitude")
        if isinstance(lat, float) and math.isnan(lat):
            raise CliError(f"latitude in {args.params} must be a finite number, got nan")
    for flag, name in (("latitude", "latitude"), ("height", "height"), ("model", "model"),
                       ("grade", "grade")):
        v = getattr(args, flag)
        if v is not None:
            values[name] = v
    for flag in ("latitude", "height"):
        v = getattr(args, flag)
        if v is not None and not math.isfinite(v):
            raise CliError(f"--{flag} must be a finite number, got {v}")
    if args.initial_rpy is not None:
        values["initial_rpy"] = [float(a) for a in args.initial_rpy]
    for flag, name in (("velocity_topic", "velocity_topic"), ("velocity_type", "velocity_type"),
                       ("velocity_frame", "velocity_frame"), ("vehicle", "vehicle"),
                       ("navsat_topic", "navsat_topic")):
        v = getattr(args, flag)
        if v is not None:
            values[name] = v
    if args.lever_arm is not None:
        if not all(math.isfinite(x) for x in args.lever_arm):
            raise CliError(f"--lever-arm must be finite numbers, got "
                           f"{' '.join(map(str, args.lever_arm))}")
        values["lever_arm"] = [float(x) for x in args.lever_arm]
    reason = check_param("euler_rate", node_only.get("euler_rate", EULER_RATE), "node")
    if reason:
        raise CliError(f"bad parameters: {reason}")
    return values, node_only


def config_or_error(values: dict[str, Any]):
    """The estimator's configuration (an AlignConfig, or a MotionConfig when a velocity
    topic is set), or a CliError naming the bad parameter."""
    lat = values.get("latitude")
    if lat is None or (isinstance(lat, float) and math.isnan(lat)):
        if not (values.get("velocity_topic") and values.get("navsat_topic")):
            raise CliError("latitude is required: pass --latitude DEG or set latitude in "
                           "--params (in motion, --navsat-topic can give it)")
        values = {**values, "latitude": math.nan}      # the first fix gives it
    try:
        return estimator_config(values)
    except ValueError as e:
        if str(e) == GRADE_REQUIRED:
            raise CliError("grade is required: pass --grade navigation|tactical|consumer (a "
                           "MEMS IMU: consumer); a grade better than the IMU's makes the "
                           "published covariance lie") from None
        raise CliError(f"bad parameters: {one_line(e)}") from None


def reference_or_error(values: dict[str, Any]) -> VelocityReference:
    """The velocity reference of the parameters, its topic resolved at root as the node's
    relative name would be (``gnss/fix_velocity`` -> ``/gnss/fix_velocity``)."""
    try:
        ref = velocity_reference(values)
    except ValueError as e:
        raise CliError(f"bad parameters: {one_line(e)}") from None
    return VelocityReference(_at_root(ref.topic), ref.type, ref.frame, _at_root(ref.navsat_topic))


def _at_root(topic: str) -> str:
    return topic if not topic or topic.startswith("/") else "/" + topic


def merged_params(values: dict[str, Any]) -> dict[str, Any]:
    m = defaults()
    m.update(values)
    return m


# ----------------------------------------------------------------------------- helpers
class Ticker:
    """True at the first stamp of every ``period_ns`` bin of data time (a data-time timer)."""

    def __init__(self, period_ns: int):
        self.period = int(period_ns)
        self._bin: int | None = None

    def due(self, ns: int) -> bool:
        b = ns // self.period
        if b == self._bin:
            return False
        self._bin = b
        return True

    def due_block(self, ns: np.ndarray) -> np.ndarray:
        """:meth:`due` for each stamp of ``ns`` (int64, in order), as a boolean array."""
        bins = ns // self.period
        due = np.empty(len(ns), dtype=bool)
        due[0] = self._bin is None or bins[0] != self._bin
        np.not_equal(bins[1:], bins[:-1], out=due[1:])
        self._bin = int(bins[-1])
        return due


class TruthMatcher:
    """Matches estimates to truth samples by stamp, streaming, in bounded memory.

    Truth samples (ns, C_b^n) are kept for ``keep_s`` seconds of stamps. A query waits until
    truth at or after its stamp has arrived, then takes the truth at the same stamp or
    interpolates (SO(3)) between the two neighbours when they are at most ``max_gap_s``
    apart; at the edges the nearest truth within ``edge_tol_s`` is used, else no match.
    """

    def __init__(self, keep_s: float = 5.0, max_gap_s: float = 1.0, edge_tol_s: float = 0.5,
                 wait_s: float = 2.0):
        self.ns: deque[int] = deque()
        self.C: deque[np.ndarray] = deque()
        self.pending: deque[tuple[int, Any]] = deque()
        self.keep = int(keep_s * NS)
        self.max_gap = int(max_gap_s * NS)
        self.edge_tol = int(edge_tol_s * NS)
        self.wait = int(wait_s * NS)
        self.count = 0

    def add_truth(self, ns: int, C: np.ndarray):
        if self.ns and ns <= self.ns[-1]:
            if ns == self.ns[-1]:
                return
            # out of order: insert (rare; keeps the deque sorted)
            i = bisect.bisect_left(list(self.ns), ns)
            self.ns.insert(i, ns)
            self.C.insert(i, C)
        else:
            self.ns.append(ns)
            self.C.append(C)
        self.count += 1
        while len(self.ns) > 2 and self.ns[0] < self.ns[-1] - self.keep:
            self.ns.popleft()
            self.C.popleft()

    def query(self, ns: int, payload) -> list:
        """Queue a query; returns the queries resolved so far [(payload, C_true | None)]."""
        self.pending.append((ns, payload))
        return self.resolve(ns)

    def resolve(self, now_ns: int, final: bool = False) -> list:
        done = []
        while self.pending:
            ns, payload = self.pending[0]
            ready = final or (self.ns and self.ns[-1] >= ns) or now_ns - ns > self.wait
            if not ready:
                break
            self.pending.popleft()
            done.append((payload, self.lookup(ns)))
        return done

    def lookup(self, ns: int) -> np.ndarray | None:
        if not self.ns:
            return None
        stamps = self.ns
        i = bisect.bisect_left(stamps, ns)
        if i < len(stamps) and stamps[i] == ns:
            return self.C[i]
        if 0 < i < len(stamps):
            t0, t1 = stamps[i - 1], stamps[i]
            if t1 - t0 <= self.max_gap:
                a = (ns - t0) / (t1 - t0)
                C0, C1 = self.C[i - 1], self.C[i]
                return C0 @ so3_exp(a * so3_log(C0.T @ C1))
        j = min(range(max(i - 1, 0), min(i + 1, len(stamps))), key=lambda k: abs(stamps[k] - ns))
        return self.C[j] if abs(stamps[j] - ns) <= self.edge_tol else None


class DecimatedSeries:
    """Rows for the plot, at most ``2 * max_rows``: halves its resolution when full."""

    def __init__(self, max_rows: int = 10000):
        self.max_rows = max_rows
        self.rows: list[tuple] = []
        self.stride = 1
        self._n = 0

    def add(self, row: tuple, force: bool = False):
        if force or self._n % self.stride == 0:
            self.rows.append(row)
            if len(self.rows) >= 2 * self.max_rows:
                self.rows = self.rows[::2]
                self.stride *= 2
        self._n += 1


def _stamp_ns(msg) -> int:
    st = msg.header.stamp
    return int(st.sec) * NS + int(st.nanosec)


# ----------------------------------------------------------------------------- the session
class ReplaySession:
    """Runs the estimator over Imu messages and produces the node's outputs.

    Feed :meth:`on_imu` (and :meth:`on_truth`) in bag order, then call :meth:`finish`; or,
    with ``block=True`` (no bag output, no truth), feed :meth:`on_imu_block` with the Imu
    messages decoded in bulk.
    """

    def __init__(self, config, writer=None, csv_file=None, with_truth=False,
                 keep_plot=False, euler_period_ns: int = EULER_PERIOD_NS, block: bool = False,
                 reference: VelocityReference | None = None):
        if block and (writer is not None or with_truth):
            raise ValueError("the block path writes no bag and takes no truth")
        self.config = config
        self.block = block
        self.al = make_estimator(config)
        #: in-motion alignment (a velocity reference): the estimator's extras are read
        #: through its public interface only
        self.motion = reference is not None and reference.enabled
        self.reference = reference
        self.session = AlignmentSession(self.al, record_flag_changes=block)
        self.clock = StampClock()
        self.feed = ReferenceFeed(self.session, reference, self.clock) if self.motion else None
        #: reference messages not fed yet: (header stamp ns, 'velocity' | 'navsat', msg),
        #: in stamp order (:meth:`add_references`)
        self._refs: deque = deque()
        self._last_velocity_ns: int | None = None
        #: the estimator estimates its biases (the in-motion one): reported in the summary
        self._has_biases = hasattr(self.al, "bias_gyro")
        self._msgs: Messages | None = None        # rosbags' messages, made when needed
        #: /imu/data from the input bytes (``on_imu``'s ``raw``); False: built by rosbags
        self.bytes_output = True
        self.out_layout: ImuLayout | None = None
        self.writer = writer
        self.with_truth = with_truth
        self.truth = TruthMatcher() if with_truth else None
        self.series = DecimatedSeries() if keep_plot else None
        self.euler_tick = Ticker(euler_period_ns)
        self.diag_tick = Ticker(DIAG_PERIOD_NS)
        self.samples = 0
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        self.last_header: tuple[int, int, str] | None = None   # of the last accepted sample
        self.last_frame_id = ""                                 # of the last accepted sample
        self._aligned_pub: bool | None = None    # the block path's last flag change
        self._rejected_seen = 0
        self._reset_reason = ""        # the session's last_reset_reason after the last block
        self._diag_prev: tuple[int, int] | None = None     # (ns, samples) at the last diag
        self.aligned_changes: list[tuple[float, bool]] = []
        self.final_error: np.ndarray | None = None
        self.final_truth: np.ndarray | None = None
        self.max_err_after_aligned = np.zeros(3)
        self.truth_matched = 0
        self.truth_unmatched = 0
        self._last_row_ns: int | None = None
        #: how the bag was read: (path, why rosbags read it or None)
        self.reading: tuple[str, str | None] = ("", None)
        self._csv = None
        if csv_file is not None:
            self._csv = csv_mod.writer(csv_file, lineterminator="\n")
            self._csv.writerow(CSV_COLUMNS + (CSV_TRUTH_COLUMNS if with_truth else ()))
        if writer is not None:
            def connection(topic, msgtype, **qos):
                msgdef, rihs01 = DEFINITIONS[msgtype]
                return writer.add_connection(topic, msgtype, msgdef=msgdef, rihs01=rihs01,
                                             offered_qos_profiles=[qos_profile(**qos)])
            self.c_imu = connection(IMU_OUT_TOPIC, Messages.IMU)
            self.c_aligned = connection(ALIGNED_TOPIC, Messages.BOOL, transient_local=True,
                                        depth=1)
            self.c_euler = connection(EULER_TOPIC, Messages.VECTOR3_STAMPED)
            self.c_diag = connection(DIAG_TOPIC, Messages.DIAGNOSTIC_ARRAY)

    @property
    def msgs(self) -> Messages:
        """rosbags' message types (its typestore loads on first use)."""
        if self._msgs is None:
            self._msgs = Messages()
        return self._msgs

    # -- input ---------------------------------------------------------------------------
    def add_references(self, items) -> None:
        """Velocity-reference and NavSatFix messages ``[(header stamp ns, 'velocity' |
        'navsat', msg)]`` in stamp order. Each is fed to the estimator before the first IMU
        sample whose stamp is not earlier than its own (a merge by header stamp: what the node
        does when the messages come in stamp order); those after the last sample at
        :meth:`finish`."""
        self._refs.extend(items)

    def _feed_refs(self, until_ns: float) -> None:
        """Feed the reference messages stamped at or before ``until_ns``."""
        refs, feed = self._refs, self.feed
        while refs and refs[0][0] <= until_ns:
            ns, kind, msg = refs.popleft()
            if kind == "velocity":
                self._last_velocity_ns = ns
                feed.on_velocity(msg)
            else:
                feed.on_navsat(msg)

    def on_imu(self, msg, raw: bytes | None = None):
        """One sensor_msgs/Imu message (rosbags object, ROS 1 or ROS 2 layout); ``raw``: its
        ROS 2 CDR bytes, if known (the /imu/data output is then these bytes with the
        orientation written in, as the node republishes them, instead of a message built
        and serialised by rosbags: the same bytes, test_replay_output).

        The data path of align_node's ``_on_imu``: stamps far behind the last accepted one
        several times in a row restart the alignment; accepted samples (and the first one)
        are republished with the orientation, rejected ones are not; the aligned flag is
        published when it changes.
        """
        al = self.al
        ns = _stamp_ns(msg)
        if self._refs:
            self._feed_refs(ns)
        accepted = self.session.feed(*imu_sample(msg, self.clock))
        self.samples += 1
        if self.first_ns is None:
            self.first_ns = ns
        self.last_ns = ns
        wr = self.writer
        if accepted:
            st = msg.header.stamp
            self.last_header = (int(st.sec), int(st.nanosec), msg.header.frame_id)
            self.last_frame_id = msg.header.frame_id
            if wr is not None:
                self._publish_imu(msg, ns, raw)
        self._publish_aligned(ns)
        tick = self.euler_tick.due(ns)
        if wr is not None:
            if tick and self.last_header is not None and al.t_last is not None:
                wr.write(self.c_euler, ns, self.msgs.serialize(self.msgs.vector3_stamped(
                    self.msgs.header(*self.last_header), euler_deg(al))))
            if self.diag_tick.due(ns):
                self._publish_diagnostics(ns)
        if tick and (self._csv is not None or self.series is not None
                     or self.truth is not None):      # rows only where they are kept
            self._row(ns)
        if self.truth is not None:
            self._take(self.truth.resolve(ns))

    def on_imu_block(self, batch: "ImuBatch | ImuSamples"):
        """Imu messages decoded in bulk, in bag order (``block=True``): what :meth:`on_imu`
        does for each, with the estimator fed whole runs of samples.

        Stamps become seconds through the same :class:`StampClock` arithmetic. The block is
        cut (each piece one :meth:`Aligner.update` call, which takes its clean runs on the
        fast path) before and after every sample that could be far behind the last accepted
        stamp (handled alone, exactly as :meth:`on_imu`: the node's restart on a backward
        jump), wherever the frame_id changes (so the frame of the last accepted sample is
        known from the rejection counts), and, when CSV rows or the plot are kept, after the
        first sample of every ``euler_period`` of data time (the row is taken there, after
        that sample, as :meth:`on_imu` does). Changes of the aligned flag are placed at their
        sample from the stamps of the session's flag changes.
        """
        if not self.block:
            raise RuntimeError("on_imu_block needs a session made with block=True")
        n = len(batch)
        if n == 0:
            return
        sec, nsec = batch.sec, batch.nanosec
        ns = sec * NS + nsec
        if self._refs:                  # those before the first sample set the clock first
            self._feed_refs(int(ns[0]))
        if self.clock.epoch is None:
            self.clock(int(sec[0]), int(nsec[0]))
        # StampClock.__call__, element-wise: float(sec - epoch) + nanosec * 1e-9
        t = (sec - self.clock.epoch).astype(np.float64) + nsec.astype(np.float64) * 1e-9
        w, f = batch.gyro, batch.accel
        if self.first_ns is None:
            self.first_ns = int(ns[0])
        cut = np.zeros(n + 1, dtype=bool)
        cut[0] = cut[n] = True
        due = self.euler_tick.due_block(ns)
        rows = self._csv is not None or self.series is not None
        # rows from the estimator's outputs after each sample (no cut: its fast path), or,
        # for an estimator without them, blocks cut after each row's sample
        states = rows and hasattr(self.al, "update_states")
        if rows and not states:
            cut[np.flatnonzero(due) + 1] = True
        frames = batch.frame_id
        if frames.count(frames[0]) != n:
            for i in range(1, n):
                if frames[i] != frames[i - 1]:
                    cut[i] = True
        reach, ahead = None, False
        if self._refs:      # each before the first sample whose stamp is not earlier
            reach = np.maximum.accumulate(ns)           # (as on_imu, stamps out of order too)
            last = int(reach[-1])
            refs = list(itertools.takewhile(lambda r: r[0] <= last, self._refs))
            # Velocities are applied at their stamps wherever they come from: on a clean
            # piece (stamps increasing, no gap that restarts the estimator and clears what
            # it holds) those of a whole piece go in before it, and the in-motion estimator
            # sums the runs between them at once. A position is applied on arrival: cut there.
            d = np.diff(t)
            ahead = bool(self.motion and np.all(d > 0)
                         and not np.any(d > self.al.config.max_gap))
            stamps = [r[0] for r in refs if not (ahead and r[1] == "velocity")]
            cut[np.searchsorted(reach, np.array(stamps, dtype=np.int64), side="left")] = True
        bounds = np.flatnonzero(cut).tolist()
        for a, b in zip(bounds, bounds[1:]):
            if reach is not None:
                self._feed_refs(int(reach[b - 1] if ahead else reach[a]))
            before = self.al.aligned
            if states:
                st = self.session.feed_block_states(t[a:b], w[a:b], f[a:b], due[a:b])
                accepted = bool(st.accepted.any())
            else:
                accepted = self.session.feed_block(t[a:b], w[a:b], f[a:b])
            if accepted:
                self.last_frame_id = frames[a]
            self.samples += b - a
            self.last_ns = int(ns[b - 1])
            self._publish_flips(self.session.take_flag_changes(), before, t[a:b], ns[a:b])
            if states:
                self._rows_from_states(st, np.flatnonzero(due[a:b]), ns[a:b])
            elif rows and due[b - 1]:
                self._row(self.last_ns)

    def on_imu_output_block(self, batch: ImuBatch, mb):
        """Imu messages decoded in bulk (``batch``) with their bytes (``mb``: a
        :class:`~sins_align.io.bagio.MessageBlock`), in bag order, for ``--output``: what
        :meth:`on_imu` writes for each, in the same order (per sample: /imu/data if
        accepted, the aligned flag if changed, the Euler angles, the diagnostics), from the
        estimator's outputs after each sample
        (:meth:`~sins_align.estimators.session.AlignmentSession.feed_block_states`, whose
        ``views`` give the diagnostics their estimator state at their sample). Needs the
        quasi-static Aligner (``update_states``) and ROS 2 messages."""
        n = len(batch)
        if n == 0:
            return
        sec, nsec = batch.sec, batch.nanosec
        ns = sec * NS + nsec
        if self.clock.epoch is None:
            self.clock(int(sec[0]), int(nsec[0]))
        t = (sec - self.clock.epoch).astype(np.float64) + nsec.astype(np.float64) * 1e-9
        if self.first_ns is None:
            self.first_ns = int(ns[0])
        euler_due = self.euler_tick.due_block(ns)
        diag_due = self.diag_tick.due_block(ns)
        st = self.session.feed_block_states(t, np.ascontiguousarray(batch.gyro),
                                            np.ascontiguousarray(batch.accel), None, diag_due)
        restarts = self.session.block_restarts
        acc = st.accepted
        acc_idx = np.flatnonzero(acc)
        last_acc = np.maximum.accumulate(np.where(acc, np.arange(n), -1))
        frames = batch.frame_id
        ns_l = ns.tolist()
        samples0 = self.samples
        # per topic: (the samples they follow, the topic's rank in the node's order,
        # connection, their bytes)
        parts: list[tuple[np.ndarray, int, Any, list]] = []
        # /imu/data: the input's bytes with the orientation written in
        if len(acc_idx):
            C = st.dcm[acc_idx]
            vals = np.concatenate((quat_from_dcm(C), st.covariance[acc_idx].reshape(-1, 9)), 1)
            datas = imu_with_orientations(mb.buf, mb.starts[acc_idx], mb.sizes[acc_idx], vals)
            if self.out_layout is None:
                self.out_layout = ImuLayout.of(mb.raw(int(acc_idx[0])))
            if None in datas:               # no CDR layout recognised: built by rosbags
                m = self.msgs
                msgs = list(batch.messages())
                for k in [k for k, d in enumerate(datas) if d is None]:
                    q = vals[k]
                    j = int(acc_idx[k])
                    msg = msgs[j]
                    w, a = msg.angular_velocity, msg.linear_acceleration
                    datas[k] = m.serialize(m.imu(
                        m.header(int(sec[j]), int(nsec[j]), frames[j]), q[:4], q[4:],
                        (w.x, w.y, w.z), msg.angular_velocity_covariance, (a.x, a.y, a.z),
                        msg.linear_acceleration_covariance))
            parts.append((acc_idx, 0, self.c_imu, datas))
        # the aligned flag, when it changes
        flips = self.session.flags_to_publish(st.aligned)
        if len(flips):
            for j in flips.tolist():
                self.aligned_changes.append(((ns_l[j] - self.first_ns) / NS,
                                             bool(st.aligned[j])))
            parts.append((flips, 1, self.c_aligned,
                          [BOOL_CDR[bool(v)] for v in st.aligned[flips]]))
        prev_header = self.last_header

        def header_at(j):
            i = int(last_acc[j])
            if i < 0:
                return prev_header
            return (int(sec[i]), int(nsec[i]), frames[i])
        # Euler angles at the 10 Hz ticks, once a sample was accepted and time runs: the
        # header of the last accepted sample (before the block's first: the one before)
        eu = np.flatnonzero(euler_due & st.started)
        li = last_acc[eu]
        if prev_header is None:
            eu, li = eu[li >= 0], li[li >= 0]
        if len(eu):
            rpy = rpy_from_dcm(st.dcm[eu]) / DEG
            own = li >= 0
            es = np.where(own, sec[np.maximum(li, 0)], prev_header[0] if prev_header else 0)
            en = np.where(own, nsec[np.maximum(li, 0)], prev_header[1] if prev_header else 0)
            ef = [frames[i] if i >= 0 else prev_header[2] for i in li.tolist()]
            datas = [b""] * len(eu)
            for fr in dict.fromkeys(ef):        # (one, unless the frame_id changed)
                sel = np.flatnonzero([x == fr for x in ef])
                for k, d in zip(sel.tolist(), vector3_stamped_cdr_many(
                        es[sel], en[sel], fr, rpy[sel])):
                    datas[k] = d
            parts.append((eu, 2, self.c_euler, datas))
        # diagnostics at the 1 Hz ticks, from the estimator's state after their sample
        ri = 0
        resets, reason = self.session.resets, self.session.last_reset_reason
        if restarts:        # the values before the first restart of the block
            resets, reason = restarts[0][1] - 1, self._reset_reason
        dg = np.flatnonzero(diag_due)
        if len(dg):
            datas = []
            for j in dg.tolist():
                while ri < len(restarts) and restarts[ri][0] <= j:
                    resets, reason = restarts[ri][1], restarts[ri][2]
                    ri += 1
                h = header_at(j)
                datas.append(self._diagnostics_bytes(
                    st.views[j], ns_l[j], samples0 + j + 1, resets, reason, h[2] if h else ""))
            parts.append((dg, 3, self.c_diag, datas))
        self._reset_reason = self.session.last_reset_reason
        # the node's order: by sample, then imu, aligned, euler, diagnostics
        if parts:
            key = np.concatenate([4 * idx + rank for idx, rank, _, _ in parts])
            datas = [d for _, _, _, ds in parts for d in ds]
            cid = np.concatenate([np.full(len(ds), i) for i, (_, _, _, ds) in
                                  enumerate(parts)])
            if len(parts) > 1:
                order = np.argsort(key, kind="stable")
                key, cid = key[order], cid[order]
                datas = [datas[i] for i in order.tolist()]
            conns = [parts[i][2] for i in cid.tolist()]
            stamps = ns[key // 4]
            if hasattr(self.writer, "write_many"):
                self.writer.write_many(conns, stamps, datas)
            else:
                for conn, st_ns, data in zip(conns, stamps.tolist(), datas):
                    self.writer.write(conn, st_ns, data)
        self.samples += n
        self.last_ns = int(ns[-1])
        if len(acc_idx):
            i = int(acc_idx[-1])
            self.last_header = (int(sec[i]), int(nsec[i]), frames[i])
            self.last_frame_id = frames[i]
        if self._csv is not None or self.series is not None:
            self._rows_from_states(st, np.flatnonzero(euler_due), ns)

    def _publish_flips(self, flips, before: bool, t: np.ndarray, ns: np.ndarray):
        """aligned_changes of one update call, as :meth:`_publish_aligned` after each sample."""
        events: list[tuple[int, bool]] = []        # (sample, flag after it)
        j0 = 0
        for t_flip, state in flips:
            hit = np.flatnonzero(t[j0:] == t_flip)
            j = j0 + int(hit[0]) if len(hit) else len(t) - 1
            if events and events[-1][0] == j:
                events[-1] = (j, state)
            else:
                events.append((j, state))
            j0 = j
        if self._aligned_pub is None and (not events or events[0][0] != 0):
            events.insert(0, (0, before))
        # a change the hooks did not place (a restart before a lone sample): after the last
        if self.al.aligned != (events[-1][1] if events else self._aligned_pub):
            events.append((len(t) - 1, self.al.aligned))
        for j, state in events:
            if state != self._aligned_pub:
                self._aligned_pub = state
                self.aligned_changes.append(((int(ns[j]) - self.first_ns) / NS, state))

    def on_truth(self, msg):
        q = msg.quaternion
        self.truth.add_truth(_stamp_ns(msg), dcm_from_quat(np.array([q.x, q.y, q.z, q.w])))
        if self.last_ns is not None:
            self._take(self.truth.resolve(self.last_ns))

    # -- node outputs ----------------------------------------------------------------------
    def _publish_imu(self, msg, ns: int, raw: bytes | None = None):
        if raw is not None and self.bytes_output:
            lay = self.out_layout
            if lay is None or not lay.matches(raw):
                lay = self.out_layout = ImuLayout.of(raw)
            if lay is not None:
                self.writer.write(self.c_imu, ns,
                                  lay.with_orientation(raw, imu_output_values(self.al)))
                return
        m = self.msgs
        out = imu_output(self.al)
        w, a = msg.angular_velocity, msg.linear_acceleration
        imu = m.imu(m.header(*self.last_header), out.orientation_xyzw,
                    out.orientation_covariance, (w.x, w.y, w.z), msg.angular_velocity_covariance,
                    (a.x, a.y, a.z), msg.linear_acceleration_covariance)
        self.writer.write(self.c_imu, ns, m.serialize(imu))

    def _publish_aligned(self, ns: int):
        value = self.session.flag_to_publish()
        if value is None:
            return
        self.aligned_changes.append(((ns - self.first_ns) / NS, value))
        if self.writer is not None:
            self.writer.write(self.c_aligned, ns, self.msgs.serialize(self.msgs.bool(value)))

    def _diagnostics_bytes(self, view, ns: int, samples: int, resets: int, reason: str,
                           frame: str) -> bytes:
        """:meth:`_publish_diagnostics`'s message (quasi-static estimator) from a view of the
        estimator after the sample (its ``view()``), the samples counted then, the
        restarts then and the frame of the last accepted sample."""
        rate = None
        if self._diag_prev is not None and ns > self._diag_prev[0]:
            rate = (samples - self._diag_prev[1]) / ((ns - self._diag_prev[0]) / NS)
        self._diag_prev = (ns, samples)
        level, text, values, self._rejected_seen = node_diagnostics(
            view, rate, self._rejected_seen, resets, reason)
        sec, nsec = divmod(ns, NS)
        return diagnostic_array_cdr(sec, nsec, frame, [(level, DIAG_NAME, text, frame, values)])

    def _publish_diagnostics(self, ns: int):
        """align_node's diagnostics, with data time for the rate and the stamp."""
        al, m = self.al, self.msgs
        rate = None
        if self._diag_prev is not None and ns > self._diag_prev[0]:
            rate = (self.samples - self._diag_prev[1]) / ((ns - self._diag_prev[0]) / NS)
        self._diag_prev = (ns, self.samples)
        if self.motion:
            # the node's silence check in data time: no velocity stamp for VELOCITY_SILENCE s
            last = max(self.first_ns, self._last_velocity_ns or self.first_ns)
            silent = (ns - last) / NS
            level, text, values, self._rejected_seen = motion_diagnostics(
                al, rate, self._rejected_seen, self.session.resets,
                self.session.last_reset_reason, self.feed, self.reference.topic,
                silent if silent > VELOCITY_SILENCE else None)
        else:
            level, text, values, self._rejected_seen = node_diagnostics(
                al, rate, self._rejected_seen, self.session.resets,
                self.session.last_reset_reason)
        frame = self.last_header[2] if self.last_header else ""
        sec, nsec = divmod(ns, NS)
        arr = m.diagnostic_array(m.header(sec, nsec, frame),
                                 [(level, DIAG_NAME, text, frame, values)])
        self.writer.write(self.c_diag, ns, m.serialize(arr))

    # -- time series -----------------------------------------------------------------------
    def _row(self, ns: int, force: bool = False):
        al = self.al
        self._last_row_ns = ns
        q = al.quaternion
        rpy = al.rpy_deg
        std = al.std_enu_deg
        row = ((ns - self.first_ns) / NS, q, rpy, al.heading_deg, std, al.aligned, ns)
        if self.truth is not None:
            self._take(self.truth.query(ns, (row, al.dcm.copy())))
        else:
            self._emit(row, None, force)

    def _rows_from_states(self, st, at: np.ndarray, ns: np.ndarray):
        """The rows :meth:`_row` takes after the samples ``at`` of a block, from the
        estimator's outputs after each (``st``: its SampleStates)."""
        if not len(at):
            return
        C, P = st.dcm[at], st.covariance[at]
        q = quat_from_dcm(C)
        rpy = rpy_from_dcm(C) / DEG
        heading = (heading_from_dcm(C) / DEG).tolist()
        std = np.sqrt(np.einsum("nii->ni", P)) / DEG
        for i, j in enumerate(at.tolist()):
            n = int(ns[j])
            self._last_row_ns = n
            self._emit(((n - self.first_ns) / NS, q[i], rpy[i], heading[i], std[i],
                        bool(st.aligned[j]), n), None)

    def _take(self, resolved):
        for (row, C_est), C_true in resolved:
            err = None
            if C_true is not None:
                err = attitude_error(C_true, C_est) / DEG
                self.truth_matched += 1
                if row[5]:
                    self.max_err_after_aligned = np.maximum(self.max_err_after_aligned,
                                                            np.abs(err))
                if row[6] == self.last_ns:
                    self.final_error = err
                    self.final_truth = rpy_from_dcm(C_true) / DEG
            else:
                self.truth_unmatched += 1
            self._emit(row, err, row[6] == self.last_ns)

    def _emit(self, row, err, force=False):
        t, q, rpy, heading, std, aligned, ns = row
        if self._csv is not None:
            vals = [f"{t:.9f}", *(f"{x:.12g}" for x in q), *(f"{x:.9g}" for x in rpy),
                    f"{heading:.9g}", *(f"{x:.6g}" for x in std), str(int(aligned)),
                    f"{ns // NS}.{ns % NS:09d}"]
            if self.with_truth:
                vals += [f"{x:.6g}" for x in err] if err is not None else ["", "", ""]
            self._csv.writerow(vals)
        if self.series is not None:
            e = tuple(err) if err is not None else (math.nan,) * 3
            self.series.add((t, *rpy, heading, *std, *e), force=force)

    # -- end ---------------------------------------------------------------------------------
    def finish(self):
        """Final sample row (if not on a tick) and the pending truth matches; then the
        reference messages stamped after the last sample (the node receives them too)."""
        if self.samples == 0:
            return
        if self._last_row_ns != self.last_ns:
            self._row(self.last_ns, force=True)
        if self.truth is not None:
            self._take(self.truth.resolve(self.last_ns, final=True))
        if self._refs:
            self._feed_refs(math.inf)

    def summary(self, config_echo: dict[str, Any]) -> dict[str, Any]:
        al = self.al
        s = al.summary()
        if self.motion:
            # the in-motion estimator's public interface; what it does not report is None
            tta = s.get("time_to_aligned_s", next(
                (t for t, a in self.aligned_changes if a), None))
            used = s.get("samples_used")
            stage = s.get("stage")
        else:
            tta, used, stage = al.time_to_aligned, al.samples_used, al.stage
        out: dict[str, Any] = {
            "samples": self.samples,
            "samples_used": used,
            "rejected": dict(al.rejected),
            "events": dict(al.events),
            "duration_s": (self.last_ns - self.first_ns) / NS,
            "aligned": bool(al.aligned),
            "time_to_aligned_s": tta,
            "status": al.status,
            "resets": self.session.resets,
            "stage": stage,
            "heading_observable": bool(al.heading_observable),
            "aligned_changes": [{"t_s": t, "aligned": a} for t, a in self.aligned_changes],
            "final": {
                "stamp_s": self.last_ns / NS,
                "frame_id": self.last_frame_id,
                "orientation_xyzw": np.asarray(al.quaternion, dtype=float).tolist(),
                "rpy_deg": np.asarray(al.rpy_deg, dtype=float).tolist(),
                "heading_deg": float(al.heading_deg),
                "std_enu_deg": np.asarray(al.std_enu_deg, dtype=float).tolist(),
                "covariance_enu_rad2": np.asarray(al.covariance).reshape(-1).tolist(),
                "heading_observable": bool(al.heading_observable),
            },
            "config": config_echo,
            "limit_std_enu_deg": s.get("limit_std_enu_deg"),
            "fine_velocity_noise_mps": s.get("fine_velocity_noise_mps"),
            "nis": s.get("nis"),
            "gyro_noise_ratio": s.get("gyro_noise_ratio"),
            "specs_consistent": s.get("specs_consistent"),
        }
        if self._has_biases:
            bg, ba = bias_estimates(al)
            out["final"]["bias_gyro_dph"] = bg
            out["final"]["bias_accel_mg"] = ba
        if self.motion:
            ref = self.reference
            out["velocity_reference"] = {
                "topic": ref.topic, "type": ref.type, "frame": ref.frame,
                "navsat_topic": ref.navsat_topic or None, **self.feed.counts()}
            out["final"]["velocity_enu_mps"] = np.asarray(al.velocity, dtype=float).tolist()
            out["final"]["velocity_latency_s"] = al.velocity_latency
            out["final"]["reference_consistent"] = bool(al.reference_consistent)
            out["final"]["velocity_noise_scale"] = float(al.noise_scale)
            if al.config.vehicle == "ground":
                out["final"]["nhc_lever_arm_m"] = np.asarray(al.nhc_lever_arm,
                                                             dtype=float).tolist()
                out["final"]["nhc_mount_deg"] = np.degrees(al.nhc_mount).tolist()
        if self.truth is not None:
            fin = out["final"]
            fin["error_enu_deg"] = None if self.final_error is None else self.final_error.tolist()
            fin["truth_rpy_deg"] = None if self.final_truth is None else self.final_truth.tolist()
            out["truth"] = {
                "samples": self.truth.count,
                "matched_rows": self.truth_matched,
                "unmatched_rows": self.truth_unmatched,
                "max_abs_error_after_aligned_enu_deg": (
                    self.max_err_after_aligned.tolist() if al.time_to_aligned is not None
                    else None),
            }
        return out


# ----------------------------------------------------------------------------- bag input
def select_imu_connections(reader, topic: str | None, path) -> tuple[str, list]:
    topics = reader.topics
    if topic is None:
        imu = sorted(t for t, info in topics.items() if info.msgtype == IMU_TYPE)
        if not imu:
            listing = ", ".join(f"{t} ({i.msgtype})" for t, i in sorted(topics.items()))
            raise CliError(f"no {IMU_TYPE} topic in {path}" + (f" (topics: {listing})"
                                                               if listing else " (empty bag)"))
        if len(imu) > 1:
            raise CliError(f"{path} has several {IMU_TYPE} topics ({', '.join(imu)}); "
                           f"choose one with --topic")
        topic = imu[0]
    info = topics.get(topic)
    if info is None:
        listing = ", ".join(sorted(topics)) or "none"
        raise CliError(f"topic {topic} not in {path} (topics: {listing})")
    if info.msgtype != IMU_TYPE:
        raise CliError(f"topic {topic} in {path} is {info.msgtype}, not {IMU_TYPE}")
    conns = [c for c in reader.connections if c.topic == topic]
    if sum(c.msgcount for c in conns) == 0 and info.msgcount == 0:
        raise CliError(f"topic {topic} in {path} has no messages")
    return topic, conns


def select_truth_connections(reader, topic: str, path) -> list:
    info = reader.topics.get(topic)
    if info is None:
        raise CliError(f"truth topic {topic} not in {path} (topics: "
                       f"{', '.join(sorted(reader.topics)) or 'none'})")
    if info.msgtype != TRUTH_TYPE:
        raise CliError(f"truth topic {topic} in {path} is {info.msgtype}, not {TRUTH_TYPE}")
    return [c for c in reader.connections if c.topic == topic]


def _reference_connections(reader, topic: str, msgtype: str, what: str, flag: str, path):
    info = reader.topics.get(topic)
    if info is None:
        listing = ", ".join(f"{t} ({i.msgtype})" for t, i in sorted(reader.topics.items()))
        raise CliError(f"{what} topic {topic} not in {path} (topics: {listing or 'none'}; "
                       f"choose it with {flag})")
    if info.msgtype != msgtype:
        raise CliError(f"{what} topic {topic} in {path} is {info.msgtype}, not {msgtype}"
                       + (" (set --velocity-type)" if what == "velocity" else ""))
    conns = [c for c in reader.connections if c.topic == topic]
    if sum(c.msgcount for c in conns) == 0 and info.msgcount == 0:
        raise CliError(f"{what} topic {topic} in {path} has no messages")
    return conns


def read_references(reader, reference: VelocityReference, path) -> list:
    """The velocity-reference (and NavSatFix) messages of the bag as ``[(header stamp ns,
    'velocity' | 'navsat', msg)]`` sorted by stamp (a stable sort: bag order at equal stamps,
    velocity before position). They are held in memory: a few per second of data.

    Raises CliError for a topic that is missing, of another type or empty."""
    want = [(reference.topic, VELOCITY_TYPES[reference.type], "velocity", "--velocity-topic")]
    if reference.navsat_topic:
        want.append((reference.navsat_topic, NAVSAT_TYPE, "navsat", "--navsat-topic"))
    items = []
    for topic, msgtype, kind, flag in want:
        conns = _reference_connections(reader, topic, msgtype, kind, flag, path)
        for conn, log_ns, raw in read_messages(reader, conns, path):
            msg = deserialize(reader, raw, msgtype, path, log_ns)
            items.append((_stamp_ns(msg), kind, msg))
    items.sort(key=lambda it: it[0])
    return items


#: Messages read and decoded at once (bounds the memory of the bulk decoding); also the
#: samples per estimator call on the block path (fixed, whatever the bag's chunking).
READ_CHUNK = 16384


def imu_messages(reader, items: list, layout: str | None, path):
    """Iterator over the Imu messages of ``items`` [(connection, log ns, raw)], in order.

    With a known ``layout`` (:func:`sins_align.io.cdr.reader_imu_layout`) they are decoded in
    bulk (:func:`sins_align.io.cdr.decode_imu_batch`); the messages it cannot take, and every
    message when ``layout`` is None, are deserialised by rosbags, a malformed one raising
    the CliError of :func:`~sins_align.io.bagio.deserialize` (naming its log time).
    """
    if layout is None:
        return (deserialize(reader, raw, IMU_TYPE, path, ns) for _, ns, raw in items)
    batch = decode_imu_batch(
        [raw for _, _, raw in items], layout,
        fallback=lambda raw, i: deserialize(reader, raw, IMU_TYPE, path, items[i][1]))
    return batch.messages()


class ImuSamples:
    """What :meth:`ReplaySession.on_imu_block` takes from decoded Imu messages."""

    __slots__ = ("sec", "nanosec", "frame_id", "gyro", "accel")

    def __init__(self, sec, nanosec, frame_id, gyro, accel):
        self.sec, self.nanosec, self.frame_id = sec, nanosec, frame_id
        self.gyro, self.accel = gyro, accel

    def __len__(self) -> int:
        return len(self.sec)

    @classmethod
    def join(cls, parts: list) -> "ImuSamples":
        if len(parts) == 1:
            p = parts[0]        # contiguous (a batch's gyro is a strided view of its floats:
            return cls(p.sec, p.nanosec, list(p.frame_id),   # the estimator reads it 2x slower)
                       np.ascontiguousarray(p.gyro), np.ascontiguousarray(p.accel))
        return cls(np.concatenate([p.sec for p in parts]),
                   np.concatenate([p.nanosec for p in parts]),
                   [x for p in parts for x in p.frame_id],
                   np.concatenate([p.gyro for p in parts]),
                   np.concatenate([p.accel for p in parts]))

    def __getitem__(self, sl: slice) -> "ImuSamples":
        return ImuSamples(self.sec[sl], self.nanosec[sl], self.frame_id[sl], self.gyro[sl],
                          self.accel[sl])


def feed_blocks(batches, size: int):
    """Decoded batches (any lengths) regrouped into blocks of ``size`` samples, the last one
    shorter: the estimator gets the same block boundaries whatever the bag's storage and
    chunking, so MCAP, sqlite3 and ROS 1 copies of a bag give bit-identical results."""
    pending: list = []
    have = 0
    for b in batches:
        if not len(b):
            continue
        pending.append(b)
        have += len(b)
        if have < size:
            continue
        joined = ImuSamples.join(pending)
        k = 0
        while have - k >= size:
            yield joined[k:k + size]
            k += size
        pending = [joined[k:]] if k < have else []
        have -= k
    if have:
        yield ImuSamples.join(pending)


def config_echo(config, params: dict[str, Any]) -> dict[str, Any]:
    """The estimator's configuration in the summary: the quasi-static AlignConfig's, or the
    in-motion MotionConfig's (model and backtrack None; site, lever arm, noise, vehicle)."""
    sp = config.specs
    quasi_static = isinstance(config, AlignConfig)
    out = {
        "latitude_deg": config.latitude_deg,
        "height_m": config.height_m,
        "model": config.model if quasi_static else None,
        "grade": params.get("grade"),
        "specs": {"gyro_bias_deg_h": sp.gyro_bias / DPH,
                  "gyro_arw_deg_sqrt_h": sp.gyro_arw / DPSH,
                  "accel_bias_ug": sp.accel_bias / UG,
                  "accel_vrw_ug_sqrt_hz": sp.accel_vrw / UG_PSHZ},
        "initial_rpy_deg": None if config.initial_rpy_deg is None else list(config.initial_rpy_deg),
        "backtrack": config.backtrack if quasi_static else None,
        "backtrack_time_s": config.backtrack_time if quasi_static else None,
        "params": params,
    }
    if not quasi_static:
        out.update(estimator="in_motion", longitude_deg=config.longitude_deg,
                   lever_arm_m=list(config.lever_arm), lever_arm_std_m=config.lever_arm_std,
                   velocity_noise_mps=config.velocity_noise,
                   velocity_latency_s=config.velocity_latency,
                   velocity_latency_std_s=config.velocity_latency_std,
                   max_measurement_lag_s=config.max_measurement_lag, vehicle=config.vehicle,
                   velocity_averaging_s=config.velocity_averaging)
        if config.vehicle == "ground":
            out.update(nhc_lever_arm_m=list(config.nhc_lever_arm),
                       nhc_lever_arm_std_m=config.nhc_lever_arm_std,
                       nhc_mount_std_deg=config.nhc_mount_std_deg,
                       nhc_slip_deg=config.nhc_slip_deg)
    return out


def _block_reading(reader, blocks) -> tuple:
    """The summary's (reading, fallback reason) after the block path read ``blocks``."""
    fast_name = "sqlite3-bulk" if getattr(reader, "storage", "") == "sqlite3" else "mcap-numpy"
    return (fast_name if blocks.fallback_reason is None else
            "rosbags" if blocks.fast_messages == 0 else f"{fast_name}+rosbags",
            blocks.fallback_reason)


def replay(bag: str | os.PathLike, config, *, topic: str | None = None,
           truth_topic: str | None = None, output: Path | None = None, csv_path: Path | None = None,
           keep_plot: bool = False, progress: bool | None = None,
           params: dict[str, Any] | None = None,
           euler_period_ns: int = EULER_PERIOD_NS, per_sample: bool = False,
           fast_mcap: bool = True, reference: VelocityReference | None = None,
           bytes_output: bool = True) -> tuple[dict[str, Any], ReplaySession]:
    """Replay ``bag`` and write the optional outputs to the given (temporary) paths.

    Two paths, same results: with an ``output`` bag or a ``truth_topic`` (or ``per_sample``,
    or an Imu definition the bulk decoder does not know) every message goes through
    :meth:`ReplaySession.on_imu`, in bag order, as the node takes it; otherwise the Imu
    messages are read in blocks (:class:`~sins_align.io.bagio.TopicBlocks`: MCAP parsed with
    numpy, sqlite3 in bulk, the usual bags opened without rosbags by
    :func:`sins_align.io.fastbag.open_fast`; ``fast_mcap=False`` to open and read with
    rosbags only), decoded in bulk and fed to :meth:`ReplaySession.on_imu_block`.
    ``bytes_output=False``: every /imu/data message built and serialised by rosbags (the
    reference of the default, which writes the orientation into the input's bytes).

    With a ``reference`` whose topic is set (``config`` is then a MotionConfig) the velocity
    topic (and the NavSatFix topic) are read first, sorted by header stamp, and merged with
    the IMU samples by header stamp (:meth:`ReplaySession.add_references`); a missing topic
    is a CliError.

    Returns the summary dict and the session (for the plot). Raises CliError on bad input.
    """
    t_wall = time.perf_counter()
    motion = reference is not None and reference.enabled
    # the block path's usual bags open without rosbags (its import is most of a cold start)
    reader = (open_fast(bag) if fast_mcap and not per_sample and bytes_output
              and not truth_topic and not motion else None)
    if reader is None:
        reader = open_reader(bag)
    writer = None
    csv_file = None
    try:
        topic, conns = select_imu_connections(reader, topic, bag)
        truth_conns = select_truth_connections(reader, truth_topic, bag) if truth_topic else []
        refs = read_references(reader, reference, bag) if motion else []
        layout = "ros2" if isinstance(reader, FastBag) else reader_imu_layout(reader)
        block = (not per_sample and output is None and not truth_conns
                 and layout is not None)
        if output is not None:
            writer = open_writer(Path(output), "mcap", "zstd", bulk=True)
        if csv_path is not None:
            csv_file = open(csv_path, "w", newline="", encoding="utf-8")
        session = ReplaySession(config, writer=writer, csv_file=csv_file,
                                with_truth=bool(truth_conns), keep_plot=keep_plot,
                                euler_period_ns=euler_period_ns, block=block,
                                reference=reference if motion else None)
        session.bytes_output = bytes_output
        session.add_references(refs)
        total = sum(c.msgcount for c in conns + truth_conns)
        bar = Progress(total, PROG, enabled=progress)
        n = 0
        # --output on the block path: ROS 2 Imu bytes, the quasi-static estimator's
        # per-sample outputs (update_states), no truth
        out_block = (writer is not None and not block and not per_sample and not truth_conns
                     and layout == "ros2" and bytes_output and not motion
                     and hasattr(session.al, "update_states"))
        if out_block:
            blocks = TopicBlocks(reader, conns, bag, READ_CHUNK, fast=fast_mcap)
            for mb in blocks:
                batch = decode_imu_array(
                    mb.buf, mb.starts, mb.sizes, layout, fallback=lambda raw, i, mb=mb:
                    deserialize(reader, raw, IMU_TYPE, bag, int(mb.log_ns[i])))
                session.on_imu_output_block(batch, mb)
                n += len(batch)
                bar.update(n)
            session.reading = _block_reading(reader, blocks)
        elif block:
            blocks = TopicBlocks(reader, conns, bag, READ_CHUNK, fast=fast_mcap)
            decoded = (decode_imu_array(mb.buf, mb.starts, mb.sizes, layout, fallback=lambda
                                        raw, i, mb=mb: deserialize(reader, raw, IMU_TYPE, bag,
                                                                   int(mb.log_ns[i])))
                       for mb in blocks)
            for samples in feed_blocks(decoded, READ_CHUNK):
                session.on_imu_block(samples)
                n += len(samples)
                bar.update(n)
            session.reading = _block_reading(reader, blocks)
        else:
            truth_ids = {id(c) for c in truth_conns}
            if truth_conns or per_sample or layout != "ros2":
                chunks = read_message_chunks(reader, conns + truth_conns, bag, READ_CHUNK)
                session.reading = ("rosbags", "per-sample path")
            else:       # --output: the Imu topic alone, read as the block path reads it
                blocks = TopicBlocks(reader, conns, bag, READ_CHUNK, fast=fast_mcap)
                chunks = ([(conns[0], ns, mb.raw(i)) for i, ns in enumerate(mb.log_ns.tolist())]
                          for mb in blocks)
            for chunk in chunks:
                imu_items = [it for it in chunk if id(it[0]) not in truth_ids] if truth_ids \
                    else chunk
                imu_msgs = imu_messages(reader, imu_items, layout, bag)
                for conn, log_ns, raw in chunk:
                    if id(conn) in truth_ids:
                        session.on_truth(deserialize(reader, raw, conn.msgtype, bag, log_ns))
                    else:
                        session.on_imu(next(imu_msgs), raw if layout == "ros2" else None)
                    n += 1
                    if n % 512 == 0:
                        bar.update(n)
            if not session.reading[0]:
                session.reading = ("mcap-numpy" if blocks.fallback_reason is None else "rosbags"
                                   if blocks.fast_messages == 0 else "mcap-numpy+rosbags",
                                   blocks.fallback_reason)
        bar.close()
        if session.samples == 0:
            raise CliError(f"topic {topic} in {bag} has no messages")
        session.finish()
        if writer is not None:
            writer.close()
            writer = None
        if csv_file is not None:
            csv_file.close()
            csv_file = None
    except BaseException:
        if writer is not None:
            try:
                writer.abort()
            except Exception:   # noqa: BLE001 - already failing
                pass
        if csv_file is not None:
            csv_file.close()
        raise
    finally:
        reader.close()
    wall = time.perf_counter() - t_wall
    params = params if params is not None else {}
    summ = session.summary(config_echo(config, params))
    summ = {"bag": str(bag), "topic": topic, "truth_topic": truth_topic, **summ,
            "wall_time_s": wall, "messages_per_s": n / wall if wall > 0 else None}
    if motion:
        summ["messages_per_s"] = (n + len(refs)) / wall if wall > 0 else None
    return finite_or_none(summ), session


# ----------------------------------------------------------------------------- plot
def write_plot(path: Path, session: ReplaySession, summary: dict[str, Any]):
    plt = pyplot()
    rows = np.array(session.series.rows, dtype=float).reshape(-1, 11)
    t = rows[:, 0]
    truth = session.with_truth
    fig, axes = plt.subplots(4 if truth else 3, 1, figsize=(10, 11 if truth else 8.5),
                             sharex=True)
    ax = axes[0]
    ax.plot(t, rows[:, 1], label="roll")
    ax.plot(t, rows[:, 2], label="pitch")
    ax.set_ylabel("deg")
    ax.set_title(f"{Path(summary['bag']).name} {summary['topic']}: attitude (REP-103, ENU)")
    ax.legend(loc="best")
    ax = axes[1]
    ax.plot(t, rows[:, 4], color="C2", label="true heading (x axis, CW from North)")
    ax.set_ylabel("deg")
    ax.legend(loc="best")
    ax = axes[2]
    lim = summary["limit_std_enu_deg"] or (None, None, None)
    for i, (name, col) in enumerate((("E", "C0"), ("N", "C1"), ("U", "C2"))):
        ax.semilogy(t, rows[:, 5 + i], color=col, label=f"std {name}")
        if lim[i] is not None:
            ax.axhline(lim[i], color=col, ls="--", lw=0.8, label=f"limit {name}")
    if summary["time_to_aligned_s"] is not None:
        for a in axes:
            a.axvline(summary["time_to_aligned_s"], color="k", ls=":", lw=0.8)
    ax.set_ylabel("deg (1 sigma)")
    ax.legend(loc="best", ncol=2, fontsize="small")
    if truth:
        ax = axes[3]
        for i, (name, col) in enumerate((("E", "C0"), ("N", "C1"), ("U", "C2"))):
            ax.plot(t, rows[:, 8 + i], color=col, label=f"error {name}")
            ax.fill_between(t, -3 * rows[:, 5 + i], 3 * rows[:, 5 + i], color=col, alpha=0.12)
        ax.set_ylabel("deg (shaded: 3 sigma)")
        ax.set_ylim(*_robust_limits(rows[:, 8:11]))
        ax.legend(loc="best", fontsize="small")
    axes[-1].set_xlabel("time since first sample, s")
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=100)
    plt.close(fig)


def _robust_limits(err: np.ndarray) -> tuple[float, float]:
    """Error axis limits: the second half of the run stays readable despite the transient."""
    e = np.abs(err[np.isfinite(err).all(axis=1)])
    if e.size == 0:
        return -1.0, 1.0
    m = 1.5 * max(float(e[len(e) // 2:].max()), float(np.median(e)))
    return (-m, m) if m > 0 else (-1.0, 1.0)


# ----------------------------------------------------------------------------- CLI
def print_summary(s: dict[str, Any], outputs: dict[str, str], file=None):
    # sys.stdout looked up when called (a default bound at import misses a redirection)
    file = sys.stdout if file is None else file
    c = s["config"]
    fin = s["final"]
    rej = ", ".join(f"{k} {v}" for k, v in sorted(s["rejected"].items())) or "none"

    def f3(v, fmt="{:.4f}"):
        return " ".join("-" if x is None else fmt.format(x) for x in v)

    ref = s.get("velocity_reference")
    if ref is None:
        estimator = f"model {c['model']}"
    else:
        estimator = f"in motion, vehicle {c['vehicle']}"
    used = "" if s["samples_used"] is None else f" ({s['samples_used']} used)"
    stage = "" if s["stage"] is None or ref is not None else f" ({s['stage']} pass)"
    lines = [
        f"replay {s['bag']}  topic {s['topic']}",
        (f"  config    latitude {c['latitude_deg']:.6f} deg, height {c['height_m']:g} m, "
         if c['latitude_deg'] is not None and math.isfinite(c['latitude_deg']) else
         f"  config    position from {ref['navsat_topic']}, ")
        + f"{estimator}, " + (f"grade {c['grade']}" if c["grade"] else "specs as given"),
        f"  samples   {s['samples']}{used}, rejected: {rej}",
    ]
    if ref is not None:
        # (each topic its own refusals: the NavSatFix ones are the position's)
        refused = (sum(n for k, n in ref["refused"].items() if not k.startswith("navsat_"))
                   + sum(n for k, n in ref["rejected_by_estimator"].items()
                         if k != "position"))
        lines.append(f"  velocity  {ref['topic']} ({ref['type']}, {ref['frame']}): "
                     f"{ref['velocity_received']} messages, {ref['velocity_used']} used, "
                     f"{refused} refused or rejected"
                     + (f"; position {ref['navsat_topic']}: {ref['position_used']} of "
                        f"{ref['position_received']} used" if ref["navsat_topic"] else ""))
    lines += [
        f"  duration  {s['duration_s']:.3f} s, status {s['status']}{stage}, "
        + (f"aligned after {s['time_to_aligned_s']:.2f} s" if s["time_to_aligned_s"] is not None
           else "never aligned") + ("" if s["aligned"] else "; not aligned at the end")
        + ("" if s.get("specs_consistent", True) else
           f"; the gyro's noise is {s['gyro_noise_ratio']:.0f} x the configured gyro_arw: "
           f"the IMU is worse than its grade, attitude published as unknown"),
        f"  final     roll {fin['rpy_deg'][0]:.4f}  pitch {fin['rpy_deg'][1]:.4f}  "
        f"yaw {fin['rpy_deg'][2]:.4f} deg (REP-103, ENU); heading {fin['heading_deg']:.4f} deg "
        f"true",
        f"  std E N U {f3(fin['std_enu_deg'])} deg"
        + ("" if s["limit_std_enu_deg"] is None else
           f"   limit {f3(s['limit_std_enu_deg'])} deg"),
    ]
    if "bias_gyro_dph" in fin:
        lines.append(f"  biases    gyro {f3(fin['bias_gyro_dph'], '{:.3f}')} deg/h, accel "
                     f"{f3(fin['bias_accel_mg'], '{:.3f}')} mg; heading "
                     + ("observable" if fin["heading_observable"] else "not observable yet"))
    if "error_enu_deg" in fin:
        err = fin["error_enu_deg"]
        if err is None:
            lines.append("  vs truth  no truth at the final stamp")
        else:
            sig = [abs(e) / sd for e, sd in zip(err, fin["std_enu_deg"])]
            lines.append(f"  vs truth  error E N U {f3(err)} deg ({f3(sig, '{:.1f}')} sigma)")
    lines.append(f"  speed     {s['messages_per_s']:.0f} msg/s ({s['wall_time_s']:.2f} s wall)")
    for what, p in outputs.items():
        lines.append(f"  wrote     {what} {p}")
    print("\n".join(lines), file=file)


def run(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.plot:
        need_matplotlib()
    if not Path(args.bag).exists():
        raise CliError(f"bag {args.bag} does not exist")
    outs = {}
    for what, p, is_dir in (("bag", args.output, True), ("csv", args.csv, False),
                            ("plot", args.plot, False), ("summary", args.summary_json, False)):
        if p:
            flag = {"bag": "--output", "summary": "--summary-json"}.get(what, f"--{what}")
            if is_dir:
                check_bag_dir_name(p, flag)
            outs[what] = (check_new_output(p, flag, force=args.force, is_dir=is_dir), is_dir)
    if len({str(p.resolve()) for p, _ in outs.values()}) != len(outs):
        raise CliError("the output paths must differ")
    if any(p.resolve() == Path(args.bag).resolve() for p, _ in outs.values()):
        raise CliError("an output path is the input bag")
    values, node_only = params_from_args(args)
    config = config_or_error(values)
    reference = reference_or_error(values)
    params = merged_params(values)
    euler_rate = float(node_only.get("euler_rate", EULER_RATE))

    with atomic_outputs({w: AtomicOutput(p, is_dir=d, force=args.force)
                         for w, (p, d) in outs.items()}) as atomic:
        summary, session = replay(
            args.bag, config, topic=args.topic, truth_topic=args.truth_topic,
            output=atomic["bag"].tmp if "bag" in atomic else None,
            csv_path=atomic["csv"].tmp if "csv" in atomic else None,
            keep_plot="plot" in atomic, params=params,
            euler_period_ns=int(round(1e9 / euler_rate)), reference=reference)
        if "plot" in atomic:
            write_plot(atomic["plot"].tmp, session, summary)
        if "summary" in atomic:
            atomic["summary"].tmp.write_text(json.dumps(summary, indent=2, allow_nan=False)
                                             + "\n")
    if not args.quiet:
        print_summary(summary, {w: str(p) for w, (p, _) in outs.items()})
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return cli_main(PROG, run, argv)


if __name__ == "__main__":
    sys.exit(main())
