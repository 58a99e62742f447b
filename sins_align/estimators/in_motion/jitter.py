"""The attitude jitter that high-frequency gyro content puts on the estimate (numpy only).

The filter's error model knows the gyro's white noise and biases. A vibrating IMU (a rotor
UAV, an engine) adds a large, band-limited content to every sample; at the sample rate much
of it is aliased (a 60 Hz tone shows at 40 Hz in 100 Hz samples). The strapdown integrates
it, and the attitude it gives carries that vibration's angle: a jitter of about
``rate / (2 pi f)`` that the covariance of the filter does not contain (0.008 deg RMS on
each level axis with 2 deg/s RMS at 20-80 Hz, as large as the level std the velocity
reference supports). Whether the vibration is the body's real motion (then the estimate
follows it) or an error of the sensor, the estimate cannot be trusted below it.

:class:`JitterMonitor` measures it from the samples themselves: over windows of
:data:`WINDOW` s, the integrated angle of each gyro axis, detrended by a cubic in time and
tapered (Hann), and its power at :data:`CUTOFF` Hz and above (manoeuvres live below it;
what a manoeuvre leaks through the taper stays below 0.004 deg: a yaw rate reaching 30 deg/s
in 0.5 s, a +-10 deg roll at 0.5 Hz, a 1 deg one at 2 Hz). The 3 x 3 covariance (body
axes) of the larger of the last two windows is what
:class:`~sins_align.estimators.in_motion.aligner.MotionAligner` adds to the published
attitude covariance. A white-noise gyro adds almost nothing (0.0002 deg for a
0.1 deg/sqrt(h) MEMS).

The accelerometer's vibration makes the IMU velocity jitter in the same way (~0.012 m/s
with 3 m/s^2 RMS at 20-80 Hz: ``a / (2 pi f)``). The truth does not vibrate, nor does a
velocity reference (GNSS Doppler is averaged over the receiver's interval), so each velocity
update samples that jitter, and a tone near a multiple of the update rate aliases into a
slow velocity error that the filter takes for tilt. :class:`VelocityJitter` estimates the
jitter at the update's sample from the accelerometer samples of the reference's interval
before it (``MotionConfig.velocity_averaging``); the aligner compares the reference with
the IMU velocity less it (rotated to ENU by each filter's attitude). Seed 003's UAV with the
accelerometer vibrating, 120 s, 16 seeds: the attitude error is beyond 3 sigma at 1.77 %
of the instants uncorrected, 1.07 % corrected, 1.27 % with the vibration taken out of the
samples (``test/test_in_motion_jitter.py``).

Windows are delimited by the stamps alone, so a stream fed sample by sample and the same
stream fed in blocks give the same figures at every sample.
"""
from __future__ import annotations

import numpy as np

from sins_align.estimators.in_motion.gaps import GAP_RATIO

__all__ = ["JitterMonitor", "VelocityJitter", "WINDOW", "CUTOFF"]

#: s of samples per window
WINDOW = 1.0
#: Hz: content of the integrated angle at and above this counts as jitter
CUTOFF = 5.0
#: fewer samples than this in a window (a very slow stream): no figure from it
_MIN_SAMPLES = 16


class JitterMonitor:
    """Attitude jitter from the high-frequency content of the gyro samples.

    Feed it every accepted sample, in order (:meth:`add`); :attr:`covariance` is the jitter
    covariance (3, 3), rad^2, body axes (zeros until a window is complete)."""

    def __init__(self):
        self.covariance = np.zeros((3, 3))
        self._last = np.zeros((3, 3))           # the last window's covariance
        self._t0: float | None = None           # the current window's first stamp
        self._t_before: float | None = None     # the stamp before the current window's
        self._t: list = []                      # the current window's stamps and rates
        self._w: list = []

    def add(self, t, w) -> None:
        """Accepted samples: stamps t (n,) s, increasing; rates w (n, 3) rad/s."""
        t = np.asarray(t, dtype=float).reshape(-1)
        w = np.asarray(w, dtype=float).reshape(-1, 3)
        if len(t) == 1 and self._t0 is not None and t[0] < self._t0 + WINDOW:
            # (a live stream: one sample inside the window; what the loop below does)
            self._t.append(t)
            self._w.append(w)
            return
        i = 0
        while i < len(t):
            if self._t0 is None:
                self._t0 = float(t[i])
            # the first sample at or beyond the window's end closes it (it is the window's)
            j = int(np.searchsorted(t, self._t0 + WINDOW, "left"))
            end = min(j + 1, len(t))
            self._t.append(t[i:end])
            self._w.append(w[i:end])
            if j < len(t):
                self._close()
            i = end

    def _close(self) -> None:
        t = np.concatenate(self._t)
        w = np.concatenate(self._w)
        prev = self._t_before
        self._t, self._w, self._t0 = [], [], None
        self._t_before = float(t[-1])
        n = len(t)
        if n < _MIN_SAMPLES:
            return
        dt = np.diff(np.concatenate(([t[0] if prev is None else prev], t)))
        theta = np.cumsum(w * dt[:, None], axis=0)
        x = (t - t[0]) / max(t[-1] - t[0], 1e-12)
        basis = np.column_stack([np.ones(n), x, x * x, x * x * x])
        coef, *_ = np.linalg.lstsq(basis, theta, rcond=None)
        r = theta - basis @ coef
        taper = np.hanning(n + 2)[1:-1]
        spec = np.fft.rfft(r * taper[:, None], axis=0)
        rate = (n - 1) / max(t[-1] - t[0], 1e-12)
        k0 = int(np.ceil(CUTOFF * n / rate))
        hi = spec[k0:]
        # one-sided power of the tapered series at and above the cut-off, per sample and
        # undone for the taper's mean power (Parseval)
        scale = 2.0 / (n * n * float(np.mean(taper * taper)))
        cov = scale * (hi.conj().T @ hi).real
        cov = 0.5 * (cov + cov.T)
        self.covariance = cov if np.trace(cov) >= np.trace(self._last) else self._last
        self._last = cov


class VelocityJitter:
    """The jitter of the IMU velocity at a sample, from the accelerometer samples.

    Feed it every accepted sample, in order (:meth:`add`). :meth:`at` looks at the
    velocity integrated from the specific force (body axes) at the samples of an interval
    ``T`` before a sample (from the sample nearest to ``t - T`` to the one stamped ``t``),
    fits a straight line to it (least squares, every sample alike) and gives the velocity
    at ``t`` less the line there: zero for a velocity that changes linearly, ``j T^2 / 12``
    for a jerk ``j`` (0.001 m/s for 1 m/s^3 at T = 0.1 s), 3 % of the velocity's swing for
    a 1 Hz motion, 13 % at 2 Hz. For a tone of a few tens of Hz the line takes little of it
    (it spans two cycles or more at 20 Hz and T = 0.1 s), so the figure is the tone's
    jitter ``a / (2 pi f)`` at ``t``, whatever the tone's frequency against the interval's.

    What the velocity updates need (measured on seed 003's UAV with 3 m/s^2 of vibration,
    8 seeds): the jitter in full. An earlier form (the two ends' mean less the time-mean,
    which takes only the tones near a multiple of ``1 / T``, those that sampled every
    ``T`` s alias to a slow error) left the others in the updates, and the heading in the
    first 30 s, while the bank of hypotheses runs, came out overconfident ((e/sigma)^2 2.7
    instead of 1.2 with this form; 1.0 with the true jitter).

    What it holds and gives depends only on the stamps: a stream fed sample by sample and
    in blocks gives the same figures. ``keep`` s: how far before the newest sample (or the
    last question) the interval of a question may start (a rewind, the interval and a
    sample); older samples are dropped.
    """

    def __init__(self, keep: float):
        self.keep = float(keep)
        self._t = np.empty(0)
        self._f = np.empty((0, 3))
        self._w = np.empty((0, 3))
        self._new: list = []                     # (t, f, w) blocks not yet joined

    def add(self, t, f, w=None) -> None:
        """Accepted samples: stamps t (n,) s, increasing; specific force f (n, 3) m/s^2;
        rates w (n, 3) rad/s, or None (zeros), held for :meth:`before`."""
        t = np.asarray(t, dtype=float).reshape(-1)
        if not len(t):
            return
        f = np.asarray(f, dtype=float).reshape(-1, 3)
        w = np.zeros_like(f) if w is None else np.asarray(w, dtype=float).reshape(-1, 3)
        self._new.append((t, f, w))
        if len(self._new) >= 32:            # (questions come after this block's start)
            self._join(float(t[0]))

    def _join(self, t_query: float | None) -> None:
        """Join the new blocks; drop what is older than ``keep`` s before ``t_query`` (a
        block fed at once may reach far beyond the sample asked about) once that is as
        much again (None: drop nothing; the questions about earlier samples may follow)."""
        if self._new:
            self._t = np.concatenate([self._t] + [b[0] for b in self._new])
            self._f = np.concatenate([self._f] + [b[1] for b in self._new])
            self._w = np.concatenate([self._w] + [b[2] for b in self._new])
            self._new = []
        if t_query is not None and len(self._t) and self._t[0] < t_query - 2.0 * self.keep:
            i = int(self._t.searchsorted(t_query - self.keep, "left"))
            self._t = self._t[i:]
            self._f = self._f[i:]
            self._w = self._w[i:]

    def before(self, t_end: float, length: float):
        """The samples held (t (m,), w (m, 3), f (m, 3)) stamped within ``[t_end - length,
        t_end]`` (asked about the holes of a block before the block's measurements ask
        :meth:`at` about its earlier samples: nothing is dropped here)."""
        self._join(None)
        i0 = int(self._t.searchsorted(t_end - length, "left"))
        i1 = int(self._t.searchsorted(t_end, "right"))
        return self._t[i0:i1], self._w[i0:i1], self._f[i0:i1]

    def at(self, t: float, interval: float, nominal_dt: float | None = None):
        """(jitter (3,) m/s, mean specific force (3,) m/s^2), body axes, at the sample
        stamped ``t``, over the ``interval`` s before it (see the class); None when that
        sample is not held or the interval holds fewer than two sample intervals.

        With the samples ``t_0 .. t_n = t`` of the window, ``V_k`` the velocity integrated
        from ``t_0`` to ``t_k`` and ``L`` the least-squares line through the ``(t_k, V_k)``,
        the jitter is ``V_n - L(t)``. ``L(t) = sum_k a_k V_k`` with ``a_k = 1/(n+1) + (t_k -
        tbar) (t - tbar) / sum (t_k - tbar)^2``, and ``V_k = sum_{j<=k} f_j dt_j``, so the
        jitter is ``sum_j f_j dt_j (1 - A_j)`` with ``A_j = sum_{k>=j} a_k`` (one weight
        per sample interval).

        Lost samples (an interval above ``GAP_RATIO`` x ``nominal_dt``): the sample after
        the hole stands for one nominal interval and this window's mean specific force (its
        samples on both sides of the hole) for the rest; the filter bridges the hole with the
        samples before it only (:mod:`~sins_align.estimators.in_motion.gaps`), the
        difference being of the vibration's size over the hole. A measurement stamped
        inside a hole is applied at the made-up sample, which this does not hold: that
        update goes without the jitter correction."""
        self._join(t)
        ts = self._t
        i1 = int(ts.searchsorted(t, "right")) - 1
        if i1 < 0 or ts[i1] != t:
            return None
        # the window starts at the sample nearest to t - interval
        start = t - interval
        i0 = int(ts.searchsorted(start, "left"))
        if i0 > 0 and (i0 > i1 or start - ts[i0 - 1] < ts[i0] - start):
            i0 -= 1
        if i1 - i0 < 2:
            return None
        tw = ts[i0:i1 + 1]
        dt = tw[1:] - tw[:-1]
        T = t - tw[0]
        tc = tw - tw.mean()
        a = 1.0 / len(tw) + tc * (tc[-1] / (tc @ tc))
        A = np.cumsum(a[::-1])[::-1][1:]                  # sum_{k >= j}, j = 1 .. n
        f = self._f[i0 + 1:i1 + 1]
        dv = dt[:, None] * f                              # each interval's increment
        if nominal_dt is not None and dt.max() > GAP_RATIO * nominal_dt:
            h = dt > GAP_RATIO * nominal_dt
            dv[h] = nominal_dt * f[h] + (dt[h, None] - nominal_dt) * f.mean(axis=0)
        return (1.0 - A) @ dv, dv.sum(axis=0) / T
