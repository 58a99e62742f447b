"""The package is a working ament_python package.

A copy of the package source is built with the venv's colcon (colcon-ros from PyPI) into a
temporary workspace (test/colcon_build.py, one build per session); the tests check the
installed layout that ``ros2 run`` relies on (executables, config, the sample bags, the real
data inside the package) and run every installed executable with ``--help`` (and replay on
the installed real-data bag). A second group checks that package.xml declares an ``exec_depend`` for
every ROS package the code imports.
"""
from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from colcon_build import PKG, REPO_ROOT, installed_env, session_install

# ROS packages whose import needs an exec_depend of the same name.
ROS_PACKAGES = {'rclpy', 'sensor_msgs', 'geometry_msgs', 'std_msgs', 'std_srvs',
                'diagnostic_msgs', 'nav_msgs', 'builtin_interfaces', 'rcl_interfaces'}
# Other imports with a rosdep key.
ROSDEP_KEYS = {'numpy': 'python3-numpy', 'scipy': 'python3-scipy'}


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


def _tree(root: Path) -> dict[str, int]:
    """relative path -> size of every file under root (caches excluded)."""
    return {str(p.relative_to(root)): p.stat().st_size for p in sorted(root.rglob('*'))
            if p.is_file() and '__pycache__' not in p.parts}


def test_sample_bags_installed(install_dir):
    """bags/ (README.md and every bag directory, byte for byte in size) is installed into
    share/sins_align/bags/, where `ros2 pkg prefix sins_align` leads from anywhere."""
    src = _tree(REPO_ROOT / 'bags')
    assert 'README.md' in src and 'lasergyro_300s/metadata.yaml' in src, sorted(src)
    assert _tree(install_dir / 'share' / PKG / 'bags') == src


def _site_packages(install_dir: Path) -> Path:
    (site,) = (install_dir / 'lib').glob('python3*/site-packages')
    return site


def test_real_data_installed_with_the_package(install_dir):
    """sins_align/data (each data set with its README.md and LICENSE: the xz log, the
    transfer-alignment .mat) is installed with the package, and the installed package finds
    and reads both there."""
    src = _tree(REPO_ROOT / PKG / 'data')
    for name in ('psins-lasergyro/lasergyro.imu.xz',
                 'psins-transfer-fog-mems/transfer_align_fog_mems.mat'):
        folder = name.split('/')[0]
        assert {name, f'{folder}/LICENSE', f'{folder}/README.md'} <= set(src), sorted(src)
    assert _tree(_site_packages(install_dir) / PKG / 'data') == src
    code = ('from sins_align.data import LASERGYRO, TRANSFER_FOG_MEMS; '
            'from sins_align.io.psins import read_psins, read_psins_mat; '
            'print(LASERGYRO); print(read_psins(LASERGYRO).n); '
            'print(TRANSFER_FOG_MEMS); m = read_psins_mat(TRANSFER_FOG_MEMS); '
            'print(m.n, m.n_master)')
    proc = subprocess.run([sys.executable, '-c', code], cwd=install_dir,
                          env=installed_env(install_dir), capture_output=True, text=True,
                          stdin=subprocess.DEVNULL, timeout=60)
    assert proc.returncode == 0, proc.stderr
    path, n, mat_path, n_imu, n_master = proc.stdout.split()
    assert Path(path).resolve().is_relative_to(install_dir.resolve()) and n == '184718'
    assert Path(mat_path).resolve().is_relative_to(install_dir.resolve())
    assert (n_imu, n_master) == ('10001', '1000')


def test_installed_replay_runs_on_the_installed_real_bag(install_dir, tmp_path):
    """`ros2 run sins_align replay` on the installed real-data bag (what the README shows)
    uses all 30,000 samples, aligns, and gives exactly what the source tree's replay gives
    on the repository's bags/lasergyro_300s."""
    args = ['--latitude', '34.246048', '--height', '380', '--grade', 'navigation', '--quiet',
            '--summary-json']
    runs = {'installed': ([str(install_dir / 'lib' / PKG / 'replay'),
                           str(install_dir / 'share' / PKG / 'bags' / 'lasergyro_300s')],
                          installed_env(install_dir)),
            'source': ([sys.executable, '-m', 'sins_align.tools.replay',
                        str(REPO_ROOT / 'bags' / 'lasergyro_300s')], None)}
    res = {}
    for name, (cmd, env) in runs.items():
        js = tmp_path / f'{name}.json'
        proc = subprocess.run([*cmd, *args, str(js)], cwd=tmp_path, env=env,
                              capture_output=True, text=True, stdin=subprocess.DEVNULL,
                              timeout=120)
        assert proc.returncode == 0, proc.stderr
        res[name] = json.loads(js.read_text())
    inst, src = res['installed'], res['source']
    assert inst['samples'] == 30000 and inst['rejected'] == {} and inst['aligned'] is True
    assert inst['final'] == src['final'] and inst['time_to_aligned_s'] == src['time_to_aligned_s']


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
