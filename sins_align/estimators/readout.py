"""What every estimator derives the same way from its attitude and covariance.

:class:`AttitudeReadout` gives ``quaternion``, ``rpy_deg``, ``heading_deg`` and
``std_enu_deg`` to a class that defines ``dcm`` (C_b^n, (3, 3)) and ``covariance`` (E/N/U
attitude error, rad^2).
"""
from __future__ import annotations

import numpy as np

from sins_align.core.rotation import heading_from_dcm, quat_from_dcm, rpy_from_dcm
from sins_align.core.specs import DEG

__all__ = ["AttitudeReadout"]


class AttitudeReadout:
    """Mixin: the attitude in the forms the fronts publish."""

    dcm: np.ndarray
    covariance: np.ndarray

    @property
    def quaternion(self) -> np.ndarray:
        """Orientation of the IMU frame in ENU, [x, y, z, w] (C_b^n, as imu_filter_madgwick)."""
        return quat_from_dcm(self.dcm)

    @property
    def rpy_deg(self) -> np.ndarray:
        """REP-103 [roll, pitch, yaw], deg (yaw 0 = x axis East, counter-clockwise)."""
        return rpy_from_dcm(self.dcm) / DEG

    @property
    def heading_deg(self) -> float:
        """True heading of the IMU x axis, deg clockwise from North, [0, 360)."""
        return float(heading_from_dcm(self.dcm) / DEG)

    @property
    def std_enu_deg(self) -> np.ndarray:
        """Published one-sigma attitude error per axis (E, N, U), deg."""
        return np.sqrt(np.diag(self.covariance)) / DEG
