"""The fast path of :class:`~sins_align.estimators.quasi_static.filter.AlignmentFilter`.

Between two Kalman updates the damped mechanization has no feedback, so a whole interval is
integrated in closed form from vectorised sums (:mod:`sins_align.core.preint`), and the
covariance jumps over it with cached m-step matrices; the constant model's gain schedule
does not depend on the data and comes from a shared cache
(:mod:`~sins_align.estimators.quasi_static.schedule`). Same results as the per-sample
recursion (test_fast_path). :class:`FastPath` is one of the parts AlignmentFilter is made
of: its methods work on the filter's state (C, v, P, S, the pass) and call its update
(``_innovate``, ``_settle``, ``_gain``).
"""
from __future__ import annotations

import math

import numpy as np

from sins_align.core.kalman import affine_scan, discretize, inv3, riccati_steps
from sins_align.core.models import (averaged_measurement_matrix,
                                    measurement_matrix)
from sins_align.core.preint import prefix_rotations, preintegrate, scratch_array
from sins_align.core.rotation import dcm_entries_from_quat, so3_exp, so3_exp_entries

#: runs of at least this many regular samples take the fast path (Aligner.update, backtrack)
FAST_MIN_BLOCK = 64
#: samples x runs pre-integrated at once by the fast path (bounds its temporaries)
PIECE_SAMPLE_RUNS = 1 << 18
#: fraction of a sample interval by which a clock may fall short of a threshold and still
#: reach it (:func:`reached`). The clocks (time into an update interval, time since the
#: first sample) are sums of intervals: the per-sample path adds stamp differences, the fast
#: path multiples of the block's rounded uniform interval, so they differ by rounding
#: (1e-12 s). A clock that lands exactly on a threshold (the double interval after a
#: rejected or missing sample) must fall the same way in both.
DUE_TOL = 1e-6


#: most multiply-adds of one matrix product in :func:`_small_products`: OpenBLAS runs a
#: product above 262,144 of them on several threads, whose start costs milliseconds while
#: other processes hold the cores (a 909 x 36 by 36 x 25 product took 1.5-8 ms instead of
#: 20 us on the 2 cores shared with two other jobs)
SMALL_PRODUCT = 200_000


def _small_products(Y, K):
    """``Y @ K.T`` (Y (G, k), K (a, k)) as products of row blocks of K small enough for one
    thread (:data:`SMALL_PRODUCT`)."""
    G, k = Y.shape
    rows = max(1, SMALL_PRODUCT // max(1, G * k))
    if len(K) <= rows:
        return Y @ K.T
    return np.concatenate([Y @ K[i:i + rows].T for i in range(0, len(K), rows)], axis=1)


class FastPath:
    """Closed-form integration between updates and the cached gain schedule (a part of
    AlignmentFilter; see the module docstring)."""

    def coast_states(self, model, dts: np.ndarray, w: np.ndarray, starts, C0, P0, S0,
                     at: np.ndarray | None = None):
        """The state after every sample of a stretch with no update and no change of the
        model (one run, constant model, uniform intervals): what the per-sample recursion
        gives, in closed form and vectorised over the samples.

        Parameters
        ----------
        model : :meth:`coast_model` of the stretch (taken while the model held: the
            backtrack changes the process noise).
        dts, w : ndarray (L,), (L, 3) — the samples' intervals (s) and rates (rad/s).
        starts : sequence of G increasing ints in [-1, L) — state g is the state after sample
            ``starts[g]`` (-1: before the first); it holds (``m`` = 0) at that sample and is
            coasted over the samples after it until the next start. ``starts[0]`` must be
            -1 or 0.
        C0 : (G, 3, 3) attitudes; P0, S0 : (G, 6, 6) covariance and bias sensitivity.

        at : indices of the samples wanted (default: all L).

        Returns
        -------
        C : (L, 3, 3) (or one per index of ``at``) ``E(T) C0 Q``: Earth rotation over the T s
            since the start times the
            gyro's prefix rotation ``Q`` since it (:func:`sins_align.core.preint.prefix_rotations`).
        Pa : (L, 3, 3) the attitude block of ``P + S Sigma_b S^T`` with ``P = Phi_m P0 Phi_m^T +
            Qd_m`` and ``S = Phi_m S0 + G_m`` (m steps of the constant model).
        """
        L = len(dts)
        starts = np.asarray(starts, dtype=np.int64)
        idx = np.arange(L) if at is None else np.asarray(at, dtype=np.int64)
        g = np.searchsorted(starts, idx, side="right") - 1          # the state each takes
        s = starts[g]
        m = idx - s                                                  # steps since it
        q = prefix_rotations(dts[None, :], np.asarray(w, dtype=float)[None])
        Qg = np.stack(dcm_entries_from_quat(*(c[0] for c in q)), -1).reshape(L, 3, 3)
        cum = np.cumsum(dts)
        # the rotation and the time since each start: Q_s^T Q_j, cum_j - cum_s
        Qs = np.concatenate([np.eye(3)[None], Qg])[starts + 1]         # (G, 3, 3)
        Ts = np.concatenate([[0.0], cum])[starts + 1]
        M = np.asarray(C0) @ Qs.transpose(0, 2, 1)                   # C0 Q_s^T
        Qg, T = Qg[idx], cum[idx] - Ts[g]
        W, K = self._W, self._Ue
        E = (np.eye(3) + np.sin(W * T)[:, None, None] * K
             + (1.0 - np.cos(W * T))[:, None, None] * (K @ K))
        C = E @ M[g] @ Qg
        at = np.flatnonzero(m == 0)                                  # the states themselves
        C[at] = np.asarray(C0)[g[at]]
        PhiA, QdA, GmA = model
        top = int(m.max()) + 1 if len(m) else 1
        if top > len(PhiA):
            raise ValueError(f"coast_states: {top - 1} steps, the model has {len(PhiA) - 1}")
        # Pa = Phi (P + S B S^T) Phi^T + Phi S B Gm^T + (its transpose) + Qd + Gm B Gm^T
        # (B: the bias variances), linear in the state's P + S B S^T and S B: computed once
        # for every (steps, state) pair by two matrix products over the stacked
        # vec(Phi X Psi^T) = (Phi kron Psi) vec(X), then gathered (a few thousand samples
        # share some 25 states and 100 step counts)
        Phi, Gm = PhiA[:top], GmA[:top]
        G = len(starts)
        S0 = np.asarray(S0, dtype=float)
        V = S0 * self._bias_var                                      # S B
        Y = (np.asarray(P0, dtype=float) + V @ S0.transpose(0, 2, 1)).reshape(G, 36)
        KP = np.einsum("mik,mjl->mijkl", Phi, Phi).reshape(9 * top, 36)
        KG = np.einsum("mik,mjl->mijkl", Phi, Gm)
        KG = (KG + KG.transpose(0, 2, 1, 3, 4)).reshape(9 * top, 36)
        c = QdA[:top] + (Gm * self._bias_var) @ Gm.transpose(0, 2, 1)
        grid = _small_products(Y, KP) + _small_products(V.reshape(G, 36), KG)
        grid = grid.reshape(G, top, 9) + c.reshape(top, 9)
        Pa = grid[g, m].reshape(-1, 3, 3)
        return C, Pa

    def coast_model(self, dt: float, most: int):
        """For :meth:`coast_states`, with the current process noise: the attitude rows of
        the m-step transition and bias input and the attitude block
        of the m-step process noise, m = 0..most, stacked (m = 0: I, 0, 0)."""
        key = ("Dm", dt, "stacks")
        st = self._cache.get(key)
        if st is None or len(st[0]) <= most:
            steps = [self._disc_m(k, dt) for k in range(1, most + 1)]
            eye = np.eye(6)[:3]
            st = self._cache[key] = (
                np.array([eye] + [p[:3] for p, _, _ in steps]),
                np.array([np.zeros((3, 3))] + [q[:3, :3] for _, q, _ in steps]),
                np.array([np.zeros((3, 6))] + [gm[:3] for _, _, gm in steps]))
        return st

    def run_fast(self, dt, w: np.ndarray, f: np.ndarray):
        """Many samples: same result as :meth:`run`, much faster.

        ``dt`` is one interval for all samples, or one per sample (T,) for jittered stamps
        (each within 40 % of their mean). Between updates the mechanization is integrated in
        closed form from vectorised sums (:mod:`sins_align.core.preint`) and the covariance jumps
        over the whole interval, so the Python work is per update, not per sample. The
        update schedule, the backtrack and every update are those of :meth:`run`; the
        results agree to rounding (test_fast_path). Models other than 'constant' (whose F
        depends on the state at every sample) go through :meth:`run`.
        """
        w = np.asarray(w, dtype=float).reshape(len(w), self.n, 3)
        f = np.asarray(f, dtype=float).reshape(len(f), self.n, 3)
        dts = np.broadcast_to(np.asarray(dt, dtype=float), (len(w),))
        if self.config.model != "constant" or len(w) == 0:
            self.run(dts, w, f)
            return
        mean = float(dts.mean())
        uni = uniform_interval(dts)
        if uni is not None:
            dts = uni
        elif not np.all(np.abs(dts - mean) <= 0.4 * mean):
            raise ValueError("run_fast: sample intervals vary by more than 40 %")
        self.fast = True
        k, T = 0, len(w)
        while k < T:
            end = T
            if self._buf is not None and not self.backtracked:
                end = k + self._samples_until(self.config.backtrack_time - self.t_int,
                                              part(dts, k, T))
                self._buf.extend(part(dts, k, end), w[k:end], f[k:end])
            self._advance_block(part(dts, k, end), w[k:end], f[k:end],
                                track_B=not self.backtracked and self._buf is not None,
                                offset=k)
            k = end
            if self._backtrack_due(last_interval(dts, end)):
                self.backtrack()
                if self.on_update is not None:
                    self.on_update(end - 1)

    @staticmethod
    def _samples_until(left: float, dts) -> int:
        """How many samples until an accumulated time reaches ``left`` (the per-sample
        rule, :func:`reached`: t + dt_j >= left - dt_j / 2), at least 1, at most all of
        them."""
        if np.ndim(dts) == 0:
            return max(1, int(math.ceil(left / dts - 0.5 - DUE_TOL)))
        key = np.cumsum(dts) + (0.5 + DUE_TOL) * dts    # increasing: intervals within 40 %
        return min(len(dts), int(np.searchsorted(key, left)) + 1)

    def _period(self) -> float:
        return self.fine_period if self.fine else self.config.coarse_update_period

    def _advance_block(self, dt, w, f, track_B: bool = False, offset: int | None = None):
        """Samples through the mechanization and the updates they contain.

        ``dt``: one interval (float) or one per sample (T,).
        """
        period = self._period()
        T = len(w)
        left = period - self.t_acc
        if np.ndim(dt) == 0:                # uniform: every interval after the first is alike
            m0 = min(T, self._samples_until(left, dt))
            mp = self._samples_until(period, dt)
            full, rest = divmod(T - m0, mp)
            lengths = [m0] + [mp] * full + ([rest] if rest else [])
        else:
            lengths, k = [], 0
            while k < T:
                m = min(T - k, self._samples_until(left, part(dt, k, T)))
                lengths.append(m)
                k += m
                left = period
        # pieces of about PIECE_SAMPLE_RUNS sample-runs keep the pre-integrated sums small
        per = max(1, PIECE_SAMPLE_RUNS // self.n)
        starts = np.concatenate([[0], np.cumsum(lengths)])
        a = 0
        while a < len(lengths):
            b = int(np.searchsorted(starts, starts[a] + per, side="right")) - 1
            b = min(len(lengths), max(b, a + 1))
            i0, i1 = int(starts[a]), int(starts[b])
            self._advance_segments(part(dt, i0, i1), w[i0:i1], f[i0:i1],
                                   np.array(lengths[a:b]), track_B,
                                   None if offset is None else offset + i0)
            a = b

    def _advance_segments(self, dt, w, f, lengths, track_B: bool, offset: int | None):
        """Samples cut into update intervals (``lengths``): pre-integration of all of them,
        then the intervals one by one (mechanization in closed form, update when due).

        A single run (the Aligner) takes :meth:`_one_run_intervals`, on floats. For N runs the
        state in the loop is component-major, the attitude transposed:
        ``Ct[k, i, n] = C[i, k, n]`` and ``v[:, n]`` for run n, so that each product of
        per-run 3x3 matrices is one einsum over contiguous rows of the N runs, and each
        product with a matrix shared by all runs is one GEMM. Every array of N runs is
        written into a reused scratch array (no page faults per update).
        """
        period = self._period()
        uniform = np.ndim(dt) == 0
        sc = self._scratch
        B, segT, sdt = preintegrate(dt, w, f, lengths, self._W, self.fine, sc)
        if uniform:
            self._prefetch_schedule(lengths, dt)
        if self.n == 1:
            self._one_run_intervals(dt, B[..., 0], segT, sdt, lengths, track_B, offset)
            return
        # P = C0 B[i] row by row: P[k] = C0 times column k of B[i] (Qm, then A0 Aa Ab, then
        # V0 Va Vb); the velocity increment sum_k M_k C0 A_k is G @ P[3:6] as (9, N) rows
        G = self._Gv
        H = measurement_matrix("constant")
        ends = np.cumsum(lengths).tolist()
        n = self.n
        P = scratch_array(sc, "P", (B.shape[2], 3, n))
        Ct, X = (scratch_array(sc, name, (3, 3, n)) for name in ("C", "X"))
        v, vs, inc = (scratch_array(sc, name, (3, n)) for name in ("v", "v_sum", "inc"))
        x = scratch_array(sc, "x", (6, n))
        Ct[...] = self.C.transpose(2, 1, 0)
        v[...] = self.v.T
        vs[...] = self.v_sum.T
        if track_B:
            Bt, BX = (scratch_array(sc, name, (3, 3, n)) for name in ("Bt", "BX"))
            Bt[...] = self._B.transpose(2, 1, 0)
        P_Qm, P_A = P[:3], P[3:6].reshape(9, n)
        P_V = P[6:9].reshape(9, n) if self.fine else None
        earth = {}                                   # uniform: E and g T of each length m
        for i, m in enumerate(lengths.tolist()):
            if uniform:
                Ti, dti = m * dt, dt
                E, gT = earth.get(m) or earth.setdefault(
                    m, (self._earth_rot(m, dt), self._g_col * Ti))
            else:
                Ti, dti = float(segT[i]), float(dt[ends[i] - 1])
                E, gT = so3_exp(-self.w_ie * Ti), self._g_col * Ti
            rows_times(Ct, B[i], P)
            np.matmul(E, P_Qm, out=X)                        # (E C0 Qm)^T
            if track_B:
                rows_times(Bt, B[i, :, :3], BX)
                Bt, BX = BX, Bt
            if self.fine:
                vs += v * Ti
                vs += np.matmul(G, P_V, out=inc)
                vs += self._g_col * (dt * dt * m * (m + 1) / 2.0 if uniform else float(sdt[i]))
            v += np.matmul(G, P_A, out=inc)
            v += gT
            Hu, scale, jumps = self._interval_end(Ti, m, dt, uniform, part, ends[i], period,
                                                  dti, H)
            if Hu is None:                          # partial interval: no update yet
                Ct, X = X, Ct
                continue
            before = self.P, self.S, self._node
            Kg, Sinv = self._cov_block(m, dt, Hu, scale, jumps)
            if self.fine:
                self._innovate(vs / self.t_acc, Kg, Sinv, out=x)
                vs[...] = 0.0
            else:
                self._innovate(v, Kg, Sinv, out=x)
            self._settle(lambda: self._coast(before, m, dt, jumps), Hu, scale, x)
            # feedback (models.apply_correction, constant model): C <- exp(phi x) C, v -= dv
            R = np.stack(so3_exp_entries(x[0], x[1], x[2]), out=scratch_array(sc, "R", (9, n)))
            times_rows(R.reshape(3, 3, n), X, Ct)
            if self.fine:                       # the velocity turns with the attitude
                v[...] = np.einsum("ijn,jn->in", R.reshape(3, 3, n), v)
            v -= x[3:]
            self.t_acc = 0.0
            if self.on_update is not None and offset is not None:
                self.C, self.v = Ct.transpose(2, 1, 0).copy(), v.T.copy()   # the state now
                self.on_update(offset + ends[i] - 1)
        self.C = np.ascontiguousarray(Ct.transpose(2, 1, 0))
        self.v = v.T.copy()              # copies: v and vs are scratch, reused next call
        self.v_sum = vs.T.copy()
        if track_B:
            self._B = np.ascontiguousarray(Bt.transpose(2, 1, 0))

    def _one_run_intervals(self, dt, B, segT, sdt, lengths, track_B: bool, offset):
        """The interval loop of :meth:`_advance_segments` for a single run (the Aligner's
        case) on Python floats: the attitude is nine numbers, the velocity and its sum three
        each, and every interval's sums come from lists made in one go. The same steps as
        the loop over N runs (C <- R E C Q, v += sum_k M_k C A_k + g T, the update, the
        feedback), but a 3x3 product in floats costs half of one numpy call and nothing is
        allocated. ``B``: (S, 3, K), the sums of :func:`preintegrate` of the one run."""
        period = self._period()
        uniform = np.ndim(dt) == 0
        fine = self.fine
        H = measurement_matrix("constant")
        ends = np.cumsum(lengths).tolist()
        S = len(lengths)
        Qs = B[:, :, :3].reshape(S, 9).tolist()         # body rotation over the interval
        As = B[:, :, 3:6].reshape(S, 9).tolist()        # columns A0, Aa, Ab (m/s)
        Vs = B[:, :, 6:9].reshape(S, 9).tolist() if fine else None   # V0, Va, Vb (m)
        U, U2 = self._Ue.ravel().tolist(), self._Ue2.ravel().tolist()
        C = self.C[0].ravel().tolist()
        v0, v1, v2 = self.v[0].tolist()
        s0, s1, s2 = self.v_sum[0].tolist()
        g0, g1, g2 = self.g_n.tolist()
        Bt = self._B[0].ravel().tolist() if track_B else None
        z, x = np.empty((3, 1)), np.empty((6, 1))
        earth = {}                                   # uniform: E of each length m
        for i, m in enumerate(lengths.tolist()):
            if uniform:
                Ti, dti = m * dt, dt
                E = earth.get(m) or earth.setdefault(m, self._earth_rot(m, dt).ravel().tolist())
                cg = dt * dt * m * (m + 1) / 2.0
            else:
                Ti, dti = float(segT[i]), float(dt[ends[i] - 1])
                E = so3_exp(-self.w_ie * Ti).ravel().tolist()
                cg = float(sdt[i])
            if track_B:
                Bt = _mm3(Bt, Qs[i])
            if fine:
                a0, a1, a2 = _increment(_mm3(C, Vs[i]), U, U2)
                s0, s1, s2 = s0 + v0 * Ti, s1 + v1 * Ti, s2 + v2 * Ti
                s0, s1, s2 = s0 + a0 + g0 * cg, s1 + a1 + g1 * cg, s2 + a2 + g2 * cg
            a0, a1, a2 = _increment(_mm3(C, As[i]), U, U2)
            v0, v1, v2 = v0 + a0 + g0 * Ti, v1 + a1 + g1 * Ti, v2 + a2 + g2 * Ti
            X = _mm3(E, _mm3(C, Qs[i]))
            Hu, scale, jumps = self._interval_end(Ti, m, dt, uniform, part, ends[i], period,
                                                  dti, H)
            if Hu is None:                          # partial interval: no update yet
                C = X
                continue
            before = self.P, self.S, self._node
            Kg, Sinv = self._cov_block(m, dt, Hu, scale, jumps)
            if fine:
                t = self.t_acc
                z0, z1, z2 = s0 / t, s1 / t, s2 / t
                s0 = s1 = s2 = 0.0
            else:
                z0, z1, z2 = v0, v1, v2
            xs = self._innovate_one(z0, z1, z2, Kg, Sinv)
            if xs is None:                  # gated, absorbed or re-inflated: the array path
                z[0, 0], z[1, 0], z[2, 0] = z0, z1, z2
                self._innovate(z, Kg, Sinv, out=x)
                self._settle(lambda: self._coast(before, m, dt, jumps), Hu, scale, x)
                xs = x[:, 0].tolist()
            x0, x1, x2, x3, x4, x5 = xs
            # feedback (models.apply_correction, constant model): C <- exp(phi x) C, v -= dv
            R = so3_exp_entries(x0, x1, x2)
            C = _mm3(R, X)
            if fine:                       # the velocity turns with the attitude
                v0, v1, v2 = (R[0] * v0 + R[1] * v1 + R[2] * v2,
                              R[3] * v0 + R[4] * v1 + R[5] * v2,
                              R[6] * v0 + R[7] * v1 + R[8] * v2)
            v0, v1, v2 = v0 - x3, v1 - x4, v2 - x5
            self.t_acc = 0.0
            if self.on_update is not None and offset is not None:
                self.C, self.v = np.array(C).reshape(1, 3, 3), np.array([[v0, v1, v2]])
                self.on_update(offset + ends[i] - 1)
        self.C = np.array(C).reshape(1, 3, 3)
        self.v = np.array([[v0, v1, v2]])
        self.v_sum = np.array([[s0, s1, s2]])
        if track_B:
            self._B = np.array(Bt).reshape(1, 3, 3)

    def _coast(self, before, m: int, dt, jumps):
        """P and S propagated over the interval from ``before`` (P, S, cache node) with no
        update: what a gated update leaves (fast path)."""
        self.P, self.S, self._node = before
        self._cov_block(m, dt, None, 0.0, jumps)
        return self.P, self.S

    def _interval_end(self, Ti, m, dt, uniform, part, end, period, dti, H):
        """The end of an interval of m samples (the last at index ``end``) of Ti s: the
        clocks advance; returns (H of the update due, its noise scale, the interval's
        covariance jumps), H None for a partial interval, whose covariance jump is then
        applied here."""
        self.t_int += Ti
        self.t_acc += Ti
        jumps = (lambda: self._disc_m(m, dt)) if uniform else (
            lambda: self._disc_var(part(dt, end - m, end)))
        Hu, scale = self._update_due(self.t_acc, period, dti, H, uniform)
        if Hu is None:
            self._cov_block(m, dt, None, 0.0, jumps)
        return Hu, scale, jumps

    def _update_due(self, t_acc: float, period: float, dt: float, H, cache: bool = True):
        """(H, R scale) of the fast path's update after ``t_acc`` s of the current interval
        (last sample interval ``dt``), or (None, 0.0) when none is due yet: the coarse
        pass's instantaneous velocity (``H``, R scaled to the interval), the fine pass's
        mean velocity over it."""
        if not reached(t_acc, period, dt):
            return None, 0.0
        if self.fine:
            return self._averaged_H(t_acc, cache), 1.0
        return H, 0.01 / t_acc

    def _averaged_H(self, period: float, cache: bool):
        """H of the fine pass's mean-velocity measurement over ``period`` s (constant model)."""
        Ha = self._cache.get(("Ha", period))
        if Ha is None:
            Ha = averaged_measurement_matrix(measurement_matrix("constant"), self._Fconst, period)
            if cache:
                self._cache[("Ha", period)] = Ha
        return Ha

    def _prefetch_schedule(self, lengths: np.ndarray, dt: float, most: int = 4096):
        """Put the gain schedule of the coming intervals (uniform ``dt``) into the cache.

        :meth:`_advance_segments` then finds every step there, as in a warm run. The steps
        already cached are walked over; from the first missing one, each run of identical
        steps (same length, H and R) is computed at once: the covariance and gain by
        :func:`kalman.riccati_steps`, the bias sensitivity S by :func:`kalman.affine_scan`,
        the NIS covariance batched. This replaces about 30 us of Python and numpy calls per
        step; the values agree with the step-by-step recursion to about 1e-9 (relative to
        sqrt(P_ii P_jj), see riccati_steps; the attitude to about 1e-12 rad). At most
        ``most`` steps a call: the loop computes any others step by step, as before.
        """
        node = self._node if self._node is not None else self._schedule_root()
        if node is None:
            return
        if self.schedules.make_room(min(len(lengths), most)):
            # cleared before the walk, and a root the loop will find
            node = self._node if self._node is not None else self._schedule_root()
        period, t_acc = self._period(), self.t_acc
        H0 = measurement_matrix("constant")
        plan = []
        for m in lengths.tolist()[:most]:
            t_acc += m * dt
            plan.append((m, *self._update_due(t_acc, period, dt, H0)))
            if plan[-1][1] is not None:
                t_acc = 0.0
        keys = [(m, dt, sc, self._h_bytes(H)) for m, H, sc in plan]
        P, S, i = self.P[0], self.S[0], 0
        while i < len(keys):                        # the part of the chain already built
            hit = node.get(keys[i])
            if hit is None:
                break
            P, S, node = hit[0][0], hit[1][0], hit[4]
            i += 1
        while i < len(keys):
            j = i + 1
            while j < len(keys) and keys[j] == keys[i]:
                j += 1
            m, H, scale = plan[i]
            Phi, Qd, Gm = self._disc_m(m, dt)
            if H is None:
                steps = []
                for _ in range(j - i):
                    P, S = Phi @ P @ Phi.T + Qd, Phi @ S + Gm
                    steps.append((P[None], S[None], None, None))
            else:
                Ps, Ks, Sn = riccati_steps(P, Phi, Qd, H, self.R[0] * scale, j - i)
                IKH = np.eye(6) - Ks @ H
                Ss = affine_scan(IKH @ Phi, IKH @ Gm, S)
                HS = H @ (Phi @ np.concatenate([S[None], Ss[:-1]]) + Gm)  # H S before update
                Ns = inv3(Sn + (HS * self._bias_var) @ HS.mT)
                P, S = Ps[-1], Ss[-1]
                # entries of shape (1, ...): iterating over (n, 1, ...) arrays gives them
                steps = zip(Ps[:, None], Ss[:, None], Ks[:, None], Ns[:, None])
            for key, step in zip(keys[i:j], steps):
                nxt = {}
                node[key] = (*step, nxt)
                node = nxt
            self.schedules.added(j - i)
            i = j

    def _disc_var(self, dts: np.ndarray):
        """Transition, process noise and bias input over samples of varying interval: what
        the per-sample recursion composes to (Phi and Qd exactly, the bias input as its
        Riemann sum, both to fourth order in F)."""
        T = float(dts.sum())
        Phi, Qd = discretize(self._Fconst, self.Qc, T)
        r = T - np.cumsum(dts)                      # time left after each sample
        F, G = self._Fconst, self.Gamma
        FG = F @ G
        F2G = F @ FG
        Gm = G * T + FG * float(r @ dts) + F2G * float((r * r) @ dts / 2.0) \
            + F @ F2G * float((r ** 3) @ dts / 6.0)
        return Phi, Qd, Gm

    def _cov_block(self, m: int, dt, H, scale: float, jumps=None):
        """Propagate P and S over m samples and, unless H is None, do the covariance part
        of an update (returns its gain and inverse innovation covariance).

        With one covariance shared by all runs (the constant model: it does not depend on
        the data) the result only depends on the covariance at the start of the pass and
        on the steps since, so the schedule is kept as a chain in the bounded shared
        cache (:attr:`schedules`, :mod:`~sins_align.estimators.quasi_static.schedule`): a
        second run of the same configuration (the next bag, the next Monte Carlo batch)
        reuses the whole gain schedule, and a step costs one dictionary look-up.
        """
        node = None
        if not isinstance(dt, np.ndarray):           # uniform intervals: cacheable
            node = self._node if self._node is not None else self._schedule_root()
        self._node = None                            # P and S are about to move on
        if node is not None:
            key = (m, dt, scale, self._h_bytes(H))
            hit = node.get(key)
            if hit is not None:
                self.P, self.S, K, Sinv, self._node = hit
                return K, Sinv
        Phi, Qd, Gm = jumps() if jumps is not None else self._disc_m(m, dt)
        self.P = Phi @ self.P @ Phi.T + Qd
        self.S = Phi @ self.S + Gm
        K = Sinv = None
        if H is not None:
            K, Sinv = self._gain(H, scale)
        if node is not None:
            self.schedules.added(1)
            self.schedules.make_room(0)
            self._node = {}
            node[key] = (self.P, self.S, K, Sinv, self._node)
        return K, Sinv

    def _h_bytes(self, H):
        """H's bytes (the schedule keys' part for the measurement; None for none), kept by
        the array's identity: the loop asks for the same few matrices at every update. The
        memo holds the arrays themselves (so no identity is reused) and at most 64 of them."""
        if H is None:
            return None
        hit = self._h_memo.get(id(H))
        if hit is None:
            if len(self._h_memo) >= 64:
                self._h_memo.clear()
            hit = self._h_memo[id(H)] = (H, H.tobytes())
        return hit[1]

    def _schedule_root(self):
        """The cache chain of the current pass (None when the covariance is per run)."""
        if self.P.shape[0] != 1 or self.S.shape[0] != 1 or self.R.shape[0] != 1:
            return None
        key = (self._cfg_key, self.P.tobytes(), self.S.tobytes(), self.R.tobytes())
        return self.schedules.root(key)

    def _earth_rot(self, m: int, dt: float):
        key = ("Em", m, dt)
        E = self._cache.get(key)
        if E is None:
            E = self._cache[key] = so3_exp(-self.w_ie * (m * dt))
        return E

    def _disc_m(self, m: int, dt: float):
        """m-step transition, process noise and bias input of the constant model."""
        steps = self._cache.setdefault(("Dm", dt), [])    # steps[k-1]: the k-step triple
        if len(steps) < m:
            Phi1, Qd1 = self._disc(self._Fconst, dt)
            G1 = self.Gamma * dt
            Phi, Qd, Gm = steps[-1] if steps else (np.eye(6), np.zeros((6, 6)), np.zeros((6, 6)))
            while len(steps) < m:
                Phi, Qd, Gm = Phi1 @ Phi, Phi1 @ Qd @ Phi1.T + Qd1, Phi1 @ Gm + G1
                steps.append((Phi, Qd, Gm))
        return steps[m - 1]


def rows_times(Ct, M, out):
    """``out[k, i, n] = sum_j Ct[j, i, n] M[j, k, n]``: C M for each run n, component-major
    with C transposed (``Ct[j, i, n] = C[i, j, n]``), so out is (C M) transposed. One einsum
    over the runs (a single run takes :meth:`FastPath._one_run_intervals` instead)."""
    np.einsum("jin,jkn->kin", Ct, M, out=out)


def times_rows(R, Xt, out):
    """``out[k, r, n] = sum_j R[r, j, n] Xt[k, j, n]``: R X for each run n, with X and the
    result transposed as in :func:`rows_times`."""
    np.einsum("rjn,kjn->krn", R, Xt, out=out)


def _mm3(a, b) -> list:
    """The product of two 3x3 matrices given as nine floats row by row (lists or tuples)."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    return [a0 * b0 + a1 * b3 + a2 * b6, a0 * b1 + a1 * b4 + a2 * b7, a0 * b2 + a1 * b5 + a2 * b8,
            a3 * b0 + a4 * b3 + a5 * b6, a3 * b1 + a4 * b4 + a5 * b7, a3 * b2 + a4 * b5 + a5 * b8,
            a6 * b0 + a7 * b3 + a8 * b6, a6 * b1 + a7 * b4 + a8 * b7, a6 * b2 + a7 * b5 + a8 * b8]


def _increment(CA, U, U2) -> tuple:
    """``sum_k M_k y_k`` with M = I, U, U2 and y_k column k of CA (nine floats row by row;
    U, U2 the same): the velocity (sum) increment of an interval, C times the sums A_k
    (or V_k) turned by the Earth-rate polynomial (:func:`sins_align.core.preint.earth_poly`)."""
    c0, c1, c2, c3, c4, c5, c6, c7, c8 = CA
    u0, u1, u2, u3, u4, u5, u6, u7, u8 = U
    w0, w1, w2, w3, w4, w5, w6, w7, w8 = U2
    return (c0 + u0 * c1 + u1 * c4 + u2 * c7 + w0 * c2 + w1 * c5 + w2 * c8,
            c3 + u3 * c1 + u4 * c4 + u5 * c7 + w3 * c2 + w4 * c5 + w5 * c8,
            c6 + u6 * c1 + u7 * c4 + u8 * c7 + w6 * c2 + w7 * c5 + w8 * c8)


def reached(clock: float, target: float, dt: float) -> bool:
    """Whether a clock that has just advanced by a sample interval ``dt`` has reached
    ``target``: the sample whose end is nearest the target reaches it
    (``clock >= target - dt / 2``), a tie (to ``DUE_TOL`` of ``dt``) counted as reached."""
    return clock >= target - (0.5 + DUE_TOL) * dt


def uniform_interval(dts: np.ndarray) -> float | None:
    """The one interval the fast path integrates ``dts`` with when they are uniform (each
    within 1e-9 of their mean; 12 significant digits make the mean of stamp differences the
    same number from one block to the next, so the cached m-step schedule applies), else
    None."""
    mean = float(dts.mean())
    if np.all(np.abs(dts - mean) <= 1e-9 * mean):
        return float(f"{mean:.12g}")
    return None


def part(dt, a: int, b: int):
    """dt for samples a:b (a float stays a float)."""
    return dt if np.ndim(dt) == 0 else dt[a:b]


def last_interval(dt, end: int) -> float:
    return float(dt) if np.ndim(dt) == 0 else float(dt[end - 1])
