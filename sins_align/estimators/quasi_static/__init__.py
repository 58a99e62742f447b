"""Self-alignment on a quasi-static base: roll and pitch from gravity, heading from Earth rate.

- :mod:`~sins_align.estimators.quasi_static.aligner`: :class:`Aligner`, the streaming
  estimator behind the common interface (input checks, holes and shocks, the time line, the
  aligned flag, events).
- :mod:`~sins_align.estimators.quasi_static.config`: :class:`AlignConfig`.
- :mod:`~sins_align.estimators.quasi_static.filter`: :class:`AlignmentFilter`, the damped
  mechanization and Kalman filter of the paper, N runs at once (the per-sample recursion),
  made with :mod:`~sins_align.estimators.quasi_static.fast_path` (closed-form integration
  between updates), :mod:`~sins_align.estimators.quasi_static.schedule` (the shared
  gain-schedule cache) and :mod:`~sins_align.estimators.quasi_static.backtrack` (the
  backtrack and the fine pass's tuning).
- :mod:`~sins_align.estimators.quasi_static.monitors`: the recent motion (hole bridges) and
  the deg/s-for-rad/s check.
- :mod:`~sins_align.estimators.quasi_static.coarse`: analytic coarse alignment.
- :mod:`~sins_align.estimators.quasi_static.inertial`: inertial-frame (sway-immune) alignment
  the fine pass can start from.
"""
from sins_align.estimators.quasi_static.aligner import (EVENT_KINDS, REJECT_REASONS, STATES,
                                                         Aligner, AlignmentEvent)
from sins_align.estimators.quasi_static.config import AlignConfig
from sins_align.estimators.quasi_static.filter import AlignmentFilter
from sins_align.estimators.quasi_static.schedule import SHARED_SCHEDULES, GainScheduleCache

__all__ = ["Aligner", "AlignConfig", "AlignmentEvent", "AlignmentFilter", "EVENT_KINDS",
           "GainScheduleCache", "REJECT_REASONS", "SHARED_SCHEDULES", "STATES"]
