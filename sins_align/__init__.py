"""sins_align: strapdown INS self-alignment on a quasi-static base.

Roll and pitch from gravity, true heading from Earth rate (no magnetometer), from any
initial attitude. The numpy core has no ROS dependency:

>>> from sins_align import Aligner, AlignConfig
>>> al = Aligner(AlignConfig(latitude_deg=34.0, specs="navigation"))
>>> al.update(t, gyro, accel)     # s, rad/s (N, 3), m/s^2 (N, 3) — one sample or a block
>>> al.quaternion                 # [x, y, z, w] of C_b^n: IMU frame in ENU
>>> al.covariance                 # attitude-error covariance on E/N/U, rad^2 (bias floor included)
>>> al.aligned, al.status, al.rejected

Packages: ``core`` (rotation, earth, specs, models, kalman, preint), ``estimators``
(``quasi_static``: Aligner, AlignmentFilter, AlignConfig), ``io`` (bags, CDR, PSINS logs),
``sim`` (IMU simulator with truth, disturbance matrix), ``ros`` (align_node, imu_sim_node,
parameters, outputs, demo), ``tools`` (replay, simulate, import_imu, montecarlo), ``data``
(the real laser-gyro log).
"""
from sins_align.core.specs import (GRADES, SensorSpecs, grade_specs, limit_covariance,
                                   limit_error, limit_std)
from sins_align.estimators.quasi_static import (REJECT_REASONS, STATES, AlignConfig, Aligner,
                                                AlignmentFilter)

__all__ = ["Aligner", "AlignConfig", "AlignmentFilter", "REJECT_REASONS", "STATES", "GRADES",
           "SensorSpecs", "grade_specs", "limit_covariance", "limit_error", "limit_std"]
__version__ = "0.1.0"
