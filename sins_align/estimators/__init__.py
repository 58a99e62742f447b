"""The estimators. Each subpackage is one estimator behind the same small interface:

- ``update(stamp, gyro, accel)`` for one sample or a block (returns how many were used);
- ``reset(reason)``; read-only results: ``quaternion``, ``dcm``, ``covariance`` (E/N/U,
  rad^2), ``std_enu_deg``, ``aligned``, ``status``, ``t_last``, ``rejected``, ``events``;
- ``subscribe(callback)``: events (the aligned flag changed, a restart, a rejected sample with
  its reason), each an ``AlignmentEvent(kind, stamp, value)``.

:mod:`~sins_align.estimators.session` holds the data-path rules the fronts share around any
estimator (accepted or not, restart on a backward jump of the stamps, when to publish the
flag). The fronts (:mod:`sins_align.ros`, :mod:`sins_align.tools`, the benchmarks) use
nothing else.

- :mod:`~sins_align.estimators.quasi_static`: self-alignment on a still or swaying base
  (gyrocompassing, the paper's damped mechanization and constant-matrix Kalman filter).
- :mod:`~sins_align.estimators.in_motion`: alignment on a moving base from a velocity
  reference (GNSS velocity or a master INS; left-invariant error-state filter, a bank of
  heading hypotheses while the heading is unknown). Besides the common interface it takes
  ``add_velocity``, ``add_position`` and ``add_attitude`` and reports
  ``heading_observable`` and the bias estimates.
"""
