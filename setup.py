"""Build script for the sins_align ament_python package (ros2/examples minimal_publisher style)."""
from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'sins_align'

# The one list of executables. Each lands in lib/sins_align/ (setup.cfg), where `ros2 run`
# finds it; every tool also runs as `python -m sins_align.<tool>`.
# Entries are added here as their modules land (align_node, imu_sim_node, replay, simulate,
# import_imu, montecarlo, observability). test/test_package_layout.py reads this list with
# ast, so keep it a plain list of string literals.
ENTRY_POINTS = [
    'demo = sins_align.ros.demo:main',
    'align_node = sins_align.ros.align_node:main',
    'imu_sim_node = sins_align.ros.imu_sim_node:main',
    'replay = sins_align.tools.replay:main',
    'simulate = sins_align.tools.simulate:main',
    'import_imu = sins_align.tools.import_imu:main',
    'montecarlo = sins_align.tools.montecarlo:main',
    'observability = sins_align.tools.observability:main',
]


def sample_bags():
    """data_files entries for bags/: README.md, and each bag directory's files, installed
    under share/sins_align/bags/ (where `ros2 pkg prefix sins_align` leads)."""
    entries = [('share/' + package_name + '/bags', ['bags/README.md'])]
    for bag in sorted(glob(os.path.join('bags', '*', ''))):
        name = os.path.basename(os.path.dirname(bag))
        files = sorted(f for f in glob(os.path.join(bag, '*')) if os.path.isfile(f))
        entries.append(('share/' + package_name + '/bags/' + name, files))
    return entries


setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    # the real data sets (sins_align/data/<set>/: log, README.md, LICENSE) travel with the
    # package, so sins_align.data finds them in the source tree and in any install
    package_data={package_name + '.data': ['*/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config',
         sorted(glob(os.path.join(package_name, 'config', '*.yaml')))),
        *sample_bags(),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='sins_align developers',
    maintainer_email='sins_align@example.com',
    description='Strapdown INS self-alignment (roll, pitch, true heading from Earth rate) '
                'from IMU data on a quasi-static base',
    license='BSD-3-Clause',
    tests_require=['pytest'],
    # --plot of the replay and montecarlo tools; the tools fail fast with a hint without it
    extras_require={'plot': ['matplotlib>=3.8']},
    entry_points={
        'console_scripts': ENTRY_POINTS,
    },
)
