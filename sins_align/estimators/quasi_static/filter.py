"""The filter itself: damped mechanization and error-state Kalman filter of the paper,
vectorised over N runs (:class:`AlignmentFilter`).

AlignmentFilter is made of three parts, one module each: this one (the per-sample
recursion: mechanization, covariance propagation, the update with its gate and
re-inflation), :mod:`~sins_align.estimators.quasi_static.fast_path` (closed-form integration
between updates, the gain-schedule cache) and
:mod:`~sins_align.estimators.quasi_static.backtrack` (the backtrack and the fine pass's
tuning).
"""
from __future__ import annotations


import numpy as np

from sins_align.core.earth import earth_rate_enu, gravity_enu
from sins_align.core.kalman import discretize, inv3, joseph_update, nis
from sins_align.core.models import (apply_correction, averaged_measurement_matrix,
                                    bias_input_matrix, measurement_matrix,
                                    system_matrix)
from sins_align.core.preint import earth_poly
from sins_align.core.rotation import so3_exp
from sins_align.core.specs import DEG, limit_covariance
from sins_align.estimators.quasi_static.backtrack import Backtrack, SampleBuffer
from sins_align.estimators.quasi_static.config import AlignConfig
from sins_align.estimators.quasi_static.fast_path import FastPath, reached
from sins_align.estimators.quasi_static.schedule import SHARED_SCHEDULES, GainScheduleCache

#: s: with heading unobservable, the gyro bias is attitude noise reaching its size in this time
BIAS_TRACK_TIME = 10.0
_THIRDS = np.full(3, 1.0 / 3.0)     # NIS per degree of freedom


class AlignmentFilter(FastPath, Backtrack):
    """The filter itself, vectorised over N independent runs that share one time line.

    No input checking: callers hand it accepted samples only. :class:`Aligner` (N = 1)
    wraps it for streaming data; Monte Carlo and batch tools drive N runs at once. With
    the 'constant' model the coarse-pass covariance and gain do not depend on the data,
    so they are computed once and shared by all runs (shape (1, 6, 6)).

    Parameters
    ----------
    config : AlignConfig
    C0 : ndarray (N, 3, 3) — initial C_b^n estimate of each run.
    fast_backtrack : re-run the buffer with the fast path when it is uniformly sampled
        (constant model); False keeps the whole run on the per-sample reference path.
    schedules : the gain-schedule cache (default: the one all filters share).
    """

    def __init__(self, config: AlignConfig, C0: np.ndarray, fast_backtrack: bool = True,
                 schedules: GainScheduleCache | None = None):
        self.config = c = config
        self.fast_backtrack = fast_backtrack
        self.schedules = SHARED_SCHEDULES if schedules is None else schedules
        self.lat = c.latitude_deg * DEG
        self.w_ie = earth_rate_enu(self.lat)
        self.g_n = gravity_enu(self.lat, c.height_m)
        self.g = -self.g_n[2]
        sp = c.specs
        self.limit_std = np.sqrt(np.diag(limit_covariance(self.lat, sp, self.g)))
        q_att = sp.gyro_arw ** 2
        if not (self.limit_std[2] < c.heading_max_limit_std_deg * DEG):
            # heading unobservable (MEMS): a gyro bias of degrees per minute turns the level
            # faster than the gyro noise alone lets the filter follow; without bias states
            # it would lag, be gated and diverge. The bias enters as attitude noise that
            # reaches its own size over BIAS_TRACK_TIME.
            q_att += sp.gyro_bias ** 2 * BIAS_TRACK_TIME
        # Bias instability (first-order Gauss-Markov wander of std s, correlation time tau):
        # at any instant the wander is one more bias of std s, considered with the turn-on
        # bias; and its changes move the accelerometer-levelled tilt by (change) / g. The
        # filter, which has no accelerometer bias states, would read that apparent tilt drift
        # as an east gyro rate, i.e. as heading (nav grade, 30 ug at tau 300 s: heading 4-9
        # sigma off, flagged aligned). Over times short next to tau the wander is a random
        # walk of density s sqrt(2 / tau): the same walk of the tilt (E and N), 2 s^2 /
        # (tau g^2) rad^2/s, is level process noise, which widens the heading that the level
        # drift gives. (The gyro's wander is covered by the considered bias alone.) A warm-up
        # in the specs is covered as one more such wander, of its size and time constant.
        q_lvl = q_att + sp.bias_walk_var[1] / self.g ** 2
        self.Qc = np.diag([q_lvl, q_lvl, q_att] + [sp.accel_vrw ** 2] * 3)
        bg2, ba2 = sp.bias_prior_var
        self._bias_var = np.array([ba2] * 3 + [bg2] * 3)
        self.Gamma = bias_input_matrix(c.model)
        self._Fconst = system_matrix("constant", self.w_ie, self.g_n)
        self._Ue, self._W = earth_poly(self.w_ie)    # exp(-(w_ie x) s) in sin, cos of W s
        self._Ue2 = self._Ue @ self._Ue
        # (3, 9): column 3 k + i holds column i of M_k, M = I, Ue, Ue^2 (see _advance_segments)
        self._g_col = self.g_n[:, None]
        self._g_floats = tuple(self.g_n.tolist())
        self._Gv = np.stack([np.eye(3), self._Ue, self._Ue2]).transpose(1, 0, 2).reshape(3, 9)
        self._cache: dict = {}
        self._scratch: dict = {}       # the fast path's large temporaries, reused (scratch_array)
        self._h_memo: dict = {}        # id(H) -> (H, its bytes) (FastPath._h_bytes)
        self.on_update = None          # fast path: called with the sample index after updates
        self._rerun = False
        self._cfg_key = (c.model, self.w_ie.tobytes(), self.g_n.tobytes(), self.Qc.tobytes(),
                         self._bias_var.tobytes())
        self.fast = False
        C0 = np.asarray(C0, dtype=float).reshape(-1, 3, 3)
        self.n = len(C0)
        self._start_pass(C0, fine=False, std=c.coarse_initial_std_deg,
                         R=np.eye(3)[None] * c.coarse_velocity_noise ** 2)
        self.stage = "coarse"
        self.backtracked = False
        self.fine_R_std: np.ndarray | None = None
        # the fine pass's accelerometer noise density per run, m/s/sqrt(s): the configured
        # accel_vrw, or more when the buffer shows more (None before the backtrack)
        self.accel_vrw_used: np.ndarray | None = None
        # the gyro's white-noise floor the buffer shows (backtrack.GyroNoiseFit; None
        # before the backtrack)
        self.gyro_noise = None
        self.fine_period = c.fine_update_period
        self._steady_start = None
        self._steady_std = None
        self._buf = SampleBuffer(self.n) if c.backtrack else None
        self._B = np.broadcast_to(np.eye(3), (self.n, 3, 3)).copy()
        self.reinflations = np.zeros(self.n, dtype=int)
        self.gated_updates = np.zeros(self.n, dtype=int)
        # the fine pass started from the inertial-frame alignment (inertial.py)
        self.started_inertial = np.zeros(self.n, dtype=bool)

    # ------------------------------------------------------------------ state
    def _start_pass(self, C0, fine: bool, std, R, v0=None):
        """``std``: (level, heading) deg shared by all runs, or the initial (attitude E, N,
        U rad; velocity E, N, U m/s) std per run, (N, 6). ``v0``: initial velocity (N, 3)."""
        if isinstance(std, np.ndarray) and std.ndim == 2:
            P = np.zeros((len(std), 6, 6))
            P[:, range(6), range(6)] = std ** 2
        else:
            lv, hd = std[0] * DEG, std[1] * DEG
            P = np.zeros((1, 6, 6))
            P[0, :3, :3] = np.diag([lv ** 2, lv ** 2, hd ** 2])
            P[0, 3:, 3:] = np.eye(3) * self.config.initial_velocity_std ** 2
        self.C = np.array(C0, dtype=float)
        self.v = np.zeros((self.n, 3)) if v0 is None else np.array(v0, dtype=float)
        self.P0 = P
        self.P = P                     # noise covariance, (1|N, 6, 6): what the gain uses
        self.S = np.zeros((1, 6, 6))   # sensitivity of the error to ENU biases [accel; gyro]
        self.R = R                     # measurement noise, (1|N, 3, 3)
        self.fine = fine
        self.v_sum = np.zeros((self.n, 3))
        self.t_acc = 0.0               # time since the last fine update
        self.t_int = 0.0               # integrated time since this pass started
        self.nis_mean = np.zeros(self.n)
        self.updates = 0
        self.last_reinflate = np.zeros(self.n)
        self.gate_start = np.full(self.n, np.nan)   # t_int of the first gated update in a row
        self._gated = None             # runs whose last update was gated (None: none)
        self._absorb = None            # runs whose last update absorbs a velocity error
        self._inflate = None           # runs to re-inflate after the last update (fine pass)
        self._z = None                 # innovation of the last update out of the gate
        self._node = None              # position in the gain-schedule cache (None: unknown)

    def total_covariance(self) -> np.ndarray:
        """Noise covariance plus the bias-induced part ``S Sigma_b S^T``, (1|N, 6, 6)."""
        return self._with_bias(self.P, self.S)

    def attitude_covariance(self, run: int = 0) -> np.ndarray:
        """The attitude block (3, 3) of :meth:`total_covariance` for one run, a new array
        (computed from the attitude rows only)."""
        P, S = self.P, self.S
        Sa = S[run if len(S) > 1 else 0, :3]
        return P[run if len(P) > 1 else 0, :3, :3] + np.dot(Sa * self._bias_var, Sa.T)

    def _with_bias(self, P, S):
        """P + S Sigma_b S^T (Sigma_b diagonal: the bias variances of the specs)."""
        return P + (S * self._bias_var) @ S.mT

    # ------------------------------------------------------------------ one sample
    def step(self, dt: float, w: np.ndarray, f: np.ndarray, gap: float = 0.0, dR=None,
             hole=(0.0, 0.0), bridge=None):
        """One accepted IMU sample for every run: w, f (N, 3); dt, gap shared (s).
        ``dR``: exp(w dt) (N, 3, 3), when the caller has it already. ``hole``: (attitude
        rad^2, velocity (m/s)^2) variance per axis of what the motion could have done in
        ``gap`` seconds of missing samples (added to the covariance, see :meth:`_advance`).
        ``bridge``: (rate, specific force) in body axes (3,) each that stand in for the gap's
        missing samples (the recent means; None: the state is held)."""
        if dR is None:
            dR = so3_exp(w * dt)
        if self._buf is not None and not self.backtracked:
            self._buf.append(dt, w, f, gap, hole, bridge)
            if gap > 0.0 and bridge is not None:
                self._B = self._B @ so3_exp(np.asarray(bridge[0], float) * gap)
            if self.n == 1:
                self._B = np.dot(self._B[0], dR.reshape(3, 3))[None]
            else:
                self._B = self._B @ dR
        self._advance(dt, w, f, gap, dR, hole, bridge)
        if self._backtrack_due(dt):
            self.backtrack()

    def _backtrack_due(self, dt: float) -> bool:
        return (self._buf is not None and not self.backtracked
                and reached(self.t_int, self.config.backtrack_time, dt))

    def run(self, dt, w: np.ndarray, f: np.ndarray):
        """Many samples through :meth:`step` one by one (the reference path).

        dt scalar or (T,), w and f (T, N, 3) (or (T, 3) when N = 1).
        """
        w = np.asarray(w, dtype=float).reshape(len(w), self.n, 3)
        f = np.asarray(f, dtype=float).reshape(len(f), self.n, 3)
        dts = np.broadcast_to(np.asarray(dt, dtype=float), (len(w),))
        for k in range(len(w)):
            self.step(float(dts[k]), w[k], f[k])

    def _earth_step(self, dt):
        key = ("E", dt)
        E = self._cache.get(key)
        if E is None:
            E = so3_exp(-self.w_ie * dt)
            if len(self._cache) < 256:
                self._cache[key] = E
        return E

    def _disc(self, F, dt):
        if F.ndim == 3:
            return discretize(F, self.Qc, dt)
        key = ("D", dt)
        hit = self._cache.get(key)
        if hit is None:
            hit = discretize(F, self.Qc, dt)
            if len(self._cache) < 256:
                self._cache[key] = hit
        return hit

    def _F(self, fn):
        model = self.config.model
        if model == "constant":
            return self._Fconst
        return system_matrix(model, self.w_ie, self.g_n, fn, self.v)

    def _propagate(self, F, dt):
        if F.ndim == 2:                     # shared F: the step's matrices cached with dt
            # (dropped with "D" when Qc changes: Backtrack)
            key = ("DT", dt)
            hit = self._cache.get(key)
            if hit is None:
                Phi, Qd = self._disc(F, dt)
                hit = (Phi, np.swapaxes(Phi, -1, -2), Qd, self.Gamma * dt)
                if len(self._cache) < 256:
                    self._cache[key] = hit
            Phi, PhiT, Qd, Gdt = hit
        else:
            Phi, Qd = self._disc(F, dt)
            PhiT, Gdt = np.swapaxes(Phi, -1, -2), self.Gamma * dt
        P, S = self.P, self.S
        if len(P) == len(S) == 1 and Phi.ndim == Qd.ndim == 2:
            self._propagate_one(Phi, PhiT, Qd, Gdt)
            return
        self.P = Phi @ P @ PhiT + Qd
        self.S = Phi @ S + Gdt
        self._node = None

    def _propagate_one(self, Phi, PhiT, Qd, Gdt) -> None:
        """:meth:`_propagate` of one covariance (one run, or a shared one) with 2-D
        matrices: 2-D products (numpy's stacked ones cost more for a single matrix)."""
        P = np.dot(np.dot(Phi, self.P[0]), PhiT)
        P += Qd
        S = np.dot(Phi, self.S[0])
        S += Gdt
        self.P, self.S = P[None], S[None]
        self._node = None

    def _advance(self, dt, w, f, gap, dR=None, hole=(0.0, 0.0), bridge=None):
        """Mechanization (paper eq. 1), covariance propagation, and an update when due.
        ``dR``: exp(w dt), when the caller has it already."""
        if self.fine and self.t_acc > 0.0 and (gap > 0.0 or hole[0] > 0.0 or hole[1] > 0.0):
            # samples missing: the interval so far is updated before the hole (see below)
            self._close_interval(self._F(-self.g_n + 0.0 * self.v),
                                 (self.fine_period / self.t_acc) ** 2)
        if gap > 0.0:
            # bridged as static: the errors grow over the gap, and when the recent mean rate
            # and specific force are given the state is mechanized with them over the gap as
            # one step (the velocity then carries the level error's signal C f + g as the
            # error model says; a velocity held still would contradict the model's coupling
            # of velocity and attitude errors and bias the heading)
            self._propagate(self._F(-self.g_n + 0.0 * self.v), gap)
            if bridge is not None:
                wb, fb = (np.asarray(b, float) for b in bridge)
                self.C = self._earth_step(gap) @ self.C @ so3_exp(wb * gap)
                self.v = self.v + ((self.C @ fb) + self.g_n) * gap
                self.t_int += gap
        va, vv = hole
        if va > 0.0 or vv > 0.0:
            # samples were missing: what the motion could have done meanwhile (Aligner)
            self.P = self.P + np.diag([va] * 3 + [vv] * 3)
            self._node = None
        R = so3_exp(w * dt) if dR is None else dR
        if self.n == 1:
            # one run (the node, replay): 2-D products (the stacked ones cost more), and the
            # velocity on floats: v + (C f + g) dt element by element, as numpy computes it
            C = np.dot(np.dot(self._earth_step(dt), self.C[0]), R.reshape(3, 3))
            F, vf = self._navigate_one(C, f.reshape(3), dt)
        else:
            self.C = self._earth_step(dt) @ self.C @ R
            fn = (self.C @ f[..., None])[..., 0]
            self.v = self.v + (fn + self.g_n) * dt
            self.t_int += dt
            F = self._F(fn)
            vf = None
        self._propagate(F, dt)
        self._measure(F, dt, vf)

    def _navigate_one(self, C, f, dt: float):
        """One run's attitude ``C`` (3, 3) after the sample taken, its velocity moved by the
        sample's specific force ``f`` (3,) on floats (v + (C f + g) dt element by element, as
        numpy computes it); returns (F, the velocity as three floats)."""
        fv = np.dot(C, f)
        self.C = C[None]
        f0, f1, f2 = fv.tolist()
        g0, g1, g2 = self._g_floats
        (v0, v1, v2), = self.v.tolist()
        v0 += (f0 + g0) * dt
        v1 += (f1 + g1) * dt
        v2 += (f2 + g2) * dt
        self.v = np.array([[v0, v1, v2]])
        self.t_int += dt
        return (self._Fconst if self.config.model == "constant" else self._F(fv[None]),
                (v0, v1, v2))

    def step_one(self, dt: float, w: np.ndarray, f: np.ndarray, dR=None) -> None:
        """:meth:`step` for one run (N = 1) and an ordinary sample (no gap, no hole): w, f
        (3,), ``dR`` exp(w dt) (3, 3) when the caller has it. The same operations on the same
        numbers as step, without its general branches and calls (the node's per-sample path;
        bit-identical, test_one_run_step.py)."""
        if dR is None:
            dR = so3_exp(w * dt)
        buffering = self._buf is not None and not self.backtracked
        if buffering:
            self._buf.append(dt, w, f, 0.0)
            self._B = np.dot(self._B[0], dR)[None]
        E = self._cache.get(("E", dt))
        if E is None:
            E = self._earth_step(dt)
        F, vf = self._navigate_one(np.dot(np.dot(E, self.C[0]), dR), f, dt)
        hit = self._cache.get(("DT", dt)) if F.ndim == 2 else None
        if hit is not None and len(self.P) == 1 and len(self.S) == 1:
            self._propagate_one(*hit)       # its matrices cached (Phi, Qd 2-D)
        else:
            self._propagate(F, dt)
        self._measure(F, dt, vf)
        if buffering and reached(self.t_int, self.config.backtrack_time, dt):
            self.backtrack()

    def _measure(self, F, dt: float, vf=None) -> None:
        """After a sample's mechanization and propagation: the coarse pass's update when
        due, or the fine pass's interval sum and its update when due (``vf``: the velocity
        as three floats, one run)."""
        if not self.fine:
            # coarse pass: the paper's instantaneous zero-velocity update, at every sample or
            # every coarse_update_period; R scaled so the noise density does not depend on it
            period = self.config.coarse_update_period
            self.t_acc += dt
            if reached(self.t_acc, period, dt):
                H = measurement_matrix(self.config.model, self.v)
                self._correct(self.v, H, scale=0.01 / self.t_acc)
                self.t_acc = 0.0
            return
        if vf is not None:
            v0, v1, v2 = vf
            (s0, s1, s2), = self.v_sum.tolist()
            s0 += v0 * dt
            s1 += v1 * dt
            s2 += v2 * dt
            self.v_sum = np.array([[s0, s1, s2]])
        else:
            self.v_sum += self.v * dt
        self.t_acc += dt
        if reached(self.t_acc, self.fine_period, dt):
            self._close_interval(F)

    def _close_interval(self, F, scale: float = 1.0):
        """Fine pass: the update with the mean velocity of the interval averaged so far
        (transition matrix ``F``; the noise times ``scale``), and a new interval.

        Samples missing close the interval early, before the hole. The mean velocity of an
        interval measures the attitude error through the averaged H
        (``averaged_measurement_matrix``), which holds for an error present over the whole
        interval. The error a hole adds (its variance, :meth:`_advance`) appears at the hole:
        a mean closing 5 ms after it hardly sees it, and an update there would take that for
        a small error and shrink the hole's level variance to almost nothing; the next one
        then hands the level error's velocity to the heading (on a navigation IMU with 0.01
        deg angular vibration, a hole every 20 s: the heading 2 deg off with a 0.9 deg std).
        So the interval closes at the hole and the next starts after it. Its noise is the
        full interval's times ``(period / T) ** 2``: the mean of a bounded sway over T errs
        as 1 / T (white noise as 1 / sqrt(T)), so a short piece weighs little either way."""
        H = measurement_matrix(self.config.model, self.v)
        Ha = averaged_measurement_matrix(H, F, self.t_acc)
        self._correct(self.v_sum / self.t_acc, Ha, scale=scale)
        self.v_sum = np.zeros((self.n, 3))
        self.t_acc = 0.0

    def _correct(self, z, H, scale: float = 1.0):
        prior = (self.P, self.S)
        K, Sinv = self._gain(H, scale)
        x = self._innovate(z.T, K, Sinv)
        self._settle(lambda: prior, H, scale, x)
        self.C, self.v = apply_correction(self.config.model, self.C, self.v, x.T,
                                          turn_velocity=self.fine)

    def _gain(self, H, scale: float):
        """Covariance part of an update: gain K and the inverse innovation covariance
        (with the bias part) for the NIS. Updates P and S."""
        R = self.R * scale
        HS = H @ self.S
        self.P, K, Sn = joseph_update(self.P, H, R)
        self._node = None
        self.S = self.S - K @ HS
        # innovation covariance with the bias part: H (P + S Sb S^T) H^T + R
        return K, inv3(Sn + (HS * self._bias_var) @ HS.mT)

    def _innovate(self, z, K, Sinv, out=None):
        """The correction ``x = K z`` of an update and its NIS bookkeeping, component-major:
        z (3, N), returns x (6, N) (in ``out`` if given).

        Coarse pass: runs whose running mean NIS exceeds ``reinflate_nis`` are re-inflated
        here. Fine pass: runs whose NIS exceeds ``gate_nis`` are gated (their x is zero and
        they are marked in ``_gated``: the caller's :meth:`_settle` gives them back their
        prior covariance); runs gated persistently are marked in ``_inflate``."""
        self.updates += 1
        a = 0.1 if self.updates > 10 else 1.0 / self.updates
        c = self.config
        self._gated = self._absorb = self._inflate = None
        if K.shape[0] == 1:                 # one gain for all runs: plain 2-D products
            x = np.matmul(K[0], z, out=out)
            if z.shape[1] == 1:             # one run (the node, replay): scalar arithmetic
                r = _nis_one(*z.ravel().tolist(), Sinv[0])
                if self._ordinary_one(r, a):
                    return x
                if self.fine:
                    r = np.array([r])
                else:
                    m = float(self.nis_mean[0])
                    self.nis_mean = np.array([m + a * (r - m)])
                    r = None                # already in the mean
            else:
                r = _THIRDS @ ((Sinv[0] @ z) * z)
        else:
            x = np.einsum("nij,jn->in", K, z, out=out)
            r = nis(z.T, Sinv) / 3.0
        if self.fine:
            self._gate(r, a, x, z)
            return x
        if r is not None:
            self.nis_mean = self.nis_mean + a * (r - self.nis_mean)
        if self.nis_mean.max() > c.reinflate_nis:
            bad = (self.nis_mean > c.reinflate_nis) & (
                self.t_int - self.last_reinflate >= c.reinflate_holdoff - 1e-6)
            if bad.any():
                self._reinflate(bad)
        return x

    def _ordinary_one(self, r: float, a: float) -> bool:
        """One run: an ordinary update (coarse pass: the running NIS mean stays within
        ``reinflate_nis``; fine pass: the NIS ``3 r`` within the gate) gets its running mean
        (weight ``a``) and True; any other gets False, nothing changed."""
        c = self.config
        m = float(self.nis_mean[0])
        if self.fine:
            if not 3.0 * r <= c.gate_nis:
                return False
            self.nis_mean = np.array([m + a * (r - m)])
            if self.gate_start[0] == self.gate_start[0]:      # not NaN
                self.gate_start = np.full(1, np.nan)
            return True
        m += a * (r - m)
        if not m <= c.reinflate_nis:
            return False
        self.nis_mean = np.array([m])
        return True

    def _innovate_one(self, z0: float, z1: float, z2: float, K, Sinv):
        """:meth:`_innovate` for one run and one gain, on floats (the fast path's single
        run): for an ordinary update (:meth:`_ordinary_one`), its bookkeeping done and the
        six floats of ``x = K z`` returned (nothing for :meth:`_settle` to do); None for any
        other, with nothing changed (the caller then takes :meth:`_innovate`)."""
        n = self.updates + 1
        if not self._ordinary_one(_nis_one(z0, z1, z2, Sinv[0]), 0.1 if n > 10 else 1.0 / n):
            return None
        self.updates = n
        self._gated = self._absorb = self._inflate = None
        return [k0 * z0 + k1 * z1 + k2 * z2 for k0, k1, k2 in K[0].tolist()]

    def _gate(self, r, a: float, x, z):
        """Fine-pass gating (chi-square on the NIS, robot_localization style).

        An update whose NIS ``3 r`` exceeds ``gate_nis`` is not applied: a shove or a door
        slam is not evidence about the attitude (and its velocity returns). Its NIS still
        enters the running mean (capped at 100 per dof, so one jolt does not read as
        'disturbed' for minutes). When the next update is out of the gate too, the
        velocity error is lasting (a lost velocity increment, a push that did not return):
        the update is applied with the velocity variance grown by the innovation
        (``_absorb``), so the velocity state takes it instead of the attitude. Updates out
        of the gate for ``reinflate_gated_time`` in a row mean the attitude really changed
        (re-levelled, moved): the run is marked for re-inflation (``_inflate``).
        """
        c = self.config
        self.nis_mean = self.nis_mean + a * (np.minimum(r, 100.0) - self.nis_mean)
        g = 3.0 * r > c.gate_nis
        if not g.any():
            self.gate_start = np.full(self.n, np.nan)
            return
        again = g & ~np.isnan(self.gate_start)
        self.gate_start = np.where(g, np.where(again, self.gate_start, self.t_int), np.nan)
        self.gated_updates += g
        self._z = z.copy()
        first = g & ~again
        if first.any():
            x[:, first] = 0.0
            self._gated = first
        if again.any():
            self._absorb = again
        persist = g & (self.t_int - self.gate_start >= c.reinflate_gated_time - 1e-6)
        if persist.any():
            self._inflate = persist

    def _settle(self, prior, H=None, scale: float = 1.0, x=None):
        """After an update (before its feedback): runs that were gated get back their prior
        covariance (``prior()`` returns it: P, S of the propagation alone); runs that absorb
        a lasting velocity error are updated again from that prior with the velocity
        variance grown by the innovation (``x`` rewritten); runs whose gating persisted are
        re-inflated (fine pass). Nothing to do (the usual case): returns at once."""
        g, ab = self._gated, self._absorb
        if g is not None or ab is not None:
            self._gated = self._absorb = None
            post = self.P, self.S
            Pp, Sp = prior()
            if ab is None and g.all():      # every run coasts: the prior, still shared (the
                self.P, self.S = Pp, Sp     # fast path's prior() set the cache node to it)
            else:
                shape = (self.n, 6, 6)
                P, S = (np.broadcast_to(q, shape) for q in post)
                if g is not None:
                    P, S = _where_runs(g, Pp, P), _where_runs(g, Sp, S)
                if ab is not None:
                    self.P = _grow_velocity(np.broadcast_to(Pp, shape), ab, self._z)
                    self.S = np.broadcast_to(Sp, shape).copy()
                    K, _ = self._gain(H, scale)
                    x[:, ab] = np.einsum("nij,jn->in", K, self._z)[:, ab]
                    P, S = _where_runs(ab, self.P, P), _where_runs(ab, self.S, S)
                self.P, self.S, self._node = P, S, None
        if self._inflate is not None:
            mask, self._inflate = self._inflate, None
            self._reinflate(mask, self._z)

    def _reinflate(self, mask: np.ndarray, z=None):
        """Reset the covariance of the runs in ``mask`` to the pass's initial value.

        Coarse pass: the innovations say the error is far larger than the covariance claims
        (a large-angle transient stuck near a 180 deg flip): restarting the gain schedule
        lets the filter move again instead of crawling with a collapsed covariance. Fine
        pass (``z``, the last innovation, given): the attitude really changed; the velocity
        variance also covers the velocity error accumulated while updates were gated.
        """
        P = np.broadcast_to(self.P, (self.n, 6, 6)).copy()
        S = np.broadcast_to(self.S, (self.n, 6, 6)).copy()
        P[mask] = np.broadcast_to(self.P0, P.shape)[mask]
        if z is not None:
            P = _grow_velocity(P, mask, z)
        S[mask] = 0.0
        self.P, self.S = P, S
        self._node = None
        self.nis_mean = np.where(mask, 0.0, self.nis_mean)
        self.gate_start = np.where(mask, np.nan, self.gate_start)
        self.last_reinflate = np.where(mask, self.t_int, self.last_reinflate)
        self.reinflations += mask


def _nis_one(z0: float, z1: float, z2: float, Sinv: np.ndarray) -> float:
    """NIS per degree of freedom ``z^T Sinv z / 3`` of one innovation (floats; Sinv (3, 3))."""
    (s00, s01, s02), (s10, s11, s12), (s20, s21, s22) = Sinv.tolist()
    return (z0 * (s00 * z0 + s01 * z1 + s02 * z2)
            + z1 * (s10 * z0 + s11 * z1 + s12 * z2)
            + z2 * (s20 * z0 + s21 * z1 + s22 * z2)) / 3.0


def _where_runs(mask: np.ndarray, a, b) -> np.ndarray:
    """(N, 6, 6): ``a`` for the runs in ``mask``, ``b`` for the others (either (1|N, 6, 6))."""
    return np.where(mask[:, None, None], a, b)


def _grow_velocity(P: np.ndarray, mask: np.ndarray, z: np.ndarray) -> np.ndarray:
    """P (N, 6, 6) with the velocity variances of the runs in ``mask`` grown by z^2 (z (3, N),
    an innovation the model could not explain): a new array."""
    P = P.copy()
    i = np.arange(3, 6)
    P[:, i, i] += np.where(mask[:, None], (z * z).T, 0.0)
    return P
