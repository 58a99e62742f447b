"""Real IMU data shipped with sins_align, with provenance and license beside each file.

The files live inside the package (``sins_align/data/<set>/``), so the same paths work from
the source tree, an editable install and an installed package (colcon or pip).

``LASERGYRO``: the PSINS ring-laser-gyro log of a parked car, 34.246° N, 100 Hz, 1847 s
(``psins-lasergyro/README.md``; BSD 2-clause, ``psins-lasergyro/LICENSE``), xz-compressed;
``sins_align.io.psins.read_psins`` reads it as it is.
"""
from __future__ import annotations

from pathlib import Path

#: folder of the shipped data sets
DATA_DIR = Path(__file__).resolve().parent

#: the PSINS laser-gyro log (compact SIMU text, xz)
LASERGYRO = DATA_DIR / "psins-lasergyro" / "lasergyro.imu.xz"

__all__ = ["DATA_DIR", "LASERGYRO"]
