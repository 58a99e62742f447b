"""The velocity-reference data path of an in-motion alignment, shared by align_node and replay.

A :class:`ReferenceFeed` takes the velocity-reference and NavSatFix messages (rclpy or rosbags
objects), turns them into estimator inputs with :mod:`sins_align.io.velocity` (the same stamp
clock as the IMU samples) and hands them to the estimator through the
:class:`~sins_align.estimators.session.AlignmentSession`; it counts what happened to each
(used, refused by the conversion with a reason, rejected by the estimator). The node's
callbacks and the replay loop call the same two methods, so both give the estimator the same
numbers. No ROS imports here.
"""
from __future__ import annotations

from collections import Counter
from typing import Callable

from sins_align.core.rotation import dcm_from_quat
from sins_align.io.velocity import Refused, from_navsat, velocity_from_message
from sins_align.ros.params import VelocityReference

#: s without a velocity message while IMU data comes before the node warns and its
#: diagnostics say so (wall time in the node, data time in replay's diagnostics)
VELOCITY_SILENCE = 2.0

#: What a refused message means, for the node's throttled warnings (io.velocity reasons).
REFUSE_TEXT = {
    "nonfinite": "NaN or Inf in the velocity, its covariance or the position",
    "negative_variance": "negative variance in the covariance",
    "covariance_not_psd": "covariance not positive semi-definite",
    "bad_orientation": "Odometry orientation is not a unit quaternion: its twist (in "
                       "child_frame_id) cannot be rotated into the world frame",
    "no_fix": "NavSatFix without a fix (status < 0)",
}


class ReferenceFeed:
    """Velocity-reference and position messages into ``session`` (see the module docstring).

    Parameters
    ----------
    session : the :class:`~sins_align.estimators.session.AlignmentSession` of an in-motion
        estimator (``add_velocity``, ``add_position``, ``add_attitude``).
    reference : the :class:`~sins_align.ros.params.VelocityReference` (type and frame).
    clock : ``clock(sec, nanosec) -> s``, the one the IMU samples go through.
    on_refused : optional ``callback(topic kind, reason, text)`` for a refused message
        ('velocity' or 'navsat'), e.g. the node's throttled warnings.

    Counters (over the feed's life): ``velocity_received``, ``velocity_used``,
    ``position_received``, ``position_used``, ``attitude_used``; ``refused`` (Counter of
    '<kind>_<reason>'), ``rejected`` (estimator refusals: velocity, position, attitude);
    ``last_velocity_stamp`` (s, the clock's) and ``last_reason``.
    """

    def __init__(self, session, reference: VelocityReference,
                 clock: Callable[[int, int], float],
                 on_refused: Callable[[str, str, str], None] | None = None):
        self.session = session
        self.reference = reference
        self.clock = clock
        self.on_refused = on_refused
        self.velocity_received = 0
        self.velocity_used = 0
        self.position_received = 0
        self.position_used = 0
        self.attitude_used = 0
        self.refused: Counter[str] = Counter()
        self.rejected: Counter[str] = Counter()
        self.last_velocity_stamp: float | None = None
        self.last_reason = ""

    def _refuse(self, kind: str, e: Refused) -> bool:
        self.refused[f"{kind}_{e.reason}"] += 1
        self.last_reason = f"{kind}: {e}"
        if self.on_refused is not None:
            self.on_refused(kind, e.reason, str(e))
        return False

    def on_velocity(self, msg) -> bool:
        """One message of the velocity topic; True when the estimator took its velocity."""
        self.velocity_received += 1
        ref = self.reference
        try:
            velocity, attitude = velocity_from_message(ref.type, msg, ref.frame, self.clock)
        except Refused as e:
            return self._refuse("velocity", e)
        self.last_velocity_stamp = velocity.stamp
        ok = self.session.add_velocity(*velocity)
        if ok:
            self.velocity_used += 1
        else:
            self.rejected["velocity"] += 1
        if attitude is not None:
            t, q, cov = attitude
            if cov is not None:
                # the estimator takes the attitude noise about the master's body axes
                C = dcm_from_quat(q)
                cov = C.T @ cov @ C
            if self.session.add_attitude(t, q, cov):
                self.attitude_used += 1
            else:
                self.rejected["attitude"] += 1
        return ok

    def on_navsat(self, msg) -> bool:
        """One NavSatFix; True when the estimator took the position."""
        self.position_received += 1
        try:
            position = from_navsat(msg, self.clock)
        except Refused as e:
            return self._refuse("navsat", e)
        if self.session.add_position(*position):
            self.position_used += 1
            return True
        self.rejected["position"] += 1
        return False

    def counts(self) -> dict:
        """The counters as a plain dict (replay's summary, the diagnostics)."""
        return {
            "velocity_received": self.velocity_received,
            "velocity_used": self.velocity_used,
            "position_received": self.position_received,
            "position_used": self.position_used,
            "attitude_used": self.attitude_used,
            "refused": dict(sorted(self.refused.items())),
            "rejected_by_estimator": dict(sorted(self.rejected.items())),
        }
