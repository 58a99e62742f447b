"""The package is a working ament_python package.

A copy of the package source is built with the venv's colcon (colcon-ros from PyPI) into a
temporary workspace (test/colcon_build.py, one build per session); the tests check the
installed layout that ``ros2 run`` relies on and run every installed executable with
``--help``. A second group checks that package.xml declares an ``exec_depend`` for every ROS
package the code imports.
"""
from __future__ import annotations

import ast
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from colcon_build import PKG, REPO_ROOT, installed_env, session_install

# ROS packages whose import needs an exec_depend of the same name.
ROS_PACKAGES = {'rclpy', 'sensor_msgs', 'geometry_msgs', 'std_msgs', 'std_srvs',
                'diagnostic_msgs', 'builtin_interfaces', 'rcl_interfaces'}
# Other imports with a rosdep key.
ROSDEP_KEYS = {'numpy': 'python3-numpy'}


def entry_points() -> list[str]:
    """ENTRY_POINTS from setup.py, read with ast (setup() is not run)."""
    tree = ast.parse((REPO_ROOT / 'setup.py').read_text(), filename='setup.py')
    for node in tree.body:
        if (isinstance(node, ast.Assign) and len(node.targets) == 1
                and isinstance(node.targets[0], ast.Name)
                and node.targets[0].id == 'ENTRY_POINTS'):
            return list(ast.literal_eval(node.value))
    raise AssertionError('setup.py has no module-level ENTRY_POINTS list')


def executable_names() -> list[str]:
    return [item.split('=', 1)[0].strip() for item in entry_points()]


@pytest.fixture(scope='module')
def install_dir(tmp_path_factory) -> Path:
    """Build a copy of the package with colcon (once per session); return install/<pkg>."""
    return session_install(tmp_path_factory)


def test_entry_points_are_well_formed():
    """Every ENTRY_POINTS item is 'name = sins_align.module:main' and names are unique."""
    items = entry_points()
    assert items, 'ENTRY_POINTS is empty'
    names = executable_names()
    assert len(names) == len(set(names)), f'duplicate executable names: {names}'
    for item in items:
        name, _, target = (part.strip() for part in item.partition('='))
        module, _, func = target.partition(':')
        assert name and func, f'bad entry point {item!r}'
        assert module.startswith(PKG + '.'), f'{item!r} points outside {PKG}'
        module_file = REPO_ROOT / (module.replace('.', '/') + '.py')
        assert module_file.is_file(), f'{item!r}: {module_file.relative_to(REPO_ROOT)} missing'


def test_ament_index_marker_and_package_xml_installed(install_dir):
    """The ament index marker and package.xml are installed where ament/ros2 look."""
    share = install_dir / 'share'
    assert (share / 'ament_index' / 'resource_index' / 'packages' / PKG).is_file()
    assert (share / PKG / 'package.xml').is_file()


def test_config_files_installed(install_dir):
    """Every sins_align/config/*.yaml is installed into share/sins_align/config/."""
    for yaml_file in sorted((REPO_ROOT / PKG / 'config').glob('*.yaml')):
        assert (install_dir / 'share' / PKG / 'config' / yaml_file.name).is_file(), yaml_file


def test_colcon_writes_setup_bash_that_finds_the_package(install_dir):
    """`colcon build` writes install/setup.bash (colcon-bash, pinned in .ci/requirements.txt);
    sourcing it in bash puts the package on the ament index, PYTHONPATH and
    ros2 run's lib/sins_align path."""
    install = install_dir.parent
    setup_bash = install / 'setup.bash'
    assert setup_bash.is_file(), (
        f'{setup_bash} missing: colcon wrote {sorted(p.name for p in install.iterdir())} '
        '(is colcon-bash installed?)')
    assert (install_dir / 'share' / PKG / 'package.bash').is_file()
    env = {k: v for k, v in os.environ.items()
           if k not in ('AMENT_PREFIX_PATH', 'COLCON_PREFIX_PATH', 'PYTHONPATH')}
    script = (f'source {setup_bash} && '
              f'python -c "import {PKG}; from ament_index_python.packages import '
              f'get_package_prefix; print(get_package_prefix(\'{PKG}\')); print({PKG}.__file__)"')
    env['PATH'] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    proc = subprocess.run(['bash', '-c', script], cwd=install, env=env, capture_output=True,
                          text=True, stdin=subprocess.DEVNULL, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    prefix, module = proc.stdout.split()
    assert Path(prefix).resolve() == install_dir.resolve(), proc.stdout
    assert Path(module).resolve().is_relative_to(install_dir.resolve()), proc.stdout
    assert (Path(prefix) / 'lib' / PKG / 'align_node').is_file()


def test_package_importable_from_install(install_dir):
    """The installed copy (not the source tree) is what the installed environment imports."""
    proc = subprocess.run(
        [sys.executable, '-c', f'import {PKG}; print({PKG}.__file__)'],
        cwd=install_dir, env=installed_env(install_dir), capture_output=True, text=True,
        stdin=subprocess.DEVNULL, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert Path(proc.stdout.strip()).resolve().is_relative_to(install_dir.resolve()), proc.stdout


@pytest.mark.parametrize('exe', executable_names())
def test_executable_installed_in_lib_pkg(install_dir, exe):
    """`ros2 run sins_align <exe>` needs lib/sins_align/<exe> (setup.cfg install_scripts)."""
    path = install_dir / 'lib' / PKG / exe
    assert path.is_file(), f'{path} missing'
    assert os.access(path, os.X_OK), f'{path} is not executable'


@pytest.mark.parametrize('exe', executable_names())
def test_executable_help_exits_zero(install_dir, exe):
    """Each installed executable runs and answers --help with exit status 0."""
    path = install_dir / 'lib' / PKG / exe
    try:
        proc = subprocess.run([str(path), '--help'], cwd=install_dir,
                              env=installed_env(install_dir), capture_output=True, text=True,
                              stdin=subprocess.DEVNULL, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail(f'{exe} --help did not exit within 60 s (handle --help before spinning)')
    assert proc.returncode == 0, (
        f'{exe} --help exited {proc.returncode}:\n{proc.stdout}\n{proc.stderr}')


def _declared_depends(tag_names: tuple[str, ...]) -> set[str]:
    root = ET.parse(REPO_ROOT / 'package.xml').getroot()
    return {el.text.strip() for tag in tag_names for el in root.iter(tag) if el.text}


def _imported_top_level_names() -> dict[str, set[str]]:
    """Top-level package name -> files that import it, over every sins_align/**/*.py."""
    found: dict[str, set[str]] = {}
    for path in sorted((REPO_ROOT / PKG).rglob('*.py')):
        rel = str(path.relative_to(REPO_ROOT))
        tree = ast.parse(path.read_text(encoding='utf-8'), filename=rel)
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                found.setdefault(name.split('.')[0], set()).add(rel)
    return found


def test_package_xml_exec_depends_cover_ros_imports():
    """Every ROS package (and numpy) imported under sins_align/ has an exec_depend."""
    declared = _declared_depends(('exec_depend', 'depend'))
    missing = {}
    for top, files in _imported_top_level_names().items():
        key = top if top in ROS_PACKAGES else ROSDEP_KEYS.get(top)
        if key is not None and key not in declared:
            missing[key] = sorted(files)
    assert not missing, f'package.xml lacks <exec_depend> for: {missing}'


def test_package_xml_has_no_unresolvable_rosbags_key():
    """rosbags has no rosdep key: it is documented as a pip install, not declared."""
    text = (REPO_ROOT / 'package.xml').read_text()
    assert 'rosbags' not in _declared_depends(
        ('depend', 'exec_depend', 'build_depend', 'test_depend'))
    pins = [line.split('==', 1)[1].strip()
            for line in (REPO_ROOT / '.ci' / 'requirements.txt').read_text().splitlines()
            if line.startswith('rosbags==')]
    assert len(pins) == 1, 'rosbags must be pinned once in .ci/requirements.txt'
    assert f'pip install rosbags=={pins[0]}' in text, 'package.xml comment and pin disagree'
