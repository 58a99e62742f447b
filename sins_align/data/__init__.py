"""Real IMU data shipped with sins_align, with provenance and license beside each file.

The files live inside the package (``sins_align/data/<set>/``), so the same paths work from
the source tree, an editable install and an installed package (colcon or pip).

``LASERGYRO``: the PSINS ring-laser-gyro log of a parked car, 34.246° N, 100 Hz, 1847 s
(``psins-lasergyro/README.md``; BSD 2-clause, ``psins-lasergyro/LICENSE``), xz-compressed;
``sins_align.io.psins.read_psins`` reads it as it is.

``TRANSFER_FOG_MEMS``: the PSINS transfer-alignment recording of a driving car, 34.43° N,
100 s: a MEMS IMU (100 Hz increments) and a master FOG INS (10 Hz attitude, velocity,
position), with reference MEMS biases and mounting angles (``psins-transfer-fog-mems/README.md``;
BSD 2-clause, ``psins-transfer-fog-mems/LICENSE``), the original MATLAB file;
``sins_align.io.psins.read_psins_mat`` reads it.
"""
from __future__ import annotations

from pathlib import Path

#: folder of the shipped data sets
DATA_DIR = Path(__file__).resolve().parent

#: the PSINS laser-gyro log (compact SIMU text, xz)
LASERGYRO = DATA_DIR / "psins-lasergyro" / "lasergyro.imu.xz"

#: the PSINS transfer-alignment data: MEMS IMU + master FOG INS in a car (MATLAB v5 .mat)
TRANSFER_FOG_MEMS = DATA_DIR / "psins-transfer-fog-mems" / "transfer_align_fog_mems.mat"

__all__ = ["DATA_DIR", "LASERGYRO", "TRANSFER_FOG_MEMS"]
