"""The batched covariance recursion (kalman.riccati_steps, kalman.affine_scan) equals the
plain step-by-step recursion it replaces in the fast path's gain-schedule cache."""
import numpy as np
import pytest

from sins_align.estimators.quasi_static.aligner import AlignConfig, AlignmentFilter
from sins_align.core import kalman
from sins_align.core.kalman import affine_scan, inv3, joseph_update, riccati_steps
from sins_align.core.models import averaged_measurement_matrix, measurement_matrix


def plain(P, Phi, Qd, H, R, n):
    out = []
    for _ in range(n):
        P = Phi @ P @ Phi.T + Qd
        out.append(joseph_update(P, H, R))
        P = out[-1][0]
    return [np.array(x) for x in zip(*out)]


def alignment_case(fine: bool, r_std: float, m: int = 10, dt: float = 0.01,
                   grade: str = "navigation"):
    """(P0, Phi, Qd, H, R) of the package's coarse or fine pass (constant model, 34 deg)."""
    cfg = AlignConfig(latitude_deg=34.0, specs=grade)
    fl = AlignmentFilter(cfg, np.eye(3)[None])
    if fine:
        fl._start_pass(np.eye(3)[None], True, cfg.fine_initial_std_deg,
                       np.eye(3)[None] * r_std ** 2)
        H = averaged_measurement_matrix(measurement_matrix("constant"), fl._Fconst, m * dt)
        R = fl.R[0]
    else:
        H = measurement_matrix("constant")
        R = fl.R[0] * (0.01 / (m * dt))
    Phi, Qd, _ = fl._disc_m(m, dt)
    return fl.P[0], Phi, Qd, H, R


@pytest.mark.parametrize("fine,r_std,m,n", [
    (False, 0.0, 10, 600),       # coarse pass, 100 Hz, update every 0.1 s
    (False, 0.0, 1, 300),        # the paper's schedule: an update at every sample
    (True, 1e-4, 100, 600),      # fine pass at the noise floor, 1 s intervals
    (True, 1e-2, 100, 37),       # fine pass, heavy sway; n not a multiple of the chunk
    (True, 1e-7, 100, 50),       # far below the floor: the chunk check must shrink chunks
])
def test_riccati_steps_equal_the_plain_recursion(fine, r_std, m, n):
    """Gains to 1e-9 relative and covariances to 1e-9 of sqrt(P_ii P_jj) (the plain
    recursion's own rounding in the well-measured velocity block is ~1e-10 of that)."""
    P0, Phi, Qd, H, R = alignment_case(fine, r_std, m)
    P1, K1, S1 = plain(P0, Phi, Qd, H, R, n)
    P2, K2, S2 = riccati_steps(P0, Phi, Qd, H, R, n)
    assert P2.shape == (n, 6, 6) and K2.shape == (n, 6, 3) and S2.shape == (n, 3, 3)
    scale = np.sqrt(np.einsum("kii,kjj->kij", P1, P1))
    assert np.max(np.abs(P2 - P1) / scale) < 1e-9
    assert np.max(np.abs(K2 - K1)) < 1e-9 * np.abs(K1).max()
    assert np.max(np.abs(S2 - S1) / np.abs(S1).max(axis=(1, 2))[:, None, None]) < 1e-9


@pytest.mark.parametrize("grade,fine,r_std,m", [
    ("tactical", True, 1e-4, 100),      # fine pass: chunks of 16 and 8 fail, 4 pass
    ("consumer", False, 0.0, 200),      # coarse updates every 2 s, MEMS grade
])
def test_riccati_steps_after_shorter_chunks_equal_the_plain_recursion(monkeypatch, grade, fine,
                                                                     r_std, m):
    """The path the tactical and consumer grades take: the first chunk fails the check at 16
    steps, a shorter chunk passes, and the whole run still agrees with the plain recursion."""
    seen = []
    check = kalman._prior_error
    monkeypatch.setattr(kalman, "_prior_error",
                        lambda P0, prior, *a, **k: seen.append(len(prior)) or check(P0, prior,
                                                                                    *a, **k))
    P0, Phi, Qd, H, R = alignment_case(fine, r_std, m, grade=grade)
    n = 200
    P1, K1, _ = plain(P0, Phi, Qd, H, R, n)
    P2, K2, _ = riccati_steps(P0, Phi, Qd, H, R, n)
    if grade == "tactical":
        assert seen[-1] == n and 4 <= seen[-2] < 16, seen  # shortened, then checked whole
    else:
        # consumer grade: its gyro bias is attitude noise now (BIAS_TRACK_TIME), and the
        # chunks settle at 4 steps without a whole-run check; the result must still agree
        assert seen and seen[0] < 16, seen
    scale = np.sqrt(np.einsum("kii,kjj->kij", P1, P1))
    assert np.max(np.abs(P2 - P1) / scale) < 1e-9
    assert np.max(np.abs(K2 - K1)) < 1e-9 * np.abs(K1).max()


def test_riccati_chunk_check_catches_a_bad_chunk():
    """With chunks forced long, the unchecked transformation is far off for a
    well-measured state; the check must fall back to shorter chunks and still agree."""
    P0, Phi, Qd, H, R = alignment_case(True, 1e-6, 100)
    P1, K1, _ = plain(P0, Phi, Qd, H, R, 64)
    _, K2, _ = riccati_steps(P0, Phi, Qd, H, R, 64, chunk=64)
    assert np.max(np.abs(K2 - K1)) < 1e-9 * np.abs(K1).max()
    _, K3, _ = riccati_steps(P0, Phi, Qd, H, R, 64, chunk=64, tol=np.inf)   # no check
    assert not np.max(np.abs(K3 - K1)) < 1e-6 * np.abs(K1).max()


@pytest.mark.parametrize("n", [1, 2, 3, 16, 17, 600])
def test_affine_scan_equals_the_loop(n):
    rng = np.random.default_rng(n)
    A = rng.normal(size=(n, 6, 6)) * 0.3
    b = rng.normal(size=(n, 6, 6))
    x, ref = rng.normal(size=(6, 6)), []
    x0 = x
    for k in range(n):
        x = A[k] @ x + b[k]
        ref.append(x)
    assert np.allclose(affine_scan(A, b, x0), ref, rtol=0, atol=1e-12)


def test_inv3_stack_matches_lapack_and_raises_on_singular():
    rng = np.random.default_rng(0)
    S = rng.normal(size=(5, 4, 3, 3)) + 3 * np.eye(3)
    assert np.allclose(inv3(S), np.linalg.inv(S), rtol=1e-13, atol=1e-14)
    S[2, 1] = 0.0
    with pytest.raises(np.linalg.LinAlgError):
        inv3(S)


def _series3(F, Qc, h):
    """The former 3rd-order series: exact to rounding only for |F h| far below 1."""
    Fh = F * h
    F2 = Fh @ Fh
    Phi = np.eye(len(F)) + Fh + F2 / 2.0 + F2 @ Fh / 6.0
    FQ = F @ Qc
    FFQ = F @ FQ
    Qd = Qc * h + (FQ + FQ.T) * (h * h / 2.0) + (FFQ + 2.0 * FQ @ F.T + FFQ.T) * (h ** 3 / 6.0)
    return Phi, 0.5 * (Qd + Qd.T)


def _compose(Phi, Qd, Phi2, Qd2):
    """The step (Phi, Qd) followed by the step (Phi2, Qd2)."""
    return Phi2 @ Phi, Phi2 @ Qd @ Phi2.T + Qd2


def _long_reference(F, Qc, dt, h_max=1e-3, loop_max=1.0):
    """Phi, Qd over dt from many short 3rd-order steps (at most h_max): a plain loop over
    steps of at most loop_max s, each of them 2^k short steps composed by doubling."""
    n = max(1, int(np.ceil(dt / loop_max)))
    k = max(0, int(np.ceil(np.log2(dt / n / h_max))))
    Phi1, Qd1 = _series3(F, Qc, dt / n / 2 ** k)
    for _ in range(k):
        Phi1, Qd1 = _compose(Phi1, Qd1, Phi1, Qd1)
    Phi, Qd = np.eye(len(F)), np.zeros_like(Qc)
    for _ in range(n):
        Phi, Qd = _compose(Phi, Qd, Phi1, Qd1)
    return Phi, Qd


def _rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


@pytest.mark.parametrize("grade", ["navigation", "consumer"])
@pytest.mark.parametrize("model", ["constant", "conventional"])
@pytest.mark.parametrize("dt", [0.01, 1.0, 60.0, 3600.0])
def test_discretize_exact_over_long_intervals(grade, model, dt):
    """discretize equals the composition of many short steps for 0.01 s to 3600 s (the
    former 3rd-order series was off by far more than rounding beyond a few seconds)."""
    from sins_align.core.models import system_matrix
    fl = AlignmentFilter(AlignConfig(latitude_deg=34.0, specs=grade), np.eye(3)[None])
    f_n = np.array([0.3, -0.2, 9.79])          # a tilted specific force for 'conventional'
    F = system_matrix(model, fl.w_ie, fl.g_n, f_n, np.zeros(3))
    Phi, Qd = kalman.discretize(F, fl.Qc, dt)
    Phi_r, Qd_r = _long_reference(F, fl.Qc, dt)
    # the reference's own rounding grows with the number of steps (about 3e-14 x dt / s;
    # the closed-form test below shows discretize itself to be far closer)
    tol = 1e-13 * max(dt, 1.0)
    assert _rel(Phi, Phi_r) < tol and _rel(Qd, Qd_r) < tol
    assert np.array_equal(Qd, Qd.T)
    # each block (attitude, velocity, cross) on its own scale
    for blk in (np.s_[:3, :3], np.s_[3:, 3:], np.s_[:3, 3:]):
        assert _rel(Qd[blk], Qd_r[blk]) < tol
    for blk in (np.s_[:3, :3], np.s_[3:, :3]):
        assert _rel(Phi[blk], Phi_r[blk]) < tol
    if dt >= 60.0:
        P3, Q3 = _series3(F, fl.Qc, dt)
        assert _rel(Q3, Qd_r) > 1e-8          # the old series: far from rounding there
    # stacked input gives the same as one by one
    Fs = np.stack([F, F * 0.5])
    Ps, Qs = kalman.discretize(Fs, fl.Qc, dt)
    assert np.allclose(Ps[0], Phi, rtol=0, atol=1e-13 * np.abs(Phi).max())
    assert _rel(Qs[0], Qd) < 1e-13


def test_discretize_constant_model_closed_form():
    """Constant model: Phi in closed form (Earth-rate rotation and its integral) and Qd by
    Gauss-Legendre quadrature of exp(F s) Qc exp(F s)^T over [0, dt]."""
    from sins_align.core.rotation import so3_exp
    fl = AlignmentFilter(AlignConfig(latitude_deg=60.0, specs="tactical"), np.eye(3)[None])
    F, Qc = fl._Fconst, fl.Qc
    A, B = F[:3, :3], F[3:, :3]

    def phi(t):
        P = np.eye(6)
        P[:3, :3] = so3_exp(-fl.w_ie * t)
        # int_0^t exp(A s) ds with A = -(w x): t I + (1 - cos wt)/w^2 A + (wt - sin wt)/w^3 A^2
        w = np.linalg.norm(fl.w_ie)
        x = w * t                               # (1 - cos x) and (x - sin x) without cancellation
        x_sin = x ** 3 / 6 - x ** 5 / 120 + x ** 7 / 5040 if x < 1e-2 else x - np.sin(x)
        P[3:, :3] = B @ (t * np.eye(3) + 2.0 * np.sin(0.5 * x) ** 2 / w ** 2 * A
                         + x_sin / w ** 3 * A @ A)
        return P

    for dt in (1.0, 60.0, 3600.0):
        x, wq = np.polynomial.legendre.leggauss(40)
        edges = np.linspace(0.0, dt, 9)
        Qd_r = np.zeros((6, 6))
        for a, b in zip(edges[:-1], edges[1:]):
            for xi, wi in zip(x, wq):
                P = phi(0.5 * (b - a) * xi + 0.5 * (a + b))
                Qd_r += 0.5 * (b - a) * wi * P @ Qc @ P.T
        Phi, Qd = kalman.discretize(F, Qc, dt)
        assert _rel(Phi, phi(dt)) < 1e-13
        assert _rel(Qd, Qd_r) < 1e-12


def test_discretize_small_dt_equals_the_former_series():
    """At the per-sample intervals the result equals the former 3rd-order series (which is
    exact to rounding there): the fast path's equalities rest on it. dt = 0 is identity."""
    for grade in ("navigation", "tactical", "consumer"):
        fl = AlignmentFilter(AlignConfig(latitude_deg=34.0, specs=grade), np.eye(3)[None])
        for dt in (0.001, 0.005, 0.01, 0.02):
            Phi, Qd = kalman.discretize(fl._Fconst, fl.Qc, dt)
            P3, Q3 = _series3(fl._Fconst, fl.Qc, dt)
            # equal to rounding (nav, tactical); the consumer grade, whose attitude noise now
            # holds its gyro bias, leaves the series a 4th-order term of ~2e-14
            tol = 1e-13 if grade == "consumer" else 1e-15
            assert _rel(Phi, P3) < 1e-15 and _rel(Qd, Q3) < tol
    Phi, Qd = kalman.discretize(fl._Fconst, fl.Qc, 0.0)
    assert np.array_equal(Phi, np.eye(6)) and not Qd.any()


def test_discretize_general_stable_matrix():
    """Not only the nearly nilpotent alignment models: F = S - 0.2 I with S a random skew
    matrix (eigenvalues of size 3), against the closed form in the eigenbasis of S (unitary):
    exp(F t) = U diag(e^(mu t)) U^H, Qd_jk = (U^H Qc U)_jk (e^((mu_j + conj mu_k) dt) - 1)
    / (mu_j + conj mu_k) in that basis."""
    rng = np.random.default_rng(5)
    S = rng.normal(size=(5, 5))
    S = S - S.T
    F = S - 0.2 * np.eye(5)
    L = rng.normal(size=(5, 5))
    Qc = L @ L.T
    lam, U = np.linalg.eigh(1j * S)             # S = U diag(-i lam) U^H
    mu = -1j * lam - 0.2
    Qu = U.conj().T @ Qc @ U
    nu = mu[:, None] + mu.conj()[None, :]
    for dt in (0.01, 1.0, 10.0, 60.0):
        Phi_r = (U @ np.diag(np.exp(mu * dt)) @ U.conj().T).real
        Qd_r = (U @ (Qu * np.expm1(nu * dt) / nu) @ U.conj().T).real
        Phi, Qd = kalman.discretize(F, Qc, dt)
        assert _rel(Phi, Phi_r) < 1e-12 and _rel(Qd, Qd_r) < 1e-12, (dt, _rel(Phi, Phi_r),
                                                                   _rel(Qd, Qd_r))
