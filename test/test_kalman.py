"""The batched covariance recursion (kalman.riccati_steps, kalman.affine_scan) equals the
plain step-by-step recursion it replaces in the fast path's gain-schedule cache."""
import numpy as np
import pytest

from sins_align.estimator import AlignConfig, AlignmentFilter
from sins_align import kalman
from sins_align.kalman import affine_scan, inv3, joseph_update, riccati_steps
from sins_align.models import averaged_measurement_matrix, measurement_matrix


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
        fl._start_pass(np.eye(3)[None], True, cfg.fine_initial_std_deg, np.eye(3)[None] * r_std ** 2)
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
    ("consumer", False, 0.0, 200),      # coarse updates every 2 s, MEMS grade: 8 pass
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
    assert seen[-1] == n and 4 <= seen[-2] < 16, seen      # shortened, then checked whole
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
