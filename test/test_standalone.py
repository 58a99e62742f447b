"""The repository stands alone: a fresh clone, with nothing beside it, has the real data.

The committed HEAD of this repository is cloned into an empty temporary directory (so there
is no ``../shared`` beside it), and the clone, not this work tree nor the installed package,
imports sins_align, reads the real laser-gyro log and runs the real-data tests.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent


def _git(*args: str, cwd: Path = REPO_ROOT) -> str:
    p = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True,
                       stdin=subprocess.DEVNULL, timeout=120)
    assert p.returncode == 0, f"git {' '.join(args)} failed:\n{p.stderr}"
    return p.stdout.strip()


@pytest.fixture(scope="module")
def clone(tmp_path_factory) -> Path:
    if not (REPO_ROOT / ".git").exists():
        pytest.fail(f"{REPO_ROOT} is not a git checkout: this test clones the committed HEAD",
                    pytrace=False)
    head = _git("rev-parse", "HEAD")
    root = tmp_path_factory.mktemp("fresh")
    dest = root / "sins_align"
    _git("clone", "--quiet", "--no-checkout", str(REPO_ROOT), str(dest), cwd=root)
    _git("checkout", "--quiet", head, cwd=dest)
    assert sorted(p.name for p in root.iterdir()) == ["sins_align"]    # no shared/ beside it
    return dest


def _env(clone: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(clone)        # the clone's package comes before the venv's
    return env


def test_fresh_clone_reads_the_real_log(clone):
    """From the clone: sins_align is imported from the clone, its data folder holds the log,
    README and LICENSE, and read_psins gives all 184,718 samples of it."""
    code = ("import json, sins_align\n"
            "from sins_align.data import LASERGYRO\n"
            "from sins_align.io.psins import read_psins\n"
            "log = read_psins(LASERGYRO)\n"
            "print(json.dumps({'pkg': sins_align.__file__, 'data': str(LASERGYRO), 'n': log.n,"
            " 'lat': log.lat_rad, 'files': sorted(p.name for p in LASERGYRO.parent.iterdir())}))")
    p = subprocess.run([sys.executable, "-c", code], cwd=clone, env=_env(clone),
                       capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=120)
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout)
    assert Path(got["pkg"]).resolve().is_relative_to(clone.resolve()), got
    assert Path(got["data"]).resolve().is_relative_to(clone.resolve()), got
    assert got["n"] == 184718
    assert {"LICENSE", "README.md", "lasergyro.imu.xz"} <= set(got["files"]), got


def test_fresh_clone_passes_its_real_data_tests(clone):
    """The clone's own real-data tests (the reader, the reference, the estimator on the log)
    pass in the clone, against the clone's package."""
    tests = ["test/test_psins.py", "test/test_inertial_alignment.py", "test/test_real_data.py"]
    p = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *tests],
                       cwd=clone, env=_env(clone), capture_output=True, text=True,
                       stdin=subprocess.DEVNULL, timeout=600)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-2000:]
    assert " passed" in p.stdout and "failed" not in p.stdout and "error" not in p.stdout
