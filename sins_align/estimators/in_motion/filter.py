"""Left-invariant error-state Kalman filter on a moving base (numpy only; seed 003).

A bank of K such filters runs at once (a leading batch axis on every array): the heading
hypotheses of :class:`~sins_align.estimators.in_motion.aligner.MotionAligner` while the
heading is unknown (a Gaussian sum), one filter afterwards.

State and error
---------------
The navigation state is ``X = (C, v)`` with ``C = C_b^n`` (body to local ENU) and ``v = v^n``
(ENU, m/s), plus geodetic position (lat, lon, h; mechanized, not estimated), the gyro and
accelerometer biases ``b_g``, ``b_a`` (body, rad/s and m/s^2) and, optionally, the lever arm
``l`` (body, m, IMU to the antenna of the velocity reference).

The error is left-invariant (``eta = X^-1 X_hat``, ALGORITHM.md): with the estimate ``X_hat``,

    C_hat = C exp(phi x)            phi: attitude error, body axes (rad)
    v_hat = v + C nu                nu:  velocity error, body axes (m/s)
    b_hat = b + zeta                zeta_g, zeta_a: bias errors
    l_hat = l + dl

so the error vector is ``x = [phi, nu, zeta_g, zeta_a(, dl)]``: 12 states, 15 with the lever
arm (the issue and ALGORITHM.md say 15 for (C, v) in SE(3) and two biases: that is 6 + 6 = 12;
position is mechanized but not estimated, since a velocity reference says nothing of it).

Error dynamics (first order; w_hat = gyro - b_g_hat, f_hat = accel - b_a_hat)::

    d phi/dt = -(w_hat x) phi - zeta_g + n_g
    d nu/dt  = -(w_hat x) nu - (f_hat x) phi - zeta_a + n_a
    d zeta/dt = n_b (random walks), d dl/dt = 0

Two terms are left out, both below 1e-4 of what is kept on any vehicle: the rotation of ``nu``
by the Earth rate in body axes (``-(C^T w_ie x) nu``: 7e-5 rad/s on a velocity error), and
the transport-rate difference caused by the velocity error (``nu / R``). What makes the
left-invariant form worth it shows here: the attitude/velocity block depends only on the
measured rates and specific force, not on the attitude estimate, so a wrong start
(upside down, heading off by 175 deg) does not corrupt the model the filter runs on.

Discrete propagation over a run of samples
------------------------------------------
With ``Gamma_j`` the body rotation from the start of the run to the end of sample j
(``Gamma_j = Gamma_{j-1} exp(w_hat_j dt_j)``) and ``dV_j = Gamma_{j-1} exp(w_hat_j dt_j / 2)
f_hat_j dt_j`` the velocity increment of sample j in the start's body axes, each sample maps
``phi -> rho^T (phi - h dt zeta_g)`` and ``nu -> rho^T (nu - (dV x) (phi - h dt zeta_g / 2)
- h dt zeta_a)`` (``rho = exp(w_hat dt)``, ``h = exp(w_hat dt / 2)``, ``dV`` in the sample's
own start axes: the bias acts at the middle of the sample, and the tilt that turns the
specific force is the one of the middle too). Their product over m samples is, in closed form
(``R_j = Gamma_{j-1} h_j``, ``S_j = sum_{i<=j} R_i dt_i``, ``V = sum dV_j``,
``M = sum_j (dV_j x) (S_j - R_j dt_j / 2)``)::

    phi_m = Gamma_m^T (phi_0 - S_m zeta_g)
    nu_m  = Gamma_m^T (nu_0 - (V x) phi_0 + M zeta_g - S_m zeta_a)

which :mod:`~sins_align.estimators.in_motion.runs` evaluates with cumulative sums (exactly
the product of the per-sample maps), for many runs at once: the runs up to the next few
measurements are known before they are applied, and their sums depend only on the samples
and the biases. A measurement that changes the biases between the pass and a run is
applied to the run to first order (the transition above is that Jacobian), and the pass is
recomputed once the neglected term could reach 1e-10 rad (pre-integration with bias
Jacobians). White noise enters after every sample (``q_g dt`` on phi, ``q_a dt`` on
nu, ``q_b dt`` on the biases); its sum over the run is also closed form
(``D_j = V - V_j``): ``Cov(phi) = q_g T``, ``Cov(phi, nu) = Gamma^T q_g (sum dt_j D_j x) Gamma``,
``Cov(nu) = q_a T + Gamma^T q_g sum dt_j (|D_j|^2 I - D_j D_j^T) Gamma`` (bias noise entering
the attitude and velocity within one run, of order q_b T^3, is left out; runs are at most
:data:`MAX_RUN` s).

The mechanization of a run (:func:`~sins_align.estimators.in_motion.runs.advance_navigation`,
scalar arithmetic, filter by filter) uses the run's sums: the navigation frame's rotation
``w_in``, gravity and Coriolis are held at the run's start, Coriolis applied to the integral
of the velocity and the frame rotated at the run's mean velocity (their change within
:data:`MAX_RUN` s moves the attitude by < 1e-8 rad); :func:`propagate_reference` is the
per-sample reference it is tested against.

Measurements
------------
Velocity of the antenna in ENU: ``z = v + C (w_nb x l) + n``, ``w_nb = w - C^T w_in``; with
``a = C_hat^T w_in`` and ``u = w_hat_nb x l_hat``, the residual ``y = z - z_hat`` is
``C_hat [ (u x) - (l x)(a x) , -I , -(l x) , 0 , -(w_hat_nb x) ] x + n``.
Non-holonomic (ground vehicle): the lateral body velocity is zero:
``y = -e^T C_hat^T v_hat = -e^T [ (v_b x), I, 0, 0 ] x``.
Attitude of a master (body axes equal to ours): ``C_m = C exp(n x)`` gives
``y = log(C_hat^T C_m) = phi`` to first order... (see :meth:`update_attitude`).

After an update the error estimate is fed back in full (``X <- X_hat eta_hat^-1``,
biases and lever arm subtract) and the covariance is kept as updated (Joseph form); no
first-order reset correction is applied (ALGORITHM.md: it manufactures correlations after
the large early corrections).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from sins_align.core.earth import (GRAVITY_EQUATOR, GRAVITY_PER_METRE, OMEGA_IE, SOMIGLIANA_K,
                                   WGS84_A, WGS84_E2, normal_gravity, radii)
from sins_align.core.rotation import skew, so3_exp, so3_exp_entries, so3_log
from sins_align.core.strapdown import NavState, mechanize
from sins_align.estimators.in_motion.runs import (RELINEARIZE_ROTATION, RELINEARIZE_VELOCITY,
                                                 SHORT_PASS, advance_navigation,
                                                 cross as _cross, mm as _mm,
                                                 one_sample_entries, white_noise_rate,
                                                 mT as _mT, one_sample_sums, run_sums,
                                                 short_run_sums, skew as _skew)

__all__ = ["InvariantEKF", "NoiseModel", "MAX_RUN", "propagate_reference", "sample_transition",
           "IPHI", "INU", "IBG", "IBA", "EXTRA_STATES", "EXTRA_SIZES", "extra_size",
           "SINGLE_FLOATS"]

#: longest run of samples propagated in one closed-form step, s
MAX_RUN = 1.0
#: a bank of one filter computes its velocity model and non-holonomic update in Python
#: floats (:meth:`InvariantEKF.velocity_model`, :meth:`InvariantEKF.update_lateral`); False:
#: with the bank's arrays, the reference those are equal to, bit for bit (the equality test
#: sets it)
SINGLE_FLOATS = True

IPHI, INU, IBG, IBA = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
#: optional 3-state blocks after the 12 core states, in this order when present: the lever
#: arm (body, m), the mounting misalignment of a master INS (``C_slave = C_master exp(mu
#: x)``, rad, master axes), the gyro scale factors (``gyro = (1 + s) w + b_g``, per axis)
#: and the accelerometer scale factors (``accel = (1 + s_a) f + b_a``), the lever arm of the
#: non-holonomic point (body, m) and the rotation of the vehicle's axes against the IMU's
#: (``nhc_mount``, kept as the rotation matrix ``exp(eps x)``, eps in IMU axes: the
#: vehicle's side is its column ``e_axis``; see
#: :meth:`InvariantEKF.update_lateral`), and one state: the velocity reference's latency
#: (``latency``, s: its stamps are that much later than the instant it measured; see
#: :meth:`InvariantEKF.velocity_model`)
EXTRA_STATES = ("lever", "mount", "gyro_scale", "accel_scale", "nhc_lever", "nhc_mount",
                "latency")
#: states of each optional block (3 unless given here)
EXTRA_SIZES = {"latency": 1}
_I3 = np.eye(3)


def extra_size(blocks) -> int:
    """States of the optional blocks ``blocks`` (names of :data:`EXTRA_STATES`)."""
    return sum(EXTRA_SIZES.get(x, 3) for x in blocks)


@dataclass(frozen=True)
class NoiseModel:
    """White-noise densities of the error model.

    gyro_arw : rad/sqrt(s); accel_vrw : m/s/sqrt(s); gyro_bias_walk : rad/s/sqrt(s);
    accel_bias_walk : m/s^2/sqrt(s).
    """

    gyro_arw: float
    accel_vrw: float
    gyro_bias_walk: float
    accel_bias_walk: float


def _w_in(v, lat, h):
    """Earth rate and transport rate, ENU, for (K, 3) velocities and (K,) lat, h."""
    rm, rn = radii(lat)
    cl, sl = np.cos(lat), np.sin(lat)
    w_ie = OMEGA_IE * np.stack([np.zeros_like(lat), cl, sl], -1)
    ve = v[..., 0] / (rn + h)
    w_en = np.stack([-v[..., 1] / (rm + h), ve, ve * sl / cl], -1)
    return w_ie, w_en


@functools.lru_cache(maxsize=8)
def _transition_layout(n: int):
    """Where :meth:`InvariantEKF._advance_one` puts the entries of a run's transition (n
    states): (the identity with its first six rows zero, the flat positions of the core
    blocks, which of the 36 entries of [Gb^T, Gb^T S, Gb^T (V x), Gb^T M] goes there, its
    sign); read only."""
    pos, src, sign = [], [], []
    for br, bc, first, sg in ((0, 0, 0, 1.0), (0, 2, 9, -1.0), (1, 0, 18, -1.0),
                              (1, 1, 0, 1.0), (1, 2, 27, 1.0), (1, 3, 9, -1.0)):
        for i in range(3):
            for j in range(3):
                pos.append((3 * br + i) * n + 3 * bc + j)
                src.append(first + 3 * i + j)
                sign.append(sg)
    base = np.eye(n)
    base[:6] = 0.0
    out = (base, np.array(pos), np.array(src), np.array(sign))
    for a in out:
        a.flags.writeable = False
    return out


#: samples whose run sums are computed in one pass (fewer after a re-linearisation)
_CHUNK_SAMPLES = 2048


def _earth(ekf):
    """Per filter of the bank: (w_ie north, w_ie up, 1 / (R_M + h), 1 / (R_N + h), tan lat,
    1 / cos lat, gravity, h) (what runs.advance_navigation reads); kept by the bank while
    every filter stays within 1e-6 rad of latitude and 10 m of height of where they were
    computed (that moves the Earth rate by 1e-10 rad/s and the radii by 2e-6 relative;
    gravity follows the height in advance_navigation)."""
    lat, h = ekf.lat, ekf.h
    cached = ekf._earth
    lat_l, h_l = lat.tolist(), h.tolist()       # (compared in floats: a few filters)
    if (cached is not None and len(cached[0]) == len(lat_l)
            and all(abs(a - b) < 1e-6 for a, b in zip(cached[0], lat_l))
            and all(abs(a - b) < 10.0 for a, b in zip(cached[1], h_l))):
        return cached[2]
    rm, rn = radii(lat)
    earth = np.stack([OMEGA_IE * np.cos(lat), OMEGA_IE * np.sin(lat),
                      1.0 / (rm + h), 1.0 / (rn + h), np.tan(lat), 1.0 / np.cos(lat),
                      normal_gravity(lat, h), h], -1).tolist()
    ekf._earth = (lat_l, h_l, earth)
    return earth


class _Linearisation:
    """The point the run sums of one pass are computed at: each filter's biases and scale
    factors, the corrected samples, and the Earth's quantities at each filter's position
    (held over the pass: a few seconds move them by less than 1e-9 relative, except
    gravity, corrected for height within the pass)."""

    def __init__(self, ekf, gyro, accel):
        self.ids = ekf.ids.copy()
        self.bg, self.ba = ekf.bg.copy(), ekf.ba.copy()
        self.sf, self.sa = ekf.sf.copy(), ekf.sa.copy()
        self._lists = {}
        self.w = (gyro - ekf.bg[:, None]) / (1.0 + ekf.sf[:, None])
        self.f = (accel - ekf.ba[:, None]) / (1.0 + ekf.sa[:, None])
        self.earth = _earth(ekf)

    def lists(self, row):
        """Row ``row``'s bg, ba, sf and sa as lists of floats (computed once)."""
        out = self._lists.get(row)
        if out is None:
            out = self._lists[row] = (self.bg[row].tolist(), self.ba[row].tolist(),
                                      self.sf[row].tolist(), self.sa[row].tolist())
        return out

    def rows(self, ekf):
        """The rows of this pass's arrays of the bank's filters now (None: all, in order)."""
        if len(ekf.ids) == len(self.ids):
            return None
        return np.searchsorted(self.ids, ekf.ids)

    @staticmethod
    def take(a, rows):
        return a if rows is None else a[rows]

    def drifted(self, ekf, r, s) -> bool:
        """Have the biases moved so far since this point that run r must be recomputed?"""
        rows = self.rows(ekf)
        T = float(s.T[r])
        if ekf.K == 1 and ekf.i_sf is None and ekf.i_sa is None:
            # one filter: the same test in floats
            lbg, lba, _, _ = self.lists(0 if rows is None else int(rows[0]))
            rot = max(abs(a - b) for a, b in zip(ekf.bg[0].tolist(), lbg))
            vel = max(abs(a - b) for a, b in zip(ekf.ba[0].tolist(), lba))
            return rot * T > RELINEARIZE_ROTATION or vel * T > RELINEARIZE_VELOCITY
        rot = np.abs(ekf.bg - self.take(self.bg, rows)).max()
        vel = np.abs(ekf.ba - self.take(self.ba, rows)).max()
        if ekf.i_sf is not None:
            rot += np.abs(ekf.sf - self.take(self.sf, rows)).max() * s.w_max
        if ekf.i_sa is not None:
            vel += np.abs(ekf.sa - self.take(self.sa, rows)).max() * s.f_max
        return rot * T > RELINEARIZE_ROTATION or vel * T > RELINEARIZE_VELOCITY


class InvariantEKF:
    """A bank of K filters: states, covariances and the operations on them (no stream logic).

    Attributes (K = number of filters)
    ----------
    C (K, 3, 3), v (K, 3), lat, lon, h (K,), bg, ba, lever (K, 3), P (K, n, n) with n = 12,
    or 15 with the lever arm; w_last, f_last (K, 3): the last bias-corrected rate and
    specific force.

    Parameters
    ----------
    state : NavState — the start, shared by all filters, except:
    C : optional (K, 3, 3) attitudes (the hypotheses); default ``state.C`` once.
    P0 : (n, n) or (K, n, n) — initial error covariance(s).
    noise : NoiseModel.
    lever_arm : (3,) m, body — initial lever arm.
    nhc_lever_arm : (3,) m, body — initial lever arm of the non-holonomic point
        (:meth:`update_lateral`).
    extra : which of :data:`EXTRA_STATES` are estimated (their blocks follow the core 12 in
        that order; P0 must have 12 + 3 per block rows).
    """

    def __init__(self, state: NavState, P0, noise: NoiseModel, lever_arm=(0, 0, 0), C=None,
                 extra=(), nhc_lever_arm=(0, 0, 0)):
        C = state.C[None] if C is None else np.asarray(C, dtype=float).reshape(-1, 3, 3)
        K = len(C)
        self.C = C.copy()
        self.v = np.tile(state.v, (K, 1))
        self.lat = np.full(K, state.lat)
        self.lon = np.full(K, state.lon)
        self.h = np.full(K, state.h)
        self._innovation = None                 # (y, H P H^T + R) of the last update
        self._correction = None                 # (K, n): the error estimate the last update made
        P0 = np.asarray(P0, dtype=float)
        self.P = np.broadcast_to(P0, (K,) + P0.shape[-2:]).copy()
        self.n = self.P.shape[-1]
        unknown = set(extra) - set(EXTRA_STATES)
        if unknown:
            raise ValueError(f"unknown extra states {sorted(unknown)}")
        blocks = [x for x in EXTRA_STATES if x in extra]
        if self.P.shape[-2:] != (12 + extra_size(blocks),) * 2:
            raise ValueError(f"P0 must be {12 + extra_size(blocks)} square for extra={blocks}")
        self.i_lev = self.i_mnt = self.i_sf = self.i_sa = self.i_nhl = self.i_nhm = None
        self.i_lat = None
        i0 = 12
        for x in blocks:
            sl = slice(i0, i0 + EXTRA_SIZES.get(x, 3))
            i0 = sl.stop
            if x == "latency":
                self.i_lat = sl
            elif x == "lever":
                self.i_lev = sl
            elif x == "mount":
                self.i_mnt = sl
            elif x == "gyro_scale":
                self.i_sf = sl
            elif x == "accel_scale":
                self.i_sa = sl
            elif x == "nhc_lever":
                self.i_nhl = sl
            else:
                self.i_nhm = sl
        self.noise = noise
        self.bg = np.zeros((K, 3))
        self.ba = np.zeros((K, 3))
        self.lever = np.tile(np.asarray(lever_arm, dtype=float).reshape(3), (K, 1))
        self.mount = np.zeros((K, 3))
        self.sf = np.zeros((K, 3))            # gyro scale factors (estimated with i_sf)
        self.sa = np.zeros((K, 3))            # accelerometer scale factors (with i_sa)
        self.nhc_lever = np.tile(np.asarray(nhc_lever_arm, dtype=float).reshape(3), (K, 1))
        #: the vehicle's axes against the IMU's, (K, 3, 3) rotations (estimated with i_nhm)
        self.nhc_mount = np.tile(_I3, (K, 1, 1))
        self.latency = np.zeros((K, 1))       # velocity reference latency, s (with i_lat)
        self.dx = np.zeros((K, self.n))       # error estimate not yet fed back (see feedback)
        #: None: full reset after every update; else a callable giving, for the time since
        #: the last feedback, the (n, n) fraction of the error estimate to feed back
        #: (:class:`~sins_align.estimators.in_motion.feedback.LqrFeedback`)
        self.schedule = None
        self.t_since_feedback = 0.0
        self.w_last = np.zeros((K, 3))
        self.f_last = np.zeros((K, 3))
        #: the velocity jitter (ENU, m/s) taken out of the last velocity update
        #: (:meth:`exclude_velocity_jitter`)
        self.jitter_enu = np.zeros((K, 3))
        #: which filter of the original bank each one is (kept by :meth:`select`)
        self.ids = np.arange(K)
        self._eye = np.eye(self.n)
        self._earth = None            # (lat, h, earth list) of the last pass (_Linearisation)

    _ARRAYS = ("C", "v", "lat", "lon", "h", "P", "bg", "ba", "lever", "mount", "sf", "sa",
               "nhc_lever", "nhc_mount", "latency", "dx", "w_last", "f_last", "jitter_enu", "ids")

    @property
    def K(self) -> int:
        return len(self.C)

    def copy(self) -> "InvariantEKF":
        """An independent copy (its own arrays)."""
        new = self.snapshot()
        for k in self._ARRAYS:
            setattr(new, k, getattr(self, k).copy())
        return new

    def snapshot(self) -> "InvariantEKF":
        """A copy that shares the arrays: cheap, and it keeps the state of now because
        every method of this class replaces its arrays instead of writing into them. Code
        that writes into the arrays in place takes :meth:`copy`."""
        new = InvariantEKF.__new__(InvariantEKF)
        new.__dict__.update(self.__dict__)
        return new

    def select(self, index) -> None:
        """Keep only the filters ``index`` (an index array or a boolean mask)."""
        for k in self._ARRAYS:
            setattr(self, k, getattr(self, k)[index])

    def nav(self, i: int = 0) -> NavState:
        return NavState(self.C[i], self.v[i], self.lat[i], self.lon[i], self.h[i])

    def corrected_dcms(self) -> np.ndarray:
        """(K, 3, 3): every filter's attitude with the error estimate not yet fed back
        removed (``corrected(i)[0]`` of each; with full feedback the state's own)."""
        if self.schedule is None:
            return self.C
        return self.C @ so3_exp(-self.dx[:, IPHI])

    @property
    def covariance_enu(self) -> np.ndarray:
        """(K, 3, 3): covariance of the attitude error in ENU (C_true = exp(e x) C_hat,
        e = -C_hat phi)."""
        return self.C @ self.P[:, IPHI, IPHI] @ _mT(self.C)

    # ------------------------------------------------------------ propagation
    def propagate(self, dt, gyro, accel) -> None:
        """Propagate over samples: dt (m,); gyro and accel (m, 3), the same samples for every
        filter, or (K, m, 3), each filter its own (a Monte Carlo of K runs)."""
        for _ in self.propagate_runs(dt, gyro, accel, [len(np.reshape(dt, -1))]):
            pass

    def propagate_runs(self, dt, gyro, accel, ends):
        """Propagate the runs of samples ``[ends[r-1], ends[r])`` one after the other, and
        yield r after run r (the state is then that of its last sample: the caller applies
        its measurements there, and may change the states, even drop filters with
        :meth:`select`, before asking for the next run). A generator.

        Runs longer than :data:`MAX_RUN` are propagated in pieces. The sums of the runs
        are computed ahead, many runs at once, at the biases of that moment
        (:func:`~sins_align.estimators.in_motion.runs.run_sums`); a run applied after the
        biases changed is corrected to first order, and the sums are computed anew once
        the change could matter (see :mod:`~sins_align.estimators.in_motion.runs`)."""
        dt = np.asarray(dt, dtype=float).reshape(-1)
        gyro = np.asarray(gyro, dtype=float)
        accel = np.asarray(accel, dtype=float)
        m = len(dt)
        if m == 0:
            return
        if gyro.shape[-2:] != (m, 3) or accel.shape != gyro.shape or gyro.ndim > 3:
            raise ValueError(f"gyro and accel must be ({m}, 3) or (K, {m}, 3)")
        ends = [int(e) for e in ends]
        if not ends or ends[-1] != m or any(b <= a for a, b in zip([0] + ends, ends)):
            raise ValueError(f"ends must increase from above 0 to {m}")
        if m == 1 and self.K == 1 and gyro.ndim == 2:
            self._step_one(float(dt[0]), gyro[0], accel[0])      # (the same, in floats)
            yield 0
            return
        # pieces of at most MAX_RUN s; owner[p]: the run a piece ends, or -1
        tt = np.cumsum(dt) if m > 1 else None
        pieces, owner = ([1], [0]) if m == 1 else ([], [])     # (one sample: one piece)
        k = m if m == 1 else 0
        for r, e in enumerate(ends):
            while k < e:
                p = k + max(1, int(np.searchsorted(tt[k:e], tt[k] - dt[k] + MAX_RUN, "right")))
                p = min(p, e)
                pieces.append(p)
                owner.append(r if p == e else -1)
                k = p
        size = _CHUNK_SAMPLES
        i = 0
        while i < len(pieces):
            a = pieces[i - 1] if i else 0
            j = i + 1
            while j < len(pieces) and pieces[j] - a <= size:
                j += 1
            b = pieces[j - 1]
            lin = _Linearisation(self, gyro[..., a:b, :], accel[..., a:b, :])
            if b - a == 1:
                sums = one_sample_sums(dt[a], lin.w[:, 0], lin.f[:, 0], self.noise, self.n,
                                       self.i_sf, self.i_sa)
            elif b - a <= SHORT_PASS and len(lin.w) == 1:
                # one filter, a short pass (a live stream's rewind): the same sums in floats
                sums = short_run_sums(dt[a:b], lin.w, lin.f, [p - a for p in pieces[i:j]],
                                      self.noise, self.n, self.i_sf, self.i_sa)
            else:
                sums = run_sums(dt[a:b], lin.w, lin.f, [p - a for p in pieces[i:j]],
                                self.noise, self.n, self.i_sf, self.i_sa)
            q = i
            while q < j:
                if q > i and lin.drifted(self, q - i, sums):
                    break
                self._advance(sums, q - i, lin, gyro[..., pieces[q] - 1, :],
                              accel[..., pieces[q] - 1, :])
                q += 1
                if owner[q - 1] >= 0:
                    yield owner[q - 1]
            # fewer runs ahead after a re-linearisation, more when none was needed
            size = max(1, (pieces[q - 1] - a) // 2) if q < j else min(2 * size,
                                                                        _CHUNK_SAMPLES)
            i = q

    def _advance(self, s, r, lin, gyro_end, accel_end) -> None:
        """Apply run r of the sums ``s`` (bias-corrected to first order) to every filter."""
        rows = lin.rows(self)
        if self.K == 1:
            self._advance_one(s, r, lin, 0 if rows is None else int(rows[0]), gyro_end,
                              accel_end)
            return
        if rows is None:
            def g(a):
                return a[:, r]
        else:
            def g(a):
                return a[rows, r]
        T = float(s.T[r])
        K = self.K
        # ------------------------------------------------------------ navigation
        # filter by filter, in scalar arithmetic (see runs.advance_navigation)
        sums = g(s.packed).tolist()
        dbg = (self.bg - lin.take(lin.bg, rows)).tolist()
        dba = (self.ba - lin.take(lin.ba, rows)).tolist()
        earth = lin.earth if rows is None else [lin.earth[i] for i in rows]
        Cs, vs = self.C.reshape(K, 9).tolist(), self.v.tolist()
        lat, lon, h = self.lat.tolist(), self.lon.tolist(), self.h.tolist()
        extra = [dict() for _ in range(K)]
        if s.Sw is not None:
            dsf = (self.sf - lin.take(lin.sf, rows)).tolist()
            Sw, Mw = g(s.Sw).reshape(K, 9).tolist(), g(s.Mw).reshape(K, 9).tolist()
            for k in range(K):
                extra[k].update(dsf=dsf[k], Sw=Sw[k], Mw=Mw[k])
        if s.Sa is not None:
            dsa = (self.sa - lin.take(lin.sa, rows)).tolist()
            Sa = g(s.Sa).reshape(K, 9).tolist()
            for k in range(K):
                extra[k].update(dsa=dsa[k], Sa=Sa[k])
        Gb, Vb = [None] * K, [None] * K
        for k in range(K):
            Cs[k], vs[k], lat[k], lon[k], h[k], Gb[k], Vb[k] = advance_navigation(
                Cs[k], vs[k], lat[k], lon[k], h[k], sums[k], T, dbg[k], dba[k], earth[k],
                **extra[k])
        # ------------------------------------------------------------ covariance
        # the transition at the biases of now (the run's own sums, corrected as above):
        # the sums' linearisation point would turn a large heading variance into the level
        # by the rotation the biases' change causes (up to RELINEARIZE_ROTATION per run)
        GbT = _mT(np.array(Gb).reshape(K, 3, 3))
        S = g(s.S)
        Phi = np.broadcast_to(self._eye, (K, self.n, self.n)).copy()
        GS = GbT @ S
        Phi[:, IPHI, IPHI] = GbT
        Phi[:, IPHI, IBG] = -GS
        Phi[:, INU, IPHI] = -GbT @ _skew(np.array(Vb))
        Phi[:, INU, INU] = GbT
        Phi[:, INU, IBG] = GbT @ g(s.M)
        Phi[:, INU, IBA] = -GS
        if s.Sw is not None:
            Phi[:, IPHI, self.i_sf] = -GbT @ g(s.Sw)
            Phi[:, INU, self.i_sf] = GbT @ g(s.Mw)
        if s.Sa is not None:
            Phi[:, INU, self.i_sa] = -GbT @ g(s.Sa)
        P = Phi @ self.P @ _mT(Phi) + g(s.Q)
        self.P = 0.5 * (P + _mT(P))
        self.t_since_feedback += T
        if self.schedule is not None:
            self.dx = np.einsum("kij,kj->ki", Phi, self.dx)
        self.C = np.array(Cs).reshape(K, 3, 3)
        self.v = np.array(vs)
        self.lat, self.lon, self.h = np.array(lat), np.array(lon), np.array(h)
        self.w_last = (gyro_end - self.bg) / (1.0 + self.sf)
        self.f_last = (accel_end - self.ba) / (1.0 + self.sa)

    def _advance_one(self, s, r, lin, row, gyro_end, accel_end) -> None:
        """:meth:`_advance` of a bank of one filter (row ``row`` of the pass): the same
        arithmetic in Python floats and 2-D arrays, without the batch axis's per-call cost
        (the equality test compares it with a bank of identical filters)."""
        lbg, lba, lsf, lsa = lin.lists(row)
        extra = {}
        if s.Sw is not None:
            extra.update(dsf=[x - y for x, y in zip(self.sf[0].tolist(), lsf)],
                         Sw=s.Sw[row, r].ravel().tolist(), Mw=s.Mw[row, r].ravel().tolist())
        if s.Sa is not None:
            extra.update(dsa=[x - y for x, y in zip(self.sa[0].tolist(), lsa)],
                         Sa=s.Sa[row, r].ravel().tolist())
        self._advance_floats(float(s.T[r]), s.packed[row, r].tolist(),
                             [x - y for x, y in zip(self.bg[0].tolist(), lbg)],
                             [x - y for x, y in zip(self.ba[0].tolist(), lba)], extra,
                             s.Q[row, r], lin.earth[row], gyro_end, accel_end)

    def _step_one(self, dt: float, gyro, accel) -> None:
        """One sample of a bank of one filter (a live stream's usual pass): what
        :meth:`propagate_runs` does with a pass of one sample (the linearisation point is
        the state of now, so the bias differences are zero; the sums of
        :func:`~sins_align.estimators.in_motion.runs.one_sample_entries`), in floats."""
        bg, ba = self.bg[0].tolist(), self.ba[0].tolist()
        sf, sa = self.sf[0].tolist(), self.sa[0].tolist()
        w = [(x - y) / (1.0 + z) for x, y, z in zip(gyro.tolist(), bg, sf)]
        f = [(x - y) / (1.0 + z) for x, y, z in zip(accel.tolist(), ba, sa)]
        packed, Sw, Mw, Sa = one_sample_entries(dt, w, f, self.i_sf is not None,
                                                self.i_sa is not None)
        zero = [0.0, 0.0, 0.0]
        extra = {}
        if Sw is not None:
            extra.update(dsf=zero, Sw=Sw, Mw=Mw)
        if Sa is not None:
            extra.update(dsa=zero, Sa=Sa)
        self._advance_floats(dt, packed, zero, zero, extra, white_noise_rate(self.noise, self.n)
                             * dt, _earth(self)[0], gyro, accel)

    def _advance_floats(self, T, sums, dbg, dba, extra, Q, earth, gyro_end, accel_end):
        """The navigation and covariance of a bank of one filter over one run: sums (36
        floats, :class:`~sins_align.estimators.in_motion.runs.RunSums`), the bias
        differences from the linearisation point dbg, dba and ``extra`` (the scale-factor
        sums and differences, 9 and 3 floats) as runs.advance_navigation takes them, the
        run's noise Q (n, n)."""
        C1, v1, lat, lon, h, Gb, Vb = advance_navigation(
            self.C[0].ravel().tolist(), self.v[0].tolist(), float(self.lat[0]),
            float(self.lon[0]), float(self.h[0]), sums, T, dbg, dba, earth, **extra)
        # the transition's first six rows (the others are the identity's), as in _advance:
        # the entries of Gb^T, Gb^T S, Gb^T (Vb x) and Gb^T M put in place with their signs
        g0, g1, g2, g3, g4, g5, g6, g7, g8 = Gb
        GbT = [g0, g3, g6, g1, g4, g7, g2, g5, g8]
        Vx, Vy, Vz = Vb
        blocks = np.array(GbT + _mm(GbT, sums[9:18])
                          + _mm(GbT, [0.0, -Vz, Vy, Vz, 0.0, -Vx, -Vy, Vx, 0.0])
                          + _mm(GbT, sums[18:27]))
        base, pos, src, sign = _transition_layout(self.n)
        Phi = base.copy()
        Phi.reshape(-1)[pos] = blocks[src] * sign
        if extra:
            G = np.array(GbT).reshape(3, 3)
            if "Sw" in extra:
                Phi[IPHI, self.i_sf] = -G @ np.reshape(extra["Sw"], (3, 3))
                Phi[INU, self.i_sf] = G @ np.reshape(extra["Mw"], (3, 3))
            if "Sa" in extra:
                Phi[INU, self.i_sa] = -G @ np.reshape(extra["Sa"], (3, 3))
        P = Phi @ self.P[0] @ Phi.T + Q
        P = P + P.T
        P *= 0.5
        self.P = P[None]
        self.t_since_feedback += T
        if self.schedule is not None:
            self.dx = (Phi @ self.dx[0])[None]
        if gyro_end.ndim == 1:
            # one buffer, seven arrays
            nav = np.array(C1 + v1 + [lat, lon, h]
                           + [(x - y) / (1.0 + z) for x, y, z in zip(
                               gyro_end.tolist(), self.bg[0].tolist(), self.sf[0].tolist())]
                           + [(x - y) / (1.0 + z) for x, y, z in zip(
                               accel_end.tolist(), self.ba[0].tolist(), self.sa[0].tolist())])
            self.w_last = nav[15:18].reshape(1, 3)
            self.f_last = nav[18:21].reshape(1, 3)
        else:
            nav = np.array(C1 + v1 + [lat, lon, h])        # one buffer, five arrays
            self.w_last = (gyro_end - self.bg) / (1.0 + self.sf)
            self.f_last = (accel_end - self.ba) / (1.0 + self.sa)
        self.C = nav[0:9].reshape(1, 3, 3)
        self.v = nav[9:12].reshape(1, 3)
        self.lat, self.lon, self.h = nav[12:13], nav[13:14], nav[14:15]

    # ---------------------------------------------------------------- updates
    def _apply(self, y, H, R, nis_limit=None, consider_heading=False):
        """Kalman update of every filter: residuals y (K, d), models H (K, d, n), noise R
        (d, d) or (K, d, d); feeds the estimates back. Returns (NIS per degree of freedom
        before any inflation (K,), log-likelihood of y (K,): zeros for a single filter, which
        has no other to be weighed against).

        consider_heading: a Schmidt (consider) update of the heading: the gain loses its
        component along the heading error direction (the navigation vertical in the error
        state's body axes, ``a = C_hat^T u``: the heading error is ``-a . phi``), the other
        states keep theirs, and the covariance takes the Joseph form of that gain, so the
        heading variance ``a^T P_phi a`` is exactly what it was before the update (its
        correlations with the other states are updated)."""
        if self.K == 1:
            return self._apply_one(y[0], H[0], R if R.ndim == 2 else R[0], nis_limit,
                                   consider_heading)
        P = self.P
        PHT = P @ _mT(H)
        S = H @ PHT + R
        self._innovation = (y, S)
        Sinv = np.linalg.inv(S)
        d = y.shape[-1]
        Sy = (Sinv @ y[..., None])[..., 0]
        maha = np.einsum("ki,ki->k", y, Sy)
        nis = maha / d
        if self.K > 1:
            loglik = -0.5 * (maha + np.linalg.slogdet(S)[1] + d * math.log(2.0 * math.pi))
        else:
            loglik = np.zeros(1)
        if nis_limit is not None and float(nis.max()) > nis_limit:
            a = np.maximum(nis / nis_limit, 1.0)
            R = R + (a - 1.0)[:, None, None] * S
            Sinv = Sinv / a[:, None, None]
            Sy = Sy / a[:, None]
        Kg = PHT @ Sinv
        if consider_heading:
            a = self.C[:, 2, :]                                  # (K, 3): C_hat^T u
            Kg = Kg.copy()
            Kg[:, IPHI] -= a[:, :, None] * np.einsum("ki,kid->kd", a, Kg[:, IPHI])[:, None]
        IKH = self._eye - Kg @ H
        P = IKH @ P @ _mT(IKH) + Kg @ R @ _mT(Kg)
        self.P = 0.5 * (P + _mT(P))
        if self.schedule is None:
            if consider_heading:
                self._correction = np.einsum("kid,kd->ki", Kg, y)
            else:
                self._correction = (PHT @ Sy[..., None])[..., 0]
            self.feedback(self._correction)
        else:
            # the error estimate carried on: the residual about it, then its scheduled part
            # fed back (seed 002's LQR feedback)
            self._correction = np.einsum("kij,kj->ki", Kg,
                                         y - np.einsum("kij,kj->ki", H, self.dx))
            dx = self.dx + self._correction
            u = np.einsum("ij,kj->ki", self.schedule(self.t_since_feedback), dx)
            self.feedback(u)
            self.dx = dx - u
        self.t_since_feedback = 0.0
        return nis, loglik

    def _apply_one(self, y, H, R, nis_limit, consider_heading=False):
        """:meth:`_apply` of a bank of one filter: y (d,), H (d, n), R (d, d); the same
        arithmetic on 2-D arrays."""
        P = self.P[0]
        PHT = P @ H.T
        S = H @ PHT + R
        self._innovation = (y[None], S[None])
        Sinv = 1.0 / S if len(y) == 1 else np.linalg.inv(S)     # (1 x 1: the same division)
        Sy = Sinv @ y
        nis = float(y @ Sy) / len(y)
        if nis_limit is not None and nis > nis_limit:
            a = nis / nis_limit
            R = R + (a - 1.0) * S
            Sinv = Sinv / a
            Sy = Sy / a
        Kg = PHT @ Sinv
        if consider_heading:
            a = self.C[0, 2]                                     # C_hat^T u
            Kg = Kg.copy()
            Kg[IPHI] -= np.outer(a, a @ Kg[IPHI])
        IKH = self._eye - Kg @ H
        P = IKH @ P @ IKH.T + Kg @ R @ Kg.T
        self.P = (0.5 * (P + P.T))[None]
        if self.schedule is None:
            c = Kg @ y if consider_heading else PHT @ Sy
            self._correction = c[None]
            self._feedback_one(c)
        else:
            c = Kg @ (y - H @ self.dx[0])
            self._correction = c[None]
            dx = self.dx[0] + c
            u = self.schedule(self.t_since_feedback) @ dx
            self._feedback_one(u)
            self.dx = (dx - u)[None]
        self.t_since_feedback = 0.0
        return np.array([nis]), np.zeros(1)

    def last_correction(self, i: int) -> np.ndarray:
        """Filter i's error estimate (n,) made by the last update (what it fed back, or
        with a feedback schedule what it added to the carried estimate), after any inflation
        by ``nis_limit``."""
        return self._correction[i]

    def last_innovation(self, i: int):
        """Filter i's residual (d,) and its covariance H P H^T + R (d, d) in the last update,
        before any inflation by ``nis_limit``."""
        y, S = self._innovation
        return y[i], S[i]

    def corrected(self, i: int):
        """Filter i's state with the error estimate not yet fed back removed: (C, v, bg, ba,
        lever, mount, nhc_lever, nhc_mount (a rotation matrix)). With full feedback that is
        the state itself."""
        dx = self.dx[i]
        if not dx.any():           # (full reset: nothing carried; the same values, copied)
            return (self.C[i].copy(), self.v[i].copy(), self.bg[i].copy(), self.ba[i].copy(),
                    self.lever[i].copy(), self.mount[i].copy(), self.nhc_lever[i].copy(),
                    self.nhc_mount[i].copy())
        C = self.C[i] @ so3_exp(-dx[IPHI])
        out = [C, self.v[i] - C @ dx[INU], self.bg[i] - dx[IBG], self.ba[i] - dx[IBA],
               self.lever[i].copy(), self.mount[i].copy(), self.nhc_lever[i].copy(),
               self.nhc_mount[i].copy()]
        if self.i_lev is not None:
            out[4] = out[4] - dx[self.i_lev]
        if self.i_mnt is not None:
            out[5] = out[5] - dx[self.i_mnt]
        if self.i_nhl is not None:
            out[6] = out[6] - dx[self.i_nhl]
        if self.i_nhm is not None:
            out[7] = so3_exp(-dx[self.i_nhm]) @ out[7]
        return tuple(out)

    def feedback(self, dx) -> None:
        """Remove estimated errors ``dx`` (K, n) from the states (full reset)."""
        if self.K == 1:
            self._feedback_one(dx[0])
            return
        self.C = self.C @ so3_exp(-dx[:, IPHI])
        self.v = self.v - np.einsum("kij,kj->ki", self.C, dx[:, INU])
        self.bg = self.bg - dx[:, IBG]
        self.ba = self.ba - dx[:, IBA]
        if self.i_lev is not None:
            self.lever = self.lever - dx[:, self.i_lev]
        if self.i_mnt is not None:
            self.mount = self.mount - dx[:, self.i_mnt]
        if self.i_sf is not None:
            self.sf = self.sf - dx[:, self.i_sf]
        if self.i_sa is not None:
            self.sa = self.sa - dx[:, self.i_sa]
        if self.i_nhl is not None:
            self.nhc_lever = self.nhc_lever - dx[:, self.i_nhl]
        if self.i_nhm is not None:
            self.nhc_mount = so3_exp(-dx[:, self.i_nhm]) @ self.nhc_mount
        if self.i_lat is not None:
            self.latency = self.latency - dx[:, self.i_lat]

    def _feedback_one(self, dx) -> None:
        """:meth:`feedback` of a bank of one filter, dx (n,): the same arithmetic in floats
        (the attitude, velocity, biases and the optional blocks that subtract in one new
        buffer)."""
        d = dx.tolist()
        C = _mm(self.C[0].ravel().tolist(), list(so3_exp_entries(-d[0], -d[1], -d[2])))
        n0, n1, n2 = d[3:6]
        v0, v1, v2 = self.v[0].tolist()
        b = self.bg[0].tolist() + self.ba[0].tolist()
        vals = (C + [v0 - (C[0] * n0 + C[1] * n1 + C[2] * n2),
                     v1 - (C[3] * n0 + C[4] * n1 + C[5] * n2),
                     v2 - (C[6] * n0 + C[7] * n1 + C[8] * n2)]
                + [x - y for x, y in zip(b, d[6:12])])
        blocks = [(name, sl) for name, sl in (
            ("lever", self.i_lev), ("mount", self.i_mnt), ("sf", self.i_sf), ("sa", self.i_sa),
            ("nhc_lever", self.i_nhl), ("latency", self.i_lat)) if sl is not None]
        for name, sl in blocks:
            vals += [x - y for x, y in zip(getattr(self, name)[0].tolist(), d[sl])]
        buf = np.array(vals)
        self.C = buf[0:9].reshape(1, 3, 3)
        self.v = buf[9:12].reshape(1, 3)
        self.bg = buf[12:15].reshape(1, 3)
        self.ba = buf[15:18].reshape(1, 3)
        i = 18
        for name, sl in blocks:
            m = sl.stop - sl.start
            setattr(self, name, buf[i:i + m].reshape(1, m))
            i += m
        if self.i_nhm is not None:
            self.nhc_mount = np.dot(so3_exp(-dx[self.i_nhm]), self.nhc_mount[0])[None]

    def _body_rate(self, rate=None):
        """(a, w_nb), each (K, 3), body axes: the navigation frame's rate (Earth and
        transport) and the body's rate with respect to it, from the last corrected rate (or
        the corrected ``rate`` given, (K, 3))."""
        w_ie, w_en = _w_in(self.v, self.lat, self.h)
        a = np.einsum("kji,kj->ki", self.C, w_ie + w_en)
        return a, (self.w_last if rate is None else rate) - a

    def velocity_model(self, force=None, rate=None):
        """Predicted antenna velocity (K, 3) ENU and its H (K, 3, n) against the error state.

        With the ``latency`` state (a reference stamped ``tau`` s after the instant it
        measured, a driver stamping at reception), the prediction is the velocity ``tau``
        before: ``v - tau a`` with ``a = C f + g`` the acceleration (ENU; the Coriolis and
        lever-arm terms left out), and ``dz/d tau = -a``.

        ``force``, ``rate`` (K, 3), body axes, corrected: the specific force of that
        acceleration and the rate of the antenna's ``w x l`` (prediction and H alike), the
        vehicle's; default the last sample's. A reference that does not see the IMU's
        vibration (``MotionConfig.velocity_averaging`` > 0) is compared with the vehicle's
        motion: a vibrating sample made the latency's and the lever arm's columns of H
        regressors of the vibration, which the jitter the updates still hold follows (both
        alias alike at the update rate), and those states and their correlations took it
        into the attitude (a 5 Hz tone: the attitude beyond 3 sigma 30-50 % of the time)."""
        if self.K == 1 and SINGLE_FLOATS:
            return self._velocity_model_one(force, rate)
        z_hat, H = self._velocity_model(rate)
        if self.i_lat is not None:
            a = np.einsum("kij,kj->ki", self.C, self.f_last if force is None else force)
            a[:, 2] -= normal_gravity(self.lat, self.h)
            z_hat = z_hat - self.latency * a
            H[:, :, self.i_lat] = a[:, :, None]
        return z_hat, H

    def _velocity_model_one(self, force=None, rate=None):
        """:meth:`velocity_model` of a bank of one filter: the same arithmetic on Python
        floats (the Earth's and transport rate, the cross products, the latency's
        acceleration, each sum in numpy's order of terms) and 2-D arrays, the products of
        matrices numpy's as in the bank's path (BLAS rounds them its own way): the same
        numbers to the bit (:data:`SINGLE_FLOATS`; test_in_motion_single.py)."""
        C = self.C[0]
        c0, c1, c2, c3, c4, c5, c6, c7, c8 = C.ravel().tolist()
        v0, v1, v2 = self.v[0].tolist()
        lever = self.lever[0]
        lat = h = None
        if self.i_lev is None and not lever.any():
            H = np.zeros((3, self.n))
            H[:, INU] = -C
            z0, z1, z2 = v0, v1, v2
        else:
            # _body_rate: C^T (w_ie + w_en) and the body's rate against the frame
            lat, h = float(self.lat[0]), float(self.h[0])
            a0, a1, a2 = _frame_rate_floats(lat, h, v0, v1, c0, c1, c2, c3, c4, c5, c6, c7, c8)
            r = (self.w_last if rate is None else rate)[0].tolist()
            n0, n1, n2 = r[0] - a0, r[1] - a1, r[2] - a2
            l0, l1, l2 = lever.tolist()
            u0, u1, u2 = n1 * l2 - n2 * l1, n2 * l0 - n0 * l2, n0 * l1 - n1 * l0
            # (the order of the terms is einsum's over a contiguous axis of 3)
            z0 = v0 + ((c0 * u0 + c2 * u2) + c1 * u1)
            z1 = v1 + ((c3 * u0 + c5 * u2) + c4 * u1)
            z2 = v2 + ((c6 * u0 + c8 * u2) + c7 * u1)
            Sl = np.array([[0.0, -l2, l1], [l2, 0.0, -l0], [-l1, l0, 0.0]])
            Hb = np.zeros((3, self.n))
            Hb[:, IPHI] = (np.array([[0.0, -u2, u1], [u2, 0.0, -u0], [-u1, u0, 0.0]])
                           - Sl @ np.array([[0.0, -a2, a1], [a2, 0.0, -a0], [-a1, a0, 0.0]]))
            Hb[:, INU] = -_I3
            Hb[:, IBG] = -Sl
            if self.i_lev is not None:
                Hb[:, self.i_lev] = [[0.0, n2, -n1], [-n2, 0.0, n0], [n1, -n0, 0.0]]
            if self.i_sf is not None:
                Hb[:, self.i_sf] = -Sl * r
            H = C @ Hb
        if self.i_lat is not None:
            # velocity_model's latency: the acceleration C f + g
            f0, f1, f2 = (self.f_last if force is None else force)[0].tolist()
            if lat is None:
                lat, h = float(self.lat[0]), float(self.h[0])
            sl = math.sin(lat)
            s2 = sl * sl
            g = (GRAVITY_EQUATOR * (1.0 + SOMIGLIANA_K * s2) / math.sqrt(1.0 - WGS84_E2 * s2)
                 - GRAVITY_PER_METRE * h)
            e0 = (c0 * f0 + c2 * f2) + c1 * f1
            e1 = (c3 * f0 + c5 * f2) + c4 * f1
            e2 = ((c6 * f0 + c8 * f2) + c7 * f1) - g
            tau = float(self.latency[0, 0])
            z0, z1, z2 = z0 - tau * e0, z1 - tau * e1, z2 - tau * e2
            H[:, self.i_lat] = [[e0], [e1], [e2]]
        return np.array([[z0, z1, z2]]), H[None]

    def _velocity_model(self, rate=None):
        C, lever = self.C, self.lever
        K = self.K
        if self.i_lev is None and not lever.any():
            # no lever arm: the antenna is the IMU (the general form below gives these)
            H = np.zeros((K, 3, self.n))
            H[:, :, INU] = -C
            return self.v.copy(), H
        a, w_nb = self._body_rate(rate)
        u = _cross(w_nb, lever)
        z_hat = self.v + np.einsum("kij,kj->ki", C, u)
        Hb = np.zeros((K, 3, self.n))
        Hb[:, :, IPHI] = _skew(u) - _skew(lever) @ _skew(a)
        Hb[:, :, INU] = -_I3
        Hb[:, :, IBG] = -_skew(lever)
        if self.i_lev is not None:
            Hb[:, :, self.i_lev] = -_skew(w_nb)
        if self.i_sf is not None:
            Hb[:, :, self.i_sf] = -_skew(lever) * (self.w_last if rate is None
                                                   else rate)[:, None, :]
        return z_hat, C @ Hb

    def add_body_noise(self, var_attitude, var_velocity) -> None:
        """Grow every filter's attitude and velocity error variances by ``var_attitude``
        (3,) rad^2 and ``var_velocity`` (3,) (m/s)^2, body axes (the error state's own):
        content of the increments that the samples do not hold (lost samples:
        :mod:`~sins_align.estimators.in_motion.gaps`)."""
        P = self.P.copy()           # (the stored states share the old one)
        i = np.arange(3)
        P[:, i, i] += np.asarray(var_attitude, dtype=float)
        P[:, 3 + i, 3 + i] += np.asarray(var_velocity, dtype=float)
        self.P = P

    def exclude_velocity_jitter(self, jitter) -> None:
        """Take the IMU velocity's jitter out of the transition since the last call.

        jitter: (3,) m/s, body axes: the jitter of the IMU velocity now (the part of it a
        velocity reference that does not vibrate cannot see; ``VelocityJitter`` in
        :mod:`~sins_align.estimators.in_motion.jitter`), which the caller is about to take
        out of a velocity update. The runs since the previous call coupled the attitude
        error into the velocity error through the whole velocity increment
        (``-(V x) phi``), the jitter's change ``d`` included; an update that compares the
        reference with the IMU velocity less its jitter does not see that part, and a
        transition that keeps it gives the filter attitude (heading) information from the
        vibration that no measurement holds. So the velocity error is moved as if the
        increment had been ``V - d``: ``nu <- nu + (d x) phi`` (``d`` in body axes now: the
        jitter now less the previous one, carried in ENU by each filter's attitude). The
        same change of the bias coupling (``(d x)`` times the run's ``S zeta_g``, below 1 %
        of that coupling for a jitter of 0.01 m/s) is left out."""
        jitter = np.asarray(jitter, dtype=float).reshape(3)
        C = self.C
        if self.K == 1 and self.schedule is None:
            # (the same for one filter, on 2-D arrays)
            C0 = C[0]
            x, y, z = (jitter - self.jitter_enu[0] @ C0).tolist()
            self.jitter_enu = (C0 @ jitter)[None]
            D = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
            P = self.P[0].copy()
            P[INU, :] += D @ P[IPHI, :]
            P[:, INU] += P[:, IPHI] @ D.T
            self.P = (0.5 * (P + P.T))[None]
            return
        d = jitter - np.einsum("kji,kj->ki", C, self.jitter_enu)          # (K, 3), body
        self.jitter_enu = C @ jitter
        D = _skew(d)                                                      # (K, 3, 3)
        P = self.P.copy()
        P[:, INU, :] += D @ P[:, IPHI, :]
        P[:, :, INU] += P[:, :, IPHI] @ _mT(D)
        self.P = 0.5 * (P + _mT(P))
        if self.schedule is not None:
            dx = self.dx.copy()
            dx[:, INU] += np.einsum("kij,kj->ki", D, dx[:, IPHI])
            self.dx = dx

    def update_velocity(self, z, R, nis_limit=None, consider_heading=False, force=None,
                        rate=None):
        """Velocity of the antenna, ENU: (3,) for every filter, NaN components not measured,
        R (3, 3); or (K, 3), each filter its own (a component NaN in every row or in none),
        and R (3, 3) or (K, 3, 3). ``consider_heading``: the heading is a consider state of
        this update (:meth:`_apply`; what a standing vehicle whose gyro cannot gyrocompass
        asks for: there the measured rates and forces hold only noise, and a transition built
        on them turns velocity updates into heading information that is not there).
        ``force``, ``rate``: the vehicle's specific force and rate (:meth:`velocity_model`).
        Returns (NIS per dof, log-likelihood), each (K,)."""
        z = np.asarray(z, dtype=float)
        z_hat, H = self.velocity_model(force, rate)
        R = np.asarray(R, dtype=float)
        if z.size == 3 and all(map(math.isfinite, z.ravel().tolist())):
            # (one measurement, every component: the usual case)
            return self._apply(z - z_hat, H, R, nis_limit, consider_heading)
        ok = np.isfinite(z) if z.ndim == 1 else np.isfinite(z).all(axis=0)
        if ok.all():
            return self._apply(z - z_hat, H, R, nis_limit, consider_heading)
        Rk = R[np.ix_(ok, ok)] if R.ndim == 2 else R[:, ok][:, :, ok]
        return self._apply((z - z_hat)[:, ok], H[:, ok], Rk, nis_limit, consider_heading)

    def update_lateral(self, axis: int, sigma: float, nis_limit=None, slip: float = 0.0,
                       slip_updates: float = 1.0, consider_heading=False):
        """Non-holonomic constraint: the velocity of the point at ``nhc_lever`` (body axes,
        from the IMU: a car's rear-axle centre) has no component along the vehicle's side
        (+- sigma). That velocity is ``C^T v + w_nb x l``, the rate term as the antenna's of
        :meth:`velocity_model`, in body axes; the vehicle's side is the IMU's ``axis``, or,
        with the ``nhc_mount`` states (an IMU mounted a little rotated against the vehicle:
        a 2 deg yaw puts 0.35 m/s of the forward speed on the IMU's side axis at 10 m/s),
        ``u = exp(eps x) e_axis`` (eps in IMU axes; its component along ``e_axis`` is
        invisible and keeps its prior).

        ``slip`` (rad per m/s^2): a tyre's sideslip angle per m/s^2 of lateral acceleration
        (a bound). In a turn the lateral velocity is not zero but about ``slip a_lat u`` (u
        the forward speed), for the whole turn: the noise gets that, times the square root of
        ``slip_updates`` (how many updates it lasts), so that the updates of one turn together
        claim no more than one. Each filter of the bank takes its own speed and rate.
        ``consider_heading``: as :meth:`update_velocity`'s (a parked vehicle)."""
        if self.K == 1 and SINGLE_FLOATS:
            return self._lateral_one(axis, sigma, nis_limit, slip, slip_updates,
                                     consider_heading)
        # the vehicle's side: the IMU's ``axis`` (u None), or the unit vectors u (K, 3) in
        # IMU axes of the nhc_mount states
        u = None if self.i_nhm is None else self.nhc_mount[:, :, axis]
        C = self.C
        vb = np.einsum("kji,kj->ki", C, self.v)
        if u is None:
            def side(M):                    # the side's row of (K, 3, m) body-axis rows
                return M[:, axis, :]

            def side_v(x):                  # the side's component of (K, 3) vectors
                return x[:, axis]
        else:
            uT = u[:, None, :]

            def side(M):
                return (uT @ M)[:, 0]

            def side_v(x):
                return (uT @ x[:, :, None])[:, 0, 0]
        H = np.zeros((self.K, 1, self.n))
        H[:, 0, IPHI] = -side(_skew(vb))
        H[:, 0, INU] = -(_I3[axis] if u is None else u)
        lever = self.nhc_lever
        at_lever = self.i_nhl is not None or lever.any()
        R = np.array([[sigma * sigma]])
        if at_lever or slip > 0.0:
            a, w_nb = self._body_rate()
        if slip > 0.0:                      # the IMU's own lateral acceleration and speed
            a_lat = np.abs(side_v(_cross(w_nb, vb)))
            speed = np.linalg.norm(vb, axis=1)
            R = (sigma * sigma + slip_updates * (slip * a_lat * speed) ** 2)[:, None, None]
        if at_lever:
            vb = vb + _cross(w_nb, lever)
            H[:, 0, IPHI] -= side(_skew(lever) @ _skew(a))
            H[:, 0, IBG] = -side(_skew(lever))
            if self.i_nhl is not None:
                H[:, 0, self.i_nhl] = -side(_skew(w_nb))
            if self.i_sf is not None:
                H[:, 0, self.i_sf] = side(-_skew(lever) * self.w_last[:, None, :])
        if u is not None:
            # the side's error (a rotation on the left of the estimate: the feedback
            # composes exp(-d x) R): u_true = exp(-d x) u, so its velocity
            # component changes by -d . (u x v_b) to first order
            H[:, 0, self.i_nhm] = -_cross(u, vb)
        return self._apply(-side_v(vb)[:, None], H, R, nis_limit, consider_heading)

    def _lateral_one(self, axis, sigma, nis_limit, slip, slip_updates, consider_heading):
        """:meth:`update_lateral` of a bank of one filter: the body velocity, the rates,
        the cross products, the speed and the noise in Python floats (in numpy's order of
        terms), the products with the vehicle's side and of matrices numpy's as in the
        bank's path (BLAS rounds them its own way): the same numbers to the bit
        (:data:`SINGLE_FLOATS`; test_in_motion_single.py)."""
        c0, c1, c2, c3, c4, c5, c6, c7, c8 = self.C[0].ravel().tolist()
        v0, v1, v2 = self.v[0].tolist()
        b0 = c0 * v0 + c3 * v1 + c6 * v2                # C^T v
        b1 = c1 * v0 + c4 * v1 + c7 * v2
        b2 = c2 * v0 + c5 * v1 + c8 * v2
        if self.i_nhm is None:
            u = None

            def side(M):                    # the side's row of (3, m) body-axis rows
                return M[axis]

            def side_v(x):                  # the side's component of a 3-vector
                return x[axis]
        else:
            u = self.nhc_mount[:, :, axis]
            uT = u[:, None, :]

            def side(M):
                return (uT @ M[None])[0, 0]

            def side_v(x):
                return float((uT @ np.array(x)[None, :, None])[0, 0, 0])
        H = np.zeros((1, 1, self.n))
        H[0, 0, IPHI] = -side(np.array([[0.0, -b2, b1], [b2, 0.0, -b0], [-b1, b0, 0.0]]))
        H[0, 0, INU] = -(_I3[axis] if u is None else u[0])
        lever = self.nhc_lever[0]
        at_lever = self.i_nhl is not None or lever.any()
        R = np.array([[sigma * sigma]])
        if at_lever or slip > 0.0:
            # _body_rate: C^T (w_ie + w_en) and the body's rate against the frame
            lat, h = float(self.lat[0]), float(self.h[0])
            a0, a1, a2 = _frame_rate_floats(lat, h, v0, v1, c0, c1, c2, c3, c4, c5, c6, c7, c8)
            wl = self.w_last[0].tolist()
            n0, n1, n2 = wl[0] - a0, wl[1] - a1, wl[2] - a2
        if slip > 0.0:                      # the IMU's own lateral acceleration and speed
            a_lat = abs(side_v([n1 * b2 - n2 * b1, n2 * b0 - n0 * b2, n0 * b1 - n1 * b0]))
            speed = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
            q = slip * a_lat * speed
            R = np.array([[[sigma * sigma + slip_updates * (q * q)]]])
        if at_lever:
            l0, l1, l2 = lever.tolist()
            b0, b1, b2 = b0 + (n1 * l2 - n2 * l1), b1 + (n2 * l0 - n0 * l2), \
                b2 + (n0 * l1 - n1 * l0)
            Sl = np.array([[0.0, -l2, l1], [l2, 0.0, -l0], [-l1, l0, 0.0]])
            H[0, 0, IPHI] -= side(Sl @ np.array([[0.0, -a2, a1], [a2, 0.0, -a0],
                                                 [-a1, a0, 0.0]]))
            H[0, 0, IBG] = -side(Sl)
            if self.i_nhl is not None:
                H[0, 0, self.i_nhl] = -side(np.array([[0.0, -n2, n1], [n2, 0.0, -n0],
                                                      [-n1, n0, 0.0]]))
            if self.i_sf is not None:
                H[0, 0, self.i_sf] = side(-Sl * wl)
        if u is not None:
            # (see update_lateral)
            x0, x1, x2 = u[0].tolist()
            H[0, 0, self.i_nhm] = [-(x1 * b2 - x2 * b1), -(x2 * b0 - x0 * b2),
                                   -(x0 * b1 - x1 * b0)]
        return self._apply(np.array([[-side_v([b0, b1, b2])]]), H, R, nis_limit,
                           consider_heading)

    def update_attitude(self, C_ref, R, nis_limit=None):
        """Attitude of a master INS: ``C_ref = C exp(-mu x) exp(n x)``, with ``mu`` the
        mounting misalignment (the estimated state, or zero) and n of covariance R (rad^2).
        The residual ``log((C_hat exp(-mu_hat x))^T C_ref)`` is ``-phi + d_mu + n`` to first
        order (``d_mu = mu_hat - mu``)."""
        Cm_hat = self.C @ so3_exp(-self.mount)
        y = so3_log(_mT(Cm_hat) @ np.asarray(C_ref, dtype=float))
        H = np.zeros((self.K, 3, self.n))
        H[:, :, IPHI] = -_I3
        if self.i_mnt is not None:
            H[:, :, self.i_mnt] = _I3
        return self._apply(y, H, np.asarray(R, dtype=float), nis_limit)


def sample_transition(ekf: InvariantEKF, dt: float, gyro, accel) -> np.ndarray:
    """The (n, n) transition of filter 0 of the bank over one sample (the per-sample map the
    closed-form runs are the product of; see the module docstring)."""
    w = (np.asarray(gyro, float) - ekf.bg[0]) / (1.0 + ekf.sf[0])
    f = (np.asarray(accel, float) - ekf.ba[0]) / (1.0 + ekf.sa[0])
    rho = so3_exp(w * dt)
    half = so3_exp(0.5 * w * dt)
    dV = half @ f * dt
    Phi = np.eye(ekf.n)
    Phi[IPHI, IPHI] = rho.T
    Phi[IPHI, IBG] = -dt * rho.T @ half
    Phi[INU, IPHI] = -rho.T @ skew(dV)
    Phi[INU, INU] = rho.T
    Phi[INU, IBG] = 0.5 * dt * rho.T @ skew(dV) @ half
    Phi[INU, IBA] = -dt * rho.T @ half
    if ekf.i_sf is not None:
        Phi[IPHI, ekf.i_sf] = Phi[IPHI, IBG] @ np.diag(w)
        Phi[INU, ekf.i_sf] = Phi[INU, IBG] @ np.diag(w)
    if ekf.i_sa is not None:
        Phi[INU, ekf.i_sa] = Phi[INU, IBA] @ np.diag(f)
    return Phi


def propagate_reference(ekf: InvariantEKF, dt, gyro, accel) -> None:
    """Per-sample reference of :meth:`InvariantEKF.propagate` (filter 0 of the bank): the
    strapdown mechanization (:func:`sins_align.core.strapdown.mechanize`) and each sample's
    transition (:func:`sample_transition`) and noise applied one after the other. Slow; for
    tests."""
    nz = ekf.noise
    n = ekf.n
    for k in ekf._ARRAYS:                  # written in place below: its own arrays
        setattr(ekf, k, getattr(ekf, k).copy())
    for d, g, a in zip(np.asarray(dt, float).reshape(-1), np.asarray(gyro, float).reshape(-1, 3),
                       np.asarray(accel, float).reshape(-1, 3)):
        Phi = sample_transition(ekf, d, g, a)
        w = (g - ekf.bg[0]) / (1.0 + ekf.sf[0])
        f = (a - ekf.ba[0]) / (1.0 + ekf.sa[0])
        Q = np.zeros((n, n))
        Q[IPHI, IPHI] = nz.gyro_arw ** 2 * d * _I3
        Q[INU, INU] = nz.accel_vrw ** 2 * d * _I3
        Q[IBG, IBG] = nz.gyro_bias_walk ** 2 * d * _I3
        Q[IBA, IBA] = nz.accel_bias_walk ** 2 * d * _I3
        ekf.P[0] = Phi @ ekf.P[0] @ Phi.T + Q
        s = mechanize(ekf.nav(0), d, w, f)
        ekf.C[0], ekf.v[0], ekf.lat[0], ekf.lon[0], ekf.h[0] = s.C, s.v, s.lat, s.lon, s.h
        ekf.w_last[0] = w
        ekf.f_last[0] = f


def _frame_rate_floats(lat, h, v0, v1, c0, c1, c2, c3, c4, c5, c6, c7, c8):
    """C^T (w_ie + w_en) in Python floats, C = [[c0, c1, c2], [c3, c4, c5], [c6, c7, c8]]
    (body to ENU), at latitude ``lat`` (rad), height ``h`` and east / north velocity ``v0``,
    ``v1``: the frame's rate in the body axes as :meth:`InvariantEKF._body_rate` computes it
    for one filter, term for term (the single-filter velocity and lateral models share it)."""
    sl, cl = math.sin(lat), math.cos(lat)
    d = 1.0 - WGS84_E2 * (sl * sl)
    rn = WGS84_A / math.sqrt(d)
    rm = rn * (1.0 - WGS84_E2) / d
    ve = v0 / (rn + h)
    w0 = -v1 / (rm + h)
    w1 = OMEGA_IE * cl + ve
    w2 = OMEGA_IE * sl + ve * sl / cl
    return (c0 * w0 + c3 * w1 + c6 * w2, c1 * w0 + c4 * w1 + c7 * w2,
            c2 * w0 + c5 * w1 + c8 * w2)
