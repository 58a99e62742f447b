"""The IMU's sample instants from jittering stamps (numpy only).

An IMU samples at a steady rate; each sample is the mean rate and specific force over its
interval. Many drivers stamp a message when it is received (USB, serial), so the stamps
jitter by a few ms around the sampling instants while the samples do not. Integrated over
its stamps' interval, sample ``k`` gets ``f_k (e_k - e_(k-1))`` too much (``e`` the stamps'
errors), which adds up to ``-sum e_k (f_(k+1) - f_k)``: a random walk as large as the
sample-to-sample change of the samples. On a vibrating IMU it is huge: 3 m/s^2 RMS at 20-80
Hz with stamps +-10 % of a 100 Hz interval is ~0.03 m/s/sqrt(s), 60 x the velocity random
walk of seed 003's accelerometer, and the filter took it for tilt (seed 003's UAV, 60 s,
seeds 0-2: 57-100 % of the instants after 25 s beyond 3 sigma at +-10 %, 78-100 % at
+-20 %, with stamps received 1 ms late on average 56-92 %; honest without the vibration).
At +-40 %, 7 % of the intervals exceeded 1.5 nominal ones and were bridged as lost samples
(`gaps.py`), whose variance hid it in some seeds (level std 8 x).

Both estimators use it: the in-motion one (``estimators/in_motion``) and the quasi-static
``Aligner``, whose block path computes the instants of a run before it is taken, so that
the per-sample path finds the same ones.

:class:`SampleClock` gives each accepted stamp the instant of a steady clock fitted to the
stamps: straight lines over the sample count (least squares, each stamp's weight decaying
by ``1/e`` over :data:`MEMORY` s for the long line, whose slope is the clock's period and
which the instants follow, over :data:`COUNT_MEMORY` s for the intercept of the counting
line, which has the long line's slope). The filter integrates over the instants' intervals
(one interval per sample, a whole number across a hole: ``gaps.py`` bridges it).

- Lost samples. A lost sample moves every later stamp by one interval, a late stamp only
  itself: the samples lost before a stamp are decided by the stamps from it on, the least
  of their distances from the counting line (rounded; one stamp after it, two, or four
  while :attr:`SampleClock.late` says the stamps are late by over half an interval more
  often than :data:`LATE`: reception delays in runs; four while the fit is younger than
  :data:`YOUNG` s), and only then does the stamp join the lines at its count. What the next
  stamp already shows is bridged there (the sample after the hole took the lost one's
  place), and what the stamps after decide otherwise is bridged when they do, or given back
  over :data:`GIVE_BACK` intervals; :meth:`SampleClock.lag` tells the quasi-static filter
  how many stamps late a bridge came, for its budget. Samples lost beyond one and
  :data:`IMMEDIATE` RMS of the scatter are bridged at once (a long hole). Once the fit is
  :data:`YOUNG` s old, stamps that all lie a whole interval early take a count back.
- Why the period is not the counting line's. Decided stamp by stamp against a line over
  the last second whose slope was free, a stamp 2.5 sigma late (Gaussian 20 %: 1 in 160)
  counted a lost sample, that line took the made-up count in, its period shortened and
  made up the next: 1,600 made-up samples and a period 10 % short in 300 s; +-40 %, one
  draw: 3,700 and 15 %; 3 ms mean delays 3,500 and 14 %. The IMU's rate against the stamps'
  clock moves by ppm; the long line's slope follows that, and the counts are decided
  before a stamp joins it (the period within 5e-7, below). Its memory grows with the
  fit's age (:data:`GROW` of it), so that the first stamps' counts (a lost sample among
  the :data:`START` first, told by a better fit, :data:`LOST_COST`) do not hold a wrong
  period for 30 s.
- Why the instants are drawn to the long line slowly. The instants pass what the stamps'
  errors hold below ``1 / memory``, and an error of the instants that varies with the
  motion's own period is rectified: a time scale off by ``d phi / dt`` turns a rate
  ``W cos(w t)`` into a bias ``W A w / 2`` for ``phi = A cos(w t)`` (0.35 ms at 0.1 Hz on
  the rolling ship, 3 deg/s: 1.2 deg/h). Each stamp moves the long line's end by ~1/1000
  of its error; drawn to it over GIVE_BACK intervals, the instants kept that at 1 Hz
  (0.4-0.6 us against the 6 deg/s roll of ``ang_x_1Hz_1deg``, +-40 %: its heading 0.15 deg
  off, 72 % beyond 3 sigma); now over a quarter of the stamps the line holds (up to
  :data:`PULL_MAX` intervals, 7.5 s): 0.05 us on the sweep's +-40 % draw (0.37 us
  before), and that case 0 % beyond 3 sigma; farther than :data:`BAND` intervals
  from it (the start), over GIVE_BACK intervals. At epoch stamps (1.7e9 s, a float step
  0.24 us) the slow pull rounds away: after 20 s of +-40 % jitter and then exact stamps
  the instants stayed 89 us behind them (a constant offset: the intervals are right) and
  the clock kept fitting (``jittering`` True, ~5 us a stamp) for over 580 s (review of
  session 17; keeping instants relative to an origin would fix it).
- A stamp within :data:`TOLERANCE` intervals of its instant is kept as it is, and while
  every stamp is (stamps from the IMU's own clock, with or without lost samples) the stamps
  go through untouched and nothing is fitted: the same figures bit for bit as before the
  clock. The first :data:`START` stamps are given as they are (the filter starts later).

Measured (100 Hz, 300 s, blocks of 10, seeds 0/1; scratch harness, ``test/test_clock.py``
holds four of these runs): the instants within 0.08-0.22 ms RMS of the true ones (plus
the stamps' mean delay) with stamps Gaussian sigma 20-40 % of the interval, +-40 %
uniform, received 1 or 3 ms late on average (exponential, in order), the period within
5e-7, at most one sample bridged and given back; before, 1.2-5.6 ms with 4,100-5,600
made-up samples at Gaussian 30-40 %, 3,400-3,700 at 3 ms and at +-40 % (seed 1), 2-17 at
Gaussian 20 %. With 1 % of the samples lost at random: every hole counted, the instants
1.0 ms RMS (2.0 ms at 3 ms delays: the samples between a hole and its bridge are one
interval early). Not handled: delays of 5 ms mean (half the interval): runs of late stamps
still count 11-13 samples too many in 300 s, taken back later, 0.7-1.5 ms RMS (before
5,800-6,000 made-up samples, 8.4 ms). Samples the estimators reject before the clock
(stamped backwards: Gaussian stamps 20 % make 1 in 4,000) are holes to it.
"""
from __future__ import annotations

import math
import statistics

import numpy as np

__all__ = ["SampleClock", "MEMORY", "COUNT_MEMORY", "TOLERANCE", "START", "GIVE_BACK",
           "DECIDE", "LATE"]

#: s: the weight of a stamp in the line the instants follow decays by 1/e over this long
MEMORY = 30.0
#: s: the same in the counting line's intercept (and the long line's at the fit's start)
COUNT_MEMORY = 1.0
#: a stamp within this fraction of the interval of the clock is kept as it is
TOLERANCE = 1e-4
#: intervals over which a sample bridged and not confirmed is given back (and the
#: instants drawn to the long line while farther than BAND from it)
GIVE_BACK = 8.0
#: a lost sample among the first stamps costs this many variances of the best fit's
LOST_COST = 10.0
#: the long line's memory is this fraction of the time since the fit began (up to MEMORY)
GROW = 0.5
#: s: a sample counted too many is taken back once the fit is this old (before, its
#: period may be what is wrong)
YOUNG = 10.0
#: the instants are drawn towards the long line over this fraction of the stamps it holds
PULL = 0.25
#: intervals: at most
PULL_MAX = 750.0
#: intervals: the instants farther than this from the long line are drawn to it over
#: GIVE_BACK intervals (up to it)
BAND = 0.05
#: stamps given as they are before the clock starts (its first line is through them)
START = 16
#: stamps after one that decide the samples lost before it (see LATE)
DECIDE = 2
#: the fraction of the stamps late by over half an interval (a skewed scatter: reception
#: delays) beyond which twice DECIDE stamps decide (and while the fit is YOUNG); below
#: RARE, with an RMS scatter of NARROW intervals at most, one
LATE = 0.02
RARE = 1e-4
NARROW = 0.1
#: instants whose bridge came late kept for :meth:`SampleClock.lag` (instants computed
#: ahead of the filter, blocks of thousands of samples)
LAGS_KEPT = 16384
#: samples lost are bridged at once beyond this many RMS of the stamps' scatter
IMMEDIATE = 8.0


class SampleClock:
    """The sampling instants of a steady IMU from its stamps (see the module docstring).

    :meth:`times` maps accepted stamps (in order) to instants; :attr:`period` is the
    clock's interval (None before :data:`START` stamps), :attr:`jittering` whether the
    stamps are being replaced, :attr:`rms` the RMS of the stamps about the clock (s) since
    it began to replace them. How surely the samples are counted: :attr:`late` the
    fraction of the stamps late by over half an interval (over 30 s), :attr:`doubtful`
    while it is over :data:`LATE` (reception delays spread over a good part of the
    interval: a lost sample is told from late stamps by 2 x :data:`DECIDE` stamps, and a
    run of late stamps that long still counts one), :attr:`given_back` the samples bridged
    that the stamps after did not confirm, :attr:`taken_back` those counted too many and
    taken back later (each a whole interval integrated wrongly for a while)."""

    def __init__(self):
        self.period: float | None = None
        self.jittering = False
        self._early: list = []               # the first stamps (given as they are)
        self._last: float | None = None      # the last instant given
        self._ref = 0.0                      # the fit's instant at the last count
        self._buf: list = []                 # stamps whose lost samples are undecided
        self._pc = 0.0                       # the last stamp's count past the decided one
        self._var = 0.0                      # the stamps' variance about the counting line
        self._debt = 0.0                     # intervals bridged too many, to give back
        self.late = 0.0                      # (see the class docstring)
        self.given_back = 0
        self.taken_back = 0
        self._lags: dict = {}                # instant -> stamps its bridge came late by
        self._seen = 0                       # stamps on the steady clock in a row
        self._sums: list | None = None       # the counting line (S0, S1, Sy, lambda)
        self._long: list | None = None       # the long one (S0, S1, S2, Sy, Sky, lambda)
        self._age = 0.0                      # s since the fit began (its memory grows)
        self._r2 = 0.0                       # the sum of the squared residuals, their
        self._n2 = 0                         # count

    def times(self, t) -> np.ndarray:
        """The instants of the accepted stamps ``t`` (n,) (increasing)."""
        t = np.asarray(t, dtype=float)
        x = self._times(t)
        if len(x) == len(t):
            return x
        # the stamps came back on the IMU's own clock within ``t``: the rest from there
        parts = [x]
        while len(x) < len(t):
            t = t[len(x):]
            x = self._times(t)
            parts.append(x)
        return np.concatenate(parts)

    def _times(self, t: np.ndarray) -> np.ndarray:
        """The instants of the first stamps of ``t``: all of them, or those up to the one
        after which the stamps are back on the IMU's own clock (no fit any more)."""
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
            # (statistics.median: the same value, without importing numpy.ma, 12 ms)
            T = float(statistics.median(d.tolist()))
            if np.all(np.abs(d - np.maximum(np.rint(d / T), 1.0) * T) <= TOLERANCE * T):
                self.period, self._seen = T, len(e)
            else:
                self._start_fit(e, _start_counts(e))
            if k == n:
                return t
            return np.concatenate((t[:k], self.times(t[k:])))
        if not self.jittering:
            if n == 1 and self._on_clock(float(t[0])):     # (a live stream's sample)
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
                if not self.jittering:
                    return out[:j + i + 1]
            return out
        out = np.empty(n)
        for i, s in enumerate(t.tolist()):
            out[i] = self._one(s)
            if not self.jittering:
                return out[:i + 1]
        return out

    def time(self, s: float) -> float:
        """The instant of one accepted stamp ``s`` (what ``times([s])[0]`` gives, in
        floats: a live stream's sample on the IMU's own clock costs a few float operations)."""
        if self.period is not None and not self.jittering and self._on_clock(s):
            return s
        return float(self.times(np.array([s]))[0])

    @property
    def rms(self) -> float:
        """The RMS of the stamps about the clock (s) since it began to replace them."""
        return math.sqrt(self._r2 / self._n2) if self._n2 else 0.0

    @property
    def doubtful(self) -> bool:
        """Whether the stamps scatter so that lost samples are told from late stamps with
        doubt (see the class docstring)."""
        return self.late > LATE

    def lag(self, x: float) -> int:
        """How many stamps after its place the samples lost before the instant ``x`` (one
        given lately) were bridged (0: at it): the samples between took their place."""
        lags = self._lags
        while lags:                         # (those before x are not asked for any more)
            k = next(iter(lags))
            if k >= x:
                break
            del lags[k]
        return lags.pop(x, 0)

    def _on_clock(self, s: float) -> bool:
        """Whether the stamp ``s`` lies on the steady clock so far (a whole number of
        intervals after the last one, within the tolerance), taken if it does; in floats.
        (Not jittering, the period known.)"""
        T = self.period
        d = s - self._last
        m = max(round(d / T), 1)
        if abs(d - m * T) > TOLERANCE * T:
            return False
        if m == 1:
            self.period = d
        self._last = s
        self._seen += 1
        return True

    def _start_fit(self, e, k=None):
        """The fit through the stamps ``e`` at the counts ``k`` (one interval apart if
        None), the last at count 0."""
        if k is None:
            k = np.arange(len(e), dtype=float)
        k = k - k[-1]
        T0 = (e[-1] - e[0]) / -k[0]
        y = e - e[-1]
        # the counting line and the long one start alike, over COUNT_MEMORY s (the long
        # line's memory then grows with the fit's age: _join)
        lam = math.exp(-1.0 / max(2.0, COUNT_MEMORY / T0))
        w = lam ** -k
        sums = [w.sum(), w @ k, w @ (k * k), w @ y, w @ (k * y), lam]
        lines = [sums, list(sums)]
        S0, S1, S2, Sy, Sky, _ = lines[1]
        det = S0 * S2 - S1 * S1
        self.period = (S0 * Sky - S1 * Sy) / det
        S0, S1, _, Sy, _, lam = lines[0]
        a = (Sy - self.period * S1) / S0
        r = y - a - self.period * k
        self._var = float(r @ r) / len(r)
        self.late = float(np.mean(r > 0.5 * self.period))
        # (the times' origin: the counting line at the last stamp)
        S0, S1, S2, Sy, Sky, lam = lines[1]
        self._long = [S0, S1, S2, Sy - a * S0, Sky - a * S1, lam]
        S0, S1, _, Sy, _, lam = lines[0]
        self._sums = [S0, S1, Sy - a * S0, lam]
        self._ref = float(e[-1]) + a
        self._buf = []
        self._pc = self._debt = 0.0
        self._age = COUNT_MEMORY / GROW
        self.jittering = True
        self._seen = 0

    def _join(self, y: float, a: float, m: float, T: float,
              ref: float) -> tuple[float, float]:
        """A decided stamp (``y`` from the times' origin ``ref``) joins the lines ``m``
        counts on (the counting line at ``a`` at the last count). Returns the period and the
        counting line at this count (the new origin, which the lines are moved to: by what
        ``ref + a`` rounds to, as the caller moves ``ref``; at epoch stamps, 0.24 us apart
        in floats, the difference came back at every stamp and held the period 1e-5 off)."""
        r = y - a - m * T
        self._var += (min(r * r, T * T) - self._var) * (1.0 - self._sums[3])
        self.late += ((r > 0.5 * T) - self.late) * (1.0 - self._long[5])
        # the counts move on by m, the weights decay, the stamp joins at count 0: the long
        # line (its period the clock's) and the counting line (its intercept)
        S0, S1, S2, Sy, Sky, lam = self._long
        S2 = S2 - 2.0 * m * S1 + m * m * S0
        S1 = S1 - m * S0
        Sky = Sky - m * Sy
        dec = lam if m == 1.0 else lam ** m
        S0, S1, S2, Sy, Sky = S0 * dec + 1.0, S1 * dec, S2 * dec, Sy * dec + y, Sky * dec
        T = (S0 * Sky - S1 * Sy) / (S0 * S2 - S1 * S1)
        if self._age < MEMORY / GROW:
            # (its memory grows with the fit's age: the first stamps' counts, a lost sample
            # among them, are not kept for MEMORY s)
            self._age += m * T
            lam = math.exp(-1.0 / max(2.0, min(MEMORY, GROW * self._age) / T))
        C0, C1, Cy, mu = self._sums
        dec = mu if m == 1.0 else mu ** m
        C0, C1, Cy = C0 * dec + 1.0, (C1 - m * C0) * dec, Cy * dec + y
        a = (Cy - T * C1) / C0
        a = (ref + a) - ref
        self._long = [S0, S1, S2, Sy - a * S0, Sky - a * S1, lam]
        self._sums = [C0, C1, Cy - a * C0, mu]
        return T, a

    def _one(self, s: float) -> float:
        """The instant of one stamp (the per-sample fit)."""
        T, ref, last = self.period, self._ref, self._last
        C0, C1, Cy, _ = self._sums
        a = (Cy - T * C1) / C0              # the counting line at the last decided count
        buf = self._buf
        # the stamp's count, the undecided ones before it taken one interval apart (and
        # the samples bridged before them)
        r0 = (s - ref - a) / T - self._pc - 1.0
        bridged, lag = 0.0, 0
        if not buf and -0.5 < r0 < 0.5:
            # (the common stamp: nothing undecided, on time: one interval on, decided)
            T, a = self._join(s - ref, a, 1.0, T, ref)
            ref += a
        else:
            late, rho = self.late, math.sqrt(self._var) / T
            if late > LATE or self._age < YOUNG:
                keep = 2 * DECIDE
            else:
                keep = 1 if late <= RARE and rho <= NARROW else DECIDE
            if buf and keep <= DECIDE:
                # the samples lost before the stamp before, as this stamp sees them too,
                # are bridged here (the stamps after it decide for the lines; a sample
                # bridged too many is given back, one not bridged yet bridged when they
                # decide)
                sp, n_p = buf[-1]
                more = float(round(min((sp - ref - a) / T - self._pc, r0)))
                if more >= 1.0:
                    buf[-1] = (sp, n_p + more)
                    self._pc += more
                    r0 -= more
                    bridged, lag = more, 1
            # samples lost before this stamp are bridged at once beyond one (a late stamp
            # is not taken for a lost sample) and what the stamps' scatter could make of it
            now = max(0.0, float(round(r0 - 1.0 - IMMEDIATE * rho)))
            buf.append((s, now))
            self._pc += 1.0 + now
            bridged += now
            while buf and (len(buf) > keep
                           or abs((buf[0][0] - ref - a) / T - 1.0) < 0.5):
                # the oldest undecided stamp: the samples lost before it are those that
                # every stamp from it on shows (a late stamp moves itself only, a lost
                # sample every later stamp): the least of their distances from the
                # counting line
                c, least, most = 0.0, math.inf, -math.inf
                for j, (sj, nj) in enumerate(buf):
                    c += 1.0 + (nj if j else 0.0)
                    r = (sj - ref - a) / T - c
                    least, most = min(least, r), max(most, r)
                s0, n0 = buf.pop(0)
                # (every one of them early by over half an interval, the period known: a
                # sample counted too many before, taken back: this stamp at the count of
                # the one before. Not while the fit is young: its period may be what is
                # wrong)
                n = max(0.0, float(round(least)))
                if most < -0.5 and self._age >= YOUNG:
                    n = -1.0
                    self.taken_back += 1
                elif n < n0:
                    self.given_back += int(n0 - n)
                if n > n0:
                    lag = len(buf)
                bridged += n - n0
                self._pc -= 1.0 + n0
                T, a = self._join(s0 - ref, a, 1.0 + n, T, ref)
                ref += a
                a = 0.0
        S0, S1, S2, Sy, Sky, _ = self._long
        fit = ref + (Sy * S2 - S1 * Sky) / (S0 * S2 - S1 * S1) + self._pc * T
        if abs(fit - ref - self._pc * T) > 0.5 * T:   # (the lines apart: the counting one)
            fit = ref + self._pc * T
        # the instant: one interval on and the lost samples bridged here, less what is
        # given back (a sample bridged that the stamps after did not confirm, over GIVE_BACK
        # intervals); drawn towards the long line, slowly (its noise is the instants')
        if bridged < 0.0 or self._debt:
            debt = self._debt - min(bridged, 0.0)
            back = min(debt, 1.0 / GIVE_BACK)
            self._debt = debt - back
            x = last + (1.0 + max(bridged, 0.0) - back) * T
        else:
            x = last + (1.0 + bridged) * T
        d = fit - x
        x += d / min(max(GIVE_BACK, PULL * S0), PULL_MAX)
        if abs(d) > BAND * T:               # (far from the line: fast, up to BAND)
            x += math.copysign(abs(d) - BAND * T, d) / GIVE_BACK
        r = s - x
        if abs(r) <= TOLERANCE * T:
            x = s
            self._seen += 1
        else:
            self._seen = 0
            self._r2 += r * r
            self._n2 += 1
        if x <= last:                       # (kept increasing)
            x = last + 0.5 * T
        if lag and bridged > 0.0:
            lags = self._lags
            lags[x] = lag
            if len(lags) > LAGS_KEPT:
                del lags[next(iter(lags))]
        self._ref = ref
        self._last = x
        self.period = T
        if self._seen >= self._sums[0]:     # back on the IMU's own clock: untouched again
            self.jittering = False
            self._sums = self._long = None
            self._buf = []
        return x


def _start_counts(e) -> np.ndarray:
    """The counts of the first stamps ``e``: one interval apart, or with one or two samples
    lost among them where that fits the stamps by far better (a line through them with
    one lost sample unseen is 1/START off in its period, and the counts of the first
    seconds with it)."""
    n = len(e)
    base = np.arange(n, dtype=float)
    hyp = [base]
    for i in range(1, n):
        hyp.append(base + (base >= i))
        for j in range(i, n):
            hyp.append(base + (base >= i) + (base >= j))
    K = np.array(hyp)
    y = e - e.mean()
    Kc = K - K.mean(axis=1, keepdims=True)
    slope = (Kc @ y) / np.einsum("ij,ij->i", Kc, Kc)
    rss = ((y - slope[:, None] * Kc) ** 2).sum(axis=1)
    lost = K[:, -1] - (n - 1)
    var = rss.min() / (n - 2)
    return K[int(np.argmin(rss + LOST_COST * var * lost))]
