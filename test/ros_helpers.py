"""Helpers for the node tests: child node processes and an in-test rclpy probe.

Everything goes over real DDS on the session's private domain (conftest.py sets
``ROS_DOMAIN_ID`` and ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` before rclpy is imported).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Callable

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def wait_until(pred: Callable[[], object], timeout: float, what: str = "condition",
               interval: float = 0.02):
    """Poll ``pred`` until it returns something truthy; fail with ``what`` on timeout."""
    deadline = time.monotonic() + timeout
    while True:
        value = pred()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(interval)


class NodeProcess:
    """A sins_align node in a child process: ``python -m sins_align.<module> --ros-args ...``.

    ``cmd`` replaces the ``python -m`` prefix (e.g. an installed executable). Output goes to
    ``<log_dir>/<label>.out|.err``.
    """

    def __init__(self, module: str, ros_args: list[str], log_dir: Path, label: str | None = None,
                 cmd: list[str] | None = None, env: dict | None = None):
        self.label = label or module
        log_dir.mkdir(parents=True, exist_ok=True)
        self.out_path = log_dir / f"{self.label}.out"
        self.err_path = log_dir / f"{self.label}.err"
        self._out = open(self.out_path, "w")
        self._err = open(self.err_path, "w")
        argv = (cmd or [sys.executable, "-m", f"sins_align.{module}"]) + ["--ros-args", *ros_args]
        self.argv = argv
        self.proc = subprocess.Popen(argv, stdout=self._out, stderr=self._err,
                                     stdin=subprocess.DEVNULL, env=env or dict(os.environ))

    def alive(self) -> bool:
        return self.proc.poll() is None

    def wait(self, timeout: float) -> int:
        rc = self.proc.wait(timeout=timeout)
        self._close()
        return rc

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT (what Ctrl-C sends), then kill if it does not exit in time."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._close()
        return self.proc.returncode

    def _close(self):
        for f in (self._out, self._err):
            if not f.closed:
                f.close()

    def _flush(self):
        for f in (self._out, self._err):
            if not f.closed:
                f.flush()

    def stderr(self) -> str:
        self._flush()
        return self.err_path.read_text(errors="replace")

    def output(self) -> str:
        self._flush()
        return (f"--- {self.label} stdout\n{self.out_path.read_text(errors='replace')}"
                f"--- {self.label} stderr\n{self.err_path.read_text(errors='replace')}")


class Collector:
    """Thread-safe list of received messages (filled by the probe's executor thread).

    ``maxlen`` keeps only the newest messages; ``count`` counts them all.
    """

    def __init__(self, maxlen: int | None = None):
        self._lock = threading.Lock()
        self._msgs: deque = deque(maxlen=maxlen)
        self.count = 0

    def __call__(self, msg):
        with self._lock:
            self._msgs.append(msg)
            self.count += 1

    @property
    def msgs(self) -> list:
        with self._lock:
            return list(self._msgs)

    def __len__(self):
        with self._lock:
            return len(self._msgs)

    def last(self):
        with self._lock:
            return self._msgs[-1] if self._msgs else None

    def clear(self):
        with self._lock:
            self._msgs.clear()


class Probe:
    """An rclpy node in its own context, spun by a background thread."""

    def __init__(self, name: str = "test_probe"):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, args=[])
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        try:
            while self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)
        except Exception:  # context shut down under us at the end of the tests
            pass

    def subscribe(self, msg_type, topic: str, qos=50, maxlen: int | None = None) -> Collector:
        col = Collector(maxlen)
        col.subscription = self.node.create_subscription(msg_type, topic, col, qos)
        return col

    def unsubscribe(self, col: Collector):
        self.node.destroy_subscription(col.subscription)

    def call(self, srv_type, name: str, request, timeout: float = 10.0):
        """Call a service and return the response (fails on timeout)."""
        client = self.node.create_client(srv_type, name)
        try:
            wait_until(lambda: client.service_is_ready(), timeout, f"service {name}")
            future = client.call_async(request)
            wait_until(future.done, timeout, f"response of {name}")
            return future.result()
        finally:
            self.node.destroy_client(client)

    def set_parameters(self, node_name: str, **values):
        """Set parameters of a remote node through its set_parameters service."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        req = SetParameters.Request(
            parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
        return self.call(SetParameters, f"{node_name}/set_parameters", req).results

    def close(self):
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self._thread.join(timeout=5.0)


def assert_refuses_start(executable: str, args: list[str], reason: str, tmp_path) -> NodeProcess:
    """Start a node that must refuse its parameters: exit status 1 and one stderr line
    containing ``reason``. Returns the finished process (for more checks)."""
    p = NodeProcess(executable, args, tmp_path)
    try:
        rc = p.wait(timeout=30)
    finally:
        p.stop()
    err = [ln for ln in p.stderr().splitlines() if ln.strip()]
    assert rc == 1, p.output()
    assert len(err) == 1 and reason in err[0], p.output()
    return p


def diag_values(arr, status_name: str) -> dict[str, str] | None:
    """Key/values (plus 'message' and 'level') of the status ``status_name`` in an array."""
    for st in arr.status:
        if st.name == status_name:
            d = {kv.key: kv.value for kv in st.values}
            d["message"] = st.message
            d["level"] = str(st.level[0] if isinstance(st.level, bytes) else st.level)
            return d
    return None


def latest_diag(col: Collector, status_name: str) -> dict[str, str] | None:
    """The newest diagnostics of ``status_name`` received on ``col``."""
    for arr in reversed(col.msgs):
        d = diag_values(arr, status_name)
        if d is not None:
            return d
    return None


def stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec
