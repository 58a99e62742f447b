"""Numerics shared by every estimator, simulator and tool; no ROS, no I/O.

- :mod:`~sins_align.core.rotation`: DCM, quaternion, Euler angles, SO(3) exp/log.
- :mod:`~sins_align.core.earth`: WGS-84 gravity and Earth rate in ENU.
- :mod:`~sins_align.core.specs`: sensor grades and the limit accuracy of self-alignment.
- :mod:`~sins_align.core.models`: the paper's error models (F, H, noise input).
- :mod:`~sins_align.core.kalman`: discretisation, Joseph update, batched Riccati steps.
- :mod:`~sins_align.core.preint`: vectorised integration of gyro and accelerometer samples.
- :mod:`~sins_align.core.strapdown`: moving-base strapdown mechanization (ENU, lat/lon/h).
"""
