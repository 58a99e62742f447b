"""Build a copy of the package with the venv's colcon, once per pytest session.

Shared by test_package_layout.py (installed layout, ``--help``) and test_ros2_run.py
(installed executables over DDS). The build goes into a pytest temporary directory.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
PKG = 'sins_align'
VENV_BIN = Path(sys.executable).parent
PY_VER = f'python{sys.version_info.major}.{sys.version_info.minor}'

_built: dict[str, Path] = {}


def colcon_build(ws: Path) -> Path:
    """Copy the package into ``ws/src``, ``colcon build`` it; return ``ws/install/<pkg>``."""
    src = ws / 'src' / PKG
    src.mkdir(parents=True)
    for name in ('package.xml', 'setup.py', 'setup.cfg'):
        shutil.copy2(REPO_ROOT / name, src / name)
    ignore = shutil.ignore_patterns('__pycache__', '*.pyc', '.venv', '*.egg-info')
    for name in ('resource', 'bags', PKG):
        shutil.copytree(REPO_ROOT / name, src / name, ignore=ignore)

    colcon = VENV_BIN / 'colcon'
    assert colcon.exists(), f'{colcon} missing: run `make setup` (colcon-ros is pinned there)'
    env = dict(os.environ)
    env['PATH'] = f"{VENV_BIN}{os.pathsep}{env.get('PATH', '')}"
    env['COLCON_HOME'] = str(ws / 'colcon_home')  # ignore any user-level colcon defaults
    env.pop('PYTHONPATH', None)
    cmd = [str(colcon), '--log-base', str(ws / 'log'), 'build',
           '--base-paths', str(ws / 'src'),
           '--build-base', str(ws / 'build'),
           '--install-base', str(ws / 'install'),
           '--executor', 'sequential']
    proc = subprocess.run(cmd, cwd=ws, env=env, capture_output=True, text=True,
                          stdin=subprocess.DEVNULL, timeout=300)
    assert proc.returncode == 0, (
        f'colcon build failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}')
    return ws / 'install' / PKG


def session_install(tmp_path_factory) -> Path:
    """The session's colcon build (built on first use): ``install/<pkg>``."""
    if 'install' not in _built:
        _built['install'] = colcon_build(tmp_path_factory.mktemp('colcon_ws'))
    return _built['install']


def installed_env(install_dir: Path, with_venv_site: bool = False) -> dict[str, str]:
    """Environment that runs installed executables against the installed package.

    ``with_venv_site`` adds the venv's site-packages to PYTHONPATH after the install's, as a
    sourced workspace on top of a Python environment would (what ``ros2 run`` sees).
    """
    env = dict(os.environ)
    paths = [str(install_dir / 'lib' / PY_VER / 'site-packages')]
    if with_venv_site:
        paths.append(str(VENV_BIN.parent / 'lib' / PY_VER / 'site-packages'))
    env['PYTHONPATH'] = os.pathsep.join(paths)
    env['PATH'] = f"{VENV_BIN}{os.pathsep}{env.get('PATH', '')}"
    env['AMENT_PREFIX_PATH'] = os.pathsep.join(
        p for p in (str(install_dir), env.get('AMENT_PREFIX_PATH', '')) if p)
    return env
