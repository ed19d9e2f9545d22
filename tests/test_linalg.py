"""Batched run-last linear algebra against plain numpy on (M, n, n) stacks."""
import numpy as np
import pytest

from adaptfilt import linalg as la


def random_spd(rng, n, M, cond=1e3):
    """(M, n, n) random SPD matrices with eigenvalues in [1, cond]."""
    G = rng.standard_normal((M, n, n))
    Q, _ = np.linalg.qr(G)
    ev = np.exp(rng.uniform(0.0, np.log(cond), (M, n)))
    return np.einsum("mik,mk,mjk->mij", Q, ev, Q)


def rl(A):
    """(M, ...) -> run-last (..., M)."""
    return np.moveaxis(A, 0, -1)


def pub(A):
    return np.moveaxis(A, -1, 0)


@pytest.mark.parametrize("n", [1, 2, 4, 7, 14])  # 14 > _LOOP_MAX_N: the LAPACK path
def test_chol_matches_numpy(n):
    rng = np.random.default_rng(n)
    P = random_spd(rng, n, 50)
    L = la.chol(rl(P))
    np.testing.assert_allclose(pub(L), np.linalg.cholesky(P), rtol=1e-10, atol=1e-12)
    assert np.all(np.triu(pub(L), 1) == 0)


def test_chol_extra_batch_axes():
    rng = np.random.default_rng(0)
    P = random_spd(rng, 3, 12).reshape(3, 4, 3, 3)  # batch (3, 4)
    L = la.chol(np.moveaxis(P, (2, 3), (0, 1)))
    np.testing.assert_allclose(np.moveaxis(L, (0, 1), (2, 3)), np.linalg.cholesky(P), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("n", [1, 3, 14])
def test_chol_names_bad_runs(n):
    rng = np.random.default_rng(1)
    P = random_spd(rng, n, 8)
    P[2] = -P[2]  # negative definite
    P[5, 0, 0] = np.nan
    with pytest.raises(la.NotPositiveDefinite, match=r"Pzz is not positive definite in run\(s\) 2, 5") as e:
        la.chol(rl(P), "Pzz")
    assert list(e.value.runs) == [2, 5]
    assert isinstance(e.value, np.linalg.LinAlgError)


def test_chol_rejects_nonsquare():
    with pytest.raises(ValueError, match="square"):
        la.chol(np.ones((2, 3, 4)))


def test_mm_mv_sym():
    rng = np.random.default_rng(2)
    A, B = rng.standard_normal((10, 3, 4)), rng.standard_normal((10, 4, 2))
    x = rng.standard_normal((10, 4))
    np.testing.assert_allclose(pub(la.mm(rl(A), rl(B))), A @ B, rtol=1e-13)
    np.testing.assert_allclose(pub(la.mv(rl(A), rl(x))), (A @ x[..., None])[..., 0], rtol=1e-13)
    S = rng.standard_normal((10, 3, 3))
    np.testing.assert_allclose(pub(la.sym(rl(S))), (S + S.transpose(0, 2, 1)) / 2)


@pytest.mark.parametrize("n,k", [(1, 1), (1, 3), (3, 1), (4, 4), (6, 2)])
def test_solve_spd_and_logdet(n, k):
    rng = np.random.default_rng(10 * n + k)
    A = random_spd(rng, n, 20)
    B = rng.standard_normal((20, n, k))
    L = la.chol(rl(A))
    np.testing.assert_allclose(pub(la.solve_spd(L, rl(B))), np.linalg.solve(A, B), rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(la.logdet_chol(L), np.linalg.slogdet(A)[1], rtol=1e-12, atol=1e-12)


def test_clip_to_pd_repairs_only_listed_runs():
    rng = np.random.default_rng(3)
    P = random_spd(rng, 3, 6)
    P[1] = P[1] - 2.0 * np.linalg.eigvalsh(P[1])[-1] * np.diag([1.0, 0.0, 0.0])  # indefinite
    P[4] = np.diag([2.0, -1.0, 1e-20])
    assert np.linalg.eigvalsh(P[1])[0] < 0
    fixed = pub(la.clip_to_pd(rl(P), np.array([1, 4])))
    for r in (0, 2, 3, 5):
        np.testing.assert_array_equal(fixed[r], P[r])
    for r in (1, 4):
        ev = np.linalg.eigvalsh(fixed[r])
        assert ev[0] > 0
        np.linalg.cholesky(fixed[r])
        np.testing.assert_allclose(fixed[r], fixed[r].T)
    # the nearest-PD repair keeps the positive part: diag(2, floor, floor)
    np.testing.assert_allclose(fixed[4], np.diag([2.0, 2e-9, 2e-9]), rtol=1e-9, atol=1e-15)
    # the input is not modified
    assert np.linalg.eigvalsh(P[1])[0] < 0


def test_wrap_angle_range_and_congruence():
    rng = np.random.default_rng(4)
    a = np.concatenate([rng.uniform(-50, 50, 10000), [np.pi, -np.pi, 3 * np.pi, -3 * np.pi, 0.0, 2 * np.pi, 1e-17]])
    w = la.wrap_angle(a)
    assert np.all(w > -np.pi) and np.all(w <= np.pi)
    # same angle: congruent modulo 2 pi
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    k = (a - w) / (2 * np.pi)
    np.testing.assert_allclose(k, np.round(k), atol=1e-12)
    # +-pi both map to +pi (half-open interval), 2 pi to 0
    assert la.wrap_angle(np.array(np.pi)) == np.pi
    assert la.wrap_angle(np.array(-np.pi)) == np.pi
    assert la.wrap_angle(np.array(-3 * np.pi)) == np.pi
    assert abs(la.wrap_angle(np.array(2 * np.pi))) < 1e-15
    # angles already inside are left alone (up to round-off)
    inside = rng.uniform(-np.pi + 1e-9, np.pi, 1000)
    np.testing.assert_allclose(la.wrap_angle(inside), inside, atol=1e-15)
    # shape preserved on batched input
    assert la.wrap_angle(rng.uniform(-9, 9, (3, 5, 2))).shape == (3, 5, 2)


def test_not_positive_definite_survives_pickling():
    """A worker process that raises it sends it back to the pool (an exception that cannot be rebuilt
    breaks the whole pool, which then reports a dead worker instead of the error)."""
    import pickle

    from adaptfilt.linalg import NotPositiveDefinite

    err = pickle.loads(pickle.dumps(NotPositiveDefinite(np.array([3, 5]), "P_pred")))
    assert err.runs.tolist() == [3, 5] and str(err) == "P_pred is not positive definite in run(s) 3, 5"
