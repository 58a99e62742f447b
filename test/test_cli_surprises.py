"""What a user of the command-line tools runs into (issue 11, "A ROS user's surprises"):
existing outputs and ``--force``, SIGTERM and SIGHUP (``timeout``, ``kill``, a closed
terminal), units written in CSV header names, a UTF-8 byte-order mark, rosbag2 directories
named ``x.bag``, stamps out of a ROS stamp's range, non-finite latitudes, a params file keyed
with the node's old name.

The rule for bad input: one line on stderr, a non-zero exit, no half-written output (hidden
``.partial-PID`` files included).
"""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import cli, listing
from sins_align.tools import import_imu

from sins_align.tools import replay

from sins_align.tools import simulate

G = 9.80665



def imu_values(bag: Path):
    """(stamps ns, gyro Nx3, accel Nx3) of /imu/data_raw."""
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as r:
        conns = [c for c in r.connections if c.topic == "/imu/data_raw"]
        msgs = [r.deserialize(raw, c.msgtype) for c, _, raw in r.messages(conns)]
    t = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs]
    g = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                  for m in msgs])
    a = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                  for m in msgs])
    return t, g, a


def one_error_line(rc, err, prog, words):
    lines = err.strip().splitlines()
    assert rc == 2, err
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), err
    assert words in lines[0], lines[0]


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_sim")
    bag = d / "sim"
    assert simulate.main(["--duration", "20", "--rate", "50", str(bag)]) == 0
    return bag


# ---------------------------------------------------------------------------- --force
def test_simulate_and_import_refuse_an_existing_output_unless_force(tmp_path, capsys):
    """An existing OUT is refused with a hint at --force; --force replaces a previous bag
    with the new one (nothing hidden left behind) and refuses to replace anything else."""
    out = tmp_path / "bag"
    rc, _, err = cli(simulate, ["--duration", "2", out], capsys)
    assert rc == 0, err
    t1, _, _ = imu_values(out)
    rc, _, err = cli(simulate, ["--duration", "3", out], capsys)
    one_error_line(rc, err, "simulate", "--force")
    assert imu_values(out)[0] == t1
    rc, _, err = cli(simulate, ["--duration", "3", "--force", out], capsys)
    assert rc == 0, err
    assert len(imu_values(out)[0]) == 300 and len(t1) == 200
    assert listing(tmp_path) == {"bag", *(f"bag/{p.name}" for p in out.iterdir())}

    csv = tmp_path / "log.csv"
    csv.write_text("t,gx,gy,gz,ax,ay,az\n" + "".join(
        f"{k * 0.01:.2f},0,0,0,0,0,9.8\n" for k in range(50)))
    rc, _, err = cli(import_imu, [csv, out], capsys)
    one_error_line(rc, err, "import_imu", "--force")
    rc, _, err = cli(import_imu, [csv, out, "--force"], capsys)
    assert rc == 0, err
    assert len(imu_values(out)[0]) == 50

    # --force never replaces what is not a previous output of the same kind
    keep = tmp_path / "my_documents"
    keep.mkdir()
    (keep / "thesis.txt").write_text("precious\n")
    before = listing(tmp_path)
    rc, _, err = cli(simulate, ["--duration", "2", "--force", keep], capsys)
    one_error_line(rc, err, "simulate", "not a rosbag2 bag")
    rc, _, err = cli(import_imu, [csv, csv, "--force"], capsys)
    one_error_line(rc, err, "import_imu", "not a directory")
    assert listing(tmp_path) == before


def test_replay_refuses_existing_outputs_unless_force(sim_bag, tmp_path, capsys):
    """replay's --output/--csv/--summary-json/--plot: refused when present, replaced with
    --force (each by a new complete one), never the input bag, never a directory for a file."""
    outs = {"--output": tmp_path / "out", "--csv": tmp_path / "a.csv",
            "--summary-json": tmp_path / "s.json", "--plot": tmp_path / "p.png"}
    args = [sim_bag, "--latitude", 34, "--grade", "navigation", "--quiet"]
    for flag, p in outs.items():
        args += [flag, p]
    rc, _, err = cli(replay, args, capsys)
    assert rc == 0, err
    stamp = {p: p.stat().st_mtime_ns for p in outs.values()}
    for flag, p in outs.items():
        rc, _, err = cli(replay, [sim_bag, "--latitude", 34, "--grade", "navigation", "--quiet",
                                  flag, p], capsys)
        one_error_line(rc, err, "replay", "--force")
    (outs["--csv"]).write_text("old\n")
    (outs["--summary-json"]).write_text("old\n")
    time.sleep(0.01)
    rc, _, err = cli(replay, [*args, "--force", "--model", "conventional"], capsys)
    assert rc == 0, err
    assert json.loads(outs["--summary-json"].read_text())["config"]["model"] == "conventional"
    assert outs["--csv"].read_text().startswith("t,qx,qy,qz,qw")
    assert all(p.stat().st_mtime_ns > stamp[p] for p in outs.values() if p.is_file())
    assert not [n for n in listing(tmp_path) if n.startswith(".")], listing(tmp_path)
    # never the input, never a directory in place of a file
    rc, _, err = cli(replay, [sim_bag, "--latitude", 34, "--grade", "navigation", "--output",
                              sim_bag, "--force"], capsys)
    one_error_line(rc, err, "replay", "input bag")
    rc, _, err = cli(replay, [sim_bag, "--latitude", 34, "--grade", "navigation", "--csv",
                              outs["--output"], "--force"], capsys)
    one_error_line(rc, err, "replay", "is a directory")


# ---------------------------------------------------------------------------- signals
def _run_and_signal(argv, workdir: Path, partial_glob: str, sig: int):
    """Start a tool, wait until its hidden partial output exists, send ``sig``."""
    proc = subprocess.Popen([sys.executable, "-m", *argv], cwd=workdir,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, text=True)
    try:
        deadline = time.monotonic() + 60
        while not list(workdir.glob(partial_glob)):
            assert proc.poll() is None, f"ended before writing: {proc.communicate()}"
            assert time.monotonic() < deadline, "no partial output appeared"
            time.sleep(0.02)
        time.sleep(0.3)                      # well inside the writing
        assert proc.poll() is None, "finished before the signal: make the job longer"
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return proc.returncode, out, err


@pytest.fixture(scope="module")
def long_inputs(tmp_path_factory):
    """A bag long enough that replay --output takes seconds (an hour at 50 Hz: the block
    path wrote 600 s of it in 0.3 s, before the test's signal came), and a 100k-line CSV."""
    d = tmp_path_factory.mktemp("long")
    assert simulate.main(["--duration", "3600", "--rate", "50", str(d / "long_bag")]) == 0
    k = np.arange(100_000)
    np.savetxt(d / "long.csv", np.column_stack([k * 0.01, np.zeros((len(k), 5)),
                                                np.full(len(k), 9.8)]),
               fmt="%.2f", delimiter=",", header="t,gx,gy,gz,ax,ay,az", comments="")
    return d


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGHUP"])
@pytest.mark.parametrize("tool", ["simulate", "import_imu", "replay"])
def test_sigterm_and_sighup_remove_partial_outputs_with_one_line(tool, sig, long_inputs,
                                                                 tmp_path):
    """`timeout` (SIGTERM) or a closed terminal (SIGHUP) while a tool writes: one line on
    stderr, exit 128 + signal, and no output at all (no hidden .partial-PID file)."""
    signum = getattr(signal, sig)
    argv = {"simulate": ["sins_align.tools.simulate", "--duration", "1e6", "out"],
            "import_imu": ["sins_align.tools.import_imu", str(long_inputs / "long.csv"), "out"],
            "replay": ["sins_align.tools.replay", str(long_inputs / "long_bag"), "--latitude", "34",
                       "--grade", "navigation",
                       "--output", "out", "--csv", "out.csv"]}[tool]
    rc, out, err = _run_and_signal(argv, tmp_path, ".out*.partial-*", signum)
    assert rc == 128 + signum, (rc, out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0] == (
        f"{tool}: terminated by {sig}; unfinished outputs removed"), err
    assert listing(tmp_path) == set(), listing(tmp_path)


# ---------------------------------------------------------------------------- import units
def _csv(path: Path, header: str, rows, bom: bool = False):
    text = header + "\n" + "".join(",".join(repr(float(x)) for x in r) + "\n" for r in rows)
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode())


def test_import_honours_units_in_header_names(tmp_path, capsys):
    """`time [ms]`, `gx [deg/s]`, `az [g]` in the header are converted (not read as s, rad/s,
    m/s^2): stamps, rates and forces in SI, and the summary names the units."""
    n = 100
    w = np.array([0.5, -0.25, 1.0])       # deg/s
    f = np.array([0.01, -0.02, 1.0])      # g
    rows = [(10.0 * k, *w, *f) for k in range(n)]
    src = tmp_path / "units.csv"
    _csv(src, "time [ms],gx [deg/s],gy [deg/s],gz [deg/s],ax [g],ay [g],az [g]", rows)
    rc, out, err = cli(import_imu, [src, tmp_path / "bag"], capsys)
    assert rc == 0, err
    t, g, a = imu_values(tmp_path / "bag")
    assert t == [10_000_000 * k for k in range(n)]
    np.testing.assert_allclose(g, np.tile(np.radians(w), (n, 1)), rtol=1e-12)
    np.testing.assert_allclose(a, np.tile(f * G, (n, 1)), rtol=1e-12)
    assert "time ms (header)" in out and "gyro deg/s (header)" in out and "accel g (header)" in out
    # increments in the header too: gx (rad) per 0.01 s sample, ax (m/s) likewise
    src2 = tmp_path / "inc.csv"
    _csv(src2, "t (s),gx (rad),gy (rad),gz (rad),ax (m/s),ay (m/s),az (m/s)",
         [(0.01 * k, 1e-4, 0.0, -1e-4, 0.0, 0.0, 0.098) for k in range(n)])
    rc, _, err = cli(import_imu, [src2, tmp_path / "bag2"], capsys)
    assert rc == 0, err
    _, g2, a2 = imu_values(tmp_path / "bag2")
    np.testing.assert_allclose(g2[:, 0], 1e-2, rtol=1e-9)
    np.testing.assert_allclose(a2[:, 2], 9.8, rtol=1e-9)


@pytest.mark.parametrize("header, extra, words", [
    ("t,gx [mrad/s],gy,gz,ax,ay,az", [], "unknown gyro unit 'mrad/s'"),
    ("time [furlong],gx,gy,gz,ax,ay,az", [], "unknown time unit 'furlong'"),
    ("t,gx [deg/s],gy [rad/s],gz,ax,ay,az", [], "different gyro units"),
    ("t,gx,gy,gz,ax [g],ay [g],az [g]", ["--accel-units", "m/s2"],
     "says g, --accel-units says m/s2"),
    ("time [ms],gx,gy,gz,ax,ay,az", ["--time-units", "s"], "says ms, --time-units says s"),
], ids=["unknown-gyro", "unknown-time", "mixed-gyro", "contradicts-accel-flag",
        "contradicts-time-flag"])
def test_import_refuses_units_it_cannot_honour(header, extra, words, tmp_path, capsys):
    src = tmp_path / "u.csv"
    _csv(src, header, [(0.01 * k, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0) for k in range(5)])
    before = listing(tmp_path)
    rc, _, err = cli(import_imu, [src, tmp_path / "never", *extra], capsys)
    one_error_line(rc, err, "import_imu", words)
    assert "u.csv:1:" in err
    assert listing(tmp_path) == before


def test_import_accepts_a_utf8_byte_order_mark(tmp_path, capsys):
    """A spreadsheet's BOM before the header ('\\ufefftime,...') is not part of the name."""
    src = tmp_path / "bom.csv"
    _csv(src, "time,gyro_x,gyro_y,gyro_z,acc_x,acc_y,acc_z",
         [(0.01 * k, 0.001, 0.0, 0.0, 0.0, 0.0, 9.8) for k in range(20)], bom=True)
    rc, _, err = cli(import_imu, [src, tmp_path / "bag"], capsys)
    assert rc == 0, err
    t, g, a = imu_values(tmp_path / "bag")
    assert len(t) == 20 and g[0, 0] == 0.001 and a[0, 2] == 9.8


# ---------------------------------------------------------------------------- names, ranges
def test_rosbag2_outputs_named_like_ros1_bags_are_refused(sim_bag, tmp_path, capsys):
    """simulate, import_imu and replay --output refuse OUT 'x.bag' (a directory replay would
    take for a ROS 1 bag file); replay on such a directory says what to do in one line."""
    csv = tmp_path / "log.csv"
    csv.write_text("t,gx,gy,gz,ax,ay,az\n0.01,0,0,0,0,0,9.8\n0.02,0,0,0,0,0,9.8\n")
    before = listing(tmp_path)
    for mod, args in ((simulate, ["--duration", "1", tmp_path / "x.bag"]),
                      (import_imu, [csv, tmp_path / "x.bag"]),
                      (replay, [sim_bag, "--latitude", 34, "--grade", "navigation", "--output",
                                tmp_path / "x.BAG"])):
        rc, _, err = cli(mod, args, capsys)
        one_error_line(rc, err, mod.PROG, "without .bag")
    assert listing(tmp_path) == before
    named = tmp_path / "old.bag"
    named.mkdir()
    for f in sim_bag.iterdir():
        (named / f.name).write_bytes(f.read_bytes())
    rc, _, err = cli(replay, [named, "--latitude", 34, "--grade", "navigation"], capsys)
    one_error_line(rc, err, "replay", "rename it without .bag")


@pytest.mark.parametrize("t0", ["-5", "1e12", "2147483640", "nan"])
def test_simulate_t0_outside_a_ros_stamp_is_one_line(t0, tmp_path, capsys):
    rc, _, err = cli(simulate, ["--duration", "10", "--t0", t0, tmp_path / "out"], capsys)
    one_error_line(rc, err, "simulate", "--t0 must be >= 0 s")
    assert listing(tmp_path) == set()


def test_simulate_t0_at_the_edge_of_a_ros_stamp_works(tmp_path, capsys):
    t0 = 2**31 - 2.0
    rc, _, err = cli(simulate, ["--duration", "1", "--rate", "10", "--t0", t0,
                                tmp_path / "out"], capsys)
    assert rc == 0, err
    t, _, _ = imu_values(tmp_path / "out")
    assert t[-1] == (2**31 - 1) * 10**9


@pytest.mark.parametrize("value", ["inf", "-inf", "nan"])
def test_non_finite_latitude_says_not_finite(value, sim_bag, tmp_path, capsys):
    """--latitude inf/nan is 'not finite', never 'latitude is required'."""
    rc, _, err = cli(replay, [sim_bag, f"--latitude={value}"], capsys)
    one_error_line(rc, err, "replay", f"--latitude must be a finite number, got {value}")
    rc, _, err = cli(simulate, [f"--latitude={value}", tmp_path / "out"], capsys)
    one_error_line(rc, err, "simulate", f"--latitude must be a finite number, got {value}")
    y = tmp_path / "p.yaml"
    y.write_text(f"/**:\n  ros__parameters:\n    latitude: {'.inf' if 'inf' in value else '.nan'}"
                 "\n")
    rc, _, err = cli(replay, [sim_bag, "--params", y], capsys)
    one_error_line(rc, err, "replay", "must be finite" if "inf" in value else
                   "must be a finite number, got nan")


def test_replay_params_keyed_with_the_old_node_name_says_so(sim_bag, tmp_path, capsys):
    """A params file keyed 'sins_align:' (the node's old name) no longer applies to the node;
    replay says so instead of ignoring it."""
    y = tmp_path / "old.yaml"
    y.write_text("sins_align:\n  ros__parameters:\n    latitude: 34.0\n")
    rc, _, err = cli(replay, [sim_bag, "--params", y], capsys)
    one_error_line(rc, err, "replay", "instead of 'sins_align:'")
    y.write_text("/**/align_node:\n  ros__parameters:\n    latitude: 34.0\n    grade: navigation\n")
    rc, _, err = cli(replay, [sim_bag, "--params", y, "--quiet"], capsys)
    assert rc == 0, err
