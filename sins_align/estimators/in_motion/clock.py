"""The IMU's sample instants from jittering stamps (numpy only).

An IMU samples at a steady rate; each sample is the mean rate and specific force over its
interval. Many drivers stamp a message when it is received (USB, serial), so the stamps
jitter by a few ms around the sampling instants while the samples do not. The strapdown
integrates each sample over its interval; over the stamps' intervals, sample ``k`` gets
``f_k (e_k - e_(k-1))`` too much, ``e`` the stamps' errors, which adds up to
``-sum e_k (f_(k+1) - f_k)``: a random walk as large as the sample-to-sample change of the
samples. On a vibrating IMU that is huge: 3 m/s^2 RMS at 20-80 Hz, stamps +-10 % of a
100 Hz interval (uniform) make ~0.03 m/s/sqrt(s), 60 x the velocity random walk of seed
003's accelerometer; the filter took it for tilt (seed 003's UAV, 60 s: 56-80 % of the
instants beyond 3 sigma at +-10 %, 82-97 % at +-20 %; honest without the vibration, whose
sample-to-sample change is the noise's only).

:class:`SampleClock` gives each accepted stamp the instant of a steady clock fitted to the
stamps: a straight line over the sample count (least squares, each sample's weight
decaying by ``1/e`` over :data:`MEMORY` s), the count advancing by the whole number of
intervals nearest to the stamp's distance from the clock (lost samples leave it one
interval more each). The filter integrates over the clock's intervals (one interval for
a sample, a whole number of them across a hole); a hole is a stamp a whole interval or
more beyond the clock rather than an interval 1.5 x the nominal one (which +-40 % jitter
passed 7 % of the time). A stamp within :data:`TOLERANCE` of the clock is kept as it is,
and while every stamp is (stamps from the IMU's own clock), the stamps go through
untouched, without the per-sample fit: the same figures bit for bit as without the clock.

What a stamp's error can be: a uniform or Gaussian jitter about the instant (half the
interval or less: every hole is counted right), a reception delay (positive; the clock
follows the stamps' mean, so a delay that exceeds it by half an interval counts one sample
more, and the next stamps, early against the clock, give the time back over the memory).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["SampleClock", "MEMORY", "TOLERANCE", "START"]

#: s: the weight of a stamp in the clock's fit decays by 1/e over this long
MEMORY = 1.0
#: a stamp within this fraction of the interval of the clock is kept as it is
TOLERANCE = 1e-4
#: intervals over which the instants given are drawn to the fit (a count too many, a
#: reception delay mistaken for a lost sample, is given back so)
GIVE_BACK = 8.0
#: stamps given as they are before the clock starts (its first line is through them)
START = 16


class SampleClock:
    """The sampling instants of a steady IMU from its stamps (see the module docstring).

    :meth:`times` maps accepted stamps (in order) to instants; :attr:`period` is the
    clock's interval (None before :data:`START` stamps), :attr:`jittering` whether the
    stamps are being replaced, :attr:`rms` the RMS of the stamps about the clock (s) since
    it began to replace them."""

    def __init__(self):
        self.period: float | None = None
        self.jittering = False
        self.rms = 0.0
        self._early: list = []               # the first stamps (given as they are)
        self._last: float | None = None      # the last instant given
        self._ref = 0.0                      # the fit's instant at the last count
        self._wait = 0.0                     # lost samples counted, not confirmed
        self._owed = 0.0                     # lost samples counted, not bridged yet
        self._seen = 0                       # stamps on the steady clock in a row
        self._sums: list | None = None       # (S0, S1, S2, Sy, Sky) of the fit
        self._lam = 0.0
        self._r2 = [0.0, 0]

    def times(self, t) -> np.ndarray:
        """The instants of the accepted stamps ``t`` (n,) (increasing)."""
        t = np.asarray(t, dtype=float)
        n = len(t)
        if not n:
            return t
        if self.period is None:
            # the first START stamps are given as they are (the filter starts later); then
            # the clock is a line through them, one interval apart
            k = min(n, START - len(self._early))
            self._early.extend(t[:k].tolist())
            self._last = float(t[k - 1])
            if len(self._early) < START:
                return t
            e = np.array(self._early)
            d = np.diff(e)
            T = float(np.median(d))
            if np.all(np.abs(d - np.maximum(np.rint(d / T), 1.0) * T) <= TOLERANCE * T):
                self.period, self._seen = T, len(e)
            else:
                self._start_fit(e)
            if k == n:
                return t
            return np.concatenate((t[:k], self.times(t[k:])))
        if not self.jittering:
            if n == 1:                      # (a live stream's sample, in floats)
                s = float(t[0])
                d = s - self._last
                T = self.period
                m = max(round(d / T), 1)
                if abs(d - m * T) <= TOLERANCE * T:
                    if m == 1:
                        self.period = d
                    self._last = s
                    self._seen += 1
                    return t
            d = np.diff(np.concatenate(([self._last], t)))
            T = self.period
            m = np.maximum(np.rint(d / T), 1.0)
            if np.all(np.abs(d - m * T) <= TOLERANCE * T):
                single = np.flatnonzero(m == 1.0)
                if len(single):
                    self.period = float(d[single[-1]])
                self._last = float(t[-1])
                self._seen += n
                return t
            # off the clock: the fit starts from the steady clock so far (the stamps that
            # lay on it, up to MEMORY s of them)
            j = int(np.argmax(np.abs(d - m * T) > TOLERANCE * T))
            if j:
                self.times(t[:j])
            c = min(self._seen, max(2, int(round(MEMORY / self.period))))
            self._start_fit(self._last - self.period * np.arange(c - 1, -1, -1.0))
            out = np.empty(n)
            out[:j] = t[:j]
            for i, s in enumerate(t[j:].tolist()):
                out[j + i] = self._one(s)
            return out
        out = np.empty(n)
        for i, s in enumerate(t.tolist()):
            out[i] = self._one(s)
        return out

    def _start_fit(self, e):
        """The fit through the stamps ``e`` (one interval apart, the last at count 0)."""
        self._lam = math.exp(-1.0 / max(2.0, MEMORY / ((e[-1] - e[0]) / (len(e) - 1))))
        k = np.arange(1 - len(e), 1, dtype=float)
        w = self._lam ** -k
        y = e - e[-1]
        S0, S1, S2, Sy, Sky = w.sum(), w @ k, w @ (k * k), w @ y, w @ (k * y)
        det = S0 * S2 - S1 * S1
        a = (Sy * S2 - S1 * Sky) / det
        self.period = (S0 * Sky - S1 * Sy) / det
        # (the times' origin: the clock at the last stamp)
        self._sums = [S0, S1, S2, Sy - a * S0, Sky - a * S1]
        self._ref = float(e[-1]) + a
        self.jittering = True
        self._seen = 0
        self._wait = self._owed = 0.0

    def _one(self, s: float) -> float:
        """The instant of one stamp (the per-sample fit)."""
        S0, S1, S2, Sy, Sky = self._sums
        lam, T, ref, last = self._lam, self.period, self._ref, self._last
        a = (Sy * S2 - S1 * Sky) / (S0 * S2 - S1 * S1)   # the fit at the last count
        # the count moves on by the whole intervals nearest to the stamp's distance: one at
        # least, less the lost samples counted but not confirmed yet (a stamp that comes
        # early against them says a stamp before was late, not that samples were lost)
        m = max(1.0 - self._wait, float(round((s - ref - a) / T)))
        S2 = S2 - 2.0 * m * S1 + m * m * S0
        S1 = S1 - m * S0
        Sky = Sky - m * Sy
        dec = lam ** m
        S0, S1, S2, Sy, Sky = S0 * dec + 1.0, S1 * dec, S2 * dec, Sy * dec, Sky * dec
        Sy += s - ref
        det = S0 * S2 - S1 * S1
        T = (S0 * Sky - S1 * Sy) / det
        a = (Sy * S2 - S1 * Sky) / det
        fit = ref + a
        # the instant: one interval on, and the lost samples owed. A stamp that counts one
        # lost sample waits for the next stamp to confirm it (one interval on from the
        # count; a stamp late by more than half an interval looks the same until then) and
        # it is bridged there; more than one is bridged at once (no stamp is that late)
        wait, owed = self._wait + m - 1.0, self._owed
        if m == 1.0:                        # on time: what was counted is confirmed
            bridged, owed, wait = owed, 0.0, 0.0
        elif m == 2.0:
            bridged, owed = 0.0, owed + 1.0
        elif m > 2.0:
            bridged, owed = owed + m - 1.0, 0.0
        else:                               # early: a stamp before was late
            bridged, owed = 0.0, min(owed, max(wait, 0.0))
        self._wait, self._owed = wait, owed
        x = last + (1.0 + bridged) * T
        # drawn towards the fit (less what is owed) over GIVE_BACK intervals
        x += (fit - owed * T - x) / GIVE_BACK
        r = s - x
        if abs(r) <= TOLERANCE * T:
            x = s
            self._seen += 1
        else:
            self._seen = 0
            self._r2[0] += r * r
            self._r2[1] += 1
            self.rms = math.sqrt(self._r2[0] / self._r2[1])
        if x <= last:                       # (kept increasing)
            x = last + 0.5 * T
        self._sums = [S0, S1, S2, Sy - a * S0, Sky - a * S1]
        self._ref = fit
        self._last = x
        self.period = T
        if self._seen >= S0:                # back on the IMU's own clock: untouched again
            self.jittering = False
            self._sums = None
        return x
