"""Bridging lost IMU samples (numpy only).

A stream that loses samples (a dropped message, a busy bus) leaves a hole of ``g`` s between
two accepted samples that is longer than the IMU's interval. The strapdown turns each sample
(an interval's mean rate and specific force) into its interval's increments; taken as it is,
the sample after the hole would stand for the whole hole. On a vibrating IMU (a rotor UAV:
3 m/s^2 and 2 deg/s RMS at 20-80 Hz) one sample's vibration times the hole is a velocity and
attitude step that nothing in the filter's covariance contains: 0.05 m/s for three lost
samples at 100 Hz, 0.7 m/s for 35, against a velocity std of 0.02 m/s. The filter takes the
step for tilt: with 3 samples lost once at 100 Hz, 28-40 % of the instants that follow had
the attitude error beyond 3 sigma (seed 003's UAV with the accelerometer vibrating; honest
without the vibration); with a 0.35 s hole while the bank of heading hypotheses ran, the
bank collapsed onto a hypothesis 70 deg off.

So a hole is bridged with what the samples before it say and the covariance grows by what
they cannot say (:func:`bridge_gaps`):

- the sample after the hole keeps one nominal interval; the rest of the hole, ``g``, is
  bridged by a made-up sample, the mean of the accepted samples over :data:`FILL_WINDOW` s
  before the hole (the slow motion; the vibration averages out of it); when another hole
  just before leaves that window less than half full (losses come in bursts), the last
  window's worth of samples held within :data:`FILL_REACH` windows;
- one sample lost (``g`` up to ``GAP_RATIO`` nominal intervals) is predicted instead, when
  the :data:`PREDICT_LAGS` samples before it are a nominal interval apart: per axis, the
  least-squares fit of each sample on the ones before it, the one after it and a constant,
  over the last :data:`PREDICT_FIT` s of samples, applied around the hole (the sample after
  it is at hand: it shows the hole). A rotor's vibration is a few tones, which such a fit
  follows: seed 003's UAV with 3 m/s^2 at 20-80 Hz and 2 % of the samples lost at random,
  the made-up sample erred by 1.5-2.0 m/s^2 RMS (the vibration itself) as the mean,
  0.010-0.019 predicted. The mean's error was a velocity step of ~0.02 m/s that every
  heading hypothesis of a bank carries turned by its own heading and that the likelihood
  weights took for heading evidence (each hole turned the log-weights by 0.3-0.45, in a
  random direction): while the UAV hovered, the bank's heading (e/sigma)^2 was 1.5-7.7 over
  seeds 0-5 (38 % of the instants beyond 3 sigma in seed 1), 0.3-3.6 predicted (0.2-3.9
  with nothing lost). The variance stays the mean's (below): it covers the prediction many
  times over;
- the hole's true content differs from that mean by its own fast part (vibration, noise)
  and by any change of the slow motion. Per axis, with ``s^2`` the variance of the samples
  about their mean over the window and ``d`` the sample after the hole less the mean, the
  variance is ``g dt s^2 + (g d)^2``, and the largest axis's is added to all three (body
  axes, at the hole's end: attitude from the rates, velocity from the specific force; the
  same on every axis, so no heading hypothesis of a bank is favoured by its shape): the
  first as if the lost samples' deviations were independent, the second a change up to
  the one the sample after the hole shows (reached at the hole's start). Measured per axis
  over 1,200 holes of 1-90 samples at random places on seed 003's UAV (with and without
  vibration) and a city car: 0.06-0.7 % of the axes beyond 3 sigma, the mean squared
  ratio 0.1-0.6; the misses are holes of 0.6 s and more in a manoeuvre that starts and
  ends inside the hole (nothing in the samples shows it; ``max_gap`` bounds the holes
  bridged at all).

A hole is an interval above :data:`GAP_RATIO` times the nominal interval (the median of the
intervals the filter started with), between the samples' instants (the stamps' own unless
they jitter: then those of a steady clock fitted to them, whose intervals across a hole are
a whole number of nominal ones; :mod:`~sins_align.core.clock`).
Everything depends on the stamps and the samples only, so a stream fed sample by sample, in
blocks, or run again after a late measurement gives the same bridges.
"""
from __future__ import annotations

import numpy as np

__all__ = ["GAP_RATIO", "FILL_WINDOW", "FILL_REACH", "PREDICT_LAGS", "PREDICT_FIT",
           "Bridges", "bridge_gaps"]

#: an interval above this multiple of the nominal interval is a hole
GAP_RATIO = 1.5
#: s of samples before a hole whose mean bridges it (at least 4 nominal intervals)
FILL_WINDOW = 0.25
#: how far back (in windows) a hole looks when its window holds less than half the samples
#: it should (another hole just before it: losses come in bursts)
FILL_REACH = 3.0
#: one lost sample is predicted from this many samples before it (and the one after it)
PREDICT_LAGS = 6
#: s of held samples the predictor of a lost sample is fitted on (within what the aligner
#: holds for a rewind; an IMU slower than ~32 Hz has too few rows in it: the mean)
PREDICT_FIT = 1.0


class Bridges:
    """The samples with their holes bridged: stamps ``t`` (m,), intervals ``dts`` (m,),
    rates ``w`` and specific forces ``f`` (m, 3); ``fills``: the index of each made-up
    sample, ``var_w`` and ``var_f`` (len(fills), 3): the variance each adds, rad^2 and
    (m/s)^2, body axes."""

    __slots__ = ("t", "dts", "w", "f", "fills", "var_w", "var_f")

    def __init__(self, t, dts, w, f, fills=(), var_w=None, var_f=None):
        self.t, self.dts, self.w, self.f = t, dts, w, f
        self.fills = list(fills)
        self.var_w, self.var_f = var_w, var_f


def bridge_gaps(prev: float, t, w, f, dt_nominal: float, before) -> Bridges:
    """Bridge the holes among samples ``t`` (after the stamp ``prev``), rates ``w`` and
    specific forces ``f`` (see the module docstring).

    ``before(t_end, length)`` gives the accepted samples (t, w, f) stamped within
    ``[t_end - length, t_end]`` (those of ``t`` included: they are accepted). Without holes
    the inputs come back as they are."""
    n = len(t)
    if n == 1:                              # (a live stream's sample, in floats)
        dt = float(t[0]) - prev
        dts = np.array([dt])
        if dt <= GAP_RATIO * dt_nominal:
            return Bridges(t, dts, w, f)
    else:
        dts = np.diff(np.concatenate(([prev], t)))
    holes = np.flatnonzero(dts > GAP_RATIO * dt_nominal)
    if not len(holes):
        return Bridges(t, dts, w, f)
    window = max(FILL_WINDOW, 4.0 * dt_nominal)
    full = int(window / dt_nominal)         # the samples a window holds without holes
    ft, fw, ff, vw, vf = [], [], [], [], []
    for i in holes.tolist():
        t_prev = prev if i == 0 else float(t[i - 1])
        g = float(dts[i]) - dt_nominal
        _, ww, fs = before(t_prev, window)
        if len(ww) < 0.5 * full:            # (a hole just before: the last samples held)
            _, ww, fs = before(t_prev, FILL_REACH * window)
            ww, fs = ww[-full:], fs[-full:]
        if len(ww) >= 2:
            mw, mf = ww.mean(axis=0), fs.mean(axis=0)
            sw, sf = ((ww - mw) ** 2).mean(axis=0), ((fs - mf) ** 2).mean(axis=0)
        else:                               # (nothing before it: the sample bridges it)
            mw, mf, sw, sf = w[i], f[i], np.zeros(3), np.zeros(3)
        ft.append(t_prev + g)
        # the variance: that of the mean (below: the predicted sample errs less)
        vw.append(np.full(3, (g * dt_nominal * sw + (g * (w[i] - mw)) ** 2).max()))
        vf.append(np.full(3, (g * dt_nominal * sf + (g * (f[i] - mf)) ** 2).max()))
        if g <= GAP_RATIO * dt_nominal:     # one sample lost: predicted, if it can be
            th, wh, fh = before(t_prev, PREDICT_FIT)
            pw = _predicted(th, wh, w[i], dt_nominal)
            pf = _predicted(th, fh, f[i], dt_nominal)
            if pw is not None and pf is not None:
                mw, mf = pw, pf
        fw.append(mw)
        ff.append(mf)
    t2 = np.insert(np.asarray(t, dtype=float), holes, ft)
    w2 = np.insert(np.asarray(w, dtype=float), holes, fw, axis=0)
    f2 = np.insert(np.asarray(f, dtype=float), holes, ff, axis=0)
    d2 = np.insert(dts, holes, 0.0)
    fills = holes + np.arange(len(holes))
    d2[fills] = np.array(ft) - np.concatenate(([prev], t2))[fills]
    d2[fills + 1] = t2[fills + 1] - t2[fills]
    return Bridges(t2, d2, w2, f2, fills.tolist(), np.array(vw), np.array(vf))


def _predicted(th, xh, x_after, dt_nominal: float):
    """The lost sample between the held samples ``th``, ``xh`` (m,), (m, 3) (the last of them
    the one before the hole) and ``x_after`` (3,), the sample after it: per axis, the least
    squares fit of each held sample on the :data:`PREDICT_LAGS` before it, the one after it
    and a constant, over the rows of ``th`` whose samples are all one nominal interval apart;
    None when the samples before the hole are not, or fewer than ``3 x`` the coefficients'
    rows are."""
    p = PREDICT_LAGS
    m = len(th)
    if m < p + 2:
        return None
    steady = np.diff(th) <= GAP_RATIO * dt_nominal
    if not steady[-p:].all():
        return None
    breaks = np.concatenate(([0], np.cumsum(~steady)))
    rows = np.arange(p, m - 1)
    rows = rows[breaks[rows + 1] == breaks[rows - p]]
    if len(rows) < 3 * (p + 2):
        return None
    out = np.empty(3)
    for a in range(3):
        x = xh[:, a]
        X = np.column_stack([x[rows - j] for j in range(1, p + 1)]
                            + [x[rows + 1], np.ones(len(rows))])
        coef = np.linalg.lstsq(X, x[rows], rcond=None)[0]
        out[a] = np.concatenate((x[-1:-p - 1:-1], [x_after[a], 1.0])) @ coef
    return out
