"""In-motion alignment with a velocity reference (GNSS velocity or a master INS; seeds 003,
002, 001): roll, pitch and true heading of a moving IMU, MEMS included.

- :mod:`~sins_align.estimators.in_motion.aligner`: :class:`MotionAligner`, the streaming
  estimator behind the common interface (input checks, measurements at their own stamps,
  the start, heading observability, the aligned flag, events).
- :mod:`~sins_align.estimators.in_motion.config`: :class:`MotionConfig`.
- :mod:`~sins_align.estimators.in_motion.filter`: :class:`InvariantEKF`, the left-invariant
  error-state filter (closed-form propagation over runs of samples, velocity, attitude and
  non-holonomic updates).
"""
from sins_align.estimators.in_motion.aligner import (MOTION_REJECT_REASONS, MOTION_STATES,
                                                     MotionAligner)
from sins_align.estimators.in_motion.config import VEHICLES, MotionConfig
from sins_align.estimators.in_motion.filter import InvariantEKF, NoiseModel

__all__ = ["MotionAligner", "MotionConfig", "InvariantEKF", "NoiseModel", "VEHICLES",
           "MOTION_REJECT_REASONS", "MOTION_STATES"]
