"""Self-alignment on a quasi-static base: roll and pitch from gravity, heading from Earth rate.

- :mod:`~sins_align.estimators.quasi_static.aligner`: :class:`Aligner` (the streaming
  estimator: input checks, holes, time line, aligned flag) over :class:`AlignmentFilter` (the
  damped mechanization and Kalman filter of the paper, N runs at once), :class:`AlignConfig`.
- :mod:`~sins_align.estimators.quasi_static.coarse`: analytic coarse alignment.
- :mod:`~sins_align.estimators.quasi_static.inertial`: inertial-frame (sway-immune) alignment
  the fine pass can start from.
"""
from sins_align.estimators.quasi_static.aligner import (EVENT_KINDS, REJECT_REASONS, STATES,
                                                         AlignConfig, Aligner, AlignmentEvent,
                                                         AlignmentFilter)

__all__ = ["Aligner", "AlignConfig", "AlignmentEvent", "AlignmentFilter", "EVENT_KINDS",
           "REJECT_REASONS", "STATES"]
