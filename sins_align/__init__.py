"""sins_align: strapdown INS self-alignment on a quasi-static base.

Roll and pitch from gravity, true heading from Earth rate (no magnetometer), from any
initial attitude. The numpy core has no ROS dependency:

>>> from sins_align import Aligner, AlignConfig
>>> al = Aligner(AlignConfig(latitude_deg=34.0, specs="navigation"))
>>> al.update(t, gyro, accel)     # s, rad/s (N, 3), m/s^2 (N, 3) — one sample or a block
>>> al.quaternion                 # [x, y, z, w] of C_b^n: IMU frame in ENU
>>> al.covariance                 # attitude-error covariance on E/N/U, rad^2 (bias floor included)
>>> al.aligned, al.status, al.rejected

Modules: ``estimator`` (Aligner, AlignmentFilter, AlignConfig), ``models`` (the paper's three
error models), ``kalman``, ``rotation``, ``earth``, ``specs`` (grades, limit accuracy),
``sim`` (IMU simulator with truth), ``psins`` (PSINS log reader). The ROS nodes and tools
(``align_node``, ``imu_sim_node``, ``replay``, ``simulate``, ``import_imu``) sit on top.
"""
from .estimator import REJECT_REASONS, STATES, AlignConfig, Aligner, AlignmentFilter
from .specs import GRADES, SensorSpecs, grade_specs, limit_covariance, limit_error, limit_std

__all__ = ["Aligner", "AlignConfig", "AlignmentFilter", "REJECT_REASONS", "STATES", "GRADES",
           "SensorSpecs", "grade_specs", "limit_covariance", "limit_error", "limit_std"]
__version__ = "0.1.0"
