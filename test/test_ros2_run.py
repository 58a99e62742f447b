"""The `ros2 run` path: the colcon-installed executables align over DDS.

The package is built with colcon into a temporary workspace (test/colcon_build.py, shared
with test_package_layout.py), and ``install/sins_align/lib/sins_align/{align_node,
imu_sim_node}`` are started with ``--ros-args`` exactly as ``ros2 run sins_align <exe>`` does
in a sourced workspace: PYTHONPATH = the install's site-packages then the venv's,
AMENT_PREFIX_PATH = the install prefix. The node reads the installed config/align.yaml.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from std_msgs.msg import Bool

from colcon_build import PKG, installed_env, session_install
from ros_helpers import LATCHED, NodeProcess, Probe, wait_until

NS = f"/ros2run_{os.getpid()}"


@pytest.fixture(scope="module")
def install_dir(tmp_path_factory) -> Path:
    return session_install(tmp_path_factory)


def test_installed_executables_align(install_dir, tmp_path):
    """The installed align_node (params file + -p overrides) aligns on data from the
    installed imu_sim_node; a TRANSIENT_LOCAL subscriber sees aligned=true."""
    env = installed_env(install_dir, with_venv_site=True)
    exe = install_dir / "lib" / PKG
    params = install_dir / "share" / PKG / "config" / "align.yaml"
    assert params.is_file()
    remap = ["-r", f"__ns:={NS}"]
    probe = Probe("test_ros2_run_probe")
    aligned = probe.subscribe(Bool, f"{NS}/alignment/aligned", LATCHED)
    node = sim = None
    try:
        node = NodeProcess("align_node", [
            *remap, "--params-file", str(params), "-p", "latitude:=34.0",
            "-p", "backtrack_time:=20.0", "-p", "initial_rpy:=[0.0, 0.0, 180.0]"],
            tmp_path, cmd=[str(exe / "align_node")], env=env)
        wait_until(lambda: len(aligned) or not node.alive(), 30.0, "installed align_node up")
        assert node.alive(), node.output()
        assert aligned.msgs[0].data is False
        sim = NodeProcess("imu_sim_node", [
            *remap, "-p", "rate:=50.0", "-p", "speed:=10.0", "-p", "rpy:=[1.0, 2.0, -60.0]",
            "-p", "wait_for_subscribers:=true", "-p", "publish_truth:=false"],
            tmp_path, cmd=[str(exe / "imu_sim_node")], env=env)
        try:
            wait_until(lambda: any(m.data for m in aligned.msgs), 90.0, "aligned=true")
        except AssertionError as e:
            raise AssertionError(f"{e}\n{node.output()}\n{sim.output()}") from None
        for p in (sim, node):
            assert p.stop() == 0, p.output()
    finally:
        for p in (sim, node):
            if p is not None:
                p.stop()
        probe.close()
