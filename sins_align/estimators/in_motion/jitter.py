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

What it does not cover: the accelerometer's vibration makes the IMU velocity jitter too
(~0.012 m/s with 3 m/s^2 RMS); sampled by the velocity updates it aliases to slow errors
that the filter takes for tilt (``test/test_in_motion_jitter.py``, an expected failure).

Windows are delimited by the stamps alone, so a stream fed sample by sample and the same
stream fed in blocks give the same figures at every sample.
"""
from __future__ import annotations

import numpy as np

__all__ = ["JitterMonitor", "WINDOW", "CUTOFF"]

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
