"""What the Aligner watches on the input besides single samples: the recent motion (for
bridging holes, :class:`RecentMotion`) and the units of the rates (:class:`UnitsMonitor`,
deg/s sent for rad/s).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from sins_align.core.earth import OMEGA_IE
from sins_align.core.preint import (prefix_rotations, prefix_rotations_components,
                                    rotate_components)
from sins_align.core.rotation import dcm_from_quat, so3_exp_entries
from sins_align.core.specs import DEG

if TYPE_CHECKING:
    from sins_align.estimators.quasi_static.aligner import Aligner


class RecentMotion:
    """The last accepted samples (a ring of fixed size): how much the platform moves.

    Read when samples are missing (how far the attitude and velocity could have moved in
    the hole) and while the coarse pass runs (the specific force of the last second, the
    accelerometer's own view of the level error). Fed sample by sample (the node) or in
    blocks (replay), it holds the same numbers either way.
    """

    SIZE = 16384
    WINDOW = 20.0                       # s of samples the motion statistics look at
    #: incremental steps (rows in, rows out) between two sums of :meth:`second_mean_force`
    #: from scratch: its rounding stays that of a few hundred additions
    REFRESH = 512
    #: rows come in since the last call beyond which that sum is taken from scratch
    CATCH_UP = 64

    def __init__(self):
        self._a = np.zeros((self.SIZE, 7))       # dt, w, f
        self._i = 0                              # next row to write
        self._n = 0                              # rows filled
        # for mean_force: the time before each row (sum of the dts before it) and the
        # specific force component-major, so a window's mean is one contiguous sum
        self._before = np.zeros(self.SIZE)
        self._fT = np.zeros((3, self.SIZE))
        self._total = 0.0                        # sum of every dt pushed
        self._count = 0                          # rows ever written (absolute row index)
        # second_mean_force's running sum: the specific force of absolute rows [start, end),
        # and the additions and subtractions made since it was last summed from scratch
        self._sec = (0, 0, 0.0, 0.0, 0.0)
        self._sec_steps = 0

    def push(self, dt: float, w, f):
        i = self._i
        fl = f.tolist()
        self._a[i] = [dt, *w.tolist(), *fl]
        self._before[i] = self._total
        self._total += dt
        self._fT[:, i] = fl
        self._i = (i + 1) % self.SIZE
        self._n = min(self._n + 1, self.SIZE)
        self._count += 1

    def extend(self, dts, w, f):
        m = len(w)
        # the running time as push() sums it, one addition after the other
        run = np.cumsum(np.concatenate(([self._total], np.broadcast_to(dts, (m,)))))
        self._total = float(run[-1])
        before = run[:-1]
        if m >= self.SIZE:
            dts, w, f = dts[-self.SIZE:], w[-self.SIZE:], f[-self.SIZE:]
            before = before[-self.SIZE:]
            m = self.SIZE
        idx = (self._i + np.arange(m)) % self.SIZE
        self._a[idx, 0] = dts
        self._a[idx, 1:4] = w
        self._a[idx, 4:7] = f
        self._before[idx] = before
        self._fT[:, idx] = np.asarray(f, dtype=float).T
        self._i = (self._i + m) % self.SIZE
        self._n = min(self._n + m, self.SIZE)
        self._count += len(w)

    def last(self, seconds: float) -> np.ndarray:
        """Rows (dt, w, f) of the last samples spanning at most ``seconds``, oldest first."""
        if self._n == 0:
            return self._a[:0]
        dt = self._a[self._i - 1, 0]
        # read back only as far as the span needs: guessed from the newest interval, doubled
        # while it falls short
        m = self._n if dt <= 0.0 else min(self._n, int(1.25 * seconds / dt) + 2)
        while True:
            rows = self._tail(m)
            span = np.cumsum(rows[::-1, 0])
            if m == self._n or span[-1] > seconds:
                break
            m = min(2 * m, self._n)
        k = max(1, int(np.searchsorted(span, seconds, side="right")))
        return rows[m - k:]

    def _tail(self, m: int) -> np.ndarray:
        """The newest m rows, oldest first (two slices when they wrap round the ring)."""
        a, i = self._a, self._i
        if m <= i:
            return a[i - m:i]
        return np.concatenate((a[self.SIZE - (m - i):], a[:i]))

    def _pieces(self):
        """The filled ring positions oldest first, as at most two (start, stop) slices."""
        n, i = self._n, self._i
        if n <= i:
            return ((i - n, i),)
        return ((self.SIZE - (n - i), self.SIZE), (0, i))

    def window_rows(self, seconds: float) -> int:
        """How many of the newest samples span at most ``seconds`` (at least one; 0 before
        any): :meth:`last`'s rows, found from the running time before each row instead of
        summing their intervals again, so a span equal to ``seconds`` to rounding (uniform
        stamps) may count one row more or less than there."""
        if self._n == 0:
            return 0
        lo = self._total - seconds
        k = 0
        for a, b in reversed(self._pieces()):   # newest piece first
            j = a + int(np.searchsorted(self._before[a:b], lo, side="left"))
            k += b - j
            if j > a:
                break
        return max(k, 1)

    def mean_force(self, seconds: float = 1.0) -> np.ndarray | None:
        """Mean specific force over the newest :meth:`window_rows` samples (None before any
        sample). The coarse pass reads it after every sample: one contiguous sum per axis."""
        k = self.window_rows(seconds)
        if k == 0:
            return None
        return self._force_sum(k) / k

    def _force_sum(self, k: int) -> np.ndarray:
        """Sum of the specific force of the newest k rows (3,)."""
        left, total = k, None
        for a, b in reversed(self._pieces()):
            m = min(left, b - a)
            if m:
                part = self._fT[:, b - m:b].sum(axis=1)
                total = part if total is None else total + part
            left -= m
        return total

    def second_mean_force(self) -> list[float] | None:
        """:meth:`mean_force` over the last second as three floats, equal to it to rounding:
        the same rows (those of ``window_rows(1.0)``), summed as a running sum (the rows
        that came in added, those that left the window subtracted, a new sum from scratch
        every REFRESH steps, or when more than CATCH_UP rows came in since the last call).
        The coarse pass reads it after every sample. None before any sample.

        The rows that left are found as window_rows finds them: the running time before
        each row never decreases, nor does the window's lower bound ``total - 1 s``, so the
        first row at or after that bound only moves forward."""
        n, m = self._n, self._count
        if n == 0:
            return None
        start, end, s0, s1, s2 = self._sec
        lo = self._total - 1.0
        steps = self._sec_steps + (m - end)
        if m - end > self.CATCH_UP or start < m - n or steps >= self.REFRESH:
            return self._second_from_scratch()
        a, size = self._a, self.SIZE
        for j in range(end, m):
            _, _, _, _, g0, g1, g2 = a[j % size].tolist()
            s0 += g0
            s1 += g1
            s2 += g2
        before = self._before
        while start < m and before[start % size] < lo:
            _, _, _, _, g0, g1, g2 = a[start % size].tolist()
            s0 -= g0
            s1 -= g1
            s2 -= g2
            start += 1
            steps += 1
        if start == m:                  # no row within the second: the newest one alone
            return self._second_from_scratch()
        self._sec = (start, m, s0, s1, s2)
        self._sec_steps = steps
        k = m - start
        return [s0 / k, s1 / k, s2 / k]

    def _second_from_scratch(self) -> list[float]:
        k = self.window_rows(1.0)
        s0, s1, s2 = self._force_sum(k).tolist()
        self._sec = (self._count - k, self._count, s0, s1, s2)
        self._sec_steps = 0
        return [s0 / k, s1 / k, s2 / k]

    def window_mean_forces(self, seconds: float, m: int) -> np.ndarray:
        """:meth:`mean_force` as it read after each of the newest ``m`` rows were pushed,
        (m, 3): the same windows (:meth:`window_rows`), summed as differences of a running
        sum over the rows they span (equal to rounding)."""
        n = self._n
        m = min(m, n)
        pieces = self._pieces()
        before = np.concatenate([self._before[a:b] for a, b in pieces])
        after = np.append(before[1:], self._total)          # the running time after each row
        end = np.arange(n - m, n) + 1
        start = np.searchsorted(before, after[n - m:] - seconds, side="left")
        start = np.minimum(start, end - 1)
        lo = int(start.min()) if m else n
        fT = np.concatenate([self._fT[:, a:b] for a, b in pieces], axis=1)[:, lo:]
        cs = np.concatenate([np.zeros((3, 1)), np.cumsum(fT, axis=1)], axis=1)
        return ((cs[:, end - lo] - cs[:, start - lo]) / (end - start)).T

    def bridge_errors(self, hole: float, nom: float, w_next, f_next, held: bool = True):
        """The bridges of a hole of ``hole`` seconds before the sample (w_next, f_next) and
        their errors: ``(means, held, (w_mean, f_mean))`` with ``means`` and ``held`` the
        (attitude rad^2, velocity (m/s)^2) variance per axis of each bridge (``held`` None
        when not asked for) and the constant rate and specific force of the ``means``
        bridge: for each, the last second's mean or the mid bridge, whichever errs less (see
        below). The errors are measured on the motion of the last WINDOW seconds (the
        largest axis counts for all three, the body axes not being the ENU ones).

        Each bridge is replayed at every position of the window, and the RMS of its error
        there, times sqrt(2) (a tone's peak over its RMS), is one sigma:

        - ``held`` (m = hole / nom missing samples): the next sample's rate and specific
          force stand in for the missing ones, so the error is
          ``nom sum_i (x_next - x_i)`` over the m samples it replaces. At the hole itself
          the change from the last sample to the next one is seen: a ramp between them
          makes ``|x_next - x_last| nom m / 2``, taken when larger (a shove in the hole).
        - bridged with the recent means: the rate's (specific force's) deviation from its
          mean over the window, integrated over m samples; a hole longer than the window is
          bounded by the range of that integral (a bounded sway cannot move further than its
          own range), grown with the hole's length beyond the window for a wander that is
          not stationary. At the hole itself, the mean of the samples on either side less
          the last second's mean, over the hole, is taken when larger.
        - mid: the mean of the last sample and the next one stands in for the missing ones
          (a linear interpolation's mean: exact for a ramp, and for a smooth sway far
          better than either bridge above), replayed as the held one; at the hole itself a
          change between the two samples at any instant of the hole (a shove) errs by at
          most ``|x_next - x_last| nom m / 2``, taken when larger. It replaces the recent
          mean (for the rate and the specific force separately) when both its replayed
          error and its variance are the smaller: the replay decides, so two noisy samples
          never stand in for a mean the edge term alone made look worse.

        Noise counts as motion here (the bridge's error against the complete data). Only
        white noise whose integral wanders (ARW, VRW) is absent from the truth over a hole,
        and the process noise the filter adds over the hole already holds it at the specs'
        level. The sample-to-sample scatter of real data is mostly quantization, dither and
        vibration whose integral stays bounded (the laser-gyro log: 100x the specs' ARW per
        sample, its sums over 20 s growing far slower than a random walk's): a lost sample
        loses that part for good, an error like the motion's, so nothing is subtracted.
        """
        second = self.last(1.0)[:, 1:7].mean(axis=0)        # the means bridge
        rows = self.last(self.WINDOW)
        n = len(rows)
        if n < 3:
            return (0.0, 0.0), ((0.0, 0.0) if held else None), (second[:3], second[3:])
        T = float(rows[:, 0].sum())
        m = max(1, int(round(hole / nom)))
        means, holds, values = [], [], []
        for x, nxt, mean in ((rows[:, 1:4], w_next, second[:3]), (rows[:, 4:7], f_next,
                                                                  second[3:])):
            nxt = np.asarray(nxt, dtype=float)
            d = x - (x * rows[:, :1]).sum(0) / T
            wander = np.cumsum(d * rows[:, :1], axis=0)
            spread = float((wander.max(0) - wander.min(0)).max())
            bound = spread * math.sqrt(1.0 + hole / T)
            if m < n:
                Sd = np.concatenate((np.zeros((1, 3)), wander))
                e = Sd[m:] - Sd[:-m]
                rms = float(np.sqrt(np.mean(e * e, axis=0)).max())
                bound = min(bound, math.sqrt(2.0) * rms)
            # at the hole itself: the samples on either side of it away from the mean of the
            # last 1 / nom samples say the missing ones were too (a sway's peak)
            edge = 0.5 * (nxt + x[-1]) - x[-min(n, int(round(1.0 / nom))):].mean(0)
            var, value = max(bound, float(np.abs(edge).max()) * nom * m) ** 2, mean
            # a change from the last sample to the next one, anywhere in the hole (a shove):
            # the held and the mid bridge err by up to half of it over the hole
            ramp = float(np.abs(nxt - x[-1]).max()) * nom * m / 2.0
            if m + 1 < n:
                # at position k the replaced samples are x[k+1..k+m], the next one x[k+m+1]
                S = np.concatenate((np.zeros((1, 3)), np.cumsum(x, axis=0)))
                missed = S[m + 1:n] - S[1:n - m]
                # the mid bridge: the mean of the last sample and the next one (exact for a
                # ramp between them), used instead of the recent mean when it errs less, both
                # on the recent motion and with the terms at the hole
                e = nom * (0.5 * m * (x[:n - m - 1] + x[m + 1:]) - missed)
                rms = math.sqrt(2.0) * float(np.sqrt(np.mean(e * e, axis=0)).max())
                mid = max(rms, ramp) ** 2
                if rms < bound and mid < var:
                    var, value = mid, 0.5 * (nxt + x[-1])
            means.append(var)
            values.append(value)
            if held:
                # the held bridge; a hole as long as the window: what the means bridge errs
                if m + 1 < n:
                    e = nom * (m * x[m + 1:] - missed)
                    rms = float(np.sqrt(np.mean(e * e, axis=0)).max())
                    holds.append(max(math.sqrt(2.0) * rms, ramp) ** 2)
                else:
                    holds.append(means[-1])
        return tuple(means), (tuple(holds) if held else None), tuple(values)


class UnitsMonitor:
    """Detects gyro rates that are not rad/s (deg/s is 57.3x too large).

    Statistic: over each window (``units_check_window``, 30 s) every specific-force sample
    is rotated into the window's start frame with the gyro-integrated rotation B
    (``u = B f``) and averaged over 1 s bins; the body-frame samples ``f`` are binned the
    same way. The scatter of a set of bin means is the RMS angle between each of them and
    their (time-weighted) mean direction.

    - With rad/s rates all u point along gravity (fixed in the start frame) up to linear
      acceleration ``a / g`` and the slow drift of Earth rate and gyro bias. Linear
      acceleration shows in the body-frame f just as much (rotation does not change its
      size), so the u scatter stays below about the f scatter: sway, heave, surge and a
      shove raise both together.
    - With rates 57.3x too large B turns the wrong way: the u wander by the rotation error
      (tens of degrees in sway; on a static base Earth rate's horizontal component x 57.3,
      about 0.2 deg/s at 34 deg N and 0.12 deg/s at 60 deg N, i.e. a ramp of 3.6-6 deg in
      30 s, 1-1.7 deg RMS), while f does not move.

    The rates are flagged when ``scatter(u) > RATIO x scatter(f) + allow T / sqrt(12) + TOL``:
    ``allow T / sqrt(12)`` is the RMS of the largest genuine drift over the window (Earth
    rate plus 3x the gyro bias spec), TOL a margin for the rest (noise, the second-order
    terms of sway). A window is discarded without a verdict at a gap or a time jump (an
    interval above ``gap_ratio`` x nominal, or above ``max_gap``): the rate of one sample
    cannot be integrated over the hole.
    """

    RATIO = 2.0
    TOL = 0.25 * DEG

    def __init__(self, al: Aligner):
        self.al = al
        self.window = al.config.units_check_window
        self.allow = OMEGA_IE + 3.0 * al.config.specs.gyro_bias
        self.bins = int(math.ceil(self.window)) + 1
        self.last_mismatch_deg = None       # scatter of u of the last judged window, deg
        self.last_limit_deg = None          # and the limit it was compared with, deg
        self._verdict_now: bool | None = None   # of the window add() closed, until taken
        self._row = None        # (bin, its sums as floats): add()'s row not yet in acc
        self._start()

    def _start(self):
        self.T = 0.0
        self.B = np.eye(3)
        self.acc = np.zeros((self.bins, 7))     # per 1 s bin: sum dt, sum f dt, sum u dt

    @property
    def acc(self) -> np.ndarray:
        """The bin sums (bins, 7). add() sums the current bin's row on floats (the same
        additions in the same order) and writes it here when the bin changes, or when this
        is read."""
        row = self._row
        if row is not None:
            self._acc[row[0]] = row[1]
            self._row = None
        return self._acc

    @acc.setter
    def acc(self, value: np.ndarray) -> None:
        self._acc, self._row = value, None

    def _gap(self, dt) -> float:
        """Largest interval that is not a gap (the Aligner's rule; max_gap while the
        nominal interval is not known yet)."""
        c, nom = self.al.config, self.al.nominal_dt
        return c.max_gap if nom is None else min(c.gap_ratio * nom, c.max_gap)

    def add_block(self, dts, w, f) -> int:
        """Samples of a run. Windows that close inside it are judged as :meth:`add` would
        (a gap or a non-positive interval discards the window, as there); the block stops
        before the closing sample of a window that would flag the rates (that sample goes
        through :meth:`add`). Returns how many samples were taken."""
        dts = np.asarray(dts, dtype=float)
        n = len(dts)
        bad = np.flatnonzero(~((dts > 0.0) & (dts <= self._gap(None))))
        k = 0
        for b in list(bad) + [n]:
            m = self._add_run(dts[k:b], w[k:b], f[k:b])
            if m < b - k:
                return k + m
            if b < n:
                self._start()                 # a gap: no verdict, a new window after it
            k = b + 1
        return n

    def _add_run(self, dts, w, f) -> int:
        """add_block for a run without gaps. The windows of the run are found first, their
        sums computed all at once (:meth:`_accumulated_windows`), then judged in order."""
        n = len(dts)
        if n == 0:
            return 0
        wins, k, T0 = [], 0, self.T
        while k < n:
            T = self._window_times(T0, dts[k:])
            closes = T[-1] >= self.window
            end = k + int(np.argmax(T >= self.window)) + 1 if closes else n
            wins.append((k, end, T[:end - k]))
            k, T0 = end, 0.0
        for (k, end, T), state in zip(wins, self._accumulated_windows(dts, w, f, wins)):
            if end == n and T[-1] < self.window:
                self.B, self.acc, self.T = state
                return n
            verdict = self._verdict(*state)
            if verdict is not None and verdict[0] and not self.al.units_suspect:
                if end - 1 > k:                   # everything before the closing sample
                    self.B, self.acc, self.T = self._accumulated(
                        dts[k:end - 1], w[k:end - 1], f[k:end - 1], T[:end - 1 - k])
                return end - 1
            if verdict is not None:
                self.last_mismatch_deg, self.last_limit_deg = verdict[1] / DEG, verdict[2] / DEG
            self._start()
        return n

    def _window_times(self, T0: float, dts) -> np.ndarray:
        """Window times after each of ``dts`` from ``T0``, as add() sums them (one addition
        after the other), up to the first that closes the window (or all of them)."""
        m, parts = max(64, 2 * int(self.window / max(float(dts[0]), 1e-3))), []
        k = 0
        while k < len(dts):
            T = np.cumsum(np.concatenate([[T0], dts[k:k + m]]))[1:]
            parts.append(T)
            if T[-1] >= self.window:
                break
            k, T0, m = k + m, float(T[-1]), 2 * m
        return parts[0] if len(parts) == 1 else np.concatenate(parts)

    def _accumulated_windows(self, dts, w, f, wins) -> list:
        """:meth:`_accumulated` of each window (k, end, T) of ``wins`` (the first one from the
        current state, the others from a new window), computed together, component-major:
        one prefix scan of the windows padded with zero rates (identity rotations) to a
        multiple of 64 samples (a length the scan splits well), the forces turned by
        quaternions in place, one bincount per sum column."""
        S = len(wins)
        lens = np.array([end - k for k, end, _ in wins])
        L = -(-int(lens.max()) // 64) * 64
        dtp, T = np.zeros((S, L)), np.zeros((S, L))          # padding: no time, no rotation
        rot, udt = np.zeros((3, S, L)), np.zeros((3, S, L))  # w dt, then f dt turned
        for i, (k, end, Ti) in enumerate(wins):
            m = end - k
            dtp[i, :m], T[i, :m] = dts[k:end], Ti
            rot[:, i, :m] = (w[k:end] * dts[k:end, None]).T
            udt[:, i, :m] = (f[k:end] * dts[k:end, None]).T
        fdt = udt.copy()
        q = prefix_rotations_components(rot[0], rot[1], rot[2])
        rotate_components(q, tuple(udt))               # into the window's start frame
        udt[:, 0] = self.B @ udt[:, 0]                 # the first window goes on from B
        j = (np.minimum(T.astype(int), self.bins - 1) + self.bins * np.arange(S)[:, None]).ravel()
        acc = np.zeros((S, self.bins, 7))
        acc[0] = self.acc
        for col, x in ((0, dtp[None]), (1, fdt), (4, udt)):
            for i, xi in enumerate(x):
                acc[:, :, col + i] += np.bincount(j, xi.ravel(),
                                                  minlength=S * self.bins).reshape(S, self.bins)
        last = dcm_from_quat(np.stack([c[np.arange(S), lens - 1] for c in q], axis=-1))
        B = np.concatenate([(self.B @ last[0])[None], last[1:]])
        return [(B[i], acc[i], float(wins[i][2][-1])) for i in range(S)]

    def _accumulated(self, dts, w, f, T):
        """(B, bin sums, T) after samples with window times T (not stored)."""
        q = prefix_rotations(dts[None], w[None])       # exp(w_1 dt_1) ... exp(w_k dt_k)
        Q = dcm_from_quat(np.stack([c[0] for c in q], axis=-1))
        u = np.einsum("ij,kjl,kl->ki", self.B, Q, f)
        acc = self.acc.copy()
        j = np.minimum(T.astype(int), self.bins - 1)
        for col, x in ((0, dts[:, None]), (1, f * dts[:, None]), (4, u * dts[:, None])):
            for i in range(x.shape[1]):
                acc[:, col + i] += np.bincount(j, x[:, i], minlength=self.bins)
        return self.B @ Q[-1], acc, float(T[-1])

    @staticmethod
    def _scatter(m: np.ndarray, wt: np.ndarray) -> float:
        """RMS angle (rad, weights wt) between vectors m (k, 3) and their weighted mean."""
        d = wt @ m
        d = d / np.linalg.norm(d)
        # |m x d| by components (np.cross's products and np.linalg.norm's sum, a fifth of
        # their time on these few bins)
        d0, d1, d2 = d.tolist()
        x, y, z = m[:, 0], m[:, 1], m[:, 2]
        c0, c1, c2 = y * d2 - z * d1, z * d0 - x * d2, x * d1 - y * d0
        ang = np.arctan2(np.sqrt(c0 * c0 + c1 * c1 + c2 * c2), m @ d)
        return math.sqrt(float(wt @ (ang * ang)) / float(wt.sum()))

    def _verdict(self, B, acc, T):
        """(flag the rates?, scatter of u, limit), rad, of a closed window; None without
        data (fewer than two bins, or a zero mean)."""
        wt = acc[:, 0]
        use = wt > 0.0
        if use.sum() < 2:
            return None
        wt = wt[use]
        mf = acc[use, 1:4] / wt[:, None]
        mu = acc[use, 4:7] / wt[:, None]
        if not (np.linalg.norm(wt @ mf) > 0.0 and np.linalg.norm(wt @ mu) > 0.0):
            return None
        su, sf = self._scatter(mu, wt), self._scatter(mf, wt)
        limit = self.RATIO * sf + self.allow * T / math.sqrt(12.0) + self.TOL
        return su > limit, su, limit

    def take_verdict(self) -> bool | None:
        """The verdict of the window the last :meth:`add` closed (True: the rates look like
        deg/s; False: they do not), once; None when no window closed since."""
        out, self._verdict_now = self._verdict_now, None
        return out

    def add(self, dt, w, f):
        """One sample; returns exp(w dt), which the filter can reuse (None if skipped: a
        gap or a time jump, which also discards the window). A window closing here leaves
        its verdict for :meth:`take_verdict`."""
        if not 0.0 < dt <= self._gap(None):
            self._start()
            return None
        w0, w1, w2 = w.tolist()
        dR = np.array(so3_exp_entries(w0 * dt, w1 * dt, w2 * dt)).reshape(3, 3)
        self.B = B = np.dot(self.B, dR)
        self.T += dt
        j = min(int(self.T), self.bins - 1)
        # scalar arithmetic on the 3-vectors (one sample: numpy calls cost more than the sums)
        f0, f1, f2 = f.tolist()
        (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = B.tolist()
        row = self._row
        if row is None or row[0] != j:
            a = self.acc[j].tolist()            # (the property writes the last row back)
            self._row = (j, a)
        else:
            a = row[1]
        a[0] += dt
        a[1] += f0 * dt
        a[2] += f1 * dt
        a[3] += f2 * dt
        a[4] += (b00 * f0 + b01 * f1 + b02 * f2) * dt
        a[5] += (b10 * f0 + b11 * f1 + b12 * f2) * dt
        a[6] += (b20 * f0 + b21 * f1 + b22 * f2) * dt
        if self.T >= self.window:
            verdict = self._verdict(self.B, self.acc, self.T)
            if verdict is not None:
                bad, su, limit = verdict
                self._verdict_now = bool(bad)
                self.last_mismatch_deg, self.last_limit_deg = su / DEG, limit / DEG
            self._start()
        return dR
