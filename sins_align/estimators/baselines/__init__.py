"""Published alignment filters beside ours, for the comparison studies (issue 13; numpy only,
nothing here imports ROS).

- :mod:`~sins_align.estimators.baselines.unscented`: sigma points, the linear Kalman update,
  the strong-tracking fading factor, a linear-Gaussian model for checks.
- :mod:`~sins_align.estimators.baselines.euler_model`: seed 004's large-azimuth Euler-error
  model and the open-loop damped mechanization it describes.
- :mod:`~sins_align.estimators.baselines.filters`: UKF, UPF and adaptive UPF on that model,
  one interface (``run(dt, gyro, accel, C_est0)``), vectorised over Monte Carlo runs.
"""
from sins_align.estimators.baselines.euler_model import (EulerErrorModel, dcm_euler, euler_dcm,
                                                         mechanize_static)
from sins_align.estimators.baselines.filters import (BASELINES, AdaptiveUPF, BaselineConfig,
                                                     BaselineResult, UKF, UPF)
from sins_align.estimators.baselines.unscented import (LinearGaussianModel, SigmaPoints,
                                                       kalman_filter)

__all__ = ["BASELINES", "AdaptiveUPF", "BaselineConfig", "BaselineResult", "UKF", "UPF",
           "EulerErrorModel", "euler_dcm", "dcm_euler", "mechanize_static",
           "LinearGaussianModel", "SigmaPoints", "kalman_filter"]
