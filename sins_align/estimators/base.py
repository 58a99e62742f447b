"""What every estimator has the same way.

- :class:`AlignmentEvent` and :class:`EventSource`: ``subscribe`` and the events an estimator
  tells its subscribers (the aligned flag changed, a restart, a rejected input with its
  reason), and the rejection counters (``rejected``, ``last_reject``,
  ``reject_undecodable``). The class sets ``_listeners`` (a list) and ``rejected`` (a
  Counter) in its constructor.
- :class:`AttitudeReadout`: ``quaternion``, ``rpy_deg``, ``heading_deg`` and ``std_enu_deg``
  for a class that defines ``dcm`` (C_b^n, (3, 3)) and ``covariance`` (E/N/U attitude
  error, rad^2), and ``orientation_values`` (the two as 13 floats, what the fronts publish
  after every sample; a class may compute it faster itself).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sins_align.core.rotation import heading_from_dcm, quat_from_dcm, rpy_from_dcm
from sins_align.core.specs import DEG

__all__ = ["AlignmentEvent", "AttitudeReadout", "EventSource"]


@dataclass(frozen=True)
class AlignmentEvent:
    """One event of an estimator: ``kind`` ('aligned', 'restarted', 'rejected'), ``stamp``
    (s, of the sample being processed; None when there is none) and ``value`` (the new flag,
    or a reason)."""
    kind: str
    stamp: float | None
    value: bool | str


class EventSource:
    """Mixin: subscriptions, events and rejection counting."""

    _listeners: list
    rejected: dict

    def subscribe(self, callback: Callable[[AlignmentEvent], None]) -> None:
        """Call ``callback(event)`` for every :class:`AlignmentEvent` from now on (the
        aligned flag changed, a restart, a rejected input), in the order they happen, on
        the per-sample and the block path alike. Subscriptions survive ``reset``."""
        self._listeners.append(callback)

    def _emit(self, kind: str, stamp: float | None, value) -> None:
        if self._listeners:
            event = AlignmentEvent(kind, stamp, value)
            for callback in self._listeners:
                callback(event)

    def _reject(self, reason: str, stamp: float | None = None) -> int:
        """Count a rejected input, remember the reason, tell the subscribers; 0 (accepted
        samples) for the callers that return it."""
        self.rejected[reason] += 1
        self.last_reject = reason
        self._emit("rejected", stamp, reason)
        return 0

    def reject_undecodable(self) -> None:
        """Count an input message that could not be decoded into a sample at all (reason
        ``undecodable``); the state is not touched."""
        self._reject("undecodable")


class AttitudeReadout:
    """Mixin: the attitude in the forms the fronts publish."""

    dcm: np.ndarray
    covariance: np.ndarray

    @property
    def quaternion(self) -> np.ndarray:
        """Orientation of the IMU frame in ENU, [x, y, z, w] (C_b^n, as imu_filter_madgwick)."""
        return quat_from_dcm(self.dcm)

    def orientation_values(self) -> list[float]:
        """:attr:`quaternion` [x, y, z, w] then :attr:`covariance` (9, row-major): 13 floats."""
        return self.quaternion.tolist() + np.asarray(self.covariance, dtype=float).reshape(
            -1).tolist()

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
