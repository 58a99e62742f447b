"""The data-path rules every front applies around an estimator (align_node, replay).

An :class:`AlignmentSession` owns one estimator (anything with the interface of
:mod:`sins_align.estimators`: ``update``, ``reset``, ``subscribe``, ``t_last``, ``aligned``,
``config.max_gap``; an in-motion one also ``add_velocity``, ``add_position``,
``add_attitude``, passed on by the methods of the same names) and decides, the same way for
the live node and for replay:

- whether a sample was accepted (republished): no 'rejected' event while it was processed;
- when the input has restarted: :data:`BACKWARD_JUMP_CONFIRM` stamps in a row more than
  ``max_gap`` behind the last accepted one (a bag loop, a restarted driver; one old stamp is
  only a rejected sample), or a restart asked for (the reset service, ROS time set back),
  applied before the next sample;
- when to publish the aligned flag: whenever it differs from the value published last
  (:meth:`flag_to_publish`); and, when asked for, every change with the stamp of the sample at
  which it happened (:meth:`take_flag_changes`), so replay can name that sample on the block
  path too.

Restarts are counted here (:attr:`resets`, :attr:`last_reset_reason`); the estimator's own
counters (``rejected``, ``events``) run over its life.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

#: consecutive stamps more than max_gap behind the last accepted one that mean a restart
BACKWARD_JUMP_CONFIRM = 3


class AlignmentSession:
    """One estimator and the data-path rules around it (see the module docstring).

    Parameters
    ----------
    estimator : the estimator (e.g. :class:`~sins_align.estimators.quasi_static.Aligner`).
    on_event : optional ``callback(event)`` for every event of the estimator (rejections,
        restarts, flag changes), e.g. the node's throttled warnings.
    record_flag_changes : keep every change of the flag for :meth:`take_flag_changes`.
    """

    def __init__(self, estimator, on_event: Callable | None = None,
                 record_flag_changes: bool = False):
        self.estimator = estimator
        self.resets = 0
        self.last_reset_reason = ""
        self._on_event = on_event
        self._restart_request: str | None = None
        self._back_run = 0
        self._rejections = 0
        self._record = record_flag_changes
        self._flag_changes: list[tuple[float | None, bool]] = []
        self._published: bool | None = None
        #: restarts of the last :meth:`feed_block_states` call
        self.block_restarts: list[tuple[int, int, str]] = []
        estimator.subscribe(self._event)

    def _event(self, event) -> None:
        if event.kind == "rejected":
            self._rejections += 1
        elif event.kind == "aligned" and self._record:
            self._flag_changes.append((event.stamp, bool(event.value)))
        if self._on_event is not None:
            self._on_event(event)

    # -------------------------------------------------------------- restarts
    def request_restart(self, why: str) -> None:
        """Restart before the next sample (safe to call from another callback)."""
        self._restart_request = why

    def restart(self, why: str) -> None:
        """Start the alignment over now (the estimator's counters are kept)."""
        self._restart_request = None
        self._back_run = 0
        self.estimator.reset(why)
        self.resets += 1
        self.last_reset_reason = why

    def _jumped_back(self, t: float) -> bool:
        """One more stamp far behind the last accepted one: True on the confirming one."""
        last = self.estimator.t_last
        if last is None or not math.isfinite(t) or t >= last - self.estimator.config.max_gap:
            self._back_run = 0
            return False
        self._back_run += 1
        return self._back_run >= BACKWARD_JUMP_CONFIRM

    def _before(self, t: float) -> None:
        if self._restart_request:
            self.restart(self._restart_request)
        if self._jumped_back(t):
            self.restart(f"input stamps jumped back by {self.estimator.t_last - t:.3f} s")

    # -------------------------------------------------------------- samples
    def feed(self, t: float, w, f) -> bool:
        """One sample; True when it was accepted (to be republished), False when rejected."""
        self._before(t)
        n = self._rejections
        self.estimator.update(t, w, f)
        return self._rejections == n

    def feed_block(self, t: np.ndarray, w: np.ndarray, f: np.ndarray) -> int:
        """Samples in order, with the same results as :meth:`feed` one at a time; returns
        how many were accepted. Whole runs go to the estimator in one ``update`` call; a
        sample that could be far behind the last accepted stamp is handled alone, as
        :meth:`feed` does (the estimator's ``t_last`` never exceeds the largest stamp seen,
        so a sample not below that bound minus ``max_gap`` cannot be one)."""
        n = len(t)
        if n == 0:
            return 0
        if self._restart_request:
            self.restart(self._restart_request)
        accepted, k = 0, 0
        for b in self._alone(t) + [n]:
            if b > k:
                self._back_run = 0
                r = self._rejections
                self.estimator.update(t[k:b], w[k:b], f[k:b])
                accepted += (b - k) - (self._rejections - r)
            if b < n:
                accepted += self.feed(float(t[b]), w[b], f[b])
            k = b + 1
        return accepted

    def _alone(self, t: np.ndarray) -> list[int]:
        """Indices of the samples of a block that could be far behind the last accepted
        stamp (below the largest stamp seen before them minus ``max_gap``): the block
        paths hand those to :meth:`feed` alone."""
        finite = np.isfinite(t)
        tl = self.estimator.t_last
        bound = np.maximum.accumulate(np.concatenate((
            [-np.inf if tl is None else tl], np.where(finite[:-1], t[:-1], -np.inf))))
        return np.flatnonzero(finite & (t < bound - self.estimator.config.max_gap)).tolist()

    def feed_block_states(self, t: np.ndarray, w: np.ndarray, f: np.ndarray, want=None,
                          views=None):
        """:meth:`feed_block` for an estimator with ``update_states`` (the quasi-static
        Aligner): the same samples and results, and the estimator's outputs after each
        sample (its ``SampleStates``; ``accepted`` marks the samples :meth:`feed` would
        call accepted; ``want``: the samples whose outputs are needed, default all;
        ``views``: the samples after which the estimator's ``view()`` is wanted).

        :attr:`block_restarts` lists the restarts of the call as ``(sample index (-1:
        before the first), resets, last_reset_reason)`` after each."""
        est = self.estimator
        n = len(t)
        from sins_align.estimators.quasi_static.aligner import SampleStates

        out = SampleStates.empty(n)
        self.block_restarts: list[tuple[int, int, str]] = []
        if n == 0:
            return out
        if self._restart_request:
            self.restart(self._restart_request)
            self.block_restarts.append((-1, self.resets, self.last_reset_reason))
        k = 0
        for b in self._alone(t) + [n]:
            if b > k:
                self._back_run = 0
                st = est.update_states(t[k:b], w[k:b], f[k:b],
                                       None if want is None else want[k:b],
                                       None if views is None else views[k:b])
                for name in ("accepted", "dcm", "covariance", "aligned", "started"):
                    getattr(out, name)[k:b] = getattr(st, name)
                out.used += st.used
                out.views.update((k + i, v) for i, v in st.views.items())
            if b < n:
                resets = self.resets
                accepted = self.feed(float(t[b]), w[b], f[b])
                if self.resets != resets:
                    self.block_restarts.append((b, self.resets, self.last_reset_reason))
                out.record(b, est, accepted, views is not None and views[b])
            k = b + 1
        return out

    # -------------------------------------------------------------- aiding measurements
    def add_velocity(self, t: float, v_enu, cov=None) -> bool:
        """A velocity measurement (ENU, m/s) for an in-motion estimator; True when it was
        taken. A restart asked for is applied first, as before a sample."""
        return self._measurement(self.estimator.add_velocity, t, v_enu, cov)

    def add_position(self, t: float, lat_deg: float, lon_deg: float, height_m: float) -> bool:
        """A position fix for an in-motion estimator; True when it was taken."""
        return self._measurement(self.estimator.add_position, t, lat_deg, lon_deg, height_m)

    def add_attitude(self, t: float, quaternion_xyzw, cov=None) -> bool:
        """A master INS attitude (body in ENU) for an in-motion estimator; True when taken."""
        return self._measurement(self.estimator.add_attitude, t, quaternion_xyzw, cov)

    def _measurement(self, add, t, *values) -> bool:
        if self._restart_request:
            self.restart(self._restart_request)
        n = self._rejections
        try:
            return bool(add(t, *values))
        finally:
            # a refused measurement is no rejected sample: feed() counts samples only
            self._rejections = n

    def flag_to_publish(self) -> bool | None:
        """The aligned flag if it is to be published now (it differs from the value this
        returned last, or it was never returned), else None."""
        value = bool(self.estimator.aligned)
        if value == self._published:
            return None
        self._published = value
        return value

    def flags_to_publish(self, aligned: np.ndarray) -> np.ndarray:
        """:meth:`flag_to_publish` after each sample of a block, given the flag after each
        (``SampleStates.aligned``): the indices of the samples after which it is published."""
        a = np.asarray(aligned, dtype=bool)
        if len(a) == 0:
            return np.empty(0, dtype=np.int64)
        prev = np.empty(len(a), dtype=bool)
        prev[1:] = a[:-1]
        at = np.flatnonzero(a != prev)
        if self._published is None or a[0] != self._published:
            at = np.concatenate(([0], at[at > 0]))
        else:
            at = at[at > 0]
        self._published = bool(a[-1])
        return at

    def take_flag_changes(self) -> list[tuple[float | None, bool]]:
        """The changes of the aligned flag since the last call, oldest first:
        ``(stamp of the sample at which it changed (None: at a restart with no sample),
        new value)``."""
        out, self._flag_changes = self._flag_changes, []
        return out
