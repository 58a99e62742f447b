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

The line spans 0.1 s: a tone below ~10 Hz it takes out only in part (its end value holds
129 % of a 5 Hz tone's velocity, 120 % at 7 Hz, 71 % at 10 Hz), and the latency's and lever
arm's regressors, the last sample's specific force and rate, vibrate with the same tone, so
that at 10 Hz both alias alike and those states carried it into the attitude (``car_city``
with a 5 Hz tone of 1 m/s^2 and 0.5 deg/s RMS: 39-52 % of the instants beyond 3 sigma).
:func:`fit_tones` finds one tone per axis within :data:`TONE_BAND` (a narrow, lasting peak:
vibration, not the vehicle's broadband motion) and fits it over the last
:data:`TONE_WINDOW` s together with a cubic (the vehicle's motion): the aligner takes it out
of the jitter in full (:meth:`VelocityJitter.at`'s ``tone``) and out of those regressors,
without the lag that smoothing them had (0.4 s of a 0.8 s Hann window put the real
FOG/MEMS run's east level at 3.2 sigma).

Windows are delimited by the stamps alone, so a stream fed sample by sample and the same
stream fed in blocks give the same figures at every sample.
"""
from __future__ import annotations

import functools
import math

import numpy as np

from sins_align.estimators.in_motion.gaps import GAP_RATIO

__all__ = ["JitterMonitor", "VelocityJitter", "Tones", "fit_tones", "WINDOW", "CUTOFF",
           "TONE_BAND", "TONE_WINDOW"]

#: s of samples per window
WINDOW = 1.0
#: Hz: content of the integrated angle at and above this counts as jitter
CUTOFF = 5.0
#: fewer samples than this in a window (a very slow stream): no figure from it
_MIN_SAMPLES = 16
#: Hz: the band in which :func:`fit_tones` looks for one tone per axis (the 0.1 s line of
#: :meth:`VelocityJitter.at` leaves most of a tone below ~10 Hz in the velocity updates:
#: its end value holds 1.29 of a 5 Hz tone's velocity, 1.2 at 7 Hz, 0.71 at 10 Hz)
TONE_BAND = (2.5, 10.0)
#: s of samples before the update that :func:`fit_tones` fits
TONE_WINDOW = 1.0
#: Hz: the frequency grid of the tone search (the zero-padded spectrum's spacing)
_TONE_STEP = 0.05
#: s: the tones' frequencies are searched for at the first update of each such stretch of
#: data time (on its grid, so that a stream fed sample by sample, with the rewinds of late
#: measurements, and one fed in blocks search at the same updates); the updates after it
#: fit their amplitudes and phases only (the search cost some 0.2 ms per update: a third
#: of the in-motion replay's time at 10 Hz)
TONE_SEARCH_PERIOD = 1.0
#: a tone is taken out only when its lobe (+-1 / TONE_WINDOW Hz about its peak, Hann) holds
#: at least this fraction of the band's power (a tone, not broadband motion or noise:
#: white noise passes this and the second window's test 0.8 % of the time, per axis)
_TONE_DOMINANCE = 0.5


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
        basis = _cubic(x)
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
        # (search stretch, update stamp, frequencies (6,) Hz or NaN, whether any is a
        # number) of the last search
        self._search: tuple | None = None
        self._first: float | None = None         # the first sample's stamp
        self._peaks_kept: dict = {}              # fit_tones' searches of the last windows

    def add(self, t, f, w=None) -> None:
        """Accepted samples: stamps t (n,) s, increasing; specific force f (n, 3) m/s^2;
        rates w (n, 3) rad/s, or None (zeros), held for :meth:`before`."""
        t = np.asarray(t, dtype=float).reshape(-1)
        if not len(t):
            return
        f = np.asarray(f, dtype=float).reshape(-1, 3)
        w = np.zeros_like(f) if w is None else np.asarray(w, dtype=float).reshape(-1, 3)
        if self._first is None:
            self._first = float(t[0])
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

    def tones(self, t: float, window: float = TONE_WINDOW):
        """(specific-force tones, rate tones) (:class:`Tones`, :func:`fit_tones`) of the
        samples within two ``window`` s up to the one stamped ``t``, or None (too few)."""
        k = math.floor(t / TONE_SEARCH_PERIOD)
        known = self._search
        freq = known[2] if known is not None and known[0] == k and known[1] <= t else None
        # the stream's first seconds, while the second window fills: searched at every
        # update, nothing kept (what is taken out then weighs the heading hypotheses)
        early = self._first is None or t - self._first < 2.0 * window + TONE_SEARCH_PERIOD
        if early:
            freq = None
        if freq is not None and not known[3]:
            # (no tone at this stretch's search, which had the samples: nothing to fit)
            zero = Tones(t, np.zeros(3), np.zeros(3), np.zeros(3), found=False)
            return zero, zero
        tw, ww, fw = self.before(t, 2.0 * window)
        both = fit_tones(tw, np.hstack([fw, ww]), t, window=window, freq=freq,
                         kept=self._peaks_kept)
        if both is None:
            return None
        if freq is None and not early:
            self._search = (k, t, both.freq, bool(np.isfinite(both.freq).any()))
        return (Tones(t, both.omega[:3], both.a[:3], both.b[:3]),
                Tones(t, both.omega[3:], both.a[3:], both.b[3:]))

    def spread(self, t: float, window: float = TONE_WINDOW) -> float:
        """(m/s)^2: the largest variance over the body axes of the velocity integrated from
        the samples within ``window`` s up to the one stamped ``t``, less its least-squares
        cubic in time; 0 with fewer than :data:`_MIN_SAMPLES`. What a tone too young for
        :meth:`tones` (the stream's first ``window`` s) may leave in the updates: a
        vehicle's motion over a second leaves a few mm/s, a 3 Hz tone of 1 m/s^2 RMS 0.05 m/s
        (left in the updates it weighed the heading hypotheses within the first second)."""
        tw, _, fw = self.before(t, window)
        n = len(tw)
        if n < _MIN_SAMPLES:
            return 0.0
        v = np.cumsum(fw[1:] * np.diff(tw)[:, None], axis=0)
        u = (tw[1:] - tw[1]) / max(tw[-1] - tw[1], 1e-12)
        poly = _cubic(u)
        coef, *_ = np.linalg.lstsq(poly, v, rcond=None)
        return float(np.mean((v - poly @ coef) ** 2, axis=0).max())

    def at(self, t: float, interval: float, nominal_dt: float | None = None, tone=None):
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
        update goes without the jitter correction.

        ``tone``: specific-force :class:`Tones` (:meth:`tones`) that are jitter in full;
        the line takes only part of a tone below ~10 Hz out of the velocity (it spans less
        than a cycle), so the jitter is then the samples' less the tone's, plus the tone's
        velocity: ``V_n - L(t) + L_u(t)`` with ``L_u`` the line through the tone's
        velocity ``u`` at the window's samples (``u`` itself is ``u_n``, taken out
        whole)."""
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
        tc = tw - np.add.reduce(tw) / len(tw)            # (tw.mean(), without its wrapper)
        a = 1.0 / len(tw) + tc * (tc[-1] / (tc @ tc))
        A = np.cumsum(a[::-1])[::-1][1:]                  # sum_{k >= j}, j = 1 .. n
        f = self._f[i0 + 1:i1 + 1]
        dv = dt[:, None] * f                              # each interval's increment
        if nominal_dt is not None and dt.max() > GAP_RATIO * nominal_dt:
            h = dt > GAP_RATIO * nominal_dt
            dv[h] = nominal_dt * f[h] + (dt[h, None] - nominal_dt) * f.mean(axis=0)
        jitter = (1.0 - A) @ dv
        if tone is not None:
            jitter = jitter + a @ tone.integral(tw)
        return jitter, np.add.reduce(dv, axis=0) / T


class Tones:
    """One sinusoid per axis, ``a cos(w (s - t0)) + b sin(w (s - t0))`` (w (k,) rad/s, a, b
    (k,); an axis without a tone has a = b = 0): the tones of a sensor found by
    :func:`fit_tones` about the instant ``t0``."""

    def __init__(self, t0: float, omega, a, b, freq=None, found=None):
        self.t0 = float(t0)
        self.omega = np.asarray(omega, dtype=float)
        self.a = np.asarray(a, dtype=float)
        self.b = np.asarray(b, dtype=float)
        #: Hz (k,), NaN where none: the frequencies the search found (:func:`fit_tones`)
        self.freq: np.ndarray | None = freq
        self._found = found                     # (None: not asked yet)

    @property
    def found(self) -> bool:
        """Whether any axis has a tone."""
        if self._found is None:
            self._found = bool((self.omega > 0.0).any())
        return self._found

    def value(self, s) -> np.ndarray:
        """The tones at the instants s (m,): (m, 3)."""
        x = self.omega * (np.asarray(s, dtype=float).reshape(-1, 1) - self.t0)
        return self.a * np.cos(x) + self.b * np.sin(x)

    def integral(self, s) -> np.ndarray:
        """Their zero-mean integral (the velocity of a specific-force tone) at s: (m, 3)."""
        x = self.omega * (np.asarray(s, dtype=float).reshape(-1, 1) - self.t0)
        w = np.where(self.omega > 0.0, self.omega, 1.0)
        return (self.a * np.sin(x) - self.b * np.cos(x)) / w


def _fourier_rows(freq, ts):
    """The Hann-tapered cosine and sine rows (2 F, n) at the frequencies freq (F,) Hz and
    instants ts (n,) s (real: a complex product took milliseconds)."""
    ph = 2.0 * np.pi * freq[:, None] * ts[None, :]
    taper = np.hanning(len(ts) + 2)[1:-1]
    return np.vstack([np.cos(ph) * taper, np.sin(ph) * taper])


@functools.lru_cache(maxsize=16)
def _window_basis(n: int, span: float, lo: float, hi: float):
    """For n samples evenly over ``span`` s: (the cubic's basis (n, 4), the Hann-tapered
    Fourier rows (2 F, n) of the frequencies (F,) Hz of a :data:`_TONE_STEP` grid over
    [lo, hi] and one step beyond each end (:func:`_fourier_rows`) times the projector that
    takes the cubic out (n, n), the frequencies); read only."""
    u = np.linspace(0.0, 1.0, n)
    poly = _cubic(u)
    out = np.eye(n) - poly @ np.linalg.pinv(poly)
    freq = np.arange(np.floor(lo / _TONE_STEP) - 1, np.ceil(hi / _TONE_STEP) + 2) * _TONE_STEP
    res = (poly, _fourier_rows(freq, u * span) @ out, freq)
    for a in res:
        a.flags.writeable = False
    return res


#: windows whose search (_peaks) a VelocityJitter keeps: one search's window is, sample for
#: sample, the next search's window before (a second later)
_PEAKS_KEPT = 4


def _peaks_of(t, x, band, kept):
    """:func:`_peaks` (its frequencies a new array); with ``kept`` (a dict), a window
    searched before is taken again when its stamps and samples are the same to the bit."""
    if kept is None:
        return _peaks(t, x, band)
    key = (t.tobytes(), x.tobytes(), band)
    out = kept.get(key)
    if out is None:
        out = _peaks(t, x, band)
        if len(kept) >= _PEAKS_KEPT:
            del kept[next(iter(kept))]
        kept[key] = out
    return out[0], out[1], out[2].copy()


def _peaks(t, x, band):
    """Per column of the samples x (m, k) stamped t: (the middles of the sample intervals
    (m,), the cubic in time's basis (m, 4), the tone frequency (k,) Hz or NaN).

    The samples less their least-squares cubic, Hann-tapered, their spectrum on a
    :data:`_TONE_STEP` Hz grid searched within ``band``: a tone when the peak is a local
    maximum of the spectrum (not the tail of a motion below the band or of a vibration
    above it) and its lobe (+- 1 / window Hz) holds :data:`_TONE_DOMINANCE` of the
    band's power."""
    n = len(t)
    dt = np.diff(t)
    step = float(np.median(dt))
    tm, span = _middles(t, dt, step)
    if float(np.abs(dt - step).max()) <= 1e-6 * step:
        poly, rows_out, freq = _window_basis(n, round(span, 9), band[0], band[1])
    else:                                # (uneven stamps: the same, at these instants)
        u = (tm - tm[0]) / span
        poly = _cubic(u)
        out = np.eye(n) - poly @ np.linalg.pinv(poly)
        freq = np.arange(np.floor(band[0] / _TONE_STEP) - 1,
                         np.ceil(band[1] / _TONE_STEP) + 2) * _TONE_STEP
        rows_out = _fourier_rows(freq, u * span) @ out
    ri = rows_out @ x
    nf = len(freq)
    spec = ri[:nf] ** 2 + ri[nf:] ** 2                           # (F, k)
    inner = spec[1:-1]
    k = np.argmax(inner, axis=0)                                 # (k,) peak rows, in band
    cols = np.arange(x.shape[1])
    peak = inner[k, cols]
    total = inner.sum(axis=0)
    lobe = np.abs(freq[1:-1, None] - freq[1:-1][k][None, :]) <= 1.0 / span
    ok = ((total > 0.0) & (spec[k, cols] <= peak) & (spec[k + 2, cols] <= peak)
          & ((inner * lobe).sum(axis=0) >= _TONE_DOMINANCE * total))
    return tm, poly, np.where(ok, freq[1:-1][k], np.nan)


def fit_tones(t, x, t0: float, band=TONE_BAND, window: float = TONE_WINDOW, freq=None,
              kept: dict | None = None):
    """The tone within ``band`` Hz of each column of the samples x (m, k) stamped t (m,)
    (each the mean over the interval ending at its stamp: fitted at the intervals'
    middles), as :class:`Tones` about t0 (k entries); None when the samples span less than
    ``window`` s or it holds fewer than :data:`_MIN_SAMPLES` samples.

    A vibration's tone lasts: it is searched for (:func:`_peaks`) in the last ``window``
    s and, once the samples span two, in the ``window`` s before, and taken as one when
    both find it within 2 :data:`_TONE_STEP` (a vehicle's motion in the band, broadband,
    puts its peaks elsewhere in each window; in the first two windows of a stream the
    last one decides: a vibration not taken out while the heading hypotheses run marred
    the heading for the next 15 s); its amplitude and phase are then fitted to the last
    window by least squares together with the cubic (the vehicle's motion: a 1 Hz turn or
    roll is left to it), at the last window's peak frequency. ``freq`` (k,) Hz (NaN: no
    tone): the frequencies of an earlier search, fitted without searching (the returned
    Tones' ``freq`` are those of the search either way). ``kept``: a dict in which the
    searches of the last few windows are kept for the next calls (a window searched
    again, the same to the bit, is not searched anew)."""
    t = np.asarray(t, dtype=float).reshape(-1)
    x = np.asarray(x, dtype=float).reshape(len(t), -1)
    if len(t) < 2 or t[-1] - t[0] < 0.98 * window:
        return None
    i1 = int(t.searchsorted(t[-1] - window, "left"))
    if len(t) - i1 < _MIN_SAMPLES:
        return None
    if freq is None:
        tm, poly, f_now = _peaks_of(t[i1:], x[i1:], band, kept)
        if t[-1] - t[0] >= 1.98 * window and np.isfinite(f_now).any():
            i0 = int(t.searchsorted(t[i1] - window, "left"))
            _, _, f_before = _peaks_of(t[i0:i1 + 1], x[i0:i1 + 1], band, kept)
            f_now[~(np.abs(f_now - f_before) <= 2.01 * _TONE_STEP)] = np.nan
    else:
        f_now = np.array(freq, dtype=float)
        tm, poly = _window_poly(t[i1:])
    m = x.shape[1]
    omega, a, b = np.zeros(m), np.zeros(m), np.zeros(m)
    for i in np.flatnonzero(np.isfinite(f_now)):
        w = 2.0 * np.pi * f_now[i]
        ph = w * (tm - t0)
        A = np.column_stack([poly, np.cos(ph), np.sin(ph)])
        c, *_ = np.linalg.lstsq(A, x[i1:, i], rcond=None)
        omega[i], a[i], b[i] = w, c[4], c[5]
    return Tones(t0, omega, a, b, f_now)


def _window_poly(t):
    """The intervals' middles and the cubic's basis of :func:`_peaks` (without the
    search; the median interval only when the stamps are uneven)."""
    dt = np.diff(t)
    step = float(dt.mean())
    if float(np.abs(dt - step).max()) > 1e-6 * step:
        step = float(np.median(dt))
    tm, span = _middles(t, dt, step)
    return tm, _cubic((tm - tm[0]) / span)


def _middles(t, dt, step):
    """The middles of the sample intervals ending at the stamps t (the first one ``step``
    long) and their span."""
    tm = t - 0.5 * np.concatenate(([step], dt))
    return tm, max(tm[-1] - tm[0], 1e-12)


def _cubic(u):
    """The basis (n, 4) of a cubic in u (n,)."""
    return np.column_stack([np.ones(len(u)), u, u * u, u * u * u])
