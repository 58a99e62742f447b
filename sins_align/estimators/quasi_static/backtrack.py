"""The backtrack and the fine pass's tuning (a part of
:class:`~sins_align.estimators.quasi_static.filter.AlignmentFilter`).

At ``backtrack_time`` the coarse estimate is carried back to the first sample through the
buffered gyro data (:class:`SampleBuffer`), and the fine pass starts over the buffer: from
the inertial-frame alignment or the carried-back estimate, with its update period and
measurement noise measured from the data (the sway's velocity; the period lengthened until
the differenced interval means look white), and its steady-state std for the aligned
criterion.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sins_align.core.kalman import discretize, joseph_update
from sins_align.core.models import (averaged_measurement_matrix,
                                    measurement_matrix,
                                    system_matrix)
from sins_align.core.preint import open_loop_velocity, start_frame_increments
from sins_align.core.rotation import so3_exp, so3_log
from sins_align.core.specs import DEG
from sins_align.estimators.quasi_static.fast_path import DUE_TOL, FAST_MIN_BLOCK
from sins_align.estimators.quasi_static.inertial import inertial_alignment


class Backtrack:
    """The backtrack and the fine-pass tuning (see the module docstring)."""

    def backtrack(self):
        """Carry the estimate back to the first sample and rerun the buffer in the fine pass.

        Without feedback the damped mechanization gives ``C(T) = exp(-W T) C(0) B(T)`` where
        ``B`` is the body rotation integrated from the gyro, so the current estimate implies
        ``C(0) = exp(W T) C(T) B(T)^T`` exactly, whatever the corrections were.
        """
        c = self.config
        C0 = so3_exp(self.w_ie * self.t_int) @ self.C @ np.swapaxes(self._B, -1, -2)
        dt, w, f, gap, hole, bridge = self._buf.arrays()
        # the analyses of the buffer see a gap as one sample of its bridging means (the time
        # line stays whole: Earth rate and gravity are matched against time)
        adt, aw, af, bridging = bridged(dt, w, f, gap, bridge)
        # the samples that stand for missing ones: those put in the gaps, and those that
        # span a short hole themselves (an interval well above the usual)
        if len(adt):
            bridging |= adt > 1.5 * median(adt)
        u = start_frame_increments(adt, aw, af)     # shared by the two analyses
        C0, std0, v0 = self._fine_start(C0, adt, aw, af, u)
        r_std, self.fine_period, q = self._sway_velocity_std(
            C0, adt, aw, af, u, bridging, level_steps(hole[:, 0], gap))
        self.fine_R_std = r_std
        self._set_velocity_noise(q)
        self.gyro_noise = measure_gyro_noise(adt, aw[:, 0], bridging)
        R = np.zeros((self.n, 3, 3))
        R[:, [0, 1, 2], [0, 1, 2]] = r_std ** 2
        self._start_pass(C0, fine=True, std=std0, R=R, v0=v0)
        self._steady_start = (self.P.copy(), self.S.copy())
        self.stage = "fine"
        self.backtracked = True
        self._buf = None
        # runs of regular samples (no gap or hole, interval within 15 % of the median) take
        # the fast path, the others go one by one: the callback never stalls on a few odd
        # stamps (without the fast path, everything goes one by one)
        pieces = [(0, len(dt), False)]
        if self.fast_backtrack and c.model == "constant" and len(dt):
            med = median(dt)
            odd = (gap > 0.0) | (hole > 0.0).any(axis=1) | (np.abs(dt - med) > 0.15 * med)
            pieces = runs_of(odd, FAST_MIN_BLOCK)
        for a, b, regular in pieces:
            if not regular:
                for k in range(a, b):
                    self._advance(float(dt[k]), w[k], f[k], float(gap[k]), None,
                                  tuple(hole[k]),
                                  (bridge[k, :3], bridge[k, 3:]) if gap[k] > 0.0 else None)
                continue
            d = dt[a:b]
            mean = float(d.mean())
            uniform = np.all(np.abs(d - mean) <= 1e-9 * mean)
            self._advance_block(mean if uniform else d, w[a:b], f[a:b])

    def _fine_start(self, C0, dt, w, f, u=None):
        """Where the fine pass starts: attitude (N, 3, 3), initial std (N, 6), velocity (N, 3).

        The coarse pass's estimate carried back (``C0``) is checked against the inertial-frame
        alignment of the same buffer (:mod:`sins_align.estimators.quasi_static.inertial`, immune to
        sway): when it lies outside 3 sigma of that solution on some axis (the coarse pass was
        thrown off by sway), the fine pass starts from the inertial-frame attitude instead. The
        initial std is the configured ``fine_initial_std_deg``, widened to 3 sigma of the
        inertial-frame solution (the buffer is used twice, so the prior stays wide); the initial
        velocity is the sway velocity of the first sample, which the mechanization, starting at
        zero, would otherwise carry as a constant offset.
        """
        c = self.config
        sp = c.specs
        fit = inertial_alignment(dt, w, f, self.w_ie, self.g_n, self.limit_std,
                                 sp.gyro_arw, sp.accel_vrw, increments=u)
        lv, hd = (a * DEG for a in c.fine_initial_std_deg)
        cap = max(hd, c.coarse_initial_std_deg[1] * DEG)
        att = np.minimum(np.maximum(np.array([lv, lv, hd]), 3.0 * fit.std), cap)
        diff = np.abs(so3_log(fit.C0 @ np.swapaxes(C0, -1, -2)))
        off = np.any(diff > 3.0 * fit.std, axis=1)
        self.started_inertial = off
        C0 = np.where(off[:, None, None], fit.C0, C0)
        vel = np.maximum(c.initial_velocity_std, 3.0 * fit.v0_std)
        return C0, np.concatenate([att, vel], axis=1), fit.v0

    def buffered_forces(self) -> np.ndarray | None:
        """Before the backtrack: the specific force (M, 3) of run 0's buffered samples, a
        copy (None once the buffer is gone)."""
        if self._buf is None:
            return None
        return self._buf.arrays()[2][:, 0].copy()

    def force_block_means(self, k: int, most: int = 10) -> np.ndarray | None:
        """Before the backtrack: the mean specific force (m, N, 3) of the last ``most``
        complete blocks of ``k`` buffered samples (None once the buffer is gone)."""
        if self._buf is None:
            return None
        return self._buf.force_means(k, most)

    @property
    def steady_std(self) -> np.ndarray | None:
        """Attitude std (N, 3), rad, the fine pass tends to (None before the backtrack);
        computed on first use."""
        if self._steady_std is None and self._steady_start is not None:
            self._steady_std = self._steady_state_std()
        return self._steady_std

    def _steady_state_std(self, horizon: float = 1800.0) -> np.ndarray:
        """Attitude std (N, 3), rad, the fine pass tends to on a static base: the covariance
        recursion alone (no data), iterated over ``horizon`` seconds of fine updates.

        For navigation and tactical grades this is the limit accuracy; for MEMS gyros the
        gyro bias adds a tracking lag to the level axes that no filter without bias states
        can remove, so the aligned flag compares against whichever is larger.
        """
        T = self.fine_period
        F = self._Fconst if self.config.model == "constant" else system_matrix(
            self.config.model, self.w_ie, self.g_n, -self.g_n, np.zeros(3))
        Phi, Qd = discretize(F, self.Qc, T)
        H = averaged_measurement_matrix(measurement_matrix(self.config.model, np.zeros(3)), F, T)
        P, S = self._steady_start
        key = ("steady", self._cfg_key, P.tobytes(), S.tobytes(), self.R.tobytes(), T)
        hit = self.schedules.get(key)
        if hit is not None:
            return hit
        Gd = self.Gamma * T
        prev = None
        PhiT, R = Phi.T, self.R
        if P.shape[0] == S.shape[0] == R.shape[0] == 1:      # one covariance: 2-D arrays
            P, S, R = P[0], S[0], R[0]
        for i in range(int(horizon / T)):
            P = Phi @ P @ PhiT + Qd                           # the fine pass's recursion
            S = Phi @ S + Gd
            P, K, _ = joseph_update(P, H, R)
            S = S - K @ (H @ S)
            if i % 25 == 24:                      # stop once the attitude std has settled
                d = np.diagonal(self._with_bias(P, S), axis1=-2, axis2=-1)[..., :3]
                if prev is not None and np.all(np.abs(d - prev) <= 1e-6 * d):
                    break
                prev = d
        P, S = P.reshape(-1, 6, 6), S.reshape(-1, 6, 6)
        tot = self._with_bias(P, S)
        out = np.broadcast_to(np.sqrt(np.diagonal(tot[:, :3, :3], axis1=1, axis2=2)),
                              (self.n, 3))
        self.schedules.put(key, out)
        return out

    def _sway_velocity_std(self, C0, dt, w, f, u=None, bridging=None, steps=None):
        """Measure the sway velocity; pick the fine update period and its noise.

        Open-loop damped mechanization from ``C0`` over the buffer; a cubic per axis removes
        the drift due to the remaining attitude error; what is left is sway velocity plus
        VRW wander. For each candidate period (``fine_update_period`` times 1, 2, 5, 10, 20)
        the interval means are differenced; the first period whose differences look white
        (lag-1 autocorrelation below 0.4 on every axis: slow ship-like sway is averaged over)
        is used, with half their mean square as the measurement noise (per run, per axis),
        floored by the VRW term and ``fine_min_velocity_noise``.

        The same interval means also measure the accelerometer's white noise, which the
        configured ``accel_vrw`` may understate (a noisier sensor than its specs): it makes
        the velocity a random walk, and the differences of its interval means are then not
        white but correlated at lag 1 (:func:`velocity_random_walk`). When that density is
        significantly above the configured one, the fine pass uses it as its process noise
        (and the measurement noise keeps only the part of the differences it does not
        explain): with the configured density the filter would fit the random walk as
        attitude error and publish a heading std tens of times too small.

        ``bridging`` (bool per sample) marks the samples that stand for missing ones: the
        velocity error a hole leaves is a step of the kind a random walk makes, and it is
        accounted for by the hole's own variance; the noise measurement leaves out the
        intervals that hold one (on the real laser-gyro log, 1 % of the samples dropped in
        bursts made the complete log's in-spec noise look 17 times the specs).

        ``steps`` (rad^2 per sample, the level variance a hole added there) marks the holes
        that may leave a level step: its velocity is a ramp from the hole on (g times the
        step), which the filter estimates as attitude error but one cubic over the buffer
        cannot follow. Where that ramp's std would move the interval means by more than
        the noise floor in one base period, the residual gets a line of its own from the
        hole on (a step and a ramp), and the means' spread is scaled up for the lines'
        degrees of freedom. Without it, under 0.01 deg angular vibration at 43/29 Hz
        (navigation grade, one sample lost every 20 s: steps of 0.0195 deg) the noise
        measured 1.63 mm/s against 0.137 without holes, and the heading std came out at
        1.5 deg against 0.05.

        Returns
        -------
        r_std : ndarray (N, 3), m/s ; period : float, s ; q : ndarray (N,), (m/s)^2/s, the
        velocity random walk density per run (the configured ``accel_vrw ** 2`` unless the
        data show significantly more)
        """
        c = self.config
        vs = open_loop_velocity(dt, w, f, C0, self.w_ie, self.g_n, increments=u)
        t = np.cumsum(dt)
        tn = (t - t.mean()) / (t.std() + 1e-12)
        A = np.vander(tn, 4)
        Y = vs.reshape(len(dt), -1)
        period = base = c.fine_update_period
        r_std = None
        q_cfg = c.specs.accel_vrw ** 2
        coef, *_ = np.linalg.lstsq(A, Y, rcond=None)
        csum = running_sum(Y - A @ coef)
        pieces = None
        if steps is not None:
            ramp = math.sqrt(q_cfg * base / 3.0 + c.fine_min_velocity_noise ** 2) / base
            cut = np.flatnonzero(self.g * np.sqrt(steps) > ramp)
            cut = cut[cut > 0]
            if len(cut):
                # the cubic and a line per piece fitted together: both sides with each
                # piece's own line taken out, then the cubic (Frisch-Waugh); kept when
                # the base period's noise is smaller so, for the lines' degrees of freedom
                pieces = np.concatenate([[0], cut, [len(dt)]])
                Ap = A - piecewise_lines(t, A, pieces[:-1])
                Yp = Y - piecewise_lines(t, Y, pieces[:-1])
                coef, *_ = np.linalg.lstsq(Ap, Yp, rcond=None)
                csum_p = running_sum(Yp - Ap @ coef)
                m0 = interval_means(csum, t, dt, base)[0]
                m1 = interval_means(csum_p, t, dt, base, pieces)[0]
                if m1 is not None and m0 is not None and (noise_variance(m1).sum()
                                                           < noise_variance(m0).sum()):
                    csum = csum_p
                else:
                    pieces = None
        q = np.full(self.n, q_cfg)
        for mult in (1, 2, 5, 10, 20):
            p = base * mult
            means, edges, counts, n_int = interval_means(csum, t, dt, p, pieces)
            if means is None:
                break
            d = np.diff(means, axis=0)
            var = noise_variance(means, d)
            # differences of white means are MA(1): lag 1 -0.5, nothing beyond; a tone shows
            # at some lag up to 5 (0.2 Hz in 1 s means: lag 5), alternating means at lag 1 -1
            dd = np.maximum(np.sum(d * d, axis=0), 1e-300)
            lags = [np.sum(d[k:] * d[:-k], axis=0) / dd for k in range(1, min(6, len(d) // 2))]
            r1 = lags[0]
            white_d = (r1 < 0.4) & (r1 > -0.75)
            for rk in lags[1:]:
                white_d &= np.abs(rk) < 0.4
            # the accelerometer's white noise measured on the same means: where it is
            # significantly above the configured density, the random walk it makes is
            # process noise, and only the rest of the differences is measurement noise
            # (the specs are isotropic, so are Q and this estimate: the three axes pooled)
            valid = None
            if bridging is not None and bridging.any():
                hole = np.add.reduceat(bridging.astype(np.int64), edges[:-1])[:n_int] > 0
                hole &= counts[:n_int] > 0
                # c_k = d_k^2 + 2 d_k d_(k+1) spans the intervals k, k+1 and k+2
                valid = ~(hole[:-2] | hole[1:-1] | hole[2:])
            qa, noisy = velocity_random_walk(d.reshape(len(d), self.n, 3), p, q_cfg,
                                             valid=valid)
            q = np.where(noisy, qa, q_cfg)
            white = np.maximum(0.5 * np.mean(d ** 2, axis=0).reshape(self.n, 3)
                               - np.where(noisy, qa, 0.0)[:, None] * p / 3.0, 0.0)
            var = np.where(noisy[:, None], white, var.reshape(self.n, 3))
            floor2 = q[:, None] * p / 3.0 + c.fine_min_velocity_noise ** 2
            # the sway's direction in the estimated frame moves with the heading error: a
            # horizontal axis is as noisy as the noisier one
            var[:, :2] = var[:, :2].max(axis=1, keepdims=True)
            period, r_std = p, np.sqrt(np.maximum(var, floor2))
            if np.all(white_d):
                break
        if r_std is None:
            floor2 = q_cfg * base / 3.0 + c.fine_min_velocity_noise ** 2
            r_std = np.full((self.n, 3), math.sqrt(floor2))
        return r_std, period, q

    def _set_velocity_noise(self, q: np.ndarray):
        """The fine pass's velocity random walk density (N,), (m/s)^2/s: the process noise
        the filter propagates (shared when every run has the same, else one per run)."""
        self.accel_vrw_used = np.sqrt(q)
        Qc = self.Qc if self.Qc.ndim == 2 else self.Qc[0]
        if np.all(q == Qc[3, 3]):
            return
        if np.all(q == q[0]):
            Qc = Qc.copy()
            Qc[3:, 3:] = np.eye(3) * q[0]
        else:
            Qc = np.broadcast_to(Qc, (self.n, 6, 6)).copy()
            Qc[:, 3:, 3:] = np.eye(3) * q[:, None, None]
        self.Qc = Qc
        # everything derived from Qc: the discretisations and the schedule cache's key
        self._cache = {k: v for k, v in self._cache.items() if k[0] not in ("D", "DT", "Dm")}
        self._cfg_key = self._cfg_key[:3] + (Qc.tobytes(),) + self._cfg_key[4:]


@dataclass(frozen=True)
class GyroNoiseFit:
    """The gyro's white-noise level the buffered rates show (densities, rad^2/s: an angle
    random walk squared), from :func:`band_noise_density` in the top octave below 80 % of
    the Nyquist frequency (0.2-0.4 of the sample rate: ``q_top``) and in the octave under
    it (0.1-0.2: ``q_next``); None where the buffer holds no whole segment.

    A white noise gives one level in both; what a platform's motion leaks into them falls
    with frequency (a swaying car's or a ship's), an engine's tones raise one octave more
    than the other, and a gyro's quantization rises with frequency (the real ring-laser
    log: 25-35x the navigation preset at 5-20 Hz, 60-70x at 30-50 Hz). The top level is the
    sensor's noise floor only where the two agree (:attr:`flat`).
    """

    q_top: float | None
    q_next: float | None
    #: the white density the increments' quantization alone would give, rad^2/s (q^2/(12 dt)
    #: for a quantum q of the angle increments; 0 where the rates are not on a lattice)
    q_quant: float = 0.0

    @property
    def flat(self) -> bool:
        """The top two octaves agree within FLAT_RATIO either way (in the density's root)."""
        return (self.q_top is not None and self.q_next is not None and self.q_top > 0.0
                and self.q_top / FLAT_RATIO ** 2 <= self.q_next <= FLAT_RATIO ** 2 * self.q_top)


#: How far apart (the density's square root, either way) the top two octaves may stand for
#: the top's level to count as the gyro's noise floor (:attr:`GyroNoiseFit.flat`).
FLAT_RATIO = 1.5
#: Samples per periodogram of :func:`band_noise_density` (a Hann window this long keeps a
#: ship's sway below a navigation gyro's noise at 0.2 of the sample rate; 64 does not), and
#: the whole segments it needs (fewer: a median of a few hundred ordinates, 1 % of samples
#: lost at random leave ~2 in 60 s of the real log, and its octaves then read alike by chance)
SEGMENT = 256
MIN_SEGMENTS = 8


def measure_gyro_noise(dt: np.ndarray, w: np.ndarray,
                       bridging: np.ndarray | None = None) -> GyroNoiseFit:
    """:class:`GyroNoiseFit` of the rates ``w`` (M, 3) with intervals ``dt`` (M,); the
    samples ``bridging`` marks (put in for missing ones) are left out."""
    ok = np.ones(len(dt), dtype=bool) if bridging is None else ~np.asarray(bridging, bool)
    h = median(dt)
    fs = 1.0 / h
    q = increment_quantum(w[ok] * h)
    top, nxt = band_noise_density(dt, w, ok, [(0.2 * fs, 0.4 * fs), (0.1 * fs, 0.2 * fs)])
    return GyroNoiseFit(top, nxt, q * q / (12.0 * h))


def increment_quantum(x: np.ndarray) -> float:
    """The largest quantum (over the three axes) of increments ``x`` (M, 3) that lie on a
    lattice (an IMU giving whole counts of an angle quantum, as ring-laser and many
    navigation-grade gyros do): the smallest step between their distinct values, where at
    least 99 % of them are whole multiples of it (to 1e-3 of a step) and they take fewer
    distinct values than half the samples; 0 when no axis is on a lattice."""
    out = 0.0
    for k in range(x.shape[1]):
        v = np.unique(x[:, k])
        if len(v) < 2 or len(v) > len(x) // 2:
            continue
        step = np.diff(v)
        step = step[step > 1e-9 * max(float(np.abs(v).max()), 1e-300)]
        if not len(step):
            continue
        q = float(step.min())
        r = (x[:, k] - v[0]) / q
        if np.mean(np.abs(r - np.round(r)) <= 1e-3) >= 0.99:
            out = max(out, q)
    return out


def band_noise_density(dt: np.ndarray, x: np.ndarray, ok: np.ndarray,
                       bands: list[tuple[float, float]]) -> list[float | None]:
    """The white noise density of ``x`` (M, 3; its unit squared per Hz: rad^2/s for rates)
    in each band ``(lo, hi)`` Hz of ``bands``: the median of the periodograms of the
    segments of SEGMENT consecutive samples ``ok`` (M,) holds (each less its line,
    Hann-windowed: the leakage of a large slow motion stays within a few bins), over the
    bins in the band and the three axes, divided by ln 2 (a white noise's periodogram
    ordinate is exponential). A median: a few tones in the band move it little. None for
    every band when fewer than MIN_SEGMENTS segments are whole (no hole, no sample put in,
    intervals within 15 % of the median), for a band that holds no bin."""
    h = median(dt)
    good = ok & (np.abs(dt - h) <= 0.15 * h)
    starts, k = [], 0
    for b in np.append(np.flatnonzero(~good), len(dt)).tolist():
        while b - k >= SEGMENT:
            starts.append(k)
            k += SEGMENT
        k = b + 1
    if len(starts) < MIN_SEGMENTS:
        return [None] * len(bands)
    seg = x[np.asarray(starts)[:, None] + np.arange(SEGMENT)]        # (S, SEGMENT, 3)
    tt = np.arange(SEGMENT) - 0.5 * (SEGMENT - 1)
    seg = seg - seg.mean(axis=1, keepdims=True)
    seg = seg - tt[None, :, None] * (np.einsum("j,sjk->sk", tt, seg) / np.dot(tt, tt))[:, None]
    win = np.hanning(SEGMENT)
    spec = np.abs(np.fft.rfft(seg * win[None, :, None], axis=1)) ** 2
    f = np.fft.rfftfreq(SEGMENT, h)
    out = []
    for lo, hi in bands:
        band = (f >= lo) & (f <= hi)
        out.append(float(np.median(spec[:, band]) * h / np.dot(win, win) / math.log(2.0))
                   if band.any() else None)
    return out


def velocity_random_walk(d: np.ndarray, p: float, q0: float = 0.0, z: float = 2.0,
                         valid: np.ndarray | None = None):
    """White accelerometer noise seen in the differences ``d`` (M, K, 3) of consecutive
    interval means (``p`` s each) of a velocity (K runs, three axes with the same noise
    density): density (K,), (m/s)^2/s, and whether it is significantly above ``q0`` (K,)
    (by more than ``z`` standard errors).

    A random walk of density q gives differences of interval means whose variance is
    2/3 q p and lag-1 covariance q p / 6, nothing beyond; white noise on the means
    (sway averaged over the interval, variance R) gives 2 R and -R. So the long-run
    variance of the differences, gamma_0 + 2 gamma_1, is q p whatever R is: any motion
    whose velocity stays bounded contributes nothing to it. Its standard error comes from
    the scatter of the per-interval terms d_k^2 + 2 d_k d_(k+1) (their own long-run
    variance, lags up to 2).
    """
    c = (d[:-1] ** 2 + 2.0 * d[:-1] * d[1:]).mean(axis=-1)
    if valid is not None:
        c = c[np.asarray(valid, dtype=bool)[:len(c)]]
    if len(c) < 3:
        return np.zeros(d.shape[1]), np.zeros(d.shape[1], dtype=bool)
    m = len(c)
    qp = c.mean(axis=0)
    e = c - qp
    lrv = np.mean(e * e, axis=0)
    for k in (1, 2):
        if m > k:
            lrv = lrv + 2.0 * np.sum(e[k:] * e[:-k], axis=0) / m
    se = np.sqrt(np.maximum(lrv, np.mean(e * e, axis=0) / 4.0) / m)
    return qp / p, qp > q0 * p + z * se


def running_sum(res: np.ndarray) -> np.ndarray:
    """(M + 1, K): the running sum of the residuals ``res`` (M, K) from a row of zeros (any
    interval's sum is a difference of two rows)."""
    csum = np.cumsum(res, axis=0)
    return np.concatenate([np.zeros((1, csum.shape[1])), csum])


def interval_means(csum, t, dt, p: float, pieces=None):
    """The means (n, K) of the residuals whose running sum is ``csum`` over intervals of
    ``p`` s, with the sample index ``edges`` (n + 1) where each starts, their sample
    ``counts`` (n) and ``n``; (None, None, None, n) when fewer than 8 are left.

    With ``pieces`` (the sample indices where the residual's lines start, and its length),
    the means are scaled up by ``sqrt(n / (n - lost))``: each line after the first (the
    cubic's own) takes two degrees of freedom of the means (a piece shorter than two
    intervals, what it spans)."""
    # by the sample midpoints, a hair early: the midpoint of a double interval (a
    # rejected or missing sample) can fall on a boundary, where rounding would decide
    # (the fine pass's updates count that sample in the interval it closes, the
    # earlier one: fast_path.reached)
    idx = np.floor((t - (0.5 + DUE_TOL) * dt) / p).astype(int)
    n_int = int(idx[-1])
    lost = 0.0
    if pieces is not None:
        span = (t[pieces[2:] - 1] - t[pieces[1:-1]] + dt[pieces[1:-1]]) / p
        lost = float(np.minimum(span, 2.0).sum())
    if n_int - lost < 8:
        return None, None, None, n_int
    # idx never decreases: interval j holds the samples edges[j] .. edges[j+1] - 1
    edges = np.searchsorted(idx, np.arange(n_int + 1))
    counts = np.diff(edges)
    means = (csum[edges[1:]] - csum[edges[:-1]]) / np.maximum(counts, 1)[:, None]
    if lost:
        means = means * math.sqrt(n_int / (n_int - lost))
    return means, edges, counts, n_int


def noise_variance(means: np.ndarray, d: np.ndarray | None = None) -> np.ndarray:
    """The measurement noise variance (K,) the interval ``means`` (n, K) show: half the
    mean square of their differences ``d`` (blind to a slow wander), but never below the
    means' own mean square: a sway that is not white (a slow tone) has differences smaller
    than its spread, and gating would then take every other interval for a shove."""
    d = np.diff(means, axis=0) if d is None else d
    return np.maximum(0.5 * np.mean(d ** 2, axis=0), np.mean(means ** 2, axis=0))


def level_steps(va: np.ndarray, gap: np.ndarray) -> np.ndarray:
    """The holes' level variance ``va`` (M,) of the buffered samples on the time line of
    :func:`bridged`: a gap's on the sample put in for it (the step happens there), a short
    hole's on the sample that spans it."""
    k = np.flatnonzero(gap > 0.0)
    if not len(k):
        return va
    put = k + np.arange(len(k))
    out = np.insert(va, k, va[k])
    out[put + 1] = 0.0
    return out


def piecewise_lines(t: np.ndarray, y: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """The least-squares line of ``y`` (M, K) against ``t`` (M,) on each piece of samples
    ``starts[j] .. starts[j + 1] - 1`` (the last to the end; ``starts[0] == 0``), evaluated
    at every sample (M, K)."""
    n = np.diff(np.append(starts, len(t)))
    idx = np.repeat(np.arange(len(starts)), n)
    tc = t - np.repeat(np.add.reduceat(t, starts) / n, n)         # centred per piece
    ym = np.add.reduceat(y, starts, axis=0) / n[:, None]
    stt = np.add.reduceat(tc * tc, starts)
    sty = np.add.reduceat(tc[:, None] * y, starts, axis=0)
    b = np.where(stt[:, None] > 0.0, sty / np.where(stt > 0.0, stt, 1.0)[:, None], 0.0)
    return ym[idx] + b[idx] * tc[:, None]


def median(x: np.ndarray) -> float:
    """The median of the finite values ``x`` (1-D, not empty): np.median's value (the middle
    one, or the mean of the two middle ones) from one np.partition. np.median itself imports
    numpy.ma on its first call (10-35 ms of a cold run)."""
    n = len(x)
    h = n // 2
    if n % 2:
        return float(np.partition(x, h)[h])
    p = np.partition(x, (h - 1, h))
    return float((p[h - 1] + p[h]) / 2.0)


def bridged(dt, w, f, gap, bridge):
    """dt, w, f with a sample of the bridging means (rate, specific force) and the gap's
    length put before each sample that follows a gap (the buffer as the filter ran it),
    and a mask of the samples put in."""
    k = np.flatnonzero(gap > 0.0)
    put = np.zeros(len(dt) + len(k), dtype=bool)
    if not len(k):
        return dt, w, f, put
    n = w.shape[1]
    put[k + np.arange(len(k))] = True
    dt = np.insert(dt, k, gap[k])
    w = np.insert(w, k, np.broadcast_to(bridge[k, None, :3], (len(k), n, 3)), axis=0)
    f = np.insert(f, k, np.broadcast_to(bridge[k, None, 3:], (len(k), n, 3)), axis=0)
    return dt, w, f, put


class SampleBuffer:
    """Growable store of accepted samples for the backtrack: dt, gap, the hole variances
    (attitude, velocity) (M,) and a gap's bridging rate and specific force (M, 6), w, f
    (M, N, 3)."""

    def __init__(self, n: int):
        self._t = np.empty((1024, 10))
        self._wf = np.empty((1024, n, 6))
        self._n = 0
        self._blocks = None            # (k, block means) of force_means
        self._last_means = None        # (k, most, blocks), the array force_means returned

    def append(self, dt, w, f, gap, hole=(0.0, 0.0), bridge=None):
        if self._n == len(self._t):
            self._t = np.concatenate([self._t, np.empty_like(self._t)])
            self._wf = np.concatenate([self._wf, np.empty_like(self._wf)])
        n = self._n
        if bridge is None:
            self._t[n] = (dt, gap, hole[0], hole[1], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        else:
            self._t[n, :4] = (dt, gap, hole[0], hole[1])
            self._t[n, 4:] = np.concatenate(bridge)
        if self._wf.shape[1] == 1:           # one run: one row written at once
            self._wf[n, 0] = [*w.reshape(3).tolist(), *f.reshape(3).tolist()]
        else:
            self._wf[n, :, :3] = w
            self._wf[n, :, 3:] = f
        self._n = n + 1

    def extend(self, dt, w, f):
        """Append a block of samples (no gaps): w, f (M, N, 3)."""
        m = len(w)
        while self._n + m > len(self._t):
            self._t = np.concatenate([self._t, np.empty_like(self._t)])
            self._wf = np.concatenate([self._wf, np.empty_like(self._wf)])
        self._t[self._n:self._n + m, 0] = dt
        self._t[self._n:self._n + m, 1:] = 0.0
        self._wf[self._n:self._n + m, :, :3] = w
        self._wf[self._n:self._n + m, :, 3:] = f
        self._n += m

    def force_means(self, k: int, most: int) -> np.ndarray:
        """Mean specific force of the last ``most`` complete blocks of ``k`` samples (counted
        from the first sample, so the same blocks whatever the feeding), (m, N, 3). Each block
        is averaged once (the buffer holds a minute: tens of blocks). Until a block
        completes the same array is returned (not to be written to)."""
        key = (k, most, self._n // k)
        last = self._last_means
        if last is not None and last[0] == key:
            return last[1]
        if self._blocks is None or self._blocks[0] != k:
            self._blocks = (k, [])
        means = self._blocks[1]
        for j in range(len(means), self._n // k):
            means.append(self._wf[j * k:(j + 1) * k, :, 3:].mean(axis=0))
        got = means[-most:]
        out = np.array(got) if got else np.zeros((0, self._wf.shape[1], 3))
        out.flags.writeable = False
        self._last_means = (key, out)
        return out

    def arrays(self):
        """dt, w, f, gap, hole (M, 2), bridge (M, 6): rate, specific force."""
        t = self._t[: self._n]
        wf = self._wf[: self._n]
        return t[:, 0], wf[..., :3], wf[..., 3:], t[:, 1], t[:, 2:4], t[:, 4:]


def runs_of(odd: np.ndarray, least: int):
    """(start, end, regular) pieces covering ``odd``'s indices in order: runs of at least
    ``least`` samples that are not odd are regular, everything between them is not."""
    ok = np.concatenate(([False], ~odd, [False]))
    edges = np.flatnonzero(np.diff(ok.astype(np.int8)))
    starts, ends = edges[0::2], edges[1::2]
    keep = ends - starts >= least
    out, k = [], 0
    for a, b in zip(starts[keep].tolist(), ends[keep].tolist()):
        if a > k:
            out.append((k, a, False))
        out.append((a, b, True))
        k = b
    if k < len(odd):
        out.append((k, len(odd), False))
    return out
